//! The fused pose: the robot pose that best aligns the frame's matched
//! corners with their landmarks, weighted against the odometry/IMU
//! reference. Solved as an iterated Kalman update (Gauss-Newton on the
//! posterior: the reference's covariance is the prior's weight) with Huber
//! re-weighting, so the fix also corrects the filter's gyro bias and wheel
//! scale. A closed-form (Umeyama) alignment seeds it when it agrees with the
//! reference.

use datasets::math::Vec3;
use nalgebra::{DMatrix, DVector, Matrix6};
use serde::{Deserialize, Serialize};

use crate::estimation::ekf::{Covariance, Ekf, STATES, State, pose_of, pose_vector};
use crate::estimation::euler::{rotation, wrap};
use crate::estimation::scan_match::ScanFix;
use crate::evaluation::similarity::umeyama;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseConfig {
    /// Standard deviation of a matched corner's position.
    pub corner_sigma_m: f64,
    /// Huber threshold in standard deviations.
    pub huber: f64,
    pub iterations: usize,
    /// Fewer matches than this: keep the reference pose.
    pub min_matches: usize,
    /// The closed-form seed is used only this close to the reference.
    pub seed_gate_m: f64,
    /// Corrections move only the horizontal states (x, y, yaw, gyro z bias,
    /// wheel scale); height, roll and pitch stay the IMU's.
    pub horizontal_only: bool,
    /// Directions of position (and attitude) that the frame's corners and
    /// walls pin to better than this standard deviation are theirs: the
    /// scan registration, which refers to a map the estimates themselves
    /// placed and so drifts as odometry does, speaks only to the others (a
    /// corridor's axis, a level without corners). 0: the registration
    /// speaks to every direction.
    pub scan_pinned_m: f64,
    pub scan_pinned_rad: f64,
}

/// Height, roll, pitch, roll/pitch gyro biases and accelerometer biases.
const VERTICAL_STATES: [usize; 7] = [2, 3, 4, 6, 7, 10, 11];

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            corner_sigma_m: 0.03,
            huber: 2.0,
            iterations: 20,
            min_matches: 2,
            seed_gate_m: 0.3,
            horizontal_only: false,
            scan_pinned_m: 0.02,
            scan_pinned_rad: 0.005,
        }
    }
}

/// One correspondence: a corner in the robot frame and its landmark in the world.
#[derive(Debug, Clone, Copy)]
pub struct Correspondence {
    pub in_robot: Vec3,
    pub in_world: Vec3,
}

/// A frame plane (robot frame: normal and a point on it) and its landmark
/// (world: normal . p = distance), normals on the same side.
#[derive(Debug, Clone, Copy)]
pub struct PlaneCorrespondence {
    pub normal_in_robot: Vec3,
    pub point_in_robot: Vec3,
    pub normal_in_world: Vec3,
    pub distance_in_world: f64,
}

/// Standard deviations of the plane residuals (offset, normal).
#[derive(Debug, Clone, Copy)]
pub struct PlaneSigmas {
    pub distance_m: f64,
    pub normal_rad: f64,
}

pub struct PoseSolver {
    config: PoseConfig,
}

/// What the solver did with a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseFix {
    pub inliers: usize,
    pub rms_m: f64,
}

impl PoseSolver {
    pub fn new(config: PoseConfig) -> Self {
        Self { config }
    }

    /// Updates the filter with the correspondences; `None` (and the filter
    /// untouched) when there are too few.
    pub fn correct(&self, ekf: &mut Ekf, matches: &[Correspondence]) -> Option<PoseFix> {
        self.correct_with_planes(ekf, matches, &[], PlaneSigmas { distance_m: 1.0, normal_rad: 1.0 }, None)
    }

