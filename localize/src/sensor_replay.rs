//! Replaying the wheel odometry and IMU logs into the filter: every IMU
//! sample up to a frame's time is a prediction (with the wheel speed of that
//! moment) and a gravity update.

use datasets::formats::{ImuSample, OdometrySample};
use datasets::math::Vec3;

use crate::ekf::Ekf;

/// Drives an EKF through the odometry and IMU logs, one frame time at a time.
#[derive(Clone)]
pub struct SensorReplay<'a> {
    odometry: &'a [OdometrySample],
    imu: &'a [ImuSample],
    next_imu: usize,
}

impl<'a> SensorReplay<'a> {
    /// Replays the logs from `start` on (earlier samples are skipped).
    pub fn new(odometry: &'a [OdometrySample], imu: &'a [ImuSample], start: f64) -> Self {
        let next_imu = imu.partition_point(|s| s.timestamp <= start);
        Self { odometry, imu, next_imu }
    }

    /// Wheel speed at time t: an odometry sample reports the mean speed over
    /// the period that ends at its stamp, so the first sample at or after t.
    fn speed_at(&self, t: f64) -> f64 {
        let k = self.odometry.partition_point(|s| s.timestamp < t);
        self.odometry.get(k).or(self.odometry.last()).map_or(0.0, |s| s.v)
    }

    /// Advances the filter to `time`, integrating every IMU sample up to it.
    pub fn advance(&mut self, ekf: &mut Ekf, time: f64) {
        while self.next_imu < self.imu.len() && self.imu[self.next_imu].timestamp <= time {
            let sample = self.imu[self.next_imu];
            let gyro = Vec3::from(sample.gyro);
            let dt = sample.timestamp - ekf.time;
            let speed = self.speed_at(ekf.time + 0.5 * dt.max(0.0));
            ekf.predict(&gyro, speed, dt);
            ekf.update_gravity(&Vec3::from(sample.accel));
            self.next_imu += 1;
        }
        if time > ekf.time {
            // Hold the last rate up to the frame time.
            let last = self.next_imu.checked_sub(1).map(|k| Vec3::from(self.imu[k].gyro)).unwrap_or_default();
            let speed = self.speed_at(ekf.time);
            ekf.predict(&last, speed, time - ekf.time);
        }
    }
}
