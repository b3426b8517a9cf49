//! PCD, the Point Cloud Library's format: `ascii`, `binary` and PCL's default
//! `binary_compressed` (LZF, fields stored one after another). Reads `x y z`
//! and an optional `intensity`; other fields (rgb, normals, labels,
//! histograms) are skipped.

use std::io::Write;
use std::path::Path;

use nalgebra::{Quaternion, Translation3, UnitQuaternion};

use super::cloud::{CloudBuilder, NonFinite, PointCloud};
use super::lzf;
use crate::error::{DataError, Result};
use crate::math::Pose3;

/// Most values one field may hold per point (a descriptor histogram holds hundreds).
const MAX_FIELD_COUNT: usize = 1 << 16;
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcdData {
    Ascii,
    Binary,
    BinaryCompressed,
}

#[derive(Debug, Clone)]
struct Field {
    name: String,
    size: usize,
    kind: u8,
    count: usize,
    /// Byte offset of the field inside one point record.
    offset: usize,
}

impl Field {
    fn bytes(&self) -> usize {
        self.size * self.count
    }

    /// Decodes the first element of this field from `b` (little endian).
    fn decode(&self, b: &[u8]) -> f64 {
        let arr = |n: usize| -> [u8; 8] {
            let mut a = [0u8; 8];
            a[..n].copy_from_slice(&b[..n]);
            a
        };
        match (self.kind, self.size) {
            (b'F', 4) => f32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            (b'F', 8) => f64::from_le_bytes(arr(8)),
            (b'U', 1) => b[0] as f64,
            (b'U', 2) => u16::from_le_bytes([b[0], b[1]]) as f64,
            (b'U', 4) => u32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            (b'U', 8) => u64::from_le_bytes(arr(8)) as f64,
            (b'I', 1) => b[0] as i8 as f64,
            (b'I', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
            (b'I', 4) => i32::from_le_bytes(b[..4].try_into().expect("4 bytes")) as f64,
            (b'I', 8) => i64::from_le_bytes(arr(8)) as f64,
            _ => f64::NAN, // excluded when the header is parsed
        }
    }
}

struct Header {
    fields: Vec<Field>,
    points: usize,
    viewpoint: Pose3,
    data: PcdData,
    /// Byte offset where the data starts.
    data_start: usize,
    /// Line number of the DATA line (1-based), for ascii error messages.
    data_line: usize,
}

impl Header {
    fn record_bytes(&self) -> usize {
        self.fields.iter().map(Field::bytes).sum()
    }
    fn field(&self, names: &[&str]) -> Option<usize> {
        self.fields.iter().position(|f| names.contains(&f.name.as_str()))
    }
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
    let mut names: Vec<String> = Vec::new();
    let mut sizes: Vec<usize> = Vec::new();
    let mut kinds: Vec<u8> = Vec::new();
    let mut counts: Option<Vec<usize>> = None;
    let (mut width, mut height, mut points) = (None, None, None);
    let mut viewpoint = Pose3::identity();
    let mut pos = 0;
    let mut line_no = 0;
    loop {
        line_no += 1;
        if pos >= bytes.len() {
            return Err(DataError::line(path, line_no, "header ended without a DATA line"));
        }
        let end = bytes[pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |k| pos + k);
        let line = std::str::from_utf8(&bytes[pos..end])
            .map_err(|_| DataError::line(path, line_no, "header line is not text"))?
            .trim();
        pos = (end + 1).min(bytes.len());
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or_default().to_ascii_uppercase();
        let rest: Vec<&str> = words.collect();
        let bad = |what: &str| DataError::line(path, line_no, format!("bad {key} line: {what}"));
        let numbers = |rest: &[&str]| -> Result<Vec<usize>> {
            rest.iter().map(|w| w.parse::<usize>().map_err(|_| bad(&format!("`{w}` is not a count")))).collect()
        };
        match key.as_str() {
            "VERSION" => {}
            "FIELDS" | "COLUMNS" => names = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => sizes = numbers(&rest)?,
            "TYPE" => {
                kinds = rest
                    .iter()
                    .map(|w| match *w {
                        "F" | "U" | "I" => Ok(w.as_bytes()[0]),
                        other => Err(bad(&format!("unknown type `{other}` (expected F, U or I)"))),
                    })
                    .collect::<Result<_>>()?
            }
            "COUNT" => counts = Some(numbers(&rest)?),
            "WIDTH" => width = numbers(&rest)?.first().copied(),
            "HEIGHT" => height = numbers(&rest)?.first().copied(),
            "POINTS" => points = numbers(&rest)?.first().copied(),
            "VIEWPOINT" => viewpoint = parse_viewpoint(&rest, bad)?,
            "DATA" => {
                let data = match rest.first().copied() {
                    Some("ascii") => PcdData::Ascii,
                    Some("binary") => PcdData::Binary,
                    Some("binary_compressed") => PcdData::BinaryCompressed,
                    other => return Err(bad(&format!("unknown DATA kind {other:?}"))),
                };
                let fields = fields_of(path, line_no, &names, &sizes, &kinds, counts.clone())?;
                let points = point_count(path, line_no, width, height, points)?;
                return Ok(Header { fields, points, viewpoint, data, data_start: pos, data_line: line_no });
            }
            _ => {
                return Err(DataError::line(path, line_no, format!("unknown header keyword `{key}`")));
            }
        }
    }
}

/// The fields of a header at its DATA line: FIELDS, SIZE, TYPE and COUNT
/// agree in length, each type has a size it can have, each count is sane.
fn fields_of(
    path: &Path,
    line_no: usize,
    names: &[String],
    sizes: &[usize],
    kinds: &[u8],
    counts: Option<Vec<usize>>,
) -> Result<Vec<Field>> {
    let n = names.len();
    if n == 0 {
        return Err(DataError::line(path, line_no, "no FIELDS line before DATA"));
    }
    let counts = counts.unwrap_or_else(|| vec![1; n]);
    if sizes.len() != n || kinds.len() != n || counts.len() != n {
        return Err(DataError::line(
            path,
            line_no,
            format!(
                "FIELDS has {n} entries but SIZE has {}, TYPE {} and COUNT {}",
                sizes.len(),
                kinds.len(),
                counts.len()
            ),
        ));
    }
    let mut fields = Vec::with_capacity(n);
    let mut offset = 0;
    for i in 0..n {
        let valid = match kinds[i] {
            b'F' => matches!(sizes[i], 4 | 8),
            _ => matches!(sizes[i], 1 | 2 | 4 | 8),
        };
        if !valid {
            return Err(DataError::line(
                path,
                line_no,
                format!("field `{}` has unsupported type {} of size {}", names[i], kinds[i] as char, sizes[i]),
            ));
        }
        // COUNT 0 would give a field no bytes to read; a huge one no file can hold.
        if counts[i] == 0 || counts[i] > MAX_FIELD_COUNT {
            return Err(DataError::line(
                path,
                line_no,
                format!("field `{}` has COUNT {} (1 to {MAX_FIELD_COUNT})", names[i], counts[i]),
            ));
        }
        fields.push(Field { name: names[i].clone(), size: sizes[i], kind: kinds[i], count: counts[i], offset });
        offset += sizes[i] * counts[i];
    }
    Ok(fields)
}

/// POINTS, or WIDTH x HEIGHT, which must agree when both are given.
fn point_count(
    path: &Path,
    line_no: usize,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
) -> Result<usize> {
    let from_size = match (width, height) {
        (Some(w), Some(h)) => Some(
            w.checked_mul(h)
                .ok_or_else(|| DataError::line(path, line_no, format!("WIDTH {w} x HEIGHT {h} overflows")))?,
        ),
        _ => None,
    };
    Ok(match (points, from_size) {
        (Some(p), Some(s)) if p != s => {
            return Err(DataError::line(path, line_no, format!("POINTS {p} differs from WIDTH x HEIGHT = {s}")));
        }
        (Some(p), _) => p,
        (None, Some(s)) => s,
        (None, None) => {
            return Err(DataError::line(path, line_no, "neither POINTS nor WIDTH/HEIGHT given"));
        }
    })
}

/// VIEWPOINT's `tx ty tz qw qx qy qz`.
fn parse_viewpoint(rest: &[&str], bad: impl Fn(&str) -> DataError) -> Result<Pose3> {
    let v: Vec<f64> = rest
        .iter()
        .map(|w| w.parse::<f64>().map_err(|_| bad(&format!("`{w}` is not a number"))))
        .collect::<Result<_>>()?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        return Err(bad("expected 7 finite numbers: tx ty tz qw qx qy qz"));
    }
    let q = Quaternion::new(v[3], v[4], v[5], v[6]);
    if q.norm() < 1e-9 {
        return Err(bad("zero quaternion"));
    }
    Ok(Pose3::from_parts(Translation3::new(v[0], v[1], v[2]), UnitQuaternion::from_quaternion(q)))
}

