//! MCAP files (bare, or the storage of a rosbag2 folder) through the `mcap`
//! crate, which also undoes the chunks' lz4 and zstd compression.

use std::collections::BTreeMap;
use std::path::Path;

use crate::error::{DataError, Result};
use crate::io::recording::messages::{Encoding, canonical_type};
use crate::io::recording::{RawVisitor, TopicInfo};

fn mcap_error(path: &Path, e: mcap::McapError) -> DataError {
    // The crate's words for the two ways a copy is cut short say neither.
    let why = match e {
        mcap::McapError::BadMagic if has_start_magic(path) => {
            "truncated: the MCAP magic that ends a complete file is missing (a copy cut short, or a recorder \
             killed before it closed the file)"
                .to_string()
        }
        mcap::McapError::BadMagic => "not an MCAP file: it does not start with the MCAP magic".to_string(),
        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => {
            format!("truncated: the file ends in the middle of a record ({e})")
        }
        e => format!("not a readable MCAP file: {e}"),
    };
    DataError::invalid(path, why)
}

/// Whether the file at `path` starts as an MCAP file does.
fn has_start_magic(path: &Path) -> bool {
    use std::io::Read;
    let mut start = [0u8; 8];
    std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut start)).is_ok() && start == *mcap::MAGIC
}

fn encoding(path: &Path, topic: &str, name: &str) -> Result<Encoding> {
    match name {
        "cdr" => Ok(Encoding::Cdr),
        "ros1" => Ok(Encoding::Ros1),
        other => Err(DataError::invalid(
            path,
            format!("topic {topic}: message encoding `{other}` is not a ROS one (cdr or ros1)"),
        )),
    }
}

/// Largest record, or chunk unpacked into memory: writers cut chunks of a
/// few MiB; a larger declared size is a corrupt header, which must be an
/// error, not an allocation.
pub const MAX_RECORD_BYTES: usize = 1 << 29;

/// Every message in file order, through the crate's sans-io reader, which
/// (unlike its `MessageStream`) takes a bound on record and chunk sizes;
/// CRCs are checked where the writer stored them (a zero CRC means none).
fn for_each_message(path: &Path, bytes: &[u8], f: &mut dyn FnMut(mcap::Message<'_>) -> Result<()>) -> Result<()> {
    use mcap::sans_io::{LinearReaderOptions, MessageReadEvent, MessageReader};
    // Every chunk's CRC before any of its messages, and the data section's:
    // a flipped bit inside a chunk would otherwise move a trajectory silently.
    let options = LinearReaderOptions::default()
        .with_record_length_limit(MAX_RECORD_BYTES)
        .with_prevalidate_chunk_crcs(true)
        .with_validate_data_section_crc(true);
    super::mcap_lengths::check(path, bytes)?;
    let mut reader = MessageReader::new_with_options(options);
    let mut rest = bytes;
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| mcap_error(path, e))? {
            MessageReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            MessageReadEvent::Message(message) => f(message)?,
        }
    }
    Ok(())
}

/// The topics of an MCAP file with their counts and log-time span, from
/// its summary section when it has one, else by reading every message.
pub fn topics(path: &Path, bytes: &[u8]) -> Result<Vec<TopicInfo>> {
    let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
    let mut add = |topic: &str, type_name: &str, enc: &str, count: u64, first: u64, last: u64| -> Result<()> {
        let entry = match topics.entry(topic.to_string()) {
            std::collections::btree_map::Entry::Occupied(e) => {
                // Two channels of one topic with other types: which a role means is unknown.
                let (known, other) = (&e.get().type_name, canonical_type(type_name));
                if *known != other {
                    return Err(DataError::invalid(
                        path,
                        format!("topic {topic} carries two message types, {known} and {other}"),
                    ));
                }
                e.into_mut()
            }
            std::collections::btree_map::Entry::Vacant(v) => v.insert(TopicInfo {
                name: topic.to_string(),
                type_name: canonical_type(type_name),
                encoding: encoding(path, topic, enc)?,
                count: 0,
                first_ns: None,
                last_ns: None,
            }),
        };
        entry.count += count;
        if count > 0 {
            entry.first_ns = Some(entry.first_ns.map_or(first as i64, |t| t.min(first as i64)));
            entry.last_ns = Some(entry.last_ns.map_or(last as i64, |t| t.max(last as i64)));
        }
        Ok(())
    };
    super::mcap_lengths::check(path, bytes)?;
    let summary = mcap::Summary::read(bytes).map_err(|e| mcap_error(path, e))?;
    if let Some(summary) = summary.filter(|s| s.stats.is_some() && !s.chunk_indexes.is_empty()) {
        let stats = summary.stats.as_ref().expect("checked");
        // Each chunk's message indexes give every message's log time per
        // channel without unpacking the chunk; without them, the chunk's
        // span bounds the channel's.
        let mut spans: BTreeMap<u16, (u64, u64)> = BTreeMap::new();
        let mut widen = |id: u16, first: u64, last: u64| {
            let span = spans.entry(id).or_insert((u64::MAX, 0));
            span.0 = span.0.min(first);
            span.1 = span.1.max(last);
        };
        for chunk in &summary.chunk_indexes {
            // The crate parses whatever record lies at each offset the index gives.
            for &offset in chunk.message_index_offsets.values() {
                super::mcap_lengths::check_record_at(path, bytes, offset)?;
            }
            match summary.read_message_indexes(bytes, chunk) {
                Ok(indexes) => {
                    for (channel, entries) in indexes {
                        if let (Some(first), Some(last)) =
                            (entries.iter().map(|e| e.log_time).min(), entries.iter().map(|e| e.log_time).max())
                        {
                            widen(channel.id, first, last);
                        }
                    }
                }
                Err(_) => {
                    for id in chunk.message_index_offsets.keys() {
                        widen(*id, chunk.message_start_time, chunk.message_end_time);
                    }
                }
            }
        }
        for (id, channel) in &summary.channels {
            let count = stats.channel_message_counts.get(id).copied().unwrap_or(0);
            let schema = channel.schema.as_ref().map_or("", |s| s.name.as_str());
            let (first, last) = spans.get(id).copied().unwrap_or((stats.message_start_time, stats.message_end_time));
            add(&channel.topic, schema, &channel.message_encoding, count, first, last)?;
        }
        return Ok(topics.into_values().collect());
    }
    for_each_message(path, bytes, &mut |m| {
        let schema = m.channel.schema.as_ref().map_or("", |s| s.name.as_str());
        add(&m.channel.topic, schema, &m.channel.message_encoding, 1, m.log_time, m.log_time)
    })?;
    Ok(topics.into_values().collect())
}

