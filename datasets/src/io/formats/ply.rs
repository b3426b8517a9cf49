//! PLY point clouds: the `vertex` element's `x y z` and an optional intensity
//! (`intensity` or CloudCompare's `scalar_intensity`), in `ascii`,
//! `binary_little_endian` or `binary_big_endian`. Other properties and
//! elements (colours, normals, faces) are skipped.

use std::io::Write;
use std::path::Path;

use super::cloud::{CloudBuilder, NonFinite, PointCloud};
use crate::error::{DataError, Result};
use crate::math::Pose3;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    Ascii,
    BinaryLittleEndian,
    BinaryBigEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
    fn decode(self, b: &[u8], little: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().expect("sized slice");
                (if little { <$t>::from_le_bytes(a) } else { <$t>::from_be_bytes(a) }) as f64
            }};
        }
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => num!(i16, 2),
            Self::U16 => num!(u16, 2),
            Self::I32 => num!(i32, 4),
            Self::U32 => num!(u32, 4),
            Self::F32 => num!(f32, 4),
            Self::F64 => num!(f64, 8),
        }
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar { name: String, kind: Scalar },
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads a PLY file's vertices as a point cloud.
pub fn read_ply(path: &Path, policy: NonFinite) -> Result<PointCloud> {
    let bytes = crate::atomic::read_bytes(path)?;
    read_ply_bytes(path, &bytes, policy)
}

/// Parses PLY `bytes`; `path` only names the source in errors.
pub fn read_ply_bytes(path: &Path, bytes: &[u8], policy: NonFinite) -> Result<PointCloud> {
    let header = parse_header(path, bytes)?;
    let columns = VertexColumns::of(path, &header.elements)?;
    let n = header.elements[columns.vertex].count;
    let mut cloud = CloudBuilder::new(path, policy, n, columns.intensity.is_some());
    match header.format {
        PlyFormat::Ascii => read_ascii_body(path, bytes, &header, &columns, &mut cloud)?,
        PlyFormat::BinaryLittleEndian | PlyFormat::BinaryBigEndian => {
            read_binary_body(path, bytes, &header, &columns, &mut cloud)?
        }
    }
    Ok(cloud.finish(Pose3::identity()))
}

/// A PLY header: its format, elements, where the body starts and how many
/// lines the header took (ascii bodies count their lines on from there).
struct PlyHeader {
    format: PlyFormat,
    elements: Vec<Element>,
    body_start: usize,
    header_lines: usize,
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<PlyHeader> {
    let mut pos = 0;
    let mut line_no = 0;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut next_line = |pos: &mut usize| -> Result<(usize, String)> {
        line_no += 1;
        if *pos >= bytes.len() {
            return Err(DataError::line(path, line_no, "header ended without `end_header`"));
        }
        let end = bytes[*pos..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |k| *pos + k);
        let text = std::str::from_utf8(&bytes[*pos..end])
            .map_err(|_| DataError::line(path, line_no, "header line is not text"))?
            .trim()
            .to_string();
        *pos = (end + 1).min(bytes.len());
        Ok((line_no, text))
    };
    let (_, magic) = next_line(&mut pos)?;
    if magic != "ply" {
        return Err(DataError::line(path, 1, "not a PLY file (first line is not `ply`)"));
    }
    loop {
        let (no, line) = next_line(&mut pos)?;
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = |m: String| DataError::line(path, no, m);
        match words.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                format = Some(match words.get(1).copied() {
                    Some("ascii") => PlyFormat::Ascii,
                    Some("binary_little_endian") => PlyFormat::BinaryLittleEndian,
                    Some("binary_big_endian") => PlyFormat::BinaryBigEndian,
                    other => return Err(bad(format!("unknown format {other:?}"))),
                })
            }
            Some("element") => {
                let (Some(name), Some(count)) = (words.get(1), words.get(2).and_then(|c| c.parse().ok())) else {
                    return Err(bad("expected `element NAME COUNT`".into()));
                };
                elements.push(Element { name: name.to_string(), count, properties: Vec::new() });
            }
            Some("property") => {
                let element = elements.last_mut().ok_or_else(|| bad("property before any element".into()))?;
                let scalar = |w: Option<&&str>| {
                    w.and_then(|w| Scalar::parse(w)).ok_or_else(|| bad(format!("unknown property type in `{line}`")))
                };
                let property = if words.get(1) == Some(&"list") {
                    Property::List { count: scalar(words.get(2))?, item: scalar(words.get(3))? }
                } else {
                    let name = words.get(2).ok_or_else(|| bad("property without a name".into()))?;
                    Property::Scalar { name: name.to_string(), kind: scalar(words.get(1))? }
                };
                element.properties.push(property);
            }
            Some("end_header") => break,
            Some(other) => return Err(bad(format!("unknown header keyword `{other}`"))),
        }
    }
    let format = format.ok_or_else(|| DataError::invalid(path, "no `format` line in the header"))?;
    Ok(PlyHeader { format, elements, body_start: pos, header_lines: line_no })
}

