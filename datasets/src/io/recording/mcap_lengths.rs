//! The declared lengths inside an MCAP file's records, checked before the
//! `mcap` crate reads them: the crate allocates a string, a byte array or a
//! map for the length a record declares before it finds that the record is
//! shorter, so one damaged length field asks for up to 4 GiB. Here every
//! length-prefixed field of every record (top level, and inside uncompressed
//! chunks) must fit in its record. A compressed chunk with a CRC is covered
//! by it (the reader checks it before it parses the chunk's records); one
//! without is unpacked here and its records checked as well.

use std::path::Path;

use crate::error::{DataError, Result};

/// The fields of a record, in order, as far as they hold lengths.
#[derive(Clone, Copy)]
enum Field {
    Fixed(usize),
    /// u32 length, then that many bytes (strings, byte arrays, maps of fixed-size entries).
    Bytes32,
    /// u64 length, then that many bytes.
    Bytes64,
    /// u32 byte length, then string-to-string entries.
    StringMap,
    /// u32 byte length, then entries of this many bytes: the crate reads
    /// whole entries until it has passed the length, so a length between
    /// two entries moves every later field.
    FixedMap(usize),
    /// u64 length, then records (an uncompressed chunk's, when the compression is empty).
    ChunkRecords,
}

use Field::{Bytes32, Bytes64, ChunkRecords, Fixed, FixedMap, StringMap};

/// The layout of each record type that holds a length (MCAP specification, version 0).
fn layout(op: u8) -> &'static [Field] {
    match op {
        0x01 => &[Bytes32, Bytes32],                           // Header
        0x03 => &[Fixed(2), Bytes32, Bytes32, Bytes32],        // Schema
        0x04 => &[Fixed(4), Bytes32, Bytes32, StringMap],      // Channel
        0x06 => &[Fixed(28), Bytes32, ChunkRecords],           // Chunk
        0x07 => &[Fixed(2), FixedMap(16)],                     // MessageIndex
        0x08 => &[Fixed(32), FixedMap(10), Fixed(8), Bytes32], // ChunkIndex
        0x09 => &[Fixed(16), Bytes32, Bytes32, Bytes64],       // Attachment
        0x0A => &[Fixed(40), Bytes32, Bytes32],                // AttachmentIndex
        0x0B => &[Fixed(42), FixedMap(10)],                    // Statistics
        0x0C => &[Bytes32, StringMap],                         // Metadata
        0x0D => &[Fixed(16), Bytes32],                         // MetadataIndex
        _ => &[],
    }
}

/// Checks the records of `bytes` (a whole file: magic, records, magic).
pub fn check(path: &Path, bytes: &[u8]) -> Result<()> {
    const MAGIC: usize = 8;
    if bytes.len() < MAGIC {
        return Ok(()); // The reader says what is wrong with it.
    }
    check_records(path, bytes, MAGIC, bytes.len(), 0)?;
    // The summary is read from where the footer says it starts, whatever
    // the walk from the start reached: it is walked from there too.
    const FOOTER: usize = 1 + 8 + 20;
    if let Some(footer) = bytes.len().checked_sub(MAGIC + FOOTER).filter(|&f| f >= MAGIC && bytes[f] == 0x02) {
        let start = u64::from_le_bytes(bytes[footer + 9..footer + 17].try_into().expect("8 bytes"));
        // The crate reads on to the end of the file, not to the footer.
        if let Ok(start) = usize::try_from(start)
            && (MAGIC..bytes.len()).contains(&start)
        {
            check_records(path, bytes, start, bytes.len(), 0)?;
        }
    }
    Ok(())
}

/// Checks the one record at `offset` (a chunk index's pointer to a message
/// index, which the crate parses wherever it points).
pub fn check_record_at(path: &Path, bytes: &[u8], offset: u64) -> Result<()> {
    match usize::try_from(offset) {
        Ok(at) if at < bytes.len() => {
            let end = bytes.len().min(at.saturating_add(9).saturating_add(
                bytes.get(at + 1..at + 9).map_or(0, |l| u64::from_le_bytes(l.try_into().expect("8 bytes"))) as usize,
            ));
            check_records(path, bytes, at, end, 1)
        }
        // The crate's own bound check wraps around for an offset near 2^64 and then slices past the end.
        _ => Err(DataError::invalid(
            path,
            format!(
                "a chunk index points to a message index at byte {offset}, beyond the file's {} bytes",
                bytes.len()
            ),
        )),
    }
}

/// Checks the records in `bytes[from..to]`; a record cut off by `to` is
/// left to the reader, which names a truncated file as such.
fn check_records(path: &Path, bytes: &[u8], from: usize, to: usize, depth: u8) -> Result<()> {
    let mut at = from;
    while at + 9 <= to {
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().expect("8 bytes"));
        let body = at + 9;
        let Some(end) = usize::try_from(len).ok().and_then(|l| body.checked_add(l)).filter(|&e| e <= to) else {
            return Ok(());
        };
        check_fields(path, bytes, op, body, end, depth)?;
        if op == 0x02 {
            break; // The footer: the closing magic follows.
        }
        at = end;
    }
    Ok(())
}

