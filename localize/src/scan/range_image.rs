//! A scan's rows and columns, recovered from its points' directions: the
//! beams (by elevation) and azimuth steps of a spinning LIDAR, or the pixel
//! rows and columns of a depth image lifted through a pinhole camera. What
//! the organised normals need: each point's cell, and each cell's point.
//!
//! A spinning LIDAR's beams each keep one elevation, so the sorted elevations
//! fall into tight clusters with gaps between them; a pinhole depth image's
//! rows each keep one `z / x` and its columns one `y / x` (x forward). A cloud that does
//! not cluster so (a map, a voxel-thinned cloud, a solid-state scanner) is
//! not organised, and the exact k-nearest path serves it.

use std::f64::consts::{PI, TAU};

use datasets::math::{Vec3, median};
use nalgebra::Point3;
use rayon::prelude::*;

/// No point in this cell.
pub const EMPTY: u32 = u32::MAX;

/// How directions are laid out on the sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Projection {
    /// Rows by elevation above the sensor's x-y plane, columns by azimuth
    /// around its z axis, wrapping around a full turn.
    Spherical,
    /// Rows by `z / x`, columns by `y / x` (x forward, as a depth camera's
    /// points arrive in its body frame): a depth image's pixels.
    Pinhole,
}

/// The thresholds of the recovery.
#[derive(Debug, Clone, Copy)]
pub struct Recovery {
    /// Sorted row coordinates (elevation, or `z / x`) further apart than
    /// this (radians, or the tangent for a pinhole) start a new row.
    pub row_gap: f64,
    /// At most this share of the points may share a cell with another one.
    pub max_shared_cells: f64,
}

impl Default for Recovery {
    fn default() -> Self {
        Self { row_gap: 0.05f64.to_radians(), max_shared_cells: 0.1 }
    }
}

/// Why a cloud has no row and column structure.
#[derive(Debug, Clone, PartialEq)]
pub enum NotOrganised {
    TooFewPoints(usize),
    /// The row coordinates do not fall into separate clusters.
    Rows(usize),
    /// Too many points share a cell (columns not on a regular pitch).
    SharedCells(f64),
    /// The rows and columns would hold far more cells than there are points.
    Sparse {
        cells: usize,
        points: usize,
    },
}

impl std::fmt::Display for NotOrganised {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewPoints(n) => write!(f, "{n} points are too few for rows and columns"),
            Self::Rows(n) => write!(f, "the points' row coordinates fall into {n} clusters, not separate rows"),
            Self::SharedCells(share) => write!(f, "{:.0} % of the points share a cell", share * 100.0),
            Self::Sparse { cells, points } => write!(f, "{cells} cells for {points} points"),
        }
    }
}

#[derive(Debug, Clone)]
pub struct RangeImage {
    pub projection: Projection,
    pub rows: usize,
    pub cols: usize,
    /// The angular size of a row step and of a column step (radians; at the
    /// image centre for a pinhole): the shape of a neighbourhood.
    pub row_pitch: f64,
    pub col_pitch: f64,
    /// Each point's cell, `row * cols + col`.
    cell_of: Vec<u32>,
    /// Each cell's point ([`EMPTY`]: none): the first of the points binned there.
    occupant: Vec<u32>,
}

impl RangeImage {
    /// The rows and columns of `points` seen from `sensor`, by the first
    /// projection under which they are organised.
    pub fn recover(points: &[Point3<f32>], sensor: &Vec3, recovery: &Recovery) -> Result<Self, NotOrganised> {
        match Self::recover_as(points, sensor, Projection::Spherical, recovery) {
            Ok(image) => Ok(image),
            Err(spherical) => Self::recover_as(points, sensor, Projection::Pinhole, recovery).map_err(|_| spherical),
        }
    }

