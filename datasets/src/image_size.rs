//! The largest image any command reads, from a file or from a recording's
//! message: one bound, checked from the header before anything is decoded
//! (a 20000 x 20000 PNG of a few hundred kilobytes decodes to gigabytes).

/// Most pixels on either side.
pub const MAX_SIDE: u32 = 16_384;
/// Most pixels in all (128 megapixels: a phone's largest photos).
pub const MAX_PIXELS: u64 = 1 << 27;
/// Most bytes the decoder may allocate (a 128-megapixel RGBA image at 16 bits).
const MAX_ALLOC: u64 = MAX_PIXELS * 8;

/// Why a `width` x `height` image is refused, if it is.
pub fn check(width: u32, height: u32) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image size {width}x{height} is empty"));
    }
    if width > MAX_SIDE || height > MAX_SIDE || u64::from(width) * u64::from(height) > MAX_PIXELS {
        return Err(format!(
            "image size {width}x{height} is beyond the {MAX_SIDE} pixels a side and {} megapixels an image read",
            MAX_PIXELS >> 20
        ));
    }
    Ok(())
}

/// The same bound as the decoder's limits.
pub fn limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits.max_alloc = Some(MAX_ALLOC);
    limits
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sides_and_pixels_are_bounded() {
        assert!(check(1920, 1200).is_ok());
        assert!(check(MAX_SIDE, 8192).is_ok());
        assert!(check(MAX_SIDE + 1, 10).unwrap_err().contains("16384 pixels a side"));
        assert!(check(MAX_SIDE, MAX_SIDE).unwrap_err().contains("128 megapixels"));
        assert!(check(0, 10).unwrap_err().contains("empty"));
    }

    /// CRC-32 of a PNG chunk (type and data), bit by bit.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        !crc
    }

    fn chunk(kind: &[u8], data: &[u8]) -> Vec<u8> {
        let mut out = (data.len() as u32).to_be_bytes().to_vec();
        let body = [kind, data].concat();
        out.extend(&body);
        out.extend(crc32(&body).to_be_bytes());
        out
    }

    /// A zlib stream of nothing: the pixel data a header-only PNG lacks.
    const EMPTY_ZLIB: [u8; 8] = [0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01];

    #[test]
    fn a_png_declaring_20000_by_20000_is_refused_from_its_header_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.png");
        let mut header = 20_000u32.to_be_bytes().to_vec();
        header.extend(20_000u32.to_be_bytes());
        header.extend([8, 0, 0, 0, 0]);
        let png =
            [b"\x89PNG\r\n\x1a\n".to_vec(), chunk(b"IHDR", &header), chunk(b"IDAT", &EMPTY_ZLIB), chunk(b"IEND", &[])]
                .concat();
        std::fs::write(&path, png).unwrap();
        let error = crate::atomic::read_image(&path).unwrap_err().to_string();
        assert!(error.contains("huge.png") && error.contains("20000x20000"), "{error}");
        // The same header at 200 x 100 passes the size check and fails only on its missing data.
        let mut small = 200u32.to_be_bytes().to_vec();
        small.extend(100u32.to_be_bytes());
        small.extend([8, 0, 0, 0, 0]);
        let png =
            [b"\x89PNG\r\n\x1a\n".to_vec(), chunk(b"IHDR", &small), chunk(b"IDAT", &EMPTY_ZLIB), chunk(b"IEND", &[])]
                .concat();
        std::fs::write(&path, png).unwrap();
        let error = crate::atomic::read_image(&path).unwrap_err().to_string();
        assert!(!error.contains("megapixels"), "{error}");
    }
}
