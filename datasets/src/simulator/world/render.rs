//! The Kinect-like RGB camera, rendered by ray casting: one ray per pixel
//! through the pinhole model, the nearest surface's textured albedo lit by
//! the ceiling lights (Lambertian, with distance fall-off), then exposure and
//! sensor noise.

use image::RgbImage;
use rayon::prelude::*;

use super::surface::SurfaceKind;
use super::surface::{Pattern, Surface};
use super::{Seen, World};
use crate::camera::PinholeCamera;
use crate::math::{Point3, Pose3, Vec3};
use crate::seed::{mix, unit};

/// The lighting of one picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Lighting {
    pub ambient: f32,
    /// Exposure: multiplies the whole image.
    pub gain: f32,
    /// Intensity of each of the world's lights.
    pub intensities: Vec<f32>,
    /// Standard deviation of the per-pixel sensor noise (0..1 scale).
    pub noise: f32,
    /// Seeds the sensor noise.
    pub noise_seed: u64,
}

impl Lighting {
    /// Draws a lighting of `lights` lamps from `key`: dim to bright rooms,
    /// some lamps off-ish, different exposure.
    pub fn varied(key: u64, lights: usize) -> Self {
        let u = |k: u64| unit(mix(key) ^ k) as f32;
        Self {
            ambient: 0.18 + 0.22 * u(1),
            gain: 0.75 + 0.55 * u(2),
            intensities: (0..lights as u64).map(|i| 0.25 + 1.0 * u(10 + i)).collect(),
            noise: 0.008 + 0.012 * u(3),
            noise_seed: mix(key ^ 0x5eed),
        }
    }
}

/// Renders the view of `camera` at `world_from_camera` (camera frame: x
/// right, y down, z forward) at world time `time` (where the people are).
pub fn render(
    world: &World,
    camera: &PinholeCamera,
    world_from_camera: &Pose3,
    lighting: &Lighting,
    time: f64,
) -> RgbImage {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let origin = Point3::from(world_from_camera.translation.vector);
    let rotation = world_from_camera.rotation;
    let gamma = gamma_table();
    let mut pixels = vec![0u8; w * h * 3];
    pixels.par_chunks_mut(w * 3).enumerate().for_each(|(row, out)| {
        for col in 0..w {
            let dir = rotation * camera.ray(col as f64 + 0.5, row as f64 + 0.5);
            let colour = shade(world, &origin, &dir, lighting, time);
            let key = lighting.noise_seed ^ ((row * w + col) as u64);
            for (c, value) in colour.iter().enumerate() {
                let noise = quick_gaussian(mix(key.wrapping_mul(3).wrapping_add(c as u64)));
                let noisy = value * lighting.gain + lighting.noise * noise;
                out[col * 3 + c] = gamma[(noisy.clamp(0.0, 1.0) * (GAMMA_STEPS - 1) as f32) as usize];
            }
        }
    });
    RgbImage::from_raw(w as u32, h as u32, pixels).expect("buffer sized to the image")
}

/// The colour seen along a ray: the nearest opaque surface or person, seen
/// through any glass in front of it (each pane keeps most of the light and
/// adds a faint tint).
fn shade(world: &World, origin: &Point3, dir: &Vec3, lighting: &Lighting, time: f64) -> [f32; 3] {
    let mut t_min = 1e-4;
    let mut colour = [0.0f32; 3];
    let mut weight = 1.0f32;
    for _ in 0..4 {
        let Some(hit) = world.sense(origin, dir, t_min, 200.0, time) else { break };
        let p = origin + dir * hit.t;
        // Seen from either side: light the side facing the camera.
        let n = if hit.normal.dot(dir) > 0.0 { -hit.normal } else { hit.normal };
        let light = lit(world, &p, &n, lighting);
        match hit.seen {
            Seen::Person(i) => {
                let clothes = world.layout.walkers[i].colour;
                return std::array::from_fn(|c| colour[c] + weight * clothes[c] * light);
            }
            Seen::Surface(i) => {
                let surface = &world.layout.surfaces[i];
                let albedo = albedo(surface, &p);
                if surface.kind == SurfaceKind::Glass {
                    for c in 0..3 {
                        colour[c] += weight * 0.08 * albedo[c] * light;
                    }
                    weight *= 0.85;
                    t_min = hit.t + 1e-4;
                    continue;
                }
                return std::array::from_fn(|c| colour[c] + weight * (albedo[c] * light));
            }
        }
    }
    colour
}

/// Ambient plus Lambertian light from the lamps, with distance fall-off.
fn lit(world: &World, p: &Point3, n: &Vec3, lighting: &Lighting) -> f32 {
    let mut light = lighting.ambient;
    for (lamp, intensity) in world.layout.lights.iter().zip(&lighting.intensities) {
        let to = Point3::from(lamp.position) - p;
        let d2 = to.norm_squared();
        let cos = (n.dot(&to) / d2.sqrt()).max(0.0);
        light += intensity * cos as f32 / (1.0 + d2 as f32 / 9.0);
    }
    light
}

