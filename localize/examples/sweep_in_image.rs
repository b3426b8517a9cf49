//! A real LIDAR sweep's planes and 3D corners drawn into its camera image
//! through the given calibration and lens distortion, with the time each
//! geometry stage takes on the sweep. Written for the 64-beam sweep of
//! PJLab's SensorsCalibration data (its intrinsics and extrinsic JSON):
//!
//! ```bash
//! D=../shared/data/pjlab_lidar_camera/lidar2camera
//! cargo run --release -p localize --example sweep_in_image -- $D/calib.pcd $D/calib.png \
//!     $D/center_camera-intrinsic.json $D/top_center_lidar-to-center_camera-extrinsic.json docs/images/real-sweep.png
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use datasets::io::formats::{NonFinite, read_cloud};
use datasets::math::{Pose3, Vec3};
use datasets::undistort::distort;
use image::{Rgb, RgbImage};
use localize::config::LocalizeConfig;

/// A matrix of PJLab's calibration JSON: `{"rows", "cols", "data": [[...]]}`
/// under `<name>.param.<key>`, row by row.
fn matrix(path: &Path, key: &str) -> Result<Vec<f64>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let json: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}", path.display()))?;
    let (_, sensor) = json.as_object().and_then(|o| o.iter().next()).context("an empty calibration")?;
    let rows = sensor["param"][key]["data"].as_array().with_context(|| format!("{}: no {key}", path.display()))?;
    let values: Option<Vec<f64>> =
        rows.iter().flat_map(|r| r.as_array().into_iter().flatten()).map(|v| v.as_f64()).collect();
    values.with_context(|| format!("{}: {key} holds something other than numbers", path.display()))
}

/// A colour per plane, distinct for the first dozen.
fn colour(k: usize) -> Rgb<u8> {
    const PALETTE: [[u8; 3]; 8] = [
        [230, 25, 75],
        [60, 180, 75],
        [255, 225, 25],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
    ];
    Rgb(PALETTE[k % PALETTE.len()])
}

/// The geometry stages on `points`, seven times; prints each stage's median
/// milliseconds and what they found, returns the last run's result.
fn timed_geometry(points: &[nalgebra::Point3<f32>]) -> Result<localize::scan::geometry::Geometry> {
    let stages = LocalizeConfig::default().geometry_stages()?;
    // The stages' own clocks, over a few repeats: the median.
    let mut timings = Vec::new();
    let mut geometry = None;
    for _ in 0..7 {
        let g = stages.run(points, &Vec3::zeros())?;
        timings.push([g.normals_ms, g.planes_ms, g.corners_ms]);
        geometry = Some(g);
    }
    let geometry = geometry.expect("seven runs");
    let median = |i: usize| {
        let mut v: Vec<f64> = timings.iter().map(|t| t[i]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "{} points: normals {:.1} ms, planes {:.1} ms, corners {:.1} ms (median of 7); {} planes, {} corners",
        points.len(),
        median(0),
        median(1),
        median(2),
        geometry.planes.planes.len(),
        geometry.corners.corners.len()
    );
    Ok(geometry)
}

/// A filled disc of `colour` at pixel (u, v), clipped to the canvas.
fn dot(canvas: &mut RgbImage, (u, v): (i64, i64), radius: i64, colour: Rgb<u8>) {
    for dv in -radius..=radius {
        for du in -radius..=radius {
            let (x, y) = (u + du, v + dv);
            if du * du + dv * dv <= radius * radius
                && x >= 0
                && y >= 0
                && x < i64::from(canvas.width())
                && y < i64::from(canvas.height())
            {
                canvas.put_pixel(x as u32, y as u32, colour);
            }
        }
    }
}

fn main() -> Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [cloud, image, intrinsics, extrinsic, out] = args.as_slice() else {
        bail!("usage: sweep_in_image CLOUD IMAGE INTRINSICS.json EXTRINSIC.json OUT.png");
    };
    let k = matrix(intrinsics, "cam_K")?;
    let d = matrix(intrinsics, "cam_dist")?;
    let e = matrix(extrinsic, "sensor_calib")?;
    if k.len() != 9 || e.len() != 16 {
        bail!("K must be 3 x 3 and the extrinsic 4 x 4");
    }
    let rows =
        [[e[0], e[1], e[2], e[3]], [e[4], e[5], e[6], e[7]], [e[8], e[9], e[10], e[11]], [e[12], e[13], e[14], e[15]]];
    let camera_from_lidar: Pose3 =
        datasets::math::pose_from_rows(&rows).context("the extrinsic is not a rigid transform")?;
    let cloud = read_cloud(cloud, NonFinite::Drop)?;
    let geometry = timed_geometry(&cloud.points)?;
    let photo = datasets::atomic::read_image(image)?.to_rgb8();
    // The photo dimmed, so that the points stand out.
    let mut canvas = RgbImage::from_fn(photo.width(), photo.height(), |x, y| {
        let p = photo.get_pixel(x, y);
        Rgb([p[0] / 2, p[1] / 2, p[2] / 2])
    });
    let (width, height) = (f64::from(photo.width()), f64::from(photo.height()));
    let project = |p: &Vec3| -> Option<(i64, i64)> {
        let c = camera_from_lidar * nalgebra::Point3::from(*p);
        if c.z <= 0.5 {
            return None;
        }
        let (x, y) = distort(&d, c.x / c.z, c.y / c.z);
        let (u, v) = (k[0] * x + k[2], k[4] * y + k[5]);
        let inside = u >= 0.0 && v >= 0.0 && u < width && v < height;
        inside.then_some((u as i64, v as i64))
    };
    for (k, plane) in geometry.planes.planes.iter().enumerate() {
        for &i in &plane.inliers {
            if let Some(px) = project(&geometry.points[i as usize].cast::<f64>().coords) {
                dot(&mut canvas, px, 2, colour(k));
            }
        }
    }
    let mut shown = 0;
    for corner in &geometry.corners.corners {
        if let Some(px) = project(&corner.position) {
            dot(&mut canvas, px, 16, Rgb([255, 255, 255]));
            dot(&mut canvas, px, 10, Rgb([255, 0, 0]));
            shown += 1;
        }
    }
    println!("{shown} of the corners lie in the image");
    let small = image::imageops::resize(
        &canvas,
        canvas.width() / 2,
        canvas.height() / 2,
        image::imageops::FilterType::Triangle,
    );
    datasets::atomic::write_image(out, &image::DynamicImage::ImageRgb8(small))?;
    println!("wrote {}", out.display());
    Ok(())
}
