//! 2-D convolution on host memory as im2col tiles and one GEMM per tile: the
//! forward pass, the input gradient and the weight gradient.
//!
//! Why: Burn 0.22's CPU backends have no weight-gradient kernel; the generic
//! one runs a forward convolution whose kernel is the output gradient, a
//! skinny matrix product at a few percent of the machine's peak. Written as
//! `dW_g += grad_g · cols^T` over tiles of output positions, the same work is
//! a well-shaped GEMM (M = output channels, N = patch length, K = tile).
//!
//! Layouts are Burn's: input `[N, C, H, W]`, weight `[O, C/groups, KH, KW]`,
//! output `[N, O, OH, OW]`, all contiguous row-major `f32`.

use gemm::Parallelism;
use rayon::prelude::*;

use crate::kernels::direct_conv;

/// The sizes of one convolution. `padding` is the padding before each
/// spatial axis; padding after it only shows in `out_hw`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvGeometry {
    pub batch: usize,
    pub in_channels: usize,
    pub in_hw: [usize; 2],
    pub out_channels: usize,
    pub out_hw: [usize; 2],
    pub kernel: [usize; 2],
    pub stride: [usize; 2],
    pub padding: [usize; 2],
    pub dilation: [usize; 2],
    pub groups: usize,
}

impl ConvGeometry {
    /// The geometry of `x` [N, C, H, W] convolved with `weight` [O, C/g, KH, KW]
    /// with padding `(begin, end)` per axis; `None` when the shapes do not fit.
    pub fn new(
        x: [usize; 4],
        weight: [usize; 4],
        stride: [usize; 2],
        padding: [(usize, usize); 2],
        dilation: [usize; 2],
        groups: usize,
    ) -> Option<Self> {
        let [batch, in_channels, h, w] = x;
        let [out_channels, group_in, kh, kw] = weight;
        if groups == 0 || kh == 0 || kw == 0 || group_in * groups != in_channels || out_channels % groups != 0 {
            return None;
        }
        let out = |i: usize| -> Option<usize> {
            let size = [h, w][i] + padding[i].0 + padding[i].1;
            let span = dilation[i] * ([kh, kw][i] - 1) + 1;
            (size >= span && stride[i] > 0).then(|| (size - span) / stride[i] + 1)
        };
        Some(Self {
            batch,
            in_channels,
            in_hw: [h, w],
            out_channels,
            out_hw: [out(0)?, out(1)?],
            kernel: [kh, kw],
            stride,
            padding: [padding[0].0, padding[1].0],
            dilation,
            groups,
        })
    }

    /// For stride 1 and one group: the convolution whose forward pass is
    /// this one's input gradient (output gradient in, input gradient out).
    fn transposed(&self) -> Option<Self> {
        if self.stride != [1, 1] || self.groups != 1 {
            return None;
        }
        let span = |i: usize| self.dilation[i] * (self.kernel[i] - 1);
        let pad = |i: usize| -> Option<(usize, usize)> {
            // Before: span - p_begin; after: chosen so the output is the input size.
            let before = span(i).checked_sub(self.padding[i])?;
            let after = (self.in_hw[i] + span(i)).checked_sub(self.out_hw[i] + before)?;
            Some((before, after))
        };
        Self::new(
            [self.batch, self.out_channels, self.out_hw[0], self.out_hw[1]],
            [self.in_channels, self.out_channels, self.kernel[0], self.kernel[1]],
            [1, 1],
            [pad(0)?, pad(1)?],
            self.dilation,
            1,
        )
        .filter(|t| t.out_hw == self.in_hw)
    }

    fn group_in(&self) -> usize {
        self.in_channels / self.groups
    }

    fn group_out(&self) -> usize {
        self.out_channels / self.groups
    }

    /// Rows of one group's im2col matrix: input channels x kernel taps.
    fn patch_len(&self) -> usize {
        self.group_in() * self.kernel[0] * self.kernel[1]
    }

    fn out_len(&self) -> usize {
        self.out_hw[0] * self.out_hw[1]
    }

    fn in_len(&self) -> usize {
        self.in_hw[0] * self.in_hw[1]
    }

    /// Values of one image, [C, H, W].
    fn image_len(&self) -> usize {
        self.in_channels * self.in_len()
    }

