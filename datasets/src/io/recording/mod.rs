//! Robot recordings: ROS 2 bags (a rosbag2 folder with sqlite3 or MCAP
//! storage, a bare `.mcap`, a `.db3`) and ROS 1 `.bag` files, read as one
//! stream of `(topic, log time, serialised message)` in file order, with the
//! topics' types, counts and time spans for `localize inspect`.

pub mod mcap_export;
pub mod mcap_file;
mod mcap_lengths;
pub mod messages;
pub mod pose_topic;
pub mod ros1_bag;
pub mod rosbag2;
pub mod sqlite3;
pub mod tf_tree;
pub mod wire;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{DataError, Result};
pub use messages::{Encoding, MessageKind};
use rosbag2::{Compression, Storage};

/// A topic of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    pub name: String,
    /// The ROS 2 form of the type name (`sensor_msgs/msg/Imu`).
    pub type_name: String,
    pub encoding: Encoding,
    pub count: u64,
    /// Log times (ns) of its first and last message, when it has any.
    pub first_ns: Option<i64>,
    pub last_ns: Option<i64>,
}

impl TopicInfo {
    pub fn kind(&self) -> Option<MessageKind> {
        MessageKind::of(&self.type_name)
    }
    /// Messages per second over the topic's own span.
    pub fn rate_hz(&self) -> Option<f64> {
        let (first, last) = (self.first_ns?, self.last_ns?);
        (self.count > 1 && last > first).then(|| (self.count - 1) as f64 / ((last - first) as f64 * 1e-9))
    }
}

/// One message as stored: `index` counts the topic's messages in file order from 0.
#[derive(Debug, Clone, Copy)]
pub struct RawMessage<'m> {
    pub topic: usize,
    pub index: u64,
    pub log_time_ns: i64,
    pub data: &'m [u8],
}

/// What the containers hand each message to: topic name, log time (ns), data.
pub type RawVisitor<'v> = dyn FnMut(&str, i64, &[u8]) -> Result<()> + 'v;

#[derive(Debug, Clone)]
enum Source {
    Mcap(Vec<PathBuf>),
    Sqlite(Vec<PathBuf>),
    Ros1(PathBuf),
}

/// An opened recording.
#[derive(Debug, Clone)]
pub struct Recording {
    pub path: PathBuf,
    /// What it is, in words (`rosbag2 folder, mcap storage`, `ROS 1 bag`, ...).
    pub format: String,
    pub topics: Vec<TopicInfo>,
    source: Source,
    compression: Compression,
}

/// Largest single file or message unpacked from zstd.
const MAX_UNPACKED_BYTES: u64 = 16 << 30;

fn map_file(path: &Path) -> Result<memmap2::Mmap> {
    crate::atomic::check_regular(path)?;
    let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
    // SAFETY: the map is read only; a recording that another process
    // truncates while we read it is outside what any reader can promise.
    unsafe { memmap2::Mmap::map(&file) }.map_err(|e| DataError::io(path, e))
}

