//! Pure-Rust forward pass of a tanh MLP from flat `f32` weights ([`MlpLayout`]).
//!
//! Actors never link libtorch: the policy is small, and a plain loop over the weights
//! has no per-call overhead. The learner's tests hold this forward equal to the tch one
//! within 1e-5. It lives here, beside [`MlpLayout`], because both the actors (imitation
//! policy) and `envs` (trained expert policies that generate demonstrations) evaluate
//! such weights.
//!
//! # Why it is laid out the way it is
//!
//! The forward runs once per env step, inside the actor's loop, where a Reacher physics
//! step costs ~6 us: a 64-64 forward must cost well under a microsecond. The wire
//! layout ([`MlpLayout`], `torch.nn.Linear`'s row-major `[out][in]`) makes every output
//! a dot product over a contiguous row, which compiles to a scalar loop (each
//! accumulator is one serial chain of adds), and libm's `tanhf` is an opaque call per
//! hidden unit. Together they cost ~3.5 us per step (`bench/mujoco.md`).
//!
//! So [`Mlp::new`] keeps the wire parameters (for [`Mlp::params`]) and also packs each
//! layer once into blocks of [`BLOCK`] output neurons: block `b` holds, for each input
//! `i` in order, the `BLOCK` weights `W[b * BLOCK + k][i]` side by side (outputs past
//! `n_out` padded with zeros), then the layer's bias padded to a multiple of `BLOCK`.
//! The inner loop then updates `BLOCK` independent accumulators with one broadcast
//! input, `acc[k] += w[i][k] * x[i]`, which the compiler turns into vector
//! multiply-adds held in registers; [`tanh`] is branch-free `f32` arithmetic that
//! vectorises too.
//!
//! # Same numbers on every x86_64
//!
//! On x86_64 CPUs with AVX2 the forward runs a copy of the same code compiled for AVX2
//! (chosen at run time with `is_x86_feature_detected!`, so the binary still runs on any
//! x86_64); elsewhere the portable path (SSE2 on x86_64). Vector lanes are independent
//! and every output still sums `bias + w_0 x_0 + w_1 x_1 + ...` in input order, with
//! separate multiplies and adds (no FMA, whose single rounding would differ), so both
//! paths, and the old scalar loop up to [`tanh`] vs libm, give bit-identical results.

use crate::weights::{MlpLayout, WeightsError};

/// Output neurons per packed block: 16 `f32` accumulators are two AVX (four SSE)
/// registers. In a prototype on the dev box, 32 was ~10% faster with AVX2 but ~5x
/// slower on SSE2 (it did not stay in registers), and 8 was ~2x slower with AVX2 (one
/// serial add chain per block).
pub const BLOCK: usize = 16;

/// A tanh MLP with its flat parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    layout: MlpLayout,
    /// Wire layout, as given.
    params: Vec<f32>,
    /// Per layer: `n_blocks` blocks of `n_in * BLOCK` weights, then `n_blocks * BLOCK`
    /// biases (see the module docs).
    packed: Vec<f32>,
}

/// `n` rounded up to a multiple of [`BLOCK`].
fn padded(n: usize) -> usize {
    n.div_ceil(BLOCK) * BLOCK
}

impl Mlp {
    /// Wraps `params`, checked against `layout`, and packs them for the forward pass.
    pub fn new(layout: MlpLayout, params: Vec<f32>) -> Result<Self, WeightsError> {
        layout.check(&params)?;
        let mut packed = Vec::new();
        for l in 0..layout.n_layers() {
            let (n_in, n_out) = (layout.sizes[l], layout.sizes[l + 1]);
            let (wo, bo) = layout.offsets(l);
            let w = &params[wo..bo];
            let b = &params[bo..bo + n_out];
            let n_pad = padded(n_out);
            packed.reserve(n_pad * (n_in + 1));
            for block in 0..n_pad / BLOCK {
                for i in 0..n_in {
                    for k in 0..BLOCK {
                        let o = block * BLOCK + k;
                        packed.push(if o < n_out { w[o * n_in + i] } else { 0.0 });
                    }
                }
            }
            packed.extend((0..n_pad).map(|o| b.get(o).copied().unwrap_or(0.0)));
        }
        Ok(Self {
            layout,
            params,
            packed,
        })
    }

