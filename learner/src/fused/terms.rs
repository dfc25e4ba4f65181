//! The D/Q objective's terms (Eq. 9's D/Q side, [`crate::objective`]) on the heads'
//! outputs, each returning its value and adding its weighted gradient with respect to
//! those outputs. The tch versions in `objective/` are the definitions; each function
//! here names the one it computes, and the tests hold values and gradients to them.
//!
//! The heads' outputs of a step are one feature-major matrix `[K + 2][n]`: row 0 D's
//! logit, rows `1..=K` Q_c's logits, row `K + 1` Q_eps; the step's sources are column
//! ranges of it ([`Cols`]). Values are summed in f64; gradients are f32.

use super::math;
use super::sgemm::{Acc, Mat, MatMut, ShapeError, gemm};

/// A column range of the heads' outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cols {
    /// First column.
    pub start: usize,
    /// Columns.
    pub len: usize,
}

impl Cols {
    fn range(self) -> std::ops::Range<usize> {
        self.start..self.start + self.len
    }
}

/// The heads' outputs (or their gradient) `[K + 2][n]`.
pub struct Heads<'a, T> {
    /// Data, row-major.
    pub data: T,
    /// Columns.
    pub n: usize,
    /// Q_c's logits.
    pub k: usize,
    _p: std::marker::PhantomData<&'a ()>,
}

impl<'a, T: AsRef<[f32]>> Heads<'a, T> {
    /// A view of `data` as `[k + 2][n]`.
    pub fn new(data: T, n: usize, k: usize) -> Self {
        Self {
            data,
            n,
            k,
            _p: std::marker::PhantomData,
        }
    }

    fn row(&self, r: usize, c: Cols) -> &[f32] {
        &self.data.as_ref()[r * self.n..][c.range()]
    }

    /// D's logits on `c`.
    pub fn d(&self, c: Cols) -> &[f32] {
        self.row(0, c)
    }

    /// Q_eps on `c`.
    pub fn qeps(&self, c: Cols) -> &[f32] {
        self.row(self.k + 1, c)
    }

    /// Q_c's logit `i` on `c`.
    pub fn qc(&self, i: usize, c: Cols) -> &[f32] {
        self.row(1 + i, c)
    }
}

impl<T: AsMut<[f32]>> Heads<'_, T> {
    fn row_mut(&mut self, r: usize, c: Cols) -> &mut [f32] {
        let n = self.n;
        &mut self.data.as_mut()[r * n..][c.range()]
    }
}

/// Scratch buffers of the terms, kept between steps.
#[derive(Debug, Default)]
pub struct Scratch {
    /// `log softmax` of Q_c, `[K][len]`.
    logp: Vec<f32>,
    /// `softmax` of Q_c, `[K][len]`.
    p: Vec<f32>,
    col: [Vec<f32>; 2],
    sim: Vec<f32>,
    z: Vec<f32>,
    dz: Vec<f32>,
    /// The columns `logp` and `p` hold (several terms read the expert rows' softmax).
    memo: Option<Cols>,
}

impl Scratch {
    /// Forgets the softmax held (new heads' outputs).
    pub fn reset(&mut self) {
        self.memo = None;
    }
}

/// `log softmax` and `softmax` over Q_c's K logits of every column of `c`, into
/// `s.logp` and `s.p` (`[K][len]` each).
fn softmax(h: &Heads<'_, &[f32]>, c: Cols, s: &mut Scratch) {
    if s.memo == Some(c) {
        return;
    }
    s.memo = Some(c);
    let (k, len) = (h.k, c.len);
    let [m, sum] = &mut s.col;
    m.clear();
    m.resize(len, f32::NEG_INFINITY);
    sum.clear();
    sum.resize(len, 0.0);
    s.logp.resize(k * len, 0.0);
    s.p.resize(k * len, 0.0);
    for i in 0..k {
        for (m, &x) in m.iter_mut().zip(h.qc(i, c)) {
            *m = if x > *m { x } else { *m };
        }
    }
    for i in 0..k {
        let (row, p) = (h.qc(i, c), &mut s.p[i * len..(i + 1) * len]);
        for ((p, &x), &m) in p.iter_mut().zip(row).zip(m.iter()) {
            *p = x - m;
        }
        math::exp_inplace(p, 0.0);
        for (s, &p) in sum.iter_mut().zip(p.iter()) {
            *s += p;
        }
    }
    // m becomes log-sum-exp, sum its reciprocal.
    for (m, s) in m.iter_mut().zip(sum.iter_mut()) {
        *m += math::ln(*s);
        *s = 1.0 / *s;
    }
    for i in 0..k {
        let r = i * len..(i + 1) * len;
        for ((lp, &x), &lse) in s.logp[r.clone()].iter_mut().zip(h.qc(i, c)).zip(m.iter()) {
            *lp = x - lse;
        }
        for (p, &inv) in s.p[r].iter_mut().zip(sum.iter()) {
            *p *= inv;
        }
    }
}