fn check_fields(path: &Path, bytes: &[u8], op: u8, body: usize, end: usize, depth: u8) -> Result<()> {
    let bad = |at: usize, declared: u64| {
        DataError::invalid(
            path,
            format!(
                "record of type 0x{op:02x} at byte {}: a field at byte {at} declares {declared} bytes, more than \
                 the record holds (a damaged length)",
                body - 9
            ),
        )
    };
    let u32_at = |i: usize| u32::from_le_bytes(bytes[i..i + 4].try_into().expect("4 bytes")) as u64;
    let u64_at = |i: usize| u64::from_le_bytes(bytes[i..i + 8].try_into().expect("8 bytes"));
    let mut at = body;
    let mut compressed = true;
    for &field in layout(op) {
        let (prefix, declared) = match field {
            Fixed(n) => {
                at += n;
                if at > end {
                    return Ok(()); // Too short for its fixed fields: the reader names it.
                }
                continue;
            }
            Bytes32 | StringMap | FixedMap(_) if at + 4 <= end => (4, u32_at(at)),
            Bytes64 | ChunkRecords if at + 8 <= end => (8, u64_at(at)),
            _ => return Ok(()),
        };
        let start = at + prefix;
        if declared > (end - start) as u64 {
            return Err(bad(at, declared));
        }
        let stop = start + declared as usize;
        match field {
            StringMap => check_string_map(&bad, &u32_at, start, stop)?,
            FixedMap(entry) if declared % entry as u64 != 0 => {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "record of type 0x{op:02x} at byte {}: a map of {entry}-byte entries at byte {at} declares \
                         {declared} bytes (a damaged length)",
                        body - 9
                    ),
                ));
            }
            // The chunk's compression string comes just before its records.
            Bytes32 if op == 0x06 => compressed = declared != 0,
            ChunkRecords if !compressed && depth == 0 => check_records(path, bytes, start, stop, depth + 1)?,
            // A compressed chunk without a CRC (0: none stored) is unpacked
            // and its records checked too: nothing else vouches for them.
            ChunkRecords if compressed && depth == 0 && u32_at(body + 24) == 0 => {
                let size = u64_at(body + 16).min(super::mcap_file::MAX_RECORD_BYTES as u64);
                let compression = &bytes[body + 32..body + 32 + u32_at(body + 28) as usize];
                let records = unpack(compression, &bytes[start..stop], size);
                check_records(path, &records, 0, records.len(), depth + 1)?;
            }
            _ => {}
        }
        at = stop;
    }
    Ok(())
}

/// A chunk's records unpacked (at most `size` bytes), as far as they
/// unpack: a decoder that stops at damage late in the data has already
/// given what another decoder would parse.
fn unpack(compression: &[u8], data: &[u8], size: u64) -> Vec<u8> {
    use std::io::Read;
    let mut out = Vec::new();
    let _ = match compression {
        b"lz4" => lz4::Decoder::new(data).and_then(|d| d.take(size).read_to_end(&mut out)),
        b"zstd" => zstd::stream::read::Decoder::new(data).and_then(|d| d.take(size).read_to_end(&mut out)),
        _ => Ok(0),
    };
    out
}

