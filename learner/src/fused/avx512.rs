//! The elementwise passes of [`super::math`] in AVX-512, sixteen lanes at a time: the
//! compiler did not vectorise the scalar loops (bench/learner.md: the tanh backward
//! pass ran one element per instruction). Each function computes its scalar twin in
//! `math.rs` with the same polynomials, its multiply-adds fused (a scalar `mul_add`
//! outside AVX-512 code would be a libm call), so the two agree to about one unit in
//! the last place; the tests hold them to 2e-7 relative.
//!
//! Every function here requires AVX-512F; `math.rs` calls them only after
//! [`available`] said so.

#![allow(unsafe_op_in_unsafe_fn)]

use std::arch::x86_64::*;

/// `log2(e)`: `exp` here and in `math.rs` computes `2^(x log2 e)`.
pub(super) const LOG2E: f32 = std::f32::consts::LOG2_E;

/// `1.5 * 2^23`: adding it to a float below 2^22 in magnitude rounds that float to an
/// integer held in the low mantissa bits (no float-to-int conversion, which has no
/// saturating vector form). Shared with `math.rs`'s scalar twin.
pub(super) const ROUND: f32 = 12_582_912.0;

/// Whether this CPU runs these kernels (checked once).
pub fn available() -> bool {
    static YES: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *YES.get_or_init(|| std::arch::is_x86_feature_detected!("avx512f"))
}

const LANES: usize = 16;

#[inline(always)]
unsafe fn set(x: f32) -> __m512 {
    _mm512_set1_ps(x)
}

/// [`super::math::exp`] on sixteen lanes.
#[inline(always)]
unsafe fn exp(x: __m512) -> __m512 {
    let x = _mm512_min_ps(_mm512_max_ps(x, set(-87.3)), set(88.3));
    let t = _mm512_add_ps(_mm512_mul_ps(x, set(LOG2E)), set(ROUND));
    let n = _mm512_sub_ps(t, set(ROUND));
    let r = _mm512_sub_ps(
        _mm512_sub_ps(x, _mm512_mul_ps(n, set(0.693_359_4))),
        _mm512_mul_ps(n, set(-2.121_944_4e-4)),
    );
    let z = _mm512_mul_ps(r, r);
    let mut p = _mm512_add_ps(_mm512_mul_ps(set(1.987_569_1e-4), r), set(1.398_2e-3));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), set(8.333_452e-3));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), set(4.166_579_6e-2));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), set(1.666_666_5e-1));
    p = _mm512_add_ps(_mm512_mul_ps(p, r), set(5.0e-1));
    let y = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(p, z), r), set(1.0));
    let bits = _mm512_sub_epi32(
        _mm512_castps_si512(t),
        _mm512_set1_epi32(ROUND.to_bits() as i32),
    );
    let pow2 = _mm512_slli_epi32::<23>(_mm512_add_epi32(bits, _mm512_set1_epi32(127)));
    _mm512_mul_ps(y, _mm512_castsi512_ps(pow2))
}

/// [`super::math::tanh`] on sixteen lanes.
#[inline(always)]
unsafe fn tanh(x: __m512) -> __m512 {
    let sign = _mm512_set1_epi32(i32::MIN);
    let xi = _mm512_castps_si512(x);
    let a = _mm512_castsi512_ps(_mm512_andnot_si512(sign, xi));
    let z = _mm512_mul_ps(x, x);
    let mut p = _mm512_fmadd_ps(set(-5.704_988e-3), z, set(2.063_909e-2));
    p = _mm512_fmsub_ps(p, z, set(5.373_971_6e-2));
    p = _mm512_fmadd_ps(p, z, set(1.333_144_2e-1));
    p = _mm512_fmsub_ps(p, z, set(3.333_328e-1));
    let poly = _mm512_fmadd_ps(_mm512_mul_ps(p, z), x, x);
    let e = exp(_mm512_mul_ps(set(2.0), a));
    let t = _mm512_sub_ps(
        set(1.0),
        _mm512_div_ps(set(2.0), _mm512_add_ps(e, set(1.0))),
    );
    let big = _mm512_castsi512_ps(_mm512_or_si512(
        _mm512_andnot_si512(sign, _mm512_castps_si512(t)),
        _mm512_and_si512(sign, xi),
    ));
    let small = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(a, set(0.625));
    _mm512_mask_blend_ps(small, big, poly)
}

/// `x[i] = tanh(x[i] + bias)` on the whole vectors of `x`; returns how many elements
/// it did.
/// # Safety
/// The CPU must have AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
pub unsafe fn tanh_bias_inplace(x: &mut [f32], bias: f32) -> usize {
    let n = x.len() / LANES * LANES;
    let b = set(bias);
    let p = x.as_mut_ptr();
    for i in (0..n).step_by(LANES) {
        let v = _mm512_loadu_ps(p.add(i));
        _mm512_storeu_ps(p.add(i), tanh(_mm512_add_ps(v, b)));
    }
    n
}

/// `dz[i] *= 1 - h[i]^2` on the whole vectors of `dz`; returns how many elements it
/// did and their sum, as sixteen lane sums.
/// # Safety
/// The CPU must have AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
pub unsafe fn tanh_backward(dz: &mut [f32], h: &[f32]) -> (usize, [f32; LANES]) {
    let n = dz.len().min(h.len()) / LANES * LANES;
    let (d, hp) = (dz.as_mut_ptr(), h.as_ptr());
    let mut acc = _mm512_setzero_ps();
    for i in (0..n).step_by(LANES) {
        let hv = _mm512_loadu_ps(hp.add(i));
        let g = _mm512_fnmadd_ps(hv, hv, set(1.0));
        let v = _mm512_mul_ps(_mm512_loadu_ps(d.add(i)), g);
        _mm512_storeu_ps(d.add(i), v);
        acc = _mm512_add_ps(acc, v);
    }
    let mut lanes = [0.0f32; LANES];
    _mm512_storeu_ps(lanes.as_mut_ptr(), acc);
    (n, lanes)
}

