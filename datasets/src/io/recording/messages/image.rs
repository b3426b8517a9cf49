//! `sensor_msgs/Image` (mono8, mono16, rgb8, bgr8, rgba8, bgra8) and
//! `sensor_msgs/CompressedImage` (JPEG, PNG).

use image::{DynamicImage, ImageBuffer, Luma, Rgb, Rgba};

use crate::io::formats::DepthImage;
use crate::io::recording::messages::ensure;
use crate::io::recording::wire::{Header, WireReader, WireResult, wire_error};

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

/// The fields of a `sensor_msgs/Image` with its size, step and data length
/// checked against its encoding's bytes per pixel.
struct RawImage<'a> {
    header: Header,
    width: u32,
    height: u32,
    big_endian: bool,
    step: usize,
    bytes_per_pixel: usize,
    data: &'a [u8],
}

impl<'a> RawImage<'a> {
    /// Reads the message; `bytes_per_pixel` says what an encoding takes, or
    /// why it is not taken.
    fn read(r: &mut dyn WireReader<'a>, bytes_per_pixel: impl FnOnce(&str) -> WireResult<usize>) -> WireResult<Self> {
        let header = r.header()?;
        let height = r.u32()?;
        let width = r.u32()?;
        let encoding = r.string()?;
        let big_endian = r.u8()? != 0;
        let step = r.u32()? as usize;
        let data = r.byte_sequence()?;
        let bpp = bytes_per_pixel(&encoding)?;
        crate::image_size::check(width, height).map_err(wire_error)?;
        let (w, h) = (width as usize, height as usize);
        ensure(step >= w * bpp, || format!("step {step} is less than width {width} x {bpp} bytes"))?;
        ensure(data.len() >= step * (h - 1) + w * bpp, || {
            format!(
                "{width}x{height} {encoding} with step {step} needs {} bytes, the message has {}",
                step * h,
                data.len()
            )
        })?;
        Ok(Self { header, width, height, big_endian, step, bytes_per_pixel: bpp, data })
    }

    /// Row `y`'s pixels, without the step's padding.
    fn row(&self, y: usize) -> &'a [u8] {
        let start = y * self.step;
        &self.data[start..start + self.width as usize * self.bytes_per_pixel]
    }
}

