//! Replaying the wheel odometry and IMU logs into the filter, with whatever
//! of them the recording has: every IMU sample up to a frame's time is a
//! prediction (with the wheel speed of that moment) and a gravity update.
//! A rate or a velocity the recording does not measure (no gyro, no wheels)
//! carries on from the previous frames' motion, as KISS-ICP predicts.

use datasets::io::formats::{ImuSample, OdometrySample};
use datasets::math::{Pose3, Vec3};

use crate::estimation::ekf::{BodyMotion, Ekf, left_jacobian};

/// The motion between the last two frames, carried on where nothing measures it.
#[derive(Debug, Clone, Copy, Default)]
struct PreviousMotion {
    rate: Vec3,
    velocity: Vec3,
    /// When it was measured (the later frame's time); `None` before two frames.
    at: Option<f64>,
}

/// Drives an EKF through the odometry and IMU logs, one frame time at a time.
#[derive(Clone)]
pub struct SensorReplay<'a> {
    odometry: &'a [OdometrySample],
    imu: &'a [ImuSample],
    next_imu: usize,
    previous: PreviousMotion,
}

impl<'a> SensorReplay<'a> {
    /// Replays the logs from `start` on (earlier samples are skipped); either
    /// may be empty.
    pub fn new(odometry: &'a [OdometrySample], imu: &'a [ImuSample], start: f64) -> Self {
        let next_imu = imu.partition_point(|s| s.timestamp <= start);
        Self { odometry, imu, next_imu, previous: PreviousMotion::default() }
    }

    /// Takes the motion from `from` to `to` (world-from-robot poses at their
    /// times) as the one to carry on.
    pub fn carry_on(&mut self, from: (&Pose3, f64), to: (&Pose3, f64)) {
        let dt = to.1 - from.1;
        if !(dt > 0.0) {
            return;
        }
        let relative = from.0.inverse() * to.0;
        let turn = relative.rotation.scaled_axis();
        // The constant twist that moves `from` to `to` in `dt`.
        let Some(inverse) = left_jacobian(&turn).try_inverse() else { return };
        let (rate, velocity) = (turn / dt, inverse * relative.translation.vector / dt);
        self.previous = PreviousMotion { rate, velocity, at: Some(to.1) };
    }

    /// The motion of a step: the wheels' speed and the gyro's rate where
    /// measured, the previous motion's otherwise.
    fn motion(&self, gyro: Option<Vec3>, speed: Option<f64>) -> BodyMotion {
        let (rate, is_gyro) = match gyro {
            Some(g) => (g, true),
            None => (self.previous.rate, false),
        };
        let (velocity, wheels) = match speed {
            Some(v) => (Vec3::new(v, 0.0, 0.0), true),
            None => (self.previous.velocity, false),
        };
        BodyMotion { rate, gyro: is_gyro, velocity, wheels, measured_at: self.previous.at }
    }

    /// Wheel speed at time t: an odometry sample reports the mean speed over
    /// the period that ends at its stamp, so the first sample at or after t.
    /// `None` without wheel odometry.
    fn speed_at(&self, t: f64) -> Option<f64> {
        let k = self.odometry.partition_point(|s| s.timestamp < t);
        self.odometry.get(k).or(self.odometry.last()).map(|s| s.v)
    }