    /// Image `n` of an input `x`.
    fn image<'a>(&self, x: &'a [f32], n: usize) -> &'a [f32] {
        &x[n * self.image_len()..][..self.image_len()]
    }

    /// Where `group`'s first row of `tile` starts in an output-shaped buffer.
    fn out_offset(&self, tile: Tile, group: usize) -> usize {
        (tile.image * self.out_channels + group * self.group_out()) * self.out_len() + tile.start
    }

    /// Multiply-adds of one pass (forward, input or weight gradient).
    pub fn flops(&self) -> f64 {
        2.0 * (self.batch * self.out_channels * self.out_len() * self.patch_len()) as f64
    }

    /// Output positions per tile: an im2col tile of about 1 MB stays in the
    /// L2 cache, but never fewer than 256 columns (the weight gradient's
    /// GEMM depth) nor more than one image. A multiple of 16 (one AVX-512
    /// register of f32): `gemm` then reads the forward's im2col tile where
    /// it lies instead of packing a copy of it, for up to 48 output channels.
    fn tile_columns(&self) -> usize {
        let columns = (262_144 / self.patch_len().max(1)).clamp(256, 4096) / 16 * 16;
        columns.min(self.out_len().max(1))
    }

    /// Every tile as (image, first output position, length), image by image.
    fn tiles(&self) -> Vec<Tile> {
        let step = self.tile_columns();
        let len = self.out_len();
        (0..self.batch)
            .flat_map(|image| {
                (0..len).step_by(step).map(move |start| Tile { image, start, len: step.min(len - start) })
            })
            .collect()
    }
}

#[derive(Debug, Clone, Copy)]
struct Tile {
    image: usize,
    start: usize,
    len: usize,
}

/// A pointer that tasks writing disjoint parts of one buffer may share.
#[derive(Clone, Copy)]
struct SharedMut(*mut f32);
// SAFETY: every user writes only its own tiles' elements.
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// The pointer `offset` elements on. (A method, so that closures capture
    /// the whole `SharedMut` and not its raw-pointer field.)
    fn at(self, offset: usize) -> *mut f32 {
        self.0.wrapping_add(offset)
    }
}

/// The tiles split into at most one contiguous run per thread.
fn split_tiles(tiles: &[Tile]) -> Vec<&[Tile]> {
    let tasks = rayon::current_num_threads().clamp(1, tiles.len().max(1));
    let per_task = tiles.len().div_ceil(tasks).max(1);
    tiles.chunks(per_task).collect()
}

/// GEMM threading: one task runs the product on every thread, several tasks
/// each run theirs on one.
fn gemm_parallelism(tasks: usize) -> Parallelism {
    if tasks <= 1 && rayon::current_num_threads() > 1 { Parallelism::Rayon(0) } else { Parallelism::None }
}

/// For kernel offset `start` (may be negative) and `count` outputs spaced
/// `stride` apart, the range of outputs that land inside `0..size`.
fn valid_range(start: isize, stride: usize, count: usize, size: usize) -> (usize, usize) {
    let stride = stride as isize;
    let first = if start < 0 { ((-start) + stride - 1) / stride } else { 0 };
    let last = if start >= size as isize { 0 } else { (size as isize - 1 - start) / stride + 1 };
    let first = (first as usize).min(count);
    (first, (last as usize).clamp(first, count))
}

/// Calls `f(row, column offset in the tile, input row y, first input x,
/// run length)` for every (patch row, output row segment) of a tile; `y` is
/// `None` when the segment reads only padding.
fn for_each_segment(
    geo: &ConvGeometry,
    tile: Tile,
    mut f: impl FnMut(usize, usize, Option<usize>, isize, usize, usize),
) {
    let [kh, kw] = geo.kernel;
    let [ih, _] = geo.in_hw;
    let [_, ow] = geo.out_hw;
    for c in 0..geo.group_in() {
        for ki in 0..kh {
            for kj in 0..kw {
                let row = (c * kh + ki) * kw + kj;
                let (mut done, mut position) = (0, tile.start);
                while done < tile.len {
                    let (oy, ox) = (position / ow, position % ow);
                    let run = (ow - ox).min(tile.len - done);
                    let y = (oy * geo.stride[0] + ki * geo.dilation[0]) as isize - geo.padding[0] as isize;
                    let x0 = (ox * geo.stride[1] + kj * geo.dilation[1]) as isize - geo.padding[1] as isize;
                    let y = (0..ih as isize).contains(&y).then_some(y as usize);
                    f(c, row, y, x0, done, run);
                    done += run;
                    position += run;
                }
            }
        }
    }
}

