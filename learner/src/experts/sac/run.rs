//! The SAC training loop of `ess experts train --algo sac`: one env step, then
//! `updates_per_step` gradient steps, a CSV row every `log_every` steps and a save every
//! ten rows. [`SacRun::new`] builds a run (fresh or resumed), [`SacRun::env_step`] acts
//! and records one transition, [`SacRun::learn`] updates, [`train_expert_sac`] drives them.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Result, bail};
use ess_envs::{Env, EnvSpec, ExpertPolicy, make_plain_env};
use ess_proto::config::SacConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::nn::{self, OptimizerConfig};

use super::replay::{Replay, gather_norm};
use super::{Sac, SacInputError, StepStats, load_state, open_replay, save, update};
use crate::experts::{
    ExpertIteration, ExpertTrainConfig, RunningStats, csv_path, last_csv_iteration, open_csv,
    replay_path, state_path,
};
use crate::train::nets::tensor_to_vec;

/// Returns of the episodes a run finished.
#[derive(Default)]
struct Episodes {
    /// Return and length of the episode under way.
    ret: f64,
    len: usize,
    /// `(return, length)` of the episodes finished since the last CSV row.
    since_row: Vec<(f64, usize)>,
    /// The last 100 returns (the expert file's `mean_return`).
    recent: Vec<f64>,
}

impl Episodes {
    fn end(&mut self) {
        self.since_row.push((self.ret, self.len));
        self.recent.push(self.ret);
        let keep = self.recent.len().saturating_sub(100);
        self.recent.drain(..keep);
        (self.ret, self.len) = (0.0, 0);
    }
}

/// One SAC run's state.
struct SacRun<'a> {
    cfg: &'a ExpertTrainConfig,
    sc: &'a SacConfig,
    env: Box<dyn Env>,
    spec: EnvSpec,
    /// Observation entries the networks read (`sac.obs_prefix`).
    p: usize,
    sac: Sac,
    opts: [nn::Optimizer; 3],
    target_entropy: f64,
    stats: RunningStats,
    replay: Replay,
    rng: ChaCha8Rng,
    env_steps: u64,
    /// Episode seeds continue across a resume (they count from the resumed step).
    episode_seed: u64,
    obs: Vec<f32>,
    next: Vec<f32>,
    act: Vec<f32>,
    rewards: Vec<f32>,
    episodes: Episodes,
}

impl<'a> SacRun<'a> {
    /// A fresh run of `cfg`, or (`cfg.resume`) the one in `cfg.out` continued: its
    /// networks, normaliser and replay (when saved), the env reset.
    fn new(cfg: &'a ExpertTrainConfig, sc: &'a SacConfig) -> Result<Self> {
        if cfg.init_from.is_some() {
            bail!(SacInputError::InitFrom);
        }
        let env = make_plain_env(&cfg.env, cfg.n_modes)?;
        let spec = env.spec().clone();
        if cfg.mode >= spec.n_modes {
            bail!(ess_envs::EnvError::ModeOutOfRange {
                mode: cfg.mode,
                n_modes: spec.n_modes
            });
        }
        let (od, ad) = (spec.obs_dim, spec.act_dim);
        let p = crate::train::nets::obs_columns(sc.obs_prefix, od).ok_or_else(|| {
            SacInputError::ObsPrefix {
                prefix: sc.obs_prefix,
                env: spec.name.clone(),
                obs_dim: od,
            }
        })?;
        tch::set_num_threads(cfg.torch_threads.max(1) as i32);
        tch::manual_seed(cfg.seed as i64);
        let sac = Sac::new(p, ad, sc)?;
        let opts = [
            nn::Adam::default().build(&sac.actor_vs, sc.lr)?,
            nn::Adam::default().build(&sac.critic_vs, sc.lr)?,
            nn::Adam::default().build(&sac.alpha_vs, sc.lr)?,
        ];
        let mut stats = RunningStats::new(od);
        let mut env_steps = 0u64;
        if cfg.resume {
            let old = ExpertPolicy::load(&cfg.out)?;
            old.check_fits(&spec, cfg.mode, &cfg.out)?;
            load_state(&sac, &mut stats, &state_path(&cfg.out))?;
            env_steps = old.meta.trained_steps;
        }
        let replay = open_replay(cfg, sc, (p, ad), env_steps)?;
        let mut run = Self {
            cfg,
            sc,
            env,
            p,
            sac,
            opts,
            target_entropy: sc.target_entropy_per_dim * ad as f64,
            stats,
            replay,
            rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5AC),
            env_steps,
            episode_seed: cfg.seed.wrapping_mul(7_919).wrapping_add(env_steps),
            obs: vec![0.0; od],
            next: vec![0.0; od],
            act: vec![0.0; ad],
            rewards: vec![0.0; spec.n_modes],
            spec,
            episodes: Episodes::default(),
        };
        run.reset()?;
        Ok(run)
    }

    fn reset(&mut self) -> Result<()> {
        self.episode_seed = self.episode_seed.wrapping_add(1);
        self.env.reset(self.episode_seed, &mut self.obs)?;
        self.stats.update(&self.obs);
        Ok(())
    }

    /// Acts (the policy's sample under `norm`, or uniformly at random without one),
    /// steps the env, and records the transition in the replay and the normaliser.
    fn env_step(&mut self, norm: Option<&(Vec<f32>, Vec<f32>)>) -> Result<()> {
        match norm {
            Some((mean, std)) => {
                let x = gather_norm(&self.obs, self.spec.obs_dim, self.p, &[0], mean, std);
                let a = tch::no_grad(|| self.sac.actor.sample(&x).0);
                self.act.copy_from_slice(&tensor_to_vec(&a));
            }
            None => self
                .act
                .iter_mut()
                .for_each(|a| *a = self.rng.random_range(-1.0..1.0)),
        }
        let out = self.env.step(&self.act, &mut self.next)?;
        self.env.task_rewards(&mut self.rewards);
        let r = self.rewards[self.cfg.mode];
        let p = self.p;
        (self.replay).push(
            &self.obs[..p],
            &self.act,
            r,
            &self.next[..p],
            out.terminated,
        );
        self.stats.update(&self.next);
        self.env_steps += 1;
        self.episodes.ret += r as f64;
        self.episodes.len += 1;
        if out.done() {
            self.episodes.end();
            self.reset()?;
        } else {
            std::mem::swap(&mut self.obs, &mut self.next);
        }
        Ok(())
    }

    /// `updates_per_step` gradient steps under `norm`; the first one's statistics when
    /// `want_stats`.
    fn learn(&mut self, (mean, std): &(Vec<f32>, Vec<f32>), want_stats: bool) -> Option<StepStats> {
        let mut first = None;
        for u in 0..self.sc.updates_per_step {
            let want = want_stats && u == 0;
            let st = update(
                &self.sac,
                &mut self.opts,
                &self.replay,
                self.sc,
                self.target_entropy,
                mean,
                std,
                &mut self.rng,
                want,
            );
            if want {
                first = Some(st);
            }
        }
        first
    }

    /// Saves the expert file and the run's state (networks, normaliser).
    fn save(&self) -> Result<ExpertPolicy> {
        let recent = &self.episodes.recent;
        let (cfg, spec, sac, replay) = (self.cfg, &self.spec, &self.sac, &self.replay);
        save(
            cfg,
            spec,
            sac,
            replay,
            self.p,
            &self.stats,
            self.env_steps,
            recent,
        )
    }
}

