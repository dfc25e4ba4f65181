//! Behaviour cloning of the labeled demonstrations: the warm start (`ppo.bc_steps`),
//! before the first iteration, fits the policy's mean network to the labeled
//! demonstrations, each with its own code, so every code starts near its mode's
//! behaviour instead of from scratch; `ppo.bc_steps_per_iter` takes the same steps
//! after every PPO update, an auxiliary cloning loss (as DAPG's) that keeps each code
//! near its mode while the imitation rewards train it.
//!
//! Not part of the paper (the original InfoGAIL paper initialises its policy this
//! way). It reads only the labeled few, the same data Eq. 4 gives Q_c, so the
//! semi-supervised setting is kept. The loss is the squared error between the mean and
//! the pre-tanh demonstrated action, `atanh(a)` (the policy acts with `tanh(u)`); eps
//! is drawn as in the rollouts, so the clone does not depend on it. The steps use the
//! PPO optimiser, so PPO starts from the cloning's Adam moments (the value network gets
//! no gradient). Between PPO updates, that shared Adam moves the parameters the
//! cloning does not reach (the value network, log std) along their moments for those
//! steps, as a decaying continuation of PPO's last direction.
//!
//! `ppo.bc_unlabeled_steps_per_iter` adds cloning steps on the *unlabeled*
//! demonstrations, each row under the code Q_c reads for it (its most probable code,
//! on rows Q_c gives at least [`ENCODED_MIN_PROB`]; the rest are skipped). Q_c is the
//! method's own encoder, trained on the labeled few (Eq. 4) and the policy's codes, so
//! no true label of an unlabeled row is read and the semi-supervised setting holds.
//! Why: on Humanoid the labeled few are ~5 episodes, ~4 of them forward, and a clone
//! of 4 running episodes falls within ~80 steps (bench/humanoid.md); the unlabeled
//! set holds ~50 times more of every mode. `ppo.bc_unlabeled_balanced` draws those rows
//! equally from each code Q_c reads instead of in the demonstrations' proportions.

use crate::train::data::{Dims, ObsNorm, sample_idx};
use crate::train::nets::Discriminator;
use crate::train::ppo::PpoLearner;
use ess_envs::DemoSplit;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tch::{Kind, Tensor, nn::Module};

/// Largest |a| cloned: `atanh` of a saturated action is unbounded.
const ACT_CLAMP: f64 = 0.995;

/// Smallest Q_c probability of its most probable code at which an unlabeled row is
/// cloned under that code.
pub const ENCODED_MIN_PROB: f64 = 0.9;

/// Squared-error losses of a warm start: at its first and its last step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BcLoss {
    /// Mean squared error of the first minibatch.
    pub first: f64,
    /// Mean squared error of the last minibatch.
    pub last: f64,
}

/// `n` eps values drawn as in the rollouts (0 when the method has none).
fn draw_eps(n: usize, use_eps: bool, rng: &mut ChaCha8Rng) -> Tensor {
    let eps: Vec<f32> = (0..n)
        .map(|_| {
            if use_eps {
                rng.random_range(-1.0..1.0)
            } else {
                0.0
            }
        })
        .collect();
    Tensor::from_slice(&eps).view([-1, 1])
}

/// The policy inputs `[norm(obs), eps, one_hot(mode)]` for normalised `obs` and
/// `modes` `[n]` (i64).
fn policy_input(obs_n: Tensor, modes: &Tensor, codes: usize, eps: Tensor) -> Tensor {
    let code = modes.one_hot(codes as i64).to_kind(Kind::Float);
    Tensor::cat(&[obs_n, eps, code], 1)
}

/// The pre-tanh targets `atanh(a)` of `act` rows.
fn pre_tanh(act: &[f32], act_dim: usize) -> Tensor {
    let act = Tensor::from_slice(act).view([-1, act_dim as i64]);
    act.clamp(-ACT_CLAMP, ACT_CLAMP).atanh()
}

