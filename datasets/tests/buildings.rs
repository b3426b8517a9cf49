//! Generated buildings: every number gives a valid multilevel building with
//! the parts the benchmark needs, the same bytes every time; the sensors see
//! glass, people and the motion during a sweep as a real robot would.

use datasets::math::{Point3, Pose3, Vec3};
use datasets::simulator::world::block::BlockKind;
use datasets::simulator::world::layout::{CornerKind, Floor};
use datasets::simulator::world::lidar::{LidarConfig, scan, sweep};
use datasets::simulator::world::people::Walker;
use datasets::simulator::world::route::{Route, pose_on_floor};
use datasets::simulator::world::surface::SurfaceKind;
use datasets::simulator::world::{Seen, World, WorldConfig};

fn building(n: u32) -> World {
    World::new(&WorldConfig { building: n, ..WorldConfig::default() }, 11)
}

#[test]
fn generated_buildings_hold_every_part_and_a_drivable_route() {
    let mut hall_ramps = 0;
    for n in 1..=8 {
        let world = building(n);
        let layout = &world.layout;
        assert!((2..=4).contains(&layout.levels.len()), "building {n}: {} levels", layout.levels.len());
        assert!(layout.levels.windows(2).all(|w| w[1] > w[0] + 0.2), "building {n}: levels {:?}", layout.levels);
        let mut ramps = 0;
        for r in &layout.regions {
            if let Floor::Ramp { from, to, h0, h1, .. } = r.floor {
                let slope = ((h1 - h0).abs() / (to - from).abs()).atan().to_degrees();
                assert!((4.0..=12.0).contains(&slope), "building {n}: {} at {slope:.1} deg", r.name);
                ramps += 1;
                hall_ramps += usize::from(r.name.contains("hall"));
            }
        }
        assert_eq!(ramps, layout.levels.len() - 1, "building {n}: one ramp per level change");
        // Every level is reached by the route, which stays on the floor every 5 cm.
        let route = Route::new(&layout.route, 1.2);
        assert!((100.0..=300.0).contains(&route.length()), "building {n}: route {:.0} m", route.length());
        let mut heights_seen = vec![false; layout.levels.len()];
        let steps = (route.length() / 0.05) as usize;
        for k in 0..=steps {
            let (xy, heading) = route.at(k as f64 * 0.05);
            let pose =
                pose_on_floor(layout, xy, heading).unwrap_or_else(|| panic!("building {n}: off the floor at {xy:?}"));
            for (seen, h) in heights_seen.iter_mut().zip(&layout.levels) {
                *seen |= (pose.translation.z - h).abs() < 1e-9;
            }
            for b in &layout.blocks {
                assert!(b.distance(xy) > 0.5, "building {n}: route at {xy:?} runs into a {:?}", b.kind);
            }
        }
        assert!(heights_seen.iter().all(|&s| s), "building {n}: levels {:?} reached {heights_seen:?}", layout.levels);
        let (start, _) = route.at(0.0);
        let (end, _) = route.at(route.length());
        assert!(start[0].hypot(start[1]) < 1e-9 && end[0].hypot(end[1]) < 1e-9, "building {n}: the route loops back");

        let count = |kind: BlockKind| layout.blocks.iter().filter(|b| b.kind == kind).count();
        assert!(count(BlockKind::Pillar) + count(BlockKind::Partition) > 0, "building {n}: no pillars or partitions");
        assert!(
            count(BlockKind::Table) + count(BlockKind::Chair) + count(BlockKind::Shelf) > 0,
            "building {n}: no furniture"
        );
        let angled = layout.blocks.iter().any(|b| {
            matches!(b.kind, BlockKind::Partition | BlockKind::Pillar)
                && (b.yaw / std::f64::consts::FRAC_PI_2 - (b.yaw / std::f64::consts::FRAC_PI_2).round()).abs() > 0.05
        });
        assert!(angled, "building {n}: every wall is axis-aligned");
        assert!(layout.surfaces.iter().any(|s| s.kind == SurfaceKind::Glass), "building {n}: no glass");
        assert!(!layout.walkers.is_empty(), "building {n}: nobody walks");
        assert!(layout.regions.iter().any(|r| r.name.contains("doorway")), "building {n}: no doorways");
        // Landmarks only where three planes meet: none on tables, chairs or
        // glass; a closed shelf is a box, with the eight corners of a crate.
        for c in &layout.corners {
            let p = [c.position[0], c.position[1]];
            let on_clutter = layout.blocks.iter().any(|b| {
                matches!(b.kind, BlockKind::Table | BlockKind::Chair | BlockKind::Glass) && b.distance(p) < 1e-9
            });
            assert!(!on_clutter, "building {n}: a landmark corner at {:?} lies on clutter", c.position);
        }
        for shelf in layout.blocks.iter().filter(|b| b.kind == BlockKind::Shelf) {
            for [x, y] in shelf.footprint() {
                for (z, kind) in [(shelf.z[0], CornerKind::BoxBottom), (shelf.z[1], CornerKind::BoxTop)] {
                    let labelled = layout.corners.iter().any(|c| {
                        c.kind == kind
                            && (c.position[0] - x).hypot(c.position[1] - y) < 1e-9
                            && (c.position[2] - z).abs() < 1e-9
                    });
                    assert!(labelled, "building {n}: shelf corner {:?} is not a box corner", [x, y, z]);
                }
            }
        }
    }
    assert!(hall_ramps > 0, "no building has a ramp inside a hall");
}

