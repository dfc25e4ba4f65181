//! Elementwise functions: scalar definitions (polynomial `exp` / `ln` / `tanh` without
//! branches or libm calls), and the passes over slices, which run the AVX-512 kernels
//! of [`super::avx512`] where the CPU has them and these scalar definitions for the
//! rest (other CPUs, and a slice's last few elements).
//!
//! Accuracy: `exp` and `log` follow Cephes' single-precision polynomials (about 1-2
//! units in the last place on the ranges used here); `tanh` uses its odd polynomial
//! below |x| = 0.625 and `1 - 2 / (exp(2x) + 1)` above. The tests hold each to the
//! standard library within 1e-6 relative (absolute near 0).

use super::avx512::{LOG2E, ROUND};

/// `e^x` (Cephes `expf`), inputs clamped to `[-87.3, 88.3]`.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.3, 88.3);
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let z = r * r;
    let p = ((((1.987_569_1e-4 * r + 1.398_2e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 5.0e-1;
    let y = p * z + r + 1.0;
    // 2^n from n's bits in `t`.
    let pow2 = (t.to_bits().wrapping_sub(ROUND.to_bits()).wrapping_add(127)) << 23;
    y * f32::from_bits(pow2)
}

/// `ln x` for `x > 0` (Cephes `logf`); `x <= 0` gives a large negative number, not
/// NaN (callers clamp their arguments first).
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    let x = x.max(f32::MIN_POSITIVE);
    let bits = x.to_bits();
    let mut e = ((bits >> 23) as i32 - 126) as f32;
    // Mantissa in [0.5, 1).
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000);
    let small = m < std::f32::consts::FRAC_1_SQRT_2;
    e -= if small { 1.0 } else { 0.0 };
    m = if small { m + m - 1.0 } else { m - 1.0 };
    let z = m * m;
    let p = (((((((7.037_683_6e-2 * m - 1.151_461e-1) * m + 1.167_699_9e-1) * m
        - 1.242_014_1e-1)
        * m
        + 1.424_932_3e-1)
        * m
        - 1.666_805_8e-1)
        * m
        + 2.000_071_4e-1)
        * m
        - 2.499_999_4e-1)
        * m
        + 3.333_333e-1;
    let y = p * m * z - 2.121_944_4e-4 * e - 0.5 * z;
    m + y + e * 0.693_359_4
}

/// `tanh x`.
#[inline(always)]
pub fn tanh(x: f32) -> f32 {
    let a = x.abs();
    let z = x * x;
    let poly = ((((-5.704_988e-3 * z + 2.063_909e-2) * z - 5.373_971_6e-2) * z + 1.333_144_2e-1)
        * z
        - 3.333_328e-1)
        * z
        * x
        + x;
    let t = 1.0 - 2.0 / (exp(2.0 * a) + 1.0);
    let big = t.copysign(x);
    if a < 0.625 { poly } else { big }
}

/// `sigmoid x = 1 / (1 + e^-x)`.
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// `softplus x = ln(1 + e^x)`, stable for large |x|.
#[inline(always)]
pub fn softplus(x: f32) -> f32 {
    x.max(0.0) + ln(1.0 + exp(-x.abs()))
}

/// Whether the AVX-512 kernels run here.
fn wide() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        super::avx512::available()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `x[i] = tanh(x[i] + bias)` over one row of a layer's pre-activations.
pub fn tanh_bias_inplace(x: &mut [f32], bias: f32) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: the CPU has AVX-512F (`wide`); the kernel stays inside `x`.
        done = unsafe { super::avx512::tanh_bias_inplace(x, bias) };
    }
    for v in &mut x[done..] {
        *v = tanh(*v + bias);
    }
}

/// `dz[i] = dh[i] * (1 - h[i]^2)`, the backward pass through tanh, returning the sum
/// of `dz` (the bias gradient of the row).
pub fn tanh_backward(dz: &mut [f32], h: &[f32]) -> f32 {
    let (mut done, mut lanes) = (0, [0.0f32; 16]);
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: as in `tanh_bias_inplace`.
        (done, lanes) = unsafe { super::avx512::tanh_backward(dz, h) };
    }
    let mut tail = 0.0;
    for (d, h) in dz[done..].iter_mut().zip(&h[done..]) {
        *d *= 1.0 - h * h;
        tail += *d;
    }
    lanes.iter().sum::<f32>() + tail
}

/// The sum of a slice.
pub fn sum(x: &[f32]) -> f32 {
    let (mut done, mut lanes) = (0, [0.0f32; 16]);
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: as in `tanh_bias_inplace`.
        (done, lanes) = unsafe { super::avx512::sum(x) };
    }
    lanes.iter().sum::<f32>() + x[done..].iter().sum::<f32>()
}

