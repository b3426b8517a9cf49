//! Normals on the range image: a point's candidate neighbours are the
//! points of a fixed lattice of cells around its own (the same stencil for
//! every point), gated at depth jumps so that no normal bleeds across an
//! edge; the k nearest of those that pass go into the exact path's PCA. No
//! search: a dense 64-beam scan or a depth image costs a fixed number of
//! reads a point, and where the stencil holds the k nearest of the whole
//! cloud the normal is the exact path's.
//!
//! The gate: a point's nearer neighbour one row away, and one column away,
//! say how far apart its surface's points are per row step and per column
//! step (far on a grazing floor, near on a wall facing the sensor). A
//! neighbour `dr` rows and `dc` columns away lies on the same surface when
//! it is within `spacing_factor` times what those steps predict, plus
//! `jump_margin_m` for range noise; anything farther (the wall behind an
//! object's side, the floor behind a box) is left out. The steps
//! themselves are capped at what a surface at `max_incidence_deg` gives
//! (`range * angle / cos(incidence)`), so that two jumps on either side of
//! a thin object do not open the gate.

use datasets::InvalidSetting;
use datasets::math::Vec3;
use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::scan::normals::{PointNormal, plane_from_moments};
use crate::scan::range_image::RangeImage;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OrganisedNormalConfig {
    /// Use the range image where the scan has one (a spinning LIDAR's beams
    /// and azimuth steps, a depth image's pixels, recovered from the points'
    /// directions); false (the default): always the exact k nearest
    /// neighbours, which localize as well and, on CPUs with AVX-512, as fast
    /// (docs/speed.md).
    pub enabled: bool,
    /// Only where its rows are at most this far apart (degrees): a dense
    /// LIDAR's or a depth image's. On a few-beam LIDAR the exact k nearest
    /// reach across its distant rings as far as each point needs, and
    /// localize better (the benchmark of docs/speed.md).
    pub max_row_pitch_deg: f64,
    /// The steepest incidence at which a surface's neighbours stay together.
    pub max_incidence_deg: f64,
    /// Added to the gate's distance, for range noise.
    pub jump_margin_m: f64,
    /// How much farther than the row and column steps predict a neighbour
    /// may lie (curvature and noise).
    pub spacing_factor: f64,
    /// Cells read per point (about; a lattice around it).
    pub samples: usize,
    /// The least angular width the cells span (degrees).
    pub window_deg: f64,
}

impl Default for OrganisedNormalConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            max_row_pitch_deg: 1.0,
            max_incidence_deg: 80.0,
            jump_margin_m: 0.1,
            spacing_factor: 2.0,
            samples: 121,
            window_deg: 4.0,
        }
    }
}

impl OrganisedNormalConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.max_incidence_deg > 0.0 && self.max_incidence_deg <= 89.0) {
            let problem = format!("{} outside (0, 89]", self.max_incidence_deg);
            return Err(InvalidSetting::field("max_incidence_deg", problem));
        }
        if !(self.jump_margin_m >= 0.0 && self.jump_margin_m <= 10.0) {
            let problem = format!("{} outside [0, 10]", self.jump_margin_m);
            return Err(InvalidSetting::field("jump_margin_m", problem));
        }
        if !(self.max_row_pitch_deg > 0.0 && self.max_row_pitch_deg <= 90.0) {
            let problem = format!("{} outside (0, 90]", self.max_row_pitch_deg);
            return Err(InvalidSetting::field("max_row_pitch_deg", problem));
        }
        if !(9..=1000).contains(&self.samples) {
            return Err(InvalidSetting::field("samples", format!("{} outside 9..=1000", self.samples)));
        }
        if !(self.window_deg >= 0.0 && self.window_deg <= 90.0) {
            return Err(InvalidSetting::field("window_deg", format!("{} outside [0, 90]", self.window_deg)));
        }
        if !(self.spacing_factor >= 1.0 && self.spacing_factor <= 100.0) {
            let problem = format!("{} outside [1, 100]", self.spacing_factor);
            return Err(InvalidSetting::field("spacing_factor", problem));
        }
        Ok(())
    }
}