/// Eq. 1, [`crate::objective::disc_bce::disc_bce`]: the sum `mean_E BCE(logit, 1 -
/// smoothing) + mean_G BCE(logit, policy_target)` (`softplus(logit)` at target 0),
/// where `BCE(x, t) = t softplus(-x) + (1 - t) softplus(x)`; gradient
/// `(sigmoid(x) - t) / rows`. The value (a logarithm per row) only when `value` (the
/// step that is logged); else 0.
pub fn disc_bce(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    (expert, gen_): (Cols, Cols),
    (w, smoothing, policy_target): (f32, f32, f32),
    value: bool,
    s: &mut Scratch,
) -> f64 {
    let mut total = 0.0f64;
    for (c, target) in [(expert, 1.0 - smoothing), (gen_, policy_target)] {
        if c.len == 0 {
            continue;
        }
        let inv = w / c.len as f32;
        // e = exp(-|x|): sigmoid(x) = 1 / (1 + e) or e / (1 + e), softplus(+-x) =
        // max(+-x, 0) + ln(1 + e), both without overflow.
        let e = &mut s.z;
        e.clear();
        e.extend(h.d(c).iter().map(|x| -x.abs()));
        math::exp_inplace(e, 0.0);
        let mut sum = 0.0f64;
        for ((g, &x), &e) in d.row_mut(0, c).iter_mut().zip(h.d(c)).zip(e.iter()) {
            let sig = if x >= 0.0 {
                1.0 / (1.0 + e)
            } else {
                e / (1.0 + e)
            };
            *g += (sig - target) * inv;
            if value {
                // softplus(x) = max(x, 0) + ln(1 + e); softplus(-x) = softplus(x) - x.
                let sp = x.max(0.0) + math::ln(1.0 + e);
                sum += f64::from(sp - target * x);
            }
        }
        total += sum / c.len as f64;
    }
    total
}

/// [`crate::objective::qeps::qeps_mae`]: `mean |Q_eps - eps|` on the generated rows.
pub fn qeps_mae(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    gen_: Cols,
    eps: &[f32],
    w: f32,
) -> f64 {
    if gen_.len == 0 {
        return 0.0;
    }
    let inv = 1.0 / gen_.len as f32;
    let k = h.k;
    let mut sum = 0.0f64;
    for ((g, &q), &e) in d.row_mut(k + 1, gen_).iter_mut().zip(h.qeps(gen_)).zip(eps) {
        let diff = q - e;
        sum += f64::from(diff.abs());
        // torch's |x|' is sgn(x), 0 at 0.
        let sgn = if diff > 0.0 {
            1.0
        } else if diff < 0.0 {
            -1.0
        } else {
            0.0
        };
        *g += w * sgn * inv;
    }
    sum / gen_.len as f64
}

/// [`crate::objective::qc_ce::soft_cross_entropy`] on `c` against `target` rows
/// (`[len][K]`, row-major): `-mean_j sum_i t_ji log softmax(q_j)_i`.
pub fn soft_ce(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    c: Cols,
    target: &[f32],
    w: f32,
    s: &mut Scratch,
) -> f64 {
    ce(h, d, c, w, s, |j, i| target[j * h.k + i])
}

