//! ROS 1 bags, format 2.0: records of a length-prefixed header (`name=value`
//! fields, `op` their kind) and a length-prefixed body. Messages live in
//! chunks, stored plain or compressed with bz2 or lz4; the index section at
//! `index_pos` lists the connections (topic, type) and each chunk's
//! per-connection counts and time span.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use crate::error::{DataError, Result};
use crate::io::recording::messages::{Encoding, canonical_type};
use crate::io::recording::{RawVisitor, TopicInfo};

const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX_DATA: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;
/// Largest chunk a reader unpacks (rosbag's default chunks are 768 KiB).
const MAX_CHUNK_BYTES: u64 = 1 << 30;

struct Record<'a> {
    offset: usize,
    fields: Vec<(&'a [u8], &'a [u8])>,
    data: &'a [u8],
}

impl<'a> Record<'a> {
    fn field(&self, name: &str) -> Option<&'a [u8]> {
        self.fields.iter().find(|(n, _)| *n == name.as_bytes()).map(|(_, v)| *v)
    }
    fn op(&self) -> Option<u8> {
        self.field("op").and_then(|v| v.first().copied())
    }
}

/// Reads records one after another; `base` is the slice's offset in the file, for messages.
struct Records<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
    base: usize,
    what: &'static str,
}

impl<'a> Records<'a> {
    fn error(&self, at: usize, message: impl std::fmt::Display) -> DataError {
        DataError::byte(self.path, (self.base + at) as u64, format!("{}: {message}", self.what))
    }
    fn u32_at(&self, at: usize) -> Result<u32> {
        self.bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
            .ok_or_else(|| self.error(at, "truncated: the file ends inside a record"))
    }
    fn slice(&self, at: usize, len: usize) -> Result<&'a [u8]> {
        let bytes: &'a [u8] = self.bytes;
        at.checked_add(len)
            .and_then(|end| bytes.get(at..end))
            .ok_or_else(|| self.error(at, format!("truncated: a {len}-byte record part runs past the end")))
    }
}

impl<'a> Iterator for Records<'a> {
    type Item = Result<Record<'a>>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let offset = self.pos;
        let read = || -> Result<(Record<'a>, usize)> {
            let header_len = self.u32_at(offset)? as usize;
            let header = self.slice(offset + 4, header_len)?;
            let data_at = offset + 4 + header_len;
            let data_len = self.u32_at(data_at)? as usize;
            let data = self.slice(data_at + 4, data_len)?;
            let mut fields = Vec::new();
            let mut k = 0;
            while k < header.len() {
                let len = header
                    .get(k..k + 4)
                    .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")) as usize)
                    .ok_or_else(|| self.error(offset + 4 + k, "record header field cut short"))?;
                let field = header
                    .get(k + 4..k + 4 + len)
                    .ok_or_else(|| self.error(offset + 4 + k, "record header field runs past its header"))?;
                let eq = field
                    .iter()
                    .position(|&b| b == b'=')
                    .ok_or_else(|| self.error(offset + 4 + k, "record header field without `=`"))?;
                fields.push((&field[..eq], &field[eq + 1..]));
                k += 4 + len;
            }
            Ok((Record { offset, fields, data }, data_at + 4 + data_len))
        };
        match read() {
            Ok((record, next)) => {
                self.pos = next;
                Some(Ok(record))
            }
            Err(e) => {
                self.pos = self.bytes.len();
                Some(Err(e))
            }
        }
    }
}

fn le_u32(v: Option<&[u8]>) -> Option<u32> {
    v.and_then(|b| b.try_into().ok()).map(u32::from_le_bytes)
}
fn le_u64(v: Option<&[u8]>) -> Option<u64> {
    v.and_then(|b| b.try_into().ok()).map(u64::from_le_bytes)
}
/// A ROS 1 `time` field (u32 seconds, u32 nanoseconds) in nanoseconds.
fn time_ns(v: Option<&[u8]>) -> Option<i64> {
    let b: [u8; 8] = v?.try_into().ok()?;
    let sec = u32::from_le_bytes(b[..4].try_into().expect("4")) as i64;
    let nsec = u32::from_le_bytes(b[4..].try_into().expect("4")) as i64;
    Some(sec * 1_000_000_000 + nsec)
}

struct Connection {
    topic: String,
    type_name: String,
}

fn connection(path: &Path, record: &Record<'_>) -> Result<(u32, Connection)> {
    let bad = |what: &str| DataError::byte(path, record.offset as u64, format!("connection record: {what}"));
    let id = le_u32(record.field("conn")).ok_or_else(|| bad("no `conn` id"))?;
    let topic = std::str::from_utf8(record.field("topic").ok_or_else(|| bad("no `topic`"))?)
        .map_err(|_| bad("topic is not UTF-8"))?
        .to_string();
    // The body is a connection header: the same `name=value` fields.
    let body = Records { path, bytes: record.data, pos: 0, base: record.offset, what: "connection header" };
    let mut type_name = None;
    let mut k = 0;
    while k + 4 <= body.bytes.len() {
        let len = body.u32_at(k)? as usize;
        let field = body.slice(k + 4, len)?;
        if let Some(value) = field.strip_prefix(b"type=") {
            type_name = Some(String::from_utf8_lossy(value).into_owned());
        }
        k += 4 + len;
    }
    let type_name = type_name.ok_or_else(|| bad(&format!("topic {topic} has no message type")))?;
    Ok((id, Connection { topic, type_name }))
}

