//! Trajectories: TUM (`t tx ty tz qx qy qz qw`), KITTI poses (12 numbers, a
//! 3x4 row-major matrix per line, no timestamps) and the EuRoC ground-truth
//! CSV (`timestamp_ns, px, py, pz, qw, qx, qy, qz, ...`), the layouts that
//! trajectory evaluators such as `evo` accept. The layout of a file is
//! detected from its content.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use crate::error::{DataError, Result};
use crate::math::{Mat3, Pose3, Vec3, rotation_from_matrix};

/// Poses with their timestamps in seconds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    pub stamps: Vec<f64>,
    pub poses: Vec<Pose3>,
}

impl Trajectory {
    pub fn len(&self) -> usize {
        self.stamps.len()
    }
    pub fn is_empty(&self) -> bool {
        self.stamps.is_empty()
    }
    pub fn push(&mut self, stamp: f64, pose: Pose3) {
        self.stamps.push(stamp);
        self.poses.push(pose);
    }
    /// Positions, the part of each pose that trajectory errors are computed on.
    pub fn positions(&self) -> impl Iterator<Item = Vec3> + '_ {
        self.poses.iter().map(|p| p.translation.vector)
    }
    /// Fails unless timestamps increase. A stamp written twice passes where
    /// its two poses agree within `DUPLICATE_TOLERANCE_M` and
    /// `DUPLICATE_TOLERANCE_DEG` (TUM's motion-capture files have such pairs,
    /// about a millimetre apart; evo reads them as they are); farther apart,
    /// which pose is meant is unknown and it is an error. Returns how many
    /// stamps passed twice.
    pub fn check_increasing(&self, path: &Path) -> Result<usize> {
        let mut repeated = 0;
        for (k, w) in self.stamps.windows(2).enumerate() {
            if w[1] > w[0] {
                continue;
            }
            if w[1] < w[0] {
                return Err(DataError::invalid(
                    path,
                    format!("decreasing timestamp at pose {}: {} after {}", k + 1, w[1], w[0]),
                ));
            }
            let (a, b) = (&self.poses[k], &self.poses[k + 1]);
            let apart_m = (a.translation.vector - b.translation.vector).norm();
            let apart_deg = a.rotation.angle_to(&b.rotation).to_degrees();
            if !(apart_m <= DUPLICATE_TOLERANCE_M && apart_deg <= DUPLICATE_TOLERANCE_DEG) {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "duplicate timestamp at pose {}: {} twice, the poses {apart_m:.4} m and {apart_deg:.2} degrees \
                         apart (at most {DUPLICATE_TOLERANCE_M} m and {DUPLICATE_TOLERANCE_DEG} degree are read as one)",
                        k + 1,
                        w[1]
                    ),
                ));
            }
            repeated += 1;
        }
        Ok(repeated)
    }
}

/// How far apart two poses written at one stamp may be and still be read
/// (`Trajectory::check_increasing`).
pub const DUPLICATE_TOLERANCE_M: f64 = 0.01;
pub const DUPLICATE_TOLERANCE_DEG: f64 = 1.0;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrajectoryFormat {
    Tum,
    Kitti,
    Euroc,
}

/// Splits a data line on whitespace and commas.
fn fields(line: &str) -> Vec<&str> {
    line.split(|c: char| c.is_whitespace() || c == ',').filter(|w| !w.is_empty()).collect()
}

fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(k, l)| (k + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#') && !l.starts_with("//"))
}

fn numbers(path: &Path, line_no: usize, words: &[&str]) -> Result<Vec<f64>> {
    words
        .iter()
        .map(|w| match w.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(_) => Err(DataError::line(path, line_no, format!("non-finite value `{w}`"))),
            Err(_) => Err(DataError::line(path, line_no, format!("`{w}` is not a number"))),
        })
        .collect()
}

fn unit_quaternion(path: &Path, line_no: usize, w: f64, x: f64, y: f64, z: f64) -> Result<UnitQuaternion<f64>> {
    let q = Quaternion::new(w, x, y, z);
    let length = q.norm();
    if length < 1e-6 {
        return Err(DataError::line(path, line_no, "quaternion has zero length"));
    }
    // Writers round a unit quaternion; one far from unit length (or too long
    // to measure) is not a rotation anybody wrote.
    if !(0.9..=1.1).contains(&length) {
        return Err(DataError::line(path, line_no, format!("quaternion length {length:e} is not 1 (within 10%)")));
    }
    Ok(UnitQuaternion::from_quaternion(q))
}

/// Detects the layout from the first data line.
pub fn detect_format(path: &Path, text: &str) -> Result<TrajectoryFormat> {
    let (line_no, line) = data_lines(text).next().ok_or_else(|| DataError::invalid(path, "no poses in the file"))?;
    let words = fields(line);
    let euroc_stamp = words.first().is_some_and(|w| w.len() >= 16 && w.bytes().all(|b| b.is_ascii_digit()));
    match words.len() {
        n if line.contains(',') && euroc_stamp && n >= 8 => Ok(TrajectoryFormat::Euroc),
        8 => Ok(TrajectoryFormat::Tum),
        12 => Ok(TrajectoryFormat::Kitti),
        n => Err(DataError::line(
            path,
            line_no,
            format!("{n} values: not TUM (8), KITTI (12) or EuRoC (timestamp in ns, then >= 7 comma-separated values)"),
        )),
    }
}

/// Reads a trajectory of any supported layout. KITTI files get their line
/// index as timestamp unless a `times.txt`-style file is given.
pub fn read_trajectory(path: &Path) -> Result<(Trajectory, TrajectoryFormat)> {
    parse_trajectory(path, &crate::atomic::read_text(path)?)
}

