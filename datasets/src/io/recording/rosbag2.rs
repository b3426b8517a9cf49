//! rosbag2 folders: `metadata.yaml` names the storage (sqlite3 or mcap),
//! the split files in replay order, and rosbag2's own compression (zstd of
//! whole files, or of each message).

use std::path::{Path, PathBuf};

use yaml_rust2::parser::{Event, EventReceiver, Parser};
use yaml_rust2::{Yaml, YamlLoader};

use crate::error::{DataError, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    Sqlite3,
    Mcap,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    None,
    /// Every split file is zstd-compressed whole (`*.db3.zstd`, `*.mcap.zstd`).
    File,
    /// Every message's data is a zstd frame.
    Message,
}

#[derive(Debug, Clone)]
pub struct Metadata {
    pub storage: Storage,
    pub files: Vec<PathBuf>,
    pub compression: Compression,
}

fn text<'y>(yaml: &'y Yaml, key: &str) -> Option<&'y str> {
    yaml[key].as_str()
}

pub fn read_metadata(dir: &Path) -> Result<Metadata> {
    let path = dir.join("metadata.yaml");
    let meta = parse_metadata(dir, &path, &crate::atomic::read_text(&path)?)?;
    for file in &meta.files {
        if !file.is_file() {
            return Err(DataError::invalid(&path, format!("lists {}, which is missing", file.display())));
        }
    }
    Ok(meta)
}

/// The metadata of the bag folder `dir` from the text of its `path`
/// (`metadata.yaml`); the files it lists are not looked at.
pub fn parse_metadata(dir: &Path, path: &Path, source: &str) -> Result<Metadata> {
    let path = path.to_path_buf();
    // The loader copies an alias's node wherever it is used: nested aliases
    // grow exponentially ("billion laughs"). Count first, load within bounds.
    let nodes = expanded_nodes(source).map_err(|e| DataError::invalid(&path, format!("not YAML: {e}")))?;
    if nodes > MAX_METADATA_NODES {
        return Err(DataError::invalid(
            &path,
            format!(
                "its aliases expand to {nodes} YAML nodes, more than the {MAX_METADATA_NODES} a metadata file may hold"
            ),
        ));
    }
    let docs = YamlLoader::load_from_str(source).map_err(|e| DataError::invalid(&path, format!("not YAML: {e}")))?;
    let info = docs
        .first()
        .map(|d| &d["rosbag2_bagfile_information"])
        .filter(|i| !i.is_badvalue())
        .ok_or_else(|| DataError::invalid(&path, "no `rosbag2_bagfile_information`"))?;
    let storage = match text(info, "storage_identifier") {
        Some("sqlite3") => Storage::Sqlite3,
        Some("mcap") => Storage::Mcap,
        Some(other) => {
            return Err(DataError::invalid(&path, format!("storage `{other}` is not supported (sqlite3, mcap)")));
        }
        None => return Err(DataError::invalid(&path, "no `storage_identifier`")),
    };
    let format = text(info, "compression_format").unwrap_or("");
    let mode = text(info, "compression_mode").unwrap_or("").to_ascii_uppercase();
    let compression = match (format, mode.as_str()) {
        ("", _) | (_, "" | "NONE") => Compression::None,
        ("zstd", "FILE") => Compression::File,
        ("zstd", "MESSAGE") => Compression::Message,
        (f, m) => {
            return Err(DataError::invalid(
                &path,
                format!("compression `{f}` in mode `{m}` is not supported (zstd, FILE or MESSAGE)"),
            ));
        }
    };
    let files: Vec<PathBuf> = info["relative_file_paths"]
        .as_vec()
        .ok_or_else(|| DataError::invalid(&path, "no `relative_file_paths`"))?
        .iter()
        .map(|f| f.as_str().map(|f| dir.join(f)).ok_or_else(|| DataError::invalid(&path, "a file path is not text")))
        .collect::<Result<_>>()?;
    if files.is_empty() {
        return Err(DataError::invalid(&path, "`relative_file_paths` is empty"));
    }
    Ok(Metadata { storage, files, compression })
}

