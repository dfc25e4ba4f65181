//! What a run writes about itself: one [`IterationLog`] per iteration (`metrics.csv`,
//! the run log, the progress stream) and the [`Summary`] (`summary.json`); and the two
//! traits through which the loop hands them to what sits above it, [`Progress`] (the
//! CLI's printer) and [`RecordSink`] (the run log and TensorBoard, `crate::logs`), so
//! that the training core knows neither.

use crate::eval::EvalResult;
use anyhow::{Context, Result};
use ess_actor::EvalEpisode;
use ess_envs::Env;
use ess_proto::{CheckedConfig, Chunk, pb};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// What a caller sees of progress (the CLI draws a bar or prints lines).
pub trait Progress {
    /// Called after each iteration.
    fn iteration(&mut self, it: &IterationLog);
    /// Free-form status message (set-up phases).
    fn message(&mut self, msg: &str);
}

/// Where a resumed run continues: what the logs reopen their files at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ResumedAt {
    /// The checkpoint's iteration (records after it are dropped).
    pub iteration: usize,
    /// Env steps at that iteration.
    pub env_steps: usize,
}

/// The logs a run keeps beside `metrics.csv` (`crate::logs`: the MCAP run log and
/// TensorBoard's event file). The loop hands them its records in this order per
/// iteration: the evaluation's [`episodes`](RecordSink::episodes) and
/// [`evaluation`](RecordSink::evaluation) (when one ran), the
/// [`iteration`](RecordSink::iteration), then the [`row`](RecordSink::row) of the
/// iteration before (a row is complete once the next iteration ran).
pub trait RecordSink {
    /// An iteration as soon as it ran.
    fn iteration(&mut self, log: &IterationLog) -> Result<()>;
    /// A complete `metrics.csv` row.
    fn row(&mut self, log: &IterationLog);
    /// Iteration `iteration`'s rollout `chunks` with the policy reward of each of
    /// their steps, in order (a sink keeps a sample, or nothing).
    fn rollout(&mut self, iteration: usize, chunks: &[Chunk], rewards: &[f32]) -> Result<()>;
    /// An evaluation's result, at `env_steps`.
    fn evaluation(&mut self, env_steps: usize, result: &EvalResult);
    /// An evaluation's episodes, of the policy of `iteration`; `env` is the env that
    /// ran them (a sink that draws the robot replays their states on it).
    fn episodes(
        &mut self,
        iteration: usize,
        final_eval: bool,
        episodes: &[EvalEpisode],
        env: &mut dyn Env,
    ) -> Result<()>;
    /// A figure the run wrote (`curves.png`, `trajectories.png`), at `env_steps`.
    fn figure(&mut self, env_steps: usize, path: &Path);
    /// A failure the user should hear of once; training goes on without that log.
    fn note(&mut self) -> Option<String>;
    /// Completes the files (before `summary.json` says the run is complete).
    fn finish(self: Box<Self>) -> Result<()>;
}

/// Opens a run's [`RecordSink`] in its directory: a fresh run's (`None`) or a resumed
/// one's after its checkpoint.
pub type OpenSink =
    fn(cfg: &CheckedConfig, out: &Path, resumed: Option<ResumedAt>) -> Result<Box<dyn RecordSink>>;

/// One row of `metrics.csv`: one per iteration, in order. The last iteration's row
/// carries the final evaluation's `nmi`, `ent` and `normalized_reward` (the periodic
/// evaluation is skipped there); a run stopped before its first iteration writes a
/// single row of iteration 0 with the final evaluation of the untrained policy.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct IterationLog {
    /// Iteration index (1-based).
    pub iteration: usize,
    /// Environment steps so far.
    pub env_steps: usize,
    /// Wall seconds since training start.
    pub wall_s: f64,
    /// Seconds of this iteration's rollout.
    pub rollout_s: f64,
    /// Seconds of this iteration's D/Q updates.
    pub disc_s: f64,
    /// Seconds of this iteration's reward, GAE and PPO.
    pub ppo_s: f64,
    /// `losses/disc_bce`.
    pub disc_bce: f64,
    /// D's accuracy on expert samples of the last batch.
    pub d_acc_expert: f64,
    /// D's accuracy on policy samples of the last batch.
    pub d_acc_policy: f64,
    /// `losses/qc_labeled`.
    pub qc_labeled: f64,
    /// `losses/qc_generated`.
    pub qc_generated: f64,
    /// `losses/qeps`.
    pub qeps: f64,
    /// `losses/rim_cond_entropy`.
    pub rim_entropy: f64,
    /// `losses/rim_marginal_kl`.
    pub rim_kl: f64,
    /// `losses/contrastive`.
    pub contrastive: f64,
    /// Mean policy reward.
    pub reward_mean: f64,
    /// PPO statistics.
    pub policy_loss: f64,
    /// Value loss.
    pub value_loss: f64,
    /// Policy entropy.
    pub entropy: f64,
    /// Approximate KL of the update.
    pub approx_kl: f64,
    /// p(c) as `p0;p1;...`.
    pub prior: String,
    /// NMI if evaluated at this iteration.
    pub nmi: Option<f64>,
    /// ENT if evaluated.
    pub ent: Option<f64>,
    /// Normalised task reward if evaluated.
    pub normalized_reward: Option<f64>,
    /// Normalised task reward of each code if evaluated (empty if not; `r0;r1;...` in
    /// the CSV): the curve per code that `ess report` prints.
    #[serde(default)]
    pub normalized_reward_per_code: Vec<f64>,
}