    /// The layout.
    pub fn layout(&self) -> &MlpLayout {
        &self.layout
    }

    /// The flat parameters, in the wire layout they were given in.
    pub fn params(&self) -> &[f32] {
        &self.params
    }

    /// Scratch floats [`Mlp::forward`] needs.
    pub fn scratch_len(&self) -> usize {
        2 * self
            .layout
            .sizes
            .iter()
            .map(|&n| padded(n))
            .max()
            .unwrap_or(0)
    }

    /// Computes the output for one input row. `input.len()` must be the layout's input
    /// width, `out.len()` its output width, `scratch.len() >= scratch_len()`.
    pub fn forward(&self, input: &[f32], out: &mut [f32], scratch: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the running CPU supports AVX2, checked just above.
            unsafe { forward_avx2(&self.layout, &self.packed, input, out, scratch) };
            return;
        }
        forward_packed(&self.layout, &self.packed, input, out, scratch);
    }
}

/// [`forward_packed`] compiled for AVX2 (no FMA: see the module docs).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn forward_avx2(
    layout: &MlpLayout,
    packed: &[f32],
    input: &[f32],
    out: &mut [f32],
    scratch: &mut [f32],
) {
    forward_packed(layout, packed, input, out, scratch);
}

/// The forward pass over the packed weights; inlined into each instruction-set variant.
#[inline(always)]
fn forward_packed(
    layout: &MlpLayout,
    packed: &[f32],
    input: &[f32],
    out: &mut [f32],
    scratch: &mut [f32],
) {
    let sizes = &layout.sizes;
    let (a, b) = scratch.split_at_mut(scratch.len() / 2);
    a[..input.len()].copy_from_slice(input);
    let (mut cur, mut nxt) = (a, b);
    let n = sizes.len() - 1;
    let mut off = 0;
    for l in 0..n {
        let (n_in, n_pad) = (sizes[l], padded(sizes[l + 1]));
        let weights = &packed[off..off + n_in * n_pad];
        let bias = &packed[off + n_in * n_pad..off + (n_in + 1) * n_pad];
        off += (n_in + 1) * n_pad;
        let x = &cur[..n_in];
        let blocks = weights
            .chunks_exact(n_in * BLOCK)
            .zip(bias.chunks_exact(BLOCK));
        for ((w_block, b_block), y) in blocks.zip(nxt.chunks_exact_mut(BLOCK)) {
            let mut acc = [0.0f32; BLOCK];
            acc.copy_from_slice(b_block);
            for (w_row, &xi) in w_block.chunks_exact(BLOCK).zip(x) {
                for (a, w) in acc.iter_mut().zip(w_row) {
                    *a += w * xi;
                }
            }
            if l + 1 < n {
                for a in &mut acc {
                    *a = tanh(*a);
                }
            }
            y.copy_from_slice(&acc);
        }
        std::mem::swap(&mut cur, &mut nxt);
    }
    out.copy_from_slice(&cur[..sizes[n]]);
}

