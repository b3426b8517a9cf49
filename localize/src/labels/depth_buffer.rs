//! The nearest mapped surface along each camera ray: the point map's points
//! rendered as small discs in their surface's plane (surfels) into a coarse
//! depth image. A point behind the surface drawn at its pixel is hidden from
//! the camera. The discs lie in their planes, not facing the camera, so that
//! a floor seen at a grazing angle does not cover the corner it runs into.

use datasets::camera::PinholeCamera;
use datasets::math::Pose3;

use crate::estimation::point_map::MapPoint;

pub struct DepthBuffer {
    /// Image pixels per buffer cell (each way).
    cell_px: f64,
    columns: usize,
    rows: usize,
    /// Depth along the optical axis of the nearest surface, per cell (infinite: none).
    depth: Vec<f32>,
}

impl DepthBuffer {
    /// The surfaces of `points` seen by `camera` at `camera_from_world`, up
    /// to `max_depth_m`; each point covers a disc of radius `splat_m` in the
    /// plane through it across its normal.
    pub fn render(
        points: &[MapPoint],
        camera: &PinholeCamera,
        camera_from_world: &Pose3,
        cell_px: u32,
        splat_m: f64,
        max_depth_m: f64,
    ) -> Self {
        let cell = f64::from(cell_px.max(1));
        let columns = (f64::from(camera.width) / cell).ceil() as usize;
        let rows = (f64::from(camera.height) / cell).ceil() as usize;
        let mut depth = vec![f32::INFINITY; columns * rows];
        let focal = 0.5 * (camera.fx + camera.fy);
        let rotation = camera_from_world.rotation;
        for p in points {
            let q = camera_from_world * nalgebra::Point3::from(p.position);
            if q.z < 0.05 || q.z > max_depth_m {
                continue;
            }
            let normal = rotation * p.normal;
            // Pixel coordinates as `PinholeCamera::project` gives them (pixel centres at k + 0.5).
            let u = camera.fx * q.x / q.z + camera.cx + 0.5;
            let v = camera.fy * q.y / q.z + camera.cy + 0.5;
            // The disc spans at most f * splat / z pixels (facing the camera),
            // a little more off the axis; at least its own cell.
            let radius = (1.2 * focal * splat_m / q.z / cell).clamp(0.5, 16.0);
            let (cu, cv) = (u / cell, v / cell);
            if cu + radius < 0.0 || cv + radius < 0.0 || cu - radius > columns as f64 || cv - radius > rows as f64 {
                continue;
            }
            let (c0, c1) = ((cu - radius).floor().max(0.0) as usize, ((cu + radius).ceil() as usize).min(columns));
            let (r0, r1) = ((cv - radius).floor().max(0.0) as usize, ((cv + radius).ceil() as usize).min(rows));
            let offset = normal.dot(&q.coords);
            for r in r0..r1 {
                for c in c0..c1 {
                    // The cell's ray (depth 1) meets the disc's plane at depth t.
                    let ray = nalgebra::Vector3::new(
                        ((c as f64 + 0.5) * cell - 0.5 - camera.cx) / camera.fx,
                        ((r as f64 + 0.5) * cell - 0.5 - camera.cy) / camera.fy,
                        1.0,
                    );
                    let along = normal.dot(&ray);
                    if along.abs() < 1e-6 {
                        continue;
                    }
                    let t = offset / along;
                    if t <= 0.0 || (ray * t - q.coords).norm_squared() > splat_m * splat_m {
                        continue;
                    }
                    let d = &mut depth[r * columns + c];
                    *d = d.min(t as f32);
                }
            }
        }
        Self { cell_px: cell, columns, rows, depth }
    }