/// Reads a PCD file.
pub fn read_pcd(path: &Path, policy: NonFinite) -> Result<PointCloud> {
    let bytes = crate::atomic::read_bytes(path)?;
    read_pcd_bytes(path, &bytes, policy)
}

/// Parses PCD `bytes`; `path` only names the source in errors.
pub fn read_pcd_bytes(path: &Path, bytes: &[u8], policy: NonFinite) -> Result<PointCloud> {
    let header = parse_header(path, bytes)?;
    let missing = |axis: &str| DataError::invalid(path, format!("no `{axis}` field in FIELDS"));
    // Per-point time: Velodyne-style `time` in seconds, or Ouster-style
    // unsigned `t` in nanoseconds.
    let time = header.field(&["time", "t"]);
    let columns = Columns {
        x: header.field(&["x"]).ok_or_else(|| missing("x"))?,
        y: header.field(&["y"]).ok_or_else(|| missing("y"))?,
        z: header.field(&["z"]).ok_or_else(|| missing("z"))?,
        intensity: header.field(&["intensity", "i"]),
        time,
        time_scale: time.map_or(1.0, |k| if header.fields[k].kind == b'F' { 1.0 } else { 1e-9 }),
    };
    let mut cloud = CloudBuilder::new(path, policy, header.points, columns.intensity.is_some());
    if columns.time.is_some() {
        cloud = cloud.with_times();
    }
    let body = Body { path, bytes, header: &header, columns: &columns };
    match header.data {
        PcdData::Ascii => body.ascii(&mut cloud)?,
        PcdData::Binary => body.binary(&mut cloud)?,
        PcdData::BinaryCompressed => body.compressed(&mut cloud)?,
    }
    Ok(cloud.finish(header.viewpoint))
}