/// The policy inputs `[norm(obs), eps, one_hot(mode)]` and pre-tanh targets of `split`.
fn cloning_data(
    split: &DemoSplit,
    norm: &ObsNorm,
    act_dim: usize,
    codes: usize,
    use_eps: bool,
    rng: &mut ChaCha8Rng,
) -> (Tensor, Tensor) {
    let obs = norm.apply(&split.obs);
    let eps = draw_eps(obs.size()[0] as usize, use_eps, rng);
    let modes: Vec<i64> = split.mode.iter().map(|&m| i64::from(m)).collect();
    let input = policy_input(obs, &Tensor::from_slice(&modes), codes, eps);
    (input, pre_tanh(&split.act, act_dim))
}

/// One Adam step of the policy's mean toward `target`, rows weighted by `weight`
/// (`None`: all rows alike); the weighted mean squared error before the step.
fn mse_step(ppo: &mut PpoLearner, input: &Tensor, target: &Tensor, weight: Option<&Tensor>) -> f64 {
    let err = (ppo.policy.mean.forward(input) - target).square();
    let mse = match weight {
        None => err.mean(Kind::Float),
        Some(w) => {
            let per_row = err.mean_dim(1, false, Kind::Float);
            (per_row * w).sum(Kind::Float) / w.sum(Kind::Float).clamp_min(1.0)
        }
    };
    ppo.opt.zero_grad();
    mse.backward();
    ppo.opt.step();
    mse.double_value(&[])
}

/// `steps` minibatch steps (`batch` rows each) of behaviour cloning on `labeled`.
/// `None` when there is nothing to clone (no steps, or no labeled demonstrations).
pub fn clone_steps(
    ppo: &mut PpoLearner,
    labeled: &DemoSplit,
    norm: &ObsNorm,
    (d, use_eps): (Dims, bool),
    (steps, batch): (usize, usize),
    rng: &mut ChaCha8Rng,
) -> Option<BcLoss> {
    if steps == 0 || labeled.mode.is_empty() {
        return None;
    }
    let (input, target) = cloning_data(labeled, norm, d.act, d.codes, use_eps, rng);
    let n = input.size()[0];
    let mut loss = BcLoss {
        first: f64::NAN,
        last: f64::NAN,
    };
    for step in 0..steps {
        let idx = Tensor::from_slice(&sample_idx(rng, n, batch as i64));
        let (x, y) = (input.index_select(0, &idx), target.index_select(0, &idx));
        loss.record(step, steps, mse_step(ppo, &x, &y, None));
    }
    Some(loss)
}

/// An encoder's logits on D's inputs (Q_c's: [`qc_logits`]).
pub type QcFn<'a> = &'a dyn Fn(&Tensor) -> Tensor;

/// How [`clone_encoded_steps`] draws the unlabeled rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodedDraw {
    /// Uniformly, i.e. in the demonstrations' proportions of the modes.
    Proportional,
    /// Equally from each code Q_c reads (all rows read once per call).
    Balanced,
}