/// Fills `cols` [patch_len, tile.len] with the input patches of `group` of
/// `image` (its [C, H, W] slice).
fn im2col(geo: &ConvGeometry, image: &[f32], group: usize, tile: Tile, cols: &mut [f32]) {
    let (iw, plane) = (geo.in_hw[1], geo.in_len());
    let sx = geo.stride[1];
    for_each_segment(geo, tile, |c, row, y, x0, at, run| {
        let dst = &mut cols[row * tile.len + at..][..run];
        let Some(y) = y else {
            dst.fill(0.0);
            return;
        };
        let src = &image[(group * geo.group_in() + c) * plane + y * iw..][..iw];
        let (lo, hi) = valid_range(x0, sx, run, iw);
        dst[..lo].fill(0.0);
        dst[hi..].fill(0.0);
        if lo == hi {
            return;
        }
        let first = (x0 + (lo * sx) as isize) as usize;
        if sx == 1 {
            dst[lo..hi].copy_from_slice(&src[first..first + hi - lo]);
        } else {
            for (i, v) in dst[lo..hi].iter_mut().enumerate() {
                *v = src[first + i * sx];
            }
        }
    });
}

/// Adds `cols` [patch_len, tile.len] back onto the input positions they were
/// read from (the adjoint of `im2col`).
fn col2im(geo: &ConvGeometry, cols: &[f32], group: usize, tile: Tile, image: &mut [f32]) {
    let (iw, plane) = (geo.in_hw[1], geo.in_len());
    let sx = geo.stride[1];
    for_each_segment(geo, tile, |c, row, y, x0, at, run| {
        let Some(y) = y else { return };
        let src = &cols[row * tile.len + at..][..run];
        let dst = &mut image[(group * geo.group_in() + c) * plane + y * iw..][..iw];
        let (lo, hi) = valid_range(x0, sx, run, iw);
        if lo == hi {
            return;
        }
        let first = (x0 + (lo * sx) as isize) as usize;
        for (i, v) in src[lo..hi].iter().enumerate() {
            dst[first + i * sx] += v;
        }
    });
}

fn check_lengths(geo: &ConvGeometry, x: Option<&[f32]>, weight: Option<&[f32]>, out: Option<&[f32]>) {
    if let Some(x) = x {
        assert_eq!(x.len(), geo.batch * geo.in_channels * geo.in_len(), "input length");
    }
    if let Some(w) = weight {
        assert_eq!(w.len(), geo.out_channels * geo.patch_len(), "weight length");
    }
    if let Some(o) = out {
        assert_eq!(o.len(), geo.batch * geo.out_channels * geo.out_len(), "output length");
    }
}

/// The convolution `x * weight + bias`, [N, O, OH, OW].
pub fn forward(x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry) -> Vec<f32> {
    forward_then(x, weight, bias, geo, false)
}

/// `relu(x * weight + bias)`: the bias and the ReLU applied to each tile
/// right after its GEMM, while it is in cache, instead of two more passes
/// over the output. NaN stays NaN, as in Burn's and PyTorch's ReLU.
pub fn forward_relu(x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry) -> Vec<f32> {
    forward_then(x, weight, bias, geo, true)
}

/// The ReLU's backward pass given its output, in place: `grad` kept where
/// the output is above zero (or NaN), zeroed elsewhere, as Burn's
/// `relu_backward`.
pub fn relu_grad(out: &[f32], grad: &mut [f32]) {
    assert_eq!(out.len(), grad.len(), "ReLU output and gradient lengths");
    grad.par_chunks_mut(1 << 14).zip(out.par_chunks(1 << 14)).for_each(|(grad, out)| {
        for (g, &o) in grad.iter_mut().zip(out) {
            *g = if o.is_nan() || o > 0.0 { *g } else { 0.0 };
        }
    });
}