/// [`crate::objective::qc_ce::hard_cross_entropy`] on `c` against integer `labels`.
pub fn hard_ce(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    c: Cols,
    labels: &[i64],
    w: f32,
    s: &mut Scratch,
) -> Result<f64, ShapeError> {
    if let Some(bad) = labels.iter().find(|&&y| y < 0 || y as usize >= h.k) {
        return Err(ShapeError::new(format!("label {bad} outside 0..{}", h.k)));
    }
    Ok(ce(h, d, c, w, s, |j, i| {
        if labels[j] as usize == i { 1.0 } else { 0.0 }
    }))
}

/// Cross-entropy against per-column targets `t(j, i)`; gradient
/// `(softmax(q_j) sum_i t_ji - t_j) / len`.
fn ce(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    c: Cols,
    w: f32,
    s: &mut Scratch,
    t: impl Fn(usize, usize) -> f32,
) -> f64 {
    if c.len == 0 {
        return 0.0;
    }
    softmax(h, c, s);
    let (k, len) = (h.k, c.len);
    let inv = w / len as f32;
    let tsum = &mut s.col[0];
    tsum.clear();
    tsum.extend((0..len).map(|j| (0..k).map(|i| t(j, i)).sum::<f32>() * inv));
    let mut sum = 0.0f64;
    for i in 0..k {
        let r = i * len..(i + 1) * len;
        let (p, lp) = (&s.p[r.clone()], &s.logp[r]);
        for (j, ((g, &p), &ts)) in d
            .row_mut(1 + i, c)
            .iter_mut()
            .zip(p)
            .zip(tsum.iter())
            .enumerate()
        {
            let ti = t(j, i);
            *g += p * ts - ti * inv;
            sum -= f64::from(ti * lp[j]);
        }
    }
    sum / len as f64
}

/// Eq. 8's first two parts ([`crate::objective::rim::rim`]) on `c`: the mean conditional
/// entropy `H` of Q_c and `KL(mean_j Q_c(.|x_j) || p(c))`, weighted `w_h`, `w_kl` into
/// the gradient. Returns `(H, KL)`; `dlog_prior` (`[K]`) receives the weighted KL's
/// gradient with respect to `log p(c)`, and `marginal` the mean prediction.
#[allow(clippy::too_many_arguments)]
pub fn rim(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    c: Cols,
    log_prior: &[f32],
    w_h: f32,
    w_kl: f32,
    dlog_prior: &mut [f32],
    s: &mut Scratch,
) -> (f64, f64) {
    if c.len == 0 {
        return (0.0, 0.0);
    }
    softmax(h, c, s);
    let (k, len) = (h.k, c.len);
    let inv = 1.0 / len as f32;
    // Per column: H_j = -sum_i p_ij log p_ij; per code: the marginal m_i = mean_j p_ij.
    let ent = &mut s.col[0];
    ent.clear();
    ent.resize(len, 0.0);
    let mut marginal = [0.0f64; 64];
    for (i, m) in marginal.iter_mut().enumerate().take(k) {
        let r = i * len..(i + 1) * len;
        for ((e, &p), &lp) in ent.iter_mut().zip(&s.p[r.clone()]).zip(&s.logp[r.clone()]) {
            *e -= p * lp;
        }
        *m = f64::from(math::sum(&s.p[r])) / len as f64;
    }
    let h_sum: f64 = ent.iter().map(|&e| f64::from(e)).sum();
    let mut kl = 0.0f64;
    // dKL/dm_i (0 where the clamp at 1e-12 holds m_i).
    let mut gk = [0.0f32; 64];
    for (i, &m) in marginal.iter().enumerate().take(k) {
        let mc = (m as f32).max(1e-12);
        let lm = math::ln(mc);
        kl += f64::from(mc * (lm - log_prior[i]));
        gk[i] = if (m as f32) >= 1e-12 {
            lm + 1.0 - log_prior[i]
        } else {
            0.0
        };
        dlog_prior[i] -= w_kl * mc;
    }
    // gq_j = sum_i g_i p_ij.
    let [ent, gq] = &mut s.col;
    gq.clear();
    gq.resize(len, 0.0);
    for (i, &g) in gk.iter().enumerate().take(k) {
        for (q, &p) in gq.iter_mut().zip(&s.p[i * len..(i + 1) * len]) {
            *q += g * p;
        }
    }
    for (i, &g) in gk.iter().enumerate().take(k) {
        let r = i * len..(i + 1) * len;
        let (p, lp) = (&s.p[r.clone()], &s.logp[r]);
        for (j, grad) in d.row_mut(1 + i, c).iter_mut().enumerate() {
            let dh = -p[j] * (lp[j] + ent[j]);
            let dkl = p[j] * (g - gq[j]);
            *grad += inv * (w_h * dh + w_kl * dkl);
        }
    }
    (h_sum / len as f64, kl)
}