    pub fn recover_as(
        points: &[Point3<f32>],
        sensor: &Vec3,
        projection: Projection,
        recovery: &Recovery,
    ) -> Result<Self, NotOrganised> {
        if points.len() < 16 {
            return Err(NotOrganised::TooFewPoints(points.len()));
        }
        let coordinates: Vec<[f64; 2]> = points
            .par_iter()
            .map(|p| {
                let v = p.cast::<f64>().coords - sensor;
                match projection {
                    Projection::Spherical => [v.z.atan2(v.x.hypot(v.y)), v.y.atan2(v.x)],
                    Projection::Pinhole if v.x > 0.0 => [v.z / v.x, v.y / v.x],
                    Projection::Pinhole => [f64::NAN, f64::NAN],
                }
            })
            .collect();
        let (row_of, row_centres) = cluster_rows(&coordinates, recovery.row_gap)?;
        let rows = row_centres.len();
        let row_pitch = median(row_centres.windows(2).map(|w| w[1] - w[0]).collect()).unwrap_or(1.0);
        let col_pitch = column_pitch(&coordinates, &row_of, rows).ok_or(NotOrganised::Rows(rows))?;
        let (col0, cols, wraps) = match projection {
            Projection::Spherical => (-PI, ((TAU / col_pitch).round() as usize).clamp(1, 1 << 16), true),
            Projection::Pinhole => {
                let (lo, hi) = coordinates
                    .iter()
                    .filter(|c| c[1].is_finite())
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), c| (lo.min(c[1]), hi.max(c[1])));
                let cols = ((hi - lo) / col_pitch).round() as usize + 1;
                (lo, cols.min(1 << 16), false)
            }
        };
        // A range image is mostly full; one far emptier is no image (and
        // would be a large allocation).
        if rows * cols > MAX_CELLS_PER_POINT * points.len() {
            return Err(NotOrganised::Sparse { cells: rows * cols, points: points.len() });
        }
        let col_width = if wraps { TAU / cols as f64 } else { col_pitch };
        let phase = if wraps { row_phases(&coordinates, &row_of, rows, col0, col_width) } else { vec![0.0; rows] };
        let mut occupant = vec![EMPTY; rows * cols];
        let mut cell_of = Vec::with_capacity(points.len());
        let mut shared = 0usize;
        for (i, (c, &row)) in coordinates.iter().zip(&row_of).enumerate() {
            let col = ((c[1] - col0) / col_width - phase[row as usize]).round();
            let col = if !col.is_finite() {
                0
            } else if wraps {
                (col as i64).rem_euclid(cols as i64) as usize
            } else {
                (col.max(0.0) as usize).min(cols - 1)
            };
            let cell = row as usize * cols + col;
            if occupant[cell] == EMPTY {
                occupant[cell] = i as u32;
            } else {
                shared += 1;
            }
            cell_of.push(cell as u32);
        }
        let share = shared as f64 / points.len() as f64;
        if !(share <= recovery.max_shared_cells) {
            return Err(NotOrganised::SharedCells(share));
        }
        Ok(Self { projection, rows, cols, row_pitch, col_pitch, cell_of, occupant })
    }

    pub fn len(&self) -> usize {
        self.cell_of.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cell_of.is_empty()
    }

    /// Point `i`'s row and column.
    #[inline]
    pub fn cell(&self, i: usize) -> (usize, usize) {
        let cell = self.cell_of[i] as usize;
        (cell / self.cols, cell % self.cols)
    }

    /// The point in `row`, column `col` (taken around the turn where the
    /// columns wrap), if any.
    #[inline]
    pub fn at(&self, row: i64, col: i64) -> Option<usize> {
        if row < 0 || row >= self.rows as i64 {
            return None;
        }
        let cols = self.cols as i64;
        let col = match self.projection {
            Projection::Spherical if col < 0 && col >= -cols => col + cols,
            Projection::Spherical if col >= cols && col < 2 * cols => col - cols,
            Projection::Spherical => col.rem_euclid(cols),
            Projection::Pinhole if (0..cols).contains(&col) => col,
            Projection::Pinhole => return None,
        };
        let j = self.occupant[(row * cols + col) as usize];
        (j != EMPTY).then_some(j as usize)
    }
}

