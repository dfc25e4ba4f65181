//! The training loop (Algorithm 1), one for all seven methods, as a [`Trainer`] whose
//! methods are the algorithm's stages:
//!
//! | stage | method | file |
//! |---|---|---|
//! | roll out `run.rollout_steps` transitions under (c, eps) | [`Trainer::collect`] | `stages.rs` |
//! | D, Q_c, Q_eps (and p(c) through RIM) take `disc.steps` steps on Eq. 9's D/Q side | [`Trainer::update_discriminator`] | `stages.rs` |
//! | policy reward with the updated heads (Eqs. 1, 3, 5, 9) | [`Trainer::policy_rewards`] | `stages.rs` |
//! | GAE, PPO on policy and value, p(c) through Gumbel-softmax | [`Trainer::update_policy`] | `stages.rs` |
//! | the paper's evaluation (NMI, ENT, normalised reward) | [`Trainer::evaluate`] | `stages.rs` |
//! | `metrics.csv`, the logs above the loop ([`RecordSink`]), progress; checkpoints | [`Trainer::record`], [`Trainer::checkpoint`] | this file |
//!
//! [`Trainer::new`] (`setup.rs`) builds a run's state from its configuration, or from
//! its latest checkpoint on `--resume` (a fresh run first clones the labeled
//! demonstrations into the policy when `ppo.bc_steps` asks, `bc.rs`);
//! [`Trainer::train`] runs the iterations and [`Trainer::finish`] the final evaluation
//! and `summary.json`. The weighted objective itself lives in
//! [`crate::objective::combined`].

pub(crate) mod bc;
pub mod checkpoint;
pub(crate) mod data;
mod fused_stages;
pub mod nets;
pub mod optim;
pub mod ppo;
mod records;
pub(crate) mod setup;
mod stages;

pub use data::TrainInputError;
pub use data::{
    CodeReweight, Dims, ExpertData, ObsNorm, Rollout, demo_spec, load_or_generate_demos,
};
pub use ess_actor::actor_seed;
pub use ess_proto::config::Backend;
pub use records::{
    CSV_HEADER, EncoderAccuracy, IterationLog, OpenSink, PhaseSeconds, Progress, RecordSink,
    ResumedAt, Summary, write_atomic,
};
pub use setup::Nets;
pub use stages::Rewards;

use crate::eval::Reference;
use anyhow::{Context, Result, anyhow};
use ess_actor::{LatentSpec, PolicyWeights, RolloutSource};
use ess_envs::{Demos, EnvSpec};
use ess_proto::CheckedConfig;
use ess_proto::config::Pipeline;
use rand_chacha::ChaCha8Rng;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Everything `run` produced.
pub struct RunOutput {
    /// The summary (also written to `summary.json`).
    pub summary: Summary,
}

/// The loop's own state: what a checkpoint saves besides the networks.
pub struct LoopState {
    /// Environment steps so far.
    pub env_steps: usize,
    /// Iterations done.
    pub iters_done: usize,
    /// Summed per-phase seconds.
    pub phases: PhaseSeconds,
    /// Evaluation curve `(env steps, NMI, ENT, normalised reward)`.
    pub curve: Vec<crate::eval::report::CurvePoint>,
    /// The last iteration's row, written once the next one ran (so the last row can
    /// take the final evaluation's numbers).
    pub pending: Option<IterationLog>,
    /// The learner's random stream (minibatch draws).
    pub rng: ChaCha8Rng,
    /// Q_c's running estimate of the demos' mode marginal (`method.disc_code_reweight`).
    pub qc_marginal: Vec<f64>,
    /// PPO's reward scaler.
    pub scaler: crate::train::ppo::RewardScaler,
    /// Training seconds before this process (a resumed run).
    pub wall_before: f64,
    /// The iteration of the last checkpoint written or loaded.
    pub last_saved: Option<usize>,
}

/// With `run.pipeline = "overlap"`: the next iteration's rollout, collected while this
/// iteration updated, and what a checkpoint needs to collect it again.
pub struct Prefetch {
    rollout: Rollout,
    /// The actors' states before it was collected.
    before: Vec<crate::train::checkpoint::SavedWorker>,
    /// The weights it was collected under.
    weights: Arc<PolicyWeights>,
}

