//! People walking through a building: rounded upright figures that pace back and forth
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

/// A person's body is an upright elliptic cylinder from the floor to the
/// shoulders (semi-axes along and across the walk), with a sphere for a head:
/// rounded, so that no person shows a crate's straight edges and corners in
/// the edge image, which would teach the detector that box corners are
/// background.
const HALF_ALONG_M: f64 = 0.15;
const HALF_ACROSS_M: f64 = 0.25;
const HEAD_RADIUS_M: f64 = 0.11;

impl Walker {
    /// Position and unit walking direction at `time`.
    pub fn at(&self, time: f64) -> ([f64; 2], [f64; 2]) {
        let (dx, dy) = (self.to[0] - self.from[0], self.to[1] - self.from[1]);
        let length = dx.hypot(dy).max(1e-9);
        let s = (self.phase_m + self.speed_mps * time).rem_euclid(2.0 * length);
        let (f, sign) = if s <= length { (s / length, 1.0) } else { (2.0 - s / length, -1.0) };
        ([self.from[0] + f * dx, self.from[1] + f * dy], [sign * dx / length, sign * dy / length])
    }

    /// Where a ray from `origin` along `dir` enters the person (body or head)
    /// at `time` within `(t_min, t_max)`, and the outward normal there. A ray
    /// that starts inside the person does not see it.
    pub fn intersect(&self, time: f64, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<(f64, Vec3)> {
        let (p, d) = self.at(time);
        let along = Vec3::new(d[0], d[1], 0.0);
        let across = Vec3::new(-d[1], d[0], 0.0);
        // In the person's frame: origin on the floor under the body's axis.
        let rel = Vec3::new(origin.x - p[0], origin.y - p[1], origin.z - self.floor_m);
        let local_origin = Vec3::new(along.dot(&rel), across.dot(&rel), rel.z);
        let local_dir = Vec3::new(along.dot(dir), across.dot(dir), dir.z);
        let shoulders = self.height_m - 2.0 * HEAD_RADIUS_M;
        let body = body_entry(&local_origin, &local_dir, shoulders);
        let head = sphere_entry(&(local_origin - Vec3::new(0.0, 0.0, self.height_m - HEAD_RADIUS_M)), &local_dir);
        let (t, n) = [body, head]
            .into_iter()
            .flatten()
            .filter(|(t, _)| *t > t_min && *t < t_max)
            .min_by(|a, b| a.0.total_cmp(&b.0))?;
        Some((t, (along * n.x + across * n.y + Vec3::z() * n.z).normalize()))
    }
}

/// Entry of a ray into the elliptic cylinder `(x/a)^2 + (y/b)^2 <= 1`,
/// `0 <= z <= top` (person frame), with the outward normal; `None` if the
/// ray misses it or starts inside it.
fn body_entry(origin: &Vec3, dir: &Vec3, top: f64) -> Option<(f64, Vec3)> {
    let (a, b) = (HALF_ALONG_M, HALF_ACROSS_M);
    // The cylinder in coordinates scaled to the unit circle.
    let (ox, oy, dx, dy) = (origin.x / a, origin.y / b, dir.x / a, dir.y / b);
    let qa = dx * dx + dy * dy;
    let qb = 2.0 * (ox * dx + oy * dy);
    let qc = ox * ox + oy * oy - 1.0;
    let (mut near, mut far, mut normal) = if qa < 1e-18 {
        // Parallel to the axis: inside the ellipse for every t, or never.
        if qc > 0.0 {
            return None;
        }
        (f64::NEG_INFINITY, f64::INFINITY, Vec3::zeros())
    } else {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        let (t0, t1) = ((-qb - root) / (2.0 * qa), (-qb + root) / (2.0 * qa));
        let hit = origin + dir * t0;
        (t0, t1, Vec3::new(hit.x / (a * a), hit.y / (b * b), 0.0))
    };
    if dir.z.abs() < 1e-12 {
        if origin.z < 0.0 || origin.z > top {
            return None;
        }
    } else {
        let (mut z0, mut z1) = (-origin.z / dir.z, (top - origin.z) / dir.z);
        if z0 > z1 {
            std::mem::swap(&mut z0, &mut z1);
        }
        if z0 > near {
            near = z0;
            normal = Vec3::new(0.0, 0.0, -dir.z.signum());
        }
        far = far.min(z1);
    }
    (near <= far && near >= 0.0).then_some((near, normal))
}

/// Entry of a ray into the sphere of radius `HEAD_RADIUS_M` around the
/// origin of `origin`'s frame, with the outward normal.
fn sphere_entry(origin: &Vec3, dir: &Vec3) -> Option<(f64, Vec3)> {
    let qa = dir.norm_squared();
    let qb = 2.0 * origin.dot(dir);
    let qc = origin.norm_squared() - HEAD_RADIUS_M * HEAD_RADIUS_M;
    let disc = qb * qb - 4.0 * qa * qc;
    if qa < 1e-18 || disc < 0.0 || qc < 0.0 {
        return None;
    }
    let t = (-qb - disc.sqrt()) / (2.0 * qa);
    (t >= 0.0).then(|| (t, origin + dir * t))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walker() -> Walker {
        // Standing at (2, 0) at time 0, walking along +x.
        Walker {
            from: [0.0, 0.0],
            to: [10.0, 0.0],
            floor_m: 1.0,
            speed_mps: 1.0,
            phase_m: 2.0,
            height_m: 1.8,
            colour: [0.5; 3],
        }
    }

    #[test]
    fn a_ray_along_the_walk_meets_the_back_of_the_body() {
        let origin = Point3::new(0.0, 0.0, 2.0);
        let (t, normal) = walker().intersect(0.0, &origin, &Vec3::x(), 0.0, 100.0).unwrap();
        assert!((t - (2.0 - HALF_ALONG_M)).abs() < 1e-12, "t = {t}");
        assert!((normal - -Vec3::x()).norm() < 1e-12, "normal = {normal}");
    }

    #[test]
    fn a_ray_across_the_walk_meets_the_wider_side() {
        let origin = Point3::new(2.0, -5.0, 1.5);
        let (t, normal) = walker().intersect(0.0, &origin, &Vec3::y(), 0.0, 100.0).unwrap();
        assert!((t - (5.0 - HALF_ACROSS_M)).abs() < 1e-12, "t = {t}");
        assert!((normal - -Vec3::y()).norm() < 1e-12, "normal = {normal}");
    }

    #[test]
    fn the_body_is_round_where_a_box_would_have_a_corner() {
        // The line x + y = 0.38 (person frame) cuts the corner of the
        // body's bounding box (a + b = 0.40) but passes the ellipse, whose
        // largest x + y is sqrt(a^2 + b^2) = 0.29.
        let origin = Point3::new(2.0 + 0.38 + 1.0, -1.0, 1.5);
        let dir = Vec3::new(-1.0, 1.0, 0.0).normalize();
        assert!(walker().intersect(0.0, &origin, &dir, 0.0, 100.0).is_none());
        // Halfway out, the ellipse is at x = a * sqrt(1 - 1/4).
        let origin = Point3::new(5.0, HALF_ACROSS_M / 2.0, 1.5);
        let (t, normal) = walker().intersect(0.0, &origin, &-Vec3::x(), 0.0, 100.0).unwrap();
        let x = HALF_ALONG_M * 0.75f64.sqrt();
        assert!((t - (3.0 - x)).abs() < 1e-12, "t = {t}");
        let expected = Vec3::new(x / HALF_ALONG_M.powi(2), 0.5 / HALF_ACROSS_M, 0.0).normalize();
        assert!((normal - expected).norm() < 1e-12, "normal = {normal}");
    }

    #[test]
    fn a_ray_from_above_meets_the_top_of_the_head() {
        let origin = Point3::new(2.0, 0.0, 5.0);
        let (t, normal) = walker().intersect(0.0, &origin, &-Vec3::z(), 0.0, 100.0).unwrap();
        assert!((t - (5.0 - 2.8)).abs() < 1e-12, "t = {t}");
        assert!((normal - Vec3::z()).norm() < 1e-12, "normal = {normal}");
        // Beside the head, above the shoulders: the flat top of the body.
        let origin = Point3::new(2.0, 0.2, 5.0);
        let (t, normal) = walker().intersect(0.0, &origin, &-Vec3::z(), 0.0, 100.0).unwrap();
        assert!((t - (5.0 - (1.0 + 1.8 - 2.0 * HEAD_RADIUS_M))).abs() < 1e-12, "t = {t}");
        assert!((normal - Vec3::z()).norm() < 1e-12, "normal = {normal}");
    }

    #[test]
    fn rays_that_miss_start_inside_or_stop_short_see_nothing() {
        let w = walker();
        // Passes over the head.
        assert!(w.intersect(0.0, &Point3::new(0.0, 0.0, 2.9), &Vec3::x(), 0.0, 100.0).is_none());
        // Starts inside the body.
        assert!(w.intersect(0.0, &Point3::new(2.0, 0.0, 1.5), &Vec3::x(), 0.0, 100.0).is_none());
        // Stops before it.
        assert!(w.intersect(0.0, &Point3::new(0.0, 0.0, 2.0), &Vec3::x(), 0.0, 1.0).is_none());
        // At time 3 the person has walked on to x = 5.
        let (t, _) = w.intersect(3.0, &Point3::new(0.0, 0.0, 2.0), &Vec3::x(), 0.0, 100.0).unwrap();
        assert!((t - (5.0 - HALF_ALONG_M)).abs() < 1e-12, "t = {t}");
    }
}