/// Visits every message in file order.
pub fn visit(path: &Path, bytes: &[u8], visit: &mut RawVisitor<'_>) -> Result<()> {
    for_each_message(path, bytes, &mut |m| visit(&m.channel.topic, m.log_time as i64, &m.data))
}

#[cfg(test)]
mod crc_tests {
    use std::collections::BTreeMap;

    /// An uncompressed MCAP of three messages whose payload is `payload`.
    fn written(payload: &[u8]) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut writer = mcap::WriteOptions::new().compression(None).create(&mut out).unwrap();
        let schema = writer.add_schema("std_msgs/msg/String", "ros2msg", b"string data").unwrap();
        let channel = writer.add_channel(schema, "/chatter", "cdr", &BTreeMap::new()).unwrap();
        for sequence in 0..3 {
            let header = mcap::records::MessageHeader { channel_id: channel, sequence, log_time: 10, publish_time: 10 };
            writer.write_to_known_channel(&header, payload).unwrap();
        }
        writer.finish().unwrap();
        drop(writer);
        out.into_inner()
    }

    #[test]
    fn a_topic_with_two_message_types_is_an_error_naming_both() {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut writer = mcap::WriteOptions::new().compression(None).create(&mut out).unwrap();
        let cloud = writer.add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"").unwrap();
        let text = writer.add_schema("std_msgs/msg/String", "ros2msg", b"string data").unwrap();
        for schema in [cloud, text] {
            let channel = writer.add_channel(schema, "/points", "cdr", &BTreeMap::new()).unwrap();
            let header =
                mcap::records::MessageHeader { channel_id: channel, sequence: 0, log_time: 1, publish_time: 1 };
            writer.write_to_known_channel(&header, &[0, 1, 0, 0]).unwrap();
        }
        writer.finish().unwrap();
        drop(writer);
        let error = super::topics(std::path::Path::new("two.mcap"), out.get_ref()).unwrap_err().to_string();
        assert!(
            error.contains("two.mcap")
                && error.contains("/points carries two message types")
                && error.contains("sensor_msgs/msg/PointCloud2")
                && error.contains("std_msgs/msg/String"),
            "{error}"
        );
    }

    #[test]
    fn a_bit_flipped_inside_a_chunk_is_an_error_naming_the_file_not_a_changed_message() {
        let payload = b"a payload whose bytes are found in the file";
        let bytes = written(payload);
        let path = std::path::Path::new("flipped.mcap");
        let mut seen = Vec::new();
        super::visit(path, &bytes, &mut |_, _, data| {
            seen.push(data.to_vec());
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, vec![payload.to_vec(); 3]);
        // One bit of the second message's payload, inside the (uncompressed) chunk.
        let mut flipped = bytes.clone();
        let at = flipped.windows(payload.len()).enumerate().filter(|(_, w)| *w == payload).nth(1).unwrap().0;
        flipped[at + 5] ^= 0x04;
        let mut delivered = 0;
        let error = super::visit(path, &flipped, &mut |_, _, _| {
            delivered += 1;
            Ok(())
        })
        .unwrap_err()
        .to_string();
        assert!(error.contains("flipped.mcap") && error.to_lowercase().contains("crc"), "{error}");
        assert_eq!(delivered, 0, "no message of the damaged chunk is delivered");
    }
}
