//! The one preprocessing path of training and inference alike: RGB to
//! grayscale, resize to the network size (224 x 224), Canny edges; plus the
//! matching mapping of boxes between image and network coordinates.

use image::{DynamicImage, GrayImage, imageops};
use serde::{Deserialize, Serialize};

use crate::InvalidSetting;
use crate::bbox::BBox;

/// See [`AdaptiveCanny`]'s default.
const HIGH_QUANTILE: f32 = 0.91;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PreprocessConfig {
    /// Side of the square network input, in pixels.
    pub size: u32,
    /// Canny hysteresis thresholds on the Sobel gradient magnitude of the
    /// 0..255 grayscale image, blurred with sigma 1.4 (see `canny.rs`). 15/40
    /// keeps the wall, floor and ceiling lines of the rendered rooms, whose
    /// neighbouring surfaces differ little in brightness, without their
    /// plaster texture: 96% of the test labels have an edge within 4 px
    /// (`examples/edge_support.rs`); 40/100 keeps 71%.
    pub canny_low: f32,
    pub canny_high: f32,
    /// Thresholds from each image's own gradients instead of `canny_low` and
    /// `canny_high` (off by default: the paper's fixed thresholds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive_canny: Option<AdaptiveCanny>,
    /// A second input channel: the grayscale image the edges were found in
    /// (off by default: the paper's network sees the edges alone). A binary
    /// edge map no longer tells a corner where three differently lit planes
    /// meet from painted lines or thin furniture on one surface.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub gray_channel: bool,
}

impl Default for PreprocessConfig {
    fn default() -> Self {
        Self { size: 224, canny_low: 15.0, canny_high: 40.0, adaptive_canny: None, gray_channel: false }
    }
}

/// Canny thresholds that follow the image's contrast: the high one at a
/// quantile of its gradient magnitudes, the low one a fixed share of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveCanny {
    pub high_quantile: f32,
    pub low_ratio: f32,
}

impl Default for AdaptiveCanny {
    /// Where the fixed 15/40 sit on the rendered rooms: 40 is about the
    /// median image's 0.91 quantile of the gradient magnitudes at 224 px
    /// (`examples/canny_quantile.rs` on the default data's test split; on
    /// York Urban's photos it is their 0.62), and 15 is 0.375 of 40.
    fn default() -> Self {
        Self { high_quantile: HIGH_QUANTILE, low_ratio: 15.0 / 40.0 }
    }
}

impl PreprocessConfig {
    /// Channels of the network input.
    pub fn channels(&self) -> usize {
        1 + usize::from(self.gray_channel)
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.size < 16 {
            return Err(InvalidSetting::field("size", format!("{} is below 16 pixels", self.size)));
        }
        if !(self.canny_low.is_finite() && self.canny_low >= 0.0) {
            return Err(InvalidSetting::field("canny_low", format!("{} must be finite and >= 0", self.canny_low)));
        }
        if !(self.canny_high.is_finite() && self.canny_high >= self.canny_low) {
            let problem = format!("{} must be finite and >= canny_low {}", self.canny_high, self.canny_low);
            return Err(InvalidSetting::field("canny_high", problem));
        }
        if let Some(a) = &self.adaptive_canny {
            if !(a.high_quantile > 0.0 && a.high_quantile < 1.0) {
                let problem = format!("{} is outside (0, 1)", a.high_quantile);
                return Err(InvalidSetting::field("adaptive_canny.high_quantile", problem));
            }
            if !(a.low_ratio > 0.0 && a.low_ratio <= 1.0) {
                let problem = format!("{} is outside (0, 1]", a.low_ratio);
                return Err(InvalidSetting::field("adaptive_canny.low_ratio", problem));
            }
        }
        Ok(())
    }
}

/// Grayscale, resize and Canny: the network's edge image (edges 255, else 0).
/// The config must be valid (see [`PreprocessConfig::validate`]).
pub fn preprocess(image: &DynamicImage, config: &PreprocessConfig) -> GrayImage {
    edges_of(&network_gray(image, config), config)
}

/// The network's whole input: the edge image, then the grayscale image where
/// the config asks for it.
pub fn network_input(image: &DynamicImage, config: &PreprocessConfig) -> NetInput {
    let small = network_gray(image, config);
    let edges = edges_of(&small, config);
    NetInput { planes: if config.gray_channel { vec![edges, small] } else { vec![edges] } }
}

