//! The neighbour index of a scan: its points binned by direction from the
//! sensor (elevation and azimuth), the layout of a spinning LIDAR's range
//! image, with exact k-nearest and radius searches.
//!
//! Exactness comes from one bound: a point `q` seen at angle `theta` from
//! the direction of `p` (theta below 90 degrees) is at least
//! `|p| sin(theta)` from `p`, whatever its range. A search whose current
//! k-th distance is `d` therefore only needs the directions within
//! `asin(d / |p|)` of `p`'s: a window of rows (elevation) and of columns
//! (azimuth, widened by `1 / cos(elevation)`). Each row of the window is one
//! contiguous run of the cell-sorted points, so a search reads a few short
//! slices instead of walking a tree.

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use datasets::math::Vec3;
use nalgebra::Point3;
use rayon::prelude::*;

/// Added to every angular bound, far above the rounding of the angles.
const ANGLE_MARGIN: f64 = 1e-6;

/// Buffers of one searching thread, reused from search to search, and the
/// code that measures its distances.
#[derive(Debug)]
pub struct NeighbourScratch {
    runs: Vec<[usize; 2]>,
    distances: [f32; 64],
    /// A candidate's squared distance (its f32 bits, which order as the
    /// values do for values >= 0) above its place in the cell order.
    candidates: Vec<u64>,
    found: Vec<u32>,
    /// True only where the CPU has AVX-512F (checked when made).
    avx512: bool,
}

impl Default for NeighbourScratch {
    /// Searches with the widest vectors the CPU has (AVX-512 only in builds
    /// with the `avx512` feature).
    fn default() -> Self {
        #[cfg(target_arch = "x86_64")]
        let avx512 = cfg!(feature = "avx512") && std::arch::is_x86_feature_detected!("avx512f");
        #[cfg(not(target_arch = "x86_64"))]
        let avx512 = false;
        Self { avx512, ..Self::portable() }
    }
}

impl NeighbourScratch {
    /// Searches with code for any CPU: the same neighbours, in the same
    /// order, as the default.
    pub fn portable() -> Self {
        Self { runs: Vec::new(), distances: [0.0; 64], candidates: Vec::new(), found: Vec::new(), avx512: false }
    }

    /// Whether searches use AVX-512.
    pub fn is_avx512(&self) -> bool {
        self.avx512
    }
}

pub struct ScanGrid {
    sensor: Vec3,
    rows: usize,
    cols: usize,
    /// Elevation of the lower edge of row 0 and the rows' height (radians).
    elevation0: f64,
    row_height: f64,
    /// Azimuth width of a column (radians); columns start at azimuth -pi.
    col_width: f64,
    /// Cell `r * cols + c` holds the points `cell_start[cell]..cell_start[cell + 1]`
    /// of the cell order.
    cell_start: Vec<u32>,
    /// The points' coordinates in cell order (one array per axis, so that
    /// distances are computed several at a time), their indices in the
    /// input, and the inverse: each input point's place in the cell order.
    xs: Vec<f32>,
    ys: Vec<f32>,
    zs: Vec<f32>,
    original: Vec<u32>,
    slot: Vec<u32>,
    /// The cosine of each row edge's elevation (`rows + 1` edges).
    edge_cos: Vec<f64>,
    /// Per input point: direction and range from the sensor.
    directions: Vec<Direction>,
}

#[derive(Debug, Clone, Copy)]
struct Direction {
    elevation: f64,
    cos_elevation: f64,
    azimuth: f64,
    range: f64,
}

impl Direction {
    fn of(v: &Vec3) -> Self {
        let horizontal = v.x.hypot(v.y);
        let range = v.norm();
        Self {
            elevation: v.z.atan2(horizontal),
            cos_elevation: if range > 0.0 { horizontal / range } else { 1.0 },
            azimuth: v.y.atan2(v.x),
            range,
        }
    }
}

/// A block of cells: rows `row_lo..=row_hi` and columns `col_lo..=col_hi`
/// (unwrapped: a column index is taken modulo the column count).
#[derive(Debug, Clone, Copy)]
struct Window {
    row_lo: usize,
    row_hi: usize,
    col_lo: i64,
    col_hi: i64,
}