    /// As `correct`, with plane correspondences and a scan-to-map
    /// registration too; the frame needs `min_matches` corners, at least
    /// three planes or the registration.
    pub fn correct_with_planes(
        &self,
        ekf: &mut Ekf,
        matches: &[Correspondence],
        planes: &[PlaneCorrespondence],
        plane_sigmas: PlaneSigmas,
        scan: Option<&ScanFix>,
    ) -> Option<PoseFix> {
        let c = &self.config;
        if matches.len() < c.min_matches.max(1) && planes.len() < 3 && scan.is_none() {
            return None;
        }
        let prior = ekf.x;
        let prior_cov = ekf.p;
        let mut x = self.seed(&prior, matches);
        let landmarks = Blocks { corners: matches, planes, corner_sigma: c.corner_sigma_m, plane_sigmas, scan: None };
        let scan =
            scan.map(|fix| (fix, fix.whitening() * landmarks.unpinned(&prior, c.scan_pinned_m, c.scan_pinned_rad)));
        let blocks = Blocks { scan, ..landmarks };
        let m = blocks.rows();
        let mut weights = vec![1.0; blocks.count()];
        let mut gain_h = Covariance::zeros();
        for _ in 0..c.iterations {
            let (residual, h) = blocks.linearise(&x);
            // Huber weights on each correspondence's normalised residual.
            for (k, w) in weights.iter_mut().enumerate() {
                let d = blocks.normalised(&residual, k);
                *w = if d <= c.huber { 1.0 } else { c.huber / d };
            }
            let r = DMatrix::from_diagonal(&DVector::from_fn(m, |i, _| {
                let (block, sigma) = blocks.row_info(i);
                sigma * sigma / weights[block]
            }));
            let p = DMatrix::from_iterator(STATES, STATES, prior_cov.iter().copied());
            let s = &h * &p * h.transpose() + r;
            let s_inv = s.try_inverse()?;
            let mut gain = &p * h.transpose() * s_inv;
            if c.horizontal_only {
                for k in VERTICAL_STATES {
                    gain.row_mut(k).fill(0.0);
                }
            }
            let mut dx = DVector::from_iterator(STATES, (prior - x).iter().copied());
            for k in 3..6 {
                dx[k] = wrap(dx[k]);
            }
            let innovation = &residual - &h * &dx;
            let step = gain.clone() * innovation + dx;
            let mut next = x;
            for k in 0..STATES {
                next[k] += step[k];
            }
            for k in 3..6 {
                next[k] = wrap(next[k]);
            }
            let moved = (next - x).norm();
            x = next;
            let gh = gain * h;
            gain_h = Covariance::from_iterator(gh.iter().copied());
            if moved < 1e-9 {
                break;
            }
        }
        ekf.x = x;
        let i_kh = Covariance::identity() - gain_h;
        ekf.p = i_kh * prior_cov;
        ekf.p = 0.5 * (ekf.p + ekf.p.transpose());
        let (residual, _) = blocks.linearise(&x);
        let inliers = (0..matches.len()).filter(|&k| blocks.normalised(&residual, k) < 2.0 * c.huber).count();
        let corner_rows = 3 * matches.len();
        let rms_m = if matches.is_empty() {
            0.0
        } else {
            (residual.rows(0, corner_rows).norm_squared() / matches.len() as f64).sqrt()
        };
        Some(PoseFix { inliers, rms_m })
    }

    /// The closed-form alignment of the correspondences, if there are three
    /// and it lands near the reference; the reference otherwise.
    fn seed(&self, prior: &State, matches: &[Correspondence]) -> State {
        if matches.len() < 3 {
            return *prior;
        }
        let from: Vec<Vec3> = matches.iter().map(|m| m.in_robot).collect();
        let to: Vec<Vec3> = matches.iter().map(|m| m.in_world).collect();
        let Some(s) = umeyama(&from, &to, false) else { return *prior };
        let rot = nalgebra::Rotation3::from_matrix_unchecked(s.rotation);
        let (roll, pitch, yaw) = rot.euler_angles();
        let reference = pose_of(prior);
        let close = (s.translation - reference.translation.vector).norm() < self.config.seed_gate_m
            && wrap(yaw - prior[5]).abs() < 0.2
            && wrap(roll - prior[3]).abs() < 0.2
            && wrap(pitch - prior[4]).abs() < 0.2;
        if !close {
            return *prior;
        }
        let mut x = *prior;
        x[0] = s.translation.x;
        x[1] = s.translation.y;
        x[2] = s.translation.z;
        x[3] = roll;
        x[4] = pitch;
        x[5] = yaw;
        x
    }
}

/// The residual blocks of a frame: 3 rows per corner (landmark minus
/// predicted position), 3 per plane (landmark offset minus the predicted
/// offset of the frame plane's point, then the horizontal part of landmark
/// normal minus predicted normal). The vertical part of a wall's normal would
/// tie pitch and roll to the small tilt biases of plane fits; gravity measures
/// them better, and over a long route a pitch bias of 1 mrad is 3 cm of height.
/// Last, 6 rows for a scan registration: its pose minus the state's,
/// whitened by its information (so each row has unit deviation).
struct Blocks<'a> {
    corners: &'a [Correspondence],
    planes: &'a [PlaneCorrespondence],
    corner_sigma: f64,
    plane_sigmas: PlaneSigmas,
    scan: Option<(&'a ScanFix, Matrix6<f64>)>,
}