fn edges_of(small: &GrayImage, config: &PreprocessConfig) -> GrayImage {
    match &config.adaptive_canny {
        None => crate::canny::canny(small, config.canny_low, config.canny_high),
        Some(a) => crate::canny::canny_adaptive(small, a.high_quantile, a.low_ratio).0,
    }
}

/// A preprocessed network input: one square plane per channel, the Canny
/// edges first.
#[derive(Debug, Clone, PartialEq)]
pub struct NetInput {
    pub planes: Vec<GrayImage>,
}

impl NetInput {
    /// The Canny edges (the first plane).
    pub fn edges(&self) -> &GrayImage {
        &self.planes[0]
    }

    /// The same input mirrored left-right.
    pub fn flip_horizontal(&self) -> Self {
        Self { planes: self.planes.iter().map(imageops::flip_horizontal).collect() }
    }

    /// The network's values of plane `channel`'s pixels: the edges as 0 or 1,
    /// the grayscale image centred on 0 (-0.5 to 0.5), as the edges' zero
    /// is "nothing there".
    pub fn values(&self, channel: usize) -> impl Iterator<Item = f32> + '_ {
        let offset = if channel == 0 { 0.0 } else { 0.5 };
        self.planes[channel].as_raw().iter().map(move |&v| v as f32 / 255.0 - offset)
    }
}

/// The grayscale image at the network size, before Canny.
pub fn network_gray(image: &DynamicImage, config: &PreprocessConfig) -> GrayImage {
    imageops::resize(&image.to_luma8(), config.size, config.size, imageops::FilterType::Triangle)
}

/// Scale factors between an image and the square network input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageToNet {
    pub sx: f32,
    pub sy: f32,
}

impl ImageToNet {
    pub fn new(image_width: u32, image_height: u32, net_size: u32) -> Self {
        Self { sx: net_size as f32 / image_width as f32, sy: net_size as f32 / image_height as f32 }
    }
    pub fn to_net(&self, b: &BBox) -> BBox {
        b.scale(self.sx, self.sy)
    }
    pub fn to_image(&self, b: &BBox) -> BBox {
        b.scale(1.0 / self.sx, 1.0 / self.sy)
    }
    pub fn point_to_image(&self, [x, y]: [f32; 2]) -> [f32; 2] {
        [x / self.sx, y / self.sy]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Rgb, RgbImage};

    #[test]
    fn a_square_gives_edges_on_its_outline_only() {
        // A bright square on a dark background, 640 x 480.
        let img = RgbImage::from_fn(640, 480, |x, y| {
            if (200..440).contains(&x) && (120..360).contains(&y) { Rgb([220, 200, 180]) } else { Rgb([20, 30, 40]) }
        });
        let edges = preprocess(&DynamicImage::ImageRgb8(img), &PreprocessConfig::default());
        assert_eq!(edges.dimensions(), (224, 224));
        let map = ImageToNet::new(640, 480, 224);
        let outline = map.to_net(&BBox::new(200.0, 120.0, 440.0, 360.0));
        let mut on = 0;
        for (x, y, p) in edges.enumerate_pixels() {
            if p[0] == 0 {
                continue;
            }
            on += 1;
            let (x, y) = (x as f32 + 0.5, y as f32 + 0.5);
            let d = [(x - outline.x1).abs(), (x - outline.x2).abs(), (y - outline.y1).abs(), (y - outline.y2).abs()];
            let near = d.iter().cloned().fold(f32::INFINITY, f32::min);
            assert!(near <= 2.0, "edge pixel ({x}, {y}) is {near} px from the square's outline");
        }
        // The outline is about 2 * (84 + 112) = 392 net pixels long; a step
        // edge comes out one to two pixels thick.
        assert!((300..=800).contains(&on), "{on} edge pixels");
    }