impl IterationLog {
    /// The metrics of `log` as `ess.v1.IterationMetrics`: what the progress stream, the
    /// run log's `/metrics` topic and `WatchJob` carry (the one mapping from
    /// [`IterationLog`]).
    pub fn metrics(&self) -> pb::IterationMetrics {
        let log = self;
        pb::IterationMetrics {
            iteration: u32::try_from(log.iteration).unwrap_or(u32::MAX),
            env_steps: log.env_steps as u64,
            wall_s: log.wall_s,
            rollout_s: log.rollout_s,
            disc_s: log.disc_s,
            ppo_s: log.ppo_s,
            disc_bce: log.disc_bce,
            d_acc_expert: log.d_acc_expert,
            d_acc_policy: log.d_acc_policy,
            qc_labeled: log.qc_labeled,
            qc_generated: log.qc_generated,
            qeps: log.qeps,
            rim_entropy: log.rim_entropy,
            rim_kl: log.rim_kl,
            contrastive: log.contrastive,
            reward_mean: log.reward_mean,
            policy_loss: log.policy_loss,
            value_loss: log.value_loss,
            entropy: log.entropy,
            approx_kl: log.approx_kl,
            prior: log
                .prior
                .split(';')
                .filter_map(|p| p.trim().parse().ok())
                .collect(),
            nmi: log.nmi,
            ent: log.ent,
            normalized_reward: log.normalized_reward,
        }
    }
}

/// What `summary.json` holds.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Method (preset) name.
    pub method: String,
    /// Environment.
    pub env: String,
    /// Training seed.
    pub seed: u64,
    /// Final NMI.
    pub nmi: f64,
    /// Final ENT.
    pub ent: f64,
    /// Final normalised task reward.
    pub normalized_reward: f64,
    /// Environment steps of training.
    pub env_steps: usize,
    /// Iterations run.
    pub iterations: usize,
    /// Wall seconds of training (set-up and final evaluation excluded).
    pub wall_seconds: f64,
    /// Wall seconds including set-up and evaluation.
    pub total_seconds: f64,
    /// End-to-end training env steps per second.
    pub env_steps_per_second: f64,
    /// Mean seconds per iteration of rollout, D/Q updates and PPO.
    pub seconds_per_iteration: PhaseSeconds,
    /// Learned p(c).
    pub prior: Vec<f32>,
    /// The unlabeled demonstrations' true mode frequencies (empty when unknown).
    pub demo_mode_freq: Vec<f64>,
    /// Total variation distance between p(c) and `demo_mode_freq` (Sec. 3.2: p(c)
    /// should learn the demonstrations' imbalance); null when the modes are unknown.
    pub prior_tv: Option<f64>,
    /// Behaviour classifier's held-out accuracy on expert data.
    pub classifier_accuracy: f64,
    /// Q_c's accuracy on the unlabeled expert data against the true modes (paper
    /// Fig. 6): how well the few labels taught the encoder.
    pub encoder_accuracy: EncoderAccuracy,
    /// Final evaluation in full.
    pub eval: crate::eval::EvalResult,
    /// Whether the run was stopped early (Ctrl-C).
    pub interrupted: bool,
}

/// Total variation distance `0.5 * sum |p - q|` between two distributions of the same
/// length; `None` when `q` is empty or the lengths differ.
pub fn total_variation(p: &[f32], q: &[f64]) -> Option<f64> {
    (!q.is_empty() && p.len() == q.len()).then(|| {
        0.5 * p
            .iter()
            .zip(q)
            .map(|(&a, b)| (f64::from(a) - b).abs())
            .sum::<f64>()
    })
}

/// Accuracy of `argmax Q_c(s, a)` against the true mode on expert data.
#[derive(Debug, Clone, Default, Serialize)]
pub struct EncoderAccuracy {
    /// Over all steps (dominated by the majority modes).
    pub overall: f64,
    /// Mean of the per-mode recalls (every mode counts the same).
    pub balanced: f64,
    /// Recall of each mode (NaN-free: a mode without steps reports 0).
    pub per_mode: Vec<f64>,
}

