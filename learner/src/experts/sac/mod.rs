//! Soft actor-critic expert training (`ess experts train --algo sac`).
//!
//! The paper pre-trains one expert per behaviour mode (Sec. 4, "Multi-modal
//! demonstrations preparation") and does not say with what; our PPO ([`crate::experts`])
//! gives good experts everywhere but on Humanoid's moving modes (bench/mujoco.md), so
//! issue 4 allows SAC there. This is SAC as in Haarnoja et al. 2018, "Soft
//! Actor-Critic Algorithms and Applications" (arXiv:1812.05905), their Algorithm 1:
//!
//! - critics: two Q networks trained on `(Q_i(s, a) - y)^2` with
//!   `y = r + gamma (1 - terminated) (min_j Qbar_j(s', a') - alpha log pi(a' | s'))`,
//!   `a' ~ pi(. | s')` (their Eq. 5-6 with the clipped double-Q of Sec. 6), `Qbar` the
//!   Polyak averages `Qbar <- (1 - tau) Qbar + tau Q`; a time-limit cut (`truncated`)
//!   bootstraps, a fall (`terminated`) does not;
//! - actor: `E[alpha log pi(a | s) - min_j Q_j(s, a)]` with the reparameterised
//!   `a = tanh(mu(s) + sigma(s) n)` (their Eq. 7 and 13; the tanh log-det of Appendix C);
//! - temperature: `E[-alpha (log pi(a | s) + H_target)]` (their Eq. 18), with
//!   `H_target = target_entropy_per_dim * act_dim`.
//!
//! One env, one gradient step (or `updates_per_step`) per env step, on mode `k`'s task
//! reward ([`ess_envs::Env::task_rewards`]), after `learning_starts` uniformly random
//! steps. Observations are normalised with running statistics of every observation
//! seen (applied when a batch is drawn, so the replay keeps raw observations).
//!
//! **Export.** The expert file format ([`ess_envs::ExpertPolicy`]) is PPO's: a tanh MLP
//! for the mean and a *state-independent* log standard deviation. The actor is built
//! to fit it: a tanh trunk whose mean head is the MLP's last layer (the log-std head is
//! dropped), and the exported `log_std` is the mean of the actor's log std over the
//! latest `EXPORT_STATES` states of the replay. With `obs_prefix` the trunk reads only
//! the first entries of the observation; the exported first layer carries zero weights
//! for the rest, so the file reads the whole observation and acts identically.
//!
//! **Files**: as PPO's expert training: the expert, `<file>.state.safetensors` (all
//! networks, the temperature and the normaliser) and `<file>.csv` (one row per
//! `log_every` env steps, same columns), plus, when the run stops (finished or Ctrl-C)
//! and `save_replay` is on, `<file>.replay.safetensors`: the replay buffer. `--resume`
//! continues from the state file and, if there is one, the replay file, updating from
//! its first step on. Without a replay file (a crash, `save_replay = false`) it refills
//! its buffer with the policy (not random actions) for `learning_starts` steps before
//! updating; that costs a Humanoid run ~100K steps of progress (bench/mujoco.md), as the
//! refilled buffer holds only the current policy's data. Adam moments are not saved.
//!
//! The replay keeps only the observation entries the networks read (`obs_prefix`), raw
//! (normalised when a batch is drawn).

use anyhow::{Context, Result, bail};
use ess_envs::ExpertPolicy;
use ess_proto::config::SacConfig;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tch::nn::Module;
use tch::{Kind, Tensor, nn};

use crate::experts::{ExpertTrainConfig, RunningStats, expert_meta, replay_path, state_path};
use crate::train::nets::{Mlp, tensor_2d, tensor_to_vec};

mod replay;
mod run;
use replay::{Replay, gather_norm, read_named, write_via_tmp};
pub use run::train_expert_sac;