    #[test]
    fn the_fixed_thresholds_stay_the_serialized_default() {
        // Checkpoints written before the adaptive option read and write as before.
        let old = r#"{"size": 224, "canny_low": 15.0, "canny_high": 40.0}"#;
        let config: PreprocessConfig = serde_json::from_str(old).unwrap();
        assert_eq!(config, PreprocessConfig::default());
        assert_eq!(serde_json::to_value(&config).unwrap(), serde_json::from_str::<serde_json::Value>(old).unwrap());
        let adaptive = PreprocessConfig { adaptive_canny: Some(AdaptiveCanny::default()), ..Default::default() };
        let text = serde_json::to_string(&adaptive).unwrap();
        assert_eq!(serde_json::from_str::<PreprocessConfig>(&text).unwrap(), adaptive);
        let gray = PreprocessConfig { gray_channel: true, ..Default::default() };
        let text = serde_json::to_string(&gray).unwrap();
        assert!(text.contains("\"gray_channel\":true"), "{text}");
        assert_eq!(serde_json::from_str::<PreprocessConfig>(&text).unwrap(), gray);
    }

    #[test]
    fn the_gray_channel_follows_the_edges_and_mirrors_with_them() {
        // A lit wall beside a darker one, and a painted line on the lit one.
        let img = RgbImage::from_fn(640, 480, |x, _| match x {
            0..320 => Rgb([200, 190, 180]),
            _ if (400..404).contains(&x) => Rgb([60, 60, 60]),
            _ => Rgb([110, 100, 90]),
        });
        let img = DynamicImage::ImageRgb8(img);
        let plain = PreprocessConfig::default();
        let gray = PreprocessConfig { gray_channel: true, ..Default::default() };
        assert_eq!((plain.channels(), gray.channels()), (1, 2));
        assert_eq!(network_input(&img, &plain).planes, vec![preprocess(&img, &plain)]);
        let input = network_input(&img, &gray);
        assert_eq!(input.planes, vec![preprocess(&img, &gray), network_gray(&img, &gray)]);
        // Edges are 0 or 1, the gray image centred: lit wall above 0, dark one below.
        let edges: Vec<f32> = input.values(0).collect();
        assert!(edges.iter().all(|&v| v == 0.0 || v == 1.0));
        let row: Vec<f32> = input.values(1).take(224).collect();
        assert!(row[10] > 0.2 && row[200] < 0.0 && row[200] > -0.2, "{} {}", row[10], row[200]);
        let flipped = input.flip_horizontal();
        assert_eq!(flipped.planes[1].get_pixel(223, 5), input.planes[1].get_pixel(0, 5));
        assert_eq!(flipped.flip_horizontal(), input);
    }

    #[test]
    fn boxes_round_trip_between_image_and_network() {
        let map = ImageToNet::new(640, 480, 224);
        let b = BBox::new(100.0, 50.0, 140.0, 90.0);
        let n = map.to_net(&b);
        assert!((n.x1 - 35.0).abs() < 1e-4 && (n.y1 - 50.0 * 224.0 / 480.0).abs() < 1e-4);
        let back = map.to_image(&n);
        for (a, b) in [(back.x1, b.x1), (back.y1, b.y1), (back.x2, b.x2), (back.y2, b.y2)] {
            assert!((a - b).abs() < 1e-3);
        }
    }

    #[test]
    fn invalid_thresholds_are_reported() {
        let c = PreprocessConfig { canny_low: 90.0, canny_high: 10.0, ..Default::default() };
        assert_eq!(c.validate().unwrap_err().field, "canny_high");
        let nan = PreprocessConfig { canny_low: f32::NAN, ..Default::default() };
        assert_eq!(nan.validate().unwrap_err().field, "canny_low");
        assert_eq!(PreprocessConfig { size: 8, ..Default::default() }.validate().unwrap_err().field, "size");
        let quantile = |high_quantile| PreprocessConfig {
            adaptive_canny: Some(AdaptiveCanny { high_quantile, ..Default::default() }),
            ..Default::default()
        };
        assert_eq!(quantile(1.0).validate().unwrap_err().field, "adaptive_canny.high_quantile");
        assert_eq!(quantile(f32::NAN).validate().unwrap_err().field, "adaptive_canny.high_quantile");
        let ratio = PreprocessConfig {
            adaptive_canny: Some(AdaptiveCanny { low_ratio: 0.0, ..Default::default() }),
            ..Default::default()
        };
        assert_eq!(ratio.validate().unwrap_err().field, "adaptive_canny.low_ratio");
        assert!(quantile(0.5).validate().is_ok());
        assert!(PreprocessConfig::default().validate().is_ok());
    }
}
