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

use crate::conv_kernels::ConvGeometry;

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

fn isa() -> Option<Isa> {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
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

/// The input [N, C, H, W] in a frame one zero wide: [N, C, H + 2, W + 2].
fn padded(x: &[f32], geo: &ConvGeometry) -> Vec<f32> {
    let [h, w] = geo.in_hw;
    let (ph, pw) = (h + 2, w + 2);
    let len = geo.batch * geo.in_channels * ph * pw;
    // Every value is written below (the border once, the interior once), so
    // the frame is not zeroed first: that memset cost as much as the copy.
    let mut out: Vec<f32> = Vec::with_capacity(len);
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
                // SAFETY: the kernel reads `columns` + 2 values from each of
                // three rows of every channel of the padded frame starting at
                // `input` (inside the frame: x0 + columns <= w), 9 x C x
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

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use super::{BLOCK_O, Block};

    /// `NV` vectors of 16 columns by `BLOCK_O` output channels; the last
    /// vector holds `tail` columns (1-16).
    #[target_feature(enable = "avx512f")]
    pub unsafe fn kernel<const NV: usize>(b: &Block, tail: usize) {
        let mask: __mmask16 = if tail >= 16 { 0xffff } else { (1u16 << tail) - 1 };
        let mut acc = [[_mm512_setzero_ps(); NV]; BLOCK_O];
        unsafe {
            for c in 0..b.channels {
                let channel = b.input.add(c * b.plane);
                let weights = b.weight.add(c * 9 * BLOCK_O);
                for tap in 0..9 {
                    let src = channel.add(tap / 3 * b.row + tap % 3);
                    let mut v = [_mm512_setzero_ps(); NV];
                    for (j, v) in v.iter_mut().enumerate() {
                        *v = if j + 1 == NV {
                            _mm512_maskz_loadu_ps(mask, src.add(16 * j))
                        } else {
                            _mm512_loadu_ps(src.add(16 * j))
                        };
                    }
                    for (i, acc) in acc.iter_mut().enumerate() {
                        let wv = _mm512_set1_ps(*weights.add(tap * BLOCK_O + i));
                        for (a, v) in acc.iter_mut().zip(&v) {
                            *a = _mm512_fmadd_ps(wv, *v, *a);
                        }
                    }
                }
            }
            let zero = _mm512_setzero_ps();
            for (i, acc) in acc.iter().enumerate().take(b.valid) {
                let bias = _mm512_set1_ps(b.bias[i]);
                for (j, a) in acc.iter().enumerate() {
                    let mut r = _mm512_add_ps(*a, bias);
                    if b.relu {
                        // max(0, r) returns r when r is NaN, so NaN stays
                        // NaN; adding +0 turns a -0 into +0, as Burn's ReLU.
                        r = _mm512_add_ps(_mm512_max_ps(zero, r), zero);
                    }
                    let dst = b.out[i].add(16 * j);
                    if j + 1 == NV {
                        _mm512_mask_storeu_ps(dst, mask, r);
                    } else {
                        _mm512_storeu_ps(dst, r);
                    }
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{BLOCK_O, Block};

    /// `NV` vectors of 8 columns by `BLOCK_O` output channels; the last
    /// vector holds `tail` columns (1-8).
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn kernel<const NV: usize>(b: &Block, tail: usize) {
        let lane_on = |lane: usize| if lane < tail { -1i32 } else { 0 };
        let mask = _mm256_setr_epi32(
            lane_on(0),
            lane_on(1),
            lane_on(2),
            lane_on(3),
            lane_on(4),
            lane_on(5),
            lane_on(6),
            lane_on(7),
        );
        let mut acc = [[_mm256_setzero_ps(); NV]; BLOCK_O];
        unsafe {
            for c in 0..b.channels {
                let channel = b.input.add(c * b.plane);
                let weights = b.weight.add(c * 9 * BLOCK_O);
                for tap in 0..9 {
                    let src = channel.add(tap / 3 * b.row + tap % 3);
                    let mut v = [_mm256_setzero_ps(); NV];
                    for (j, v) in v.iter_mut().enumerate() {
                        *v = if j + 1 == NV {
                            _mm256_maskload_ps(src.add(8 * j), mask)
                        } else {
                            _mm256_loadu_ps(src.add(8 * j))
                        };
                    }
                    for (i, acc) in acc.iter_mut().enumerate() {
                        let wv = _mm256_broadcast_ss(&*weights.add(tap * BLOCK_O + i));
                        for (a, v) in acc.iter_mut().zip(&v) {
                            *a = _mm256_fmadd_ps(wv, *v, *a);
                        }
                    }
                }
            }
            let zero = _mm256_setzero_ps();
            for (i, acc) in acc.iter().enumerate().take(b.valid) {
                let bias = _mm256_set1_ps(b.bias[i]);
                for (j, a) in acc.iter().enumerate() {
                    let mut r = _mm256_add_ps(*a, bias);
                    if b.relu {
                        r = _mm256_add_ps(_mm256_max_ps(zero, r), zero);
                    }
                    let dst = b.out[i].add(8 * j);
                    if j + 1 == NV {
                        _mm256_maskstore_ps(dst, mask, r);
                    } else {
                        _mm256_storeu_ps(dst, r);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conv_kernels::forward_im2col;

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
