//! Why a frame goes on without its cloud or its image. A fault is not an
//! error: the frame falls back (to the walls and the scan, or to the
//! odometry/IMU) and `frames.csv` and the run's summary say why. Typed, so
//! that a caller can tell a camera left out from an image that did not
//! decode; its text is what `frames.csv` shows.

use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum FrameFault {
    /// No `image` within the pairing tolerance of the `scan` at `stamp`
    /// ("image" of a "scan", or "colour image" of a "depth image").
    NoImageNear { image: &'static str, tolerance_s: f64, scan: &'static str, stamp: f64 },
    /// The image message paired with the scan at `stamp` never came (a bag cut short).
    ImageNeverCame { message: u64, stamp: f64 },
    /// The file or message did not read or decode: its reader's message.
    Unreadable(String),
    /// An image of another size than its camera's: corners or depths would
    /// land on the wrong rays. `reference` says whose size `expected` is.
    WrongSize { source: String, what: &'static str, size: [u32; 2], reference: &'static str, expected: [u32; 2] },
    /// A cloud without a finite point.
    NoFinitePoints,
    /// The scan's geometry failed: its message.
    Geometry(String),
    /// The camera left out (`--without-camera`, or `localize autolabel`).
    CameraOff,
    /// `--camera-stop`: no image from this many seconds after the first scan.
    CameraStopped { after_s: f64 },
    /// The detector runs at this rate, below the scans': this image skipped.
    DetectorSkipped { rate_hz: f64 },
    /// A corner source was given no image.
    NoImage,
    /// `--corners-from-labels`: the labels file does not list this image (its stem).
    NotInLabels { stem: String },
}

impl FrameFault {
    /// No image within `tolerance_s` of the scan at `stamp`.
    pub fn no_image_near(tolerance_s: f64, stamp: f64) -> Self {
        Self::NoImageNear { image: "image", tolerance_s, scan: "scan", stamp }
    }
}

impl fmt::Display for FrameFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoImageNear { image, tolerance_s, scan, stamp } => {
                write!(f, "no {image} within {tolerance_s} s of {scan} {stamp:.6}")
            }
            Self::ImageNeverCame { message, stamp } => {
                write!(f, "image message {message} of the scan at {stamp:.6} never came")
            }
            Self::Unreadable(message) | Self::Geometry(message) => f.write_str(message),
            Self::WrongSize { source, what, size, reference, expected } => {
                write!(f, "{source}: {what} is {}x{}, {reference} {}x{}", size[0], size[1], expected[0], expected[1])
            }
            Self::NoFinitePoints => f.write_str("no finite points"),
            Self::CameraOff => f.write_str("camera left out"),
            Self::CameraStopped { after_s } => {
                write!(f, "the camera stopped {after_s} s after the first scan (--camera-stop)")
            }
            Self::DetectorSkipped { rate_hz } => write!(f, "detector at {rate_hz} Hz: this image skipped"),
            Self::NoImage => f.write_str("no image"),
            Self::NotInLabels { stem } => write!(f, "image `{stem}` is not in the labels file"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_fault_reads_as_frames_csv_shows_it() {
        assert_eq!(FrameFault::no_image_near(0.05, 1.5).to_string(), "no image within 0.05 s of scan 1.500000");
        let size = FrameFault::WrongSize {
            source: "rgb/1.png".into(),
            what: "image",
            size: [320, 240],
            reference: "the calibration's camera is",
            expected: [640, 480],
        };
        assert_eq!(size.to_string(), "rgb/1.png: image is 320x240, the calibration's camera is 640x480");
        assert_eq!(FrameFault::DetectorSkipped { rate_hz: 5.0 }.to_string(), "detector at 5 Hz: this image skipped");
        assert_eq!(
            FrameFault::NotInLabels { stem: "000003".into() }.to_string(),
            "image `000003` is not in the labels file"
        );
    }
}