/// Replay states whose mean actor log std becomes the exported `log_std`.
const EXPORT_STATES: usize = 10_000;
/// Clamp of the actor's log standard deviation.
const LOG_STD_MIN: f64 = -5.0;
const LOG_STD_MAX: f64 = 2.0;

/// The actor: a tanh trunk and linear mean and log-std heads.
struct Actor {
    trunk: Mlp,
    mean: nn::Linear,
    log_std: nn::Linear,
}

impl Actor {
    fn new(p: nn::Path, input: usize, hidden: &[usize], act_dim: usize) -> Self {
        let mut sizes = vec![input];
        sizes.extend_from_slice(hidden);
        let h = *hidden.last().unwrap_or(&input) as i64;
        Self {
            trunk: Mlp::new(&p / "trunk", &sizes, true, 1.0),
            mean: nn::linear(&p / "mean", h, act_dim as i64, Default::default()),
            log_std: nn::linear(&p / "log_std", h, act_dim as i64, Default::default()),
        }
    }

    /// Mean and clamped log std of the pre-tanh Gaussian.
    fn dist(&self, x: &Tensor) -> (Tensor, Tensor) {
        let h = self.trunk.forward(x);
        let ls = self.log_std.forward(&h).clamp(LOG_STD_MIN, LOG_STD_MAX);
        (self.mean.forward(&h), ls)
    }

    /// A reparameterised action and its log-density (tanh change of variables).
    fn sample(&self, x: &Tensor) -> (Tensor, Tensor) {
        let (mean, ls) = self.dist(x);
        let n = mean.randn_like();
        Self::squash(&mean, &ls, &n)
    }

    /// `tanh(mean + exp(ls) n)` and its log-density, for standard normal noise `n`.
    fn squash(mean: &Tensor, ls: &Tensor, n: &Tensor) -> (Tensor, Tensor) {
        let u = mean + ls.exp() * n;
        let a = u.tanh();
        let ln_sqrt_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
        let gauss = (n.square() * -0.5 - ls - ln_sqrt_2pi).sum_dim_intlist(-1, true, Kind::Float);
        // log(1 - tanh(u)^2) = 2 (ln 2 - u - softplus(-2u)), stable for large |u|.
        let log_det = ((-&u * 2.0).softplus() + &u - std::f64::consts::LN_2) * 2.0;
        let logp = gauss + log_det.sum_dim_intlist(-1, true, Kind::Float);
        (a, logp)
    }
}

/// A ReLU MLP with one output: a Q network on `[s, a]`.
struct QNet {
    layers: Vec<nn::Linear>,
}

impl QNet {
    fn new(p: nn::Path, input: usize, hidden: &[usize]) -> Self {
        let mut sizes = vec![input];
        sizes.extend_from_slice(hidden);
        sizes.push(1);
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(l, w)| {
                nn::linear(
                    &p / format!("l{l}"),
                    w[0] as i64,
                    w[1] as i64,
                    Default::default(),
                )
            })
            .collect();
        Self { layers }
    }

    fn forward(&self, s: &Tensor, a: &Tensor) -> Tensor {
        let mut h = Tensor::cat(&[s, a], 1);
        let n = self.layers.len();
        for (l, lin) in self.layers.iter().enumerate() {
            h = lin.forward(&h);
            if l + 1 < n {
                h = h.relu();
            }
        }
        h
    }
}

/// Everything SAC learns, with the target critics.
struct Sac {
    actor_vs: nn::VarStore,
    critic_vs: nn::VarStore,
    target_vs: nn::VarStore,
    alpha_vs: nn::VarStore,
    actor: Actor,
    q: [QNet; 2],
    qt: [QNet; 2],
    log_alpha: Tensor,
    /// `(target, source)` variable pairs for the Polyak update.
    polyak: Vec<(Tensor, Tensor)>,
}

