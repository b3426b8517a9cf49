//! The robot's route (a polyline with rounded corners) and its pose on the
//! floor: the base sits on the floor with its pitch and roll given by the
//! floor heights under its wheels, so ramps tilt it smoothly.

use super::layout::Layout;
use crate::math::{Mat3, Point3, Pose3, Rot3, Vec3};

#[derive(Debug, Clone, Copy)]
enum Piece {
    Line { from: [f64; 2], to: [f64; 2] },
    Arc { centre: [f64; 2], radius: f64, start: f64, sweep: f64 },
}

impl Piece {
    fn length(&self) -> f64 {
        match *self {
            Self::Line { from, to } => (to[0] - from[0]).hypot(to[1] - from[1]),
            Self::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }
    /// Position and heading at distance `s` along the piece.
    fn at(&self, s: f64) -> ([f64; 2], f64) {
        match *self {
            Self::Line { from, to } => {
                let len = self.length().max(1e-12);
                let f = s / len;
                let heading = (to[1] - from[1]).atan2(to[0] - from[0]);
                ([from[0] + f * (to[0] - from[0]), from[1] + f * (to[1] - from[1])], heading)
            }
            Self::Arc { centre, radius, start, sweep } => {
                let a = start + sweep.signum() * s / radius;
                let p = [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()];
                (p, a + sweep.signum() * std::f64::consts::FRAC_PI_2)
            }
        }
    }
}

/// A planar path with constant-radius turns.
#[derive(Debug, Clone)]
pub struct Route {
    pieces: Vec<Piece>,
    length: f64,
}

impl Route {
    /// Joins `waypoints` by straight lines, rounding each inner waypoint with
    /// an arc of `radius_m` (shrunk where the legs are too short).
    pub fn new(waypoints: &[[f64; 2]], radius_m: f64) -> Self {
        assert!(waypoints.len() >= 2, "a route needs two waypoints");
        let mut pieces = Vec::new();
        let mut cursor = waypoints[0];
        for i in 1..waypoints.len() - 1 {
            let (a, b, c) = (waypoints[i - 1], waypoints[i], waypoints[i + 1]);
            let d1 = normalize([b[0] - a[0], b[1] - a[1]]);
            let d2 = normalize([c[0] - b[0], c[1] - b[1]]);
            let turn = (d1[0] * d2[1] - d1[1] * d2[0]).atan2(d1[0] * d2[0] + d1[1] * d2[1]);
            if turn.abs() < 1e-9 {
                continue;
            }
            let leg = ((b[0] - a[0]).hypot(b[1] - a[1])).min((c[0] - b[0]).hypot(c[1] - b[1])) * 0.5;
            let mut r = radius_m;
            let mut cut = r * (turn.abs() / 2.0).tan();
            if cut > leg {
                cut = leg;
                r = cut / (turn.abs() / 2.0).tan();
            }
            let enter = [b[0] - d1[0] * cut, b[1] - d1[1] * cut];
            pieces.push(Piece::Line { from: cursor, to: enter });
            // The centre is to the left of the first leg for a left turn.
            let side = turn.signum();
            let normal = [-d1[1] * side, d1[0] * side];
            let centre = [enter[0] + normal[0] * r, enter[1] + normal[1] * r];
            let start = (enter[1] - centre[1]).atan2(enter[0] - centre[0]);
            pieces.push(Piece::Arc { centre, radius: r, start, sweep: turn });
            cursor = [b[0] + d2[0] * cut, b[1] + d2[1] * cut];
        }
        pieces.push(Piece::Line { from: cursor, to: *waypoints.last().expect("two waypoints") });
        let length = pieces.iter().map(Piece::length).sum();
        Self { pieces, length }
    }

    pub fn length(&self) -> f64 {
        self.length
    }

    /// Planar position and heading at arc length `s` (clamped to the route).
    pub fn at(&self, s: f64) -> ([f64; 2], f64) {
        let mut s = s.clamp(0.0, self.length);
        for piece in &self.pieces {
            let len = piece.length();
            if s <= len {
                return piece.at(s);
            }
            s -= len;
        }
        let last = self.pieces.last().expect("a route has pieces");
        last.at(last.length())
    }
}

fn normalize(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]).max(1e-12);
    [v[0] / n, v[1] / n]
}

/// Wheel geometry used to settle the base on the floor.
pub const WHEELBASE_M: f64 = 0.35;
pub const TRACK_M: f64 = 0.30;

/// The pose of the robot base (`world_from_robot`) at planar position `xy`
/// with `heading`: on the floor, pitched and rolled by the floor under its
/// wheels. `None` where a wheel would be outside the free space.
pub fn pose_on_floor(layout: &Layout, xy: [f64; 2], heading: f64) -> Option<Pose3> {
    let (c, s) = (heading.cos(), heading.sin());
    let at = |forward: f64, left: f64| {
        let (x, y) = (xy[0] + c * forward - s * left, xy[1] + s * forward + c * left);
        layout.floor_height(x, y)
    };
    let front = at(WHEELBASE_M / 2.0, 0.0)?;
    let rear = at(-WHEELBASE_M / 2.0, 0.0)?;
    let left = at(0.0, TRACK_M / 2.0)?;
    let right = at(0.0, -TRACK_M / 2.0)?;
    let forward = Vec3::new(c * WHEELBASE_M, s * WHEELBASE_M, front - rear).normalize();
    let leftward = Vec3::new(-s * TRACK_M, c * TRACK_M, left - right);
    let up = forward.cross(&leftward).normalize();
    let leftward = up.cross(&forward);
    let rotation = Rot3::from_matrix(&Mat3::from_columns(&[forward, leftward, up]));
    let z = (front + rear) / 2.0;
    Some(Pose3::from_parts(Point3::new(xy[0], xy[1], z).into(), rotation))
}

/// Points along `route` every `step_m` (position and heading), or the
/// first point where a wheel would leave the free space.
pub fn samples_on_floor(layout: &Layout, route: &Route, step_m: f64) -> Result<Vec<([f64; 2], f64)>, [f64; 2]> {
    let steps = (route.length() / step_m).ceil() as usize;
    (0..=steps)
        .map(|k| {
            let (xy, heading) = route.at(k as f64 * step_m);
            pose_on_floor(layout, xy, heading).map(|_| (xy, heading)).ok_or(xy)
        })
        .collect()
}
