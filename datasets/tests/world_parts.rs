//! Unit checks of the world's parts with exact answers: routes, ray casting,
//! the robot's pose on a ramp.

use datasets::math::{Point3, Vec3};
use datasets::seed::unit;
use datasets::simulator::world::World;
use datasets::simulator::world::layout::WorldConfig;
use datasets::simulator::world::route::{Route, pose_on_floor};
use datasets::simulator::world::surface::{Material, Pattern, Surface, SurfaceKind};

#[test]
fn a_rounded_right_angle_has_the_expected_length_and_headings() {
    let r = 1.0;
    let route = Route::new(&[[0.0, 0.0], [5.0, 0.0], [5.0, 4.0]], r);
    let expected = 5.0 + 4.0 - 2.0 * r + std::f64::consts::FRAC_PI_2 * r;
    assert!((route.length() - expected).abs() < 1e-12);
    let (p, h) = route.at(2.0);
    assert_eq!((p, h), ([2.0, 0.0], 0.0));
    // Halfway round the arc: 45 degrees, on the circle about (4, 1).
    let (p, h) = route.at(4.0 + std::f64::consts::FRAC_PI_4 * r);
    assert!((h - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
    assert!(((p[0] - 4.0).hypot(p[1] - 1.0) - r).abs() < 1e-12);
    let (p, h) = route.at(route.length());
    assert!(
        (p[0] - 5.0).abs() < 1e-12 && (p[1] - 4.0).abs() < 1e-12 && (h - std::f64::consts::FRAC_PI_2).abs() < 1e-12
    );
}

#[test]
fn a_quad_is_hit_inside_and_missed_outside() {
    let material = Material { base: [0.5; 3], pattern: Pattern::Cardboard, seed: 0 };
    let quad = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(2.0, 0.0, 0.0),
        Point3::new(2.0, 1.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
    ];
    let s = Surface::new(SurfaceKind::Floor, quad, -Vec3::z(), Vec3::x(), material);
    assert_eq!(s.normal, -Vec3::z());
    let down = Vec3::new(0.0, 0.0, -1.0);
    assert_eq!(s.intersect(&Point3::new(1.5, 0.5, 2.0), &down, 0.0, 10.0), Some(2.0));
    assert_eq!(s.intersect(&Point3::new(2.5, 0.5, 2.0), &down, 0.0, 10.0), None);
    assert_eq!(s.intersect(&Point3::new(1.5, 0.5, 2.0), &down, 0.0, 1.5), None);
    assert_eq!(s.intersect(&Point3::new(1.5, 0.5, 2.0), &Vec3::x(), 0.0, 10.0), None);
}

#[test]
fn the_bvh_finds_the_same_nearest_surface_as_brute_force() {
    let world = World::new(&WorldConfig::default(), 3);
    let surfaces = &world.layout.surfaces;
    for k in 0..3000u64 {
        let u = |i: u64| unit(k * 16 + i);
        let origin = Point3::new(-1.0 + 20.0 * u(0), -2.0 + 14.0 * u(1), 0.1 + 3.0 * u(2));
        let dir = Vec3::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5).normalize();
        let fast = world.cast(&origin, &dir, 1e-6, 100.0).map(|h| h.t);
        let slow = surfaces.iter().filter_map(|s| s.intersect(&origin, &dir, 1e-6, 100.0)).min_by(f64::total_cmp);
        assert_eq!(fast, slow, "ray {k} from {origin} along {dir}");
    }
}

#[test]
fn the_robot_on_a_ramp_is_pitched_by_the_slope_and_level_across_it() {
    let config = WorldConfig::default();
    let world = World::new(&config, 0);
    let mid_ramp = 7.5 + config.ramp_run(0.5) / 2.0;
    let pose = pose_on_floor(&world.layout, [mid_ramp, 0.0], 0.0).unwrap();
    let forward = pose.rotation * Vec3::x();
    let left = pose.rotation * Vec3::y();
    assert!((forward.z.asin().to_degrees() - 10.0).abs() < 1e-9);
    assert!(left.z.abs() < 1e-12);
    assert!((pose.translation.vector.z - 0.25).abs() < 1e-9);
    // Facing down the ramp: pitched down by the same angle.
    let down = pose_on_floor(&world.layout, [mid_ramp, 0.0], std::f64::consts::PI).unwrap();
    assert!(((down.rotation * Vec3::x()).z.asin().to_degrees() + 10.0).abs() < 1e-9);
    // Outside the building there is no pose.
    assert!(pose_on_floor(&world.layout, [-5.0, 0.0], 0.0).is_none());
}
