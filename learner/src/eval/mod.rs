//! Evaluation as the paper measures it (Sec. 4, "Baselines and evaluation metrics").
//!
//! 1. A [`Reference`] per env: the behaviour classifier on `(s', a)` trained on balanced
//!    expert episodes, and each mode's expert and random-policy returns.
//! 2. For each one-hot code `c_j`: deterministic episodes (eps drawn per episode);
//!    every step classified; a confusion matrix (codes x classes).
//! 3. NMI and ENT of that matrix; the normalised task reward
//!    `(R - R_random) / (R_expert - R_random)`, mean over modes, where code `j` is scored
//!    on the mode it is matched to by the optimal one-to-one assignment (so a permuted
//!    but disentangled policy of an unsupervised method is not punished, while a
//!    collapsed one is).

pub mod classifier;
pub mod metrics;
pub mod plot;
pub mod report;
pub mod table;

use crate::eval::classifier::BehaviourClassifier;
use crate::eval::metrics::{Confusion, best_assignment, ent, nmi, normalized_reward};
use ess_actor::{EvalEpisode, EvalJob, EvalRunner, LatentSpec, PolicyWeights};
use ess_envs::{Env, ScriptedExpert, expert_episode};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// What evaluation compares against.
pub struct Reference {
    /// The behaviour classifier.
    pub classifier: BehaviourClassifier,
    /// Its held-out accuracy on expert data.
    pub classifier_accuracy: f64,
    /// Mean expert return of each mode.
    pub expert_return: Vec<f64>,
    /// Mean return of each mode under a uniformly random policy.
    pub random_return: Vec<f64>,
}

/// Classifier input rows `[s', a]` of consecutive steps.
pub fn classifier_rows(next_obs: &[f32], act: &[f32], obs_dim: usize, act_dim: usize) -> Vec<f32> {
    let mut rows = Vec::with_capacity(next_obs.len() + act.len());
    for (s, a) in next_obs
        .chunks_exact(obs_dim)
        .zip(act.chunks_exact(act_dim))
    {
        rows.extend_from_slice(s);
        rows.extend_from_slice(a);
    }
    rows
}

/// Builds the reference of `env` from `episodes` expert episodes per mode.
pub fn build_reference(
    env: &mut dyn ScriptedExpert,
    episodes: usize,
    seed: u64,
) -> anyhow::Result<Reference> {
    let spec = env.spec().clone();
    let (k, od, ad) = (spec.n_modes, spec.obs_dim, spec.act_dim);
    let mut rows = Vec::new();
    let mut labels = Vec::new();
    let mut expert_return = vec![0.0; k];
    for (mode, mode_return) in expert_return.iter_mut().enumerate() {
        for e in 0..episodes {
            let ep = expert_episode(env, mode, seed ^ ((mode as u64) << 32) ^ (e as u64 + 1))?;
            rows.extend(classifier_rows(&ep.next_obs, &ep.act, od, ad));
            labels.extend(std::iter::repeat_n(mode as i64, ep.len()));
            *mode_return += ep.reward.iter().map(|&r| r as f64).sum::<f64>();
        }
        *mode_return /= episodes as f64;
    }
    let (classifier, classifier_accuracy) =
        BehaviourClassifier::train(&rows, &labels, od + ad, k, 1500, seed)?;
    let random_return = random_returns(env, episodes.max(1) * k, seed)?;
    Ok(Reference {
        classifier,
        classifier_accuracy,
        expert_return,
        random_return,
    })
}

/// Mean per-mode return of `n` episodes of uniform random actions in `[-1, 1]`.
fn random_returns(env: &mut dyn Env, n: usize, seed: u64) -> anyhow::Result<Vec<f64>> {
    let spec = env.spec().clone();
    let (k, od, ad) = (spec.n_modes, spec.obs_dim, spec.act_dim);
    let mut random_return = vec![0.0; k];
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed);
    let mut obs = vec![0.0; od];
    let mut act = vec![0.0; ad];
    let mut rew = vec![0.0; k];
    for _ in 0..n {
        env.reset(rng.random(), &mut obs)?;
        loop {
            for a in act.iter_mut() {
                *a = rng.random_range(-1.0..1.0);
            }
            let out = env.step(&act, &mut obs)?;
            env.mode_rewards(&mut rew);
            for (acc, r) in random_return.iter_mut().zip(&rew) {
                *acc += *r as f64;
            }
            if out.terminated || out.truncated {
                break;
            }
        }
    }
    for r in random_return.iter_mut() {
        *r /= n as f64;
    }
    Ok(random_return)
}

/// The reference of an env without experts (a task file), from its demonstrations:
/// the behaviour classifier trains on every demonstration step whose mode is known
/// (the labeled split, plus unlabeled episodes the source labeled); the expert return
/// of a mode is the demonstrations' own mean episode return on episodes of that mode,
/// the random return that of `random_episodes` random episodes per mode under the
/// env's per-mode rewards. Without per-mode rewards both are 0 and normalized reward
/// does not apply ([`normalized_reward`] is then 0).
pub fn reference_from_demos(
    env: &mut dyn Env,
    demos: &ess_envs::Demos,
    random_episodes: usize,
    seed: u64,
) -> anyhow::Result<Reference> {
    let spec = env.spec().clone();
    let (k, od, ad) = (spec.n_modes, spec.obs_dim, spec.act_dim);
    let mut rows = Vec::new();
    let mut labels = Vec::new();
    for s in [&demos.labeled, &demos.unlabeled] {
        for (i, &m) in s.mode.iter().enumerate() {
            if (m as usize) < k {
                rows.extend(classifier_rows(
                    &s.next_obs[i * od..(i + 1) * od],
                    &s.act[i * ad..(i + 1) * ad],
                    od,
                    ad,
                ));
                labels.push(i64::from(m));
            }
        }
    }
    let (classifier, classifier_accuracy) =
        BehaviourClassifier::train(&rows, &labels, od + ad, k, 1500, seed)?;
    if !env.has_mode_rewards() {
        return Ok(Reference {
            classifier,
            classifier_accuracy,
            expert_return: vec![0.0; k],
            random_return: vec![0.0; k],
        });
    }
    Ok(Reference {
        classifier,
        classifier_accuracy,
        expert_return: demo_returns(demos, k),
        random_return: random_returns(env, random_episodes.max(1) * k, seed)?,
    })
}