pub fn image(r: &mut dyn WireReader<'_>) -> WireResult<ImageMessage> {
    let mut kind = "";
    let raw = RawImage::read(r, |encoding| {
        let (bpp, k) = layout(encoding).ok_or_else(|| {
            wire_error(format!("image encoding `{encoding}` is not supported (supported: {})", ENCODINGS.join(", ")))
        })?;
        kind = k;
        Ok(bpp)
    })?;
    let (width, height, big_endian) = (raw.width, raw.height, raw.big_endian);
    let row = |y: usize| raw.row(y);
    let image = match kind {
        "mono8" => {
            DynamicImage::ImageLuma8(ImageBuffer::from_fn(width, height, |x, y| Luma([row(y as usize)[x as usize]])))
        }
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
    Ok(ImageMessage { header: raw.header, image })
}

/// A depth image message (`16UC1` in millimetres, `32FC1` in metres).
#[derive(Debug, Clone)]
pub struct DepthMessage {
    pub header: Header,
    pub depth: DepthImage,
}

/// `sensor_msgs/Image` holding depth, as RGB-D drivers publish it: `16UC1`
/// (or `mono16`) in millimetres, `32FC1` in metres; 0 or NaN = no reading.
pub fn depth_image(r: &mut dyn WireReader<'_>) -> WireResult<DepthMessage> {
    let raw = RawImage::read(r, |encoding| match encoding {
        "16UC1" | "mono16" => Ok(2),
        "32FC1" => Ok(4),
        other => Err(wire_error(format!("depth encoding `{other}` is not supported (16UC1 in mm, 32FC1 in m)"))),
    })?;
    let (width, height, big_endian) = (raw.width, raw.height, raw.big_endian);
    let mut metres = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height as usize {
        for b in raw.row(y).chunks_exact(raw.bytes_per_pixel) {
            let value = if raw.bytes_per_pixel == 2 {
                let mm = if big_endian { u16::from_be_bytes([b[0], b[1]]) } else { u16::from_le_bytes([b[0], b[1]]) };
                f32::from(mm) / 1000.0
            } else {
                let bytes = [b[0], b[1], b[2], b[3]];
                if big_endian { f32::from_be_bytes(bytes) } else { f32::from_le_bytes(bytes) }
            };
            metres.push(if value > 0.0 && value.is_finite() { value } else { f32::NAN });
        }
    }
    Ok(DepthMessage { header: raw.header, depth: DepthImage { width, height, metres } })
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
    reader.limits(crate::image_size::limits());
    let image = reader.decode().map_err(|e| wire_error(format!("compressed image (format `{format}`): {e}")))?;
    Ok(ImageMessage { header, image })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::recording::messages::{Encoding, decode};
    use crate::io::recording::wire::CdrWriter;

    /// A 2x1 image with `bytes` per row and a 2-byte row padding.
    fn message(encoding: &str, big_endian: bool, row: &[u8]) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.header(&Header { stamp_ns: 1, frame_id: "cam".into() });
        w.u32(1);
        w.u32(2);
        w.string(encoding);
        w.u8(big_endian as u8);
        w.u32(row.len() as u32 + 2);
        let mut data = row.to_vec();
        data.extend_from_slice(&[0xEE, 0xEE]);
        w.bytes(&data);
        w.finish()
    }

    #[test]
    fn every_listed_encoding_decodes_to_its_pixels() {
        let im = |enc: &str, be: bool, row: &[u8]| decode(Encoding::Cdr, &message(enc, be, row), image).unwrap().image;
        assert_eq!(im("mono16", false, &[0x34, 0x12, 0xff, 0x00]).as_luma16().unwrap().as_raw(), &[0x1234, 0x00ff]);
        assert_eq!(im("mono16", true, &[0x12, 0x34, 0x00, 0xff]).as_luma16().unwrap().as_raw(), &[0x1234, 0x00ff]);
        assert_eq!(
            im("rgba8", false, &[1, 2, 3, 4, 5, 6, 7, 8]).as_rgba8().unwrap().as_raw(),
            &[1, 2, 3, 4, 5, 6, 7, 8]
        );
        assert_eq!(
            im("bgra8", false, &[1, 2, 3, 4, 5, 6, 7, 8]).as_rgba8().unwrap().as_raw(),
            &[3, 2, 1, 4, 7, 6, 5, 8]
        );
        assert_eq!(im("rgb8", false, &[1, 2, 3, 4, 5, 6]).as_rgb8().unwrap().as_raw(), &[1, 2, 3, 4, 5, 6]);
        assert_eq!(im("bgr8", false, &[1, 2, 3, 4, 5, 6]).as_rgb8().unwrap().as_raw(), &[3, 2, 1, 6, 5, 4]);
        // Data shorter than height x step (less the last row's padding) is refused.
        let short = decode(Encoding::Cdr, &message("rgb8", false, &[1, 2, 3]), image).unwrap_err();
        assert!(short.0.contains("step"), "{short}");
    }

    #[test]
    fn depth_reads_in_metres_from_millimetres_or_floats_with_gaps_as_nan() {
        let depth = |enc: &str, be: bool, row: &[u8]| decode(Encoding::Cdr, &message(enc, be, row), depth_image);
        let mm = depth("16UC1", false, &1500u16.to_le_bytes().into_iter().chain([0, 0]).collect::<Vec<_>>()).unwrap();
        assert_eq!(mm.depth.metres[0], 1.5);
        assert!(mm.depth.metres[1].is_nan(), "0 is no reading");
        let be = depth("16UC1", true, &[0x05, 0xDC, 0x00, 0x01]).unwrap();
        assert_eq!((be.depth.metres[0], be.depth.metres[1]), (1.5, 0.001));
        let floats: Vec<u8> = [2.25f32, f32::NAN].iter().flat_map(|v| v.to_le_bytes()).collect();
        let m = depth("32FC1", false, &floats).unwrap();
        assert_eq!(m.depth.metres[0], 2.25);
        assert!(m.depth.metres[1].is_nan());
        let colour = depth("rgb8", false, &[1, 2, 3, 4, 5, 6]).unwrap_err();
        assert!(colour.0.contains("depth encoding `rgb8`"), "{colour}");
    }
}