/// `steps` minibatch steps (`batch` rows each) of behaviour cloning on the
/// `unlabeled` demonstrations (`disc_x`: their rows as D reads them), each row under
/// the most probable code of `qc`'s logits (Q_c's: [`qc_logits`]); rows `qc` gives
/// less than [`ENCODED_MIN_PROB`] weigh nothing. The rows' own `mode` is never read.
/// `None` when there is nothing to clone.
pub fn clone_encoded_steps(
    ppo: &mut PpoLearner,
    (qc, disc_x, draw): (QcFn<'_>, &Tensor, EncodedDraw),
    unlabeled: &DemoSplit,
    norm: &ObsNorm,
    (d, use_eps): (Dims, bool),
    (steps, batch): (usize, usize),
    rng: &mut ChaCha8Rng,
) -> Option<BcLoss> {
    let n = unlabeled.mode.len();
    if steps == 0 || n == 0 {
        return None;
    }
    let by_code = (draw == EncodedDraw::Balanced).then(|| rows_by_code(qc, disc_x, d.codes));
    if by_code
        .as_ref()
        .is_some_and(|b| b.iter().all(Vec::is_empty))
    {
        return None;
    }
    let mut loss = BcLoss {
        first: f64::NAN,
        last: f64::NAN,
    };
    for step in 0..steps {
        let (idx, code, weight) = match &by_code {
            Some(by_code) => {
                let (idx, code) = draw_balanced(by_code, batch, rng);
                (idx, Tensor::from_slice(&code), None)
            }
            None => {
                let idx = sample_idx(rng, n as i64, batch as i64);
                let (prob, code) =
                    read_codes(qc, &disc_x.index_select(0, &Tensor::from_slice(&idx)));
                (
                    idx,
                    code,
                    Some(prob.ge(ENCODED_MIN_PROB).to_kind(Kind::Float)),
                )
            }
        };
        let rows = |v: &[f32], w: usize| -> Vec<f32> {
            idx.iter()
                .flat_map(|&i| &v[i as usize * w..(i as usize + 1) * w])
                .copied()
                .collect()
        };
        let (obs, act) = (rows(&unlabeled.obs, d.obs), rows(&unlabeled.act, d.act));
        let eps = draw_eps(idx.len(), use_eps, rng);
        let x = policy_input(norm.apply(&obs), &code, d.codes, eps);
        let mse = mse_step(ppo, &x, &pre_tanh(&act, d.act), weight.as_ref());
        loss.record(step, steps, mse);
    }
    Some(loss)
}

/// The probability and index of the most probable code of `qc` on `x`.
fn read_codes(qc: QcFn<'_>, x: &Tensor) -> (Tensor, Tensor) {
    tch::no_grad(|| qc(x).softmax(-1, Kind::Float).max_dim(1, false))
}

/// Rows per read: bounds the memory of reading every unlabeled row.
const READ_CHUNK: i64 = 16_384;

/// The rows of `disc_x` under each of the `codes` codes `qc` reads for them, rows
/// it gives less than [`ENCODED_MIN_PROB`] left out.
fn rows_by_code(qc: QcFn<'_>, disc_x: &Tensor, codes: usize) -> Vec<Vec<i64>> {
    let mut by_code = vec![Vec::new(); codes];
    let n = disc_x.size()[0];
    for start in (0..n).step_by(READ_CHUNK as usize) {
        let len = READ_CHUNK.min(n - start);
        let (prob, code) = read_codes(qc, &disc_x.narrow(0, start, len));
        let prob = Vec::<f32>::try_from(&prob).unwrap_or_default();
        let code = Vec::<i64>::try_from(&code).unwrap_or_default();
        for (i, (p, c)) in prob.iter().zip(&code).enumerate() {
            if f64::from(*p) >= ENCODED_MIN_PROB {
                by_code[*c as usize].push(start + i as i64);
            }
        }
    }
    by_code
}

/// `batch` rows drawn equally from each non-empty list of `by_code` (its index is
/// the rows' code), and their codes.
fn draw_balanced(by_code: &[Vec<i64>], batch: usize, rng: &mut ChaCha8Rng) -> (Vec<i64>, Vec<i64>) {
    let present: Vec<usize> = (0..by_code.len())
        .filter(|&c| !by_code[c].is_empty())
        .collect();
    let (mut idx, mut code) = (Vec::with_capacity(batch), Vec::with_capacity(batch));
    for j in 0..batch {
        let c = present[j % present.len()];
        idx.push(by_code[c][rng.random_range(0..by_code[c].len())]);
        code.push(c as i64);
    }
    (idx, code)
}

/// Q_c's logits of `disc` on D's inputs `x`, for [`clone_encoded_steps`].
pub fn qc_logits(disc: &Discriminator) -> impl Fn(&Tensor) -> Tensor + '_ {
    move |x| disc.forward(x).qc_logits
}