/// Each point's row (by its first coordinate) and the rows' centres, low to
/// high. In linear time: the coordinates binned at a quarter of `gap`, rows
/// are runs of occupied bins with more than `gap` of empty ones between
/// them. Points with no coordinate (behind a pinhole) go to row 0; more
/// than 1 % of them and the cloud is not organised.
fn cluster_rows(coordinates: &[[f64; 2]], gap: f64) -> Result<(Vec<u32>, Vec<f64>), NotOrganised> {
    let finite = coordinates.iter().filter(|c| c[0].is_finite()).count();
    if finite * 100 < coordinates.len() * 99 || finite == 0 {
        return Err(NotOrganised::Rows(0));
    }
    let (lo, hi) = coordinates
        .iter()
        .filter(|c| c[0].is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), c| (lo.min(c[0]), hi.max(c[0])));
    let width = gap / 4.0;
    // A spread too wide to bin (a point grazing a pinhole's image plane, say)
    // is no image.
    let span_bins = (hi - lo) / width;
    if !(span_bins < (1u64 << 24) as f64) {
        return Err(NotOrganised::Rows(0));
    }
    let bins = span_bins as usize + 1;
    let bin_of = |value: f64| (((value - lo) / width) as usize).min(bins - 1);
    // Per bin: count, sum, least and greatest value.
    let mut histogram = vec![(0u32, 0.0f64, f64::INFINITY, f64::NEG_INFINITY); bins];
    for c in coordinates.iter().filter(|c| c[0].is_finite()) {
        let h = &mut histogram[bin_of(c[0])];
        *h = (h.0 + 1, h.1 + c[0], h.2.min(c[0]), h.3.max(c[0]));
    }
    // Rows: (count, sum, least, greatest); each bin's row.
    let mut rows: Vec<(u32, f64, f64, f64)> = Vec::new();
    let mut row_of_bin = vec![0u32; bins];
    let mut last_value = f64::NEG_INFINITY;
    for (b, h) in histogram.iter().enumerate() {
        if h.0 > 0 {
            if rows.is_empty() || h.2 - last_value > gap {
                rows.push((0, 0.0, h.2, h.3));
            }
            let row = rows.last_mut().expect("a row");
            *row = (row.0 + h.0, row.1 + h.1, row.2.min(h.2), row.3.max(h.3));
            last_value = h.3;
        }
        row_of_bin[b] = rows.len().saturating_sub(1) as u32;
    }
    let centres: Vec<f64> = rows.iter().map(|r| r.1 / f64::from(r.0)).collect();
    // A row needs a run of points along it, and at least two rows make an image.
    let count = centres.len();
    if !(2..=4096).contains(&count) || count * 8 > coordinates.len() {
        return Err(NotOrganised::Rows(count));
    }
    // A beam's (or pixel row's) points keep one coordinate: each row must be
    // narrow beside the gaps to its neighbours, or the clusters are only
    // breaks in a continuum (a pinhole image seen as beams, say).
    let in_narrow_rows: u32 = (0..count)
        .filter(|&r| {
            let below = if r > 0 { centres[r] - centres[r - 1] } else { f64::INFINITY };
            let above = if r + 1 < count { centres[r + 1] - centres[r] } else { f64::INFINITY };
            rows[r].3 - rows[r].2 < 0.25 * below.min(above)
        })
        .map(|r| rows[r].0)
        .sum();
    if (in_narrow_rows as usize) * 20 < finite * 19 {
        return Err(NotOrganised::Rows(count));
    }
    let row_of = coordinates.par_iter().map(|c| if c[0].is_finite() { row_of_bin[bin_of(c[0])] } else { 0 }).collect();
    Ok((row_of, centres))
}

