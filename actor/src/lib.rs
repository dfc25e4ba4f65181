//! `ess-actor`: the acting side of Ess.
//!
//! Actors step environments under sampled latents `(c, eps)` with a pure-Rust forward
//! pass of the policy (no libtorch here: see [`ess_proto::mlp`]), and hand the learner chunks of
//! transitions through a [`transport::RolloutSource`]. Evaluation episodes with a given
//! one-hot code run here too ([`rollout::eval_episode`]). [`shm`] is the iceoryx2
//! transport of actor processes (the `ess-actor` binary); [`logging`] is both
//! binaries' log set-up.

pub mod logging;
pub mod policy;
pub mod rollout;
pub mod shm;
pub mod state_msg;
pub mod transport;

pub use ess_proto::Mlp;
pub use policy::{Actor, LatentSpec, PolicyWeights, gumbel_softmax};
pub use rollout::{ActorError, EvalEpisode, Worker, WorkerState, eval_episode};
pub use transport::{
    EvalJob, EvalRunner, LocalEval, RolloutSource, ThreadedActors, actor_seed, split_steps,
};
