//! rosbag2 folders: `metadata.yaml` names the storage (sqlite3 or mcap),
//! the split files in replay order, and rosbag2's own compression (zstd of
//! whole files, or of each message).

use std::path::{Path, PathBuf};

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
