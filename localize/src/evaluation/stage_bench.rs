//! `localize bench`: milliseconds per frame of each geometry stage and of
//! the detector beside it, on M8-like scans, dense 64-beam ones and 640 x 480
//! depth images of the built-in world, with the organised normals and with
//! the exact ones, what each path finds on them (and on clouds a user
//! passes), and the decoding of a recording's messages. Speed is measured
//! here, never in tests.

use serde::Serialize;

use crate::config::LocalizeConfig;
use crate::evaluation::normal_paths::{PathComparison, compare_paths};

use crate::error::{LocalizeError, Result};

/// One scan kind's mean milliseconds per frame.
#[derive(Debug, Clone, Serialize)]
pub struct StageRow {
    pub scan: &'static str,
    pub points: f64,
    pub normals_ms: f64,
    pub planes_ms: f64,
    pub corners_ms: f64,
    pub geometry_ms: f64,
    /// Without a checkpoint, no detector time.
    pub detector_ms: Option<f64>,
    /// Geometry and detector one after the other.
    pub sequential_ms: f64,
    /// Side by side, as `localize run` does.
    pub total_ms: f64,
}

/// Decoding a recording's messages, milliseconds each.
#[derive(Debug, Clone, Serialize)]
pub struct DecodeTimes {
    pub cloud_10k_ms: f64,
    pub image_bgr8_ms: f64,
    pub image_png_ms: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct StageBench {
    pub frames: Vec<StageRow>,
    /// The organised normals against the exact ones: per scan kind, its
    /// first scan; then each cloud passed in.
    pub paths: Vec<(String, PathComparison)>,
    pub decode: DecodeTimes,
}

/// Times `frames` scans of each kind (and the detector, when given), and
/// compares the two normal paths on them and on `clouds` (name, points,
/// sensor position).
pub fn stage_bench(
    detector: Option<&infer::detector::Detector>,
    frames: usize,
    clouds: &[(String, Vec<nalgebra::Point3<f32>>, datasets::math::Vec3)],
) -> Result<StageBench> {
    let world = datasets::simulator::world::World::new(&Default::default(), 7);
    let m8 = datasets::simulator::world::lidar::LidarConfig::default();
    // A 64-beam scanner at 0.2 degrees: about 100k points a turn.
    let dense = datasets::simulator::world::lidar::LidarConfig {
        beams: 64,
        min_elevation_deg: -25.0,
        max_elevation_deg: 15.0,
        azimuth_step_deg: 0.2,
        ..m8.clone()
    };
    let image = image::DynamicImage::ImageRgb8(image::RgbImage::from_fn(640, 480, |x, y| {
        let v = if (x / 80 + y / 60) % 2 == 0 { 200 } else { 40 };
        image::Rgb([v, v, v])
    }));
    let detector_ms = detector.map(|detector| {
        detector.detect(&image);
        let start = std::time::Instant::now();
        for _ in 0..frames {
            detector.detect(&image);
        }
        start.elapsed().as_secs_f64() * 1e3 / frames.max(1) as f64
    });
    let configs = BenchConfigs::new();
    let m8_scans = bench_scans(&world, &m8, frames)?;
    let dense_scans = bench_scans(&world, &dense, frames)?;
    let depth_full = bench_depth_images(&world, frames, 1)?;
    let depth_default = bench_depth_images(&world, frames, DEPTH_STRIDE)?;
    let c = &configs;
    let kinds = [
        ("m8", &m8_scans, &c.plain),
        ("m8-organised", &m8_scans, &c.organised),
        ("dense", &dense_scans, &c.plain),
        ("dense-organised", &dense_scans, &c.organised),
        ("dense-organised-25", &dense_scans, &c.organised_fast),
        ("dense-5cm", &dense_scans, &c.thin5),
        ("dense-10cm", &dense_scans, &c.thin10),
        ("dense-10cm-k20", &dense_scans, &c.thin10_k20),
        ("depth", &depth_full, &c.plain),
        ("depth-organised", &depth_full, &c.organised),
        ("depth-stride4", &depth_default, &c.plain),
        ("depth-stride4-organised", &depth_default, &c.organised),
    ];
    let mut rows = Vec::new();
    for (scan, clouds, config) in kinds {
        rows.push(stage_row(scan, clouds, config, detector, detector_ms, &image)?);
    }
    let origin = datasets::math::Vec3::zeros();
    let mut paths = Vec::new();
    for (name, scans) in
        [("m8", &m8_scans), ("dense", &dense_scans), ("depth", &depth_full), ("depth-stride4", &depth_default)]
    {
        paths.push((name.to_string(), compare_paths(&scans[0].points, &origin, &c.organised, 3)?));
    }
    for (name, points, sensor) in clouds {
        paths.push((name.clone(), compare_paths(points, sensor, &c.organised, 3)?));
    }
    Ok(StageBench { frames: rows, paths, decode: bench_decoding(frames.max(10)) })
}

/// The settings the stage rows compare.
struct BenchConfigs {
    plain: LocalizeConfig,
    /// The organised normals, wherever a scan has rows and columns.
    organised: LocalizeConfig,
    /// ...reading 25 cells a point over 2 degrees, all that pass the gate.
    organised_fast: LocalizeConfig,
    thin5: LocalizeConfig,
    thin10: LocalizeConfig,
    thin10_k20: LocalizeConfig,
}

impl BenchConfigs {
    fn new() -> Self {
        let plain = LocalizeConfig::default();
        let mut organised = plain.clone();
        organised.normals.organised.enabled = true;
        organised.normals.organised.max_row_pitch_deg = 90.0;
        let mut organised_fast = organised.clone();
        organised_fast.normals.organised.samples = 25;
        organised_fast.normals.organised.window_deg = 2.0;
        let thinned = |size_m: f64| {
            let mut c = LocalizeConfig::default();
            c.voxel.size_m = size_m;
            c
        };
        // A thinned dense cloud is near-isotropic: k need not reach across
        // sparse rings as on an 8-beam scan.
        let mut thin10_k20 = thinned(0.10);
        thin10_k20.normals.neighbours = 20;
        Self { plain, organised, organised_fast, thin5: thinned(0.05), thin10: thinned(0.10), thin10_k20 }
    }
}

/// One scan kind's row: each stage alone, then the frame with the detector.
fn stage_row(
    scan: &'static str,
    clouds: &[datasets::io::formats::PointCloud],
    config: &LocalizeConfig,
    detector: Option<&infer::detector::Detector>,
    detector_ms: Option<f64>,
    image: &image::DynamicImage,
) -> Result<StageRow> {
    let stages = config.geometry_stages()?;
    let [normals_ms, planes_ms, corners_ms] = bench_geometry(&stages, clouds)?;
    let geometry_ms = normals_ms + planes_ms + corners_ms;
    let total_ms = match detector {
        Some(detector) => bench_frame(&stages, clouds, detector, image)?,
        None => geometry_ms,
    };
    let points = clouds.iter().map(|c| c.len() as f64).sum::<f64>() / clouds.len().max(1) as f64;
    Ok(StageRow {
        scan,
        points: points.round(),
        normals_ms,
        planes_ms,
        corners_ms,
        geometry_ms,
        detector_ms,
        sequential_ms: geometry_ms + detector_ms.unwrap_or(0.0),
        total_ms,
    })
}

/// The depth images' pixel stride that `localize run` lifts by default.
const DEPTH_STRIDE: usize = 4;

impl StageBench {
    /// The table `localize bench` prints.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut out = format!(
            "{:<15} {:>8} {:>10} {:>10} {:>10} {:>11} {:>12} {:>10}\n",
            "scan", "points", "normals", "planes", "corners", "detector", "one by one", "total"
        );
        for r in &self.frames {
            // Without a checkpoint there is no detector time to show.
            let detector = r.detector_ms.map_or("-".to_string(), |ms| format!("{ms:.1}ms"));
            let _ = writeln!(
                out,
                "{:<15} {:>8.0} {:>8.1}ms {:>8.1}ms {:>8.1}ms {:>11} {:>10.1}ms {:>8.1}ms",
                r.scan, r.points, r.normals_ms, r.planes_ms, r.corners_ms, detector, r.sequential_ms, r.total_ms
            );
        }
        out.push_str(
            "(total: the geometry and the detector side by side, as `localize run` does; one by one: their sum)\n",
        );
        out.push_str(
            "(points: as scanned; dense-5cm and dense-10cm thin them to 5 and 10 cm voxels before the normals, inside the normals time; k20: 20 neighbours per normal instead of 40)\n",
        );
        out.push_str("(fusion and pose take well under 1 ms a frame; see frames.csv of a run)\n");
        out.push_str(
            "(-organised: normals on the range image (normals.organised), -25: reading 25 cells a point over 2 degrees; depth: 640 x 480 depth images, every pixel; stride4: every 4th, as `localize run` lifts them)\n",
        );
        out.push_str(&paths_table(&self.paths));
        let d = &self.decode;
        let _ = writeln!(
            out,
            "decoding a recording's messages: PointCloud2 of 10k points {:.2} ms, 640x480 bgr8 Image {:.2} ms, the same as PNG CompressedImage {:.2} ms",
            d.cloud_10k_ms, d.image_bgr8_ms, d.image_png_ms
        );
        out
    }
}