/// Which element is the vertex, and which of its properties are x, y, z and
/// the intensity.
struct VertexColumns {
    vertex: usize,
    x: usize,
    y: usize,
    z: usize,
    intensity: Option<usize>,
}

impl VertexColumns {
    fn of(path: &Path, elements: &[Element]) -> Result<Self> {
        let vertex = elements
            .iter()
            .position(|e| e.name == "vertex")
            .ok_or_else(|| DataError::invalid(path, "no `vertex` element"))?;
        let find = |names: &[&str]| {
            elements[vertex]
                .properties
                .iter()
                .position(|p| matches!(p, Property::Scalar { name, .. } if names.contains(&name.as_str())))
        };
        let missing = |axis: &str| DataError::invalid(path, format!("vertex element has no `{axis}` property"));
        Ok(Self {
            vertex,
            x: find(&["x"]).ok_or_else(|| missing("x"))?,
            y: find(&["y"]).ok_or_else(|| missing("y"))?,
            z: find(&["z"]).ok_or_else(|| missing("z"))?,
            intensity: find(&["intensity", "scalar_intensity", "scalar_Intensity"]),
        })
    }
}

fn read_ascii_body(
    path: &Path,
    bytes: &[u8],
    header: &PlyHeader,
    columns: &VertexColumns,
    cloud: &mut CloudBuilder<'_>,
) -> Result<()> {
    let (pos, header_lines, elements) = (header.body_start, header.header_lines, &header.elements);
    let (vertex_index, ix, iy, iz, ii) = (columns.vertex, columns.x, columns.y, columns.z, columns.intensity);
    let text = std::str::from_utf8(&bytes[pos..])
        .map_err(|e| DataError::byte(path, (pos + e.valid_up_to()) as u64, "ascii body is not text"))?;
    let mut lines = text.lines().enumerate().map(|(k, l)| (header_lines + 1 + k, l));
    for (e_index, element) in elements.iter().enumerate() {
        for item in 0..element.count {
            let (no, line) = lines.next().ok_or_else(|| {
                DataError::invalid(path, format!("file ends inside element `{}` (item {item})", element.name))
            })?;
            let values: Vec<f64> = line
                .split_whitespace()
                .map(|w| w.parse::<f64>().map_err(|_| DataError::line(path, no, format!("`{w}` is not a number"))))
                .collect::<Result<_>>()?;
            if e_index != vertex_index {
                continue;
            }
            // Scalars only before any list in a vertex line; lists make positions variable.
            let mut at = 0;
            let mut scalar_values = Vec::with_capacity(element.properties.len());
            for p in &element.properties {
                match p {
                    Property::Scalar { .. } => {
                        scalar_values.push(*values.get(at).ok_or_else(|| {
                            DataError::line(path, no, format!("expected more values, found {}", values.len()))
                        })?);
                        at += 1;
                    }
                    Property::List { .. } => {
                        let len = *values.get(at).unwrap_or(&0.0) as usize;
                        scalar_values.push(f64::NAN);
                        at += 1 + len;
                    }
                }
            }
            if at != values.len() {
                return Err(DataError::line(path, no, format!("expected {at} values, found {}", values.len())));
            }
            let v = |k: usize| scalar_values[k] as f32;
            cloud.push(item, [v(ix), v(iy), v(iz)], ii.map_or(0.0, v))?;
        }
    }
    // A count lower than the data would silently drop the rest.
    if let Some((no, _)) = lines.find(|(_, l)| !l.trim().is_empty()) {
        return Err(DataError::line(path, no, "data after the items the header declares"));
    }
    Ok(())
}