    /// The nearest surface's depth at pixel `uv` (infinite where nothing was drawn).
    pub fn at(&self, uv: [f64; 2]) -> f64 {
        let (c, r) = ((uv[0] / self.cell_px).floor(), (uv[1] / self.cell_px).floor());
        if c < 0.0 || r < 0.0 || c as usize >= self.columns || r as usize >= self.rows {
            return f64::INFINITY;
        }
        f64::from(self.depth[r as usize * self.columns + c as usize])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use datasets::math::Vec3;

    fn camera() -> PinholeCamera {
        PinholeCamera { width: 640, height: 480, fx: 500.0, fy: 500.0, cx: 319.5, cy: 239.5 }
    }

    /// A wall facing the camera at `z`, spanning x and y in [-half, half], points every 5 cm.
    fn wall(z: f64, half: f64) -> Vec<MapPoint> {
        let n = (2.0 * half / 0.05) as i32;
        let mut points = Vec::new();
        for i in 0..=n {
            for j in 0..=n {
                let (x, y) = (-half + 0.05 * i as f64, -half + 0.05 * j as f64);
                points.push(MapPoint { position: Vec3::new(x, y, z), normal: -Vec3::z() });
            }
        }
        points
    }

    #[test]
    fn a_wall_in_front_hides_what_lies_behind_it_and_nothing_else() {
        // Camera at the origin looking along +z; a 1 m wide wall 2 m away, a wider one at 5 m.
        let mut points = wall(2.0, 0.5);
        points.extend(wall(5.0, 3.0));
        let buffer = DepthBuffer::render(&points, &camera(), &Pose3::identity(), 4, 0.05, 10.0);
        let centre = [319.5, 239.5];
        assert!((buffer.at(centre) - 2.0).abs() < 1e-6, "{}", buffer.at(centre));
        // 1.5 m right of the axis at 5 m: u = 469.5, beyond the near wall's edge (u = 444.5, 12.5 px of disc).
        let beside = [319.5 + 500.0 * 1.5 / 5.0, 239.5];
        assert!((buffer.at(beside) - 5.0).abs() < 1e-6, "{}", buffer.at(beside));
        // Left of the far wall (x = -3.18 m at 5 m): nothing mapped.
        assert!(buffer.at([2.0, 239.5]).is_infinite());
        assert!(buffer.at([-3.0, 10.0]).is_infinite() && buffer.at([700.0, 10.0]).is_infinite());
    }

    #[test]
    fn a_floor_seen_at_a_grazing_angle_does_not_cover_the_corner_it_runs_into() {
        // Camera 0.5 m above a floor (y down in the camera: the floor is y = 0.5),
        // looking along it; a corner on the floor 4 m ahead.
        let floor: Vec<MapPoint> = (0..=80)
            .flat_map(|i| (-10..=10).map(move |j| (i, j)))
            .map(|(i, j)| MapPoint { position: Vec3::new(0.05 * j as f64, 0.5, 0.05 * i as f64), normal: -Vec3::y() })
            .collect();
        let buffer = DepthBuffer::render(&floor, &camera(), &Pose3::identity(), 4, 0.1, 10.0);
        let corner = camera().project(&nalgebra::Point3::new(0.0, 0.5, 4.0)).unwrap();
        // The floor's depth at the corner's pixel is the corner's (within a cell's height of floor).
        assert!((buffer.at(corner) - 4.0).abs() < 0.3, "{}", buffer.at(corner));
        // Half way down the image from the horizon the floor is 2 m away... at v = 239.5 + 500 * 0.5 / 2.
        assert!((buffer.at([319.5, 239.5 + 125.0]) - 2.0).abs() < 0.05, "{}", buffer.at([319.5, 364.5]));
    }

    #[test]
    fn the_camera_pose_moves_the_surfaces() {
        // The same wall seen from 1 m closer, turned 180 degrees about y, is behind the camera.
        let points = wall(2.0, 0.5);
        let closer = Pose3::from_parts(Vec3::new(0.0, 0.0, -1.0).into(), nalgebra::UnitQuaternion::identity());
        let buffer = DepthBuffer::render(&points, &camera(), &closer, 4, 0.05, 10.0);
        assert!((buffer.at([319.5, 239.5]) - 1.0).abs() < 1e-6);
        let turned = Pose3::from_parts(
            Vec3::zeros().into(),
            nalgebra::UnitQuaternion::from_axis_angle(&Vec3::y_axis(), std::f64::consts::PI),
        );
        let behind = DepthBuffer::render(&points, &camera(), &turned, 4, 0.05, 10.0);
        assert!(behind.at([319.5, 239.5]).is_infinite());
    }
}
