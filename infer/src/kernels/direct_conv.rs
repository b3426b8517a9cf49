//! A direct 3x3 convolution (stride 1, padding 1, one group) for layers
//! with few output channels: VGG's 16- and 32-channel layers at width 1/4
//! and the input gradients of the layers after them.
//!
//! Why: im2col copies every input value nine times, and a GEMM with only
//! 16 or 32 output rows does 32-64 FLOP per copied value, so on those layers
//! the copy costs as much as the product. Here the input is copied once
//! (into a zero-padded frame) and a register block of four output channels
//! by up to 96 positions of one row accumulates over every channel and tap
//! before it is stored, with the bias and ReLU applied on the way out.
//!
//! One binary serves every x86-64 CPU: the AVX-512 or the AVX2 + FMA kernel
//! is picked at run time; elsewhere `applies` is false and the GEMM path
//! runs.

use rayon::prelude::*;

use crate::kernels::conv_kernels::ConvGeometry;

/// Output channels up to which the direct kernel beats im2col + GEMM
/// (`bench conv`; above it the GEMM's deeper products win).
const MAX_OUT_CHANNELS: usize = 32;

/// Output channels per register block.
const BLOCK_O: usize = 4;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Isa {
    Avx512,
    Avx2,
}

/// The widest kernels this CPU runs (AVX-512 only in builds with the
/// `avx512` feature).
fn isa() -> Option<Isa> {
    #[cfg(target_arch = "x86_64")]
    {
        if cfg!(feature = "avx512") && std::arch::is_x86_feature_detected!("avx512f") {
            return Some(Isa::Avx512);
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
            return Some(Isa::Avx2);
        }
    }
    None
}

/// Whether `forward` takes this convolution: 3x3, stride 1, padding 1, no
/// dilation, one group, at most `MAX_OUT_CHANNELS` outputs, on a CPU with
/// AVX2 + FMA or AVX-512.
pub fn applies(geo: &ConvGeometry) -> bool {
    geo.kernel == [3, 3]
        && geo.stride == [1, 1]
        && geo.padding == [1, 1]
        && geo.dilation == [1, 1]
        && geo.groups == 1
        && geo.out_hw == geo.in_hw
        && geo.out_channels <= MAX_OUT_CHANNELS
        && geo.in_hw[0] * geo.in_hw[1] > 0
        && isa().is_some()
}

/// Zeros after the padded frame: the forward kernel reads whole vectors
/// past a row's end (lanes it never stores), up to one vector past the last.
const FRAME_SLACK: usize = 16;

/// The input [N, C, H, W] in a frame one zero wide: [N, C, H + 2, W + 2],
/// then `FRAME_SLACK` zeros.
fn padded(x: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let [h, w] = geo.in_hw;
    let (ph, pw) = (h + 2, w + 2);
    let len = geo.batch * geo.in_channels * ph * pw;
    // Every value is written below (the border once, the interior once), so
    // the frame is not zeroed first: that memset cost as much as the copy.
    let mut out: Vec<f32> = Vec::with_capacity(len + FRAME_SLACK);
    out.spare_capacity_mut().par_chunks_mut(ph * pw).zip(x.par_chunks(h * w)).for_each(|(frame, plane)| {
        let zero = std::mem::MaybeUninit::new(0.0f32);
        frame[..pw].fill(zero);
        frame[(ph - 1) * pw..].fill(zero);
        for (y, row) in plane.chunks_exact(w).enumerate() {
            let line = &mut frame[(y + 1) * pw..][..pw];
            line[0] = zero;
            line[pw - 1] = zero;
            for (d, &v) in line[1..=w].iter_mut().zip(row) {
                *d = std::mem::MaybeUninit::new(v);
            }
        }
    });
    // SAFETY: the loop above wrote all `len` values.
    unsafe { out.set_len(len) };
    out.resize(len + FRAME_SLACK, 0.0);
    out
}

