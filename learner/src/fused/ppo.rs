//! One PPO minibatch step of the fused backend ([`crate::train::ppo::PpoLearner::update`]'s
//! loop body): the clipped surrogate, value loss and entropy bonus of the Gaussian
//! policy, p(c) through the Gumbel-softmax codes (Eq. 7), the gradient-norm clip and
//! Adam, threads over the minibatch's rows as in [`super::disc`].
//!
//! Per row, the losses' gradients with respect to the networks' outputs are closed
//! forms (the losses are means over rows), so each thread computes them for its own
//! rows right after its forward pass and goes straight on to its backward pass: one
//! meeting point per step.

use super::mlp::{Acts, Input, Mlp};
use super::sgemm::{Acc, ShapeError};
use super::team::{Team, block};
use crate::train::optim::{FlatAdam, clip_norm};

/// The policy and value networks' layout in their optimiser's flat buffer.
#[derive(Debug, Clone)]
pub struct PolicyNet {
    /// The Gaussian's mean.
    pub mean: Mlp,
    /// Offset of `log_std` (`[act]`).
    pub log_std: usize,
    /// The value network.
    pub value: Mlp,
}

/// The settings of a PPO step.
#[derive(Debug, Clone, Copy)]
pub struct PpoSettings {
    /// Clip range.
    pub clip: f64,
    /// Value loss weight.
    pub value_coef: f32,
    /// Entropy bonus weight.
    pub entropy_coef: f32,
    /// Gradient-norm clip.
    pub max_grad_norm: f64,
    /// Gumbel-softmax temperature, when the codes are recomputed from their noise (the
    /// Gumbel prior); `None`: the stored codes.
    pub gumbel_tau: Option<f32>,
    /// Step p(c) too.
    pub train_prior: bool,
}

/// Column layout of the rows matrix (`PpoRows`): obs + eps, code, Gumbel noise,
/// pre-tanh action, old log-probability, advantage, return.
#[derive(Debug, Clone, Copy)]
pub struct RowLayout {
    /// Observation and eps.
    pub obs_eps: usize,
    /// Codes K.
    pub k: usize,
    /// Action width.
    pub act: usize,
}

impl RowLayout {
    /// Columns of a row.
    pub fn width(&self) -> usize {
        self.obs_eps + 2 * self.k + self.act + 3
    }
}

/// What one step reports (summed into [`crate::train::ppo::PpoStats`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct StepStats {
    /// Clipped surrogate loss.
    pub policy_loss: f64,
    /// Value loss.
    pub value_loss: f64,
    /// Entropy.
    pub entropy: f64,
    /// Approximate KL.
    pub approx_kl: f64,
    /// Fraction of clipped ratios.
    pub clip_frac: f64,
}

#[derive(Debug, Default)]
struct Block {
    rows: (usize, usize),
    x: Input,
    pi: Acts,
    v: Acts,
    dmean: Vec<f32>,
    dv: Vec<f32>,
    dcode: Vec<f32>,
    code: Vec<f32>,
    g: Vec<f32>,
    dlog_std: Vec<f64>,
    dlog_prior: Vec<f64>,
    sums: [f64; 4],
}

/// The step's buffers, kept between steps.
#[derive(Debug, Default)]
pub struct PpoStep {
    blocks: Vec<Block>,
    g: Vec<f32>,
}

const LN_SQRT_2PI: f32 = 0.918_938_5;

/// `code = softmax((g + log p) / tau)` into `out`.
fn gumbel_code(g: &[f32], log_prior: &[f32], tau: f32, out: &mut [f32]) {
    let mut m = f32::NEG_INFINITY;
    for ((o, &g), &lp) in out.iter_mut().zip(g).zip(log_prior) {
        *o = (g + lp) / tau;
        m = m.max(*o);
    }
    let mut s = 0.0;
    for o in out.iter_mut() {
        *o = (*o - m).exp();
        s += *o;
    }
    out.iter_mut().for_each(|o| *o /= s);
}

impl PpoStep {
    /// The last step's gradient, laid out as the parameters (after PPO's norm clip).
    pub fn grad(&self) -> &[f32] {
        &self.g
    }

