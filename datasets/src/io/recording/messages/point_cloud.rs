//! `sensor_msgs/PointCloud2` with any field layout: x/y/z of any numeric
//! type (float32 and float64 in practice), optional intensity and per-point
//! time, padding, `point_step`, `row_step`, either byte order, organised
//! (height > 1) and unorganised clouds, NaN points (dropped and counted).

use crate::io::formats::PointCloud;
use crate::io::recording::messages::ensure;
use crate::io::recording::wire::{Header, WireReader, WireResult, wire_error};
use crate::math::Pose3;

/// `sensor_msgs/PointField` datatypes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldType {
    I8 = 1,
    U8 = 2,
    I16 = 3,
    U16 = 4,
    I32 = 5,
    U32 = 6,
    F32 = 7,
    F64 = 8,
}

impl FieldType {
    pub fn from_code(code: u8) -> Option<Self> {
        use FieldType::*;
        [I8, U8, I16, U16, I32, U32, F32, F64].into_iter().find(|t| *t as u8 == code)
    }
    pub fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
    fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

/// A decoded cloud: the points in `header.frame_id` and, when the cloud has
/// a time field, each point's time relative to `header.stamp` (seconds).
#[derive(Debug, Clone, PartialEq)]
pub struct CloudMessage {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub cloud: PointCloud,
}

/// Names a per-point time field goes by (Ouster `t`, Velodyne `time`,
/// Hesai and Livox `timestamp`).
const TIME_FIELDS: [&str; 4] = ["t", "time", "timestamp", "time_stamp"];

#[derive(Clone, Copy)]
struct Slot {
    offset: usize,
    kind: FieldType,
}

fn read_value(point: &[u8], slot: Slot, big_endian: bool) -> f64 {
    let b = &point[slot.offset..slot.offset + slot.kind.size()];
    macro_rules! num {
        ($t:ty) => {{
            let bytes = b.try_into().expect("field size");
            (if big_endian { <$t>::from_be_bytes(bytes) } else { <$t>::from_le_bytes(bytes) }) as f64
        }};
    }
    match slot.kind {
        FieldType::I8 => b[0] as i8 as f64,
        FieldType::U8 => b[0] as f64,
        FieldType::I16 => num!(i16),
        FieldType::U16 => num!(u16),
        FieldType::I32 => num!(i32),
        FieldType::U32 => num!(u32),
        FieldType::F32 => num!(f32),
        FieldType::F64 => num!(f64),
    }
}

pub fn point_cloud2(r: &mut dyn WireReader<'_>) -> WireResult<CloudMessage> {
    let header = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let n_fields = r.sequence_len(13)?;
    let mut fields = Vec::with_capacity(n_fields);
    for _ in 0..n_fields {
        let name = r.string()?;
        let offset = r.u32()?;
        let datatype = r.u8()?;
        let count = r.u32()?;
        fields.push(PointField { name, offset, datatype, count });
    }
    let big_endian = r.bool()?;
    let point_step = r.u32()? as usize;
    let row_step = r.u32()? as usize;
    let data = r.byte_sequence()?;
    let _is_dense = r.bool().unwrap_or(false);

    let slot = |name: &str| -> WireResult<Option<Slot>> {
        let Some(f) = fields.iter().find(|f| f.name == name && f.count > 0) else { return Ok(None) };
        let kind = FieldType::from_code(f.datatype)
            .ok_or_else(|| wire_error(format!("field `{name}` has unknown datatype {}", f.datatype)))?;
        ensure(f.offset as usize + kind.size() <= point_step, || {
            format!("field `{name}` (offset {}, {} bytes) lies outside point_step {point_step}", f.offset, kind.size())
        })?;
        Ok(Some(Slot { offset: f.offset as usize, kind }))
    };
    let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
    let [x, y, z] = ["x", "y", "z"].map(slot);
    let (Some(x), Some(y), Some(z)) = (x?, y?, z?) else {
        return Err(wire_error(format!("the cloud has no x, y and z fields (fields: {})", names.join(", "))));
    };
    let intensity = slot("intensity")?;
    let time = TIME_FIELDS.iter().map(|n| slot(n)).find_map(|s| s.transpose()).transpose()?;

    let points = (width as u64) * (height as u64);
    let row_bytes = (width as u64) * (point_step as u64);
    ensure(point_step > 0 || points == 0, || "point_step is 0".into())?;
    ensure(height <= 1 || row_step as u64 >= row_bytes, || {
        format!("row_step {row_step} is less than width {width} x point_step {point_step}")
    })?;
    let needed = if height == 0 { 0 } else { (height as u64 - 1) * row_step as u64 + row_bytes };
    ensure(needed <= data.len() as u64, || {
        format!(
            "{width} x {height} points of {point_step} bytes need {needed} bytes of data, the message has {}",
            data.len()
        )
    })?;

    let mut cloud = PointCloud::new(Vec::with_capacity(points as usize), intensity.map(|_| Vec::new()));
    let mut times = time.map(|_| Vec::new());
    let stamp_s = header.stamp_s();
    for row in 0..height as usize {
        let row_data = &data[row * row_step..];
        for col in 0..width as usize {
            let point = &row_data[col * point_step..(col + 1) * point_step];
            let xyz = [x, y, z].map(|s| read_value(point, s, big_endian) as f32);
            if !xyz.iter().all(|v| v.is_finite()) {
                cloud.dropped_non_finite += 1;
                continue;
            }
            cloud.points.push(xyz.into());
            if let (Some(values), Some(s)) = (&mut cloud.intensity, intensity) {
                values.push(read_value(point, s, big_endian) as f32);
            }
            if let (Some(values), Some(s)) = (&mut times, time) {
                values.push(relative_time(read_value(point, s, big_endian), s.kind, stamp_s) as f32);
            }
        }
    }
    if let Some(t) = &times
        && let Some(bad) = t.iter().find(|v| !v.is_finite() || v.abs() > 10.0)
    {
        return Err(wire_error(format!("a point's time is {bad} s from the header stamp (more than 10 s)")));
    }
    cloud.times = times;
    cloud.viewpoint = Pose3::identity();
    Ok(CloudMessage { header, height, width, fields, cloud })
}

/// A per-point time as seconds after the header stamp: integers are
/// nanoseconds after it (Ouster); floats are seconds after it (Velodyne),
/// or, when they are large enough to be absolute, epoch seconds (Hesai) or
/// epoch nanoseconds.
fn relative_time(value: f64, kind: FieldType, stamp_s: f64) -> f64 {
    if kind.is_integer() {
        value * 1e-9
    } else if value > 1e15 {
        value * 1e-9 - stamp_s
    } else if value > 1e8 {
        value - stamp_s
    } else {
        value
    }
}
