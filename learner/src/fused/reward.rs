//! The policy's reward from the updated heads ([`crate::objective::reward::policy_reward`],
//! Eq. 9's policy terms) and the value estimates `V(s)`, `V(s')` GAE needs: forward
//! passes only, threads over the rollout's rows.

use super::disc::DiscNet;
use super::math;
use super::mlp::{Act, Acts, Input, Mlp, layer_forward};
use super::sgemm::{Mat, ShapeError};
use super::team::{Team, block};
use crate::objective::reward::RewardWeights;

/// The rollout as the reward pass reads it (row-major).
pub struct RewardInputs<'a> {
    /// D's inputs `[n][disc inp]`.
    pub disc_x: &'a [f32],
    /// Codes `[n][K]`.
    pub code: &'a [f32],
    /// Eps `[n]`.
    pub eps: &'a [f32],
    /// Normalised observations `[n][obs]`.
    pub obs: &'a [f32],
    /// Normalised next observations `[n][obs]`.
    pub next_obs: &'a [f32],
}

/// What the pass returns, per row.
#[derive(Debug, Default, Clone)]
pub struct RewardOut {
    /// The reward.
    pub reward: Vec<f32>,
    /// D's term alone, unweighted ([`crate::objective::reward::disc_term`]).
    pub disc_term: Vec<f32>,
    /// `V(s)`.
    pub values: Vec<f32>,
    /// `V(s')`.
    pub next_values: Vec<f32>,
}

#[derive(Debug, Default)]
struct Block {
    rows: (usize, usize),
    x: Input,
    acts: Acts,
    heads: Vec<f32>,
    vx: Input,
    vacts: Acts,
    out: RewardOut,
}

/// The pass's buffers, kept between iterations.
#[derive(Debug, Default)]
pub struct RewardPass {
    blocks: Vec<Block>,
    wh: Vec<f32>,
    bh: Vec<f32>,
}

impl RewardPass {
    /// Rewards and values of the `n` rows of `r`: D (`dnet` over `dp`) and the value
    /// network (`value` over `vp`).
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        team: &Team,
        dnet: &DiscNet,
        dp: &[f32],
        value: &Mlp,
        vp: &[f32],
        r: &RewardInputs,
        rw: RewardWeights,
    ) -> Result<RewardOut, ShapeError> {
        let (k, n) = (dnet.k, r.eps.len());
        let (din, vin) = (dnet.inp(), value.inp());
        let obs = vin.saturating_sub(1 + k);
        let sizes_ok = r.disc_x.len() == n * din
            && r.code.len() == n * k
            && r.obs.len() == n * obs
            && r.next_obs.len() == n * obs;
        if !sizes_ok {
            return Err(ShapeError::new(
                "reward pass: rollout arrays of unequal lengths".into(),
            ));
        }
        dnet.stack_heads_into(dp, &mut self.wh, &mut self.bh);
        self.blocks.resize_with(team.threads(), Block::default);
        let threads = self.blocks.len();
        let (wh, bh) = (&self.wh, &self.bh);
        team.each(&mut self.blocks, |t, b| {
            b.rows = block(n, threads, t);
            let (j0, j1) = b.rows;
            let w = j1 - j0;
            b.x.reset(din, w);
            b.vx.reset(vin, 2 * w);
            for (col, j) in (j0..j1).enumerate() {
                b.x.set(col, 0, &r.disc_x[j * din..(j + 1) * din]);
                for (c, o) in [(col, r.obs), (col + w, r.next_obs)] {
                    b.vx.set(c, 0, &o[j * obs..(j + 1) * obs]);
                    b.vx.set(c, obs, &r.eps[j..j + 1]);
                    b.vx.set(c, obs + 1, &r.code[j * k..(j + 1) * k]);
                }
            }
            dnet.body.forward(dp, b.x.mat(), &mut b.acts)?;
            let hid = dnet.body.out();
            let h = b.acts.h.last().map(|h| &h[..]).unwrap_or_default();
            b.heads.resize((k + 2) * w, 0.0);
            layer_forward(
                Mat::rows(wh, k + 2, hid),
                bh,
                Mat::rows(h, hid, w),
                &mut b.heads,
                Act::Identity,
            )?;
            value.forward(vp, b.vx.mat(), &mut b.vacts)?;
            let v = b.vacts.h.last().map_or(&[][..], |h| &h[..]);
            b.out.values.clear();
            b.out.values.extend_from_slice(&v[..w]);
            b.out.next_values.clear();
            b.out.next_values.extend_from_slice(&v[w..2 * w]);
            rewards(
                &b.heads,
                w,
                k,
                &r.code[j0 * k..j1 * k],
                &r.eps[j0..j1],
                rw,
                &mut b.out,
            );
            Ok(())
        })?;
        let mut out = RewardOut::default();
        for b in &self.blocks {
            out.reward.extend_from_slice(&b.out.reward);
            out.disc_term.extend_from_slice(&b.out.disc_term);
            out.values.extend_from_slice(&b.out.values);
            out.next_values.extend_from_slice(&b.out.next_values);
        }
        Ok(out)
    }
}

/// Eq. 9's policy terms per column of the heads' outputs `[K + 2][w]`.
fn rewards(
    heads: &[f32],
    w: usize,
    k: usize,
    code: &[f32],
    eps: &[f32],
    rw: RewardWeights,
    out: &mut RewardOut,
) {
    out.reward.clear();
    out.disc_term.clear();
    for j in 0..w {
        let x = heads[j] / rw.disc_temperature as f32;
        let dterm = if rw.disc_logit { x } else { math::softplus(x) };
        let mut r = dterm * rw.disc as f32;
        // `sum_k c_k log Q_c(k | s, a)`, computed once for the gate and the information term.
        let log_qc = if rw.disc_qc_gate || rw.qc != 0.0 {
            let q = |i: usize| heads[(1 + i) * w + j];
            let m = (0..k).fold(f32::NEG_INFINITY, |a, i| a.max(q(i)));
            let lse = m + (0..k).map(|i| math::exp(q(i) - m)).sum::<f32>().ln();
            (0..k).map(|i| code[j * k + i] * (q(i) - lse)).sum::<f32>()
        } else {
            0.0
        };
        if rw.disc_qc_gate {
            r *= math::exp(log_qc);
        }
        if rw.qc != 0.0 {
            let mut lq = log_qc;
            lq += rw.qc_offset as f32;
            if let Some(v) = rw.qc_floor {
                lq = lq.max(v as f32);
            }
            r += lq * rw.qc as f32;
        }
        if rw.qeps != 0.0 {
            r -= (heads[(k + 1) * w + j] - eps[j]).abs() * rw.qeps as f32;
        }
        out.reward.push(r);
        out.disc_term.push(dterm);
    }
}
