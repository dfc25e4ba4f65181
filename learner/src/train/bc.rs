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

use crate::train::data::{Dims, ObsNorm, sample_idx};
use crate::train::ppo::PpoLearner;
use ess_envs::DemoSplit;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use tch::{Kind, Tensor, nn::Module};

/// Largest |a| cloned: `atanh` of a saturated action is unbounded.
const ACT_CLAMP: f64 = 0.995;

/// Squared-error losses of a warm start: at its first and its last step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BcLoss {
    /// Mean squared error of the first minibatch.
    pub first: f64,
    /// Mean squared error of the last minibatch.
    pub last: f64,
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
    let n = obs.size()[0];
    let eps: Vec<f32> = (0..n)
        .map(|_| {
            if use_eps {
                rng.random_range(-1.0..1.0)
            } else {
                0.0
            }
        })
        .collect();
    let modes: Vec<i64> = split.mode.iter().map(|&m| i64::from(m)).collect();
    let code = Tensor::from_slice(&modes)
        .one_hot(codes as i64)
        .to_kind(Kind::Float);
    let input = Tensor::cat(&[obs, Tensor::from_slice(&eps).view([-1, 1]), code], 1);
    let act = Tensor::from_slice(&split.act).view([-1, act_dim as i64]);
    (input, act.clamp(-ACT_CLAMP, ACT_CLAMP).atanh())
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
        let mean = ppo.policy.mean.forward(&input.index_select(0, &idx));
        let mse = (mean - target.index_select(0, &idx))
            .square()
            .mean(Kind::Float);
        ppo.opt.zero_grad();
        mse.backward();
        ppo.opt.step();
        if step == 0 {
            loss.first = mse.double_value(&[]);
        }
        if step + 1 == steps {
            loss.last = mse.double_value(&[]);
        }
    }
    Some(loss)
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
        let (vs, pvs) = (
            nn::VarStore::new(tch::Device::Cpu),
            nn::VarStore::new(tch::Device::Cpu),
        );
        let cfg = PpoConfig::default();
        let mut ppo = PpoLearner::new(
            &vs,
            &pvs,
            obs_dim + 1 + k,
            act_dim,
            k,
            &cfg,
            LatentPrior::Uniform,
            1.0,
        )
        .expect("learner");
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
        for (code, want) in [([1.0f32, 0.0], 0.5f64), ([0.0, 1.0], -0.5)] {
            let x = Tensor::from_slice(&[0.3f32, 1.0, 0.7, code[0], code[1]]).view([1, -1]);
            let a = ppo.policy.mean.forward(&x).tanh().double_value(&[0, 0]);
            assert!(
                (a - want).abs() < 0.05,
                "code {code:?}: action {a}, want {want}"
            );
        }
    }

    #[test]
    fn nothing_to_clone_is_no_warm_start() {
        let (vs, pvs) = (
            nn::VarStore::new(tch::Device::Cpu),
            nn::VarStore::new(tch::Device::Cpu),
        );
        let mut ppo = PpoLearner::new(
            &vs,
            &pvs,
            4,
            1,
            2,
            &PpoConfig::default(),
            LatentPrior::Uniform,
            1.0,
        )
        .expect("learner");
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