/// Most YAML nodes a `metadata.yaml` may expand to (rosbag2 writes about
/// twenty a topic and uses no aliases).
pub const MAX_METADATA_NODES: u64 = 1_000_000;

/// How many nodes `source` holds once its aliases are expanded, counted
/// from the parser's events without expanding them.
fn expanded_nodes(source: &str) -> std::result::Result<u64, yaml_rust2::ScanError> {
    #[derive(Default)]
    struct Count {
        /// The open collections: each one's anchor and nodes so far.
        open: Vec<(usize, u64)>,
        anchored: std::collections::HashMap<usize, u64>,
        total: u64,
    }
    impl Count {
        fn add(&mut self, nodes: u64) {
            let into = self.open.last_mut().map_or(&mut self.total, |c| &mut c.1);
            *into = into.saturating_add(nodes);
        }
        fn close(&mut self, anchor: usize, nodes: u64) {
            if anchor > 0 {
                self.anchored.insert(anchor, nodes);
            }
            self.add(nodes);
        }
    }
    impl EventReceiver for Count {
        fn on_event(&mut self, event: Event) {
            match event {
                Event::Scalar(_, _, anchor, _) => self.close(anchor, 1),
                Event::Alias(id) => self.add(self.anchored.get(&id).copied().unwrap_or(1)),
                Event::SequenceStart(anchor, _) | Event::MappingStart(anchor, _) => self.open.push((anchor, 1)),
                Event::SequenceEnd | Event::MappingEnd => {
                    if let Some((anchor, nodes)) = self.open.pop() {
                        self.close(anchor, nodes);
                    }
                }
                _ => {}
            }
        }
    }
    let mut count = Count::default();
    Parser::new_from_str(source).load(&mut count, true)?;
    Ok(count.total)
}

/// Undoes zstd compression of a whole file or of one message, refusing
/// outputs over `limit` bytes (a corrupt frame must not exhaust memory).
pub fn unzstd(path: &Path, bytes: &[u8], limit: u64) -> Result<Vec<u8>> {
    use std::io::Read;
    let mut out = Vec::new();
    zstd::stream::read::Decoder::new(bytes)
        .and_then(|d| d.take(limit + 1).read_to_end(&mut out))
        .map_err(|e| DataError::invalid(path, format!("zstd data does not unpack: {e}")))?;
    if out.len() as u64 > limit {
        return Err(DataError::invalid(path, format!("zstd data unpacks to more than {limit} bytes")));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const METADATA: &str =
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths:\n    - a.mcap\n";

    #[test]
    fn aliases_are_counted_as_expanded_and_a_bomb_is_refused_without_expanding() {
        // The mapping, three keys, and the four-node list three times.
        assert_eq!(expanded_nodes("a: &x [1, 2, 3]\nb: *x\nc: *x\n").unwrap(), 1 + 3 + 3 * 4);
        assert!(parse_metadata(Path::new("bag"), Path::new("bag/metadata.yaml"), METADATA).is_ok());
        // Nine levels of nine aliases each: 9^9 (387 million) copies of the first list.
        let mut bomb = String::from("a: &a [x, x, x, x, x, x, x, x, x]\n");
        for (k, name) in ["b", "c", "d", "e", "f", "g", "h", "i"].iter().enumerate() {
            let previous = ["a", "b", "c", "d", "e", "f", "g", "h"][k];
            bomb += &format!("{name}: &{name} [{}]\n", vec![format!("*{previous}"); 9].join(", "));
        }
        let text = format!("{METADATA}{bomb}");
        let error = parse_metadata(Path::new("bag"), Path::new("bag/metadata.yaml"), &text).unwrap_err().to_string();
        assert!(error.contains("metadata.yaml") && error.contains("aliases expand to"), "{error}");
    }
}
