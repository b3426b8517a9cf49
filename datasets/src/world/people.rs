//! People walking through a building: upright boxes that pace back and forth
//! along a line at walking speed. Camera and LIDAR see them (moving
//! occluders); they are never landmarks and the robot drives through them.

use serde::Serialize;

use crate::math::{Point3, Vec3};

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Walker {
    pub from: [f64; 2],
    pub to: [f64; 2],
    /// Floor height under the whole walk.
    pub floor_m: f64,
    pub speed_mps: f64,
    /// Where on the walk the person is at time 0, as a distance in metres.
    pub phase_m: f64,
    pub height_m: f64,
    /// Clothing colour (linear RGB).
    pub colour: [f32; 3],
}

/// Half extents of a person's box: along the walk and across it.
const HALF_ALONG_M: f64 = 0.15;
const HALF_ACROSS_M: f64 = 0.25;

impl Walker {
    /// Position and unit walking direction at `time`.
    pub fn at(&self, time: f64) -> ([f64; 2], [f64; 2]) {
        let (dx, dy) = (self.to[0] - self.from[0], self.to[1] - self.from[1]);
        let length = dx.hypot(dy).max(1e-9);
        let s = (self.phase_m + self.speed_mps * time).rem_euclid(2.0 * length);
        let (f, sign) = if s <= length { (s / length, 1.0) } else { (2.0 - s / length, -1.0) };
        ([self.from[0] + f * dx, self.from[1] + f * dy], [sign * dx / length, sign * dy / length])
    }

    /// Where a ray from `origin` along `dir` enters the person's box at
    /// `time` within `(t_min, t_max)`, and the normal of the face it meets.
    /// A ray that starts inside the box does not see it.
    pub fn intersect(&self, time: f64, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<(f64, Vec3)> {
        let (p, d) = self.at(time);
        let along = Vec3::new(d[0], d[1], 0.0);
        let across = Vec3::new(-d[1], d[0], 0.0);
        let rel = Vec3::new(origin.x - p[0], origin.y - p[1], origin.z - self.floor_m - self.height_m / 2.0);
        let axes = [along, across, Vec3::z()];
        let half = [HALF_ALONG_M, HALF_ACROSS_M, self.height_m / 2.0];
        let (mut near, mut far) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut normal = Vec3::zeros();
        for k in 0..3 {
            let (o, v) = (axes[k].dot(&rel), axes[k].dot(dir));
            if v.abs() < 1e-12 {
                if o.abs() > half[k] {
                    return None;
                }
                continue;
            }
            let (mut t0, mut t1) = ((-half[k] - o) / v, (half[k] - o) / v);
            if t0 > t1 {
                std::mem::swap(&mut t0, &mut t1);
            }
            if t0 > near {
                near = t0;
                normal = -axes[k] * v.signum();
            }
            far = far.min(t1);
        }
        (near <= far && near > t_min && near < t_max).then_some((near, normal))
    }
}