    /// One minibatch step on rows `idx` of `rows` (row-major, `lay`): gradients, the
    /// norm clip and Adam on `opt` (policy and value), and on `prior` (p(c)'s logits)
    /// when `s.train_prior`.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        team: &Team,
        net: &PolicyNet,
        opt: &mut FlatAdam,
        prior: &mut FlatAdam,
        rows: &[f32],
        lay: RowLayout,
        idx: &[i64],
        s: &PpoSettings,
    ) -> Result<StepStats, ShapeError> {
        let k = lay.k;
        let log_prior = log_softmax(prior.params);
        let act = net.mean.out();
        let log_std: Vec<f32> = opt.params[net.log_std..net.log_std + act].to_vec();
        self.blocks.resize_with(team.threads(), Block::default);
        let threads = self.blocks.len();
        let p: &[f32] = opt.params;
        let n = idx.len();
        team.each(&mut self.blocks, |t, b| {
            b.rows = block(n, threads, t);
            one_block(
                b,
                net,
                p,
                rows,
                lay,
                &idx[b.rows.0..b.rows.1],
                n,
                &log_std,
                &log_prior,
                s,
            )
        })?;
        self.g.clear();
        self.g.resize(p.len(), 0.0);
        let mut dlp = vec![0.0f64; k];
        let mut sums = [0.0f64; 4];
        let mut dls = vec![0.0f64; act];
        for b in &self.blocks {
            self.g.iter_mut().zip(&b.g).for_each(|(g, x)| *g += x);
            dlp.iter_mut().zip(&b.dlog_prior).for_each(|(a, x)| *a += x);
            dls.iter_mut().zip(&b.dlog_std).for_each(|(a, x)| *a += x);
            sums.iter_mut().zip(&b.sums).for_each(|(a, x)| *a += x);
        }
        for (g, d) in self.g[net.log_std..net.log_std + act].iter_mut().zip(&dls) {
            *g = *d as f32 - s.entropy_coef;
        }
        clip_norm(&mut self.g, s.max_grad_norm);
        opt.step(&self.g);
        if s.train_prior {
            // Through log_softmax: d logits_i = d lp_i - p_i sum_k d lp_k.
            let total: f64 = dlp.iter().sum();
            let g: Vec<f32> = log_prior
                .iter()
                .zip(&dlp)
                .map(|(&lp, &d)| (d - f64::from(lp.exp()) * total) as f32)
                .collect();
            prior.step(&g);
        }
        let c = (0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln()) as f32;
        let entropy: f64 = log_std.iter().map(|&l| f64::from(l + c)).sum();
        let inv = 1.0 / n.max(1) as f64;
        Ok(StepStats {
            policy_loss: -sums[0] * inv,
            value_loss: sums[1] * inv,
            entropy,
            approx_kl: sums[2] * inv,
            clip_frac: sums[3] * inv,
        })
    }
}

/// `log softmax` of a few logits.
pub fn log_softmax(x: &[f32]) -> Vec<f32> {
    let m = x.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    let lse = m + x.iter().map(|&v| (v - m).exp()).sum::<f32>().ln();
    x.iter().map(|&v| v - lse).collect()
}

/// One thread's rows: gather, forward, the losses' gradients, backward.
#[allow(clippy::too_many_arguments)]
fn one_block(
    b: &mut Block,
    net: &PolicyNet,
    p: &[f32],
    rows: &[f32],
    lay: RowLayout,
    idx: &[i64],
    n_total: usize,
    log_std: &[f32],
    log_prior: &[f32],
    s: &PpoSettings,
) -> Result<(), ShapeError> {
    let (w, k) = (idx.len(), lay.k);
    let inp = lay.obs_eps + k;
    let width = lay.width();
    b.x.reset(inp, w);
    b.code.resize(k, 0.0);
    let code = &mut b.code;
    for (col, &i) in idx.iter().enumerate() {
        let i = usize::try_from(i).map_err(|_| ShapeError::new(format!("row index {i}")))?;
        let row = rows
            .get(i * width..(i + 1) * width)
            .ok_or_else(|| ShapeError::new(format!("row {i} past the rollout")))?;
        let (oe, rest) = row.split_at(lay.obs_eps);
        let (c, rest) = rest.split_at(k);
        match s.gumbel_tau {
            Some(tau) => gumbel_code(&rest[..k], log_prior, tau, code),
            None => code.copy_from_slice(c),
        }
        b.x.set(col, 0, oe);
        b.x.set(col, lay.obs_eps, code);
    }
    net.mean.forward(p, b.x.mat(), &mut b.pi)?;
    net.value.forward(p, b.x.mat(), &mut b.v)?;
    losses(b, rows, lay, idx, n_total, log_std, s)?;
    let x = b.x.mat();
    b.g.resize(p.len(), 0.0);
    let code_rows = s.train_prior.then(|| {
        b.dcode.resize(k * w, 0.0);
        (lay.obs_eps..inp, &mut b.dcode[..])
    });
    net.mean.backward(
        p,
        x,
        &mut b.pi,
        &b.dmean,
        (&mut b.g, Acc::Overwrite),
        code_rows,
    )?;
    net.value
        .backward(p, x, &mut b.v, &b.dv, (&mut b.g, Acc::Overwrite), None)?;
    b.dlog_prior.clear();
    b.dlog_prior.resize(k, 0.0);
    if let (true, Some(tau)) = (s.train_prior, s.gumbel_tau) {
        // code = softmax(y), y = (g + log p) / tau: dy_i = c_i (dc_i - sum_k c_k dc_k).
        for col in 0..w {
            let c = |i: usize| b.x.get(lay.obs_eps + i, col);
            let dc = |i: usize| b.dcode[i * w + col];
            let dot: f32 = (0..k).map(|i| c(i) * dc(i)).sum();
            for i in 0..k {
                b.dlog_prior[i] += f64::from(c(i) * (dc(i) - dot) / tau);
            }
        }
    }
    Ok(())
}