impl Sac {
    fn new(p: usize, ad: usize, cfg: &SacConfig) -> Result<Self> {
        let dev = tch::Device::Cpu;
        let actor_vs = nn::VarStore::new(dev);
        let critic_vs = nn::VarStore::new(dev);
        let mut target_vs = nn::VarStore::new(dev);
        let alpha_vs = nn::VarStore::new(dev);
        let actor = Actor::new(actor_vs.root() / "actor", p, &cfg.hidden, ad);
        let q = [0, 1].map(|i| QNet::new(critic_vs.root() / format!("q{i}"), p + ad, &cfg.hidden));
        let qt = [0, 1].map(|i| QNet::new(target_vs.root() / format!("q{i}"), p + ad, &cfg.hidden));
        target_vs.copy(&critic_vs)?;
        let log_alpha =
            alpha_vs
                .root()
                .var("log_alpha", &[1], nn::Init::Const(cfg.init_alpha.ln()));
        let src = critic_vs.variables();
        let polyak: Vec<(Tensor, Tensor)> = target_vs
            .variables()
            .into_iter()
            .map(|(name, t)| {
                let s = src.get(&name).map(|s| s.shallow_clone());
                s.map(|s| (t, s))
                    .with_context(|| format!("target critic variable {name} has no source"))
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            actor_vs,
            critic_vs,
            target_vs,
            alpha_vs,
            actor,
            q,
            qt,
            log_alpha,
            polyak,
        })
    }

