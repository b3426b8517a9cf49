//! The two wire formats of ROS messages, behind one reader trait so that
//! each message is decoded by one function for both ROS versions:
//!
//! - ROS 2 CDR (XCDR1, what rmw implementations send): a 4-byte
//!   encapsulation header (representation and options), then every
//!   primitive aligned to its own size, counted from the end of that header;
//!   strings are a `u32` length that includes a terminating NUL.
//! - ROS 1: little endian, packed (no alignment), strings without the NUL,
//!   `time` as `u32` seconds and `u32` nanoseconds, and a `seq` counter at
//!   the front of every `std_msgs/Header`.

use crate::math::{Pose3, Rot3, Vec3};

/// Why a message could not be decoded; the caller adds the file, topic and
/// message index.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct WireError(pub String);

pub type WireResult<T> = std::result::Result<T, WireError>;

pub fn wire_error(message: impl Into<String>) -> WireError {
    WireError(message.into())
}

/// `std_msgs/Header` without ROS 1's `seq`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Header {
    /// Nanoseconds since the epoch of the recording's clock.
    pub stamp_ns: i64,
    pub frame_id: String,
}

impl Header {
    pub fn stamp_s(&self) -> f64 {
        ns_to_s(self.stamp_ns)
    }
}

/// Seconds from nanoseconds, to the f64's precision: whole seconds and the
/// fraction are converted apart (the fraction correctly rounded), so an
/// epoch stamp keeps its nanoseconds as well as an f64 can.
pub fn ns_to_s(ns: i64) -> f64 {
    ns.div_euclid(1_000_000_000) as f64 + ns.rem_euclid(1_000_000_000) as f64 / 1e9
}

/// Reads the primitives of one serialised message.
pub trait WireReader<'a> {
    fn u8(&mut self) -> WireResult<u8>;
    fn u16(&mut self) -> WireResult<u16>;
    fn u32(&mut self) -> WireResult<u32>;
    fn i32(&mut self) -> WireResult<i32>;
    fn f32(&mut self) -> WireResult<f32>;
    fn f64(&mut self) -> WireResult<f64>;
    fn string(&mut self) -> WireResult<String>;
    /// `n` raw bytes (a `uint8[]`'s payload).
    fn bytes(&mut self, n: usize) -> WireResult<&'a [u8]>;
    /// The bytes not read yet.
    fn remaining(&self) -> usize;
    /// A `time` / `builtin_interfaces/Time`, in nanoseconds.
    fn time(&mut self) -> WireResult<i64>;
    /// A `std_msgs/Header`.
    fn header(&mut self) -> WireResult<Header>;

    fn bool(&mut self) -> WireResult<bool> {
        Ok(self.u8()? != 0)
    }

    /// The length of a sequence whose elements take at least `element_bytes`
    /// each: a length the message cannot hold is an error, not an allocation.
    fn sequence_len(&mut self, element_bytes: usize) -> WireResult<usize> {
        let n = self.u32()? as usize;
        if n.saturating_mul(element_bytes.max(1)) > self.remaining() {
            return Err(wire_error(format!(
                "sequence of {n} elements does not fit in the {} bytes left",
                self.remaining()
            )));
        }
        Ok(n)
    }

    fn byte_sequence(&mut self) -> WireResult<&'a [u8]> {
        let n = self.sequence_len(1)?;
        self.bytes(n)
    }

    fn f64_sequence(&mut self) -> WireResult<Vec<f64>> {
        let n = self.sequence_len(8)?;
        (0..n).map(|_| self.f64()).collect()
    }

    /// `N` doubles of a fixed-size array.
    fn f64s(&mut self, n: usize) -> WireResult<Vec<f64>> {
        (0..n).map(|_| self.f64()).collect()
    }

    fn vector3(&mut self) -> WireResult<Vec3> {
        let (x, y, z) = (self.f64()?, self.f64()?, self.f64()?);
        Ok(Vec3::new(x, y, z))
    }

    /// `geometry_msgs/Quaternion` (x, y, z, w); a zero or non-finite one is an error.
    fn quaternion(&mut self) -> WireResult<Rot3> {
        let (x, y, z, w) = (self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        let q = nalgebra::Quaternion::new(w, x, y, z);
        if !q.coords.iter().all(|v| v.is_finite()) || q.norm() < 1e-6 {
            return Err(wire_error(format!("quaternion ({x}, {y}, {z}, {w}) is not a rotation")));
        }
        Ok(Rot3::from_quaternion(q))
    }

    /// `geometry_msgs/Pose` (position, orientation) or `Transform`
    /// (translation, rotation): the same layout.
    fn pose(&mut self) -> WireResult<Pose3> {
        let t = self.vector3()?;
        if !t.iter().all(|v| v.is_finite()) {
            return Err(wire_error(format!("position {t:?} is not finite")));
        }
        let q = self.quaternion()?;
        Ok(Pose3::from_parts(t.into(), q))
    }
}