impl ScanGrid {
    /// Bins `points` by their direction from `sensor`, with about two points
    /// a cell over the directions the cloud spans.
    pub fn new(points: &[Point3<f32>], sensor: &Vec3) -> Self {
        let directions: Vec<Direction> =
            points.par_iter().map(|p| Direction::of(&(p.cast::<f64>().coords - sensor))).collect();
        let (low, high) = directions
            .iter()
            .filter(|d| d.elevation.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), d| (lo.min(d.elevation), hi.max(d.elevation)));
        let (low, high) = if low <= high { (low, high) } else { (0.0, 0.0) };
        let span = (high - low).max(1e-3);
        let cells_wanted = (points.len() as f64 / 2.0).max(1.0);
        let side = (span * TAU / cells_wanted).sqrt().max(1e-5);
        let cols = ((TAU / side).ceil() as usize).clamp(1, 1 << 16);
        let rows = ((span / side).floor() as usize + 1).clamp(1, 1 << 16);
        let mut grid = Self {
            sensor: *sensor,
            rows,
            cols,
            elevation0: low,
            row_height: span / rows as f64 * (1.0 + 1e-9),
            col_width: TAU / cols as f64,
            cell_start: Vec::new(),
            xs: Vec::new(),
            ys: Vec::new(),
            zs: Vec::new(),
            original: Vec::new(),
            slot: Vec::new(),
            edge_cos: Vec::new(),
            directions,
        };
        // A counting sort of the points by cell.
        let cells: Vec<usize> = grid.directions.par_iter().map(|d| grid.cell_of(d)).collect();
        let mut start = vec![0u32; rows * cols + 1];
        for &cell in &cells {
            start[cell + 1] += 1;
        }
        for i in 0..rows * cols {
            start[i + 1] += start[i];
        }
        let mut next = start.clone();
        let mut original = vec![0u32; points.len()];
        let mut slot = vec![0u32; points.len()];
        for (i, &cell) in cells.iter().enumerate() {
            original[next[cell] as usize] = i as u32;
            slot[i] = next[cell];
            next[cell] += 1;
        }
        grid.slot = slot;
        grid.edge_cos = (0..=rows)
            .map(|r| (grid.elevation0 + r as f64 * grid.row_height).clamp(-FRAC_PI_2, FRAC_PI_2).cos())
            .collect();
        grid.xs = original.par_iter().map(|&i| points[i as usize].x).collect();
        grid.ys = original.par_iter().map(|&i| points[i as usize].y).collect();
        grid.zs = original.par_iter().map(|&i| points[i as usize].z).collect();
        grid.original = original;
        grid.cell_start = start;
        grid
    }

    /// Where the points are seen from.
    pub fn sensor(&self) -> Vec3 {
        self.sensor
    }

    pub fn len(&self) -> usize {
        self.original.len()
    }

    pub fn is_empty(&self) -> bool {
        self.original.is_empty()
    }

    #[inline]
    fn row_of(&self, elevation: f64) -> usize {
        let row = ((elevation - self.elevation0) / self.row_height).floor();
        if row.is_nan() { 0 } else { (row.max(0.0) as usize).min(self.rows - 1) }
    }

    #[inline]
    fn col_of(&self, azimuth: f64) -> i64 {
        let col = ((azimuth + PI) / self.col_width).floor();
        if col.is_nan() { 0 } else { col as i64 }
    }

    fn cell_of(&self, d: &Direction) -> usize {
        self.row_of(d.elevation) * self.cols + self.col_of(d.azimuth).rem_euclid(self.cols as i64) as usize
    }

    /// Every cell that can hold a point within `distance` of a point seen in
    /// direction `at`.
    #[inline(always)]
    fn window(&self, at: &Direction, distance: f64) -> Window {
        let everything = Window { row_lo: 0, row_hi: self.rows - 1, col_lo: 0, col_hi: self.cols as i64 - 1 };
        if !(distance < at.range) {
            return everything;
        }
        let sin_theta = distance / at.range;
        let theta = sin_theta.asin() + ANGLE_MARGIN;
        let row_lo = self.row_of(at.elevation - theta);
        let row_hi = self.row_of(at.elevation + theta);
        // The haversine formula: a point `theta` away differs in azimuth by at
        // most 2 asin(sin(theta / 2) / sqrt(cos e_p cos e_q)); cos e_q is
        // smallest at an edge of the rows' span.
        let cos_q = self.edge_cos[row_lo].min(self.edge_cos[row_hi + 1]);
        let sin_half = ((1.0 - (1.0 - sin_theta * sin_theta).sqrt()) / 2.0).sqrt() + ANGLE_MARGIN;
        let s = sin_half / (at.cos_elevation * cos_q).sqrt();
        if !(s < 1.0) {
            return Window { row_lo, row_hi, ..everything };
        }
        let phi = 2.0 * s.asin() + ANGLE_MARGIN;
        let col_lo = self.col_of(at.azimuth - phi);
        let col_hi = self.col_of(at.azimuth + phi);
        if col_hi - col_lo + 1 >= self.cols as i64 {
            return Window { row_lo, row_hi, ..everything };
        }
        Window { row_lo, row_hi, col_lo, col_hi }
    }

    /// The runs of the cell order that a window covers, into `runs`: per
    /// row one run, two where the columns wrap around; empty runs left out.
    #[inline(always)]
    fn runs(&self, w: &Window, runs: &mut Vec<[usize; 2]>) {
        runs.clear();
        let cols = self.cols as i64;
        for row in w.row_lo..=w.row_hi {
            let base = row * self.cols;
            let lo = w.col_lo.rem_euclid(cols) as usize;
            let hi = lo + (w.col_hi - w.col_lo) as usize;
            let parts = if hi < self.cols { [[lo, hi], [1, 0]] } else { [[lo, self.cols - 1], [0, hi - self.cols]] };
            for [c0, c1] in parts {
                if c0 <= c1 {
                    let a = self.cell_start[base + c0] as usize;
                    let b = self.cell_start[base + c1 + 1] as usize;
                    if a < b {
                        runs.push([a, b]);
                    }
                }
            }
        }
    }

    /// The input index of the point at `slot` of the cell order.
    #[inline]
    pub fn input_index(&self, slot: u32) -> usize {
        self.original[slot as usize] as usize
    }

    /// The point at `slot` of the cell order.
    #[inline]
    pub fn point(&self, slot: u32) -> [f32; 3] {
        let j = slot as usize;
        [self.xs[j], self.ys[j], self.zs[j]]
    }

    /// The `k` nearest points to point `i` (itself included), as slots of
    /// the cell order (`point`, `input_index`), in no particular order;
    /// among points equally far, those earlier in the cell order. `hint`
    /// is the neighbourhood radius to try first, updated to this search's
    /// k-th distance (scans list points in sweep order, so the next point's
    /// neighbourhood is about as large).
    #[inline(always)]
    pub fn nearest<'s>(&self, i: usize, k: usize, hint: &mut f64, scratch: &'s mut NeighbourScratch) -> &'s [u32] {
        let at = self.directions[i];
        let p = self.point(self.slot[i]);
        let k = k.min(self.len());
        let NeighbourScratch { runs, distances, candidates, found, avx512 } = scratch;
        found.clear();
        if k == 0 {
            return found;
        }
        let mut radius = if hint.is_finite() && *hint > 0.0 { *hint * 1.2 } else { at.range.max(0.05) * 0.02 };
        loop {
            // Every point within `radius` is in the window; if there are k
            // of them, the k nearest are among them.
            let window = self.window(&at, radius * (1.0 + 1e-5));
            let r2 = (radius * radius) as f32;
            candidates.clear();
            self.runs(&window, runs);
            for &[a, b] in runs.iter() {
                #[cfg(target_arch = "x86_64")]
                if *avx512 {
                    // SAFETY: `avx512` is only ever true where the CPU has AVX-512F.
                    unsafe { self.push_within_avx512(a, b, p, r2, candidates) };
                    continue;
                }
                candidates.reserve(b - a);
                for start in (a..b).step_by(64) {
                    let end = (start + 64).min(b);
                    let (xs, ys, zs) = (&self.xs[start..end], &self.ys[start..end], &self.zs[start..end]);
                    // The squared distances and which of them are inside the
                    // ball as bits (compared 8 at a time), then only those read.
                    let mut inside = 0u64;
                    for (j, ((x, y), z)) in xs.iter().zip(ys).zip(zs).enumerate() {
                        let d = [x - p[0], y - p[1], z - p[2]];
                        let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                        distances[j] = d2;
                        inside |= u64::from(d2 <= r2) << j;
                    }
                    while inside != 0 {
                        let j = inside.trailing_zeros() as usize;
                        candidates.push((u64::from(distances[j].to_bits()) << 32) | (start + j) as u64);
                        inside &= inside - 1;
                    }
                }
            }
            if candidates.len() < k {
                if radius == f64::INFINITY {
                    // Fewer than k points at a finite distance (a NaN
                    // coordinate): all of them.
                    found.extend(candidates.iter().map(|&c| c as u32));
                    return found;
                }
                if !(radius < at.range) {
                    // The window is already every cell: take every point.
                    radius = f64::INFINITY;
                    continue;
                }
                // Points on a surface grow with the radius squared.
                let grow = if candidates.is_empty() { 2.0 } else { 1.1 * (k as f64 / candidates.len() as f64).sqrt() };
                radius *= grow.clamp(1.2, 4.0);
                continue;
            }
            let farthest = select_smallest(candidates, k, r2);
            *hint = f64::from(f32::from_bits((farthest >> 32) as u32)).sqrt();
            found.extend(candidates[..k].iter().map(|&c| c as u32));
            return found;
        }
    }

    /// The slots `a..b` within `sqrt(r2)` of `p` appended to `candidates`
    /// as keys, 16 at a time: the portable loop's keys, in its order (the
    /// same arithmetic, without fused multiply-adds).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline]
    fn push_within_avx512(&self, a: usize, b: usize, p: [f32; 3], r2: f32, candidates: &mut Vec<u64>) {
        use std::arch::x86_64::*;
        let (xs, ys, zs) = (&self.xs[a..b], &self.ys[a..b], &self.zs[a..b]);
        // Each step stores 16 keys, however few are inside.
        candidates.reserve(b - a + 16);
        let (px, py, pz, r2) = (_mm512_set1_ps(p[0]), _mm512_set1_ps(p[1]), _mm512_set1_ps(p[2]), _mm512_set1_ps(r2));
        let lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        // Slot and distance bits side by side: the keys of lanes 0-7, then 8-15.
        let low = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
        let high = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
        let mut len = candidates.len();
        let out = candidates.as_mut_ptr();
        for start in (0..b - a).step_by(16) {
            let n = (b - a - start).min(16);
            let lanes: __mmask16 = if n == 16 { u16::MAX } else { (1 << n) - 1 };
            // SAFETY: the masked loads read lanes `start..start + n`, inside
            // the slices; the two stores write keys `len..len + 16`, inside
            // the capacity reserved above (`len` grows by at most `n`).
            unsafe {
                let dx = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, xs.as_ptr().add(start)), px);
                let dy = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, ys.as_ptr().add(start)), py);
                let dz = _mm512_sub_ps(_mm512_maskz_loadu_ps(lanes, zs.as_ptr().add(start)), pz);
                let d2 =
                    _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy)), _mm512_mul_ps(dz, dz));
                let inside = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(lanes, d2, r2);
                let slots = _mm512_add_epi32(_mm512_set1_epi32((a + start) as i32), lane);
                let bits = _mm512_castps_si512(d2);
                let [first, second] = [inside as u8, (inside >> 8) as u8];
                let keys = _mm512_maskz_compress_epi64(first, _mm512_permutex2var_epi32(slots, low, bits));
                _mm512_storeu_si512(out.add(len).cast(), keys);
                len += first.count_ones() as usize;
                let keys = _mm512_maskz_compress_epi64(second, _mm512_permutex2var_epi32(slots, high, bits));
                _mm512_storeu_si512(out.add(len).cast(), keys);
                len += second.count_ones() as usize;
            }
        }
        // SAFETY: keys up to `len` were written above.
        unsafe { candidates.set_len(len) };
    }

    /// Input indices of every point within `radius` of `x` (unordered).
    pub fn within(&self, x: &Vec3, radius: f64, mut visit: impl FnMut(usize)) {
        let at = Direction::of(&(x - self.sensor));
        let window = self.window(&at, radius);
        let r2 = radius * radius;
        let mut runs = Vec::new();
        self.runs(&window, &mut runs);
        for [a, b] in runs {
            for j in a..b {
                let q = Vec3::new(f64::from(self.xs[j]), f64::from(self.ys[j]), f64::from(self.zs[j]));
                if (q - x).norm_squared() <= r2 {
                    visit(self.original[j] as usize);
                }
            }
        }
    }
}

