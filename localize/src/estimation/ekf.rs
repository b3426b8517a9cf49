//! The odometry/IMU reference: an extended Kalman filter that dead-reckons
//! the robot's 3D pose from the IMU's angular rate and the wheels' forward
//! speed, levels roll and pitch with the accelerometer's gravity, and
//! estimates the gyro's biases, the wheels' speed scale and the
//! accelerometer's horizontal biases. Gravity makes the roll and pitch rate
//! biases observable; the yaw-rate bias, the scale and the accelerometer
//! biases (which tilt the gravity reading) only pose corrections do. A rig
//! without a gyro or without wheels has the rate or the velocity of its
//! previous motion carried on instead (`BodyMotion`, `sensor_replay`).
//!
//! State: position (3, world), roll, pitch, yaw (ZYX Euler, world from robot),
//! gyro bias (3, rad/s, body), wheel speed scale (1 = exact), accelerometer
//! bias along body x and y (m/s^2).

use datasets::math::{Pose3, Rot3, Vec3};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

use crate::estimation::euler::{rotation, wrap};

pub const STATES: usize = 12;
/// Index of the wheel speed scale in the state.
pub const SCALE: usize = 9;
/// Index of the accelerometer's x bias (y follows).
pub const ACCEL_BIAS: usize = 10;
pub type State = SVector<f64, STATES>;
pub type Covariance = SMatrix<f64, STATES, STATES>;

const GRAVITY: f64 = 9.80665;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EkfConfig {
    /// Gyro white noise (rad/s per sample).
    pub gyro_noise_rps: f64,
    /// Wheel speed white noise (m/s per sample).
    pub speed_noise_mps: f64,
    /// Random walk of the gyro bias (rad/s per sqrt(s)) and the speed scale (1/sqrt(s)).
    pub bias_walk: f64,
    pub scale_walk: f64,
    /// Prior standard deviations of the bias and the scale.
    pub initial_bias_rps: f64,
    pub initial_scale: f64,
    pub initial_accel_bias_mps2: f64,
    /// Standard deviation of roll/pitch read from the accelerometer, used
    /// only while the specific force is within `gravity_gate` of g.
    pub gravity_sigma_rad: f64,
    pub gravity_gate_mps2: f64,
    /// Gravity readings farther than this squared Mahalanobis distance from
    /// the state are skipped (chi-square, 2 degrees of freedom: 13.8 = 0.1%).
    pub gravity_gate_chi2: f64,
    /// How much the wheels' speed scale may change on a 10 degree slope
    /// within a second, in proportion to the slope: wheels slip on ramps.
    pub ramp_slip_per_s: f64,
    /// Without wheels, the velocity carries on from the previous motion and
    /// may change by this much a second (standard deviation).
    pub velocity_change_mps2: f64,
    /// Without a gyro, the angular rate carries on likewise.
    pub rate_change_rps2: f64,
    /// Until two frames have measured a motion, how fast the robot may
    /// already be moving and turning (standard deviations).
    pub unknown_velocity_mps: f64,
    pub unknown_rate_rps: f64,
}