    /// `(prefix, store)` of every store in the state file.
    fn stores(&self) -> [(&'static str, &nn::VarStore); 4] {
        [
            ("actor", &self.actor_vs),
            ("critic", &self.critic_vs),
            ("target", &self.target_vs),
            ("alpha", &self.alpha_vs),
        ]
    }

    fn alpha(&self) -> f64 {
        self.log_alpha.exp().double_value(&[0])
    }
}

/// Statistics of one gradient step.
#[derive(Default, Clone, Copy)]
struct StepStats {
    critic_loss: f64,
    entropy: f64,
}

/// One SAC gradient step on a uniformly drawn batch.
#[allow(clippy::too_many_arguments)]
fn update(
    sac: &Sac,
    opts: &mut [nn::Optimizer; 3],
    replay: &Replay,
    cfg: &SacConfig,
    target_entropy: f64,
    mean: &[f32],
    std: &[f32],
    rng: &mut ChaCha8Rng,
    want_stats: bool,
) -> StepStats {
    let (od, ad) = (replay.od, replay.ad);
    let idx: Vec<usize> = (0..cfg.batch)
        .map(|_| rng.random_range(0..replay.len))
        .collect();
    let s = gather_norm(&replay.obs, od, od, &idx, mean, std);
    let s2 = gather_norm(&replay.next_obs, od, od, &idx, mean, std);
    let mut a = Vec::with_capacity(idx.len() * ad);
    let (mut r, mut live) = (Vec::with_capacity(idx.len()), Vec::with_capacity(idx.len()));
    for &i in &idx {
        a.extend_from_slice(&replay.act[i * ad..(i + 1) * ad]);
        r.push(replay.rew[i]);
        live.push(replay.live[i]);
    }
    let a = tensor_2d(&a, ad);
    let r = tensor_2d(&r, 1);
    let live = tensor_2d(&live, 1);
    let alpha = sac.log_alpha.exp().detach();
    let y = tch::no_grad(|| {
        let (a2, logp2) = sac.actor.sample(&s2);
        let qmin = sac.qt[0]
            .forward(&s2, &a2)
            .minimum(&sac.qt[1].forward(&s2, &a2));
        &r + live * cfg.gamma * (qmin - &alpha * logp2)
    });
    let critic_loss = (sac.q[0].forward(&s, &a) - &y).square().mean(Kind::Float)
        + (sac.q[1].forward(&s, &a) - &y).square().mean(Kind::Float);
    opts[1].backward_step(&critic_loss);
    // The actor loss needs Q's input gradient only: no weight gradients for the critics.
    // (The Polyak pairs' sources are exactly the critics' variables.)
    for (_, v) in &sac.polyak {
        let _ = v.set_requires_grad(false);
    }
    let (api, logp) = sac.actor.sample(&s);
    let qpi = sac.q[0]
        .forward(&s, &api)
        .minimum(&sac.q[1].forward(&s, &api));
    let actor_loss = (&alpha * &logp - qpi).mean(Kind::Float);
    opts[0].backward_step(&actor_loss);
    for (_, v) in &sac.polyak {
        let _ = v.set_requires_grad(true);
    }
    let alpha_loss = -(sac.log_alpha.exp() * (logp.detach() + target_entropy)).mean(Kind::Float);
    opts[2].backward_step(&alpha_loss);
    tch::no_grad(|| {
        for (t, src) in &sac.polyak {
            let _ = t.shallow_clone().lerp_(src, cfg.tau);
        }
    });
    if want_stats {
        StepStats {
            critic_loss: critic_loss.double_value(&[]),
            entropy: -logp.mean(Kind::Float).double_value(&[]),
        }
    } else {
        StepStats::default()
    }
}

/// Writes every network, the temperature and the normaliser to `path`.
fn save_state(sac: &Sac, stats: &RunningStats, path: &std::path::Path) -> Result<()> {
    let mut named: Vec<(String, Tensor)> = Vec::new();
    for (prefix, vs) in sac.stores() {
        for (name, t) in vs.variables() {
            named.push((format!("{prefix}/{name}"), t.detach()));
        }
    }
    let f64s = |v: &[f64]| Tensor::from_slice(v);
    named.push(("stats/count".into(), f64s(&[stats.count])));
    named.push(("stats/mean".into(), f64s(&stats.mean)));
    named.push(("stats/m2".into(), f64s(&stats.m2)));
    named.sort_by(|a, b| a.0.cmp(&b.0));
    write_via_tmp(&named, path, "SAC state")
}

/// Loads what [`save_state`] wrote into `sac` and `stats`; names the file and the
/// missing or misshapen tensor on error.
fn load_state(sac: &Sac, stats: &mut RunningStats, path: &std::path::Path) -> Result<()> {
    let what = || format!("SAC training state {}", path.display());
    let tensors = read_named(path, &what())?;
    let get = |name: &str, shape: &[i64]| -> Result<&Tensor> {
        let t = tensors.get(name).with_context(|| {
            format!(
                "{}: no tensor {name} (a PPO state file? SAC resumes only SAC runs)",
                what()
            )
        })?;
        if t.size() != shape {
            bail!(
                "{}: {name} has shape {:?}, expected {:?}",
                what(),
                t.size(),
                shape
            );
        }
        Ok(t)
    };
    tch::no_grad(|| -> Result<()> {
        for (prefix, vs) in sac.stores() {
            for (name, mut var) in vs.variables() {
                let src = get(&format!("{prefix}/{name}"), &var.size())?;
                var.copy_(src);
            }
        }
        Ok(())
    })?;
    let d = stats.mean.len() as i64;
    let vec64 = |t: &Tensor| Vec::<f64>::try_from(&t.to_kind(Kind::Double)).unwrap_or_default();
    stats.count = get("stats/count", &[1])?.double_value(&[0]);
    stats.mean = vec64(get("stats/mean", &[d])?);
    stats.m2 = vec64(get("stats/m2", &[d])?);
    Ok(())
}

/// The expert file's form of the actor: the trunk plus mean head as one tanh MLP on
/// the whole observation (zero weights past `obs_prefix`), and the mean log std over
/// the newest replay states.
fn export(
    sac: &Sac,
    replay: &Replay,
    p: usize,
    od: usize,
    mean: &[f32],
    std: &[f32],
) -> (Vec<usize>, Vec<f32>, Vec<f32>) {
    let mut sizes = sac.actor.trunk.sizes().to_vec();
    sizes[0] = od;
    sizes.push(replay.ad);
    let trunk = sac.actor.trunk.export();
    let h0 = sac.actor.trunk.sizes()[1];
    let mut params = Vec::with_capacity(trunk.len() + h0 * (od - p));
    for row in trunk[..h0 * p].chunks_exact(p) {
        params.extend_from_slice(row);
        params.extend(std::iter::repeat_n(0.0, od - p));
    }
    params.extend_from_slice(&trunk[h0 * p..]);
    params.extend(tensor_to_vec(&sac.actor.mean.ws));
    if let Some(b) = &sac.actor.mean.bs {
        params.extend(tensor_to_vec(b));
    }
    let n = replay.len.min(EXPORT_STATES);
    let log_std = if n == 0 {
        vec![0.0; replay.ad]
    } else {
        let idx: Vec<usize> = (0..n).map(|b| replay.newest(b)).collect();
        let s = gather_norm(&replay.obs, replay.od, p, &idx, mean, std);
        tch::no_grad(|| tensor_to_vec(&sac.actor.dist(&s).1.mean_dim(0, false, Kind::Float)))
    };
    (sizes, params, log_std)
}

/// A [`train_expert_sac`] argument the user has to change (the CLI exits 2 on it).
#[derive(Debug, thiserror::Error)]
pub enum SacInputError {
    #[error("--init-from warm-starts PPO experts only; with --algo sac use --resume")]
    InitFrom,
    #[error("sac.obs_prefix = {prefix} exceeds env {env}'s observation length {obs_dim}")]
    ObsPrefix {
        prefix: usize,
        env: String,
        obs_dim: usize,
    },
}

/// The replay buffer a run starts with: the saved one on `--resume` (when it exists),
/// else an empty one (a fresh run removes another run's leftover buffer file, so a
/// later `--resume` of this run cannot read it). `p`: observed entries, `ad`: actions.
fn open_replay(
    cfg: &ExpertTrainConfig,
    sc: &SacConfig,
    (p, ad): (usize, usize),
    env_steps: u64,
) -> Result<Replay> {
    let rpath = replay_path(&cfg.out);
    Ok(if cfg.resume && rpath.exists() {
        let (r, at) = Replay::load(&rpath, sc.buffer, p, ad)?;
        tracing::info!(
            "resuming at {env_steps} steps with the {} transitions of {} (saved at {at} steps)",
            r.len,
            rpath.display()
        );
        r
    } else {
        if cfg.resume {
            tracing::warn!(
                "no replay {} to resume with: refilling the buffer with the policy for {} \
                 steps before updating",
                rpath.display(),
                sc.learning_starts.max(sc.batch)
            );
        } else if rpath.exists() {
            // Another run's buffer: a later --resume of this run must not read it.
            std::fs::remove_file(&rpath)
                .with_context(|| format!("removing the old replay {}", rpath.display()))?;
        }
        Replay::new(sc.buffer, p, ad)
    })
}

#[allow(clippy::too_many_arguments)]
fn save(
    cfg: &ExpertTrainConfig,
    spec: &ess_envs::EnvSpec,
    sac: &Sac,
    replay: &Replay,
    p: usize,
    stats: &RunningStats,
    env_steps: u64,
    recent: &[f64],
) -> Result<ExpertPolicy> {
    let (mean, std) = stats.mean_std();
    let (sizes, params, log_std) = export(sac, replay, p, spec.obs_dim, &mean, &std);
    let meta = expert_meta(cfg, spec, sizes, 0, env_steps, recent, " (sac)");
    let e = ExpertPolicy::new(meta, params, log_std, mean, std)
        .map_err(|r| anyhow::anyhow!("exported SAC expert is inconsistent: {r}"))?;
    e.save(&cfg.out)?;
    save_state(sac, stats, &state_path(&cfg.out))?;
    Ok(e)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ess_envs::ExpertMeta;
    use rand::SeedableRng;

    fn small() -> SacConfig {
        SacConfig {
            hidden: vec![16, 8],
            ..SacConfig::default()
        }
    }

    #[test]
    fn the_logp_is_the_gaussian_density_minus_the_tanh_log_det() {
        tch::manual_seed(1);
        let sac = Sac::new(5, 3, &small()).unwrap();
        let x = Tensor::randn([64, 5], (Kind::Float, tch::Device::Cpu));
        // One noise draw for both sides (re-seeding torch's global generator would race
        // with the tests running beside this one).
        let (mean, ls) = sac.actor.dist(&x);
        let n = mean.randn_like();
        let (a, logp) = Actor::squash(&mean, &ls, &n);
        let u = &mean + ls.exp() * &n;
        assert!(f64::try_from((u.tanh() - &a).abs().max()).unwrap() < 1e-6);
        // The naive formula in f64: in f32, 1 - tanh(u)^2 is all rounding once |u| > ~8.
        let [mean, ls, n] = [mean, ls, n].map(|t| t.to_kind(Kind::Double));
        let u = &mean + ls.exp() * &n;
        let var = (&ls * 2.0).exp();
        let gauss =
            ((&u - &mean).square() / (&var * -2.0) - &ls - 0.5 * (2.0 * std::f64::consts::PI).ln())
                .sum_dim_intlist(-1, true, Kind::Double);
        let naive = gauss
            - (u.tanh().square() * -1.0 + 1.0)
                .log()
                .sum_dim_intlist(-1, true, Kind::Double);
        let err = f64::try_from((naive - logp.to_kind(Kind::Double)).abs().max()).unwrap();
        assert!(err < 1e-4, "logp differs from the naive formula by {err}");
    }

    #[test]
    fn the_exported_expert_acts_as_the_actor_mean_on_the_whole_observation() {
        tch::manual_seed(2);
        let (od, p, ad) = (12, 7, 3);
        let sac = Sac::new(p, ad, &small()).unwrap();
        let mut replay = Replay::new(50, od, ad);
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut stats = RunningStats::new(od);
        for _ in 0..40 {
            let o: Vec<f32> = (0..od).map(|_| rng.random_range(-3.0..3.0)).collect();
            stats.update(&o);
            replay.push(&o, &[0.1, 0.2, 0.3], 1.0, &o, false);
        }
        let (mean, std) = stats.mean_std();
        let (sizes, params, log_std) = export(&sac, &replay, p, od, &mean, &std);
        let meta = ExpertMeta {
            env: "t".into(),
            mode: 0,
            n_modes: 1,
            obs_dim: od,
            act_dim: ad,
            sizes,
            extra_inputs: 0,
            trained_steps: 40,
            mean_return: 0.0,
            generator: "test".into(),
        };
        let e =
            ExpertPolicy::new(meta, params, log_std.clone(), mean.clone(), std.clone()).unwrap();
        // log_std: the actor's mean over the replay's states.
        let all: Vec<usize> = (0..40).collect();
        let s = gather_norm(&replay.obs, od, p, &all, &mean, &std);
        let want = tensor_to_vec(&sac.actor.dist(&s).1.mean_dim(0, false, Kind::Float));
        for (g, w) in log_std.iter().zip(&want) {
            assert!((g - w).abs() < 1e-5, "log_std {log_std:?} vs {want:?}");
        }
        let mut buf = e.scratch();
        let mut act = vec![0.0; ad];
        for i in 0..40 {
            // Entries past the prefix are noise the expert must ignore.
            let mut o = replay.obs[i * od..(i + 1) * od].to_vec();
            o[p..]
                .iter_mut()
                .for_each(|x| *x = rng.random_range(-50.0..50.0));
            e.act(&o, 0.0, &mut rng, &mut buf, &mut act);
            let x = gather_norm(&o, od, p, &[0], &mean, &std);
            let want = tensor_to_vec(&sac.actor.dist(&x).0.tanh());
            for (g, w) in act.iter().zip(&want) {
                assert!((g - w).abs() < 1e-5, "row {i}: {act:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn the_state_file_round_trips_and_a_foreign_one_is_refused_by_name() {
        tch::manual_seed(3);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.safetensors");
        let sac = Sac::new(4, 2, &small()).unwrap();
        let mut stats = RunningStats::new(6);
        stats.update(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0]);
        save_state(&sac, &stats, &path).unwrap();
        tch::manual_seed(4);
        let other = Sac::new(4, 2, &small()).unwrap();
        let mut back = RunningStats::new(6);
        load_state(&other, &mut back, &path).unwrap();
        for (prefix, vs) in sac.stores() {
            let theirs = other
                .stores()
                .into_iter()
                .find(|s| s.0 == prefix)
                .unwrap()
                .1;
            for (name, t) in vs.variables() {
                let u = &theirs.variables()[&name];
                assert!(t.equal(u), "{prefix}/{name} differs after loading");
            }
        }
        assert_eq!(
            (back.count, &back.mean, &back.m2),
            (stats.count, &stats.mean, &stats.m2)
        );
        // Another shape (a wider observation) is refused naming the tensor and file.
        let wide = Sac::new(5, 2, &small()).unwrap();
        let err = format!("{:#}", load_state(&wide, &mut back, &path).unwrap_err());
        assert!(
            err.contains("s.safetensors") && err.contains("shape"),
            "{err}"
        );
        // A state file without SAC tensors (e.g. PPO's) is refused too.
        write_via_tmp(
            &[(
                "pi/mean/l0/weight",
                Tensor::zeros([2], (Kind::Float, tch::Device::Cpu)),
            )],
            &path,
            "test",
        )
        .unwrap();
        let err = format!("{:#}", load_state(&other, &mut back, &path).unwrap_err());
        assert!(
            err.contains("no tensor") && err.contains("s.safetensors"),
            "{err}"
        );
    }
    #[test]
    fn the_replay_file_round_trips_wrapped_or_not_and_a_mismatch_is_refused_by_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.safetensors.replay.safetensors");
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // 3 pushes (not wrapped), then 11 (wrapped past the capacity of 8).
        for pushes in [3, 11] {
            let mut r = Replay::new(8, 4, 2);
            for i in 0..pushes {
                let o: Vec<f32> = (0..4).map(|_| rng.random_range(-1.0..1.0)).collect();
                let o2: Vec<f32> = (0..4).map(|_| rng.random_range(-1.0..1.0)).collect();
                r.push(&o, &[i as f32, -1.0], i as f32 * 0.5, &o2, i % 4 == 3);
            }
            r.save(&path, 1234).unwrap();
            let (b, at) = Replay::load(&path, 8, 4, 2).unwrap();
            assert_eq!(at, 1234);
            assert_eq!((b.len, b.next), (r.len, r.next));
            assert_eq!((&b.obs, &b.next_obs), (&r.obs, &r.next_obs));
            assert_eq!((&b.act, &b.rew, &b.live), (&r.act, &r.rew, &r.live));
            assert_eq!(b.newest(0), r.newest(0));
        }
        for ((cap, od, ad), field) in [
            ((9, 4, 2), "sac.buffer is 8 there, 9 in this run"),
            ((8, 5, 2), "sac.obs_prefix) is 4 there, 5 in this run"),
            ((8, 4, 3), "action entries is 2 there, 3 in this run"),
        ] {
            let err = format!("{:#}", Replay::load(&path, cap, od, ad).err().unwrap());
            assert!(
                err.contains(field) && err.contains("m.safetensors.replay"),
                "{err}"
            );
        }
        // A file that is not a replay (a state file, say) names the missing tensor.
        write_via_tmp(
            &[("x", Tensor::zeros([2], (Kind::Float, tch::Device::Cpu)))],
            &path,
            "test",
        )
        .unwrap();
        let err = format!("{:#}", Replay::load(&path, 8, 4, 2).err().unwrap());
        assert!(err.contains("no tensor meta"), "{err}");
    }
}
