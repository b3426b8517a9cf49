//! Level floors as an attitude reading. On level ground the IMU alone holds
//! pitch and roll, and an accelerometer bias tilts them unseen: the wheels
//! then drive the height off at speed x tilt. The floor the LIDAR sees is a
//! second, independent level: its normal in the robot frame says roll and
//! pitch, and with gravity makes the accelerometer's biases observable.
//!
//! Only a floor that is level at the predicted attitude counts, only while
//! the robot stands level and no ramp is in sight, and only when the
//! floor's two halves agree: a plane fitted across a ramp's foot is tilted
//! by milliradians, as much as the error it would mend.

use datasets::InvalidSetting;
use datasets::math::{Mat3, Pose3, Vec3};
use serde::{Deserialize, Serialize};

use crate::scan::geometry::Geometry;
use crate::scan::normals::smallest_eigenvector;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LevelFloorConfig {
    pub enabled: bool,
    /// How far from level a floor may truly be (rad): added to the fit's own
    /// uncertainty, so a building's sagging floors do not overrule the IMU.
    pub unevenness_rad: f64,
    /// A floor within this angle of level at the predicted attitude is read.
    pub max_tilt_deg: f64,
    /// Planes tilted between `max_tilt_deg` and this are ramps; with one in
    /// the frame, no floor is read.
    pub ramp_max_tilt_deg: f64,
    /// A floor must have this many inliers.
    pub min_inliers: usize,
    /// The tilts of the floor's two halves along its longer extent may
    /// differ by this many standard deviations (more: a floor and a ramp's
    /// foot, or a step).
    pub max_split_sigmas: f64,
    /// Readings farther than this squared Mahalanobis distance from the
    /// state are skipped (chi-square, 2 degrees of freedom).
    pub gate_chi2: f64,
}

impl Default for LevelFloorConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            unevenness_rad: 0.0003,
            max_tilt_deg: 1.5,
            ramp_max_tilt_deg: 30.0,
            min_inliers: 200,
            max_split_sigmas: 3.0,
            gate_chi2: 13.8,
        }
    }
}

impl LevelFloorConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        InvalidSetting::non_negative("unevenness_rad", self.unevenness_rad, 0.1)?;
        InvalidSetting::positive("max_tilt_deg", self.max_tilt_deg, 10.0)?;
        InvalidSetting::range("ramp_max_tilt_deg", self.ramp_max_tilt_deg, self.max_tilt_deg, 89.0, false)?;
        InvalidSetting::count("min_inliers", self.min_inliers, 3, 10_000_000)?;
        InvalidSetting::positive("max_split_sigmas", self.max_split_sigmas, 1e6)?;
        InvalidSetting::positive("gate_chi2", self.gate_chi2, 1e6)
    }
}

/// A floor's normal in the robot frame (pointing up) and the standard
/// deviation of its tilt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FloorReading {
    pub normal_in_robot: Vec3,
    pub sigma_rad: f64,
}

/// The frame's largest level floor below the LIDAR, when the robot stands
/// level and no ramp is in the frame; `predicted` is the filter's pose (its
/// attitude decides what is level).
pub fn read_floor(
    config: &LevelFloorConfig,
    geometry: &Geometry,
    robot_from_lidar: &Pose3,
    predicted: &Pose3,
) -> Option<FloorReading> {
    if !config.enabled {
        return None;
    }
    // On a ramp the floors in sight are other levels', seen across a crease.
    if (predicted.rotation * Vec3::z()).z.min(1.0).acos() > config.max_tilt_deg.to_radians() {
        return None;
    }
    let world_from_lidar = predicted * robot_from_lidar;
    let mut best: Option<(usize, &crate::scan::planes::Plane)> = None;
    for plane in &geometry.planes.planes {
        let up = world_from_lidar.rotation * plane.normal;
        let tilt_deg = up.z.abs().min(1.0).acos().to_degrees();
        if tilt_deg > config.max_tilt_deg && tilt_deg <= config.ramp_max_tilt_deg {
            return None;
        }
        // Normals point from the LIDAR to their plane: a floor's points down.
        let below = up.z < 0.0;
        let n = plane.inliers.len();
        if tilt_deg <= config.max_tilt_deg && below && n >= config.min_inliers && best.is_none_or(|(m, _)| n > m) {
            best = Some((n, plane));
        }
    }
    let (_, plane) = best?;
    let points: Vec<Vec3> = plane.inliers.iter().map(|&i| geometry.points[i as usize].coords.cast::<f64>()).collect();
    let fit = robust_fit(&points, plane.normal, config.min_inliers, config.max_split_sigmas)?;
    let up = if (world_from_lidar.rotation * fit.normal).z >= 0.0 { fit.normal } else { -fit.normal };
    Some(FloorReading {
        normal_in_robot: robot_from_lidar.rotation * up,
        sigma_rad: (fit.tilt_variance + config.unevenness_rad.powi(2)).sqrt(),
    })
}