/// Where each row's azimuths fall between column centres (a fraction of a
/// column, their circular mean): a beam fires at its own azimuth offset, and
/// its points are binned to the nearest column centre of its own phase.
fn row_phases(coordinates: &[[f64; 2]], row_of: &[u32], rows: usize, col0: f64, width: f64) -> Vec<f64> {
    let mut sums = vec![(0.0, 0.0); rows];
    for (c, &row) in coordinates.iter().zip(row_of) {
        if c[1].is_finite() {
            let turn = TAU * ((c[1] - col0) / width).fract();
            sums[row as usize].0 += turn.cos();
            sums[row as usize].1 += turn.sin();
        }
    }
    // Each row's phase taken nearest the phase of all rows together, so that
    // rows whose phases straddle half a column keep their columns aligned.
    let (x, y) = sums.iter().fold((0.0, 0.0), |(x, y), s| (x + s.0, y + s.1));
    let common = y.atan2(x) / TAU;
    sums.iter()
        .map(|&(x, y)| {
            let own = y.atan2(x) / TAU;
            common + (own - common + 0.5).rem_euclid(1.0) - 0.5
        })
        .collect()
}

/// The median step between neighbouring points along the rows.
fn column_pitch(coordinates: &[[f64; 2]], row_of: &[u32], rows: usize) -> Option<f64> {
    let mut by_row: Vec<Vec<f64>> = vec![Vec::new(); rows];
    for (c, &row) in coordinates.iter().zip(row_of) {
        if c[1].is_finite() {
            by_row[row as usize].push(c[1]);
        }
    }
    // The fullest rows say it well enough (sorting them all costs more than
    // the rest of the recovery).
    by_row.sort_by_key(|values| std::cmp::Reverse(values.len()));
    by_row.truncate(PITCH_ROWS);
    let mut steps = Vec::new();
    for values in &mut by_row {
        values.sort_unstable_by(f64::total_cmp);
        steps.extend(values.windows(2).map(|w| w[1] - w[0]).filter(|&d| d > 1e-9));
    }
    median(steps).filter(|p| p.is_finite() && *p > 0.0)
}

/// Cells a range image may hold per point (a depth image with most of its
/// pixels out of range, a LIDAR scan with much open sky).
const MAX_CELLS_PER_POINT: usize = 32;

