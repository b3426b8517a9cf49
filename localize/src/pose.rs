//! The fused pose: the robot pose that best aligns the frame's matched
//! corners with their landmarks, weighted against the odometry/IMU
//! reference. Solved as an iterated Kalman update (Gauss-Newton on the
//! posterior: the reference's covariance is the prior's weight) with Huber
//! re-weighting, so the fix also corrects the filter's gyro bias and wheel
//! scale. A closed-form (Umeyama) alignment seeds it when it agrees with the
//! reference.

use datasets::math::Vec3;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::ekf::{Covariance, Ekf, STATES, State, pose_of, rotation, wrap};
use crate::eval::umeyama;

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
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self { corner_sigma_m: 0.03, huber: 2.0, iterations: 8, min_matches: 2, seed_gate_m: 0.3 }
    }
}

/// One correspondence: a corner in the robot frame and its landmark in the world.
#[derive(Debug, Clone, Copy)]
pub struct Correspondence {
    pub in_robot: Vec3,
    pub in_world: Vec3,
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
        let c = &self.config;
        if matches.len() < c.min_matches.max(1) {
            return None;
        }
        let prior = ekf.x;
        let prior_cov = ekf.p;
        let mut x = self.seed(&prior, matches);
        let sigma2 = c.corner_sigma_m.powi(2);
        let m = 3 * matches.len();
        let mut weights = vec![1.0; matches.len()];
        let mut gain_h = Covariance::zeros();
        for _ in 0..c.iterations {
            let (residual, h) = linearise(&x, matches);
            // Huber weights on each correspondence's normalised distance.
            for (k, w) in weights.iter_mut().enumerate() {
                let d = residual.fixed_rows::<3>(3 * k).norm() / c.corner_sigma_m;
                *w = if d <= c.huber { 1.0 } else { c.huber / d };
            }
            let r = DMatrix::from_diagonal(&DVector::from_fn(m, |i, _| sigma2 / weights[i / 3]));
            let p = DMatrix::from_iterator(STATES, STATES, prior_cov.iter().copied());
            let s = &h * &p * h.transpose() + r;
            let s_inv = s.try_inverse()?;
            let gain = &p * h.transpose() * s_inv;
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
        let (residual, _) = linearise(&x, matches);
        let inliers = (0..matches.len())
            .filter(|&k| residual.fixed_rows::<3>(3 * k).norm() < c.huber * c.corner_sigma_m * 2.0)
            .count();
        let rms_m = (residual.norm_squared() / matches.len() as f64).sqrt();
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

/// Residuals (landmark minus predicted position) and their Jacobian with
/// respect to the state (central differences in the angles).
fn linearise(x: &State, matches: &[Correspondence]) -> (DVector<f64>, DMatrix<f64>) {
    let m = 3 * matches.len();
    let predict = |x: &State, c: &Vec3| -> Vec3 { Vec3::new(x[0], x[1], x[2]) + rotation(x[3], x[4], x[5]) * c };
    let mut residual = DVector::zeros(m);
    let mut h = DMatrix::zeros(m, STATES);
    for (k, corr) in matches.iter().enumerate() {
        let r = corr.in_world - predict(x, &corr.in_robot);
        residual.fixed_rows_mut::<3>(3 * k).copy_from(&r);
        for a in 0..3 {
            h[(3 * k + a, a)] = 1.0;
        }
        for angle in 3..6 {
            let e = 1e-6;
            let (mut plus, mut minus) = (*x, *x);
            plus[angle] += e;
            minus[angle] -= e;
            let d = (predict(&plus, &corr.in_robot) - predict(&minus, &corr.in_robot)) / (2.0 * e);
            h.fixed_view_mut::<3, 1>(3 * k, angle).copy_from(&d);
        }
    }
    (residual, h)
}