impl EncoderAccuracy {
    /// From per-mode hit and step counts.
    pub fn from_counts(hits: &[u64], counts: &[u64]) -> Self {
        let per_mode: Vec<f64> = hits
            .iter()
            .zip(counts)
            .map(|(&h, &c)| if c == 0 { 0.0 } else { h as f64 / c as f64 })
            .collect();
        let total: u64 = counts.iter().sum();
        Self {
            overall: hits.iter().sum::<u64>() as f64 / total.max(1) as f64,
            balanced: per_mode.iter().sum::<f64>() / per_mode.len().max(1) as f64,
            per_mode,
        }
    }
}

/// Per-phase seconds.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct PhaseSeconds {
    /// Rollout.
    pub rollout: f64,
    /// D/Q updates.
    pub disc: f64,
    /// Reward, GAE and PPO.
    pub ppo: f64,
}

impl PhaseSeconds {
    /// Adds one iteration's phase times.
    pub fn add(&mut self, log: &IterationLog) {
        self.rollout += log.rollout_s;
        self.disc += log.disc_s;
        self.ppo += log.ppo_s;
    }

    /// The mean over `n` iterations.
    pub fn mean(&self, n: usize) -> Self {
        let n = n.max(1) as f64;
        Self {
            rollout: self.rollout / n,
            disc: self.disc / n,
            ppo: self.ppo / n,
        }
    }
}

/// p(c) as the CSV writes it, `p0;p1;...`.
pub fn prior_string(p: &[f32]) -> String {
    p.iter()
        .map(|p| format!("{p:.4}"))
        .collect::<Vec<_>>()
        .join(";")
}

/// The header of `metrics.csv`.
pub const CSV_HEADER: &str = "iteration,env_steps,wall_s,rollout_s,disc_s,ppo_s,disc_bce,d_acc_expert,d_acc_policy,qc_labeled,qc_generated,qeps,rim_entropy,rim_kl,contrastive,reward_mean,policy_loss,value_loss,entropy,approx_kl,prior,nmi,ent,normalized_reward,normalized_reward_per_code";

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.6}")).unwrap_or_default()
}

/// Appends `l` as one row of `metrics.csv`.
pub fn write_csv_row(w: &mut impl Write, l: &IterationLog) -> Result<()> {
    writeln!(
        w,
        "{},{},{:.3},{:.4},{:.4},{:.4},{:.6},{:.4},{:.4},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{},{}",
        l.iteration,
        l.env_steps,
        l.wall_s,
        l.rollout_s,
        l.disc_s,
        l.ppo_s,
        l.disc_bce,
        l.d_acc_expert,
        l.d_acc_policy,
        l.qc_labeled,
        l.qc_generated,
        l.qeps,
        l.rim_entropy,
        l.rim_kl,
        l.contrastive,
        l.reward_mean,
        l.policy_loss,
        l.value_loss,
        l.entropy,
        l.approx_kl,
        l.prior,
        opt(l.nmi),
        opt(l.ent),
        opt(l.normalized_reward),
        l.normalized_reward_per_code
            .iter()
            .map(|r| format!("{r:.6}"))
            .collect::<Vec<_>>()
            .join(";")
    )?;
    Ok(())
}

/// Keeps the header and the rows of iterations before `next` of `metrics.csv` (rows
/// written after the checkpoint that is resumed from are dropped).
pub fn truncate_metrics(path: &Path, next: usize) -> Result<()> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading {} to resume", path.display()))?;
    let mut kept = String::new();
    for (i, line) in text.lines().enumerate() {
        let keep = i == 0
            || line
                .split(',')
                .next()
                .and_then(|f| f.parse::<usize>().ok())
                .is_some_and(|it| it < next);
        if keep {
            kept.push_str(line);
            kept.push('\n');
        }
    }
    write_atomic(path, kept.as_bytes())
}

/// Writes `bytes` to `path` atomically ([`ess_envs::write_atomic`]: a synced temporary
/// file beside it, renamed over it), with the failing path in the error.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    ess_envs::write_atomic(path, bytes)
        .map_err(|(p, e)| anyhow::Error::new(e).context(format!("writing {}", p.display())))
}

#[cfg(test)]
mod tests {
    use super::total_variation;

    #[test]
    fn total_variation_is_half_the_l1_distance() {
        let tv = total_variation(&[0.25, 0.25, 0.25, 0.25], &[0.495, 0.495, 0.005, 0.005]);
        assert!((tv.unwrap() - 0.49).abs() < 1e-6, "{tv:?}");
        assert_eq!(total_variation(&[0.5, 0.5], &[]), None);
        assert_eq!(total_variation(&[0.5, 0.5], &[1.0, 0.0, 0.0]), None);
    }
}
