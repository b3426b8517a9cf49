//! Proprioceptive sensors: wheel odometry (planar, with scale error, yaw-rate
//! bias and noise, so it drifts; it measures distance along the slope, so
//! ramps stretch it) and an IMU (specific force and angular rate in the robot
//! frame, with constant biases and white noise).

use serde::{Deserialize, Serialize};

use super::render::gaussian;
use crate::InvalidSetting;
use crate::io::formats::{ImuSample, OdometrySample};
use crate::math::{Pose3, Vec3};
use crate::seed::mix;

pub const GRAVITY_MPS2: f64 = 9.81;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    pub odometry_rate_hz: f64,
    pub imu_rate_hz: f64,
    /// Relative error of the wheel-measured speed (wheel radius, slip).
    pub speed_scale_error: f64,
    pub speed_noise_mps: f64,
    pub yaw_rate_bias_rps: f64,
    pub yaw_rate_noise_rps: f64,
    /// Standard deviation of the constant accelerometer / gyro biases.
    pub accel_bias_mps2: f64,
    pub gyro_bias_rps: f64,
    pub accel_noise_mps2: f64,
    pub gyro_noise_rps: f64,
    /// Extra relative speed the wheels measure on a 10 degree ramp (they
    /// slip when climbing or braking), in proportion to the slope.
    pub ramp_slip: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            odometry_rate_hz: 10.0,
            imu_rate_hz: 50.0,
            speed_scale_error: 0.02,
            speed_noise_mps: 0.002,
            yaw_rate_bias_rps: 0.002,
            yaw_rate_noise_rps: 0.003,
            accel_bias_mps2: 0.03,
            gyro_bias_rps: 0.002,
            accel_noise_mps2: 0.02,
            gyro_noise_rps: 0.002,
            ramp_slip: 0.0,
        }
    }
}

impl MotionConfig {
    /// Perfect sensors at the default rates: for tests with exact answers.
    pub fn noiseless() -> Self {
        Self {
            speed_scale_error: 0.0,
            speed_noise_mps: 0.0,
            yaw_rate_bias_rps: 0.0,
            yaw_rate_noise_rps: 0.0,
            accel_bias_mps2: 0.0,
            gyro_bias_rps: 0.0,
            accel_noise_mps2: 0.0,
            gyro_noise_rps: 0.0,
            ramp_slip: 0.0,
            ..Self::default()
        }
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for (field, rate) in [("odometry_rate_hz", self.odometry_rate_hz), ("imu_rate_hz", self.imu_rate_hz)] {
            if !(rate > 0.0 && rate <= 2000.0) {
                return Err(InvalidSetting::field(field, format!("{rate} Hz outside (0, 2000]")));
            }
        }
        let magnitudes = [
            ("speed_scale_error", self.speed_scale_error),
            ("speed_noise_mps", self.speed_noise_mps),
            ("yaw_rate_bias_rps", self.yaw_rate_bias_rps),
            ("yaw_rate_noise_rps", self.yaw_rate_noise_rps),
            ("accel_bias_mps2", self.accel_bias_mps2),
            ("gyro_bias_rps", self.gyro_bias_rps),
            ("accel_noise_mps2", self.accel_noise_mps2),
            ("gyro_noise_rps", self.gyro_noise_rps),
            ("ramp_slip", self.ramp_slip),
        ];
        if let Some((field, value)) = magnitudes.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            return Err(InvalidSetting::field(*field, format!("{value} must be finite and >= 0")));
        }
        Ok(())
    }
}

/// Planar heading of a pose: the yaw of its forward axis.
pub fn heading(pose: &Pose3) -> f64 {
    let f = pose.rotation * Vec3::x();
    f.y.atan2(f.x)
}

fn wrap(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// Wheel odometry over `[0, duration]`, starting at the origin of the odometry
/// frame with zero heading; `world_from_robot(t)` is the true motion.
pub fn simulate_odometry(
    world_from_robot: &dyn Fn(f64) -> Pose3,
    duration_s: f64,
    config: &MotionConfig,
    key: u64,
) -> Vec<OdometrySample> {
    let dt = 1.0 / config.odometry_rate_hz;
    let steps = (duration_s * config.odometry_rate_hz).floor() as usize;
    let scale = 1.0 + config.speed_scale_error * gaussian(mix(key ^ 1)) as f64;
    let bias = config.yaw_rate_bias_rps * gaussian(mix(key ^ 2)) as f64;
    let mut state = OdometrySample { timestamp: 0.0, x: 0.0, y: 0.0, yaw: 0.0, v: 0.0, omega: 0.0 };
    let mut out = vec![state];
    for k in 1..=steps {
        let (t0, t1) = ((k - 1) as f64 * dt, k as f64 * dt);
        let (a, b) = (world_from_robot(t0), world_from_robot(t1));
        let v_true = (b.translation.vector - a.translation.vector).norm() / dt;
        let slope = (b.rotation * Vec3::x()).z.clamp(-1.0, 1.0).asin().abs();
        let slip = 1.0 + config.ramp_slip * slope / 10f64.to_radians();
        let w_true = wrap(heading(&b) - heading(&a)) / dt;
        let v = v_true * scale * slip + config.speed_noise_mps * gaussian(mix(key ^ (k as u64) << 8 ^ 3)) as f64;
        let omega = w_true + bias + config.yaw_rate_noise_rps * gaussian(mix(key ^ (k as u64) << 8 ^ 4)) as f64;
        // Midpoint integration of the unicycle model.
        let mid = state.yaw + omega * dt / 2.0;
        state = OdometrySample {
            timestamp: t1,
            x: state.x + v * dt * mid.cos(),
            y: state.y + v * dt * mid.sin(),
            yaw: wrap(state.yaw + omega * dt),
            v,
            omega,
        };
        out.push(state);
    }
    out
}

/// IMU samples over `[0, duration]`: the mean specific force and angular rate
/// over each sample period, in the robot frame.
pub fn simulate_imu(
    world_from_robot: &dyn Fn(f64) -> Pose3,
    duration_s: f64,
    config: &MotionConfig,
    key: u64,
) -> Vec<ImuSample> {
    let dt = 1.0 / config.imu_rate_hz;
    let steps = (duration_s * config.imu_rate_hz).floor() as usize;
    let draw = |k: u64| gaussian(mix(key ^ k)) as f64;
    let accel_bias = Vec3::new(draw(11), draw(12), draw(13)) * config.accel_bias_mps2;
    let gyro_bias = Vec3::new(draw(14), draw(15), draw(16)) * config.gyro_bias_rps;
    (0..=steps)
        .map(|k| {
            let t = k as f64 * dt;
            let (before, now, after) = (world_from_robot(t - dt), world_from_robot(t), world_from_robot(t + dt));
            let accel_world =
                (after.translation.vector - 2.0 * now.translation.vector + before.translation.vector) / (dt * dt);
            let specific = now.rotation.inverse() * (accel_world + Vec3::new(0.0, 0.0, GRAVITY_MPS2));
            let (half_a, half_b) = (world_from_robot(t - dt / 2.0), world_from_robot(t + dt / 2.0));
            let rate = (half_a.rotation.inverse() * half_b.rotation).scaled_axis() / dt;
            let noise = |c: u64| draw((k as u64) << 8 ^ c);
            let accel = specific + accel_bias + Vec3::new(noise(1), noise(2), noise(3)) * config.accel_noise_mps2;
            let gyro = rate + gyro_bias + Vec3::new(noise(4), noise(5), noise(6)) * config.gyro_noise_rps;
            ImuSample { timestamp: t, accel: accel.into(), gyro: gyro.into() }
        })
        .collect()
}