impl Default for EkfConfig {
    fn default() -> Self {
        Self {
            gyro_noise_rps: 0.003,
            speed_noise_mps: 0.003,
            bias_walk: 1e-5,
            scale_walk: 1e-4,
            initial_bias_rps: 0.005,
            initial_scale: 0.05,
            initial_accel_bias_mps2: 0.05,
            gravity_sigma_rad: 0.003,
            gravity_gate_mps2: 0.3,
            gravity_gate_chi2: 13.8,
            ramp_slip_per_s: 0.03,
            velocity_change_mps2: 2.0,
            rate_change_rps2: 3.0,
            unknown_velocity_mps: 1.0,
            unknown_rate_rps: 1.0,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Ekf {
    pub config: EkfConfig,
    pub x: State,
    pub p: Covariance,
    pub time: f64,
}

impl Ekf {
    /// Starts at `start` (the world frame is the robot's start pose) at `time`.
    pub fn new(config: EkfConfig, start: &Pose3, time: f64) -> Self {
        let mut x = State::zeros();
        x.fixed_rows_mut::<6>(0).copy_from(&pose_entries(start));
        x[SCALE] = 1.0;
        let mut p = Covariance::zeros();
        for k in 0..6 {
            p[(k, k)] = 1e-8;
        }
        for k in 6..9 {
            p[(k, k)] = config.initial_bias_rps.powi(2);
        }
        p[(SCALE, SCALE)] = config.initial_scale.powi(2);
        for k in ACCEL_BIAS..ACCEL_BIAS + 2 {
            p[(k, k)] = config.initial_accel_bias_mps2.powi(2);
        }
        Self { config, x, p, time }
    }

    pub fn pose(&self) -> Pose3 {
        pose_of(&self.x)
    }

    /// Moves the pose to `pose` (a start found in a map) with `covariance`
    /// (x, y, z, roll, pitch, yaw), uncorrelated with the rest of the state.
    pub fn place(&mut self, pose: &Pose3, covariance: &nalgebra::Matrix6<f64>) {
        self.x.fixed_rows_mut::<6>(0).copy_from(&pose_entries(pose));
        self.p.fixed_rows_mut::<6>(0).fill(0.0);
        self.p.fixed_columns_mut::<6>(0).fill(0.0);
        self.p.fixed_view_mut::<6, 6>(0, 0).copy_from(&(0.5 * (covariance + covariance.transpose())));
    }

    /// Propagates by `dt` with the body angular rate `gyro` and wheel speed `speed`.
    pub fn predict(&mut self, gyro: &Vec3, speed: f64, dt: f64) {
        self.predict_motion(&BodyMotion::measured(*gyro, speed), dt);
    }

    /// Propagates by `dt` with `motion`: each of the rate and the velocity
    /// measured (gyro, wheels) or carried on from the previous motion.
    pub fn predict_motion(&mut self, motion: &BodyMotion, dt: f64) {
        if dt <= 0.0 {
            return;
        }
        let f = |x: &State| propagate_body(x, motion, dt);
        // The model is smooth and the state small: a central-difference
        // Jacobian is exact enough and cannot get a sign wrong.
        let mut jacobian = Covariance::zeros();
        for k in 0..STATES {
            let h = if k == SCALE { 1e-6 } else { 1e-7 };
            let (mut plus, mut minus) = (self.x, self.x);
            plus[k] += h;
            minus[k] -= h;
            let mut d = (f(&plus) - f(&minus)) / (2.0 * h);
            for a in 3..6 {
                d[a] = wrap(d[a] * 2.0 * h) / (2.0 * h);
            }
            jacobian.set_column(k, &d);
        }
        let c = &self.config;
        let mut q = Covariance::zeros();
        // A carried-on motion drifts as a change of velocity held since it
        // was measured: after t seconds, sigma t^2 / 2 off. The variance
        // added over the step is the growth over it, whatever the steps.
        let carried_s = motion.measured_at.map_or(0.0, |at| (self.time - at).max(0.0));
        let carried = |sigma: f64| {
            let (t0, t1) = (carried_s, carried_s + dt);
            sigma * sigma * (t1.powi(4) - t0.powi(4)) / 4.0
        };
        // Before two frames have measured a motion, the one carried on (none)
        // is a guess: the robot may already be moving at any speed.
        let guessed = |sigma: f64| if motion.measured_at.is_none() { (sigma * dt).powi(2) } else { 0.0 };
        let sv = if motion.wheels {
            (c.speed_noise_mps * dt).powi(2)
        } else {
            carried(c.velocity_change_mps2) + guessed(c.unknown_velocity_mps)
        };
        let sg = if motion.gyro {
            (c.gyro_noise_rps * dt).powi(2)
        } else {
            carried(c.rate_change_rps2) + guessed(c.unknown_rate_rps)
        };
        for k in 0..3 {
            q[(k, k)] = sv;
            q[(3 + k, 3 + k)] = sg;
        }
        for k in 6..9 {
            q[(k, k)] = c.bias_walk.powi(2) * dt;
        }
        let slope = (self.x[3].cos() * self.x[4].cos()).clamp(-1.0, 1.0).acos();
        let slip = c.ramp_slip_per_s * slope / 10f64.to_radians();
        q[(SCALE, SCALE)] = (c.scale_walk.powi(2) + slip * slip) * dt;
        self.x = f(&self.x);
        self.p = jacobian * self.p * jacobian.transpose() + q;
        self.time += dt;
    }

    /// Levels roll and pitch with the accelerometer's specific force, when
    /// the robot is not accelerating much.
    pub fn update_gravity(&mut self, accel: &Vec3) {
        let c = &self.config;
        if (accel.norm() - GRAVITY).abs() > c.gravity_gate_mps2 {
            return;
        }
        // The tilt the bias-corrected specific force says, against the state's.
        let reading = |x: &State| {
            let a = Vec3::new(accel.x - x[ACCEL_BIAS], accel.y - x[ACCEL_BIAS + 1], accel.z);
            nalgebra::Vector2::new(a.y.atan2(a.z), (-a.x).atan2((a.y * a.y + a.z * a.z).sqrt()))
        };
        let residual_of = |x: &State| {
            let r = reading(x);
            nalgebra::Vector2::new(wrap(r[0] - x[3]), wrap(r[1] - x[4]))
        };
        let mut h = SMatrix::<f64, 2, STATES>::zeros();
        for k in [3, 4, ACCEL_BIAS, ACCEL_BIAS + 1] {
            let e = 1e-6;
            let (mut plus, mut minus) = (self.x, self.x);
            plus[k] += e;
            minus[k] -= e;
            // h(x) = state tilt - reading tilt shifted; dh/dx = -d(residual)/dx.
            h.set_column(k, &((residual_of(&minus) - residual_of(&plus)) / (2.0 * e)));
        }
        let residual = residual_of(&self.x);
        let r = nalgebra::Matrix2::identity() * c.gravity_sigma_rad.powi(2);
        // While the pitch changes (the foot and top of a ramp) the reading
        // lags the state; such outliers would drag the coupled states along.
        let s = h * self.p * h.transpose() + r;
        if let Some(s_inv) = s.try_inverse()
            && (residual.transpose() * s_inv * residual)[0] <= c.gravity_gate_chi2
        {
            // Gravity says nothing about where the robot is or where it heads:
            // only attitude and biases take the correction (a Schmidt update;
            // the Joseph form keeps P right for any gain).
            self.update_only(&h, &residual, &r, &[3, 4, 6, 7, 8, ACCEL_BIAS, ACCEL_BIAS + 1]);
        }
    }

    /// Levels roll and pitch with a floor known to be level: its upward
    /// normal in the robot frame, whose tilt has standard deviation
    /// `sigma_rad`. Like gravity, it corrects only attitude and biases; the
    /// two differ in the accelerometer's bias, which the floor does not see.
    /// Returns whether the reading passed the `gate_chi2` gate.
    pub fn update_level(&mut self, normal_in_robot: &Vec3, sigma_rad: f64, gate_chi2: f64) -> bool {
        // h(x): the floor normal's horizontal part in the world, 0 when level.
        let tilt = |x: &State| {
            let n = rotation(x[3], x[4], x[5]) * normal_in_robot;
            nalgebra::Vector2::new(n.x, n.y)
        };
        let mut h = SMatrix::<f64, 2, STATES>::zeros();
        for k in 3..6 {
            let e = 1e-6;
            let (mut plus, mut minus) = (self.x, self.x);
            plus[k] += e;
            minus[k] -= e;
            h.set_column(k, &((tilt(&plus) - tilt(&minus)) / (2.0 * e)));
        }
        let residual = -tilt(&self.x);
        let r = nalgebra::Matrix2::identity() * sigma_rad.powi(2);
        let s = h * self.p * h.transpose() + r;
        let Some(s_inv) = s.try_inverse() else { return false };
        if (residual.transpose() * s_inv * residual)[0] > gate_chi2 {
            return false;
        }
        self.update_only(&h, &residual, &r, &[3, 4, 6, 7, 8, ACCEL_BIAS, ACCEL_BIAS + 1]);
        true
    }

    /// A standard Kalman update with residual `z - h(x)` already formed.
    pub fn update<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, STATES>,
        residual: &SVector<f64, M>,
        r: &SMatrix<f64, M, M>,
    ) {
        let all: Vec<usize> = (0..STATES).collect();
        self.update_only(h, residual, r, &all);
    }

    /// A Kalman update that corrects only the listed states.
    pub fn update_only<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, STATES>,
        residual: &SVector<f64, M>,
        r: &SMatrix<f64, M, M>,
        states: &[usize],
    ) {
        let s = h * self.p * h.transpose() + r;
        let Some(s_inv) = s.try_inverse() else { return };
        let mut gain = self.p * h.transpose() * s_inv;
        for k in (0..STATES).filter(|k| !states.contains(k)) {
            gain.row_mut(k).fill(0.0);
        }
        self.x += gain * residual;
        normalise(&mut self.x);
        // Joseph form keeps P symmetric and positive.
        let i_kh = Covariance::identity() - gain * h;
        self.p = i_kh * self.p * i_kh.transpose() + gain * r * gain.transpose();
    }
}

fn normalise(x: &mut State) {
    for k in 3..6 {
        x[k] = wrap(x[k]);
    }
}

pub fn pose_of(x: &State) -> Pose3 {
    pose_from_entries(&pose_vector(x))
}

/// The pose of x, y, z, roll, pitch, yaw (ZYX Euler angles).
pub fn pose_from_entries(v: &SVector<f64, 6>) -> Pose3 {
    Pose3::from_parts(Vec3::new(v[0], v[1], v[2]).into(), rotation(v[3], v[4], v[5]))
}

/// A pose as x, y, z, roll, pitch, yaw: the state's first six entries.
pub fn pose_entries(pose: &Pose3) -> SVector<f64, 6> {
    let (roll, pitch, yaw) = pose.rotation.euler_angles();
    let t = pose.translation.vector;
    SVector::<f64, 6>::new(t.x, t.y, t.z, roll, pitch, yaw)
}

/// The state's pose part as a vector: x, y, z, roll, pitch, yaw.
pub fn pose_vector(x: &State) -> SVector<f64, 6> {
    x.fixed_rows::<6>(0).into_owned()
}

/// How the body moves over one prediction step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyMotion {
    /// Angular rate (rad/s, body frame).
    pub rate: Vec3,
    /// The rate is a gyro's: the state's gyro bias is taken off it.
    pub gyro: bool,
    /// Velocity (m/s, body frame).
    pub velocity: Vec3,
    /// The velocity is the wheels' forward speed: the state's scale applies.
    pub wheels: bool,
    /// When a carried-on rate or velocity was measured (its uncertainty
    /// grows with the time since); `None`: nothing measured it yet.
    pub measured_at: Option<f64>,
}

