//! The map a run built, written for other tools and for a later run:
//! `map.ply` (the point map with its normals, grey, then the corner
//! landmarks, red; binary PLY as CloudCompare and Open3D read it) and
//! `map.json` (corner and wall landmarks with everything that makes them
//! trusted, and the point count). World frame: the robot at the first scan,
//! as in `trajectory.txt`. `read_map` takes both back for `localize run
//! --map`.

use std::io::Write as _;
use std::path::Path;

use datasets::DataError;
use datasets::math::Vec3;
use serde::{Deserialize, Serialize};

use crate::landmarks::Landmark;
use crate::plane_landmarks::PlaneLandmark;
use crate::point_map::MapPoint;

/// The version `map.json` says it is.
const FORMAT: &str = "corner-fusion map 1";

/// What `map.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapFile {
    pub format: String,
    pub frame: String,
    pub corners: Vec<Landmark>,
    /// Walls: the points p with normal . p = distance.
    pub walls: Vec<PlaneLandmark>,
    /// The first this many vertices of `map.ply` are the point map's.
    pub points: usize,
}

/// A map read back: landmarks and the point map's points.
#[derive(Debug, Clone, PartialEq)]
pub struct SavedMap {
    pub corners: Vec<Landmark>,
    pub walls: Vec<PlaneLandmark>,
    pub points: Vec<MapPoint>,
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
pub fn write_map(
    dir: &Path,
    points: &[MapPoint],
    corners: &[Landmark],
    walls: &[PlaneLandmark],
) -> datasets::Result<()> {
    datasets::atomic::write_bytes(&dir.join("map.ply"), &map_ply(points, corners))?;
    let file = MapFile {
        format: FORMAT.into(),
        frame: "world = the robot's pose at the first scan (as trajectory.txt)".into(),
        corners: corners.to_vec(),
        walls: walls.to_vec(),
        points: points.len(),
    };
    datasets::atomic::write_json(&dir.join("map.json"), &file)
}

/// Reads the map `localize run` wrote into `dir` (`map.json` and
/// `map.ply`); any other file, a torn one, or one whose numbers are not
/// finite is an error naming it.
pub fn read_map(dir: &Path) -> datasets::Result<SavedMap> {
    let json_path = dir.join("map.json");
    let text = datasets::atomic::read_text(&json_path)?;
    let file: MapFile = serde_json::from_str(&text)
        .map_err(|e| DataError::invalid(&json_path, format!("not a map written by `localize run`: {e}")))?;
    if file.format != FORMAT {
        return Err(DataError::invalid(&json_path, format!("format `{}`, expected `{FORMAT}`", file.format)));
    }
    let finite = |v: &Vec3| v.iter().all(|x| x.is_finite());
    if let Some(k) = file.corners.iter().position(|c| !finite(&c.position)) {
        return Err(DataError::invalid(&json_path, format!("corner {k} has a non-finite position")));
    }
    if let Some(k) = file.walls.iter().position(|w| !finite(&w.normal) || !w.distance.is_finite()) {
        return Err(DataError::invalid(&json_path, format!("wall {k} has a non-finite plane")));
    }
    let ply_path = dir.join("map.ply");
    let bytes = std::fs::read(&ply_path).map_err(|e| DataError::io(&ply_path, e))?;
    let count = file.points + file.corners.len();
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
    let mut points = Vec::with_capacity(file.points);
    for (k, vertex) in body.chunks_exact(VERTEX_BYTES).take(file.points).enumerate() {
        let f = |i: usize| f32::from_le_bytes(vertex[4 * i..4 * i + 4].try_into().expect("4 bytes")) as f64;
        let (position, normal) = (Vec3::new(f(0), f(1), f(2)), Vec3::new(f(3), f(4), f(5)));
        if !finite(&position) || !finite(&normal) || (normal.norm() - 1.0).abs() > 1e-3 {
            return Err(DataError::invalid(&ply_path, format!("vertex {k} is not a point with a unit normal")));
        }
        points.push(MapPoint { position, normal });
    }
    Ok(SavedMap { corners: file.corners, walls: file.walls, points })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_map_reads_back_and_a_damaged_one_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let points = vec![
            MapPoint { position: Vec3::new(1.0, 2.0, 3.0), normal: Vec3::z() },
            MapPoint { position: Vec3::new(-0.5, 0.25, 0.0), normal: -Vec3::x() },
        ];
        write_map(dir.path(), &points, &[], &[]).unwrap();
        let back = read_map(dir.path()).unwrap();
        assert_eq!(back.points, points);
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