#[test]
fn a_building_is_a_function_of_its_number() {
    let (a, b, c) = (building(3), building(3), building(4));
    let vertices = |w: &World| -> Vec<[f64; 3]> {
        w.layout.surfaces.iter().flat_map(|s| s.vertices.iter().map(|v| [v.x, v.y, v.z])).collect()
    };
    assert_eq!(vertices(&a), vertices(&b));
    assert_eq!(a.layout.route, b.layout.route);
    assert_ne!(a.layout.route, c.layout.route);
    // The appearance seed changes colours, never the geometry.
    let other = World::new(&WorldConfig { building: 3, ..WorldConfig::default() }, 99);
    assert_eq!(vertices(&a), vertices(&other));
}

#[test]
fn people_block_a_beam_while_they_stand_in_it() {
    // A person pacing north-south across the paper building's level-1 hall,
    // seen from its west end along y = 0.
    let mut world = World::new(&WorldConfig::default(), 7);
    let walker = Walker {
        from: [2.0, -2.0],
        to: [2.0, 2.0],
        floor_m: 0.0,
        speed_mps: 1.0,
        phase_m: 2.0,
        height_m: 1.7,
        colour: [0.5, 0.2, 0.2],
    };
    world.layout.walkers.push(walker);
    let eye = Point3::new(-1.0, 0.0, 1.0);
    let east = Vec3::x();
    // At time 0 the person is at y = 0: the near face of the shoulders.
    let seen = world.sense(&eye, &east, 0.01, 100.0, 0.0).expect("something ahead");
    assert_eq!(seen.seen, Seen::Person(0));
    assert!((seen.t - 2.75).abs() < 1e-9, "3 m minus half a shoulder width: {}", seen.t);
    assert!(world.blocked(&eye, &east, 0.01, 100.0, 0.0));
    // A second later the person is 1 m north: the beam runs on down the corridor.
    let later = world.sense(&eye, &east, 0.01, 100.0, 1.0).expect("a wall");
    assert!(matches!(later.seen, Seen::Surface(_)) && later.t > 7.0, "{later:?}");
    // Back and forth along the 4 m walk: at 4 s they cross y = 0 again, going south.
    assert_eq!(world.sense(&eye, &east, 0.01, 100.0, 4.0).map(|h| h.seen), Some(Seen::Person(0)));
}

#[test]
fn glass_passes_the_configured_share_of_lidar_beams() {
    let world = (1..=8).map(building).find(|w| w.layout.surfaces.iter().any(|s| s.kind == SurfaceKind::Glass));
    let world = world.expect("a building with glass");
    let layout = &world.layout;
    let pane = layout.surfaces.iter().find(|s| s.kind == SurfaceKind::Glass).expect("glass");
    let centre = pane.vertices.iter().fold(Vec3::zeros(), |a, v| a + v.coords) / pane.vertices.len() as f64;
    // The LIDAR 1 m in front of the pane at its mid height, x axis at the pane.
    let eye = centre + pane.normal * 1.0;
    let x = -pane.normal;
    let z = Vec3::z();
    let y = z.cross(&x);
    let rotation = datasets::math::Rot3::from_matrix(&datasets::math::Mat3::from_columns(&[x, y, z]));
    let pose = Pose3::from_parts(eye.into(), rotation);
    let config = LidarConfig {
        beams: 16,
        min_elevation_deg: -10.0,
        max_elevation_deg: 10.0,
        dropout: 0.0,
        range_noise_m: 0.0,
        ..LidarConfig::default()
    };
    let half_width = pane.vertices.iter().map(|v| (v.coords - centre).dot(&pane.u_axis).abs()).fold(0.0, f64::max);
    let cone = (half_width * 0.8).atan2(1.0).to_degrees();
    let mut through = 0;
    let mut aimed = 0;
    for pass in [0.0, 0.7] {
        let cloud = scan(&world, &LidarConfig { glass_pass: pass, ..config.clone() }, &pose, 0.0, 5);
        let (mut on_pane, mut beyond) = (0, 0);
        for p in &cloud.points {
            let azimuth = p.y.atan2(p.x).to_degrees();
            if f64::from(azimuth.abs()) > cone {
                continue;
            }
            let range = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt() as f64;
            let along = p.x as f64;
            if (along - 1.0).abs() < 0.02 {
                on_pane += 1;
            } else if range > 1.05 {
                beyond += 1;
            }
        }
        if pass == 0.0 {
            assert_eq!(beyond, 0, "opaque glass: every beam returns from the pane");
            aimed = on_pane;
        } else {
            through = beyond;
            let share = beyond as f64 / (beyond + on_pane) as f64;
            assert!((share - 0.7).abs() < 0.08, "{beyond} of {} beams passed", beyond + on_pane);
        }
    }
    assert!(aimed > 100 && through > 50, "aimed {aimed}, through {through}");
}