/// The organised normals against the exact ones, one line per cloud.
pub fn paths_table(paths: &[(String, PathComparison)]) -> String {
    use std::fmt::Write as _;
    let mut out =
        String::from("\norganised normals against the exact ones (planes and 3D corners matched one to one):\n");
    let _ = writeln!(
        out,
        "{:<18} {:>8} {:>10} {:>11} {:>10} {:>14} {:>16} {:>12} {:>16}",
        "cloud",
        "points",
        "image",
        "exact ms",
        "range ms",
        "planes e/o/=",
        "plane deg max/med",
        "offset mm",
        "corners e/o/= mm max/med"
    );
    for (name, p) in paths {
        let _ = writeln!(
            out,
            "{:<18} {:>8} {:>10} {:>11.1} {:>10.1} {:>14} {:>8.2} / {:<6.2} {:>12.1} {:>8} {:>6.1} / {:.1}",
            name,
            p.points,
            p.organised.as_deref().unwrap_or("none"),
            p.exact_normals_ms,
            p.organised_normals_ms,
            format!("{}/{}/{}", p.exact_planes, p.organised_planes, p.matched_planes),
            p.plane_max_deg,
            p.plane_median_deg,
            p.plane_max_offset_mm,
            format!("{}/{}/{}", p.exact_corners, p.organised_corners, p.matched_corners),
            p.corner_max_mm,
            p.corner_median_mm,
        );
    }
    out
}