/// Moves the `k` smallest of `keys` (squared distances within `r2` in
/// their high halves, as candidates are) to its front and returns the
/// largest of them. The same as a selection of the k-th key, cheaper: the
/// keys are first split at a guess of the k-th distance (points on a surface
/// fill a ball's squared radius about evenly), without branches, so that
/// the selection proper runs over the few keys near it.
#[inline(always)]
fn select_smallest(keys: &mut [u64], k: usize, r2: f32) -> u64 {
    debug_assert!(k >= 1 && keys.len() >= k);
    let guess = r2 * (k as f32 / keys.len() as f32);
    let split = if guess.is_finite() { (u64::from(guess.to_bits()) << 32) | u64::from(u32::MAX) } else { u64::MAX };
    let mut below = 0;
    for i in 0..keys.len() {
        // Keys before `below` are at most `split`, those from `below` to `i` above it.
        keys.swap(i, below);
        below += usize::from(keys[below] <= split);
    }
    if below >= k {
        keys[..below].select_nth_unstable(k - 1);
    } else {
        keys[below..].select_nth_unstable(k - below - 1);
    }
    keys[k - 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    fn brute_nearest(points: &[Point3<f32>], p: &Point3<f32>, k: usize) -> Vec<u32> {
        let mut order: Vec<u32> = (0..points.len() as u32).collect();
        let d2 = |i: u32| (points[i as usize] - p).norm_squared();
        order.sort_by(|&a, &b| d2(a).total_cmp(&d2(b)));
        order.truncate(k);
        order.sort_unstable();
        order
    }

    /// Rings of a spinning LIDAR in sweep order around `sensor`, a far
    /// cluster (so that the previous point's radius is sometimes far too
    /// small), points above and below the sensor (azimuth undefined near
    /// the poles), one at the sensor itself, and a shuffled copy.
    fn clouds(sensor: &Vec3) -> [Vec<Point3<f32>>; 2] {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut points: Vec<Point3<f32>> = Vec::new();
        for step in 0..400 {
            let a = step as f64 * TAU / 400.0;
            for ring in 0..6 {
                let e = (-15.0 + 6.0 * ring as f64).to_radians();
                let r = 3.0 / e.cos().max(0.3) + rng.random_range(-0.02..0.02);
                let v = Vec3::new(r * e.cos() * a.cos(), r * e.cos() * a.sin(), r * e.sin());
                points.push((sensor + v).cast::<f32>().into());
            }
        }
        for _ in 0..60 {
            let v = Vec3::new(20.0 + rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.0);
            points.push((sensor + v).cast::<f32>().into());
        }
        for _ in 0..60 {
            let v = Vec3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), rng.random_range(-4.0..4.0));
            points.push((sensor + v).cast::<f32>().into());
        }
        points.push(sensor.cast::<f32>().into());
        let mut shuffled = points.clone();
        for i in (1..shuffled.len()).rev() {
            shuffled.swap(i, rng.random_range(0..=i));
        }
        [points, shuffled]
    }

    #[test]
    fn nearest_finds_exactly_the_k_nearest() {
        let sensor = Vec3::new(1.0, -2.0, 0.5);
        for cloud in clouds(&sensor) {
            let grid = ScanGrid::new(&cloud, &sensor);
            // The widest vectors this CPU has, and code for any CPU.
            let (mut scratch, mut portable) = (NeighbourScratch::default(), NeighbourScratch::portable());
            for k in [1, 25, 40] {
                let (mut hint, mut portable_hint) = (f64::INFINITY, f64::INFINITY);
                for (i, p) in cloud.iter().enumerate() {
                    let slots = grid.nearest(i, k, &mut hint, &mut scratch).to_vec();
                    let portable_slots = grid.nearest(i, k, &mut portable_hint, &mut portable);
                    // The same neighbours in the same order: the same sums.
                    assert_eq!(slots, portable_slots, "point {i}, k {k}: the kernels differ");
                    let mut found: Vec<u32> = slots.iter().map(|&s| grid.input_index(s) as u32).collect();
                    found.sort_unstable();
                    assert_eq!(found, brute_nearest(&cloud, p, k), "point {i} at {p:?}, k {k}");
                }
            }
        }
    }

    #[test]
    fn select_smallest_takes_the_k_smallest_keys() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        for case in 0..2000 {
            let n = rng.random_range(1..200usize);
            let k = rng.random_range(1..=n);
            let r2 = rng.random_range(0.01f32..4.0);
            // Distances evenly spread, bunched near zero or near the radius,
            // all equal (a guess that splits nothing), and with ties.
            let keys: Vec<u64> = (0..n)
                .map(|slot| {
                    let u: f32 = rng.random_range(0.0..1.0);
                    let d2 = match case % 4 {
                        0 => r2 * u,
                        1 => r2 * u.powi(6),
                        2 => r2 * 0.5,
                        _ => r2 * (u * 4.0).floor() / 4.0,
                    };
                    (u64::from(d2.to_bits()) << 32) | slot as u64
                })
                .collect();
            let mut sorted = keys.clone();
            sorted.sort_unstable();
            let mut selected = keys.clone();
            let farthest = select_smallest(&mut selected, k, r2);
            assert_eq!(farthest, sorted[k - 1], "case {case}: n {n}, k {k}");
            selected[..k].sort_unstable();
            assert_eq!(selected[..k], sorted[..k], "case {case}: n {n}, k {k}");
        }
        // An infinite ball (the search's last resort) splits nothing.
        let mut keys: Vec<u64> = (0..10u64).rev().map(|slot| (u64::from(1.5f32.to_bits()) << 32) | slot).collect();
        assert_eq!(select_smallest(&mut keys, 3, f32::INFINITY) & 0xffff_ffff, 2);
    }

    #[test]
    fn within_finds_exactly_the_points_in_the_ball() {
        let sensor = Vec3::new(1.0, -2.0, 0.5);
        let [cloud, _] = clouds(&sensor);
        let grid = ScanGrid::new(&cloud, &sensor);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        for _ in 0..200 {
            let x = sensor
                + Vec3::new(rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0), rng.random_range(-3.0..3.0));
            let radius = rng.random_range(0.05..2.0);
            let mut found = Vec::new();
            grid.within(&x, radius, |i| found.push(i));
            found.sort_unstable();
            let expected: Vec<usize> = (0..cloud.len())
                .filter(|&i| (cloud[i].cast::<f64>().coords - x).norm_squared() <= radius * radius)
                .collect();
            assert_eq!(found, expected, "ball at {x:?} of radius {radius}");
        }
    }

    #[test]
    fn a_cloud_of_one_point_and_a_degenerate_cloud_are_searchable() {
        let sensor = Vec3::zeros();
        let one = [Point3::new(1.0f32, 0.0, 0.0)];
        let grid = ScanGrid::new(&one, &sensor);
        let mut hint = f64::INFINITY;
        let mut scratch = NeighbourScratch::default();
        let found = grid.nearest(0, 3, &mut hint, &mut scratch);
        assert_eq!(found.iter().map(|&s| grid.input_index(s)).collect::<Vec<_>>(), [0]);
        // A NaN coordinate: the search ends with the points it can measure.
        let mut with_nan: Vec<Point3<f32>> = (0..5).map(|i| Point3::new(1.0, i as f32 * 0.1, 0.0)).collect();
        with_nan.push(Point3::new(f32::NAN, 0.0, 0.0));
        let grid = ScanGrid::new(&with_nan, &sensor);
        let mut hint = f64::INFINITY;
        let mut found: Vec<usize> = grid
            .nearest(0, 6, &mut hint, &mut NeighbourScratch::default())
            .iter()
            .map(|&s| grid.input_index(s))
            .collect();
        found.sort_unstable();
        assert_eq!(found, [0, 1, 2, 3, 4]);
        assert!(grid.nearest(5, 3, &mut hint, &mut NeighbourScratch::default()).is_empty());
        // Every point at the sensor: no direction at all.
        let same = vec![Point3::new(0.0f32, 0.0, 0.0); 10];
        let grid = ScanGrid::new(&same, &sensor);
        let mut hint = f64::INFINITY;
        assert_eq!(grid.nearest(4, 3, &mut hint, &mut NeighbourScratch::default()).len(), 3);
    }
}