/// The weight [O, C, 3, 3] as blocks of `BLOCK_O` output channels,
/// [O / BLOCK_O (rounded up), C, 9, BLOCK_O], zero past the last channel.
fn packed_weight(weight: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let (o_n, c_n) = (geo.out_channels, geo.in_channels);
    let blocks = o_n.div_ceil(BLOCK_O);
    let mut out = vec![0.0f32; blocks * c_n * 9 * BLOCK_O];
    for o in 0..o_n {
        for c in 0..c_n {
            for tap in 0..9 {
                out[((o / BLOCK_O * c_n + c) * 9 + tap) * BLOCK_O + o % BLOCK_O] = weight[(o * c_n + c) * 9 + tap];
            }
        }
    }
    out
}

/// One call's pointers and sizes, shared by the kernels.
#[derive(Clone, Copy)]
struct Block {
    /// The padded frame at (channel 0, the output row's top tap row, the block's first column).
    input: *const f32,
    /// Elements between channels and between rows of the padded frame.
    plane: usize,
    row: usize,
    channels: usize,
    /// `packed_weight`'s block of these output channels.
    weight: *const f32,
    /// The output row of each channel at the block's first column.
    out: [*mut f32; BLOCK_O],
    /// Output channels of the block that exist.
    valid: usize,
    bias: [f32; BLOCK_O],
    relu: bool,
}

/// The convolution `relu?(x * weight + bias)`, [N, O, H, W]. Call only
/// where `applies` holds.
pub fn forward(x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry, relu: bool) -> Vec<f32> {
    let isa = isa().filter(|_| applies(geo)).expect("direct_conv::forward called where it does not apply");
    forward_with(isa, x, weight, bias, geo, relu)
}

/// `forward` with the kernels of `isa`, which the CPU must have.
fn forward_with(isa: Isa, x: &[f32], weight: &[f32], bias: Option<&[f32]>, geo: &ConvGeometry, relu: bool) -> Vec<f32> {
    let [h, w] = geo.in_hw;
    let (o_n, c_n) = (geo.out_channels, geo.in_channels);
    assert_eq!(x.len(), geo.batch * c_n * h * w, "input length");
    assert_eq!(weight.len(), o_n * c_n * 9, "weight length");
    let frame = padded(x, geo);
    let packed = packed_weight(weight, geo);
    let (plane, row) = ((h + 2) * (w + 2), w + 2);
    // Not zeroed: the blocks below write every output value exactly once.
    let len = geo.batch * o_n * h * w;
    let mut out: Vec<f32> = Vec::with_capacity(len);
    let dst = out.as_mut_ptr() as usize;
    let (lanes, max_vectors) = match isa {
        Isa::Avx512 => (16, 6),
        Isa::Avx2 => (8, 3),
    };
    (0..geo.batch * h).into_par_iter().with_min_len(2).for_each(|job| {
        let (n, y) = (job / h, job % h);
        for first in (0..o_n).step_by(BLOCK_O) {
            let valid = BLOCK_O.min(o_n - first);
            let mut out_rows = [std::ptr::null_mut(); BLOCK_O];
            let mut block_bias = [0.0f32; BLOCK_O];
            for i in 0..valid {
                // Row y of output channel first + i of image n; rows of
                // different jobs never overlap.
                out_rows[i] = (dst as *mut f32).wrapping_add(((n * o_n + first + i) * h + y) * w);
                block_bias[i] = bias.map_or(0.0, |b| b[first + i]);
            }
            // The row's vectors in blocks of as equal a size as the
            // register budget allows (224 columns: 5 + 5 + 4, not 6 + 6 + 2).
            let row_vectors = w.div_ceil(lanes);
            let per_block = row_vectors.div_ceil(row_vectors.div_ceil(max_vectors));
            let mut x0 = 0;
            while x0 < w {
                let vectors = (w - x0).div_ceil(lanes).min(per_block);
                let columns = (vectors * lanes).min(w - x0);
                let block = Block {
                    input: frame[(n * c_n * plane + y * row + x0)..].as_ptr(),
                    plane,
                    row,
                    channels: c_n,
                    weight: packed[first / BLOCK_O * c_n * 9 * BLOCK_O..].as_ptr(),
                    out: out_rows.map(|p| p.wrapping_add(x0)),
                    valid,
                    bias: block_bias,
                    relu,
                };
                // SAFETY: the kernel reads `vectors` x `lanes` + 2 values
                // from each of three rows of every channel of the padded frame
                // starting at `input`: at most `lanes` - 1 past a row's end
                // (columns > (vectors - 1) x lanes), so the last row's
                // overrun stays inside `FRAME_SLACK`; 9 x C x
                // BLOCK_O packed weights, and writes `columns` values to each
                // valid output row; the CPU has the kernel's features (`isa`).
                unsafe { run_kernel(isa, vectors, columns - (vectors - 1) * lanes, &block) };
                x0 += columns;
            }
        }
    });
    // SAFETY: the jobs above wrote every row of every output channel.
    unsafe { out.set_len(len) };
    out
}