impl Blocks<'_> {
    fn count(&self) -> usize {
        self.corners.len() + self.planes.len() + usize::from(self.scan.is_some())
    }
    fn scan_start(&self) -> usize {
        3 * self.corners.len() + 3 * self.planes.len()
    }
    fn rows(&self) -> usize {
        self.scan_start() + if self.scan.is_some() { 6 } else { 0 }
    }
    /// (block index, standard deviation) of a residual row.
    fn row_info(&self, row: usize) -> (usize, f64) {
        let corner_rows = 3 * self.corners.len();
        if row >= self.scan_start() {
            (self.corners.len() + self.planes.len(), 1.0)
        } else if row < corner_rows {
            (row / 3, self.corner_sigma)
        } else {
            let k = (row - corner_rows) / 3;
            let first = (row - corner_rows).is_multiple_of(3);
            (self.corners.len() + k, if first { self.plane_sigmas.distance_m } else { self.plane_sigmas.normal_rad })
        }
    }
    /// Norm of a block's residual in standard deviations, per three rows
    /// (so that one Huber threshold serves the 6-row scan block too).
    fn normalised(&self, residual: &DVector<f64>, block: usize) -> f64 {
        let (start, len) = if block < self.corners.len() {
            (3 * block, 3)
        } else if block < self.corners.len() + self.planes.len() {
            (3 * self.corners.len() + 3 * (block - self.corners.len()), 3)
        } else {
            (self.scan_start(), 6)
        };
        let squares: f64 = (start..start + len)
            .map(|row| {
                let (_, sigma) = self.row_info(row);
                (residual[row] / sigma).powi(2)
            })
            .sum();
        (squares * 3.0 / len as f64).sqrt()
    }

    fn predict(&self, x: &State) -> DVector<f64> {
        let t = Vec3::new(x[0], x[1], x[2]);
        let r = rotation(x[3], x[4], x[5]);
        let mut out = DVector::zeros(self.rows());
        for (k, c) in self.corners.iter().enumerate() {
            out.fixed_rows_mut::<3>(3 * k).copy_from(&(c.in_world - (t + r * c.in_robot)));
        }
        let base = 3 * self.corners.len();
        for (k, p) in self.planes.iter().enumerate() {
            let point = t + r * p.point_in_robot;
            out[base + 3 * k] = p.distance_in_world - p.normal_in_world.dot(&point);
            let normal_gap = p.normal_in_world - r * p.normal_in_robot;
            out[base + 3 * k + 1] = normal_gap.x;
            out[base + 3 * k + 2] = normal_gap.y;
        }
        if let Some((fix, whitening)) = &self.scan {
            out.fixed_rows_mut::<6>(self.scan_start()).copy_from(&(whitening * fix.difference(&pose_vector(x))));
        }
        out
    }

    /// The projection onto the directions of position and of attitude
    /// that these blocks pin to worse than `pinned_m` / `pinned_rad` at
    /// `x` (position and attitude taken apart: their units differ).
    fn unpinned(&self, x: &State, pinned_m: f64, pinned_rad: f64) -> Matrix6<f64> {
        let (_, h) = self.linearise(x);
        let mut information = Matrix6::zeros();
        for row in 0..self.rows() {
            let (_, sigma) = self.row_info(row);
            let j = h.fixed_view::<1, 6>(row, 0);
            information += j.transpose() * j / (sigma * sigma);
        }
        let mut projection = Matrix6::zeros();
        for (start, pinned) in [(0, pinned_m), (3, pinned_rad)] {
            let block: nalgebra::Matrix3<f64> = information.fixed_view::<3, 3>(start, start).into();
            let eigen = block.symmetric_eigen();
            let threshold = if pinned > 0.0 { 1.0 / (pinned * pinned) } else { f64::INFINITY };
            let mut p = nalgebra::Matrix3::zeros();
            for k in 0..3 {
                if eigen.eigenvalues[k] < threshold {
                    let v = eigen.eigenvectors.column(k);
                    p += v * v.transpose();
                }
            }
            projection.fixed_view_mut::<3, 3>(start, start).copy_from(&p);
        }
        projection
    }

    /// Residuals and their Jacobian with respect to the state (central
    /// differences: the pose has six components and the rest do not enter).
    fn linearise(&self, x: &State) -> (DVector<f64>, DMatrix<f64>) {
        let residual = self.predict(x);
        let mut h = DMatrix::zeros(self.rows(), STATES);
        for k in 0..6 {
            let e = 1e-6;
            let (mut plus, mut minus) = (*x, *x);
            plus[k] += e;
            minus[k] -= e;
            // h(x) = measurement - residual, so dh/dx = -d(residual)/dx.
            let d = (self.predict(&minus) - self.predict(&plus)) / (2.0 * e);
            h.set_column(k, &d);
        }
        (residual, h)
    }
}