/// 640 x 480 depth images (Kinect intrinsics, depth noise growing with the
/// square of the depth) from the RGB-D camera's mount along the built-in
/// route, lifted as `localize run` lifts them: every `stride`-th pixel,
/// 0.2 to 4 m, in the camera's body frame (x forward, y left, z up).
fn bench_depth_images(
    world: &datasets::simulator::world::World,
    frames: usize,
    stride: usize,
) -> Result<Vec<datasets::io::formats::PointCloud>> {
    use datasets::math::Vec3;
    use datasets::seed::{mix, unit};
    let camera = datasets::camera::PinholeCamera::kinect();
    let mount = nalgebra::Isometry3::translation(0.12, 0.0, 0.45);
    let poses = bench_poses(world, frames)?;
    Ok(poses
        .iter()
        .enumerate()
        .map(|(k, robot)| {
            let world_from_body = robot * mount;
            let origin = nalgebra::Point3::from(world_from_body.translation.vector);
            let mut points = Vec::new();
            for v in (0..480).step_by(stride) {
                for u in (0..640).step_by(stride) {
                    // The ray of pixel (u, v) with depth 1 along x.
                    let ray = Vec3::new(1.0, -(u as f64 - camera.cx) / camera.fx, -(v as f64 - camera.cy) / camera.fy);
                    let dir = world_from_body.rotation * ray.normalize();
                    let Some(hit) = world.cast(&origin, &dir, 0.05, 10.0) else { continue };
                    let depth = hit.t / ray.norm();
                    // Uniform noise of unit variance.
                    let gaussian = (unit(mix(k as u64 ^ mix((v * 640 + u) as u64))) - 0.5) * 3.46;
                    let depth = depth + (0.0012 + 0.0019 * (depth - 0.4).powi(2)) * gaussian;
                    if (0.2..=4.0).contains(&depth) {
                        points.push((ray * depth).cast::<f32>().into());
                    }
                }
            }
            datasets::io::formats::PointCloud::new(points, None)
        })
        .collect())
}

fn bench_scans(
    world: &datasets::simulator::world::World,
    lidar: &datasets::simulator::world::lidar::LidarConfig,
    frames: usize,
) -> Result<Vec<datasets::io::formats::PointCloud>> {
    let rig = datasets::simulator::world::rig::Rig::default();
    let poses = bench_poses(world, frames)?;
    Ok(poses
        .iter()
        .enumerate()
        .map(|(k, robot)| {
            datasets::simulator::world::lidar::scan(world, lidar, &(robot * rig.robot_from_lidar), 0.0, k as u64)
        })
        .collect())
}

/// The robot's poses at `frames` evenly spaced places along the built-in route.
fn bench_poses(world: &datasets::simulator::world::World, frames: usize) -> Result<Vec<datasets::math::Pose3>> {
    let route = datasets::simulator::world::route::Route::new(&world.layout.route, 1.2);
    (0..frames)
        .map(|k| {
            let s = route.length() * (k as f64 + 0.5) / frames as f64;
            let (xy, heading) = route.at(s);
            datasets::simulator::world::route::pose_on_floor(&world.layout, xy, heading)
                .ok_or_else(|| LocalizeError::Recording("the benchmark route left the free space".into()))
        })
        .collect()
}