/// Dispatches to the kernel for `vectors` vectors, the last of which holds
/// `tail` columns.
unsafe fn run_kernel(isa: Isa, vectors: usize, tail: usize, block: &Block) {
    #[cfg(target_arch = "x86_64")]
    unsafe {
        match (isa, vectors) {
            (Isa::Avx512, 1) => avx512::kernel::<1>(block, tail),
            (Isa::Avx512, 2) => avx512::kernel::<2>(block, tail),
            (Isa::Avx512, 3) => avx512::kernel::<3>(block, tail),
            (Isa::Avx512, 4) => avx512::kernel::<4>(block, tail),
            (Isa::Avx512, 5) => avx512::kernel::<5>(block, tail),
            (Isa::Avx512, 6) => avx512::kernel::<6>(block, tail),
            (Isa::Avx2, 1) => avx2::kernel::<1>(block, tail),
            (Isa::Avx2, 2) => avx2::kernel::<2>(block, tail),
            (Isa::Avx2, 3) => avx2::kernel::<3>(block, tail),
            _ => unreachable!("vectors per block are capped by the ISA"),
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (isa, vectors, tail, block);
        unreachable!("`applies` is false off x86-64");
    }
}

/// One weight-gradient call's pointers and sizes.
#[derive(Clone, Copy)]
struct GradBlock {
    /// The padded frame's row (tap row ky) of the band's first output row.
    input: *const f32,
    /// Elements between rows of the padded frame.
    row: usize,
    /// Each output channel's gradient at the band's first row; a channel
    /// past the last points at the first (its sums are dropped).
    grad: [*const f32; GRAD_BLOCK_MAX],
    rows: usize,
    width: usize,
    /// Where the block's lane sums go: [channel of the block][kx][lanes].
    sums: *mut f32,
}

/// Output channels per register block of the weight gradient: eight by
/// three taps (24 accumulators of 16 lanes) with AVX-512, four with AVX2.
const GRAD_BLOCK_MAX: usize = 8;

/// The gradient with respect to the weight, [O, C, 3, 3]. Call only where
/// `applies` holds: the kernel takes any number of outputs, but beyond
/// `MAX_OUT_CHANNELS` im2col + GEMM is faster (`bench conv`: ahead on
/// VGG16/4's 16- and 32-channel layers, behind on 64-channel ones).
pub fn weight_grad(x: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let isa = isa().filter(|_| applies(geo)).expect("direct_conv::weight_grad called where it does not apply");
    weight_grad_with(isa, x, grad, geo)
}

/// `weight_grad` with the kernels of `isa`, which the CPU must have.
///
/// Why: im2col + GEMM copies every input value nine times and packs it
/// again for a product only 16-64 rows tall. Here each task takes a band
/// of rows of one image, and for every (block of output channels, input
/// channel, tap row) multiplies the band's gradient rows by the three
/// shifted input rows in registers, adding lane-wise sums into its own
/// partial; the lanes and partials are summed at the end.
fn weight_grad_with(isa: Isa, x: &[f32], grad: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let [h, w] = geo.in_hw;
    let (o_n, c_n) = (geo.out_channels, geo.in_channels);
    assert_eq!(x.len(), geo.batch * c_n * h * w, "input length");
    assert_eq!(grad.len(), geo.batch * o_n * h * w, "gradient length");
    let frame = padded(x, geo);
    let (plane, row) = ((h + 2) * (w + 2), w + 2);
    let (lanes, block_o) = match isa {
        Isa::Avx512 => (16, 8),
        Isa::Avx2 => (8, 4),
    };
    let blocks = o_n.div_ceil(block_o);
    // Lane sums: [block][C][ky][channel of the block][kx][lanes].
    let per_tap_row = block_o * 3 * lanes;
    let sums_len = blocks * c_n * 3 * per_tap_row;
    // Bands of rows whose gradient for one block of channels stays in the
    // L1 cache (about 24 KB) while every input channel and tap row reads it.
    let band = (24 * 1024 / (block_o * w * 4)).clamp(1, h);
    let bands = h.div_ceil(band);
    let partials = (0..geo.batch * bands)
        .into_par_iter()
        .fold(
            || vec![0.0f32; sums_len],
            |mut sums, job| {
                let (n, y0) = (job / bands, job % bands * band);
                let rows = band.min(h - y0);
                for b in 0..blocks {
                    let first = b * block_o;
                    let mut grad_rows = [grad.as_ptr(); GRAD_BLOCK_MAX];
                    for (i, g) in grad_rows.iter_mut().enumerate().take(block_o) {
                        let o = if first + i < o_n { first + i } else { first };
                        *g = grad[((n * o_n + o) * h + y0) * w..].as_ptr();
                    }
                    for c in 0..c_n {
                        for ky in 0..3 {
                            let block = GradBlock {
                                input: frame[(n * c_n + c) * plane + (y0 + ky) * row..].as_ptr(),
                                row,
                                grad: grad_rows,
                                rows,
                                width: w,
                                sums: sums[((b * c_n + c) * 3 + ky) * per_tap_row..].as_mut_ptr(),
                            };
                            // SAFETY: the kernel reads `rows` rows of `w` + 2
                            // values from the padded frame at `input` (rows
                            // y0 + ky .. y0 + ky + rows <= h + 2), `rows` rows
                            // of `w` from each gradient pointer (inside channel
                            // o's plane), and adds into its `per_tap_row` sums;
                            // the CPU has the kernel's features (`isa`).
                            unsafe { run_grad_kernel(isa, &block) };
                        }
                    }
                }
                sums
            },
        )
        .reduce_with(|mut a, b| {
            a.iter_mut().zip(&b).for_each(|(a, b)| *a += b);
            a
        })
        .unwrap_or_else(|| vec![0.0; sums_len]);
    let mut out = vec![0.0f32; o_n * c_n * 9];
    for o in 0..o_n {
        let (b, i) = (o / block_o, o % block_o);
        for c in 0..c_n {
            for ky in 0..3 {
                for kx in 0..3 {
                    let at = ((b * c_n + c) * 3 + ky) * per_tap_row + (i * 3 + kx) * lanes;
                    out[(o * c_n + c) * 9 + ky * 3 + kx] = partials[at..at + lanes].iter().sum();
                }
            }
        }
    }
    out
}

unsafe fn run_grad_kernel(isa: Isa, block: &GradBlock) {
    #[cfg(target_arch = "x86_64")]
    unsafe {
        match isa {
            Isa::Avx512 => avx512::grad_kernel(block),
            Isa::Avx2 => avx2::grad_kernel(block),
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (isa, block);
        unreachable!("`applies` is false off x86-64");
    }
}

/// The vector operations the kernels use, for one instruction set: the
/// kernels below are written once against it and compiled for each set in
/// its own `#[target_feature]` function (`avx512`, `avx2`), where these
/// `#[inline(always)]` operations become single instructions.
#[cfg(target_arch = "x86_64")]
trait Lanes {
    /// f32 lanes per vector.
    const WIDTH: usize;
    type V: Copy;
    type Mask: Copy;
    /// The first `count` lanes (1 to `WIDTH`; more: all).
    unsafe fn mask(count: usize) -> Self::Mask;
    unsafe fn zero() -> Self::V;
    unsafe fn splat(x: f32) -> Self::V;
    unsafe fn load(p: *const f32) -> Self::V;
    /// Lanes outside the mask read as zero.
    unsafe fn load_masked(p: *const f32, mask: Self::Mask) -> Self::V;
    unsafe fn store(p: *mut f32, v: Self::V);
    unsafe fn store_masked(p: *mut f32, mask: Self::Mask, v: Self::V);
    /// a * b + c, rounded once.
    unsafe fn fmadd(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    unsafe fn add(a: Self::V, b: Self::V) -> Self::V;
    unsafe fn max(a: Self::V, b: Self::V) -> Self::V;
}

/// `NV` vectors of `L::WIDTH` columns by `BLOCK_O` output channels; the
/// last vector holds `tail` columns (1 to `L::WIDTH`).
///
/// Loads are whole vectors: lanes past the tail read the next row (or the
/// frame's slack) and are never stored. Masked loads would hold the mask in
/// a register, and AVX2's 16 are all taken (12 accumulators, 3 inputs, 1
/// weight): with it the kernel spilled and ran behind im2col + GEMM.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn kernel<L: Lanes, const NV: usize>(b: &Block, tail: usize) {
    unsafe {
        let mut acc = [[L::zero(); NV]; BLOCK_O];
        for c in 0..b.channels {
            let channel = b.input.add(c * b.plane);
            let weights = b.weight.add(c * 9 * BLOCK_O);
            for tap in 0..9 {
                let src = channel.add(tap / 3 * b.row + tap % 3);
                let mut v = [L::zero(); NV];
                for (j, v) in v.iter_mut().enumerate() {
                    *v = L::load(src.add(L::WIDTH * j));
                }
                for (i, acc) in acc.iter_mut().enumerate() {
                    let wv = L::splat(*weights.add(tap * BLOCK_O + i));
                    for (a, v) in acc.iter_mut().zip(&v) {
                        *a = L::fmadd(wv, *v, *a);
                    }
                }
            }
        }
        let mask = L::mask(tail);
        let zero = L::zero();
        for (i, acc) in acc.iter().enumerate().take(b.valid) {
            let bias = L::splat(b.bias[i]);
            for (j, a) in acc.iter().enumerate() {
                let mut r = L::add(*a, bias);
                if b.relu {
                    // max(0, r) returns r when r is NaN, so NaN stays NaN;
                    // adding +0 turns a -0 into +0, as Burn's ReLU.
                    r = L::add(L::max(zero, r), zero);
                }
                let dst = b.out[i].add(L::WIDTH * j);
                if j + 1 == NV {
                    L::store_masked(dst, mask, r);
                } else {
                    L::store(dst, r);
                }
            }
        }
    }
}

/// `BO` output channels by the three taps of one tap row, over the band's
/// rows, `L::WIDTH` columns at a time: whole vectors, then the row's last
/// columns masked (lanes past the row must read zero here, since every lane
/// is summed; and the mask stays out of the registers of the main loop).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn grad_kernel<L: Lanes, const BO: usize>(b: &GradBlock) {
    #[inline(always)]
    unsafe fn step<L: Lanes, const BO: usize>(
        acc: &mut [[L::V; 3]; BO],
        b: &GradBlock,
        y: usize,
        x: usize,
        mask: Option<L::Mask>,
    ) {
        unsafe {
            let load = |p: *const f32| match mask {
                Some(m) => L::load_masked(p, m),
                None => L::load(p),
            };
            let input = b.input.add(y * b.row + x);
            let v = [load(input), load(input.add(1)), load(input.add(2))];
            for (i, acc) in acc.iter_mut().enumerate() {
                let g = load(b.grad[i].add(y * b.width + x));
                for (a, v) in acc.iter_mut().zip(&v) {
                    *a = L::fmadd(g, *v, *a);
                }
            }
        }
    }
    unsafe {
        let mut acc = [[L::zero(); 3]; BO];
        let whole = b.width / L::WIDTH * L::WIDTH;
        let tail = (whole < b.width).then(|| L::mask(b.width - whole));
        for y in 0..b.rows {
            for x in (0..whole).step_by(L::WIDTH) {
                step::<L, BO>(&mut acc, b, y, x, None);
            }
            if tail.is_some() {
                step::<L, BO>(&mut acc, b, y, whole, tail);
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            for (kx, a) in acc.iter().enumerate() {
                let dst = b.sums.add((i * 3 + kx) * L::WIDTH);
                L::store(dst, L::add(L::load(dst), *a));
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use super::{Block, GradBlock, Lanes};

    pub struct Avx512;

    impl Lanes for Avx512 {
        const WIDTH: usize = 16;
        type V = __m512;
        type Mask = __mmask16;
        #[inline(always)]
        unsafe fn mask(count: usize) -> __mmask16 {
            if count >= 16 { 0xffff } else { (1u16 << count) - 1 }
        }
        #[inline(always)]
        unsafe fn zero() -> __m512 {
            unsafe { _mm512_setzero_ps() }
        }
        #[inline(always)]
        unsafe fn splat(x: f32) -> __m512 {
            unsafe { _mm512_set1_ps(x) }
        }
        #[inline(always)]
        unsafe fn load(p: *const f32) -> __m512 {
            unsafe { _mm512_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn load_masked(p: *const f32, mask: __mmask16) -> __m512 {
            unsafe { _mm512_maskz_loadu_ps(mask, p) }
        }
        #[inline(always)]
        unsafe fn store(p: *mut f32, v: __m512) {
            unsafe { _mm512_storeu_ps(p, v) }
        }
        #[inline(always)]
        unsafe fn store_masked(p: *mut f32, mask: __mmask16, v: __m512) {
            unsafe { _mm512_mask_storeu_ps(p, mask, v) }
        }
        #[inline(always)]
        unsafe fn fmadd(a: __m512, b: __m512, c: __m512) -> __m512 {
            unsafe { _mm512_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        unsafe fn add(a: __m512, b: __m512) -> __m512 {
            unsafe { _mm512_add_ps(a, b) }
        }
        #[inline(always)]
        unsafe fn max(a: __m512, b: __m512) -> __m512 {
            unsafe { _mm512_max_ps(a, b) }
        }
    }

    #[target_feature(enable = "avx512f")]
    pub unsafe fn kernel<const NV: usize>(b: &Block, tail: usize) {
        unsafe { super::kernel::<Avx512, NV>(b, tail) }
    }

    /// Eight output channels a block: 24 accumulators of 32 registers.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn grad_kernel(b: &GradBlock) {
        unsafe { super::grad_kernel::<Avx512, 8>(b) }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Block, GradBlock, Lanes};

    pub struct Avx2;

    impl Lanes for Avx2 {
        const WIDTH: usize = 8;
        type V = __m256;
        type Mask = __m256i;
        #[inline(always)]
        unsafe fn mask(count: usize) -> __m256i {
            unsafe {
                let left = count.min(8) as i32;
                _mm256_cmpgt_epi32(_mm256_set1_epi32(left), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7))
            }
        }
        #[inline(always)]
        unsafe fn zero() -> __m256 {
            unsafe { _mm256_setzero_ps() }
        }
        #[inline(always)]
        unsafe fn splat(x: f32) -> __m256 {
            unsafe { _mm256_set1_ps(x) }
        }
        #[inline(always)]
        unsafe fn load(p: *const f32) -> __m256 {
            unsafe { _mm256_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn load_masked(p: *const f32, mask: __m256i) -> __m256 {
            unsafe { _mm256_maskload_ps(p, mask) }
        }
        #[inline(always)]
        unsafe fn store(p: *mut f32, v: __m256) {
            unsafe { _mm256_storeu_ps(p, v) }
        }
        #[inline(always)]
        unsafe fn store_masked(p: *mut f32, mask: __m256i, v: __m256) {
            unsafe { _mm256_maskstore_ps(p, mask, v) }
        }
        #[inline(always)]
        unsafe fn fmadd(a: __m256, b: __m256, c: __m256) -> __m256 {
            unsafe { _mm256_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        unsafe fn add(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_add_ps(a, b) }
        }
        #[inline(always)]
        unsafe fn max(a: __m256, b: __m256) -> __m256 {
            unsafe { _mm256_max_ps(a, b) }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn kernel<const NV: usize>(b: &Block, tail: usize) {
        unsafe { super::kernel::<Avx2, NV>(b, tail) }
    }

    /// Four output channels a block: 12 accumulators of 16 registers.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn grad_kernel(b: &GradBlock) {
        unsafe { super::grad_kernel::<Avx2, 4>(b) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::conv_kernels::{forward_im2col, weight_grad_im2col};

    fn values(len: usize, seed: u64) -> Vec<f32> {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(seed);
        (0..len).map(|_| rng.random_range(-1.0..1.0)).collect()
    }

    /// The kernel sets this CPU has, widest first.
    fn isas() -> Vec<Isa> {
        let mut found = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                found.push(Isa::Avx512);
            }
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                found.push(Isa::Avx2);
            }
        }
        found
    }

    #[test]
    fn every_kernel_matches_im2col_on_widths_with_and_without_tails() {
        // Widths: one column, less than a vector, exact vectors, several
        // blocks with a tail; output channels not a multiple of the block.
        let shapes = [[2, 3, 5, 1, 5], [1, 16, 4, 7, 18], [2, 2, 3, 16, 4], [1, 5, 6, 33, 1], [1, 4, 2, 100, 32]];
        for (s, &[n, c, h, w, o]) in shapes.iter().enumerate() {
            let geo = ConvGeometry::new([n, c, h, w], [o, c, 3, 3], [1, 1], [(1, 1), (1, 1)], [1, 1], 1).unwrap();
            assert!(applies(&geo) || isas().is_empty());
            let seed = 10 * s as u64;
            let (mut x, weight, bias) = (values(n * c * h * w, seed), values(o * c * 9, seed + 1), values(o, seed + 2));
            x[0] = f32::NAN;
            for relu in [false, true] {
                let reference = forward_im2col(&x, &weight, Some(&bias), &geo, relu);
                for isa in isas() {
                    let ours = forward_with(isa, &x, &weight, Some(&bias), &geo, relu);
                    assert_eq!(ours.len(), reference.len());
                    for (i, (a, b)) in ours.iter().zip(&reference).enumerate() {
                        let same = if b.is_nan() { a.is_nan() } else { (a - b).abs() <= 1e-5 * (1.0 + b.abs()) };
                        assert!(same, "{isa:?} shape {s} relu {relu} element {i}: {a} vs {b}");
                        assert!(!relu || a.is_nan() || a.is_sign_positive(), "{isa:?}: ReLU gave {a}");
                    }
                }
            }
        }
    }

    #[test]
    fn every_weight_gradient_kernel_matches_im2col() {
        // Widths with and without a vector tail, bands that do not divide
        // the height, output channels not a multiple of either block.
        let shapes = [[2, 3, 5, 1, 5], [1, 16, 4, 7, 18], [2, 2, 3, 16, 4], [1, 5, 40, 33, 9], [3, 4, 7, 100, 64]];
        for (s, &[n, c, h, w, o]) in shapes.iter().enumerate() {
            let geo = ConvGeometry::new([n, c, h, w], [o, c, 3, 3], [1, 1], [(1, 1), (1, 1)], [1, 1], 1).unwrap();
            let seed = 10 * s as u64 + 5;
            let (x, grad) = (values(n * c * h * w, seed), values(n * o * h * w, seed + 1));
            let reference = weight_grad_im2col(&x, &grad, &geo);
            for isa in isas() {
                let ours = weight_grad_with(isa, &x, &grad, &geo);
                assert_eq!(ours.len(), reference.len());
                for (i, (a, b)) in ours.iter().zip(&reference).enumerate() {
                    assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()), "{isa:?} shape {s} element {i}: {a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn only_small_3x3_same_convolutions_take_it() {
        let geo = |o, k, stride, pad, groups| {
            ConvGeometry::new([1, 4, 9, 9], [o, 4 / groups, k, k], [stride; 2], [(pad, pad); 2], [1, 1], groups)
                .unwrap()
        };
        assert_eq!(applies(&geo(8, 3, 1, 1, 1)), !isas().is_empty());
        assert!(!applies(&geo(MAX_OUT_CHANNELS + 1, 3, 1, 1, 1)));
        assert!(!applies(&geo(8, 3, 2, 1, 1)));
        assert!(!applies(&geo(8, 3, 1, 0, 1)));
        assert!(!applies(&geo(8, 5, 1, 1, 1)));
        assert!(!applies(&geo(8, 3, 1, 1, 2)));
    }
}