impl Recording {
    /// Opens a rosbag2 folder, a `.mcap`, a `.db3` or a ROS 1 `.bag`
    /// (decided by what the path is, then by the file's first bytes).
    pub fn open(path: &Path) -> Result<Self> {
        let (source, compression, format) = if path.is_dir() {
            let meta = rosbag2::read_metadata(path)?;
            let storage = match meta.storage {
                Storage::Mcap => "mcap",
                Storage::Sqlite3 => "sqlite3",
            };
            let format = match meta.compression {
                Compression::None => format!("rosbag2 folder, {storage} storage"),
                Compression::File => format!("rosbag2 folder, {storage} storage, zstd-compressed files"),
                Compression::Message => format!("rosbag2 folder, {storage} storage, zstd-compressed messages"),
            };
            let source = match meta.storage {
                Storage::Mcap => Source::Mcap(meta.files),
                Storage::Sqlite3 => Source::Sqlite(meta.files),
            };
            (source, meta.compression, format)
        } else if path.is_file() {
            let mut head = [0u8; 16];
            let n = {
                use std::io::Read;
                let mut f = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
                f.read(&mut head).map_err(|e| DataError::io(path, e))?
            };
            let head = &head[..n];
            if head.starts_with(b"\x89MCAP") {
                (Source::Mcap(vec![path.to_path_buf()]), Compression::None, "MCAP file".to_string())
            } else if head.starts_with(b"SQLite format 3") {
                // A .db3 beside its metadata.yaml may be one split of several: read them all.
                let beside = path.parent().filter(|d| d.join("metadata.yaml").is_file());
                match beside {
                    Some(dir) => return Self::open(dir),
                    None => {
                        (Source::Sqlite(vec![path.to_path_buf()]), Compression::None, "rosbag2 sqlite3 file".into())
                    }
                }
            } else if head.starts_with(b"#ROSBAG") {
                (Source::Ros1(path.to_path_buf()), Compression::None, "ROS 1 bag".to_string())
            } else {
                return Err(DataError::invalid(
                    path,
                    "not a recording (expected a rosbag2 folder, an MCAP file, a rosbag2 .db3 or a ROS 1 .bag)",
                ));
            }
        } else {
            return Err(DataError::invalid(path, crate::atomic::why_unreadable(path)));
        };
        let mut recording = Self { path: path.to_path_buf(), format, topics: Vec::new(), source, compression };
        recording.topics = recording.read_topics()?;
        Ok(recording)
    }

    fn with_file_bytes<T>(&self, file: &Path, f: impl FnOnce(&[u8]) -> Result<T>) -> Result<T> {
        let map = map_file(file)?;
        if self.compression == Compression::File {
            f(&rosbag2::unzstd(file, &map, MAX_UNPACKED_BYTES)?)
        } else {
            f(&map)
        }
    }

    /// A sqlite3 split as a file on disk (unpacked into a temporary file when compressed).
    fn with_sqlite<T>(&self, file: &Path, f: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
        if self.compression != Compression::File {
            return f(file);
        }
        let bytes = self.with_file_bytes(file, |b| Ok(b.to_vec()))?;
        let tmp = tempfile::Builder::new().suffix(".db3").tempfile().map_err(|e| DataError::io(file, e))?;
        std::fs::write(tmp.path(), bytes).map_err(|e| DataError::io(tmp.path(), e))?;
        f(tmp.path())
    }

    fn read_topics(&self) -> Result<Vec<TopicInfo>> {
        let parts: Vec<Vec<TopicInfo>> = match &self.source {
            Source::Mcap(files) => {
                files.iter().map(|f| self.with_file_bytes(f, |b| mcap_file::topics(f, b))).collect::<Result<_>>()?
            }
            Source::Sqlite(files) => {
                files.iter().map(|f| self.with_sqlite(f, sqlite3::topics)).collect::<Result<_>>()?
            }
            Source::Ros1(file) => {
                let map = map_file(file)?;
                vec![ros1_bag::Ros1Bag::new(file, &map)?.topics()?]
            }
        };
        let mut merged: Vec<TopicInfo> = Vec::new();
        for topic in parts.into_iter().flatten() {
            match merged.iter_mut().find(|t| t.name == topic.name) {
                Some(t) if t.type_name != topic.type_name => {
                    return Err(DataError::invalid(
                        &self.path,
                        format!("topic {} has two types: {} and {}", t.name, t.type_name, topic.type_name),
                    ));
                }
                Some(t) => {
                    t.count += topic.count;
                    t.first_ns = [t.first_ns, topic.first_ns].into_iter().flatten().min();
                    t.last_ns = [t.last_ns, topic.last_ns].into_iter().flatten().max();
                }
                None => merged.push(topic),
            }
        }
        merged.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(merged)
    }

    pub fn topic(&self, name: &str) -> Option<usize> {
        self.topics.iter().position(|t| t.name == name)
    }

    /// Earliest and latest log time (ns) over all topics.
    pub fn span_ns(&self) -> Option<(i64, i64)> {
        let first = self.topics.iter().filter_map(|t| t.first_ns).min()?;
        let last = self.topics.iter().filter_map(|t| t.last_ns).max()?;
        Some((first, last))
    }