fn read_binary_body(
    path: &Path,
    bytes: &[u8],
    header: &PlyHeader,
    columns: &VertexColumns,
    cloud: &mut CloudBuilder<'_>,
) -> Result<()> {
    let (mut pos, format, elements) = (header.body_start, header.format, &header.elements);
    let (vertex_index, ix, iy, iz, ii) = (columns.vertex, columns.x, columns.y, columns.z, columns.intensity);
    let little = format == PlyFormat::BinaryLittleEndian;
    // Each item takes at least its scalars and list counts: a count the
    // rest of the file cannot hold is refused before the items are
    // walked (an element without properties would loop for nothing).
    let mut least = 0usize;
    for element in elements {
        let item_bytes: usize = element
            .properties
            .iter()
            .map(|p| match *p {
                Property::Scalar { kind, .. } => kind.size(),
                Property::List { count, .. } => count.size(),
            })
            .sum();
        if element.count > 0 && item_bytes == 0 {
            return Err(DataError::invalid(
                path,
                format!("element `{}` has {} items but no properties", element.name, element.count),
            ));
        }
        least = least.saturating_add(element.count.saturating_mul(item_bytes));
    }
    if least > bytes.len() - pos {
        return Err(DataError::byte(
            path,
            pos as u64,
            format!(
                "file ends inside the binary body: the header declares items of at least {least} bytes, \
                 the file has {} after it",
                bytes.len() - pos
            ),
        ));
    }
    let mut values = Vec::new();
    for (e_index, element) in elements.iter().enumerate() {
        for item in 0..element.count {
            values.clear();
            for p in &element.properties {
                match *p {
                    Property::Scalar { kind, .. } => {
                        values.push(kind.decode(take(path, bytes, &mut pos, kind.size())?, little));
                    }
                    Property::List { count, item: item_kind } => {
                        let len = count.decode(take(path, bytes, &mut pos, count.size())?, little);
                        if !(0.0..=1e9).contains(&len) {
                            return Err(DataError::byte(path, pos as u64, format!("bad list length {len}")));
                        }
                        take(path, bytes, &mut pos, len as usize * item_kind.size())?;
                        values.push(f64::NAN);
                    }
                }
            }
            if e_index == vertex_index {
                let v = |k: usize| values[k] as f32;
                cloud.push(item, [v(ix), v(iy), v(iz)], ii.map_or(0.0, v))?;
            }
        }
    }
    if pos < bytes.len() {
        return Err(DataError::byte(
            path,
            pos as u64,
            format!("{} bytes after the items the header declares", bytes.len() - pos),
        ));
    }
    Ok(())
}

/// Takes `len` bytes at `pos`, or fails naming where the file ended.
fn take<'a>(path: &Path, bytes: &'a [u8], pos: &mut usize, len: usize) -> Result<&'a [u8]> {
    if *pos + len > bytes.len() {
        return Err(DataError::byte(path, bytes.len() as u64, "file ends inside the binary body"));
    }
    let slice = &bytes[*pos..*pos + len];
    *pos += len;
    Ok(slice)
}

/// Writes a cloud as PLY (`x y z` and `intensity` when present, float32), atomically.
pub fn write_ply(path: &Path, cloud: &PointCloud, format: PlyFormat) -> Result<()> {
    crate::atomic::write_bytes(path, &ply_bytes(cloud, format))
}

/// Encodes a cloud as PLY.
pub fn ply_bytes(cloud: &PointCloud, format: PlyFormat) -> Vec<u8> {
    let mut out = Vec::new();
    let name = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
        PlyFormat::BinaryBigEndian => "binary_big_endian",
    };
    let _ = write!(out, "ply\nformat {name} 1.0\nelement vertex {}\n", cloud.len());
    let _ = write!(out, "property float x\nproperty float y\nproperty float z\n");
    if cloud.intensity.is_some() {
        let _ = writeln!(out, "property float intensity");
    }
    let _ = writeln!(out, "end_header");
    for (i, p) in cloud.points.iter().enumerate() {
        let mut values = vec![p.x, p.y, p.z];
        if let Some(v) = &cloud.intensity {
            values.push(v[i]);
        }
        match format {
            PlyFormat::Ascii => {
                let words: Vec<String> = values.iter().map(|v| v.to_string()).collect();
                let _ = writeln!(out, "{}", words.join(" "));
            }
            PlyFormat::BinaryLittleEndian => values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())),
            PlyFormat::BinaryBigEndian => values.iter().for_each(|v| out.extend_from_slice(&v.to_be_bytes())),
        }
    }
    out
}