/// Mean milliseconds of each geometry stage over `scans`, run alone.
fn bench_geometry(
    stages: &crate::scan::geometry::GeometryStages,
    scans: &[datasets::io::formats::PointCloud],
) -> Result<[f64; 3]> {
    let mut ms = [0.0; 3];
    for cloud in scans {
        let g = stages.run(&cloud.points, &datasets::math::Vec3::zeros())?;
        ms[0] += g.normals_ms;
        ms[1] += g.planes_ms;
        ms[2] += g.corners_ms;
    }
    Ok(ms.map(|v| v / scans.len().max(1) as f64))
}

/// Mean wall milliseconds of a frame as `localize run` does it: the
/// geometry and the detector side by side.
fn bench_frame(
    stages: &crate::scan::geometry::GeometryStages,
    scans: &[datasets::io::formats::PointCloud],
    detector: &infer::detector::Detector,
    image: &image::DynamicImage,
) -> Result<f64> {
    let start = std::time::Instant::now();
    for cloud in scans {
        let (geometry, _) =
            rayon::join(|| stages.run(&cloud.points, &datasets::math::Vec3::zeros()), || detector.detect(image));
        geometry?;
    }
    Ok(start.elapsed().as_secs_f64() * 1e3 / scans.len().max(1) as f64)
}

/// Mean milliseconds to decode a 10k-point PointCloud2 (x, y, z, intensity,
/// per-point time) and a 640x480 camera image, raw and PNG, from CDR.
fn bench_decoding(repeats: usize) -> DecodeTimes {
    use datasets::io::recording::messages::{Encoding, decode, image, point_cloud};
    use datasets::io::recording::wire::{CdrWriter, Header};
    let header = Header { stamp_ns: 1_700_000_000_000_000_000, frame_id: "lidar".into() };
    let n = 10_000u32;
    let mut w = CdrWriter::new();
    w.header(&header);
    w.u32(1);
    w.u32(n);
    w.u32(5);
    for (k, (name, kind)) in [("x", 7u8), ("y", 7), ("z", 7), ("intensity", 7), ("t", 6)].iter().enumerate() {
        w.string(name);
        w.u32(4 * k as u32);
        w.u8(*kind);
        w.u32(1);
    }
    w.u8(0);
    w.u32(20);
    w.u32(20 * n);
    let data: Vec<u8> = (0..n)
        .flat_map(|i| {
            let a = i as f32 * 0.01;
            [5.0 * a.cos(), 5.0 * a.sin(), 0.3, 1.0]
                .into_iter()
                .flat_map(f32::to_le_bytes)
                .chain((i * 10_000).to_le_bytes())
        })
        .collect();
    w.bytes(&data);
    w.u8(1);
    let cloud = w.finish();
    let pixels: Vec<u8> = (0..640 * 480 * 3).map(|i| (i % 251) as u8).collect();
    let mut w = CdrWriter::new();
    w.header(&header);
    w.u32(480);
    w.u32(640);
    w.string("bgr8");
    w.u8(0);
    w.u32(640 * 3);
    w.bytes(&pixels);
    let raw_image = w.finish();
    let mut png = Vec::new();
    ::image::RgbImage::from_raw(640, 480, pixels)
        .expect("sized")
        .write_to(&mut std::io::Cursor::new(&mut png), ::image::ImageFormat::Png)
        .expect("in memory");
    let mut w = CdrWriter::new();
    w.header(&header);
    w.string("png");
    w.bytes(&png);
    let png_image = w.finish();
    let time = |f: &dyn Fn()| {
        f();
        let start = std::time::Instant::now();
        for _ in 0..repeats {
            f();
        }
        start.elapsed().as_secs_f64() * 1e3 / repeats as f64
    };
    let cloud_ms = time(&|| {
        assert_eq!(decode(Encoding::Cdr, &cloud, point_cloud::point_cloud2).expect("valid").cloud.len(), n as usize)
    });
    let raw_ms =
        time(&|| assert_eq!(decode(Encoding::Cdr, &raw_image, image::image).expect("valid").image.width(), 640));
    let png_ms = time(&|| {
        assert_eq!(decode(Encoding::Cdr, &png_image, image::compressed_image).expect("valid").image.width(), 640)
    });
    DecodeTimes { cloud_10k_ms: cloud_ms, image_bgr8_ms: raw_ms, image_png_ms: png_ms }
}
