//! `sensor_msgs/CameraInfo`: the intrinsics K, the distortion D, and the
//! pinhole camera they give localization.

use crate::camera::PinholeCamera;
use crate::io::recording::wire::{Header, WireReader, WireResult};

#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    pub header: Header,
    pub width: u32,
    pub height: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    /// Row-major 3x3 intrinsics of the raw (distorted) image.
    pub k: [f64; 9],
    /// Row-major 3x4 projection of the rectified image.
    pub p: [f64; 12],
}

pub fn camera_info(r: &mut dyn WireReader<'_>) -> WireResult<CameraInfo> {
    let header = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let distortion_model = r.string()?;
    let d = r.f64_sequence()?;
    let k: [f64; 9] = r.f64s(9)?.try_into().expect("9 values");
    let _r = r.f64s(9)?;
    let p: [f64; 12] = r.f64s(12)?.try_into().expect("12 values");
    Ok(CameraInfo { header, width, height, distortion_model, d, k, p })
}

impl CameraInfo {
    /// True when D is empty or all zero: the image is already pinhole.
    pub fn is_undistorted(&self) -> bool {
        self.d.iter().all(|&v| v == 0.0)
    }

    /// The pinhole model of the raw image (K).
    pub fn raw_camera(&self) -> PinholeCamera {
        PinholeCamera {
            width: self.width,
            height: self.height,
            fx: self.k[0],
            fy: self.k[4],
            cx: self.k[2],
            cy: self.k[5],
        }
    }

    /// The pinhole model of the rectified image (P), what `image_rect` topics carry.
    pub fn rectified_camera(&self) -> PinholeCamera {
        PinholeCamera {
            width: self.width,
            height: self.height,
            fx: self.p[0],
            fy: self.p[5],
            cx: self.p[2],
            cy: self.p[6],
        }
    }
}
