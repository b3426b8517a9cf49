//! The filter's motion around a frame's time: where the robot was when the
//! image was taken and when each point of a sweep was measured. The camera
//! and the LIDAR keep their own clocks, and a spinning LIDAR measures its
//! points over a tenth of a second: both are placed by the odometry/IMU
//! prediction, not assumed simultaneous.

use datasets::io::formats::PointCloud;
use datasets::math::Pose3;

use crate::estimation::ekf::Ekf;
use crate::estimation::sensor_replay::SensorReplay;

/// World-from-robot poses at chosen times around `stamp`.
pub struct FrameMotion {
    stamp: f64,
    times: Vec<f64>,
    /// robot(stamp)_from_robot(times[k]).
    relative: Vec<Pose3>,
}

/// Sweep samples between the earliest and latest point time.
const SWEEP_SAMPLES: usize = 11;

impl FrameMotion {
    /// Advances `ekf` to `stamp` with `replay`, recording the pose at each
    /// of `times` on the way; times after `stamp` are predicted on copies,
    /// so the filter itself stops at `stamp`. Times before the filter's own
    /// time take its current pose.
    pub fn sample(ekf: &mut Ekf, replay: &mut SensorReplay<'_>, stamp: f64, times: &[f64]) -> Self {
        let mut times: Vec<f64> = times.iter().copied().filter(|t| t.is_finite()).collect();
        times.sort_by(f64::total_cmp);
        times.dedup();
        let mut world = Vec::with_capacity(times.len());
        for &t in times.iter().filter(|&&t| t <= stamp) {
            if t > ekf.time {
                replay.advance(ekf, t);
            }
            world.push(ekf.pose());
        }
        replay.advance(ekf, stamp);
        let at_stamp = ekf.pose();
        let (mut ahead, mut ahead_replay) = (ekf.clone(), replay.clone());
        for &t in times.iter().filter(|&&t| t > stamp) {
            ahead_replay.advance(&mut ahead, t);
            world.push(ahead.pose());
        }
        let inverse = at_stamp.inverse();
        let relative = world.iter().map(|p| inverse * p).collect();
        Self { stamp, times, relative }
    }

    /// The times to sample for a frame: the image's and a sweep's span.
    pub fn times_for(stamp: f64, image_stamp: Option<f64>, cloud: Option<&PointCloud>) -> Vec<f64> {
        let mut times: Vec<f64> = image_stamp.into_iter().collect();
        if let Some(point_times) = cloud.and_then(|c| c.times.as_ref()) {
            let lo = point_times.iter().copied().fold(f32::INFINITY, f32::min) as f64;
            let hi = point_times.iter().copied().fold(f32::NEG_INFINITY, f32::max) as f64;
            if lo.is_finite() && hi.is_finite() && hi > lo {
                times
                    .extend((0..SWEEP_SAMPLES).map(|k| stamp + lo + (hi - lo) * k as f64 / (SWEEP_SAMPLES - 1) as f64));
            }
        }
        times
    }

    /// robot(stamp)_from_robot(t), interpolated between the samples (held
    /// constant outside them; the identity without samples).
    pub fn relative(&self, t: f64) -> Pose3 {
        if t == self.stamp || self.times.is_empty() {
            return Pose3::identity();
        }
        let k = self.times.partition_point(|&s| s < t);
        if k == 0 {
            return self.relative[0];
        }
        if k == self.times.len() {
            return self.relative[k - 1];
        }
        let (t0, t1) = (self.times[k - 1], self.times[k]);
        let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
        let (p0, p1) = (&self.relative[k - 1], &self.relative[k]);
        let translation = p0.translation.vector.lerp(&p1.translation.vector, a);
        let rotation = p0.rotation.slerp(&p1.rotation, a);
        Pose3::from_parts(translation.into(), rotation)
    }