/// The cells a point's neighbours are read from: a lattice of about
/// `samples` cells around it (itself first) spanning at least `window`
/// radians and at least one row and one column either side, strided along
/// the denser axis so that the window is about as wide as it is tall in
/// angle. Each offset comes with its angular distance (radians).
fn stencil(image: &RangeImage, samples: usize, window: f64) -> Vec<(i64, i64, f64)> {
    let (rp, cp) = (image.row_pitch.abs().max(1e-9), image.col_pitch.abs().max(1e-9));
    let half = (window / 2.0).max(rp).max(cp);
    let row_cells = ((half / rp).round() as i64).clamp(1, 64);
    let col_cells = ((half / cp).round() as i64).clamp(1, 256);
    // Samples either side along each axis: rows first (at least one), the
    // columns get what the budget leaves.
    let side = ((samples as f64).sqrt() - 1.0) / 2.0;
    let row_samples = (side.round() as i64).clamp(1, row_cells);
    let col_samples =
        ((((samples as f64 / (2 * row_samples + 1) as f64) - 1.0) / 2.0).round() as i64).clamp(1, col_cells);
    let row_stride = (row_cells as f64 / row_samples as f64).round().max(1.0) as i64;
    let col_stride = (col_cells as f64 / col_samples as f64).round().max(1.0) as i64;
    let mut offsets = vec![(0, 0, 0.0)];
    for r in -row_samples..=row_samples {
        for c in -col_samples..=col_samples {
            if (r, c) != (0, 0) {
                let (dr, dc) = (r * row_stride, c * col_stride);
                offsets.push((dr, dc, (dr as f64 * rp).hypot(dc as f64 * cp)));
            }
        }
    }
    offsets
}

/// One normal per point of `points`, which `image` organises, oriented
/// toward `sensor`. A point whose neighbours after the gate are fewer than
/// 3, or all in its own row or its own column (alone on its surface, or on
/// a thin edge), gets the direction to the sensor and the curvature of
/// isotropic scatter (1/3), so that no stage takes it for a plane.
pub fn organised_normals(
    points: &[Point3<f32>],
    image: &RangeImage,
    sensor: &Vec3,
    k: usize,
    config: &OrganisedNormalConfig,
) -> Vec<PointNormal> {
    assert_eq!(points.len(), image.len(), "the range image must organise these points");
    let offsets = stencil(image, config.samples, config.window_deg.to_radians());
    let mut normals = vec![PointNormal { normal: Vec3::z(), curvature: 0.0, offset: 0.0 }; points.len()];
    normals.par_chunks_mut(CHUNK).enumerate().for_each(|(c, out)| {
        let mut kept = Vec::with_capacity(offsets.len());
        for (i, normal_out) in (c * CHUNK..).zip(out.iter_mut()) {
            let view = Neighbourhood { points, image, sensor, offsets: &offsets, k, config };
            *normal_out = view.normal_at(i, &mut kept);
        }
    });
    normals
}

/// What a point's normal is taken from: the organised cloud, the stencil
/// and the settings.
struct Neighbourhood<'a> {
    points: &'a [Point3<f32>],
    image: &'a RangeImage,
    sensor: &'a Vec3,
    offsets: &'a [(i64, i64, f64)],
    k: usize,
    config: &'a OrganisedNormalConfig,
}