/// A trajectory of any supported layout from the text of `path`.
pub fn parse_trajectory(path: &Path, text: &str) -> Result<(Trajectory, TrajectoryFormat)> {
    let format = detect_format(path, text)?;
    let trajectory = match format {
        TrajectoryFormat::Tum => parse_tum(path, text)?,
        TrajectoryFormat::Kitti => parse_kitti(path, text, None)?,
        TrajectoryFormat::Euroc => parse_euroc(path, text)?,
    };
    Ok((trajectory, format))
}

pub fn read_tum(path: &Path) -> Result<Trajectory> {
    parse_tum(path, &crate::atomic::read_text(path)?)
}

pub fn parse_tum(path: &Path, text: &str) -> Result<Trajectory> {
    let mut trajectory = Trajectory::default();
    for (line_no, line) in data_lines(text) {
        let words = fields(line);
        if words.len() != 8 {
            return Err(DataError::line(
                path,
                line_no,
                format!("expected 8 values `t tx ty tz qx qy qz qw`, found {}", words.len()),
            ));
        }
        let v = numbers(path, line_no, &words)?;
        let q = unit_quaternion(path, line_no, v[7], v[4], v[5], v[6])?;
        trajectory.push(v[0], Pose3::from_parts(Translation3::new(v[1], v[2], v[3]), q));
    }
    Ok(trajectory)
}

/// KITTI poses; `times` gives one timestamp per pose (a KITTI `times.txt`).
pub fn read_kitti(path: &Path, times: Option<&Path>) -> Result<Trajectory> {
    let text = crate::atomic::read_text(path)?;
    let stamps = match times {
        Some(t) => {
            let times_text = crate::atomic::read_text(t)?;
            let mut stamps = Vec::new();
            for (line_no, line) in data_lines(&times_text) {
                stamps.push(numbers(t, line_no, &[line])?[0]);
            }
            Some(stamps)
        }
        None => None,
    };
    let trajectory = parse_kitti(path, &text, stamps.as_deref())?;
    if let Some(s) = &stamps
        && s.len() != trajectory.len()
    {
        return Err(DataError::invalid(
            times.expect("times given"),
            format!("{} timestamps for {} poses in {}", s.len(), trajectory.len(), path.display()),
        ));
    }
    Ok(trajectory)
}

pub fn parse_kitti(path: &Path, text: &str, stamps: Option<&[f64]>) -> Result<Trajectory> {
    let mut trajectory = Trajectory::default();
    for (index, (line_no, line)) in data_lines(text).enumerate() {
        let words = fields(line);
        if words.len() != 12 {
            return Err(DataError::line(
                path,
                line_no,
                format!("expected 12 values (3x4 pose), found {}", words.len()),
            ));
        }
        let v = numbers(path, line_no, &words)?;
        let r = Mat3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
        let q = rotation_from_matrix(&r)
            .ok_or_else(|| DataError::line(path, line_no, "the 3x3 block is not a rotation matrix"))?;
        let stamp = stamps.and_then(|s| s.get(index).copied()).unwrap_or(index as f64);
        trajectory.push(stamp, Pose3::from_parts(Translation3::new(v[3], v[7], v[11]), q));
    }
    Ok(trajectory)
}

pub fn parse_euroc(path: &Path, text: &str) -> Result<Trajectory> {
    let mut trajectory = Trajectory::default();
    for (line_no, line) in data_lines(text) {
        let words = fields(line);
        if words.len() < 8 {
            return Err(DataError::line(path, line_no, format!("expected at least 8 values, found {}", words.len())));
        }
        let ns: u64 = words[0]
            .parse()
            .map_err(|_| DataError::line(path, line_no, format!("`{}` is not a timestamp in ns", words[0])))?;
        let v = numbers(path, line_no, &words[1..8])?;
        let stamp = (ns / 1_000_000_000) as f64 + (ns % 1_000_000_000) as f64 * 1e-9;
        let q = unit_quaternion(path, line_no, v[3], v[4], v[5], v[6])?;
        trajectory.push(stamp, Pose3::from_parts(Translation3::new(v[0], v[1], v[2]), q));
    }
    Ok(trajectory)
}

/// Formats a trajectory as TUM text (9 decimals, as precise as evo writes).
pub fn tum_text(trajectory: &Trajectory) -> String {
    let mut out = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for (t, p) in trajectory.stamps.iter().zip(&trajectory.poses) {
        let v = p.translation.vector;
        let q = p.rotation.quaternion();
        let _ = writeln!(out, "{t:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}", v.x, v.y, v.z, q.i, q.j, q.k, q.w);
    }
    out
}

/// Writes a TUM trajectory, atomically.
pub fn write_tum(path: &Path, trajectory: &Trajectory) -> Result<()> {
    crate::atomic::write_bytes(path, tum_text(trajectory).as_bytes())
}

/// Writes KITTI poses (no timestamps), atomically.
pub fn write_kitti(path: &Path, trajectory: &Trajectory) -> Result<()> {
    let mut out = String::new();
    for p in &trajectory.poses {
        let m = p.to_homogeneous();
        let row: Vec<String> =
            (0..3).flat_map(|r| (0..4).map(move |c| (r, c))).map(|(r, c)| format!("{:.9e}", m[(r, c)])).collect();
        let _ = writeln!(out, "{}", row.join(" "));
    }
    crate::atomic::write_bytes(path, out.as_bytes())
}