/// What `visit_with` hands each message to: its connection, time (ns) and data.
type ConnectionVisitor<'v> = dyn FnMut(&Connection, i64, &[u8]) -> Result<()> + 'v;

pub struct Ros1Bag<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    index_pos: usize,
    first_record: usize,
}

impl<'a> Ros1Bag<'a> {
    pub fn new(path: &'a Path, bytes: &'a [u8]) -> Result<Self> {
        if !bytes.starts_with(MAGIC) {
            let version = bytes
                .starts_with(b"#ROSBAG V")
                .then(|| String::from_utf8_lossy(&bytes[..12.min(bytes.len())]).into_owned());
            return Err(DataError::invalid(
                path,
                match version {
                    Some(v) => format!("`{}`: only ROS bag format 2.0 is supported", v.trim()),
                    None => "not a ROS 1 bag (no `#ROSBAG V2.0` line)".to_string(),
                },
            ));
        }
        let mut records = Records { path, bytes, pos: MAGIC.len(), base: 0, what: "bag header" };
        let header = records.next().ok_or_else(|| DataError::invalid(path, "no bag header record"))??;
        if header.op() != Some(OP_BAG_HEADER) {
            return Err(DataError::byte(path, MAGIC.len() as u64, "the first record is not the bag header"));
        }
        let index_pos = le_u64(header.field("index_pos")).unwrap_or(0) as usize;
        if index_pos > bytes.len() {
            return Err(DataError::invalid(
                path,
                format!("truncated: the index is declared at byte {index_pos}, the file has {}", bytes.len()),
            ));
        }
        Ok(Self { path, bytes, index_pos, first_record: records.pos })
    }

