//! Wheel odometry and IMU logs as CSV with a header row. Columns are found by
//! name, so extra columns and other orders load too.
//!
//! - odometry: `timestamp,x,y,yaw,v,omega` (s, m, m, rad, m/s, rad/s): the
//!   wheel-integrated planar pose and the measured forward speed and yaw rate.
//! - IMU: `timestamp,ax,ay,az,gx,gy,gz` (s, m/s^2 specific force, rad/s),
//!   in the robot frame (x forward, y left, z up).

use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{DataError, Result};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OdometrySample {
    pub timestamp: f64,
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
    pub v: f64,
    pub omega: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuSample {
    pub timestamp: f64,
    pub accel: [f64; 3],
    pub gyro: [f64; 3],
}

pub const ODOMETRY_COLUMNS: [&str; 6] = ["timestamp", "x", "y", "yaw", "v", "omega"];
pub const IMU_COLUMNS: [&str; 7] = ["timestamp", "ax", "ay", "az", "gx", "gy", "gz"];

/// Parses the named columns of a numeric CSV, one row of values per line, and
/// checks that timestamps (the first named column) strictly increase.
fn parse_columns<const N: usize>(path: &Path, text: &str, columns: [&str; N]) -> Result<Vec<[f64; N]>> {
    let mut lines = text.lines().enumerate().map(|(k, l)| (k + 1, l.trim())).filter(|(_, l)| !l.is_empty());
    let (_, header) = lines.next().ok_or_else(|| DataError::invalid(path, "empty file: expected a header row"))?;
    let names: Vec<&str> = header.trim_start_matches('#').split(',').map(str::trim).collect();
    let mut index = [0usize; N];
    for (slot, column) in index.iter_mut().zip(columns) {
        *slot = names.iter().position(|n| *n == column).ok_or_else(|| {
            DataError::line(path, 1, format!("header has no `{column}` column (expected {})", columns.join(",")))
        })?;
    }
    let mut rows: Vec<[f64; N]> = Vec::new();
    for (line_no, line) in lines {
        let words: Vec<&str> = line.split(',').map(str::trim).collect();
        if words.len() != names.len() {
            return Err(DataError::line(path, line_no, format!("{} values for {} columns", words.len(), names.len())));
        }
        let mut row = [0.0; N];
        for (k, &i) in index.iter().enumerate() {
            row[k] = match words[i].parse::<f64>() {
                Ok(v) if v.is_finite() => v,
                _ => {
                    return Err(DataError::line(
                        path,
                        line_no,
                        format!("column `{}`: `{}` is not a finite number", columns[k], words[i]),
                    ));
                }
            };
        }
        if let Some(prev) = rows.last()
            && row[0] <= prev[0]
        {
            return Err(DataError::line(
                path,
                line_no,
                format!("timestamp {} does not increase (previous {})", row[0], prev[0]),
            ));
        }
        rows.push(row);
    }
    Ok(rows)
}

pub fn read_odometry(path: &Path) -> Result<Vec<OdometrySample>> {
    parse_odometry(path, &crate::atomic::read_text(path)?)
}

/// Odometry from the text of `path`.
pub fn parse_odometry(path: &Path, text: &str) -> Result<Vec<OdometrySample>> {
    Ok(parse_columns(path, text, ODOMETRY_COLUMNS)?
        .into_iter()
        .map(|r| OdometrySample { timestamp: r[0], x: r[1], y: r[2], yaw: r[3], v: r[4], omega: r[5] })
        .collect())
}

pub fn read_imu(path: &Path) -> Result<Vec<ImuSample>> {
    parse_imu(path, &crate::atomic::read_text(path)?)
}

/// IMU samples from the text of `path`.
pub fn parse_imu(path: &Path, text: &str) -> Result<Vec<ImuSample>> {
    Ok(parse_columns(path, text, IMU_COLUMNS)?
        .into_iter()
        .map(|r| ImuSample { timestamp: r[0], accel: [r[1], r[2], r[3]], gyro: [r[4], r[5], r[6]] })
        .collect())
}

pub fn write_odometry(path: &Path, samples: &[OdometrySample]) -> Result<()> {
    let mut out = ODOMETRY_COLUMNS.join(",") + "\n";
    for s in samples {
        let _ = writeln!(out, "{:.6},{:.9},{:.9},{:.9},{:.9},{:.9}", s.timestamp, s.x, s.y, s.yaw, s.v, s.omega);
    }
    crate::atomic::write_bytes(path, out.as_bytes())
}

pub fn write_imu(path: &Path, samples: &[ImuSample]) -> Result<()> {
    let mut out = IMU_COLUMNS.join(",") + "\n";
    for s in samples {
        let [ax, ay, az] = s.accel;
        let [gx, gy, gz] = s.gyro;
        let _ = writeln!(out, "{:.6},{ax:.9},{ay:.9},{az:.9},{gx:.9},{gy:.9},{gz:.9}", s.timestamp);
    }
    crate::atomic::write_bytes(path, out.as_bytes())
}