/// One run's state; each method is one stage of Algorithm 1 (see the module docs).
pub struct Trainer<'c> {
    cfg: &'c CheckedConfig,
    out: PathBuf,
    spec: EnvSpec,
    dims: Dims,
    demos: Demos,
    norm: ObsNorm,
    expert: ExpertData,
    reference: Reference,
    latent: LatentSpec,
    nets: Nets,
    /// The fused backend (`learner.backend = "fused"` on a configuration it covers);
    /// `None`: tch runs the update.
    fused: Option<crate::fused::Fused>,
    /// `None` only while a rollout is collected beside an update (`run.pipeline`).
    actors: Option<Box<dyn RolloutSource>>,
    /// The overlap pipeline's rollout for the next iteration.
    prefetch: Option<Prefetch>,
    /// The weights the first collection of a resumed overlapped run runs under.
    resume_weights: Option<Arc<PolicyWeights>>,
    eval_env: Box<dyn ess_envs::Env>,
    st: LoopState,
    csv: BufWriter<std::fs::File>,
    /// The logs above the loop (run log, TensorBoard: `crate::logs`).
    sink: Box<dyn RecordSink>,
    started: Instant,
    /// When [`Trainer::train`] started its first iteration in this process.
    train_started: Instant,
}

/// Trains with `cfg`, writing into `out` (`metrics.csv`, checkpoints, `summary.json`,
/// and the logs `logs` opens, e.g. `crate::logs::open`); stops early (and still writes everything)
/// when `shutdown` is set: the current iteration finishes, a checkpoint is saved, the
/// final evaluation runs and `summary.json` says `"interrupted": true`.
pub fn run(
    cfg: &CheckedConfig,
    out: &Path,
    logs: OpenSink,
    progress: &mut dyn Progress,
    shutdown: &AtomicBool,
) -> Result<RunOutput> {
    let mut t = Trainer::new(cfg, out, logs, progress, false)?;
    let interrupted = t.train(progress, shutdown)?;
    t.finish(progress, interrupted)
}

/// The configuration a run in `out` was started with (its `config.toml`).
pub fn run_config(out: &Path) -> Result<CheckedConfig> {
    let p = out.join("config.toml");
    let text = std::fs::read_to_string(&p).with_context(|| {
        format!(
            "reading {} (is {} the output directory of an `ess train` run?)",
            p.display(),
            out.display()
        )
    })?;
    let mut b = ess_proto::config::ConfigBuilder::new();
    b.merge_toml(&p.display().to_string(), &text)?;
    Ok(b.build()?)
}

/// Continues the run in `out` from its latest checkpoint
/// ([`crate::train::checkpoint`]) with the configuration it was started with, appending to its
/// `metrics.csv`. The continued run is bit-identical to one never stopped, with actor
/// threads or processes (unless the checkpoint holds no actor states, see
/// [`crate::train::checkpoint::TrainState::actors`]).
pub fn resume(
    out: &Path,
    logs: OpenSink,
    progress: &mut dyn Progress,
    shutdown: &AtomicBool,
) -> Result<RunOutput> {
    resume_on(out, None, logs, progress, shutdown)
}

/// [`resume`], the update on `backend` when given (a checkpoint of either backend
/// resumes on the other: both keep their state in the same tensors).
pub fn resume_on(
    out: &Path,
    backend: Option<ess_proto::config::Backend>,
    logs: OpenSink,
    progress: &mut dyn Progress,
    shutdown: &AtomicBool,
) -> Result<RunOutput> {
    let cfg = run_config(out)?;
    let cfg = match backend {
        Some(b) => cfg.with_backend(b),
        None => cfg,
    };
    let mut t = Trainer::new(&cfg, out, logs, progress, true)?;
    let interrupted = t.train(progress, shutdown)?;
    t.finish(progress, interrupted)
}

/// Seed of libtorch's random stream for iteration `it`: re-seeded every iteration, so a
/// resumed run draws what the uninterrupted one drew.
fn torch_seed(seed: u64, it: usize) -> i64 {
    seed.wrapping_mul(0x2545_F491_4F6C_DD1D)
        .wrapping_add(it as u64) as i64
}