/// The fields a cloud takes its points from.
struct Columns {
    x: usize,
    y: usize,
    z: usize,
    intensity: Option<usize>,
    time: Option<usize>,
    /// Seconds per unit of the time field.
    time_scale: f64,
}

/// A PCD file's data after its header, read into a cloud by its DATA kind.
struct Body<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    header: &'a Header,
    columns: &'a Columns,
}

impl Body<'_> {
    fn ascii(&self, cloud: &mut CloudBuilder<'_>) -> Result<()> {
        let (path, header, data, n) = self.parts();
        let (ix, iy, iz, ii, it, time_scale) = self.columns.unpack();
        let text = std::str::from_utf8(data).map_err(|e| {
            DataError::byte(path, (header.data_start + e.valid_up_to()) as u64, "ascii data is not text")
        })?;
        // Token index of each field's first element within a line.
        let mut token_of = Vec::with_capacity(header.fields.len());
        let mut tokens = 0;
        for f in &header.fields {
            token_of.push(tokens);
            tokens += f.count;
        }
        let mut index = 0;
        for (k, line) in text.lines().enumerate() {
            let line_no = header.data_line + 1 + k;
            let words: Vec<&str> = line.split_whitespace().collect();
            if words.is_empty() {
                continue;
            }
            if index == n {
                return Err(DataError::line(path, line_no, format!("more than the {n} points the header declares")));
            }
            if words.len() != tokens {
                return Err(DataError::line(path, line_no, format!("expected {tokens} values, found {}", words.len())));
            }
            let value = |field: usize| -> Result<f32> {
                let w = words[token_of[field]];
                parse_ascii_number(w).ok_or_else(|| DataError::line(path, line_no, format!("`{w}` is not a number")))
            };
            let intensity = match ii {
                Some(i) => value(i)?,
                None => 0.0,
            };
            let time = match it {
                Some(k) => (value(k)? as f64 * time_scale) as f32,
                None => 0.0,
            };
            cloud.push_timed(index, [value(ix)?, value(iy)?, value(iz)?], intensity, time)?;
            index += 1;
        }
        if index != n {
            return Err(DataError::invalid(path, format!("header declares {n} points but the data has {index}")));
        }
        Ok(())
    }

    fn binary(&self, cloud: &mut CloudBuilder<'_>) -> Result<()> {
        let (path, header, data, n) = self.parts();
        let (ix, iy, iz, ii, it, time_scale) = self.columns.unpack();
        let (bytes, record) = (self.bytes, header.record_bytes());
        // A declared count is not trusted: no product may wrap around.
        let need = n.saturating_mul(record);
        // PCL pads binary files with zeros to a page; anything else past
        // the declared points is data the header does not count.
        if data.len() > need && data[need..].iter().any(|&b| b != 0) {
            return Err(DataError::byte(
                path,
                (header.data_start + need) as u64,
                format!("the data holds {} bytes after the {n} points the header declares", data.len() - need),
            ));
        }
        if data.len() < need {
            return Err(DataError::byte(
                path,
                bytes.len() as u64,
                format!("binary data ends early: {n} points of {record} bytes need {need} bytes, found {}", data.len()),
            ));
        }
        let f = &header.fields;
        for i in 0..n {
            let rec = &data[i * record..(i + 1) * record];
            let get = |k: usize| f[k].decode(&rec[f[k].offset..]) as f32;
            let time = it.map_or(0.0, |k| (f[k].decode(&rec[f[k].offset..]) * time_scale) as f32);
            cloud.push_timed(i, [get(ix), get(iy), get(iz)], ii.map_or(0.0, get), time)?;
        }
        Ok(())
    }

    fn compressed(&self, cloud: &mut CloudBuilder<'_>) -> Result<()> {
        let (path, header, data, n) = self.parts();
        let (ix, iy, iz, ii, it, time_scale) = self.columns.unpack();
        let (bytes, record) = (self.bytes, header.record_bytes());
        let at = header.data_start as u64;
        if data.len() < 8 {
            return Err(DataError::byte(path, at, "missing the compressed/uncompressed size words"));
        }
        let packed = u32::from_le_bytes(data[0..4].try_into().expect("4 bytes")) as usize;
        let unpacked = u32::from_le_bytes(data[4..8].try_into().expect("4 bytes")) as usize;
        if data.len() < 8 + packed {
            return Err(DataError::byte(
                path,
                bytes.len() as u64,
                format!("compressed block of {packed} bytes is truncated ({} present)", data.len() - 8),
            ));
        }
        if unpacked != n.saturating_mul(record) {
            return Err(DataError::byte(
                path,
                at + 4,
                format!("uncompressed size {unpacked} does not match {n} points of {record} bytes"),
            ));
        }
        let raw = lzf::decompress(&data[8..8 + packed], unpacked)
            .map_err(|e| DataError::byte(path, at + 8 + e.offset as u64, format!("LZF: {}", e.message)))?;
        // Fields are stored one after another: all x, then all y, ...
        let f = &header.fields;
        let get = |k: usize, i: usize| {
            let start = n * f[k].offset + i * f[k].bytes();
            f[k].decode(&raw[start..]) as f32
        };
        for i in 0..n {
            let time = it.map_or(0.0, |k| (get(k, i) as f64 * time_scale) as f32);
            cloud.push_timed(i, [get(ix, i), get(iy, i), get(iz, i)], ii.map_or(0.0, |k| get(k, i)), time)?;
        }
        Ok(())
    }

    /// The file, its header, the data after the header and the point count.
    fn parts(&self) -> (&Path, &Header, &[u8], usize) {
        (self.path, self.header, &self.bytes[self.header.data_start..], self.header.points)
    }
}