/// Bounds-checked cursor over a byte slice.
struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> WireResult<&'a [u8]> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len()).ok_or_else(|| {
            wire_error(format!("message ends at byte {}, {n} more bytes needed at byte {}", self.data.len(), self.pos))
        })?;
        let out = &self.data[self.pos..end];
        self.pos = end;
        Ok(out)
    }
    fn array<const N: usize>(&mut self) -> WireResult<[u8; N]> {
        Ok(self.take(N)?.try_into().expect("N bytes"))
    }
}

fn utf8(bytes: &[u8]) -> WireResult<String> {
    String::from_utf8(bytes.to_vec()).map_err(|_| wire_error("string is not UTF-8"))
}

/// ROS 2 CDR, either byte order.
pub struct CdrReader<'a> {
    cursor: Cursor<'a>,
    big_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// Reads the encapsulation header; only plain CDR (big or little endian) is accepted.
    pub fn new(message: &'a [u8]) -> WireResult<Self> {
        if message.len() < 4 {
            return Err(wire_error(format!("{} bytes: shorter than the 4-byte CDR header", message.len())));
        }
        let big_endian = match (message[0], message[1]) {
            (0, 0) => true,
            (0, 1) => false,
            (a, b) => {
                return Err(wire_error(format!(
                    "CDR representation {a:#04x}{b:02x} is not plain CDR (0x0000 or 0x0001; XCDR2 and parameter lists are not supported)"
                )));
            }
        };
        // Alignment counts from here, after the encapsulation header.
        Ok(Self { cursor: Cursor { data: &message[4..], pos: 0 }, big_endian })
    }

    fn align(&mut self, n: usize) {
        // Padding past the end is caught by the read that follows it.
        self.cursor.pos += (n - self.cursor.pos % n) % n;
    }

    fn fixed<const N: usize>(&mut self) -> WireResult<[u8; N]> {
        self.align(N);
        let mut b = self.cursor.array::<N>()?;
        if self.big_endian {
            b.reverse();
        }
        Ok(b)
    }
}

impl<'a> WireReader<'a> for CdrReader<'a> {
    fn u8(&mut self) -> WireResult<u8> {
        Ok(self.cursor.array::<1>()?[0])
    }
    fn u16(&mut self) -> WireResult<u16> {
        Ok(u16::from_le_bytes(self.fixed()?))
    }
    fn u32(&mut self) -> WireResult<u32> {
        Ok(u32::from_le_bytes(self.fixed()?))
    }
    fn i32(&mut self) -> WireResult<i32> {
        Ok(i32::from_le_bytes(self.fixed()?))
    }
    fn f32(&mut self) -> WireResult<f32> {
        Ok(f32::from_le_bytes(self.fixed()?))
    }
    fn f64(&mut self) -> WireResult<f64> {
        Ok(f64::from_le_bytes(self.fixed()?))
    }
    fn string(&mut self) -> WireResult<String> {
        let n = self.sequence_len(1)?;
        let bytes = self.cursor.take(n)?;
        // The length counts the terminating NUL.
        utf8(bytes.strip_suffix(&[0]).unwrap_or(bytes))
    }
    fn bytes(&mut self, n: usize) -> WireResult<&'a [u8]> {
        self.cursor.take(n)
    }
    fn remaining(&self) -> usize {
        self.cursor.data.len().saturating_sub(self.cursor.pos)
    }
    fn time(&mut self) -> WireResult<i64> {
        let sec = self.i32()? as i64;
        let nanosec = self.u32()? as i64;
        Ok(sec * 1_000_000_000 + nanosec)
    }
    fn header(&mut self) -> WireResult<Header> {
        let stamp_ns = self.time()?;
        Ok(Header { stamp_ns, frame_id: self.string()? })
    }
}

/// ROS 1 serialisation.
pub struct Ros1Reader<'a> {
    cursor: Cursor<'a>,
}

impl<'a> Ros1Reader<'a> {
    pub fn new(message: &'a [u8]) -> Self {
        Self { cursor: Cursor { data: message, pos: 0 } }
    }
}

impl<'a> WireReader<'a> for Ros1Reader<'a> {
    fn u8(&mut self) -> WireResult<u8> {
        Ok(self.cursor.array::<1>()?[0])
    }
    fn u16(&mut self) -> WireResult<u16> {
        Ok(u16::from_le_bytes(self.cursor.array()?))
    }
    fn u32(&mut self) -> WireResult<u32> {
        Ok(u32::from_le_bytes(self.cursor.array()?))
    }
    fn i32(&mut self) -> WireResult<i32> {
        Ok(i32::from_le_bytes(self.cursor.array()?))
    }
    fn f32(&mut self) -> WireResult<f32> {
        Ok(f32::from_le_bytes(self.cursor.array()?))
    }
    fn f64(&mut self) -> WireResult<f64> {
        Ok(f64::from_le_bytes(self.cursor.array()?))
    }
    fn string(&mut self) -> WireResult<String> {
        let n = self.sequence_len(1)?;
        utf8(self.cursor.take(n)?)
    }
    fn bytes(&mut self, n: usize) -> WireResult<&'a [u8]> {
        self.cursor.take(n)
    }
    fn remaining(&self) -> usize {
        self.cursor.data.len().saturating_sub(self.cursor.pos)
    }
    fn time(&mut self) -> WireResult<i64> {
        let sec = self.u32()? as i64;
        let nsec = self.u32()? as i64;
        Ok(sec * 1_000_000_000 + nsec)
    }
    fn header(&mut self) -> WireResult<Header> {
        let _seq = self.u32()?;
        let stamp_ns = self.time()?;
        Ok(Header { stamp_ns, frame_id: self.string()? })
    }
}