/// The forward pass by the direct kernel where it applies (3x3 layers with
/// few output channels), by im2col + GEMM elsewhere.
fn forward_then(x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry, relu: bool) -> Vec<f32> {
    check_lengths(geo, Some(x), Some(weight), None);
    if let Some(bias) = bias {
        assert_eq!(bias.len(), geo.out_channels, "bias length");
    }
    if direct_conv::applies(geo) {
        return direct_conv::forward(x, weight, bias, geo, relu);
    }
    forward_im2col(x, weight, bias, geo, relu)
}

/// The forward pass as im2col tiles and one GEMM per tile, for any geometry.
pub fn forward_im2col(x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry, relu: bool) -> Vec<f32> {
    check_lengths(geo, Some(x), Some(weight), None);
    if let Some(bias) = bias {
        assert_eq!(bias.len(), geo.out_channels, "bias length");
    }
    let (patch, l, og) = (geo.patch_len(), geo.out_len(), geo.group_out());
    let len = geo.batch * geo.out_channels * l;
    if patch == 0 {
        return vec![0.0; len];
    }
    // Not zeroed: the GEMMs below (which do not read their destination)
    // write every value once; on reused heap memory the memset was a few
    // percent of a training step.
    let mut out: Vec<f32> = Vec::with_capacity(len);
    let tiles = geo.tiles();
    let tasks = split_tiles(&tiles);
    let parallelism = gemm_parallelism(tasks.len());
    let dst = SharedMut(out.as_mut_ptr());
    tasks.par_iter().for_each(|task| {
        let mut cols = vec![0.0f32; patch * geo.tile_columns()];
        for &tile in *task {
            let image = geo.image(x, tile.image);
            for g in 0..geo.groups {
                im2col(geo, image, g, tile, &mut cols);
                let offset = geo.out_offset(tile, g);
                // SAFETY: out[image, group's rows, tile's columns] belongs to
                // this tile alone; strides stay inside `out`, `weight`, `cols`.
                unsafe {
                    gemm::gemm(
                        og,
                        tile.len,
                        patch,
                        dst.at(offset),
                        1,
                        l as isize,
                        false,
                        weight.as_ptr().add(g * og * patch),
                        1,
                        patch as isize,
                        cols.as_ptr(),
                        1,
                        tile.len as isize,
                        0.0,
                        1.0,
                        false,
                        false,
                        false,
                        parallelism,
                    );
                }
                if bias.is_none() && !relu {
                    continue;
                }
                for r in 0..og {
                    // SAFETY: row `r` of this tile's block, as written by the GEMM above.
                    let row = unsafe { std::slice::from_raw_parts_mut(dst.at(offset + r * l), tile.len) };
                    if let Some(bias) = bias {
                        let b = bias[g * og + r];
                        row.iter_mut().for_each(|v| *v += b);
                    }
                    if relu {
                        row.iter_mut().for_each(|v| *v = if v.is_nan() || *v > 0.0 { *v } else { 0.0 });
                    }
                }
            }
        }
    });
    // SAFETY: the tiles cover every image's output columns and the groups
    // every channel, so each of the `len` values was written above.
    unsafe { out.set_len(len) };
    out
}

/// The gradient with respect to the weight, [O, C/g, KH, KW]: by the
/// direct kernel where it applies (3x3 layers with up to 32 output
/// channels), by im2col + GEMM elsewhere.
pub fn weight_grad(x: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    check_lengths(geo, Some(x), None, Some(grad));
    if direct_conv::applies(geo) {
        return direct_conv::weight_grad(x, grad, geo);
    }
    weight_grad_im2col(x, grad, geo)
}