    /// Advances the filter to `time`, integrating every IMU sample up to it.
    pub fn advance(&mut self, ekf: &mut Ekf, time: f64) {
        while self.next_imu < self.imu.len() && self.imu[self.next_imu].timestamp <= time {
            let sample = self.imu[self.next_imu];
            let gyro = Vec3::from(sample.gyro);
            let dt = sample.timestamp - ekf.time;
            let speed = self.speed_at(ekf.time + 0.5 * dt.max(0.0));
            ekf.predict_motion(&self.motion(Some(gyro), speed), dt);
            ekf.update_gravity(&Vec3::from(sample.accel));
            self.next_imu += 1;
        }
        if self.imu.is_empty() {
            // No gyro: step at the wheels' samples, each with its own speed.
            let first = self.odometry.partition_point(|s| s.timestamp <= ekf.time);
            let last = self.odometry.partition_point(|s| s.timestamp < time);
            for k in first..last {
                let t = self.odometry[k].timestamp;
                let speed = self.speed_at(0.5 * (ekf.time + t));
                ekf.predict_motion(&self.motion(None, speed), t - ekf.time);
            }
        }
        if time > ekf.time {
            // Hold the last rate up to the frame time.
            let last = self.next_imu.checked_sub(1).map(|k| Vec3::from(self.imu[k].gyro));
            let gyro = if self.imu.is_empty() { None } else { Some(last.unwrap_or_default()) };
            let speed = self.speed_at(if self.imu.is_empty() { 0.5 * (ekf.time + time) } else { ekf.time });
            ekf.predict_motion(&self.motion(gyro, speed), time - ekf.time);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::ekf::EkfConfig;

    fn pose(x: f64, y: f64, yaw: f64) -> Pose3 {
        Pose3::new(Vec3::new(x, y, 0.0), Vec3::new(0.0, 0.0, yaw))
    }

    #[test]
    fn without_wheels_or_imu_the_previous_motion_carries_on_exactly() {
        // A turn at constant rate and speed: two frames 0.1 s apart give the
        // motion; the third is predicted where the turn takes the robot.
        let (v, w) = (0.8, 0.6);
        let at = |t: f64| {
            let yaw = w * t;
            pose(v / w * yaw.sin(), v / w * (1.0 - yaw.cos()), yaw)
        };
        let mut replay = SensorReplay::new(&[], &[], 0.0);
        replay.carry_on((&at(0.0), 0.0), (&at(0.1), 0.1));
        let mut ekf = Ekf::new(EkfConfig::default(), &at(0.1), 0.1);
        replay.advance(&mut ekf, 0.25);
        let (predicted, truth) = (ekf.pose(), at(0.25));
        assert!((predicted.translation.vector - truth.translation.vector).norm() < 1e-9, "{predicted} vs {truth}");
        assert!(predicted.rotation.angle_to(&truth.rotation) < 1e-9);
        // Its uncertainty is that of a change of velocity held 0.15 s.
        let c = EkfConfig::default();
        let expected = c.velocity_change_mps2.powi(2) * 0.15f64.powi(4) / 4.0;
        assert!((ekf.p[(0, 0)] - 1e-8 - expected).abs() < 1e-3 * expected, "{} vs {expected}", ekf.p[(0, 0)]);
    }

    #[test]
    fn a_carried_motion_does_not_depend_on_the_steps() {
        let mut replay = SensorReplay::new(&[], &[], 0.0);
        replay.carry_on((&pose(0.0, 0.0, 0.0), 0.0), (&pose(0.1, 0.0, 0.05), 0.1));
        let mut one = Ekf::new(EkfConfig::default(), &pose(0.1, 0.0, 0.05), 0.1);
        let mut many = one.clone();
        replay.clone().advance(&mut one, 0.5);
        let mut stepping = replay.clone();
        for k in 1..=8 {
            stepping.advance(&mut many, 0.1 + 0.05 * k as f64);
        }
        assert!((one.x - many.x).norm() < 1e-12, "{} vs {}", one.x, many.x);
        // At rest, nothing couples the attitude's doubt into the position:
        // the position's variance is the held change of velocity's, however cut.
        let mut rest = SensorReplay::new(&[], &[], 0.0);
        rest.carry_on((&Pose3::identity(), 0.0), (&Pose3::identity(), 0.1));
        let mut one = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.1);
        let mut many = one.clone();
        rest.clone().advance(&mut one, 0.5);
        for k in 1..=8 {
            rest.advance(&mut many, 0.1 + 0.05 * k as f64);
        }
        let expected = 1e-8 + EkfConfig::default().velocity_change_mps2.powi(2) * 0.4f64.powi(4) / 4.0;
        for p in [one.p[(0, 0)], many.p[(0, 0)]] {
            assert!((p - expected).abs() < 1e-9 * expected, "{p} vs {expected}");
        }
    }

    #[test]
    fn wheels_without_an_imu_move_the_robot_at_their_speed() {
        let odometry: Vec<OdometrySample> = (1..=10)
            .map(|k| OdometrySample { timestamp: 0.1 * k as f64, x: 0.0, y: 0.0, yaw: 0.0, v: 0.5, omega: 0.0 })
            .collect();
        let mut replay = SensorReplay::new(&odometry, &[], 0.0);
        let mut ekf = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.0);
        replay.advance(&mut ekf, 1.0);
        assert!((ekf.x[0] - 0.5).abs() < 1e-12 && ekf.x[1].abs() < 1e-12, "{}", ekf.x);
    }
}