impl Trainer<'_> {
    /// Runs the iterations left (all of them, or those after the checkpoint resumed
    /// from); `Ok(true)` when `shutdown` stopped it early.
    pub fn train(&mut self, progress: &mut dyn Progress, shutdown: &AtomicBool) -> Result<bool> {
        progress.message("training");
        if self.fused.is_some() {
            // The fused backend's threads do the update; libtorch keeps only the small
            // operations around it, on this thread. With more, its OpenMP workers spin
            // after each of those for a while and take the cores the fused threads
            // need (16% of a Reacher run's samples were libgomp's spin-wait;
            // bench/learner.md).
            tch::set_num_threads(1);
        }
        self.train_started = Instant::now();
        for it in self.st.iters_done + 1..=self.cfg.run.iterations {
            if shutdown.load(Ordering::Relaxed) {
                return Ok(true);
            }
            let mut log = self.iteration(it)?;
            let run = &self.cfg.run;
            if run.eval_every > 0 && it.is_multiple_of(run.eval_every) && it != run.iterations {
                let (r, episodes) =
                    self.evaluate(it, run.eval_episodes_periodic, run.seed ^ 0xE7A1)?;
                self.sink
                    .episodes(it, false, &episodes, self.eval_env.as_mut())?;
                self.sink.evaluation(self.st.env_steps, &r);
                self.st
                    .curve
                    .push((self.st.env_steps, r.nmi, r.ent, r.normalized_reward));
                log.nmi = Some(r.nmi);
                log.ent = Some(r.ent);
                log.normalized_reward = Some(r.normalized_reward);
                log.normalized_reward_per_code = r.normalized_reward_per_code;
            }
            self.record(log, progress)?;
            if run.checkpoint_every > 0 && it.is_multiple_of(run.checkpoint_every) {
                self.checkpoint()?;
            }
        }
        Ok(false)
    }

    /// One iteration of Algorithm 1: collect, D/Q updates, rewards, PPO and p(c). In
    /// the overlap pipeline the rollout was collected during the previous iteration,
    /// and the next one is collected during this one's update.
    pub fn iteration(&mut self, it: usize) -> Result<IterationLog> {
        tch::manual_seed(torch_seed(self.cfg.run.seed, it));
        let mut log = IterationLog {
            iteration: it,
            ..Default::default()
        };
        let t0 = Instant::now();
        let rollout = match self.prefetch.take() {
            Some(p) => p.rollout,
            None => self.collect(it)?,
        };
        log.rollout_s = t0.elapsed().as_secs_f64();
        let run = &self.cfg.run;
        if run.pipeline == Pipeline::Overlap && it < run.iterations {
            self.update_while_collecting(it, &rollout, &mut log)?;
        } else {
            self.update(it, &rollout, &mut log)?;
        }
        self.st.phases.add(&log);
        self.st.env_steps += rollout.len();
        self.st.iters_done = it;
        log.env_steps = self.st.env_steps;
        log.wall_s = self.wall_s();
        Ok(log)
    }

    /// [`Trainer::update`] on `rollout` while the actors, on a thread of their own,
    /// collect the next iteration's rollout under the current weights (version `it`).
    fn update_while_collecting(
        &mut self,
        it: usize,
        rollout: &Rollout,
        log: &mut IterationLog,
    ) -> Result<()> {
        let weights = Arc::new(self.weights(it as u64)?);
        let mut actors = self.actors.take().context("the actors are collecting")?;
        let before = checkpoint::actor_states(actors.as_mut());
        let steps = self.cfg.run.rollout_steps;
        let (updated, joined) = std::thread::scope(|s| {
            let w = weights.clone();
            let collector = s.spawn(move || {
                let chunks = data::gather(actors.as_mut(), w, steps);
                (actors, chunks)
            });
            let updated = self.update(it, rollout, log);
            (updated, collector.join())
        });
        let (actors, chunks) = joined.map_err(|_| anyhow!("the rollout thread panicked"))?;
        self.actors = Some(actors);
        updated?;
        self.prefetch = Some(Prefetch {
            rollout: Rollout::new(chunks?, &self.norm, self.dims),
            before,
            weights,
        });
        Ok(())
    }

    /// The actors (not while they collect beside an update).
    fn actors(&mut self) -> Result<&mut dyn RolloutSource> {
        match self.actors.as_deref_mut() {
            Some(a) => Ok(a),
            None => Err(anyhow!("the actors are collecting")),
        }
    }

    /// Training seconds so far, those of earlier processes of a resumed run included.
    fn wall_s(&self) -> f64 {
        self.st.wall_before + self.train_started.elapsed().as_secs_f64()
    }

    /// Reports an iteration (progress, run log) and writes the row before it to
    /// `metrics.csv`.
    pub fn record(&mut self, log: IterationLog, progress: &mut dyn Progress) -> Result<()> {
        progress.iteration(&log);
        self.sink.iteration(&log)?;
        if let Some(done) = self.st.pending.replace(log) {
            records::write_csv_row(&mut self.csv, &done)?;
            // Row by row, so that a reader of the file (the dashboard's curves, `tail`)
            // sees each iteration when it ends, not every ~40 when the buffer fills.
            self.csv.flush()?;
            self.sink.row(&done);
        }
        if let Some(note) = self.sink.note() {
            progress.message(&note);
        }
        Ok(())
    }

    /// Saves everything a resume needs after the iterations done (see
    /// [`crate::train::checkpoint`]).
    pub fn checkpoint(&mut self) -> Result<()> {
        self.csv.flush()?;
        let it = self.st.iters_done;
        let mut state = crate::train::checkpoint::TrainState {
            format: crate::train::checkpoint::FORMAT,
            iteration: it,
            env_steps: self.st.env_steps,
            wall_s: self.wall_s(),
            phases: self.st.phases.clone(),
            curve: self.st.curve.clone(),
            pending: self.st.pending.clone(),
            rng: crate::train::checkpoint::RngState::of(&self.st.rng),
            qc_marginal: self.st.qc_marginal.clone(),
            scaler: self.st.scaler.clone(),
            adam_steps: Default::default(),
            actors: Vec::new(),
            behaviour: None,
        };
        // With a prefetched rollout the actors are saved as they were before it, with
        // its weights, so a resume collects it again.
        match &self.prefetch {
            Some(p) => {
                state.actors = p.before.clone();
                let w = ess_actor::shm::weights_msg(&p.weights, &self.latent, "");
                state.behaviour = Some(w);
            }
            None => state.actors = checkpoint::actor_states(self.actors()?),
        }
        let n = &self.nets;
        crate::train::checkpoint::save(
            &self.out.join("checkpoints"),
            [&n.vs, &n.prior_vs, &n.dvs],
            [&n.ppo.opt, &n.ppo.prior_opt, &n.dopt],
            &mut state,
        )?;
        self.st.last_saved = Some(it);
        Ok(())
    }

    /// The last checkpoint (unless the last iteration has one), the final evaluation,
    /// the figures and `summary.json`.
    pub fn finish(mut self, progress: &mut dyn Progress, interrupted: bool) -> Result<RunOutput> {
        let wall = self.wall_s();
        if self.st.last_saved != Some(self.st.iters_done) {
            self.checkpoint()?;
        }
        progress.message("final evaluation");
        let done = self.st.iters_done;
        let (result, episodes) =
            self.evaluate(done, self.cfg.run.eval_episodes, self.cfg.run.seed ^ 0xF1AA)?;
        self.sink
            .episodes(done, true, &episodes, self.eval_env.as_mut())?;
        // The final evaluation completes the last iteration's row (no iteration ran: a
        // row of iteration 0 for the untrained policy).
        let mut last = self.st.pending.take().unwrap_or_else(|| IterationLog {
            wall_s: wall,
            prior: records::prior_string(&self.nets.ppo.prior_probs()),
            ..Default::default()
        });
        last.nmi = Some(result.nmi);
        last.ent = Some(result.ent);
        last.normalized_reward = Some(result.normalized_reward);
        last.normalized_reward_per_code = result.normalized_reward_per_code.clone();
        records::write_csv_row(&mut self.csv, &last)?;
        self.csv.flush()?;
        self.sink.row(&last);
        self.sink.evaluation(self.st.env_steps, &result);
        self.sink.iteration(&last)?;
        let (cfg, k) = (self.cfg, self.dims.codes);
        if self.spec.name == "traj2d" {
            let png = self.out.join("trajectories.png");
            crate::eval::report::plot_traj2d(&png, &self.demos, &episodes, &cfg.method.name, k)?;
        }
        let steps = self.st.env_steps;
        self.st
            .curve
            .push((steps, result.nmi, result.ent, result.normalized_reward));
        let curves = self.out.join("curves.png");
        crate::eval::report::plot_curves(&curves, &cfg.method.name, &self.st.curve)?;
        for png in ["trajectories.png", "curves.png"] {
            self.sink.figure(steps, &self.out.join(png));
        }
        if let Some(note) = self.sink.note() {
            progress.message(&note);
        }
        let prior = self.nets.ppo.prior_probs();
        let demo_mode_freq = self.expert.mode_frequencies(k);
        let summary = Summary {
            method: cfg.method.name.clone(),
            env: cfg.env.name.clone(),
            seed: cfg.run.seed,
            nmi: result.nmi,
            ent: result.ent,
            normalized_reward: result.normalized_reward,
            env_steps: steps,
            iterations: done,
            wall_seconds: wall,
            total_seconds: self.started.elapsed().as_secs_f64(),
            env_steps_per_second: steps as f64 / wall.max(1e-9),
            seconds_per_iteration: self.st.phases.mean(done),
            prior: prior.clone(),
            prior_tv: records::total_variation(&prior, &demo_mode_freq),
            demo_mode_freq,
            classifier_accuracy: self.reference.classifier_accuracy,
            encoder_accuracy: self.expert.encoder_accuracy(&self.nets.disc, k),
            eval: result,
            interrupted,
        };
        // The logs are complete before `summary.json` says the run is.
        let Self { sink, out, .. } = self;
        sink.finish()?;
        let json = serde_json::to_string_pretty(&summary)?;
        write_atomic(&out.join("summary.json"), json.as_bytes())?;
        Ok(RunOutput { summary })
    }
}

#[cfg(test)]
mod tests;