/// The weight gradient as `dW_g = sum over tiles of grad_g(tile) ·
/// im2col(tile)^T`, for any geometry.
pub fn weight_grad_im2col(x: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    check_lengths(geo, Some(x), None, Some(grad));
    let (patch, l, og) = (geo.patch_len(), geo.out_len(), geo.group_out());
    let tiles = geo.tiles();
    let tasks = split_tiles(&tiles);
    let parallelism = gemm_parallelism(tasks.len());
    // One partial sum per task, added at the end: no two tasks write the
    // same memory and each GEMM runs without synchronisation.
    let partials: Vec<Vec<f32>> = tasks
        .par_iter()
        .map(|task| {
            let mut acc = vec![0.0f32; geo.out_channels * patch];
            let mut cols = vec![0.0f32; patch * geo.tile_columns()];
            for &tile in *task {
                let image = geo.image(x, tile.image);
                for g in 0..geo.groups {
                    im2col(geo, image, g, tile, &mut cols);
                    let offset = geo.out_offset(tile, g);
                    // SAFETY: `acc` and `cols` are this task's own; the
                    // strides stay inside `acc`, `grad` and `cols`.
                    unsafe {
                        gemm::gemm(
                            og,
                            patch,
                            tile.len,
                            acc.as_mut_ptr().add(g * og * patch),
                            1,
                            patch as isize,
                            true,
                            grad.as_ptr().add(offset),
                            1,
                            l as isize,
                            cols.as_ptr(),
                            tile.len as isize,
                            1,
                            1.0,
                            1.0,
                            false,
                            false,
                            false,
                            parallelism,
                        );
                    }
                }
            }
            acc
        })
        .collect();
    let mut partials = partials.into_iter();
    let mut total = partials.next().unwrap_or_else(|| vec![0.0; geo.out_channels * patch]);
    for partial in partials {
        total.iter_mut().zip(partial).for_each(|(t, p)| *t += p);
    }
    total
}

/// The gradient with respect to the input, [N, C, H, W].
///
/// With stride 1 and one group it is itself a convolution, of the output
/// gradient with the flipped, transposed kernel, and takes the forward
/// kernel (a GEMM as deep as output channels x taps); otherwise it is
/// `col2im(weight_g^T · grad_g(tile))`, whose GEMM is only as deep as the
/// output channels.
pub fn input_grad(weight: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    check_lengths(geo, None, Some(weight), Some(grad));
    if let Some(transposed) = geo.transposed() {
        return forward(grad, &flipped_transpose(weight, geo), None, &transposed);
    }
    input_grad_col2im(weight, grad, geo)
}

/// `weight` [O, C, KH, KW] as [C, O, KH, KW] with both spatial axes
/// reversed: the kernel of the transposed convolution.
fn flipped_transpose(weight: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let [kh, kw] = geo.kernel;
    let (o_n, c_n) = (geo.out_channels, geo.in_channels);
    let mut out = vec![0.0; weight.len()];
    for o in 0..o_n {
        for c in 0..c_n {
            for i in 0..kh {
                for j in 0..kw {
                    out[((c * o_n + o) * kh + kh - 1 - i) * kw + kw - 1 - j] =
                        weight[((o * c_n + c) * kh + i) * kw + j];
                }
            }
        }
    }
    out
}

/// The input gradient by GEMM and col2im, for any stride and groups.
pub fn input_grad_col2im(weight: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    check_lengths(geo, None, Some(weight), Some(grad));
    let (patch, l, og) = (geo.patch_len(), geo.out_len(), geo.group_out());
    let mut dx = vec![0.0f32; geo.batch * geo.image_len()];
    let tiles = geo.tiles();
    // Tiles of one image overlap on the input, so images are the unit of
    // parallel work; a batch smaller than the thread count threads the GEMM.
    let parallelism = gemm_parallelism(geo.batch);
    dx.par_chunks_mut(geo.image_len().max(1)).enumerate().for_each(|(n, image)| {
        let mut cols = vec![0.0f32; patch * geo.tile_columns()];
        for &tile in tiles.iter().filter(|t| t.image == n) {
            for g in 0..geo.groups {
                let offset = geo.out_offset(tile, g);
                // SAFETY: `cols` is this task's own; strides stay inside
                // `weight` (read transposed), `grad` and `cols`.
                unsafe {
                    gemm::gemm(
                        patch,
                        tile.len,
                        og,
                        cols.as_mut_ptr(),
                        1,
                        tile.len as isize,
                        false,
                        weight.as_ptr().add(g * og * patch),
                        patch as isize,
                        1,
                        grad.as_ptr().add(offset),
                        1,
                        l as isize,
                        0.0,
                        1.0,
                        false,
                        false,
                        false,
                        parallelism,
                    );
                }
                col2im(geo, &cols, g, tile, image);
            }
        }
    });
    dx
}

