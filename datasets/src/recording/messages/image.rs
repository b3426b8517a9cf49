//! `sensor_msgs/Image` (mono8, mono16, rgb8, bgr8, rgba8, bgra8) and
//! `sensor_msgs/CompressedImage` (JPEG, PNG).

use image::{DynamicImage, ImageBuffer, Luma, Rgb, Rgba};

use crate::recording::messages::ensure;
use crate::recording::wire::{Header, WireReader, WireResult, wire_error};

#[derive(Debug, Clone)]
pub struct ImageMessage {
    pub header: Header,
    pub image: DynamicImage,
}

pub const ENCODINGS: [&str; 6] = ["mono8", "mono16", "rgb8", "bgr8", "rgba8", "bgra8"];

/// Bytes per pixel of an encoding, and its channel order.
fn layout(encoding: &str) -> Option<(usize, &'static str)> {
    Some(match encoding {
        "mono8" | "8UC1" => (1, "mono8"),
        "mono16" | "16UC1" => (2, "mono16"),
        "rgb8" => (3, "rgb8"),
        "bgr8" | "8UC3" => (3, "bgr8"),
        "rgba8" => (4, "rgba8"),
        "bgra8" | "8UC4" => (4, "bgra8"),
        _ => return None,
    })
}

/// Largest side of an image taken from a recording (a 16k camera is bigger
/// than anything localization needs; a larger header is corrupt).
const MAX_SIDE: u32 = 16384;

pub fn image(r: &mut dyn WireReader<'_>) -> WireResult<ImageMessage> {
    let header = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let encoding = r.string()?;
    let big_endian = r.u8()? != 0;
    let step = r.u32()? as usize;
    let data = r.byte_sequence()?;
    let (bpp, kind) = layout(&encoding).ok_or_else(|| {
        wire_error(format!("image encoding `{encoding}` is not supported (supported: {})", ENCODINGS.join(", ")))
    })?;
    ensure(width > 0 && height > 0 && width <= MAX_SIDE && height <= MAX_SIDE, || {
        format!("image size {width}x{height} is empty or larger than {MAX_SIDE} on a side")
    })?;
    let (w, h) = (width as usize, height as usize);
    ensure(step >= w * bpp, || format!("step {step} is less than width {width} x {bpp} bytes"))?;
    ensure(data.len() >= step * (h - 1) + w * bpp, || {
        format!("{width}x{height} {encoding} with step {step} needs {} bytes, the message has {}", step * h, data.len())
    })?;
    let row = |y: usize| &data[y * step..y * step + w * bpp];
    let image = match kind {
        "mono8" => DynamicImage::ImageLuma8(ImageBuffer::from_fn(width, height, |x, y| {
            Luma([row(y as usize)[x as usize]])
        })),
        "mono16" => DynamicImage::ImageLuma16(ImageBuffer::from_fn(width, height, |x, y| {
            let b = &row(y as usize)[2 * x as usize..2 * x as usize + 2];
            Luma([if big_endian { u16::from_be_bytes([b[0], b[1]]) } else { u16::from_le_bytes([b[0], b[1]]) }])
        })),
        "rgb8" | "bgr8" => {
            let bgr = kind == "bgr8";
            DynamicImage::ImageRgb8(ImageBuffer::from_fn(width, height, |x, y| {
                let p = &row(y as usize)[3 * x as usize..3 * x as usize + 3];
                if bgr { Rgb([p[2], p[1], p[0]]) } else { Rgb([p[0], p[1], p[2]]) }
            }))
        }
        _ => {
            let bgra = kind == "bgra8";
            DynamicImage::ImageRgba8(ImageBuffer::from_fn(width, height, |x, y| {
                let p = &row(y as usize)[4 * x as usize..4 * x as usize + 4];
                if bgra { Rgba([p[2], p[1], p[0], p[3]]) } else { Rgba([p[0], p[1], p[2], p[3]]) }
            }))
        }
    };
    Ok(ImageMessage { header, image })
}

pub fn compressed_image(r: &mut dyn WireReader<'_>) -> WireResult<ImageMessage> {
    let header = r.header()?;
    let format = r.string()?;
    let data = r.byte_sequence()?;
    if format.contains("compressedDepth") {
        return Err(wire_error(format!("`{format}`: compressed depth images are not camera images")));
    }
    let kind = image::guess_format(data)
        .ok()
        .filter(|f| matches!(f, image::ImageFormat::Jpeg | image::ImageFormat::Png))
        .ok_or_else(|| wire_error(format!("compressed image (format `{format}`) is neither JPEG nor PNG data")))?;
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(data), kind);
    reader.limits(image::Limits::default());
    let image = reader.decode().map_err(|e| wire_error(format!("compressed image (format `{format}`): {e}")))?;
    Ok(ImageMessage { header, image })
}
