//! The fused CPU backend of the learner's update (`learner.backend = "fused"`, the
//! default): D/Q steps, the policy's reward, PPO and p(c), each a few passes over
//! contiguous f32 buffers instead of a graph of libtorch operations.
//!
//! **Why.** At the learner's sizes (MLPs 64-100 wide, batches of 1000-5000 rows) an
//! eager framework spends most of a step outside arithmetic: libtorch's dispatch and
//! autograd bookkeeping, one allocation and one memory pass per elementwise operation
//! (bench/learner.md measured the tch path at a third of the CPU's matrix-product rate
//! in a D/Q step, a fifth in a PPO step). Here a step is: gather the rows, the matrix
//! products ([`sgemm`], the `gemm` crate's AVX-512 kernels), one pass per layer for
//! bias and tanh, the loss terms' closed-form gradients, one pass per layer back, one
//! fused Adam pass.
//!
//! **One state, two backends.** The fused path keeps no copy of the networks: it
//! reads and updates the parameters and Adam moments where tch keeps them, the flat
//! buffers of [`crate::train::optim::Adam`] (via [`crate::train::optim::Adam::flat_mut`]).
//! tch stays the reference implementation and everything else: network construction
//! and initialisation, checkpoints (interchangeable between the backends: the same
//! buffers are saved), ONNX export, evaluation, the behaviour-cloning warm start, and
//! the configurations the fused path does not cover ([`not_covered`]: R1's gradient
//! penalty, which needs a double backward), for which the run says so in its log and
//! uses tch throughout.
//!
//! **Equal to tch.** Each loss term of [`terms`] and [`ppo`] names the tch function it
//! computes; tests hold every gradient and every Adam-updated weight of one update to
//! tch's autograd on every preset and task default (`tests.rs`). Random draws (the
//! minibatch indices, the contrastive noise) come from the same generators as on the
//! tch path, so the two backends train the same run up to float rounding.
//!
//! | file | what |
//! |---|---|
//! | [`sgemm`] | strided matrix products, checked (the `gemm` crate) |
//! | [`math`] | exp, ln, tanh, sigmoid, softplus and the layer passes over slices |
//! | `avx512` | those passes sixteen lanes at a time |
//! | [`mlp`] | layers and MLPs in the flat buffers, feature-major activations |
//! | [`terms`] | the D/Q terms: BCE (Eq. 1), Q_eps, Q_c CE (Eqs. 4-6), RIM (Eq. 8), NT-Xent |
//! | [`disc`] | one D/Q step (Eq. 9's D/Q side) |
//! | [`ppo`] | one PPO minibatch step, p(c) through Gumbel-softmax (Eq. 7) |
//! | [`reward`] | the policy's reward (Eq. 9's policy terms) and the value estimates |
//! | [`team`] | threads over the batch |

#[cfg(target_arch = "x86_64")]
mod avx512;
pub mod disc;
pub mod math;
pub mod mlp;
pub mod ppo;
pub mod reward;
pub mod sgemm;
pub mod team;
pub mod terms;

#[cfg(test)]
mod tests;

use crate::train::nets::{Discriminator, Mlp as TchMlp, Policy};
use crate::train::optim::Adam;
use ess_proto::TrainConfig;
use tch::{Kind, Tensor, nn};

pub use sgemm::ShapeError;