/// The gradient with respect to the bias: `grad` [N, O, positions] summed
/// over images and positions, [O] (accumulated in f64).
pub fn bias_grad(grad: &[f32], batch: usize, channels: usize) -> Vec<f32> {
    let positions = grad.len() / (batch * channels).max(1);
    assert_eq!(grad.len(), batch * channels * positions, "output gradient length");
    (0..channels)
        .into_par_iter()
        .map(|o| (0..batch).map(|n| sum_f64(&grad[(n * channels + o) * positions..][..positions])).sum::<f64>() as f32)
        .collect()
}

/// The sum of `values` in f64, in 8 running sums (one chain of additions
/// would wait on each one's latency).
fn sum_f64(values: &[f32]) -> f64 {
    let mut sums = [0.0f64; 8];
    let chunks = values.chunks_exact(8);
    let rest = chunks.remainder().iter().map(|&v| f64::from(v)).sum::<f64>();
    for chunk in chunks {
        for (sum, &v) in sums.iter_mut().zip(chunk) {
            *sum += f64::from(v);
        }
    }
    sums.iter().sum::<f64>() + rest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The textbook definition, one multiply-add at a time.
    fn direct_forward(x: &[f32], w: &[f32], geo: &ConvGeometry) -> Vec<f32> {
        let [oh, ow] = geo.out_hw;
        let [ih, iw] = geo.in_hw;
        let [kh, kw] = geo.kernel;
        let (cg, og) = (geo.group_in(), geo.group_out());
        let mut out = vec![0.0; geo.batch * geo.out_channels * oh * ow];
        for n in 0..geo.batch {
            for o in 0..geo.out_channels {
                let g = o / og;
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut sum = 0.0;
                        for c in 0..cg {
                            for ki in 0..kh {
                                for kj in 0..kw {
                                    let y =
                                        (oy * geo.stride[0] + ki * geo.dilation[0]) as isize - geo.padding[0] as isize;
                                    let xx =
                                        (ox * geo.stride[1] + kj * geo.dilation[1]) as isize - geo.padding[1] as isize;
                                    if y < 0 || xx < 0 || y >= ih as isize || xx >= iw as isize {
                                        continue;
                                    }
                                    let xi = ((n * geo.in_channels + g * cg + c) * ih + y as usize) * iw + xx as usize;
                                    sum += x[xi] * w[((o * cg + c) * kh + ki) * kw + kj];
                                }
                            }
                        }
                        out[((n * geo.out_channels + o) * oh + oy) * ow + ox] = sum;
                    }
                }
            }
        }
        out
    }

    fn values(len: usize, seed: u32) -> Vec<f32> {
        // A small deterministic sequence in [-1, 1).
        (0..len)
            .map(|i| {
                (((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8) as f32 / (1 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    #[test]
    fn forward_matches_the_definition_with_stride_padding_dilation_and_groups() {
        let geo = ConvGeometry::new([2, 4, 9, 7], [6, 2, 3, 2], [2, 1], [(1, 2), (0, 1)], [1, 2], 2).unwrap();
        let (x, w) = (values(2 * 4 * 63, 1), values(6 * 2 * 6, 2));
        let ours = forward(&x, &w, None, &geo);
        let reference = direct_forward(&x, &w, &geo);
        assert_eq!(ours.len(), reference.len());
        for (a, b) in ours.iter().zip(&reference) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    #[test]
    fn the_fused_bias_and_relu_are_those_applied_afterwards() {
        let geo = ConvGeometry::new([2, 3, 10, 9], [5, 3, 3, 3], [1, 1], [(1, 1), (1, 1)], [1, 1], 1).unwrap();
        let (mut x, w, bias) = (values(2 * 3 * 90, 5), values(5 * 3 * 9, 6), values(5, 7));
        x[17] = f32::NAN;
        let plain = forward(&x, &w, Some(&bias), &geo);
        let fused = forward_relu(&x, &w, Some(&bias), &geo);
        let relu = |v: f32| if v.is_nan() || v > 0.0 { v } else { 0.0 };
        assert!(plain.iter().any(|v| v.is_nan()) && plain.iter().any(|&v| v < 0.0));
        for (i, (&p, &f)) in plain.iter().zip(&fused).enumerate() {
            assert!(relu(p).to_bits() == f.to_bits(), "element {i}: relu({p}) against {f}");
        }
        // The backward mask keeps the gradient where the output is positive or NaN.
        let grad = values(fused.len(), 8);
        let mut masked = grad.clone();
        relu_grad(&fused, &mut masked);
        for ((&o, &g), &m) in fused.iter().zip(&grad).zip(&masked) {
            assert_eq!(m, if o.is_nan() || o > 0.0 { g } else { 0.0 });
        }
    }

    #[test]
    fn the_gradients_are_the_adjoints_of_the_forward() {
        // <grad, conv(x, w)> is linear in x and in w, so its derivatives are
        // exactly weight_grad and input_grad: check <dx, x> = <dw, w> = <g, y>.
        let geo = ConvGeometry::new([3, 2, 11, 8], [4, 2, 3, 3], [2, 2], [(1, 1), (1, 1)], [1, 1], 1).unwrap();
        let (x, w) = (values(3 * 2 * 88, 3), values(4 * 2 * 9, 4));
        let y = forward(&x, &w, None, &geo);
        let g = values(y.len(), 5);
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(p, q)| (p * q) as f64).sum::<f64>();
        let gy = dot(&g, &y);
        let gw = dot(&weight_grad(&x, &g, &geo), &w);
        let gx = dot(&input_grad(&w, &g, &geo), &x);
        assert!(geo.transposed().is_none(), "stride 2 takes the col2im path");
        assert!((gy - gw).abs() < 1e-3 * gy.abs().max(1.0), "{gy} vs {gw}");
        assert!((gy - gx).abs() < 1e-3 * gy.abs().max(1.0), "{gy} vs {gx}");
    }

    #[test]
    fn both_input_gradient_paths_agree_for_stride_one() {
        for (pad, dilation) in [((1, 1), 1), ((0, 2), 1), ((2, 2), 2), ((0, 0), 1)] {
            let geo = ConvGeometry::new([2, 3, 10, 9], [5, 3, 3, 3], [1, 1], [pad, (1, 0)], [dilation, 1], 1).unwrap();
            assert!(geo.transposed().is_some(), "{pad:?} {dilation}");
            let w = values(5 * 3 * 9, 6);
            let g = values(2 * 5 * geo.out_len(), 7);
            let fast = input_grad(&w, &g, &geo);
            let general = input_grad_col2im(&w, &g, &geo);
            for (a, b) in fast.iter().zip(&general) {
                assert!((a - b).abs() < 1e-4, "{pad:?} {dilation}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn tiles_that_start_mid_row_read_padding_past_the_right_edge() {
        // 27 wide, 5x5 with padding 2: 729 positions per image and a patch
        // of 48 x 25, so tiles of 256 columns start mid-row, where taps fall
        // past the last column.
        let geo = ConvGeometry::new([1, 48, 27, 27], [3, 48, 5, 5], [1, 1], [(2, 2), (2, 2)], [1, 1], 1).unwrap();
        assert_eq!(geo.tile_columns(), 256);
        let (x, w) = (values(48 * 729, 8), values(3 * 48 * 25, 9));
        let reference = direct_forward(&x, &w, &geo);
        // f32 sums of 1200 products: compare against the output's scale.
        let scale = reference.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        for (a, b) in forward(&x, &w, None, &geo).iter().zip(&reference) {
            assert!((a - b).abs() < 1e-5 * scale, "{a} vs {b}");
        }
    }

    #[test]
    fn shapes_that_do_not_fit_are_refused() {
        assert!(ConvGeometry::new([1, 3, 8, 8], [4, 2, 3, 3], [1, 1], [(0, 0); 2], [1, 1], 1).is_none());
        assert!(ConvGeometry::new([1, 3, 2, 2], [4, 3, 5, 5], [1, 1], [(0, 0); 2], [1, 1], 1).is_none());
        assert!(ConvGeometry::new([1, 3, 8, 8], [4, 3, 0, 3], [1, 1], [(0, 0); 2], [1, 1], 1).is_none());
    }
}