impl BodyMotion {
    /// A gyro's rate and the wheels' forward speed.
    pub fn measured(gyro: Vec3, speed: f64) -> Self {
        Self { rate: gyro, gyro: true, velocity: Vec3::new(speed, 0.0, 0.0), wheels: true, measured_at: None }
    }
}

/// The motion model with a gyro and wheels: attitude integrates the
/// bias-corrected gyro rate in the body frame; position moves along the
/// body's x axis at the scaled wheel speed (midpoint attitude).
pub fn propagate(x: &State, gyro: &Vec3, speed: f64, dt: f64) -> State {
    propagate_body(x, &BodyMotion::measured(*gyro, speed), dt)
}

/// The motion model: attitude integrates the body rate (bias-corrected when
/// it is a gyro's), position moves by the body velocity (scaled when it is
/// the wheels') at the midpoint attitude.
pub fn propagate_body(x: &State, motion: &BodyMotion, dt: f64) -> State {
    let r0 = rotation(x[3], x[4], x[5]);
    let rate = if motion.gyro { motion.rate - Vec3::new(x[6], x[7], x[8]) } else { motion.rate };
    let step = Rot3::from_scaled_axis(rate * dt);
    let r1 = r0 * step;
    let velocity = if motion.wheels {
        let mid = r0 * Rot3::from_scaled_axis(rate * dt * 0.5);
        mid * (motion.velocity * x[SCALE])
    } else {
        // A carried-on twist: the exact exponential, so that the prediction
        // does not depend on how the time is cut into steps.
        r0 * (left_jacobian(&(rate * dt)) * motion.velocity)
    };
    let (roll, pitch, yaw) = r1.euler_angles();
    let mut out = *x;
    out[0] += velocity.x * dt;
    out[1] += velocity.y * dt;
    out[2] += velocity.z * dt;
    out[3] = roll;
    out[4] = pitch;
    out[5] = yaw;
    out
}