/// A plane fitted by least squares and its normal's tilt variance.
struct Fit {
    normal: Vec3,
    tilt_variance: f64,
}

impl Fit {
    /// `plane`, the least-squares plane of `points`, with its normal's tilt
    /// variance: the points' mean squared distance over their spread along
    /// the plane's narrower in-plane direction.
    fn of(points: &[Vec3], plane: &LeastSquares) -> Self {
        let mut spread: Vec<f64> = plane.scatter.symmetric_eigen().eigenvalues.iter().copied().collect();
        spread.sort_by(f64::total_cmp);
        let ms = points.iter().map(|p| plane.distance(p).powi(2)).sum::<f64>() / points.len() as f64;
        // spread[0] is across the plane.
        Self { normal: plane.normal, tilt_variance: ms / spread[1].max(1e-12) }
    }
}

/// Refits `points` keeping those within three robust standard deviations
/// of the plane: the extractor's inlier band is wide enough to take in the
/// first half metre of a ramp too few beams hit to make a plane of its own.
/// None when fewer than `min_points` remain or the fit fails the split test.
fn robust_fit(points: &[Vec3], normal: Vec3, min_points: usize, max_split_sigmas: f64) -> Option<Fit> {
    let mut kept: Vec<Vec3> = points.to_vec();
    let mut fit = LeastSquares::of(&kept, normal);
    for _ in 0..3 {
        let mut residuals: Vec<f64> = kept.iter().map(|p| fit.distance(p).abs()).collect();
        residuals.sort_by(f64::total_cmp);
        let sigma = 1.4826 * residuals[residuals.len() / 2];
        let band = (3.0 * sigma).max(1e-4);
        kept = points.iter().copied().filter(|p| fit.distance(p).abs() <= band).collect();
        if kept.len() < min_points {
            return None;
        }
        fit = LeastSquares::of(&kept, fit.normal);
    }
    let whole = Fit::of(&kept, &fit);
    // One plane, or a floor and the foot of a ramp (a step, a threshold)
    // at one end of it: the two halves along the floor's longer extent must
    // agree on the tilt.
    let eigen = fit.scatter.symmetric_eigen();
    let axis = eigen.eigenvectors.column(eigen.eigenvalues.imax()).into_owned();
    let along = |p: &Vec3| (p - fit.centroid).dot(&axis);
    let mut positions: Vec<f64> = kept.iter().map(along).collect();
    positions.sort_by(f64::total_cmp);
    let median = positions[positions.len() / 2];
    let (first, second): (Vec<Vec3>, Vec<Vec3>) = kept.iter().partition(|p| along(p) < median);
    if first.len() < 3 || second.len() < 3 {
        return None;
    }
    let a = Fit::of(&first, &LeastSquares::of(&first, whole.normal));
    let b = Fit::of(&second, &LeastSquares::of(&second, whole.normal));
    // A noise-free floor (simulated) fits exactly: a microradian of doubt
    // keeps the ratio finite.
    let sigma = (a.tilt_variance + b.tilt_variance).sqrt().max(1e-6);
    let disagreement = (a.normal - b.normal).norm() / sigma;
    (disagreement <= max_split_sigmas).then_some(whole)
}