/// Q_c's mean prediction `mean_j softmax(q_j)` on `c` (`[K]`), for p(c)'s updates.
pub fn mean_prediction(h: &Heads<'_, &[f32]>, c: Cols, out: &mut [f64], s: &mut Scratch) {
    out.iter_mut().for_each(|x| *x = 0.0);
    if c.len == 0 {
        return;
    }
    softmax(h, c, s);
    for (i, o) in out.iter_mut().enumerate().take(h.k) {
        *o = f64::from(math::sum(&s.p[i * c.len..(i + 1) * c.len])) / c.len as f64;
    }
}

/// [`crate::objective::contrastive::nt_xent`] between Q_c's logits on `z1` and on
/// `z2` (positive pairs column by column), temperature `temp`.
pub fn nt_xent(
    h: &Heads<'_, &[f32]>,
    d: &mut Heads<'_, &mut [f32]>,
    z1: Cols,
    z2: Cols,
    temp: f32,
    w: f32,
    s: &mut Scratch,
) -> Result<f64, ShapeError> {
    let (n, k) = (z1.len, h.k);
    if n == 0 {
        return Ok(0.0);
    }
    let n2 = 2 * n;
    // u = z / max(|z|, 1e-8), rows [n2][k]; keep the norms.
    s.z.resize(n2 * k, 0.0);
    let norms = &mut s.col[0];
    norms.clear();
    norms.resize(n2, 0.0);
    for (r, (cols, j)) in (0..n)
        .map(|j| (z1, j))
        .chain((0..n).map(|j| (z2, j)))
        .enumerate()
    {
        let mut sq = 0.0f32;
        for i in 0..k {
            let v = h.qc(i, cols)[j];
            s.z[r * k + i] = v;
            sq += v * v;
        }
        let norm = sq.sqrt().max(1e-8);
        norms[r] = norm;
        s.z[r * k..(r + 1) * k].iter_mut().for_each(|v| *v /= norm);
    }
    s.sim.resize(n2 * n2, 0.0);
    let u = Mat::rows(&s.z, n2, k);
    gemm(
        &mut MatMut::new(&mut s.sim, n2, n2, n2),
        u,
        u.t(),
        Acc::Overwrite,
        None,
    )?;
    let mut loss = 0.0f64;
    let inv = 1.0 / n2 as f32;
    for r in 0..n2 {
        let row = &mut s.sim[r * n2..(r + 1) * n2];
        row.iter_mut().for_each(|x| *x /= temp);
        row[r] -= 1e9;
        let m = row.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
        let sum: f32 = row.iter().map(|&x| math::exp(x - m)).sum();
        let lse = m + math::ln(sum);
        let t = (r + n) % n2;
        loss -= f64::from(row[t] - lse);
        // Row r of dL/dS, in place: (softmax - onehot) / n2.
        for (c, x) in row.iter_mut().enumerate() {
            *x = (math::exp(*x - lse) - if c == t { 1.0 } else { 0.0 }) * inv;
        }
    }
    // dU = (dS + dS^T) U / temp.
    s.dz.resize(n2 * k, 0.0);
    let ds = Mat::rows(&s.sim, n2, n2);
    let mut du = MatMut::new(&mut s.dz, n2, k, k);
    gemm(&mut du, ds, u, Acc::Overwrite, None)?;
    gemm(&mut du, ds.t(), u, Acc::Add, None)?;
    // Through the normalisation: dz = (du - u (u . du)) / |z|, or du / 1e-8 where clamped.
    for (r, (cols, j)) in (0..n)
        .map(|j| (z1, j))
        .chain((0..n).map(|j| (z2, j)))
        .enumerate()
    {
        let (ur, dur) = (&s.z[r * k..(r + 1) * k], &s.dz[r * k..(r + 1) * k]);
        let norm = norms[r];
        let dot: f32 = if norm > 1e-8 {
            ur.iter().zip(dur).map(|(a, b)| a * b).sum()
        } else {
            0.0
        };
        for i in 0..k {
            let g = (dur[i] / temp - ur[i] * dot / temp) / norm;
            d.row_mut(1 + i, cols)[j] += w * g;
        }
    }
    Ok(loss / n2 as f64)
}

