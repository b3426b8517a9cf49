//! Stable fingerprints of bytes and files (FNV-1a, 64 bits): a stage that
//! reads a file, or a result made by a program, is redone when they change.

use std::path::Path;

use crate::error::{DataError, Result};

/// The fingerprint of `bytes`, as 16 hex digits.
pub fn of_bytes(bytes: &[u8]) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{hash:016x}")
}

/// The fingerprint of the file at `path`.
pub fn of_file(path: &Path) -> Result<String> {
    Ok(of_bytes(&std::fs::read(path).map_err(|e| DataError::io(path, e))?))
}

/// The fingerprint of the running program's executable: results it made
/// are stale once it is rebuilt with other code.
pub fn of_program() -> Result<String> {
    let path = std::env::current_exe().map_err(|e| DataError::io(Path::new("the running program"), e))?;
    of_file(&path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a_matches_its_reference_values() {
        // The FNV-1a 64 test vectors of its authors' reference code.
        assert_eq!(of_bytes(b""), "cbf29ce484222325");
        assert_eq!(of_bytes(b"a"), "af63dc4c8601ec8c");
        assert_eq!(of_bytes(b"foobar"), "85944171f73967e8");
    }

    #[test]
    fn a_file_has_the_fingerprint_of_its_bytes_and_a_missing_one_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("weights.bin");
        std::fs::write(&path, b"foobar").unwrap();
        assert_eq!(of_file(&path).unwrap(), of_bytes(b"foobar"));
        let missing = of_file(&dir.path().join("nothing")).unwrap_err().to_string();
        assert!(missing.contains("nothing"), "{missing}");
    }
}
