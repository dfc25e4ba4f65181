//! `ess-learner`: the learning side of Ess and the `ess` command.
//!
//! It links the actor library (`ess-actor`) for two things: the single-process path,
//! where the actors are threads of the learner (`--actors 0`, the resume-exact path and
//! the tests' double), and the types both sides speak (`PolicyWeights`, `LatentSpec`,
//! the `RolloutSource` seam). The actor never links the learner: an
//! `ess-actor` process carries no libtorch and no tokio, only the pure-Rust policy
//! forward, the envs and iceoryx2.
//!
//! The parts, one folder each:
//!
//! | folder | what |
//! |---|---|
//! | [`train`] | the training loop (Algorithm 1) as a `Trainer` whose methods are its stages, for all seven methods; [`train::nets`] (policy, value, D with heads Q_c / Q_eps), [`train::ppo`] (PPO, GAE, p(c) through Gumbel-softmax), [`train::optim`] (Adam with a saveable state), [`train::checkpoint`] (what `--resume` continues bit for bit) |
//! | [`fused`] | the fused CPU backend of the update (`learner.backend`, default): D/Q steps, rewards, PPO and p(c) as passes over the networks' flat buffers, every gradient held to tch's autograd by tests |
//! | [`objective`] | every objective term, one file each headed by its equation, and their weighted sum for every preset ([`objective::combined`], Eq. 9) |
//! | [`eval`] | the paper's evaluation: behaviour [`eval::classifier`], NMI / ENT ([`eval::metrics`]), normalised reward; reports, Table 1 view ([`eval::table`]) and PNG figures ([`eval::plot`], [`eval::report`]) |
//! | [`logs`] | the logs a run keeps beside `metrics.csv` (the run log and TensorBoard's file) behind the loop's [`train::RecordSink`], so the training core knows neither |
//! | [`tboard`] | TensorBoard event files of a run (`tb/`): every `metrics.csv` number, the evaluations, the config and the figures |
//! | [`runlog`] | the MCAP run log `run.mcap` (writer, truncation-tolerant reader) and [`runlog::replay`] (`ess replay`) |
//! | [`control`] | the control plane: [`control::jobs`] (the job manager), [`control::serve`] (`ess serve`, gRPC), [`control::client`] (`ess job ...`) |
//! | [`import`] | `ess demos import`: Minari datasets ([`import::minari`]) and NumPy `.npz` ([`import::npz`]) into the demonstration file, labels, label ratio and provenance |
//! | [`export`] | `ess export RUN_DIR --onnx FILE`: the trained policy as a standard ONNX model ([`export::onnx`]) |
//! | [`experts`] | per-mode expert policies: PPO, and SAC ([`experts::sac`]) where PPO falls short |
//! | [`actors`] | the launcher and supervisor of `ess-actor` processes over iceoryx2 ([`actors::ShmActors`]) |
//! | [`remote`] | actor hosts on other machines over zenoh: [`remote::RemoteActors`] (the learner's side) and `ess actor-host` ([`remote::run_host`]) |
//!
//! Beside them: [`presets`] (the method presets, embedded), [`progress`] (`ess train
//! --progress jsonl`), [`malloc`] (glibc settings that spare the learner's steps page
//! faults), [`tensor_file`] (every learner safetensors file, written and read back with
//! checksums). The `ess` binary (`main.rs`) only parses and dispatches; each subcommand is
//! in `cli/<name>.rs`.

pub mod actors;
pub mod control;
pub mod eval;
pub mod experiment;
pub mod experts;
pub mod export;
pub mod fused;
pub mod import;
pub mod logs;
pub mod malloc;
pub mod objective;
pub mod presets;
pub mod progress;
pub mod remote;
pub mod runlog;
pub mod tboard;
pub mod tensor_file;
pub mod train;