/// The least-squares plane of some points: their centroid, the unit normal
/// and the scatter matrix about the centroid.
struct LeastSquares {
    centroid: Vec3,
    normal: Vec3,
    scatter: Mat3,
}

impl LeastSquares {
    /// The plane of `points`, its normal on the side of `hint`.
    fn of(points: &[Vec3], hint: Vec3) -> Self {
        let centroid = points.iter().sum::<Vec3>() / points.len().max(1) as f64;
        let scatter = points.iter().map(|p| (p - centroid) * (p - centroid).transpose()).sum::<Mat3>();
        let (normal, _) = smallest_eigenvector(&scatter);
        Self { centroid, normal: if normal.dot(&hint) >= 0.0 { normal } else { -normal }, scatter }
    }

    fn distance(&self, p: &Vec3) -> f64 {
        (p - self.centroid).dot(&self.normal)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::planes::{Plane, PlaneSet};
    use datasets::math::Rot3;
    use nalgebra::Point3;

    /// A plane through `points[range]` with `normal` pointing from the LIDAR to it.
    fn plane(points: &[Point3<f32>], range: std::ops::Range<usize>, normal: Vec3, rms_m: f64) -> Plane {
        let n = range.len() as f64;
        let centroid = range.clone().map(|i| points[i].coords.cast::<f64>()).sum::<Vec3>() / n;
        Plane { normal, distance: normal.dot(&centroid), centroid, inliers: range.map(|i| i as u32).collect(), rms_m }
    }

    /// Checkerboard noise of +-`amplitude`: symmetric about the grid's
    /// centre, so the least-squares plane stays level.
    fn noise(i: usize, j: usize, amplitude: f32) -> f32 {
        if (i + j).is_multiple_of(2) { amplitude } else { -amplitude }
    }

    /// A 4 x 2 m floor 0.5 m below the LIDAR (21 x 11 points, +-`noise_m`)
    /// whose last metre is `step_m` higher (a threshold, or the foot of a
    /// ramp that the extractor's inlier band took into the floor), a 2 m high
    /// wall 4 m ahead, and, when `ramp_deg` is some, a ramp beyond the wall.
    fn scene(ramp_deg: Option<f64>, noise_m: f32, step_m: f32) -> Geometry {
        let mut points = Vec::new();
        for i in 0..21 {
            for j in 0..11 {
                let step = if i > 15 { step_m } else { 0.0 };
                points.push(Point3::new(
                    -2.0 + 0.2 * i as f32,
                    -1.0 + 0.2 * j as f32,
                    -0.5 + step + noise(i, j, noise_m),
                ));
            }
        }
        let floor = plane(&points, 0..points.len(), -Vec3::z(), 0.01);
        let start = points.len();
        for j in 0..11 {
            for k in 0..11 {
                points.push(Point3::new(4.0, -1.0 + 0.2 * j as f32, -0.5 + 0.2 * k as f32 + noise(j, k, 0.01)));
            }
        }
        let mut planes = vec![floor, plane(&points, start..points.len(), Vec3::x(), 0.01)];
        if let Some(deg) = ramp_deg {
            let a = f64::to_radians(deg);
            let start = points.len();
            for i in 0..11 {
                let u = 0.2 * i as f32;
                for j in 0..11 {
                    points.push(Point3::new(5.0 + u, -1.0 + 0.2 * j as f32, -0.5 + u * a.tan() as f32));
                }
            }
            planes.push(plane(&points, start..points.len(), Vec3::new(a.sin(), 0.0, -a.cos()), 0.01));
        }
        let labels = vec![None; points.len()];
        Geometry {
            normals: Vec::new(),
            points,
            planes: PlaneSet { planes, labels },
            corners: Default::default(),
            organised: None,
            normals_ms: 0.0,
            planes_ms: 0.0,
            corners_ms: 0.0,
        }
    }

    fn config() -> LevelFloorConfig {
        LevelFloorConfig { min_inliers: 100, ..LevelFloorConfig::default() }
    }

    #[test]
    fn the_floor_below_reads_its_upward_normal_with_the_fits_uncertainty() {
        let geometry = scene(None, 0.01, 0.0);
        let reading = read_floor(&config(), &geometry, &Pose3::identity(), &Pose3::identity()).unwrap();
        assert!((reading.normal_in_robot - Vec3::z()).norm() < 1e-6, "{:?}", reading.normal_in_robot);
        // 116 points 1 cm up and 115 down: the plane sits c = 1 cm / 231 up and the mean
        // squared residual is 1 cm^2 - c^2; the narrower spread is across y: 21 x 4.4 m^2.
        let c = 0.01 / 231.0;
        let expected = ((1e-4 - c * c) / (21.0 * 4.4) + 0.0003f64.powi(2)).sqrt();
        assert!((reading.sigma_rad - expected).abs() < 1e-4 * expected, "{} vs {expected}", reading.sigma_rad);
        // With the LIDAR mounted upside down the same plane is above it: a ceiling, not read.
        let flipped = Pose3::from_parts(Default::default(), Rot3::from_euler_angles(std::f64::consts::PI, 0.0, 0.0));
        assert!(read_floor(&config(), &geometry, &flipped, &Pose3::identity()).is_none());
    }

    #[test]
    fn a_floor_with_a_step_at_one_end_is_not_read() {
        // A 6 mm step over the last metre tilts the whole fit by about 1.6 mrad, five times its sigma...
        let geometry = scene(None, 0.002, 0.006);
        let floor = &geometry.planes.planes[0];
        let points: Vec<Vec3> = floor.inliers.iter().map(|&i| geometry.points[i as usize].coords.cast()).collect();
        let normal = LeastSquares::of(&points, -Vec3::z()).normal;
        assert!(normal.x.abs() > 0.0012, "{normal:?}");
        // ...and its two halves disagree: no reading rather than a wrong one.
        assert!(read_floor(&config(), &geometry, &Pose3::identity(), &Pose3::identity()).is_none());
        for noise_m in [0.002, 0.0] {
            let flat = read_floor(&config(), &scene(None, noise_m, 0.0), &Pose3::identity(), &Pose3::identity());
            let flat = flat.expect("a flat floor, noisy or exact, is read");
            assert!((flat.normal_in_robot - Vec3::z()).norm() < 1e-6, "{:?}", flat.normal_in_robot);
        }
    }

    #[test]
    fn no_reading_with_a_ramp_in_sight_a_robot_on_a_slope_or_a_floor_not_level_at_the_predicted_attitude() {
        let (c, level) = (config(), Pose3::identity());
        assert!(read_floor(&c, &scene(Some(6.0), 0.01, 0.0), &level, &level).is_none());
        // A 40 degree slope is no ramp a robot drives: the floor is read.
        assert!(read_floor(&c, &scene(Some(40.0), 0.01, 0.0), &level, &level).is_some());
        // Predicted 2 degrees nose up: the robot is on a slope and the floor looks 2 degrees off level.
        let pitched = Pose3::from_parts(Default::default(), Rot3::from_euler_angles(0.0, 0.035, 0.0));
        assert!(read_floor(&c, &scene(None, 0.01, 0.0), &level, &pitched).is_none());
        // A LIDAR mounted 1 degree nose up on a robot 1 degree nose down sees a level floor level.
        let mount = Pose3::from_parts(Default::default(), Rot3::from_euler_angles(0.0, -0.0175, 0.0));
        let down = Pose3::from_parts(Default::default(), Rot3::from_euler_angles(0.0, 0.0175, 0.0));
        let reading = read_floor(&c, &scene(None, 0.01, 0.0), &mount, &down).unwrap();
        assert!((reading.normal_in_robot - down.rotation.inverse() * Vec3::z()).norm() < 1e-6);
        let off = LevelFloorConfig { enabled: false, ..c.clone() };
        assert!(read_floor(&off, &scene(None, 0.01, 0.0), &level, &level).is_none());
        let strict = LevelFloorConfig { min_inliers: 300, ..c };
        assert!(read_floor(&strict, &scene(None, 0.01, 0.0), &level, &level).is_none());
    }
}