/// The left Jacobian of SO(3) at the rotation vector `phi`: a constant
/// twist (rate w, velocity v) for time t moves the body by
/// `J(w t) v t` in its starting frame.
pub fn left_jacobian(phi: &Vec3) -> nalgebra::Matrix3<f64> {
    let theta = phi.norm();
    let k = phi.cross_matrix();
    let (a, b) = if theta < 1e-4 {
        // Series: 1/2 - theta^2/24 and 1/6 - theta^2/120.
        (0.5 - theta * theta / 24.0, 1.0 / 6.0 - theta * theta / 120.0)
    } else {
        ((1.0 - theta.cos()) / (theta * theta), (theta - theta.sin()) / (theta * theta * theta))
    };
    nalgebra::Matrix3::identity() + a * k + b * k * k
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The wheel scale's variance after `seconds` standing still at `pitch_deg`.
    fn scale_variance_after(pitch_deg: f64, seconds: f64) -> f64 {
        let start = pose_from_entries(&SVector::<f64, 6>::new(0.0, 0.0, 0.0, 0.0, pitch_deg.to_radians(), 0.0));
        let mut ekf = Ekf::new(EkfConfig::default(), &start, 0.0);
        for _ in 0..100 {
            ekf.predict(&Vec3::zeros(), 0.0, seconds / 100.0);
        }
        ekf.p[(SCALE, SCALE)]
    }

    #[test]
    fn on_a_slope_the_wheel_scale_may_change_as_fast_as_the_slip_says() {
        let c = EkfConfig::default();
        let flat = scale_variance_after(0.0, 2.0);
        // (The central-difference Jacobian's rounding, 1e-10 a step, compounds.)
        assert!((flat - (c.initial_scale.powi(2) + c.scale_walk.powi(2) * 2.0)).abs() < 1e-10, "{flat}");
        // 10 degrees: the slip's variance per second, for two seconds; 5 degrees: a quarter of it.
        let steep = scale_variance_after(10.0, 2.0) - flat;
        assert!((steep - 2.0 * c.ramp_slip_per_s.powi(2)).abs() < 1e-9, "{steep}");
        let gentle = scale_variance_after(5.0, 2.0) - flat;
        assert!((gentle - 0.5 * c.ramp_slip_per_s.powi(2)).abs() < 1e-9, "{gentle}");
    }

    #[test]
    fn a_level_floor_pulls_a_wrong_pitch_by_the_kalman_gain_and_leaves_the_position() {
        // Truly level, the filter 5 mrad nose down with 3 mrad of doubt; the floor reads 1 mrad.
        let mut ekf = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.0);
        ekf.x[0] = 2.0;
        ekf.x[4] = 0.005;
        ekf.p[(4, 4)] = 0.003f64.powi(2);
        ekf.p[(0, 4)] = 1e-6;
        ekf.p[(4, 0)] = 1e-6;
        assert!(ekf.update_level(&Vec3::z(), 0.001, 13.8));
        // Scalar Kalman: 5 mrad x 1 / (1 + 9) is left (to the small-angle approximation).
        assert!((ekf.x[4] - 0.0005).abs() < 1e-7, "{}", ekf.x[4]);
        assert!(ekf.x[3].abs() < 1e-12 && ekf.x[5].abs() < 1e-12);
        assert_eq!(ekf.x[0], 2.0, "a floor's tilt says nothing about where the robot is");
        assert!((ekf.p[(4, 4)] - 0.9e-6).abs() < 1e-10, "{}", ekf.p[(4, 4)]);
        // A floor 10 sigma off (a ramp's foot fitted as floor) is refused and changes nothing.
        let before = ekf.x;
        let tilted = Vec3::new(-0.02, 0.0, 1.0).normalize();
        assert!(!ekf.update_level(&tilted, 0.001, 13.8));
        assert_eq!(ekf.x, before);
    }

    #[test]
    fn floor_and_gravity_together_separate_the_pitch_from_the_accelerometer_bias() {
        // The accelerometer reads 0.03 m/s^2 too much along x: gravity alone
        // would take it as 3 mrad of pitch. A level floor pins the pitch, so
        // the bias must take the reading.
        let mut ekf = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.0);
        ekf.p[(4, 4)] = 0.005f64.powi(2);
        let accel = Vec3::new(0.03, 0.0, GRAVITY);
        for _ in 0..200 {
            ekf.predict(&Vec3::zeros(), 0.0, 0.005);
            ekf.update_gravity(&accel);
            ekf.update_level(&Vec3::z(), 0.0005, 13.8);
        }
        assert!(ekf.x[4].abs() < 2e-4, "pitch {}", ekf.x[4]);
        assert!((ekf.x[ACCEL_BIAS] - 0.03).abs() < 0.003, "bias {}", ekf.x[ACCEL_BIAS]);
    }
}
