//! The map a run built, written for other tools and for a later run:
//! `map.ply` (the point map with its normals, grey, then the corner
//! landmarks, red; binary PLY as CloudCompare and Open3D read it) and
//! `map.json` (corner and wall landmarks with everything that makes them
//! trusted, the point count, the keyframes a later run is placed from, and
//! where the map's frame lies in the ground truth's when the run had one).
//! World frame: the robot at the first scan, as in `trajectory.txt` (or the
//! frame of the map the run started from). `read_map` takes both back for
//! `localize run --map`.

use std::io::Write as _;
use std::path::Path;

use datasets::DataError;
use datasets::math::{Pose3, Vec3};
use serde::{Deserialize, Serialize};

use crate::estimation::landmarks::Landmark;
use crate::estimation::plane_landmarks::PlaneLandmark;
use crate::estimation::point_map::MapPoint;

/// The version `map.json` says it is; version 1 had no keyframes and no
/// ground-truth origin, and is still read.
const FORMAT: &str = "corner-fusion map 2";
const FORMAT_1: &str = "corner-fusion map 1";

/// A pose as `map.json` writes it: x y z qx qy qz qw (TUM's order).
pub type PoseArray = [f64; 7];

/// What `map.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapFile {
    pub format: String,
    pub frame: String,
    pub corners: Vec<Landmark>,
    /// Walls: the points p with normal . p = distance.
    pub walls: Vec<PlaneLandmark>,
    /// The building's axis (degrees, modulo 90): walls near it are squared
    /// with it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wall_axis_deg: Option<f64>,
    /// The first this many vertices of `map.ply` are the point map's.
    pub points: usize,
    /// Robot poses along the mapping run (every metre and on turns): where
    /// a later sequence's start is searched for.
    #[serde(default)]
    pub keyframes: Vec<PoseArray>,
    /// The map's frame in the ground truth's frame, when the mapping run
    /// had ground truth: only for scoring later runs in this map.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth_origin: Option<PoseArray>,
}

/// A map read back (or about to be written).
#[derive(Debug, Clone, PartialEq)]
pub struct SavedMap {
    pub corners: Vec<Landmark>,
    pub walls: Vec<PlaneLandmark>,
    /// Radians.
    pub wall_axis: Option<f64>,
    pub points: Vec<MapPoint>,
    pub keyframes: Vec<Pose3>,
    pub truth_origin: Option<Pose3>,
}

