//! Atomic file output: write into a temporary file beside the target, then
//! rename it into place, so an interrupted command never leaves a
//! half-written file under the final name.

use std::io::{BufWriter, Write};
use std::path::Path;

use crate::error::{DataError, Result};

/// The folder `path` is in (`.` for a bare name): where its temporary
/// siblings go.
pub fn folder_of(path: &Path) -> &Path {
    path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."))
}

/// Writes `path` through `fill`, atomically.
pub fn write_with(path: &Path, fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let dir = folder_of(path);
    std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
    let mut builder = tempfile::Builder::new();
    builder.prefix(".tmp-");
    // Temporary files are private (0600); the result is an ordinary file.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o644));
    let tmp = builder.tempfile_in(dir).map_err(|e| DataError::io(dir, e))?;
    {
        let mut out = BufWriter::new(tmp.as_file());
        fill(&mut out).map_err(|e| DataError::io(path, e))?;
        out.flush().map_err(|e| DataError::io(path, e))?;
    }
    tmp.persist(path).map_err(|e| DataError::io(path, e.error))?;
    Ok(())
}

/// Writes `bytes` to `path`, atomically.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// Serializes `value` as pretty JSON into `path`, atomically.
pub fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_vec_pretty(value).map_err(|e| DataError::json(path, e))?;
    write_bytes(path, &text)
}

/// Encodes `image` as PNG (or another format chosen by the extension) into
/// `path`, atomically.
pub fn write_image(path: &Path, image: &image::DynamicImage) -> Result<()> {
    let format = image::ImageFormat::from_path(path).map_err(|e| DataError::image(path, e))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, format).map_err(|e| DataError::image(path, e))?;
    write_bytes(path, bytes.get_ref())
}

/// Writes a folder atomically: `fill` populates a temporary sibling folder,
/// which then replaces `dir` (an existing `dir` is removed only after the new
/// one is complete).
pub fn write_dir<E: From<DataError>>(
    dir: &Path,
    fill: impl FnOnce(&Path) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let parent = folder_of(dir);
    std::fs::create_dir_all(parent).map_err(|e| DataError::io(parent, e))?;
    recover_dir(dir)?;
    remove_stale_siblings(dir, "")?;
    let prefix = sibling_prefix(dir);
    let tmp = tempfile::Builder::new().prefix(&prefix).tempdir_in(parent).map_err(|e| DataError::io(parent, e))?;
    fill(tmp.path())?;
    let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or("dir");
    let old = parent.join(format!(".old-{name}"));
    if dir.exists() {
        let _ = std::fs::remove_dir_all(&old);
        std::fs::rename(dir, &old).map_err(|e| DataError::io(dir, e))?;
    }
    std::fs::rename(tmp.keep(), dir).map_err(|e| DataError::io(dir, e))?;
    let _ = std::fs::remove_dir_all(&old);
    Ok(())
}

/// Whether `target` can be written (a file or a folder written whole, by a
/// temporary sibling renamed into place): its folder is made and a
/// temporary file tried in it, so that an unwritable output fails before
/// the work, not after it.
pub fn check_writable(target: &Path) -> Result<()> {
    let parent = folder_of(target);
    std::fs::create_dir_all(parent).map_err(|e| DataError::io(parent, e))?;
    tempfile::Builder::new()
        .prefix(&sibling_prefix(target))
        .tempfile_in(parent)
        .map_err(|e| DataError::io(parent, e))?;
    Ok(())
}

/// The name start of a temporary sibling of `target` (`.tmp-NAME.~`, then
/// tempfile's six random characters): a later write of the same target
/// finds what a killed one left, and nobody else's.
pub fn sibling_prefix(target: &Path) -> String {
    let name = target.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy());
    format!(".tmp-{name}.~")
}

/// Removes the temporary siblings of `target` (named by `sibling_prefix`,
/// six random characters, then `suffix`) that a killed write left; how many.
pub fn remove_stale_siblings(target: &Path, suffix: &str) -> Result<usize> {
    let parent = folder_of(target);
    let prefix = sibling_prefix(target);
    remove_entries(parent, |name| {
        let random = name.strip_prefix(&prefix).and_then(|rest| rest.strip_suffix(suffix));
        random.is_some_and(|r| r.len() == 6 && r.chars().all(|c| c.is_ascii_alphanumeric()))
    })
}