/// Entries of a string-to-string map: each a u32-prefixed key and value
/// inside the map's bytes.
fn check_string_map(
    bad: &dyn Fn(usize, u64) -> DataError,
    u32_at: &dyn Fn(usize) -> u64,
    from: usize,
    to: usize,
) -> Result<()> {
    let mut at = from;
    while at < to {
        if at + 4 > to {
            return Err(bad(at, 4));
        }
        let declared = u32_at(at);
        if declared > (to - at - 4) as u64 {
            return Err(bad(at, declared));
        }
        at += 4 + declared as usize;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    /// An MCAP with one schema, one channel with metadata and one message,
    /// chunked without compression or not chunked at all.
    fn written(chunked: bool) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut writer = mcap::WriteOptions::new().compression(None).use_chunks(chunked).create(&mut out).unwrap();
        let schema = writer.add_schema("sensor_msgs/msg/Imu", "ros2msg", b"float64 x").unwrap();
        let metadata = BTreeMap::from([("offered_qos_profiles".to_string(), "reliable".to_string())]);
        let channel = writer.add_channel(schema, "/imu", "cdr", &metadata).unwrap();
        // A real stamp (ns): the summary's statistics then hold large times beside their lengths.
        let t = 1_700_000_000_123_456_789;
        let header = mcap::records::MessageHeader { channel_id: channel, sequence: 0, log_time: t, publish_time: t };
        writer.write_to_known_channel(&header, &[0, 1, 0, 0, 7, 7, 7, 7]).unwrap();
        writer.finish().unwrap();
        drop(writer);
        out.into_inner()
    }

    #[test]
    fn a_compressed_chunk_without_a_crc_is_unpacked_and_its_records_checked() {
        // A channel record whose topic claims 2^31 bytes, in a zstd chunk with no CRC.
        let mut channel = vec![0x04];
        let body: Vec<u8> = [&[1u8, 0, 1, 0][..], &(1u32 << 31).to_le_bytes(), b"/imu"].concat();
        channel.extend((body.len() as u64).to_le_bytes());
        channel.extend(&body);
        let packed = zstd::encode_all(&channel[..], 3).unwrap();
        let mut chunk = Vec::new();
        chunk.extend([0u8; 16]);
        chunk.extend((channel.len() as u64).to_le_bytes());
        chunk.extend(0u32.to_le_bytes());
        chunk.extend(4u32.to_le_bytes());
        chunk.extend(b"zstd");
        chunk.extend((packed.len() as u64).to_le_bytes());
        chunk.extend(&packed);
        let mut file = b"\x89MCAP0\r\n".to_vec();
        file.push(0x06);
        file.extend((chunk.len() as u64).to_le_bytes());
        file.extend(&chunk);
        let path = std::path::Path::new("packed.mcap");
        let error = super::check(path, &file).unwrap_err().to_string();
        assert!(error.contains("declares 2147483648 bytes"), "{error}");
        // With a CRC stored the chunk is left to the reader's CRC check.
        let crc_at = 8 + 9 + 24;
        file[crc_at..crc_at + 4].copy_from_slice(&1u32.to_le_bytes());
        super::check(path, &file).unwrap();
    }

    #[test]
    fn a_whole_file_passes_and_each_damaged_length_is_named_before_any_allocation() {
        let path = std::path::Path::new("lengths.mcap");
        let mut summary_hits = 0;
        for chunked in [false, true] {
            let bytes = written(chunked);
            super::check(path, &bytes).unwrap();
            // Every place that spells a length of the schema's name, the topic
            // or the metadata value, set to 2^31: each is refused by name,
            // also when the walk from the start stops early (a damaged
            // record length before the summary).
            for needle in [&b"sensor_msgs/msg/Imu"[..], b"/imu", b"reliable"] {
                let hits: Vec<usize> =
                    bytes.windows(needle.len()).enumerate().filter(|(_, w)| *w == needle).map(|(i, _)| i).collect();
                assert!(!hits.is_empty());
                for at in hits {
                    let mut damaged = bytes.clone();
                    damaged[at - 4..at].copy_from_slice(&(1u32 << 31).to_le_bytes());
                    let error = super::check(path, &damaged).unwrap_err().to_string();
                    assert!(
                        error.contains("lengths.mcap") && error.contains("declares 2147483648 bytes"),
                        "chunked {chunked}, {}: {error}",
                        String::from_utf8_lossy(needle)
                    );
                    // The header record's length made to run past the end: the walk stops there.
                    damaged[9..17].copy_from_slice(&u64::MAX.to_le_bytes());
                    if at > bytes.len() / 2 {
                        summary_hits += 1;
                        let error = super::check(path, &damaged).unwrap_err().to_string();
                        assert!(error.contains("declares 2147483648 bytes"), "{error}");
                    }
                }
            }
        }
        assert!(summary_hits >= 4, "{summary_hits} damaged lengths in the summary section");
        // A pointer into the middle of a record reads what lies there as a
        // record: a schema's name taken for a record whose string claims 2^31 bytes.
        let bytes = written(true);
        let at = bytes.windows(4).position(|w| w == b"/imu").unwrap();
        let mut fake = bytes.clone();
        fake[at..at + 13].copy_from_slice(&[0x01, 40, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x80]);
        let error = super::check_record_at(path, &fake, at as u64).unwrap_err().to_string();
        assert!(error.contains("declares 2147483648 bytes"), "{error}");
        let error = super::check_record_at(path, &bytes, u64::MAX).unwrap_err().to_string();
        assert!(error.contains("beyond the file"), "{error}");
        // A chunk index whose offsets map (10-byte entries) claims 8 bytes:
        // the crate would read a whole entry and every later field 2 bytes off.
        let footer = bytes.len() - 37;
        let mut at = u64::from_le_bytes(bytes[footer + 9..footer + 17].try_into().unwrap()) as usize;
        while bytes[at] != 0x08 {
            at += 9 + u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        }
        let mut damaged = bytes.clone();
        damaged[at + 9 + 32..at + 9 + 36].copy_from_slice(&8u32.to_le_bytes());
        let error = super::check(path, &damaged).unwrap_err().to_string();
        assert!(error.contains("map of 10-byte entries") && error.contains("declares 8 bytes"), "{error}");
    }
}