impl BcLoss {
    /// Keeps `mse` if `step` is the first or the last of `steps`.
    fn record(&mut self, step: usize, steps: usize, mse: f64) {
        if step == 0 {
            self.first = mse;
        }
        if step + 1 == steps {
            self.last = mse;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ess_proto::config::{LatentPrior, PpoConfig};
    use rand::SeedableRng;
    use tch::nn;

    /// Two modes whose demonstrated action is a different constant: after cloning, the
    /// deterministic action of each code is its mode's.
    #[test]
    fn cloning_makes_each_code_act_as_its_labeled_mode() {
        tch::manual_seed(0);
        let (obs_dim, act_dim, k) = (2, 1, 2);
        let mut split = DemoSplit::default();
        for i in 0..200 {
            let m = (i % 2) as u32;
            split.obs.extend_from_slice(&[i as f32 / 200.0, 1.0]);
            split.act.push(if m == 0 { 0.5 } else { -0.5 });
            split.mode.push(m);
        }
        let norm = ObsNorm {
            mean: vec![0.0; obs_dim],
            std: vec![1.0; obs_dim],
        };
        let (_vs, _pvs, mut ppo) = learner(obs_dim, k);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let d = Dims {
            obs: obs_dim,
            act: act_dim,
            codes: k,
            disc_cols: obs_dim,
            disc_act: act_dim,
        };
        let loss = clone_steps(&mut ppo, &split, &norm, (d, true), (400, 64), &mut rng)
            .expect("labeled data");
        assert!(loss.last < 0.01 * loss.first, "{loss:?}");
        assert_codes_act_half_and_minus_half(&ppo);
    }

    /// At the input `[0.3, 1.0]` (eps 0.7) code 0 acts 0.5 and code 1 acts -0.5.
    fn assert_codes_act_half_and_minus_half(ppo: &PpoLearner) {
        for (code, want) in [([1.0f32, 0.0], 0.5f64), ([0.0, 1.0], -0.5)] {
            let x = Tensor::from_slice(&[0.3f32, 1.0, 0.7, code[0], code[1]]).view([1, -1]);
            let a = ppo.policy.mean.forward(&x).tanh().double_value(&[0, 0]);
            assert!(
                (a - want).abs() < 0.05,
                "code {code:?}: action {a}, want {want}"
            );
        }
    }

    /// A learner for `obs_dim` inputs, one action and `k` codes.
    fn learner(obs_dim: usize, k: usize) -> (nn::VarStore, nn::VarStore, PpoLearner) {
        let (vs, pvs) = (
            nn::VarStore::new(tch::Device::Cpu),
            nn::VarStore::new(tch::Device::Cpu),
        );
        let cfg = PpoConfig::default();
        let ppo = PpoLearner::new(
            &vs,
            &pvs,
            obs_dim + 1 + k,
            1,
            k,
            &cfg,
            LatentPrior::Uniform,
            1.0,
        )
        .expect("learner");
        (vs, pvs, ppo)
    }

    /// Unlabeled rows at `[i / 200, 1]` acting `0.5 * side` (side +1 or -1, so the
    /// policy's inputs cannot tell the two apart; only the code can), all (wrongly)
    /// marked mode 0, for two codes; D's inputs are the actions alone.
    fn two_sided_rows() -> (DemoSplit, Tensor, ObsNorm, Dims) {
        let mut split = DemoSplit::default();
        for i in 0..200 {
            let side = if i % 2 == 0 { 1.0f32 } else { -1.0 };
            split.obs.extend_from_slice(&[i as f32 / 200.0, 1.0]);
            split.act.push(0.5 * side);
            split.mode.push(0);
        }
        let x = Tensor::from_slice(&split.act).view([-1, 1]);
        let norm = ObsNorm {
            mean: vec![0.0; 2],
            std: vec![1.0; 2],
        };
        let d = Dims {
            obs: 2,
            act: 1,
            codes: 2,
            disc_cols: 0,
            disc_act: 1,
        };
        (split, x, norm, d)
    }

    /// An encoder that reads code 0 where the action is > 0 and code 1 where it is < 0,
    /// `sure` saying how sure (logit gap 5, or 0.1: a 52% guess).
    fn side_encoder(sure: bool) -> impl Fn(&Tensor) -> Tensor {
        let gap = if sure { 5.0 } else { 0.1 };
        move |x: &Tensor| Tensor::cat(&[x * gap, x * -gap], 1)
    }

    /// The unlabeled rows are cloned under the encoder's codes, not their own marks.
    #[test]
    fn unlabeled_rows_are_cloned_under_the_encoders_codes() {
        tch::manual_seed(0);
        let (split, x, norm, d) = two_sided_rows();
        let (_vs, _pvs, mut ppo) = learner(2, 2);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let qc = side_encoder(true);
        let enc = (&qc as QcFn<'_>, &x, EncodedDraw::Proportional);
        let loss =
            clone_encoded_steps(&mut ppo, enc, &split, &norm, (d, true), (400, 64), &mut rng)
                .expect("unlabeled data");
        assert!(loss.last < 0.01 * loss.first, "{loss:?}");
        assert_codes_act_half_and_minus_half(&ppo);
    }

    /// Rows the encoder is unsure of weigh nothing: the policy does not move.
    #[test]
    fn rows_the_encoder_is_unsure_of_are_not_cloned() {
        tch::manual_seed(0);
        let (split, x, norm, d) = two_sided_rows();
        let (_vs, _pvs, mut ppo) = learner(2, 2);
        let before = ppo
            .policy
            .mean
            .forward(&Tensor::ones([1, 5], (Kind::Float, tch::Device::Cpu)));
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let qc = side_encoder(false);
        let enc = (&qc as QcFn<'_>, &x, EncodedDraw::Proportional);
        let loss = clone_encoded_steps(&mut ppo, enc, &split, &norm, (d, true), (50, 64), &mut rng)
            .expect("unlabeled data");
        assert_eq!((loss.first, loss.last), (0.0, 0.0));
        let after = ppo
            .policy
            .mean
            .forward(&Tensor::ones([1, 5], (Kind::Float, tch::Device::Cpu)));
        assert_eq!(before.double_value(&[0, 0]), after.double_value(&[0, 0]));
    }

    /// Balanced draws take each code Q_c reads equally often, whatever its share, and
    /// only the rows it is sure of.
    #[test]
    fn balanced_draws_take_each_read_code_equally() {
        // 90 rows read as code 0, 10 as code 1, 10 unsure (gap 0.1), none as code 2.
        let side: Vec<f32> = (0..110)
            .map(|i| match i {
                0..90 => 1.0,
                90..100 => -1.0,
                _ => 0.01,
            })
            .collect();
        let x = Tensor::from_slice(&side).view([-1, 1]);
        let qc = |x: &Tensor| Tensor::cat(&[x * 5.0, x * -5.0, x * 0.0 - 10.0], 1);
        let by_code = rows_by_code(&qc, &x, 3);
        assert_eq!(by_code[0], (0..90).collect::<Vec<i64>>());
        assert_eq!(by_code[1], (90..100).collect::<Vec<i64>>());
        assert!(by_code[2].is_empty());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (idx, code) = draw_balanced(&by_code, 1000, &mut rng);
        assert_eq!(code.iter().filter(|&&c| c == 0).count(), 500);
        assert_eq!(code.iter().filter(|&&c| c == 1).count(), 500);
        for (i, c) in idx.iter().zip(&code) {
            assert!(
                by_code[*c as usize].contains(i),
                "row {i} drawn under code {c}"
            );
        }
    }

    #[test]
    fn nothing_to_clone_is_no_warm_start() {
        let (_vs, _pvs, mut ppo) = learner(1, 2);
        let norm = ObsNorm {
            mean: vec![0.0],
            std: vec![1.0],
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let empty = DemoSplit::default();
        let d = Dims {
            obs: 1,
            act: 1,
            codes: 2,
            disc_cols: 1,
            disc_act: 1,
        };
        assert_eq!(
            clone_steps(&mut ppo, &empty, &norm, (d, true), (10, 8), &mut rng),
            None
        );
    }
}