impl Neighbourhood<'_> {
    /// Point `i`'s normal from the `k` nearest cells of its stencil that pass
    /// the gate (`kept` is scratch space).
    #[inline(always)]
    fn normal_at(&self, i: usize, kept: &mut Vec<([f32; 3], f32, bool, bool)>) -> PointNormal {
        let Self { points, image, sensor, offsets, k, config } = *self;
        let stretch = (1.0 / config.max_incidence_deg.to_radians().cos()) as f32;
        let (margin, factor) = (config.jump_margin_m as f32, config.spacing_factor as f32);
        let p = points[i];
        let (row, col) = image.cell(i);
        let (row, col) = (row as i64, col as i64);
        let range = (p.cast::<f64>().coords - sensor).norm() as f32;
        let offset_of = |j: usize| {
            let q = points[j];
            [q.x - p.x, q.y - p.y, q.z - p.z]
        };
        let norm2 = |d: [f32; 3]| d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        // The surface's spacing per row step and per column step: the nearer
        // immediate neighbour, capped at the steepest incidence.
        let step = |a: Option<usize>, b: Option<usize>, pitch: f64| {
            let cap = stretch * range * pitch as f32;
            [a, b]
                .into_iter()
                .flatten()
                .filter(|&j| j != i)
                .map(|j| norm2(offset_of(j)))
                .fold(cap * cap, f32::min)
                .sqrt()
        };
        let row_step = step(image.at(row - 1, col), image.at(row + 1, col), image.row_pitch.abs());
        let col_step = step(image.at(row, col - 1), image.at(row, col + 1), image.col_pitch.abs());
        // The neighbours that pass the gate: offset from p, squared distance,
        // and whether it is off p's row and off p's column.
        kept.clear();
        for &(dr, dc, angle) in offsets {
            let Some(j) = image.at(row + dr, col + dc) else { continue };
            if j == i {
                continue;
            }
            let d = offset_of(j);
            let steps = factor * (dr.unsigned_abs() as f32 * row_step + dc.unsigned_abs() as f32 * col_step);
            let reach = steps.min(stretch * range * angle as f32) + margin;
            let d2 = norm2(d);
            if d2 <= reach * reach {
                kept.push((d, d2, dr != 0, dc != 0));
            }
        }
        // The k nearest of them (the point itself comes on top, where the
        // exact path counts it among its k).
        if kept.len() > k {
            kept.select_nth_unstable_by(k - 1, |a, b| a.1.total_cmp(&b.1));
            kept.truncate(k);
        }
        // Moments of the kept offsets from p (p itself counts, at zero), in f32:
        // offsets within a metre or so, far inside its precision.
        let (mut sum, mut products, mut count) = ([0f32; 3], [0f32; 6], 1u32);
        // A neighbourhood left in one row (or one column) is a line: its
        // smallest eigenvalue is near zero whatever the normal.
        let (mut other_row, mut other_col) = (false, false);
        for &(d, _, off_row, off_col) in kept.iter() {
            for (s, v) in sum.iter_mut().zip(d) {
                *s += v;
            }
            products[0] += d[0] * d[0];
            products[1] += d[0] * d[1];
            products[2] += d[0] * d[2];
            products[3] += d[1] * d[1];
            products[4] += d[1] * d[2];
            products[5] += d[2] * d[2];
            count += 1;
            other_row |= off_row;
            other_col |= off_col;
        }
        if count >= 3 && other_row && other_col {
            let sum = Vec3::new(sum[0].into(), sum[1].into(), sum[2].into());
            plane_from_moments(&p.cast::<f64>().coords, &sum, products.map(f64::from), f64::from(count), sensor)
        } else {
            let toward = sensor - p.cast::<f64>().coords;
            let normal = if toward.norm() > 0.0 { toward.normalize() } else { Vec3::z() };
            PointNormal { normal, curvature: 1.0 / 3.0, offset: 0.0 }
        }
    }
}

