//! `ess-learner`: the learning side of Ess and the `ess` command.
//!
//! - [`actors`]: `ess-actor` processes over iceoryx2 shared memory ([`actors::ShmActors`]).
//! - [`checkpoint`]: full checkpoints that `ess train --resume` continues bit-identically.
//! - [`nets`]: tch networks (policy, value, discriminator body with D / Q_c / Q_eps heads).
//! - [`objective`]: every objective term, one file each, headed by its equation.
//! - [`optim`]: Adam with a saveable state (checkpoints).
//! - [`ppo`]: PPO with GAE, including the p(c) update through Gumbel-softmax.
//! - [`experts`]: PPO experts on each mode's task reward, and their evaluation.
//! - [`train`]: Algorithm 1 for all seven methods (presets in `deploy/presets/`).
//! - [`classifier`], [`eval`], [`metrics`]: the paper's evaluation (NMI, ENT, normalised
//!   task reward).
//! - [`presets`]: the method presets, embedded in the binary.
//! - [`plot`], [`report`]: PNG figures.
//! - [`runlog`]: the MCAP run log `run.mcap` (writer, truncation-tolerant reader);
//!   [`replay`]: `ess replay`, re-simulating its evaluation episodes.
//! - [`progress`]: `ess train --progress jsonl`, the machine-readable progress stream.
//! - [`jobs`], [`serve`], [`client`]: the control plane (`ess serve`, `ess job ...`).
//! - [`malloc`]: glibc allocator settings that spare the learner's steps page faults.

pub mod actors;
pub mod checkpoint;
pub mod classifier;
pub mod client;
pub mod eval;
pub mod experts;
pub mod jobs;
pub mod malloc;
pub mod metrics;
pub mod nets;
pub mod objective;
pub mod optim;
pub mod plot;
pub mod ppo;
pub mod presets;
pub mod progress;
pub mod replay;
pub mod report;
pub mod runlog;
pub mod sac;
pub mod serve;
pub mod table;
pub mod train;