/// Trains `cfg.mode`'s expert with SAC; `progress` sees one report per `log_every`
/// env steps. Stops early (saving) when `shutdown` is set. Returns the saved expert.
pub fn train_expert_sac(
    cfg: &ExpertTrainConfig,
    sc: &SacConfig,
    progress: &mut dyn FnMut(&ExpertIteration),
    shutdown: &AtomicBool,
) -> Result<ExpertPolicy> {
    let mut run = SacRun::new(cfg, sc)?;
    let start_steps = run.env_steps;
    // A fresh run explores at random; a resumed one without a saved buffer refills it
    // with the policy before updating; one with a buffer updates at once. (`update_from`
    // is at least `batch` steps past the start: the replay then holds a batch.)
    let random_until = if cfg.resume {
        0
    } else {
        sc.learning_starts as u64
    };
    let update_from = if run.replay.len >= sc.batch.max(1) {
        start_steps
    } else {
        start_steps + sc.learning_starts.max(sc.batch) as u64
    };
    let mut csv = open_csv(cfg)?;
    let log_every = sc.log_every as u64;
    // Rows number on from the CSV's last (a stop between rows wrote a partial one).
    let mut it = cfg
        .resume
        .then(|| last_csv_iteration(&csv_path(&cfg.out)))
        .flatten()
        .map_or(start_steps.div_ceil(log_every) as usize + 1, |i| i + 1);
    let mut last = StepStats::default();
    let mut t0 = Instant::now();
    let mut expert = None;
    while run.env_steps < cfg.steps && !shutdown.load(Ordering::Relaxed) {
        // The normaliser as of this step, for acting and this step's update; the
        // random-action steps before the first update need none.
        let random = run.env_steps < random_until;
        let updating = run.env_steps + 1 >= update_from;
        let norm = (!random || updating).then(|| run.stats.mean_std());
        run.env_step(norm.as_ref().filter(|_| !random))?;
        let steps = run.env_steps;
        let row_due = steps.is_multiple_of(log_every);
        if steps >= update_from
            && let Some(norm) = &norm
            && let Some(st) = run.learn(norm, row_due)
        {
            last = st;
        }
        let finished = steps >= cfg.steps || shutdown.load(Ordering::Relaxed);
        if !(row_due || finished) {
            continue;
        }
        let (mean_return, mean_length) = crate::experts::episode_means(&run.episodes.since_row);
        run.episodes.since_row.clear();
        let report = ExpertIteration {
            iteration: it,
            env_steps: steps,
            mean_return,
            mean_length,
            seconds: t0.elapsed().as_secs_f64(),
            entropy: last.entropy,
        };
        t0 = Instant::now();
        report.write_csv_row(&mut csv)?;
        progress(&report);
        tracing::debug!(
            alpha = run.sac.alpha(),
            critic_loss = last.critic_loss,
            "sac step {steps}"
        );
        it += 1;
        if it.is_multiple_of(10) || finished {
            expert = Some(run.save()?);
            csv.flush()?;
        }
    }
    csv.flush()?;
    let expert = match expert {
        Some(e) => e,
        None => run.save()?,
    };
    if sc.save_replay && run.env_steps > start_steps && run.replay.len > 0 {
        run.replay.save(&replay_path(&cfg.out), run.env_steps)?;
    }
    Ok(expert)
}