    fn records(&self, from: usize, to: usize, what: &'static str) -> Records<'a> {
        Records { path: self.path, bytes: &self.bytes[..to], pos: from, base: 0, what }
    }

    fn chunk_data(&self, record: &Record<'a>) -> Result<std::borrow::Cow<'a, [u8]>> {
        let at = record.offset as u64;
        let compression = String::from_utf8_lossy(record.field("compression").unwrap_or(b"none")).into_owned();
        let size = le_u32(record.field("size"))
            .map(u64::from)
            .ok_or_else(|| DataError::byte(self.path, at, "chunk without a `size`"))?;
        if size > MAX_CHUNK_BYTES {
            return Err(DataError::byte(self.path, at, format!("chunk declares {size} bytes unpacked (over 1 GiB)")));
        }
        let mut out = Vec::with_capacity(size as usize);
        let result = match compression.as_str() {
            "none" => return Ok(std::borrow::Cow::Borrowed(record.data)),
            "bz2" => bzip2::read::BzDecoder::new(record.data).take(size + 1).read_to_end(&mut out),
            "lz4" => lz4::Decoder::new(record.data).and_then(|d| d.take(size + 1).read_to_end(&mut out)),
            other => {
                return Err(DataError::byte(
                    self.path,
                    at,
                    format!("chunk compression `{other}` is not supported (none, bz2, lz4)"),
                ));
            }
        };
        result.map_err(|e| DataError::byte(self.path, at, format!("{compression} chunk does not unpack: {e}")))?;
        if out.len() as u64 != size {
            return Err(DataError::byte(
                self.path,
                at,
                format!("{compression} chunk unpacks to {} bytes, its header says {size}", out.len()),
            ));
        }
        Ok(std::borrow::Cow::Owned(out))
    }

    /// Connections and chunk infos of the index section.
    fn index(&self) -> Result<(BTreeMap<u32, Connection>, Vec<Record<'a>>)> {
        let mut connections = BTreeMap::new();
        let mut infos = Vec::new();
        if self.index_pos == 0 {
            return Ok((connections, infos));
        }
        for record in self.records(self.index_pos, self.bytes.len(), "index") {
            let record = record?;
            match record.op() {
                Some(OP_CONNECTION) => {
                    let (id, c) = connection(self.path, &record)?;
                    connections.insert(id, c);
                }
                Some(OP_CHUNK_INFO) => infos.push(record),
                _ => {}
            }
        }
        Ok((connections, infos))
    }

    pub fn topics(&self) -> Result<Vec<TopicInfo>> {
        let (connections, infos) = self.index()?;
        let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
        let path = self.path;
        let topic_of = |topics: &mut BTreeMap<String, TopicInfo>, c: &Connection| -> Result<()> {
            let entry = topics.entry(c.topic.clone()).or_insert_with(|| TopicInfo {
                name: c.topic.clone(),
                type_name: canonical_type(&c.type_name),
                encoding: Encoding::Ros1,
                count: 0,
                first_ns: None,
                last_ns: None,
            });
            // Two connections of one topic with other types: which a role means is unknown.
            let other = canonical_type(&c.type_name);
            if entry.type_name != other {
                let problem = format!("topic {} carries two message types, {} and {other}", c.topic, entry.type_name);
                return Err(DataError::invalid(path, problem));
            }
            Ok(())
        };
        if connections.is_empty() || infos.is_empty() {
            // No index (a recording that was cut off): count by reading.
            self.visit_with(&mut |c: &Connection, t: i64, _| {
                topic_of(&mut topics, c)?;
                let entry = topics.get_mut(&c.topic).expect("inserted");
                entry.count += 1;
                entry.first_ns = Some(entry.first_ns.map_or(t, |f| f.min(t)));
                entry.last_ns = Some(entry.last_ns.map_or(t, |l| l.max(t)));
                Ok(())
            })?;
            return Ok(topics.into_values().collect());
        }
        for c in connections.values() {
            topic_of(&mut topics, c)?;
        }
        // The index records after each chunk hold every message's time per
        // connection: exact spans without unpacking a chunk.
        let mut spans: BTreeMap<u32, (i64, i64)> = BTreeMap::new();
        for record in self.records(self.first_record, self.index_pos, "index data") {
            let record = record?;
            if record.op() != Some(OP_INDEX_DATA) {
                continue;
            }
            let Some(id) = le_u32(record.field("conn")) else { continue };
            for entry in record.data.chunks_exact(12) {
                if let Some(t) = time_ns(Some(&entry[..8])) {
                    let span = spans.entry(id).or_insert((t, t));
                    span.0 = span.0.min(t);
                    span.1 = span.1.max(t);
                }
            }
        }
        for info in &infos {
            let (start, end) = (time_ns(info.field("start_time")), time_ns(info.field("end_time")));
            for pair in info.data.chunks_exact(8) {
                let id = u32::from_le_bytes(pair[..4].try_into().expect("4"));
                let count = u32::from_le_bytes(pair[4..].try_into().expect("4")) as u64;
                let Some(c) = connections.get(&id) else {
                    return Err(DataError::byte(
                        self.path,
                        info.offset as u64,
                        format!("chunk info names unknown connection {id}"),
                    ));
                };
                let entry = topics.get_mut(&c.topic).expect("inserted");
                entry.count += count;
                if let Some(&(s, e)) = spans.get(&id) {
                    entry.first_ns = Some(entry.first_ns.map_or(s, |f| f.min(s)));
                    entry.last_ns = Some(entry.last_ns.map_or(e, |l| l.max(e)));
                } else if let (Some(s), Some(e)) = (start, end) {
                    entry.first_ns = Some(entry.first_ns.map_or(s, |f| f.min(s)));
                    entry.last_ns = Some(entry.last_ns.map_or(e, |l| l.max(e)));
                }
            }
        }
        Ok(topics.into_values().collect())
    }

    fn visit_with(&self, visit: &mut ConnectionVisitor<'_>) -> Result<()> {
        let (mut connections, _) = self.index()?;
        let end = if self.index_pos == 0 { self.bytes.len() } else { self.index_pos };
        let mut handle =
            |connections: &mut BTreeMap<u32, Connection>, record: &Record<'_>, base: usize| -> Result<()> {
                match record.op() {
                    Some(OP_CONNECTION) => {
                        let (id, c) = connection(self.path, record)?;
                        connections.entry(id).or_insert(c);
                    }
                    Some(OP_MESSAGE) => {
                        let at = (base + record.offset) as u64;
                        let id = le_u32(record.field("conn"))
                            .ok_or_else(|| DataError::byte(self.path, at, "message record without `conn`"))?;
                        let time = time_ns(record.field("time"))
                            .ok_or_else(|| DataError::byte(self.path, at, "message record without `time`"))?;
                        let c = connections.get(&id).ok_or_else(|| {
                            DataError::byte(self.path, at, format!("message of unknown connection {id}"))
                        })?;
                        visit(c, time, record.data)?;
                    }
                    _ => {}
                }
                Ok(())
            };
        for record in self.records(self.first_record, end, "record") {
            let record = record?;
            match record.op() {
                Some(OP_CHUNK) => {
                    let data = self.chunk_data(&record)?;
                    let inner =
                        Records { path: self.path, bytes: &data, pos: 0, base: record.offset, what: "chunk record" };
                    for r in inner {
                        handle(&mut connections, &r?, 0)?;
                    }
                }
                _ => handle(&mut connections, &record, 0)?,
            }
        }
        Ok(())
    }

    /// Visits every message in file order.
    pub fn visit(&self, visit: &mut RawVisitor<'_>) -> Result<()> {
        self.visit_with(&mut |c, t, data| visit(&c.topic, t, data))
    }
}