/// Puts back a folder that a kill between `write_dir`'s two renames left
/// only as `.old-NAME` beside it; true when it did.
pub fn recover_dir(dir: &Path) -> Result<bool> {
    let (Some(parent), Some(name)) = (dir.parent(), dir.file_name().and_then(|n| n.to_str())) else {
        return Ok(false);
    };
    let old = parent.join(format!(".old-{name}"));
    if dir.exists() || !old.is_dir() {
        return Ok(false);
    }
    std::fs::rename(&old, dir).map_err(|e| DataError::io(&old, e))?;
    Ok(true)
}

/// Removes the temporary files and folders (`.tmp-*`) that a killed writer
/// left in `dir`; only for a folder that no other writer is using.
pub fn remove_leftovers(dir: &Path) -> Result<usize> {
    remove_entries(dir, |name| name.starts_with(".tmp-"))
}

/// Removes the files and folders in `dir` whose names `doomed` picks; how
/// many. A missing `dir` has none.
fn remove_entries(dir: &Path, doomed: impl Fn(&str) -> bool) -> Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(DataError::io(dir, e)),
    };
    let mut removed = 0;
    for entry in entries {
        let entry = entry.map_err(|e| DataError::io(dir, e))?;
        if !doomed(&entry.file_name().to_string_lossy()) {
            continue;
        }
        let path = entry.path();
        let gone = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        gone.map_err(|e| DataError::io(&path, e))?;
        removed += 1;
    }
    Ok(removed)
}

/// Reads a whole file, naming it in the error.
/// Only regular files are read: a FIFO or a device would block or never end.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    check_regular(path)?;
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// Fails unless `path` is a regular file (after symbolic links), before
/// anything opens it (opening a FIFO for reading waits for a writer).
/// Why `path` cannot be opened, in words: missing, a link to nothing, a loop
/// of links, or the system's reason.
pub fn why_unreadable(path: &Path) -> String {
    match std::fs::metadata(path) {
        Ok(_) => "not a regular file or a folder (a FIFO or device?)".into(),
        // ELOOP on Linux and macOS: the system's own words would do, but std maps it to "other".
        Err(e) if e.raw_os_error() == Some(40) || e.raw_os_error() == Some(62) => {
            "a loop of symbolic links (it links back to itself)".into()
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => match std::fs::read_link(path) {
            Ok(target) => format!("a symbolic link to {}, which does not exist", target.display()),
            Err(_) => "no such file or folder".into(),
        },
        Err(e) => e.to_string(),
    }
}

pub fn check_regular(path: &Path) -> Result<()> {
    let meta = std::fs::metadata(path).map_err(|e| DataError::io(path, e))?;
    if !meta.is_file() {
        return Err(DataError::invalid(path, "not a regular file (a folder, FIFO or device)"));
    }
    Ok(())
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = read_bytes(path)?;
    String::from_utf8(bytes)
        .map_err(|e| DataError::byte(path, e.utf8_error().valid_up_to() as u64, "not valid UTF-8 text"))
}

/// Reads and decodes an image, naming the file in the error.
pub fn read_image(path: &Path) -> Result<image::DynamicImage> {
    let bytes = read_bytes(path)?;
    let reader = || {
        image::ImageReader::new(std::io::Cursor::new(&bytes)).with_guessed_format().map_err(|e| DataError::io(path, e))
    };
    // The size from the header first: decoding is where a small file becomes gigabytes.
    let (width, height) = reader()?.into_dimensions().map_err(|e| DataError::image(path, e))?;
    crate::image_size::check(width, height).map_err(|why| DataError::invalid(path, why))?;
    let mut decoder = reader()?;
    decoder.limits(crate::image_size::limits());
    decoder.decode().map_err(|e| DataError::image(path, e))
}

#[cfg(all(test, unix))]
mod tests {
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn written_files_are_readable_by_others_like_ordinary_files() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        super::write_bytes(&path, b"x").unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().permissions().mode() & 0o777, 0o644);
        assert_eq!(std::fs::read(&path).unwrap(), b"x");
    }
}