/// The sum of the whole vectors of `x`, as sixteen lane sums, and how many elements.
/// # Safety
/// The CPU must have AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
pub unsafe fn sum(x: &[f32]) -> (usize, [f32; LANES]) {
    let n = x.len() / LANES * LANES;
    let mut acc = _mm512_setzero_ps();
    for i in (0..n).step_by(LANES) {
        acc = _mm512_add_ps(acc, _mm512_loadu_ps(x.as_ptr().add(i)));
    }
    let mut lanes = [0.0f32; LANES];
    _mm512_storeu_ps(lanes.as_mut_ptr(), acc);
    (n, lanes)
}

/// `x[i] = e^(x[i] + shift)` on the whole vectors of `x`; returns how many elements.
/// # Safety
/// The CPU must have AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
pub unsafe fn exp_inplace(x: &mut [f32], shift: f32) -> usize {
    let n = x.len() / LANES * LANES;
    let p = x.as_mut_ptr();
    for i in (0..n).step_by(LANES) {
        _mm512_storeu_ps(
            p.add(i),
            exp(_mm512_add_ps(_mm512_loadu_ps(p.add(i)), set(shift))),
        );
    }
    n
}

/// `C[m][n] = A B` (or `+=` with `add`) for the weight gradients of narrow layers: `A`'s
/// rows (`a[i * lda..][..k]`) and `B`'s columns (`b[j * ldb..][..k]`) contiguous, `k`
/// (the batch) long and `m` or `n` small, where a blocked product's tiles are mostly
/// empty. Every output is a dot product of two contiguous runs, four by four at a time
/// (sixteen accumulators).
///
/// # Safety
/// The CPU must have AVX-512F; `a` must hold `m` rows of `k` at stride `lda`, `b` `n`
/// columns of `k` at stride `ldb`, `c` `m` rows of `n` at stride `ldc`.
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
pub unsafe fn dot_gemm(
    m: usize,
    n: usize,
    k: usize,
    a: &[f32],
    lda: usize,
    b: &[f32],
    ldb: usize,
    c: &mut [f32],
    ldc: usize,
    add: bool,
) {
    let kv = k / LANES * LANES;
    let mut i0 = 0;
    while i0 < m {
        let mi = (m - i0).min(4);
        let mut j0 = 0;
        while j0 < n {
            let nj = (n - j0).min(4);
            let mut acc = [[_mm512_setzero_ps(); 4]; 4];
            let mut p = 0;
            while p < kv {
                let mut bv = [_mm512_setzero_ps(); 4];
                for (j, v) in bv.iter_mut().enumerate().take(nj) {
                    *v = _mm512_loadu_ps(b.as_ptr().add((j0 + j) * ldb + p));
                }
                for (i, row) in acc.iter_mut().enumerate().take(mi) {
                    let av = _mm512_loadu_ps(a.as_ptr().add((i0 + i) * lda + p));
                    for (s, &b) in row.iter_mut().zip(&bv).take(nj) {
                        *s = _mm512_fmadd_ps(av, b, *s);
                    }
                }
                p += LANES;
            }
            for i in 0..mi {
                for j in 0..nj {
                    let (ar, br) = (&a[(i0 + i) * lda..], &b[(j0 + j) * ldb..]);
                    let tail: f32 = (kv..k).map(|q| ar[q] * br[q]).sum();
                    let v = _mm512_reduce_add_ps(acc[i][j]) + tail;
                    let out = &mut c[(i0 + i) * ldc + j0 + j];
                    *out = if add { *out + v } else { v };
                }
            }
            j0 += nj;
        }
        i0 += mi;
    }
}

/// Adam's moments and parameters on the whole vectors (see
/// [`crate::train::optim::FlatAdam::step`], whose operation order this keeps: no fused
/// multiply-adds, as libtorch's separate operations); returns how many elements.
///
/// # Safety
/// The CPU must have AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
pub unsafe fn adam(
    p: &mut [f32],
    m: &mut [f32],
    v: &mut [f32],
    g: &[f32],
    [b1, c1, b2, c2, sbc2, eps, step]: [f32; 7],
) -> usize {
    let n = p.len().min(m.len()).min(v.len()).min(g.len()) / LANES * LANES;
    let (pp, mp, vp, gp) = (p.as_mut_ptr(), m.as_mut_ptr(), v.as_mut_ptr(), g.as_ptr());
    for i in (0..n).step_by(LANES) {
        let gv = _mm512_loadu_ps(gp.add(i));
        let mv = _mm512_add_ps(
            _mm512_mul_ps(_mm512_loadu_ps(mp.add(i)), set(b1)),
            _mm512_mul_ps(gv, set(c1)),
        );
        let vv = _mm512_add_ps(
            _mm512_mul_ps(_mm512_loadu_ps(vp.add(i)), set(b2)),
            _mm512_mul_ps(_mm512_mul_ps(gv, gv), set(c2)),
        );
        let denom = _mm512_add_ps(_mm512_div_ps(_mm512_sqrt_ps(vv), set(sbc2)), set(eps));
        let upd = _mm512_mul_ps(_mm512_div_ps(mv, denom), set(step));
        _mm512_storeu_ps(mp.add(i), mv);
        _mm512_storeu_ps(vp.add(i), vv);
        _mm512_storeu_ps(pp.add(i), _mm512_sub_ps(_mm512_loadu_ps(pp.add(i)), upd));
    }
    n
}