/// `1.5 * 2^23`: adding it rounds an `f32` of magnitude < 2^22 to the nearest integer,
/// which then sits in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// `tanh` in branch-free `f32` arithmetic, so that a loop over it vectorises.
///
/// Within 2.3 ulp of the exact value for every finite `f32` (checked exhaustively for
/// `|x| < 20` against `f64::tanh` while it was written; the unit test re-checks a dense
/// grid), as close as glibc's `tanhf` (2.2 ulp). `tanh(±0) = ±0`, `tanh(±inf) = ±1`,
/// `|x| >= 10` gives exactly `±1`, NaN gives NaN.
///
/// - `|x| < 0.5`: `x + x^3 P(x^2)`, `P` a degree-4 near-minimax fit (Chebyshev, mpmath)
///   of `(tanh(x) - x) / x^3`; its relative error is < 2e-9.
/// - else: `(1 - e) / (1 + e)` with `e = exp(-2|x|)`, `exp` by `2^n * exp(r)`,
///   `|r| <= ln2 / 2`, `exp(r) = 1 + r + r^2 Q(r)` with `Q` a degree-4 fit (error
///   < 1e-8 relative); `|x|` is clamped to 10, where `tanh` is 1 in `f32`.
///
/// The result takes the sign of `x`.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    let a = x.abs();
    // Small |x|: odd polynomial.
    let s = a * a;
    let mut p = -0.006_942_942_f32;
    p = p * s + 0.021_470_683;
    p = p * s + -0.053_933_468;
    p = p * s + 0.133_332_25;
    p = p * s + -0.333_333_3;
    let small = a + a * s * p;
    // Large |x|: (1 - e) / (1 + e), e = exp(-2|x|). NaN fails `a > 10` and stays NaN.
    let y = -2.0 * if a > 10.0 { 10.0 } else { a };
    let t = y * std::f32::consts::LOG2_E + ROUND_MAGIC;
    let n = t.to_bits() as i32 - ROUND_MAGIC.to_bits() as i32;
    let nf = t - ROUND_MAGIC;
    // r = y - n ln2, with ln2 split in a short high part (n * LN2_HI is exact) and a low one.
    let r = (y - nf * 0.693_145_75) - nf * 1.428_606_8e-6;
    let mut q = 0.001_392_617_6_f32;
    q = q * r + 0.008_363_173;
    q = q * r + 0.041_666_556;
    q = q * r + 0.166_665_78;
    q = q * r + 0.5;
    let exp_r = 1.0 + r + r * r * q;
    // 2^n as bits: n is in [-29, 0] here, far from under- or overflow.
    let e = exp_r * f32::from_bits(((n + 127) as u32) << 23);
    let large = (1.0 - e) / (1.0 + e);
    let v = if a < 0.5 { small } else { large };
    v.copysign(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pre-packing forward: one dot product per output over the wire layout, libm tanh.
    fn reference_forward(mlp: &Mlp, input: &[f32]) -> Vec<f32> {
        let sizes = &mlp.layout().sizes;
        let mut x = input.to_vec();
        for l in 0..mlp.layout().n_layers() {
            let (n_in, n_out) = (sizes[l], sizes[l + 1]);
            let (wo, bo) = mlp.layout().offsets(l);
            let p = mlp.params();
            x = (0..n_out)
                .map(|o| {
                    let mut acc = p[bo + o];
                    for i in 0..n_in {
                        acc += p[wo + o * n_in + i] * x[i];
                    }
                    if l + 1 < mlp.layout().n_layers() {
                        acc.tanh()
                    } else {
                        acc
                    }
                })
                .collect();
        }
        x
    }

    /// Distance in units in the last place of `want` (rounded to `f32`).
    fn ulps(got: f32, want: f64) -> f64 {
        let w = (want as f32).abs();
        let ulp = f64::from(f32::from_bits(w.to_bits() + 1) - w);
        (f64::from(got) - want).abs() / ulp
    }

    #[test]
    fn forward_matches_a_hand_computed_two_layer_net() {
        // in 2 -> hidden 2 (tanh) -> out 1
        let layout = MlpLayout::new(2, &[2], 1).unwrap();
        #[rustfmt::skip]
        let params = vec![
            0.5, -1.0,   // W0 row 0
            2.0, 0.25,   // W0 row 1
            0.1, -0.2,   // b0
            1.5, -0.5,   // W1
            0.3,         // b1
        ];
        let mlp = Mlp::new(layout, params).unwrap();
        let x = [0.2f32, -0.4];
        let h0 = (0.5f32 * 0.2 + -1.0 * -0.4 + 0.1).tanh();
        let h1 = (2.0f32 * 0.2 + 0.25 * -0.4 - 0.2).tanh();
        let y = 1.5 * h0 - 0.5 * h1 + 0.3;
        let mut out = [0.0f32];
        let mut scratch = vec![0.0; mlp.scratch_len()];
        mlp.forward(&x, &mut out, &mut scratch);
        assert!((out[0] - y).abs() < 1e-6, "{} vs {y}", out[0]);
    }

    #[test]
    fn packed_forward_matches_the_row_major_libm_forward_for_odd_widths() {
        // Widths that are not multiples of BLOCK, and wider than it, exercise the padding.
        for sizes in [
            vec![19, 64, 64, 2],
            vec![3, 17, 5, 33],
            vec![1, 1],
            vec![45, 64, 64, 17],
        ] {
            let layout = MlpLayout { sizes };
            let mut state = 0x2545_f491_u32;
            let params: Vec<f32> = (0..layout.n_params())
                .map(|_| {
                    state ^= state << 13;
                    state ^= state >> 17;
                    state ^= state << 5;
                    (state as f32 / u32::MAX as f32 - 0.5) * 0.8
                })
                .collect();
            let mlp = Mlp::new(layout.clone(), params).unwrap();
            let mut scratch = vec![0.0; mlp.scratch_len()];
            let mut out = vec![0.0; layout.output()];
            for r in 0..20 {
                let x: Vec<f32> = (0..layout.input())
                    .map(|i| ((i * 7 + r * 13) % 23) as f32 / 5.0 - 2.2)
                    .collect();
                mlp.forward(&x, &mut out, &mut scratch);
                let want = reference_forward(&mlp, &x);
                for (o, w) in out.iter().zip(&want) {
                    assert!((o - w).abs() < 1e-5, "{:?}: {o} vs {w}", layout.sizes);
                }
            }
        }
    }

    #[test]
    fn dispatched_forward_is_bit_identical_to_the_portable_path() {
        // On an AVX2 machine `forward` takes the AVX2 copy; called directly,
        // `forward_packed` is compiled for the baseline target.
        let layout = MlpLayout {
            sizes: vec![23, 64, 64, 6],
        };
        let params: Vec<f32> = (0..layout.n_params())
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * 0.004)
            .collect();
        let mlp = Mlp::new(layout.clone(), params).unwrap();
        let mut scratch = vec![0.0; mlp.scratch_len()];
        let (mut a, mut b) = (vec![0.0; 6], vec![0.0; 6]);
        for r in 0..50 {
            let x: Vec<f32> = (0..23).map(|i| ((i + r) % 9) as f32 * 0.7 - 2.8).collect();
            mlp.forward(&x, &mut a, &mut scratch);
            forward_packed(&layout, &mlp.packed, &x, &mut b, &mut scratch);
            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a), bits(&b));
        }
    }

    #[test]
    fn tanh_is_within_a_few_ulp_of_the_exact_value_over_a_dense_grid() {
        // Every 61st f32 from the smallest subnormal up to 20 (|x| >= 10 is exactly ±1),
        // both signs: ~18M points.
        let mut worst = (0.0f64, 0.0f32);
        let mut bits = 1u32;
        while f32::from_bits(bits) < 20.0 {
            let x = f32::from_bits(bits);
            for x in [x, -x] {
                let u = ulps(tanh(x), f64::from(x).tanh());
                if u > worst.0 {
                    worst = (u, x);
                }
            }
            bits += 61;
        }
        assert!(worst.0 <= 2.5, "{} ulp at x = {}", worst.0, worst.1);
    }

    #[test]
    fn tanh_handles_zeros_infinities_huge_values_and_nan() {
        assert_eq!(tanh(0.0).to_bits(), 0.0f32.to_bits());
        assert_eq!(tanh(-0.0).to_bits(), (-0.0f32).to_bits());
        assert_eq!(tanh(f32::INFINITY), 1.0);
        assert_eq!(tanh(f32::NEG_INFINITY), -1.0);
        for x in [10.0f32, 88.0, 1e30, f32::MAX] {
            assert_eq!(tanh(x), 1.0);
            assert_eq!(tanh(-x), -1.0);
        }
        assert_eq!(tanh(1e-30), 1e-30);
        assert_eq!(tanh(f32::MIN_POSITIVE), f32::MIN_POSITIVE);
        assert!(tanh(f32::NAN).is_nan());
        assert!(tanh(-f32::NAN).is_nan());
    }

    #[test]
    fn tanh_agrees_with_libm_within_a_few_ulp() {
        let mut worst = 0.0f64;
        for i in -200_000..=200_000 {
            let x = i as f32 * 6e-5;
            worst = worst.max(f64::from((tanh(x) - x.tanh()).abs()) / f64::from(f32::EPSILON));
        }
        // In units of 2^-23 (one ulp at 1, two at 0.5..1): a few ulp apart at most.
        assert!(worst <= 4.0, "{worst}");
    }
}