    /// Visits the messages of the `wanted` topics (indices into `topics`)
    /// in file order; every topic's messages are counted, wanted or not,
    /// so `index` names the message as `ros2 bag` would count it.
    pub fn read(&self, wanted: &[usize], visit: &mut dyn FnMut(RawMessage<'_>) -> Result<()>) -> Result<()> {
        let by_name: HashMap<&str, usize> = self.topics.iter().enumerate().map(|(k, t)| (t.name.as_str(), k)).collect();
        let mut want = vec![false; self.topics.len()];
        wanted.iter().for_each(|&k| want[k] = true);
        let mut counts = vec![0u64; self.topics.len()];
        let message_compression = self.compression == Compression::Message;
        let mut on_message = |name: &str, log_time_ns: i64, data: &[u8]| -> Result<()> {
            let Some(&topic) = by_name.get(name) else { return Ok(()) };
            let index = counts[topic];
            counts[topic] += 1;
            if !want[topic] {
                return Ok(());
            }
            if message_compression {
                let unpacked = rosbag2::unzstd(&self.path, data, MAX_UNPACKED_BYTES)
                    .map_err(|e| DataError::message(&self.path, name, index, e.to_string()))?;
                visit(RawMessage { topic, index, log_time_ns, data: &unpacked })
            } else {
                visit(RawMessage { topic, index, log_time_ns, data })
            }
        };
        match &self.source {
            Source::Mcap(files) => {
                for f in files {
                    self.with_file_bytes(f, |b| mcap_file::visit(f, b, &mut on_message))?;
                }
            }
            Source::Sqlite(files) => {
                for f in files {
                    self.with_sqlite(f, |p| sqlite3::visit(p, &mut on_message))?;
                }
            }
            Source::Ros1(file) => {
                let map = map_file(file)?;
                ros1_bag::Ros1Bag::new(file, &map)?.visit(&mut on_message)?;
            }
        }
        Ok(())
    }

    /// Decodes one message of `topic` with `decode`, naming the recording,
    /// the topic and the message index in an error.
    pub fn decode<T>(
        &self,
        message: &RawMessage<'_>,
        decode: impl for<'a> FnOnce(&mut dyn wire::WireReader<'a>) -> wire::WireResult<T>,
    ) -> Result<T> {
        let topic = &self.topics[message.topic];
        messages::decode(topic.encoding, message.data, decode)
            .map_err(|e| DataError::message(&self.path, &topic.name, message.index, e.0))
    }

    /// What `ros2 bag info` prints: the files, the span and each topic's
    /// type, count and rate.
    pub fn info(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(out, "Files:             {}", self.path.display());
        let _ = writeln!(out, "Format:            {}", self.format);
        let messages: u64 = self.topics.iter().map(|t| t.count).sum();
        if let Some((first, last)) = self.span_ns() {
            let _ = writeln!(out, "Duration:          {:.9}s", (last - first) as f64 * 1e-9);
            // Printed from the integer nanoseconds: exact, as `ros2 bag info` does.
            let stamp = |ns: i64| format!("{}.{:09}", ns.div_euclid(1_000_000_000), ns.rem_euclid(1_000_000_000));
            let _ = writeln!(out, "Start:             {} (epoch s)", stamp(first));
            let _ = writeln!(out, "End:               {} (epoch s)", stamp(last));
        }
        let _ = writeln!(out, "Messages:          {messages}");
        let _ = writeln!(out, "Topic information:");
        let width = self.topics.iter().map(|t| t.name.len()).max().unwrap_or(0);
        let type_width = self.topics.iter().map(|t| t.type_name.len()).max().unwrap_or(0);
        for t in &self.topics {
            let rate = t.rate_hz().map_or("-".to_string(), |r| format!("{r:.2} Hz"));
            let _ = writeln!(
                out,
                "  {:<width$}  {:<type_width$}  {:>8} msgs  {:>11}  {}",
                t.name,
                t.type_name,
                t.count,
                rate,
                t.encoding.name()
            );
        }
        out
    }
}