/// Per row: the clipped surrogate (its gradient with respect to the mean and
/// log_std), the value loss's gradient, and the step's statistics.
fn losses(
    b: &mut Block,
    rows: &[f32],
    lay: RowLayout,
    idx: &[i64],
    n_total: usize,
    log_std: &[f32],
    s: &PpoSettings,
) -> Result<(), ShapeError> {
    let (w, act, width) = (idx.len(), lay.act, lay.width());
    let inv = 1.0 / n_total as f32;
    let mean = b.pi.h.last().map_or(&[][..], |h| &h[..]);
    let v = b.v.h.last().map_or(&[][..], |h| &h[..]);
    b.dmean.resize(act * w, 0.0);
    b.dv.resize(w, 0.0);
    b.dlog_std.clear();
    b.dlog_std.resize(act, 0.0);
    b.sums = [0.0; 4];
    let inv_std: Vec<f32> = log_std.iter().map(|&l| (-l).exp()).collect();
    let (lo, hi, clip) = ((1.0 - s.clip) as f32, (1.0 + s.clip) as f32, s.clip as f32);
    for (col, &i) in idx.iter().enumerate() {
        let row = &rows[i as usize * width..(i as usize + 1) * width];
        let tail = lay.obs_eps + 2 * lay.k;
        let (u, rest) = row[tail..].split_at(act);
        let (old, adv, ret) = (rest[0], rest[1], rest[2]);
        let mut logp = 0.0f32;
        for r in 0..act {
            let z = (u[r] - mean[r * w + col]) * inv_std[r];
            logp += z * z * -0.5 - log_std[r] - LN_SQRT_2PI;
        }
        let log_ratio = logp - old;
        let ratio = log_ratio.exp();
        let (s1, s2) = (ratio * adv, ratio.clamp(lo, hi) * adv);
        let inside = (lo..=hi).contains(&ratio);
        // d(-mean min(s1, s2))/d ratio as torch's autograd takes it: a tie splits the
        // gradient between the two sides; the clamp passes it inside its range only.
        let g = -inv * adv;
        let dratio = if s1 < s2 {
            g
        } else if s1 > s2 {
            if inside { g } else { 0.0 }
        } else {
            0.5 * g + if inside { 0.5 * g } else { 0.0 }
        };
        let dlogp = dratio * ratio;
        for r in 0..act {
            let z = (u[r] - mean[r * w + col]) * inv_std[r];
            b.dmean[r * w + col] = dlogp * z * inv_std[r];
            b.dlog_std[r] += f64::from(dlogp * (z * z - 1.0));
        }
        let diff = v[col] - ret;
        b.dv[col] = s.value_coef * 2.0 * diff * inv;
        b.sums[0] += f64::from(s1.min(s2));
        b.sums[1] += f64::from(diff * diff);
        b.sums[2] += f64::from((ratio - 1.0) - log_ratio);
        b.sums[3] += f64::from(u8::from((ratio - 1.0).abs() > clip));
    }
    Ok(())
}