/// The surface colour at `p` (linear RGB, 0..1).
pub fn albedo(surface: &Surface, p: &Point3) -> [f32; 3] {
    let rel = p.coords;
    let (u, v) = (surface.u_axis.dot(&rel), surface.v_axis.dot(&rel));
    let m = &surface.material;
    let base = m.base;
    let scale = |f: f32| base.map(|c| c * f);
    match m.pattern {
        Pattern::Tiles { size_m } => {
            let (iu, iv) = ((u / size_m).floor(), (v / size_m).floor());
            let (fu, fv) = (u / size_m - iu, v / size_m - iv);
            let grout = 0.02 / size_m;
            if fu < grout || fv < grout {
                return scale(0.35);
            }
            let tile = unit(m.seed ^ mix((iu as i64 as u64) << 20 ^ iv as i64 as u64)) as f32;
            scale(0.85 + 0.25 * tile + 0.05 * value_noise(u * 8.0, v * 8.0, m.seed))
        }
        Pattern::Plaster { posters } => {
            if posters && let Some(colour) = poster(m.seed, u, p.z) {
                return colour;
            }
            scale(0.93 + 0.07 * value_noise(u * 3.0, v * 3.0, m.seed))
        }
        Pattern::Panels { size_m } => {
            let (fu, fv) = ((u / size_m).rem_euclid(1.0), (v / size_m).rem_euclid(1.0));
            if fu < 0.015 || fv < 0.015 { scale(0.6) } else { scale(1.0) }
        }
        Pattern::Stripes { period_m } => {
            if (u / period_m).rem_euclid(1.0) < 0.25 {
                scale(0.55)
            } else {
                scale(1.0 + 0.05 * value_noise(u * 6.0, v * 6.0, m.seed))
            }
        }
        Pattern::Cardboard => {
            let tape = (u.rem_euclid(0.6) - 0.3).abs() < 0.04;
            if tape { [0.75, 0.70, 0.55] } else { scale(0.9 + 0.1 * value_noise(u * 10.0, v * 10.0, m.seed)) }
        }
        Pattern::Wood => scale(0.85 + 0.15 * value_noise(u * 2.0, v * 40.0, m.seed)),
        Pattern::Glass => base,
    }
}

/// At most one poster every 2.5 m of wall, between 1.1 m and 2.1 m up:
/// 2D corners that are not 3D corners, which a detector must learn to ignore.
fn poster(seed: u64, u: f64, z: f64) -> Option<[f32; 3]> {
    let slot = (u / 2.5).floor();
    let key = seed ^ mix(slot as i64 as u64);
    if unit(key) < 0.45 {
        return None;
    }
    let start = slot * 2.5 + 0.3 + 1.2 * unit(key ^ 1);
    let width = 0.4 + 0.4 * unit(key ^ 2);
    let bottom = 1.1 + 0.3 * unit(key ^ 3);
    if u < start || u > start + width || z < bottom || z > bottom + 0.5 + 0.2 * unit(key ^ 4) {
        return None;
    }
    Some([0.2 + 0.7 * unit(key ^ 5) as f32, 0.2 + 0.7 * unit(key ^ 6) as f32, 0.2 + 0.7 * unit(key ^ 7) as f32])
}

/// Smooth noise in -1..1 (bilinear interpolation of hashed lattice values).
fn value_noise(x: f64, y: f64, seed: u64) -> f32 {
    let (ix, iy) = (x.floor(), y.floor());
    let (fx, fy) = (x - ix, y - iy);
    let at = |dx: f64, dy: f64| unit(seed ^ mix(((ix + dx) as i64 as u64) << 32 ^ (iy + dy) as i64 as u64)) * 2.0 - 1.0;
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let top = at(0.0, 0.0) * (1.0 - sx) + at(1.0, 0.0) * sx;
    let bottom = at(0.0, 1.0) * (1.0 - sx) + at(1.0, 1.0) * sx;
    (top * (1.0 - sy) + bottom * sy) as f32
}

const GAMMA_STEPS: usize = 4096;

/// Display gamma (1/2.2), as a camera encodes its output, tabulated: a
/// `powf` per pixel and channel was a tenth of the rendering time.
fn gamma_table() -> Vec<u8> {
    (0..GAMMA_STEPS).map(|i| ((i as f32 / (GAMMA_STEPS - 1) as f32).powf(1.0 / 2.2) * 255.0 + 0.5) as u8).collect()
}

/// An approximately standard normal value (sum of four uniforms, scaled to
/// unit variance): cheap enough for per-pixel sensor noise.
fn quick_gaussian(key: u64) -> f32 {
    let sum: u32 = (0..4).map(|i| ((key >> (16 * i)) & 0xffff) as u32).sum();
    (sum as f32 / 65535.0 - 2.0) * 3f32.sqrt()
}

/// A standard normal value from a hashed key (Box-Muller on two uniforms).
pub fn gaussian(key: u64) -> f32 {
    let u1 = unit(key).max(1e-12);
    let u2 = unit(key ^ 0xabcd_ef01_2345_6789);
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}