#[cfg(test)]
mod tests {
    //! One golden test per term: the value and the gradient with respect to the
    //! heads' outputs equal tch's autograd through the `objective/` definition.

    use super::*;
    use crate::objective;
    use tch::{Device, Kind, Tensor};

    const K: usize = 4;
    const N: usize = 90;

    /// Heads' outputs `[K + 2][N]` with logits of either sign and size.
    fn outputs() -> Vec<f32> {
        (0..(K + 2) * N)
            .map(|i| 2.5 * ((i as f32) * 0.61).sin() + 0.3 * ((i as f32) * 2.9).cos())
            .collect()
    }

    /// Rows `r0..r0 + rows` of columns `c` as a `[len][rows]` tensor requiring grad.
    fn leaf(o: &[f32], r0: usize, rows: usize, c: Cols) -> Tensor {
        let mut v = Vec::with_capacity(rows * c.len);
        for j in c.range() {
            for r in r0..r0 + rows {
                v.push(o[r * N + j]);
            }
        }
        Tensor::from_slice(&v)
            .view([c.len as i64, rows as i64])
            .set_requires_grad(true)
    }

    /// The gradient tensor `[len][rows]` laid back into `[K + 2][N]`.
    fn place(g: &Tensor, r0: usize, rows: usize, c: Cols, out: &mut [f32]) {
        let v = Vec::<f32>::try_from(g.contiguous().view([-1])).expect("grad");
        for (jj, j) in c.range().enumerate() {
            for r in 0..rows {
                out[(r0 + r) * N + j] += v[jj * rows + r];
            }
        }
    }

    fn assert_close(what: &str, got: &[f32], want: &[f32], rel: f64) {
        let n = |x: &[f32]| x.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
        let d: Vec<f32> = got.iter().zip(want).map(|(a, b)| a - b).collect();
        let e = n(&d) / n(want).max(1e-30);
        assert!(e <= rel, "{what}: relative error {e:.2e}");
    }

    fn value(t: &Tensor) -> f64 {
        f64::try_from(t).expect("scalar")
    }

    const G: Cols = Cols { start: 0, len: 40 };
    const E: Cols = Cols { start: 40, len: 30 };
    const L: Cols = Cols { start: 70, len: 20 };

    fn codes() -> Vec<f32> {
        (0..G.len * K)
            .map(|i| ((i * 7 % 5) as f32 + 0.2) / 10.0)
            .collect::<Vec<_>>()
            .chunks(K)
            .flat_map(|r| {
                let s: f32 = r.iter().sum();
                r.iter().map(move |x| x / s).collect::<Vec<_>>()
            })
            .collect()
    }

    #[test]
    fn disc_bce_is_eq_1_with_its_gradient() {
        for (smoothing, policy_target) in [(0.0, 0.0), (0.1, 0.0), (0.1, 0.2)] {
            disc_bce_matches_tch(smoothing, policy_target);
        }
    }