/// Mean episode return of each mode's demonstrations (unlabeled episodes of known mode,
/// or the labeled split's where a mode has none).
fn demo_returns(demos: &ess_envs::Demos, k: usize) -> Vec<f64> {
    let per_mode = |s: &ess_envs::DemoSplit| {
        let mut sum = vec![0.0f64; k];
        let mut eps = vec![std::collections::BTreeSet::new(); k];
        for ((&m, &e), &r) in s.mode.iter().zip(&s.episode).zip(&s.reward) {
            if let Some(acc) = sum.get_mut(m as usize) {
                *acc += f64::from(r);
                eps[m as usize].insert(e);
            }
        }
        (sum, eps.iter().map(|e| e.len()).collect::<Vec<_>>())
    };
    let (u, ue) = per_mode(&demos.unlabeled);
    let (l, le) = per_mode(&demos.labeled);
    (0..k)
        .map(|m| match (ue[m], le[m]) {
            (0, 0) => 0.0,
            (0, n) => l[m] / n as f64,
            (n, _) => u[m] / n as f64,
        })
        .collect()
}

/// The result of one evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct EvalResult {
    /// Normalised mutual information between code and predicted mode.
    pub nmi: f64,
    /// Average entropy (rows and columns) of the confusion matrix.
    pub ent: f64,
    /// Mean over modes of the normalised task reward.
    pub normalized_reward: f64,
    /// Normalised task reward of each code on its matched mode.
    pub normalized_reward_per_code: Vec<f64>,
    /// Matched mode of each code (optimal one-to-one assignment).
    pub assignment: Vec<Option<usize>>,
    /// Fraction of steps classified as the mode with the code's own index (meaningful
    /// for methods that use labels, where code k should be mode k).
    pub label_accuracy: f64,
    /// Confusion counts, `[codes][classes]`.
    pub confusion: Vec<Vec<u64>>,
    /// Episodes evaluated per code.
    pub episodes_per_code: usize,
}

/// The episodes of an evaluation: for each code in order, `episodes` jobs whose eps and
/// reset seed are drawn from one stream seeded with `seed`.
pub fn eval_jobs(n_codes: usize, episodes: usize, seed: u64) -> Vec<EvalJob> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut jobs = Vec::with_capacity(n_codes * episodes);
    for code in 0..n_codes {
        for _ in 0..episodes {
            let eps = rng.random_range(-1.0..1.0);
            jobs.push(EvalJob {
                code,
                eps,
                seed: rng.random(),
            });
        }
    }
    jobs
}

/// Evaluates `w` with `episodes` deterministic episodes per code, run by `runner` (this
/// process's eval env, or the actor processes: the jobs and their order are the same, so
/// is the result); returns the result and the episodes (for plots).
pub fn evaluate(
    reference: &Reference,
    runner: &mut dyn EvalRunner,
    w: &PolicyWeights,
    latent: &LatentSpec,
    episodes: usize,
    seed: u64,
) -> anyhow::Result<(EvalResult, Vec<EvalEpisode>)> {
    let k = reference.expert_return.len();
    let (od, ad) = (w.obs_mean.len(), w.log_std.len());
    let n_codes = latent.n_codes;
    let mut confusion = Confusion::new(n_codes, k);
    let mut returns = vec![vec![0.0f64; k]; n_codes];
    let jobs = eval_jobs(n_codes, episodes, seed);
    let all = runner.run_eval(w, latent, &jobs)?;
    anyhow::ensure!(
        all.len() == jobs.len(),
        "evaluation returned {} episodes for {} jobs",
        all.len(),
        jobs.len()
    );
    for ep in &all {
        let code = ep.code;
        let rows = classifier_rows(&ep.next_obs, &ep.act, od, ad);
        for class in reference.classifier.predict(&rows) {
            confusion.add(code, class.min(k - 1))?;
        }
        for (m, r) in returns[code].iter_mut().enumerate() {
            *r += ep.mode_return(m) as f64 / episodes as f64;
        }
    }
    let assignment = best_assignment(&confusion);
    let per_code: Vec<f64> = assignment
        .iter()
        .enumerate()
        .map(|(code, m)| match m {
            Some(m) => normalized_reward(
                returns[code][*m],
                reference.random_return[*m],
                reference.expert_return[*m],
            ),
            None => 0.0,
        })
        .collect();
    let matched = (0..n_codes.min(k))
        .map(|c| confusion.row(c)[c])
        .sum::<u64>() as f64;
    let total = confusion.total().max(1) as f64;
    let result = EvalResult {
        nmi: nmi(&confusion),
        ent: ent(&confusion),
        normalized_reward: per_code.iter().sum::<f64>() / per_code.len().max(1) as f64,
        normalized_reward_per_code: per_code,
        assignment,
        label_accuracy: matched / total,
        confusion: (0..n_codes).map(|c| confusion.row(c).to_vec()).collect(),
        episodes_per_code: episodes,
    };
    Ok((result, all))
}