/// The fused backend cannot serve these networks.
#[derive(Debug, thiserror::Error)]
pub enum FusedError {
    /// A network's parameters are not where the fused path looks for them.
    #[error("fused learner: {0}")]
    Layout(String),
    /// An operand of the wrong shape (a bug, reported rather than a crash).
    #[error(transparent)]
    Shape(#[from] ShapeError),
    /// The worker threads did not start.
    #[error(transparent)]
    Team(#[from] team::TeamError),
}

/// Why the fused backend does not cover `cfg` (`None`: it does).
pub fn not_covered(cfg: &TrainConfig) -> Option<String> {
    if cfg.method.w_grad_penalty > 0.0 {
        return Some(
            "method.w_grad_penalty > 0 (R1's gradient penalty needs a double backward)".into(),
        );
    }
    if cfg.disc.hidden.is_empty() {
        return Some("disc.hidden is empty (a discriminator without a body)".into());
    }
    if cfg.env.n_modes > 64 {
        return Some(format!("env.n_modes = {} > 64", cfg.env.n_modes));
    }
    None
}

/// A contiguous CPU float tensor's values.
pub fn floats(t: &Tensor) -> Result<&[f32], FusedError> {
    view(t, Kind::Float)?;
    if t.numel() == 0 {
        return Ok(&[]);
    }
    // SAFETY: checked contiguous, CPU and f32 above; the slice borrows `t`, which keeps
    // the storage alive, and nothing writes to it while the borrow lasts.
    Ok(unsafe { std::slice::from_raw_parts(t.data_ptr() as *const f32, t.numel()) })
}

/// A contiguous CPU i64 tensor's values.
pub fn longs(t: &Tensor) -> Result<&[i64], FusedError> {
    view(t, Kind::Int64)?;
    if t.numel() == 0 {
        return Ok(&[]);
    }
    // SAFETY: as in [`floats`], for i64.
    Ok(unsafe { std::slice::from_raw_parts(t.data_ptr() as *const i64, t.numel()) })
}

fn view(t: &Tensor, kind: Kind) -> Result<(), FusedError> {
    if t.numel() > 0 && (t.kind() != kind || !t.is_contiguous() || t.device() != tch::Device::Cpu) {
        return Err(FusedError::Layout(format!(
            "a {:?} {:?} tensor on {:?} where a contiguous CPU {kind:?} one is read",
            t.kind(),
            t.size(),
            t.device()
        )));
    }
    Ok(())
}

/// Where `lin`'s weight and bias sit in `opt`'s flat buffer.
fn linear(opt: &Adam, lin: &nn::Linear) -> Result<mlp::Linear, FusedError> {
    let size = lin.ws.size();
    let bias = lin
        .bs
        .as_ref()
        .ok_or_else(|| FusedError::Layout("a layer without bias".into()))?;
    let at = |t: &Tensor| {
        opt.offset_of(t)
            .ok_or_else(|| FusedError::Layout("a layer outside its optimiser's buffer".into()))
    };
    match size[..] {
        [out, inp] => Ok(mlp::Linear {
            w: at(&lin.ws)?,
            b: at(bias)?,
            inp: inp as usize,
            out: out as usize,
        }),
        _ => Err(FusedError::Layout(format!(
            "a layer weight of shape {size:?}"
        ))),
    }
}

fn mlp_of(opt: &Adam, m: &TchMlp) -> Result<mlp::Mlp, FusedError> {
    Ok(mlp::Mlp {
        layers: m
            .layers()
            .iter()
            .map(|l| linear(opt, l))
            .collect::<Result<_, _>>()?,
        tanh_last: m.tanh_out(),
    })
}

/// The fused backend of one run: the networks' layouts, the threads, the steps'
/// buffers.
pub struct Fused {
    /// Worker threads.
    pub team: team::Team,
    /// D's layout.
    pub disc_net: disc::DiscNet,
    /// The policy's and value's layout.
    pub policy: ppo::PolicyNet,
    /// D/Q step buffers.
    pub disc: disc::DiscStep,
    /// PPO step buffers.
    pub ppo: ppo::PpoStep,
    /// Reward pass buffers.
    pub reward: reward::RewardPass,
}

/// The networks and optimisers the fused passes run on, borrowed from the run's
/// (`crate::train::Nets::fused_view`): the backend reads their layouts, not the run.
#[derive(Clone, Copy)]
pub struct NetsView<'a> {
    /// D's body and heads.
    pub disc: &'a Discriminator,
    /// Their optimiser.
    pub dopt: &'a Adam,
    /// The policy.
    pub policy: &'a Policy,
    /// The value network.
    pub value: &'a TchMlp,
    /// The policy's and value's optimiser.
    pub opt: &'a Adam,
    /// The p(c) logits' optimiser.
    pub prior_opt: &'a Adam,
}

impl Fused {
    /// The backend for the networks of `nets`, on `threads` threads.
    pub fn new(nets: NetsView<'_>, threads: usize) -> Result<Self, FusedError> {
        let d = nets.disc;
        let dopt = nets.dopt;
        let disc_net = disc::DiscNet {
            body: mlp_of(dopt, &d.body)?,
            heads: [
                linear(dopt, &d.d)?,
                linear(dopt, &d.qc)?,
                linear(dopt, &d.qeps)?,
            ],
            k: d.qc.ws.size()[0] as usize,
        };
        let (pol, opt) = (nets.policy, nets.opt);
        let policy = ppo::PolicyNet {
            mean: mlp_of(opt, &pol.mean)?,
            log_std: opt.offset_of(&pol.log_std).ok_or_else(|| {
                FusedError::Layout("log_std outside the policy's optimiser".into())
            })?,
            value: mlp_of(opt, nets.value)?,
        };
        if nets.prior_opt.len() != disc_net.k {
            return Err(FusedError::Layout(
                "p(c)'s optimiser holds more than its logits".into(),
            ));
        }
        Ok(Self {
            team: team::Team::new(threads)?,
            disc_net,
            policy,
            disc: Default::default(),
            ppo: Default::default(),
            reward: Default::default(),
        })
    }
}