    /// Moves every point of a sweep to where the LIDAR saw it from at
    /// `stamp`: p' = lidar(stamp)_from_lidar(t) p. Clouds without
    /// per-point times are left as they are.
    pub fn deskew(&self, cloud: &mut PointCloud, robot_from_lidar: &Pose3) {
        let Some(times) = cloud.times.as_ref() else { return };
        let lidar_from_robot = robot_from_lidar.inverse();
        // Points come in sweep order: one pose per 0.1 ms bin moves a point
        // by well under a millimetre at 1.5 m/s and 1 rad/s within 5 m.
        let mut cached: Option<(i64, nalgebra::Isometry3<f32>)> = None;
        for (p, &dt) in cloud.points.iter_mut().zip(times) {
            let bin = (dt as f64 * 1e4).round() as i64;
            let transform = match cached {
                Some((b, t)) if b == bin => t,
                _ => {
                    let t = self.stamp + bin as f64 * 1e-4;
                    let m: nalgebra::Isometry3<f32> = (lidar_from_robot * self.relative(t) * robot_from_lidar).cast();
                    cached = Some((bin, m));
                    m
                }
            };
            *p = transform * *p;
        }
    }
}

#[cfg(test)]
mod tests {
    use datasets::io::formats::{ImuSample, OdometrySample};
    use datasets::math::Vec3;

    use super::*;
    use crate::estimation::ekf::EkfConfig;

    /// A robot driving straight along x at 1 m/s, level.
    fn logs() -> (Vec<OdometrySample>, Vec<ImuSample>) {
        let odometry = (0..100)
            .map(|k| OdometrySample {
                timestamp: k as f64 * 0.02,
                x: k as f64 * 0.02,
                y: 0.0,
                yaw: 0.0,
                v: 1.0,
                omega: 0.0,
            })
            .collect();
        let imu = (0..400)
            .map(|k| ImuSample { timestamp: k as f64 * 0.005, accel: [0.0, 0.0, 9.80665], gyro: [0.0; 3] })
            .collect();
        (odometry, imu)
    }

    #[test]
    fn the_camera_later_than_the_scan_is_ahead_by_the_distance_driven() {
        let (odometry, imu) = logs();
        let mut ekf = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.0);
        let mut replay = SensorReplay::new(&odometry, &imu, 0.0);
        let motion = FrameMotion::sample(&mut ekf, &mut replay, 1.0, &[0.97, 1.03]);
        assert_eq!(ekf.time, 1.0, "the filter stops at the scan");
        assert!((ekf.pose().translation.vector.x - 1.0).abs() < 1e-9);
        assert!((motion.relative(1.03).translation.vector - Vec3::new(0.03, 0.0, 0.0)).norm() < 1e-9);
        assert!((motion.relative(0.97).translation.vector - Vec3::new(-0.03, 0.0, 0.0)).norm() < 1e-9);
        assert!((motion.relative(1.0).translation.vector).norm() == 0.0);
        // Halfway between samples: interpolated.
        assert!((motion.relative(1.015).translation.vector.x - 0.015).abs() < 1e-9);
    }

    #[test]
    fn deskewing_puts_a_sweep_of_one_wall_back_on_one_plane() {
        let (odometry, imu) = logs();
        let mut ekf = Ekf::new(EkfConfig::default(), &Pose3::identity(), 0.0);
        let mut replay = SensorReplay::new(&odometry, &imu, 0.0);
        // A wall at x = 5 m (in the robot frame at the stamp), measured over
        // 0.1 s while the robot drives towards it: a point at time dt is seen
        // (5 - dt) m ahead. The LIDAR sits 0.2 m up on the robot.
        let robot_from_lidar = Pose3::translation(0.0, 0.0, 0.2);
        let times: Vec<f32> = (0..100).map(|k| k as f32 * 0.001).collect();
        let points = times.iter().map(|&dt| nalgebra::Point3::new(5.0 - dt, (dt * 40.0).sin(), 0.1)).collect();
        let mut cloud = PointCloud::new(points, None);
        cloud.times = Some(times.clone());
        let stamp = 1.0;
        let motion =
            FrameMotion::sample(&mut ekf, &mut replay, stamp, &FrameMotion::times_for(stamp, None, Some(&cloud)));
        motion.deskew(&mut cloud, &robot_from_lidar);
        for (p, dt) in cloud.points.iter().zip(&times) {
            assert!((p.x - 5.0).abs() < 2e-4, "point at {dt}: x {}", p.x);
            assert!((p.z - 0.1).abs() < 1e-6);
        }
    }
}