#[test]
fn a_sweep_is_distorted_by_the_motion_during_it() {
    // The paper building's level-1 hall: the LIDAR drives at 1 m/s towards
    // the east end of the hall during a 0.1 s sweep.
    let world = World::new(&WorldConfig::default(), 7);
    let config = LidarConfig { dropout: 0.0, range_noise_m: 0.0, sweep_period_s: 0.1, ..LidarConfig::default() };
    let speed = 1.0;
    let at = |t: f64| Pose3::translation(0.0 + speed * t, 0.0, 0.75);
    let moving = sweep(&world, &config, &at, 0.0, 3);
    let still = scan(&world, &config, &at(0.0), 0.0, 3);
    let times = moving.times.as_ref().expect("a sweep stamps its points");
    assert_eq!(times.len(), moving.len());
    assert!(times.windows(2).all(|w| w[1] >= w[0]), "firings in time order");
    assert!(times[0] == 0.0 && *times.last().expect("points") < 0.1);
    assert!(still.times.is_none());
    // Beams fired at time t see the walls from 1 m/s x t further east: the
    // shift of each point against the still scan is that motion.
    assert_eq!(moving.len(), still.len());
    let mut checked = 0;
    for ((m, s), &t) in moving.points.iter().zip(&still.points).zip(times) {
        let shift = Vec3::new((s.x - m.x) as f64, (s.y - m.y) as f64, (s.z - m.z) as f64);
        let dir = Vec3::new(s.x as f64, s.y as f64, s.z as f64).normalize();
        // The near-horizontal beam on the hall's west wall (x = -1.5).
        if shift.norm() < 0.3 && dir.x < -0.9 && dir.z.abs() < 0.01 {
            // A wall across x: the point is farther by the motion along x.
            assert!((shift.x - speed * t as f64).abs() < 0.02, "shift {shift:?} at {t} s");
            checked += 1;
        }
    }
    assert!(checked > 50, "only {checked} points on the west wall");
}

#[test]
fn a_generated_sequence_is_a_function_of_its_seeds() {
    let mut config = datasets::simulator::generate::DatagenConfig::for_building(2);
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.frames = Some(3);
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    datasets::simulator::generate::generate(a.path(), &config).unwrap();
    datasets::simulator::generate::generate(b.path(), &config).unwrap();
    let files = |root: &std::path::Path| -> Vec<(std::path::PathBuf, Vec<u8>)> {
        let mut out = Vec::new();
        let mut stack = vec![root.to_path_buf()];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    stack.push(path);
                } else {
                    out.push((path.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&path).unwrap()));
                }
            }
        }
        out.sort();
        out
    };
    let (fa, fb) = (files(a.path()), files(b.path()));
    assert!(fa.len() > 10, "{} files", fa.len());
    assert_eq!(fa.len(), fb.len());
    for ((pa, da), (pb, db)) in fa.iter().zip(&fb) {
        assert_eq!(pa, pb);
        assert!(da == db, "{} differs between two runs", pa.display());
    }
    // Another seed changes the noise and the looks, not the building.
    config.seed += 1;
    let c = tempfile::tempdir().unwrap();
    datasets::simulator::generate::generate(c.path(), &config).unwrap();
    let cloud = |root: &std::path::Path| std::fs::read(root.join("sequence/cloud/0000000000.100000.pcd")).unwrap();
    assert_ne!(cloud(a.path()), cloud(c.path()));
    let world = |root: &std::path::Path| std::fs::read_to_string(root.join("sequence/world.json")).unwrap();
    assert_eq!(world(a.path()), world(c.path()));
}