pub fn pose_array(pose: &Pose3) -> PoseArray {
    let (t, q) = (pose.translation.vector, pose.rotation.coords);
    [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
}

/// The pose of an array; `None` unless finite with a unit quaternion (1e-6).
pub fn pose_from_array(a: &PoseArray) -> Option<Pose3> {
    let q = nalgebra::Quaternion::new(a[6], a[3], a[4], a[5]);
    if !a.iter().all(|v| v.is_finite()) || (q.norm() - 1.0).abs() > 1e-6 {
        return None;
    }
    Some(Pose3::from_parts(Vec3::new(a[0], a[1], a[2]).into(), nalgebra::UnitQuaternion::new_normalize(q)))
}

const GREY: [u8; 3] = [160, 160, 160];
const RED: [u8; 3] = [230, 30, 30];

fn ply_header(count: usize) -> String {
    format!(
        "ply\nformat binary_little_endian 1.0\ncomment corner-fusion map: surface points grey, corner landmarks red\n\
         element vertex {count}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
}

/// Bytes per vertex: six floats and three colour bytes.
const VERTEX_BYTES: usize = 6 * 4 + 3;

/// The PLY bytes: `x y z nx ny nz` as float, `red green blue` as uchar;
/// corners carry a zero normal.
pub fn map_ply(points: &[MapPoint], corners: &[Landmark]) -> Vec<u8> {
    let mut out = Vec::new();
    let _ = write!(out, "{}", ply_header(points.len() + corners.len()));
    let mut vertex = |p: [f64; 3], n: [f64; 3], colour: [u8; 3]| {
        for v in p.iter().chain(&n) {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
        out.extend_from_slice(&colour);
    };
    for p in points {
        vertex(p.position.into(), p.normal.into(), GREY);
    }
    for c in corners {
        vertex(c.position.into(), [0.0; 3], RED);
    }
    out
}

/// Writes `map.ply` and `map.json` into `dir`.
pub fn write_map(dir: &Path, map: &SavedMap) -> datasets::Result<()> {
    datasets::atomic::write_bytes(&dir.join("map.ply"), &map_ply(&map.points, &map.corners))?;
    let file = MapFile {
        format: FORMAT.into(),
        frame: "world = the robot's pose at the first scan (as trajectory.txt)".into(),
        corners: map.corners.clone(),
        walls: map.walls.clone(),
        wall_axis_deg: map.wall_axis.map(f64::to_degrees),
        points: map.points.len(),
        keyframes: map.keyframes.iter().map(pose_array).collect(),
        truth_origin: map.truth_origin.as_ref().map(pose_array),
    };
    datasets::atomic::write_json(&dir.join("map.json"), &file)
}

/// The most keyframes a map may hold (a route of several kilometres).
pub const MAX_KEYFRAMES: usize = 5000;
/// Farthest a map's poses, corners and walls may lie from its origin: a
/// building's map is not a continent's.
pub const MAX_COORDINATE_M: f64 = 1e6;

/// Reads the map `localize run` wrote into `dir` (`map.json` and
/// `map.ply`); any other file, a torn one, or one whose numbers are not
/// finite is an error naming it.
pub fn read_map(dir: &Path) -> datasets::Result<SavedMap> {
    let json_path = dir.join("map.json");
    let text = datasets::atomic::read_text(&json_path)?;
    let file: MapFile = serde_json::from_str(&text)
        .map_err(|e| DataError::invalid(&json_path, format!("not a map written by `localize run`: {e}")))?;
    if file.format != FORMAT && file.format != FORMAT_1 {
        return Err(DataError::invalid(&json_path, format!("format `{}`, expected `{FORMAT}`", file.format)));
    }
    // Each keyframe is a start the placement tries: beyond this the search takes minutes.
    if file.keyframes.len() > MAX_KEYFRAMES {
        return Err(DataError::invalid(
            &json_path,
            format!("{} keyframes, more than the {MAX_KEYFRAMES} a map may hold", file.keyframes.len()),
        ));
    }
    let within = |v: &Vec3| v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE_M);
    let (keyframes, truth_origin) = map_poses(&json_path, &file)?;
    if let Some(k) = file.corners.iter().position(|c| !within(&c.position) || !c.is_valid()) {
        return Err(DataError::invalid(
            &json_path,
            format!(
                "corner {k} is not a position within {MAX_COORDINATE_M} m with finite sums and 1 to `observations` \
                 observations used"
            ),
        ));
    }
    if let Some(k) = file.walls.iter().position(|w| !w.is_valid()) {
        return Err(DataError::invalid(&json_path, format!("wall {k} has a non-finite plane or no weight")));
    }
    let unit = |w: &crate::estimation::plane_landmarks::PlaneLandmark| {
        (w.normal.norm() - 1.0).abs() <= 1e-3 && w.distance.abs() <= MAX_COORDINATE_M
    };
    if let Some(k) = file.walls.iter().position(|w| !unit(w)) {
        return Err(DataError::invalid(
            &json_path,
            format!("wall {k} has no unit normal, or lies farther than {MAX_COORDINATE_M} m"),
        ));
    }
    if file.wall_axis_deg.is_some_and(|a| !a.is_finite()) {
        return Err(DataError::invalid(&json_path, "wall_axis_deg is not a finite angle"));
    }
    let points = read_map_points(dir, file.points, file.corners.len())?;
    let wall_axis = file.wall_axis_deg.map(f64::to_radians);
    Ok(SavedMap { corners: file.corners, walls: file.walls, wall_axis, points, keyframes, truth_origin })
}

/// The map's keyframes and ground-truth origin, each a pose with a unit
/// quaternion within the coordinate bound.
fn map_poses(json_path: &Path, file: &MapFile) -> datasets::Result<(Vec<Pose3>, Option<Pose3>)> {
    let within = |v: &Vec3| v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE_M);
    let mut keyframes = Vec::with_capacity(file.keyframes.len());
    for (k, a) in file.keyframes.iter().enumerate() {
        let pose = pose_from_array(a).filter(|p| within(&p.translation.vector)).ok_or_else(|| {
            DataError::invalid(
                json_path,
                format!("keyframe {k} is not a pose with a unit quaternion within {MAX_COORDINATE_M} m"),
            )
        })?;
        keyframes.push(pose);
    }
    let truth_origin = match &file.truth_origin {
        Some(a) => Some(pose_from_array(a).filter(|p| within(&p.translation.vector)).ok_or_else(|| {
            DataError::invalid(
                json_path,
                format!("truth_origin is not a pose with a unit quaternion within {MAX_COORDINATE_M} m"),
            )
        })?),
        None => None,
    };
    Ok((keyframes, truth_origin))
}

/// The point map of `map.ply`: exactly the layout `localize run` writes,
/// `points` map points (then `corners` corner vertices, skipped), each
/// within the coordinate bound with a unit normal.
fn read_map_points(dir: &Path, points_count: usize, corners: usize) -> datasets::Result<Vec<MapPoint>> {
    let within = |v: &Vec3| v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE_M);
    let ply_path = dir.join("map.ply");
    let bytes = std::fs::read(&ply_path).map_err(|e| DataError::io(&ply_path, e))?;
    let count = points_count + corners;
    let header = ply_header(count);
    let Some(body) = bytes.strip_prefix(header.as_bytes()) else {
        return Err(DataError::invalid(
            &ply_path,
            format!("not the map.ply that goes with map.json ({count} vertices of `localize run`'s layout expected)"),
        ));
    };
    if body.len() != count * VERTEX_BYTES {
        return Err(DataError::invalid(
            &ply_path,
            format!("{} bytes of vertices, {} expected for {count}", body.len(), count * VERTEX_BYTES),
        ));
    }
    let mut points = Vec::with_capacity(points_count);
    for (k, vertex) in body.chunks_exact(VERTEX_BYTES).take(points_count).enumerate() {
        let f = |i: usize| f32::from_le_bytes(vertex[4 * i..4 * i + 4].try_into().expect("4 bytes")) as f64;
        let (position, normal) = (Vec3::new(f(0), f(1), f(2)), Vec3::new(f(3), f(4), f(5)));
        if !within(&position) || !normal.iter().all(|x| x.is_finite()) || (normal.norm() - 1.0).abs() > 1e-3 {
            return Err(DataError::invalid(
                &ply_path,
                format!("vertex {k} is not a point within {MAX_COORDINATE_M} m with a unit normal"),
            ));
        }
        points.push(MapPoint { position, normal });
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A map of two points, two keyframes and a wall axis.
    fn saved_map() -> (SavedMap, Pose3) {
        let points = vec![
            MapPoint { position: Vec3::new(1.0, 2.0, 3.0), normal: Vec3::z() },
            MapPoint { position: Vec3::new(-0.5, 0.25, 0.0), normal: -Vec3::x() },
        ];
        let turned =
            Pose3::from_parts(Vec3::new(1.0, -2.0, 0.5).into(), crate::estimation::euler::rotation(0.1, 0.0, 2.0));
        let map = SavedMap {
            corners: Vec::new(),
            walls: Vec::new(),
            wall_axis: Some(0.3),
            points: points.clone(),
            keyframes: vec![Pose3::identity(), turned],
            truth_origin: Some(turned),
        };
        (map, turned)
    }

    /// `map.json` of `dir` rewritten as a version-1 map (no keyframes, no
    /// origin, no wall axis); returns its JSON.
    fn as_version_one(dir: &std::path::Path) -> serde_json::Value {
        let json = dir.join("map.json");
        let mut old: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        old["format"] = "corner-fusion map 1".into();
        old.as_object_mut().unwrap().remove("keyframes");
        old.as_object_mut().unwrap().remove("truth_origin");
        old.as_object_mut().unwrap().remove("wall_axis_deg");
        std::fs::write(&json, old.to_string()).unwrap();
        old
    }

    #[test]
    fn a_written_map_reads_back_and_a_version_one_map_still_reads() {
        let dir = tempfile::tempdir().unwrap();
        let (map, turned) = saved_map();
        let points = map.points.clone();
        write_map(dir.path(), &map).unwrap();
        let back = read_map(dir.path()).unwrap();
        assert_eq!(back.points, points);
        assert_eq!(back.keyframes[0], Pose3::identity());
        assert!((back.keyframes[1].inverse() * turned).translation.vector.norm() < 1e-12);
        assert!(back.truth_origin.unwrap().rotation.angle_to(&turned.rotation) < 1e-12);
        assert!((back.wall_axis.unwrap() - 0.3).abs() < 1e-12);
        // A version-1 map (no keyframes, no origin) still reads.
        as_version_one(dir.path());
        let v1 = read_map(dir.path()).unwrap();
        assert!(v1.keyframes.is_empty() && v1.truth_origin.is_none() && v1.wall_axis.is_none() && v1.points == points);
    }

    #[test]
    fn damaged_fields_of_map_json_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let (map, _) = saved_map();
        write_map(dir.path(), &map).unwrap();
        let json = dir.path().join("map.json");
        let mut old = as_version_one(dir.path());
        // A keyframe that is no pose is named.
        old["keyframes"] = serde_json::json!([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]]);
        std::fs::write(&json, old.to_string()).unwrap();
        let bad = read_map(dir.path()).unwrap_err().to_string();
        assert!(bad.contains("map.json") && bad.contains("keyframe 0"), "{bad}");
        // A wall whose weight is 0 would divide by it: named.
        old["keyframes"] = serde_json::json!([]);
        let wall = |weight: f64| {
            serde_json::json!([{"normal": [1.0, 0.0, 0.0], "distance": 2.0, "observations": 3,
                "normal_sum": [1.0, 0.0, 0.0], "distance_sum": 2.0, "distance_square_sum": 4.0,
                "weight": weight, "point_sum": [2.0, 0.5, 1.0]}])
        };
        old["walls"] = wall(1.0);
        std::fs::write(&json, old.to_string()).unwrap();
        assert_eq!(read_map(dir.path()).unwrap().walls.len(), 1);
        // ...and so would a weight of 1e-320 (found by fuzzing: spreads of inf).
        for weight in [0.0, 1e-320] {
            old["walls"] = wall(weight);
            std::fs::write(&json, old.to_string()).unwrap();
            let weightless = read_map(dir.path()).unwrap_err().to_string();
            assert!(weightless.contains("wall 0") && weightless.contains("no weight"), "{weightless}");
        }
        // A wall without a direction, an origin a light year away, too many keyframes: named.
        let mut zero = wall(1.0);
        zero[0]["normal"] = serde_json::json!([0.0, 0.0, 0.0]);
        old["walls"] = zero;
        std::fs::write(&json, old.to_string()).unwrap();
        let m = read_map(dir.path()).unwrap_err().to_string();
        assert!(m.contains("wall 0 has no unit normal"), "{m}");
        old["walls"] = wall(1.0);
        old["truth_origin"] = serde_json::json!([9.5e15, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        std::fs::write(&json, old.to_string()).unwrap();
        let m = read_map(dir.path()).unwrap_err().to_string();
        assert!(m.contains("truth_origin") && m.contains("within 1000000 m"), "{m}");
        old.as_object_mut().unwrap().remove("truth_origin");
        old["keyframes"] = serde_json::json!(vec![[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]; MAX_KEYFRAMES + 1]);
        std::fs::write(&json, old.to_string()).unwrap();
        let m = read_map(dir.path()).unwrap_err().to_string();
        assert!(m.contains("5001 keyframes, more than the 5000"), "{m}");
        old["keyframes"] = serde_json::json!([]);
        // A corner averaged over no observation, or over more than it saw, would divide by 0 or drift: named.
        for used in [0, 4] {
            old["corners"] = serde_json::json!([{"position": [1.0, 2.0, 3.0], "observations": 3,
                "sum": [3.0, 6.0, 9.0], "square_sum": 42.0, "used": used}]);
            std::fs::write(&json, old.to_string()).unwrap();
            let m = read_map(dir.path()).unwrap_err().to_string();
            assert!(m.contains("corner 0") && m.contains("observations used"), "used {used}: {m}");
        }
    }

    #[test]
    fn a_torn_map_ply_and_a_foreign_map_json_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let (map, _) = saved_map();
        write_map(dir.path(), &map).unwrap();
        let ply = dir.path().join("map.ply");
        let bytes = std::fs::read(&ply).unwrap();
        std::fs::write(&ply, &bytes[..bytes.len() - 5]).unwrap();
        let torn = read_map(dir.path()).unwrap_err().to_string();
        assert!(torn.contains("map.ply") && torn.contains("bytes of vertices"), "{torn}");
        std::fs::write(dir.path().join("map.json"), "{\"format\": \"other\"}").unwrap();
        let other = read_map(dir.path()).unwrap_err().to_string();
        assert!(other.contains("map.json") && other.contains("not a map"), "{other}");
    }
}