    fn disc_bce_matches_tch(smoothing: f32, policy_target: f32) {
        let o = outputs();
        let mut g = vec![0.0; o.len()];
        let v = disc_bce(
            &Heads::new(&o[..], N, K),
            &mut Heads::new(&mut g[..], N, K),
            (E, G),
            (0.7, smoothing, policy_target),
            true,
            &mut Scratch::default(),
        );
        let (e, p) = (leaf(&o, 0, 1, E), leaf(&o, 0, 1, G));
        let t = objective::disc_bce::disc_bce(
            &e.view([-1]),
            &p.view([-1]),
            smoothing.into(),
            policy_target.into(),
        );
        (&t * 0.7).backward();
        let mut want = vec![0.0; o.len()];
        place(&e.grad(), 0, 1, E, &mut want);
        place(&p.grad(), 0, 1, G, &mut want);
        assert!(
            (v - value(&t)).abs() < 1e-6 * value(&t),
            "{v} vs {}",
            value(&t)
        );
        assert_close("BCE gradient", &g, &want, 1e-6);
    }

    #[test]
    fn qeps_mae_with_its_gradient() {
        let o = outputs();
        let eps: Vec<f32> = (0..G.len).map(|i| ((i as f32) * 0.37).cos()).collect();
        let mut g = vec![0.0; o.len()];
        let v = qeps_mae(
            &Heads::new(&o[..], N, K),
            &mut Heads::new(&mut g[..], N, K),
            G,
            &eps,
            1.3,
        );
        let q = leaf(&o, K + 1, 1, G);
        let t = objective::qeps::qeps_mae(&q.view([-1]), &Tensor::from_slice(&eps));
        (&t * 1.3).backward();
        let mut want = vec![0.0; o.len()];
        place(&q.grad(), K + 1, 1, G, &mut want);
        assert!((v - value(&t)).abs() < 1e-6, "{v} vs {}", value(&t));
        assert_close("MAE gradient", &g, &want, 1e-6);
    }

    #[test]
    fn soft_and_hard_cross_entropy_are_eqs_4_and_5_with_their_gradients() {
        let o = outputs();
        let code = codes();
        let labels: Vec<i64> = (0..L.len as i64).map(|i| (i * 3) % K as i64).collect();
        let mut g = vec![0.0; o.len()];
        let mut s = Scratch::default();
        let (h, mut d) = (Heads::new(&o[..], N, K), Heads::new(&mut g[..], N, K));
        let v1 = soft_ce(&h, &mut d, G, &code, 0.5, &mut s);
        let v2 = hard_ce(&h, &mut d, L, &labels, 2.0, &mut s).expect("labels");
        let (qg, ql) = (leaf(&o, 1, K, G), leaf(&o, 1, K, L));
        let t1 = objective::qc_ce::soft_cross_entropy(
            &qg,
            &Tensor::from_slice(&code).view([G.len as i64, K as i64]),
        );
        let t2 = objective::qc_ce::hard_cross_entropy(&ql, &Tensor::from_slice(&labels));
        (&t1 * 0.5 + &t2 * 2.0).backward();
        let mut want = vec![0.0; o.len()];
        place(&qg.grad(), 1, K, G, &mut want);
        place(&ql.grad(), 1, K, L, &mut want);
        let bad = hard_ce(&h, &mut d, L, &[K as i64; L.len], 1.0, &mut s);
        assert!(bad.unwrap_err().to_string().contains("label 4"));
        assert!(
            (v1 - value(&t1)).abs() < 1e-6 * value(&t1)
                && (v2 - value(&t2)).abs() < 1e-6 * value(&t2)
        );
        assert_close("CE gradient", &g, &want, 1e-6);
    }