/// Writes ROS 2 CDR, little endian (what `datagen --bag` records).
#[derive(Default)]
pub struct CdrWriter {
    out: Vec<u8>,
}

impl CdrWriter {
    pub fn new() -> Self {
        Self { out: vec![0, 1, 0, 0] }
    }
    pub fn finish(self) -> Vec<u8> {
        self.out
    }
    fn align(&mut self, n: usize) {
        let pos = self.out.len() - 4;
        let pad = (n - pos % n) % n;
        self.out.extend(std::iter::repeat_n(0, pad));
    }
    pub fn u8(&mut self, v: u8) {
        self.out.push(v);
    }
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.out.extend_from_slice(&v.to_le_bytes());
    }
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.out.extend_from_slice(&v.to_le_bytes());
    }
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.out.extend_from_slice(s.as_bytes());
        self.out.push(0);
    }
    pub fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.out.extend_from_slice(b);
    }
    pub fn f64s(&mut self, values: &[f64]) {
        values.iter().for_each(|&v| self.f64(v));
    }
    pub fn time(&mut self, ns: i64) {
        self.i32(ns.div_euclid(1_000_000_000) as i32);
        self.u32(ns.rem_euclid(1_000_000_000) as u32);
    }
    pub fn header(&mut self, header: &Header) {
        self.time(header.stamp_ns);
        self.string(&header.frame_id);
    }
    pub fn pose(&mut self, pose: &Pose3) {
        let t = pose.translation.vector;
        let q = pose.rotation.coords;
        self.f64s(&[t.x, t.y, t.z, q.x, q.y, q.z, q.w]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `uint8` then a `float64`: in CDR the double sits at offset 8
    /// counted from after the 4-byte encapsulation header (byte 12 of the
    /// message), not at offset 8 of the message.
    fn u8_then_f64(big_endian: bool, value: f64) -> Vec<u8> {
        let mut bytes = vec![0, if big_endian { 0 } else { 1 }, 0, 0, 7, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA];
        bytes.extend_from_slice(&if big_endian { value.to_be_bytes() } else { value.to_le_bytes() });
        bytes
    }

    #[test]
    fn cdr_alignment_counts_from_after_the_encapsulation_header() {
        for big_endian in [false, true] {
            let bytes = u8_then_f64(big_endian, 1.25);
            let mut r = CdrReader::new(&bytes).unwrap();
            assert_eq!(r.u8().unwrap(), 7);
            assert_eq!(r.f64().unwrap(), 1.25, "big endian {big_endian}");
            assert_eq!(r.remaining(), 0);
        }
    }

    #[test]
    fn cdr_strings_count_their_nul_and_sequences_are_bounded() {
        let mut w = CdrWriter::new();
        w.string("map");
        w.f64(-2.5);
        w.time(1_700_000_000_123_456_789);
        let bytes = w.finish();
        // length 4 ("map\0") at 0, the double aligned to 8, then sec and nanosec.
        assert_eq!(&bytes[4..12], &[4, 0, 0, 0, b'm', b'a', b'p', 0]);
        let mut r = CdrReader::new(&bytes).unwrap();
        assert_eq!(r.string().unwrap(), "map");
        assert_eq!(r.f64().unwrap(), -2.5);
        assert_eq!(r.time().unwrap(), 1_700_000_000_123_456_789);
        let mut short = CdrReader::new(&[0, 1, 0, 0, 255, 255, 255, 255]).unwrap();
        assert!(short.byte_sequence().unwrap_err().0.contains("does not fit"));
        assert!(CdrReader::new(&[0, 7, 0, 0]).err().unwrap().0.contains("XCDR2"));
    }

    #[test]
    fn ros1_is_packed_with_a_seq_in_the_header() {
        let mut bytes = Vec::new();
        bytes.extend_from_slice(&9u32.to_le_bytes());
        bytes.extend_from_slice(&12u32.to_le_bytes());
        bytes.extend_from_slice(&500u32.to_le_bytes());
        bytes.extend_from_slice(&4u32.to_le_bytes());
        bytes.extend_from_slice(b"odom");
        bytes.push(3);
        bytes.extend_from_slice(&0.5f64.to_le_bytes());
        let mut r = Ros1Reader::new(&bytes);
        assert_eq!(r.header().unwrap(), Header { stamp_ns: 12_000_000_500, frame_id: "odom".into() });
        assert_eq!(r.u8().unwrap(), 3);
        assert_eq!(r.f64().unwrap(), 0.5, "no padding before a double");
    }

    #[test]
    fn nanoseconds_become_seconds_without_losing_the_fraction() {
        assert_eq!(ns_to_s(1_700_000_000_500_000_000), 1_700_000_000.5);
        assert!((ns_to_s(-1) + 1e-9).abs() < 1e-15);
    }
}