impl Columns {
    fn unpack(&self) -> (usize, usize, usize, Option<usize>, Option<usize>, f64) {
        (self.x, self.y, self.z, self.intensity, self.time, self.time_scale)
    }
}

fn parse_ascii_number(w: &str) -> Option<f32> {
    match w.to_ascii_lowercase().as_str() {
        "nan" | "-nan" => Some(f32::NAN),
        _ => w.parse::<f32>().ok(),
    }
}

/// Writes a PCD file (fields `x y z`, then `intensity` and `time` (seconds
/// after the stamp) when present), atomically.
pub fn write_pcd(path: &Path, cloud: &PointCloud, data: PcdData) -> Result<()> {
    let bytes = pcd_bytes(cloud, data);
    crate::atomic::write_bytes(path, &bytes)
}

/// Encodes a cloud as PCD.
pub fn pcd_bytes(cloud: &PointCloud, data: PcdData) -> Vec<u8> {
    let n = cloud.len();
    let mut names = vec!["x", "y", "z"];
    if cloud.intensity.is_some() {
        names.push("intensity");
    }
    if cloud.times.is_some() {
        names.push("time");
    }
    let fields = names.len();
    let vp = &cloud.viewpoint;
    let (t, q) = (vp.translation.vector, vp.rotation.quaternion());
    let mut out = Vec::new();
    let kind = match data {
        PcdData::Ascii => "ascii",
        PcdData::Binary => "binary",
        PcdData::BinaryCompressed => "binary_compressed",
    };
    let repeat = |word: &str| vec![word; fields].join(" ");
    let (sizes, types, counts) = (repeat("4"), repeat("F"), repeat("1"));
    let names = names.join(" ");
    let _ = write!(
        out,
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {names}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n\
         WIDTH {n}\nHEIGHT 1\nVIEWPOINT {} {} {} {} {} {} {}\nPOINTS {n}\nDATA {kind}\n",
        t.x, t.y, t.z, q.w, q.i, q.j, q.k
    );
    let time_field = if cloud.intensity.is_some() { 4 } else { 3 };
    let value = |i: usize, k: usize| -> f32 {
        match k {
            0 => cloud.points[i].x,
            1 => cloud.points[i].y,
            2 => cloud.points[i].z,
            k if k == time_field => cloud.times.as_ref().map_or(0.0, |v| v[i]),
            _ => cloud.intensity.as_ref().map_or(0.0, |v| v[i]),
        }
    };
    match data {
        PcdData::Ascii => {
            for i in 0..n {
                let line: Vec<String> = (0..fields).map(|k| format!("{}", value(i, k))).collect();
                let _ = writeln!(out, "{}", line.join(" "));
            }
        }
        PcdData::Binary => {
            for i in 0..n {
                for k in 0..fields {
                    out.extend_from_slice(&value(i, k).to_le_bytes());
                }
            }
        }
        PcdData::BinaryCompressed => {
            let mut raw = Vec::with_capacity(n * fields * 4);
            for k in 0..fields {
                for i in 0..n {
                    raw.extend_from_slice(&value(i, k).to_le_bytes());
                }
            }
            let packed = lzf::compress(&raw);
            out.extend_from_slice(&(packed.len() as u32).to_le_bytes());
            out.extend_from_slice(&(raw.len() as u32).to_le_bytes());
            out.extend_from_slice(&packed);
        }
    }
    out
}