/// One Adam step over flat buffers (`consts`: beta1, 1 - beta1, beta2, 1 - beta2,
/// sqrt(bias correction 2), eps, lr / bias correction 1; the order of operations of
/// [`crate::train::optim::Adam`]'s tch version).
pub fn adam(p: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32], consts: [f32; 7]) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: as in `tanh_bias_inplace`.
        done = unsafe { super::avx512::adam(p, m, v, g, consts) };
    }
    let [b1, c1, b2, c2, sbc2, eps, step] = consts;
    let it = p[done..].iter_mut().zip(&mut m[done..]).zip(&mut v[done..]);
    for (((p, m), v), &g) in it.zip(&g[done..]) {
        *m = *m * b1 + g * c1;
        *v = *v * b2 + g * g * c2;
        let denom = v.sqrt() / sbc2 + eps;
        *p -= *m / denom * step;
    }
}

/// `x[i] = e^(x[i] + shift)`.
pub fn exp_inplace(x: &mut [f32], shift: f32) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: as in `tanh_bias_inplace`.
        done = unsafe { super::avx512::exp_inplace(x, shift) };
    }
    for v in &mut x[done..] {
        *v = exp(*v + shift);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> impl Iterator<Item = f32> {
        (-4000..=4000)
            .map(|i| i as f32 * 0.005)
            .chain([1e-6, -1e-7, 30.0, -30.0, 80.0, -80.0])
    }

    fn close(got: f32, want: f64, what: &str, x: f32) {
        let err = (f64::from(got) - want).abs();
        assert!(
            err <= 1e-6 * want.abs().max(1.0) * 2.0,
            "{what}({x}) = {got}, want {want}, error {err}"
        );
    }

    #[test]
    fn exp_ln_tanh_sigmoid_softplus_match_the_standard_library() {
        for x in grid() {
            let xd = f64::from(x);
            close(
                exp(x.min(80.0)) / xd.min(80.0).exp() as f32,
                1.0,
                "exp ratio",
                x,
            );
            close(tanh(x), xd.tanh(), "tanh", x);
            close(sigmoid(x), 1.0 / (1.0 + (-xd).exp()), "sigmoid", x);
            close(
                softplus(x),
                xd.max(0.0) + (-xd.abs()).exp().ln_1p(),
                "softplus",
                x,
            );
            let p = x.abs() + 1e-3;
            close(ln(p), f64::from(p).ln(), "ln", p);
        }
        for p in [1e-30f32, 1e-12, 0.3, 0.707, 0.708, 1.0, 2.0, 1e10] {
            close(ln(p), f64::from(p).ln(), "ln", p);
        }
    }

    #[test]
    fn tanh_of_small_inputs_keeps_its_relative_precision() {
        for x in [1e-3f32, -2e-4, 0.3, 0.62, 0.63] {
            let want = f64::from(x).tanh();
            let rel = ((f64::from(tanh(x)) - want) / want).abs();
            assert!(rel < 1e-6, "tanh({x}): relative error {rel}");
        }
    }

    #[test]
    fn slice_passes_equal_their_scalar_definitions() {
        let h: Vec<f32> = (0..37).map(|i| (i as f32 * 0.3).sin()).collect();
        let mut dz: Vec<f32> = (0..37).map(|i| (i as f32 * 0.7).cos()).collect();
        let scale: Vec<f32> = dz.iter().map(|d| d.abs()).collect();
        let want: Vec<f32> = dz.iter().zip(&h).map(|(d, h)| d * (1.0 - h * h)).collect();
        let s = tanh_backward(&mut dz, &h);
        let ulp = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 2e-7 * y.abs().max(1e-30))
        };
        // 1 - h^2 fused or not differs by an ulp of 1, not of the (small) result.
        let close = dz
            .iter()
            .zip(&want)
            .zip(&scale)
            .all(|((x, y), s)| (x - y).abs() <= 2e-7 * s);
        assert!(close, "{dz:?} {want:?}");
        assert!((s - want.iter().sum::<f32>()).abs() < 1e-5);
        let mut x: Vec<f32> = (0..37).map(|i| i as f32 * 0.1 - 2.0).collect();
        let want: Vec<f32> = x.iter().map(|v| tanh(v + 0.5)).collect();
        tanh_bias_inplace(&mut x, 0.5);
        assert!(ulp(&x, &want), "{x:?} {want:?}");
        assert!((sum(&h) - h.iter().sum::<f32>()).abs() < 1e-5);
        let mut e: Vec<f32> = (0..37).map(|i| i as f32 * 0.9 - 20.0).collect();
        let want: Vec<f32> = e.iter().map(|v| exp(v - 1.5)).collect();
        exp_inplace(&mut e, -1.5);
        assert!(ulp(&e, &want), "{e:?} {want:?}");
    }
}