    #[test]
    fn rim_is_eq_8_with_its_gradient_and_the_priors() {
        let o = outputs();
        let lp = Tensor::from_slice(&[0.1f32, 0.2, 0.3, 0.4])
            .log()
            .set_requires_grad(true);
        let lpv = Vec::<f32>::try_from(&lp.detach()).expect("lp");
        let mut g = vec![0.0; o.len()];
        let mut dlp = vec![0.0; K];
        let mut s = Scratch::default();
        let (ent, kl) = rim(
            &Heads::new(&o[..], N, K),
            &mut Heads::new(&mut g[..], N, K),
            E,
            &lpv,
            0.8,
            1.7,
            &mut dlp,
            &mut s,
        );
        let q = leaf(&o, 1, K, E);
        let r = objective::rim::rim(&q, &lp, &[]);
        r.weighted(0.8, 1.7, 0.0).backward();
        let mut want = vec![0.0; o.len()];
        place(&q.grad(), 1, K, E, &mut want);
        assert!(
            (ent - value(&r.cond_entropy)).abs() < 1e-6
                && (kl - value(&r.marginal_kl)).abs() < 1e-6
        );
        assert_close("RIM gradient", &g, &want, 1e-6);
        assert_close(
            "RIM prior gradient",
            &dlp,
            &Vec::<f32>::try_from(&lp.grad()).expect("g"),
            1e-6,
        );
        let mut m = vec![0.0; K];
        mean_prediction(&Heads::new(&o[..], N, K), E, &mut m, &mut s);
        let want_m =
            Vec::<f32>::try_from(q.softmax(-1, Kind::Float).mean_dim(0, false, Kind::Float))
                .expect("m");
        assert!(
            m.iter()
                .zip(&want_m)
                .all(|(a, b)| (*a as f32 - b).abs() < 1e-6),
            "{m:?} {want_m:?}"
        );
    }

    /// NT-Xent in f64 (tch's definition, every operation in double precision).
    fn nt_xent_f64(z1: &Tensor, z2: &Tensor, temp: f64) -> Tensor {
        let n = z1.size()[0];
        let z = Tensor::cat(&[z1, z2], 0);
        let z = &z
            / z.norm_scalaropt_dim(2.0, [-1i64].as_slice(), true)
                .clamp_min(1e-8);
        let sim = z.matmul(&z.transpose(0, 1)) / temp
            - Tensor::eye(2 * n, (Kind::Double, Device::Cpu)) * 1e9;
        let idx: Vec<i64> = (0..2 * n).map(|i| (i + n) % (2 * n)).collect();
        sim.log_softmax(-1, Kind::Double)
            .nll_loss(&Tensor::from_slice(&idx))
    }

    #[test]
    fn nt_xent_with_its_gradient_as_accurate_as_tch() {
        let o = outputs();
        let (z1, z2) = (Cols { start: 40, len: 20 }, Cols { start: 70, len: 20 });
        let mut g = vec![0.0; o.len()];
        let mut s = Scratch::default();
        let v = nt_xent(
            &Heads::new(&o[..], N, K),
            &mut Heads::new(&mut g[..], N, K),
            z1,
            z2,
            0.5,
            0.9,
            &mut s,
        )
        .expect("nt-xent");
        let (a, b) = (leaf(&o, 1, K, z1), leaf(&o, 1, K, z2));
        let t = objective::contrastive::nt_xent(&a, &b, 0.5);
        (&t * 0.9).backward();
        let mut want = vec![0.0; o.len()];
        place(&a.grad(), 1, K, z1, &mut want);
        place(&b.grad(), 1, K, z2, &mut want);
        // The f64 reference, to tell rounding from a wrong formula.
        let (a64, b64) = (
            a.detach().to_kind(Kind::Double).set_requires_grad(true),
            b.detach().to_kind(Kind::Double).set_requires_grad(true),
        );
        (nt_xent_f64(&a64, &b64, 0.5) * 0.9).backward();
        let mut exact = vec![0.0; o.len()];
        place(&a64.grad().to_kind(Kind::Float), 1, K, z1, &mut exact);
        place(&b64.grad().to_kind(Kind::Float), 1, K, z2, &mut exact);
        assert!(
            (v - value(&t)).abs() < 1e-6 * value(&t),
            "{v} vs {}",
            value(&t)
        );
        let err = |x: &[f32]| {
            let d: f64 = x
                .iter()
                .zip(&exact)
                .map(|(a, b)| f64::from(a - b).powi(2))
                .sum();
            let n: f64 = exact.iter().map(|b| f64::from(*b).powi(2)).sum();
            (d / n).sqrt()
        };
        eprintln!(
            "NT-Xent gradient error against f64: fused {:.2e}, tch {:.2e}",
            err(&g),
            err(&want)
        );
        assert_close("NT-Xent gradient", &g, &want, 1e-5);
        assert!(
            err(&g) <= 2.0 * err(&want).max(1e-7),
            "fused {:.2e} tch {:.2e}",
            err(&g),
            err(&want)
        );
    }
}