const CHUNK: usize = 512;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scan::normals::{NormalConfig, NormalEstimator};
    use crate::scan::range_image::{Projection, Recovery};
    use crate::scan::scan_grid::ScanGrid;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    /// An 8-beam scan (-17 to 3 degrees, 0.25 degree steps, 1 cm range
    /// noise) from 0.75 m above the floor of a 10 x 8 m room, with a 1 m
    /// box standing 2 m in front of the x = 5 wall: the floor grazed by the
    /// lowest beams, and depth jumps at the box's sides.
    fn scan() -> Vec<Point3<f32>> {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut points = Vec::new();
        for step in 0..1440 {
            let azimuth = step as f64 * 0.25f64.to_radians();
            for beam in 0..8 {
                let elevation = (-17.0 + 20.0 * beam as f64 / 7.0).to_radians();
                let ray = Vec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
                let mut range = f64::INFINITY;
                for (axis, face) in [(0, 5.0), (0, -5.0), (1, 4.0), (1, -4.0), (2, -0.75), (2, 2.25)] {
                    let t = face / ray[axis];
                    if t > 0.0 {
                        range = range.min(t);
                    }
                }
                // The box: x in [3, 4], y in [-0.5, 0.5], up to 0.25 m above the sensor.
                let t = 3.0 / ray.x;
                let at = ray * t;
                if t > 0.0 && at.y.abs() <= 0.5 && at.z <= 0.25 {
                    range = range.min(t);
                }
                points.push((ray * (range + rng.random_range(-0.01..0.01))).cast::<f32>().into());
            }
        }
        points
    }

    /// The true normal of a point of `scan()`'s surfaces (the box's face
    /// toward the sensor, the walls, the floor); zero elsewhere.
    fn true_normal(p: &Point3<f32>) -> Vec3 {
        let p = p.cast::<f64>();
        if (p.x - 3.0).abs() < 0.05 && p.y.abs() < 0.45 {
            -Vec3::x()
        } else if (p.z + 0.75).abs() < 0.05 {
            Vec3::z()
        } else if (p.x.abs() - 5.0).abs() < 0.05 && p.y.abs() < 3.9 && p.z < 2.1 && p.z > -0.6 {
            -Vec3::x() * p.x.signum()
        } else if (p.y.abs() - 4.0).abs() < 0.05 && p.x.abs() < 4.9 && p.z < 2.1 && p.z > -0.6 {
            -Vec3::y() * p.y.signum()
        } else {
            Vec3::zeros()
        }
    }

    /// The floor, grazed by the lowest beams, stays whole: its normals point
    /// up. The exact k nearest are mostly on one ring there (a line: no
    /// normal to speak of).
    fn the_grazed_floor_stays_whole(points: &[Point3<f32>], organised: &[PointNormal], exact: &[PointNormal]) {
        let share_within = |v: &[f64], deg: f64| v.iter().filter(|&&e| e < deg).count() as f64 / v.len() as f64;
        let floor: Vec<f64> = points
            .iter()
            .zip(organised)
            .filter(|(p, _)| (p.z + 0.75).abs() < 0.05 && p.x.hypot(p.y) > 2.0)
            .map(|(_, n)| angle_deg(&n.normal, &Vec3::z()))
            .collect();
        let floor_exact: Vec<f64> = points
            .iter()
            .zip(exact)
            .filter(|(p, _)| (p.z + 0.75).abs() < 0.05 && p.x.hypot(p.y) > 2.0)
            .map(|(_, n)| angle_deg(&n.normal, &Vec3::z()))
            .collect();
        assert!(
            floor.len() > 1000 && share_within(&floor, 5.0) > 0.7 && share_within(&floor_exact, 5.0) < 0.5,
            "{} floor points, {:.3} within 5 degrees (exact {:.3})",
            floor.len(),
            share_within(&floor, 5.0),
            share_within(&floor_exact, 5.0)
        );
    }

    fn angle_deg(a: &Vec3, b: &Vec3) -> f64 {
        a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn the_range_image_normals_agree_with_the_exact_ones_and_stop_at_depth_jumps() {
        let points = scan();
        let sensor = Vec3::zeros();
        let image = RangeImage::recover(&points, &sensor, &Recovery::default()).unwrap();
        assert_eq!((image.projection, image.rows, image.cols), (Projection::Spherical, 8, 1440));
        let config = OrganisedNormalConfig::default();
        let organised = organised_normals(&points, &image, &sensor, 40, &config);
        let grid = ScanGrid::new(&points, &sensor);
        let exact = NormalEstimator::new(NormalConfig::default()).unwrap().estimate(&points, &grid).unwrap();
        let (mut errors_organised, mut errors_exact) = (Vec::new(), Vec::new());
        for (i, p) in points.iter().enumerate() {
            let t = true_normal(p);
            if t == Vec3::zeros() {
                continue;
            }
            errors_organised.push(angle_deg(&organised[i].normal, &t));
            errors_exact.push(angle_deg(&exact[i].normal, &t));
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let share_within = |v: &[f64], deg: f64| v.iter().filter(|&&e| e < deg).count() as f64 / v.len() as f64;
        assert!(errors_organised.len() > 9000, "{} points on known surfaces", errors_organised.len());
        let (mo, me) = (median(&mut errors_organised), median(&mut errors_exact));
        assert!(mo < 1.5 && mo < 1.5 * me + 0.2, "median error organised {mo:.2} deg, exact {me:.2} deg");
        assert!(share_within(&errors_organised, 5.0) >= share_within(&errors_exact, 5.0) - 0.01);
        the_grazed_floor_stays_whole(&points, &organised, &exact);
        // On the box's face, next to its sides (the wall 2 m behind), the
        // normals do not bleed: within 5 degrees of -x on both sides (the
        let edge: Vec<usize> = (0..points.len())
            .filter(|&i| {
                let p = points[i];
                (p.x - 3.0).abs() < 0.05 && (p.y.abs() - 0.5).abs() < 0.03 && p.z < 0.2 && p.z > -0.6
            })
            .collect();
        assert!(edge.len() >= 8, "{} points at the box's sides", edge.len());
        for &i in &edge {
            let e = angle_deg(&organised[i].normal, &-Vec3::x());
            let (row, col) = image.cell(i);
            let near: Vec<String> = (-1..=1)
                .flat_map(|dr| (-3..=3).map(move |dc| (dr, dc)))
                .filter_map(|(dr, dc)| {
                    image.at(row as i64 + dr, col as i64 + dc).map(|j| format!("{dr},{dc}: {:?}", points[j]))
                })
                .collect();
            assert!(
                e < 5.0,
                "box edge point {:?}: organised normal {e:.1} deg off; exact {:.1}; {near:#?}",
                points[i],
                angle_deg(&exact[i].normal, &-Vec3::x())
            );
        }
    }

    #[test]
    fn a_point_alone_on_its_surface_is_not_taken_for_a_plane() {
        // Four rows of a wall 2 m away and one stray return 10 m behind it.
        let mut points: Vec<Point3<f32>> = Vec::new();
        for row in 0..4 {
            for col in 0..40 {
                let (e, a) = ((row as f64 - 1.5).to_radians(), (col as f64 * 0.5 - 10.0).to_radians());
                let ray = Vec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
                let range = if row == 2 && col == 20 { 12.0 / ray.x } else { 2.0 / ray.x };
                points.push((ray * range).cast::<f32>().into());
            }
        }
        let image =
            RangeImage::recover_as(&points, &Vec3::zeros(), Projection::Spherical, &Recovery::default()).unwrap();
        let normals = organised_normals(&points, &image, &Vec3::zeros(), 40, &OrganisedNormalConfig::default());
        let stray = 2 * 40 + 20;
        assert_eq!(normals[stray].curvature, 1.0 / 3.0);
        assert!(angle_deg(&normals[stray].normal, &-points[stray].cast::<f64>().coords.normalize()) < 1e-6);
        // Its neighbours on the wall are planes facing the sensor, untouched by it.
        for i in [stray - 1, stray + 1, stray - 40, stray + 40] {
            assert!(normals[i].curvature < 1e-6 && angle_deg(&normals[i].normal, &-Vec3::x()) < 1e-3, "point {i}");
        }
    }

    #[test]
    fn settings_outside_their_range_are_refused_by_name() {
        let bad = OrganisedNormalConfig { max_incidence_deg: 90.0, ..Default::default() };
        assert_eq!(bad.validate().unwrap_err().field, "max_incidence_deg");
        let bad = OrganisedNormalConfig { jump_margin_m: f64::NAN, ..Default::default() };
        assert_eq!(bad.validate().unwrap_err().field, "jump_margin_m");
        let bad = OrganisedNormalConfig { spacing_factor: 0.5, ..Default::default() };
        assert_eq!(bad.validate().unwrap_err().field, "spacing_factor");
        assert!(OrganisedNormalConfig::default().validate().is_ok());
    }
}