/// Rows whose points give the column pitch.
const PITCH_ROWS: usize = 8;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    /// A spinning scan of a 6 m room from (0.3, -0.2, 0.1): `beams` beams,
    /// `steps` azimuth steps from `azimuth0`, 2 cm range noise, 3 % of the
    /// returns missing; each point with its beam and step.
    fn spinning_scan(beams: usize, steps: usize, azimuth0: f64) -> (Vec<Point3<f32>>, Vec<(usize, usize)>, Vec3) {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let sensor = Vec3::new(0.3, -0.2, 0.1);
        let (mut points, mut cells) = (Vec::new(), Vec::new());
        for step in 0..steps {
            let azimuth = azimuth0 + step as f64 * TAU / steps as f64;
            for beam in 0..beams {
                if rng.random_range(0.0..1.0) < 0.03 {
                    continue;
                }
                let elevation = (-20.0 + 30.0 * beam as f64 / (beams - 1) as f64).to_radians();
                let ray = Vec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
                let range = [(-3.0, ray.x), (3.0, ray.x), (-3.0, ray.y), (3.0, ray.y), (-1.0, ray.z), (2.0, ray.z)]
                    .iter()
                    .map(|&(face, along): &(f64, f64)| {
                        let from = face - sensor[if face.abs() == 3.0 && along == ray.x { 0 } else { 1 }];
                        (face, along, from)
                    })
                    .filter(|(_, along, _)| along.abs() > 1e-9)
                    .map(|(_, along, from)| from / along)
                    .filter(|t| *t > 0.0)
                    .fold(f64::INFINITY, f64::min);
                let range = if range.is_finite() { range } else { 10.0 };
                points.push((sensor + ray * (range + rng.random_range(-0.02..0.02))).cast::<f32>().into());
                cells.push((beam, step));
            }
        }
        (points, cells, sensor)
    }

    #[test]
    fn a_spinning_scan_gives_back_its_beams_and_azimuth_steps() {
        let (points, cells, sensor) = spinning_scan(16, 900, -PI + 0.2f64.to_radians());
        let image = RangeImage::recover(&points, &sensor, &Recovery::default()).unwrap();
        assert_eq!((image.projection, image.rows, image.cols), (Projection::Spherical, 16, 900));
        assert!((image.row_pitch - 2.0f64.to_radians()).abs() < 1e-6, "{}", image.row_pitch.to_degrees());
        assert!((image.col_pitch - 0.4f64.to_radians()).abs() < 1e-6, "{}", image.col_pitch.to_degrees());
        // Rows in the beams' order, columns in the steps' order (one fixed
        // shift around the turn), each point in a cell of its own.
        let shift = (image.cell(0).1 + 900 - cells[0].1) % 900;
        for (i, &(beam, step)) in cells.iter().enumerate() {
            assert_eq!(image.cell(i), (beam, (step + shift) % 900), "point {i}");
            assert_eq!(image.at(beam as i64, (step + shift) as i64), Some(i));
        }
        assert_eq!(image.at(3, -1), image.at(3, 899), "the columns wrap around the turn");
        assert_eq!(image.at(-1, 0), None);
    }

    #[test]
    fn a_depth_image_gives_back_its_pixels() {
        // A 64 x 48 depth image (f 50) of a slanted wall, as the body frame
        // sees it (x forward, y left, z up), with holes.
        let (mut points, mut pixels) = (Vec::new(), Vec::new());
        for v in 0..48 {
            for u in 0..64 {
                if (u * 7 + v * 3) % 11 == 0 {
                    continue;
                }
                let (y, z) = (-(u as f64 - 31.5) / 50.0, -(v as f64 - 23.5) / 50.0);
                let depth = 3.0 + 0.5 * y;
                points.push(Point3::new(depth as f32, (y * depth) as f32, (z * depth) as f32));
                pixels.push((v, u));
            }
        }
        let image = RangeImage::recover(&points, &Vec3::zeros(), &Recovery::default()).unwrap();
        assert_eq!((image.projection, image.rows, image.cols), (Projection::Pinhole, 48, 64));
        // Rows run up (z / x grows), columns left (y / x grows): image rows and columns reversed.
        for (i, &(v, u)) in pixels.iter().enumerate() {
            assert_eq!(image.cell(i), (47 - v, 63 - u), "pixel ({u}, {v})");
        }
    }

    #[test]
    fn scattered_and_thinned_clouds_are_not_organised() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let scattered: Vec<Point3<f32>> = (0..5000)
            .map(|_| Point3::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0), rng.random_range(-2.0..2.0)))
            .collect();
        assert!(RangeImage::recover(&scattered, &Vec3::zeros(), &Recovery::default()).is_err());
        // A spinning scan thinned to 20 cm voxel centroids loses its beams.
        let (points, _, sensor) = spinning_scan(16, 900, 0.0);
        let thinned = crate::scan::voxel::VoxelFilter::new(crate::scan::voxel::VoxelConfig { size_m: 0.2 })
            .unwrap()
            .downsample(&points);
        assert!(RangeImage::recover(&thinned, &sensor, &Recovery::default()).is_err());
        assert!(RangeImage::recover(&points[..10], &sensor, &Recovery::default()).is_err());
        // One point nearly in the sensor's plane spreads the coordinates
        // beyond binning: refused, not a huge allocation.
        let mut grazing = points.clone();
        grazing[0] = Point3::new(1e-30, 1.0, 1.0);
        assert!(RangeImage::recover_as(&grazing, &Vec3::zeros(), Projection::Pinhole, &Recovery::default()).is_err());
        // Two rings of points in close pairs: a column pitch of a microradian
        // would make an image of 131,072 cells for 64 points.
        let pairs: Vec<Point3<f32>> = (0..64)
            .map(|k| {
                let (ring, pair, second) = (k / 32, (k % 32) / 2, k % 2);
                let azimuth = pair as f64 * 0.2 + second as f64 * 1e-6;
                let elevation = (ring as f64).to_radians();
                let ray = Vec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
                (ray * 5.0).cast::<f32>().into()
            })
            .collect();
        let error = RangeImage::recover_as(&pairs, &Vec3::zeros(), Projection::Spherical, &Recovery::default());
        assert!(matches!(error, Err(NotOrganised::Sparse { points: 64, .. })), "{error:?}");
    }
}
