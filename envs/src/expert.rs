//! Trained expert policies and the envs they drive (paper Sec. 4, "Multi-modal
//! demonstrations preparation": "we first pre-train K expert policies, each
//! corresponding to K different goals").
//!
//! An [`ExpertPolicy`] is one behaviour mode's PPO policy as `ess experts train` saves
//! it: a tanh MLP for the Gaussian mean (evaluated with the pure-Rust
//! [`ess_proto::Mlp`]), a state-independent log standard deviation, and the
//! observation normalisation it was trained with. Actions are `tanh(mean + std * n)`,
//! `n ~ N(0, I)` (or `tanh(mean)` deterministically), exactly how it acted in training.
//!
//! ## File format (`format = "ess-expert"`, version 2)
//! A safetensors file with `f32` tensors `params` (the flat MLP parameters in
//! [`ess_proto::MlpLayout`] order), `log_std` `[act_dim]`, `obs_mean` and `obs_std`
//! `[obs_dim]`, and a JSON [`ExpertMeta`] under the header key `meta`: env name, mode,
//! mode count, dims, layer sizes, how many zero inputs follow the observation (the
//! trainer's unused eps/code slots), training steps and the final mean return; and
//! `ess.sha256`, the checksums of every tensor and of the other entries
//! ([`ess_proto::checksum`]). Version 1 files (before checksums) still load, unverified.
//! [`ExpertPolicy::load`] validates all of it and names the file and field on error;
//! [`ExpertPolicy::check_fits`] refuses an expert of another env, mode or shape.
//!
//! ## Where experts live
//! `deploy/experts/<env>/mode<k>.safetensors` in the repository (small files, shipped so
//! demonstrations regenerate deterministically without retraining); the
//! `ESS_EXPERTS_DIR` environment variable points elsewhere ([`experts_dir`]).
//!
//! [`ExpertEnv`] wraps any [`Env`] with one expert per mode and so implements
//! [`ScriptedExpert`]: demonstrations, the behaviour classifier and the expert returns
//! of the evaluation come from it exactly as from a scripted expert.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use ess_proto::{Mlp, MlpLayout};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use safetensors::tensor::{Dtype, TensorView};
use serde::{Deserialize, Serialize};

use crate::env::{Env, EnvError, EnvSpec, ScriptedExpert, StepOutcome};

/// Value of the `format` header key.
pub const FORMAT: &str = "ess-expert";
/// The `format_version` this build writes (sealed with checksums).
pub const FORMAT_VERSION: u32 = 2;
/// The version before checksums: still read, without them.
const UNSEALED_VERSION: u32 = 1;
/// The format as [`ess_proto::checksum::open`] checks it.
const FILE_FORMAT: ess_proto::checksum::Format = ess_proto::checksum::Format {
    name: FORMAT,
    current: FORMAT_VERSION,
    unsealed: UNSEALED_VERSION,
};

/// What an expert file says about itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpertMeta {
    /// Environment name (as `make_env` takes it).
    pub env: String,
    /// Behaviour mode the expert was trained for.
    pub mode: usize,
    /// Number of modes of the env it was trained in.
    pub n_modes: usize,
    /// Observation length.
    pub obs_dim: usize,
    /// Action length.
    pub act_dim: usize,
    /// Layer widths of the mean MLP, input first.
    pub sizes: Vec<usize>,
    /// Zero inputs appended after the normalised observation.
    pub extra_inputs: usize,
    /// Env steps the expert was trained for.
    pub trained_steps: u64,
    /// Mean task return of its last training episodes.
    pub mean_return: f64,
    /// What wrote the file.
    pub generator: String,
}

/// What makes an expert file's contents unusable; each names the field or tensor.
#[derive(Debug, thiserror::Error)]
pub enum ExpertFileError {
    /// The container (safetensors with checksums) cannot be read or written.
    #[error("{0}")]
    Container(String),
    /// The `meta` header is not the expected JSON.
    #[error("header meta: {0}")]
    Meta(String),
    /// `meta.sizes` names fewer than two layers.
    #[error("meta.sizes = {0:?}: needs input and output")]
    Sizes(Vec<usize>),
    /// The first layer's width is not the observation plus the extra inputs.
    #[error("meta.sizes[0] = {first} but obs_dim + extra_inputs = {inputs}")]
    InputWidth {
        /// `meta.sizes[0]`.
        first: usize,
        /// `obs_dim + extra_inputs`.
        inputs: usize,
    },
    /// The last layer's width is not the action's.
    #[error("meta.sizes ends in {last:?} but act_dim = {act_dim}")]
    OutputWidth {
        /// The last size.
        last: Option<usize>,
        /// `meta.act_dim`.
        act_dim: usize,
    },
    /// `meta.mode` is not one of the env's modes.
    #[error("meta.mode = {mode} is not below meta.n_modes = {n_modes}")]
    Mode {
        /// `meta.mode`.
        mode: usize,
        /// `meta.n_modes`.
        n_modes: usize,
    },
    /// A tensor is missing.
    #[error("tensor {0:?} is missing")]
    Missing(String),
    /// A tensor is not a rank-1 F32 tensor.
    #[error("tensor {name:?} has dtype {dtype} shape {shape:?}, expected F32 of rank 1")]
    Kind {
        /// Tensor.
        name: String,
        /// Its dtype.
        dtype: String,
        /// Its shape.
        shape: Vec<usize>,
    },
    /// The MLP parameters do not fit `meta.sizes`.
    #[error("tensor \"params\": {0}")]
    Params(String),
    /// A tensor has the wrong length.
    #[error("tensor {name:?} has {got} values, expected {want}")]
    Length {
        /// Tensor.
        name: &'static str,
        /// Values found.
        got: usize,
        /// Values expected.
        want: usize,
    },
    /// A value is NaN or infinite.
    #[error("tensor {name:?}[{index}] = {value} is not finite")]
    NotFinite {
        /// Tensor.
        name: &'static str,
        /// Index.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A standard deviation is not positive.
    #[error("tensor \"obs_std\"[{index}] = {value} must be > 0")]
    StdNotPositive {
        /// Index.
        index: usize,
        /// The value.
        value: f32,
    },
}

/// Errors of expert files.
#[derive(Debug, thiserror::Error)]
pub enum ExpertError {
    /// Reading or writing failed.
    #[error("{path}: I/O error: {source}")]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// No expert file where one was looked for.
    #[error(
        "no expert for env {env:?} mode {mode} at {path}; train one with `ess experts train --env {env} --mode {mode}` or set ESS_EXPERTS_DIR"
    )]
    Missing {
        /// Env name.
        env: String,
        /// Mode.
        mode: usize,
        /// Where it was looked for.
        path: PathBuf,
    },
    /// The file is not a valid expert file.
    #[error("{path}: invalid expert file: {source}")]
    Invalid {
        /// File.
        path: PathBuf,
        /// What is wrong (names the key, tensor or field).
        #[source]
        source: ExpertFileError,
    },
    /// The expert was trained for another env, mode or shape.
    #[error("{path}: expert does not fit: {reason}")]
    Mismatch {
        /// File.
        path: PathBuf,
        /// Which field differs, with both values.
        reason: String,
    },
    /// Environment error while driving the expert.
    #[error(transparent)]
    Env(#[from] EnvError),
}

/// One mode's trained policy; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct ExpertPolicy {
    /// What the file says about itself.
    pub meta: ExpertMeta,
    mean: Mlp,
    log_std: Vec<f32>,
    obs_mean: Vec<f32>,
    obs_std: Vec<f32>,
}

/// Reusable buffers for [`ExpertPolicy::act`].
#[derive(Debug, Clone, Default)]
pub struct ExpertScratch {
    input: Vec<f32>,
    out: Vec<f32>,
    scratch: Vec<f32>,
}

impl ExpertPolicy {
    /// Builds an expert from its parts, checking every length against `meta`.
    pub fn new(
        meta: ExpertMeta,
        params: Vec<f32>,
        log_std: Vec<f32>,
        obs_mean: Vec<f32>,
        obs_std: Vec<f32>,
    ) -> Result<Self, ExpertFileError> {
        use ExpertFileError as E;
        if meta.sizes.len() < 2 {
            return Err(E::Sizes(meta.sizes.clone()));
        }
        if meta.sizes[0] != meta.obs_dim + meta.extra_inputs {
            return Err(E::InputWidth {
                first: meta.sizes[0],
                inputs: meta.obs_dim + meta.extra_inputs,
            });
        }
        if meta.sizes.last() != Some(&meta.act_dim) {
            return Err(E::OutputWidth {
                last: meta.sizes.last().copied(),
                act_dim: meta.act_dim,
            });
        }
        if meta.mode >= meta.n_modes {
            return Err(E::Mode {
                mode: meta.mode,
                n_modes: meta.n_modes,
            });
        }
        let layout = MlpLayout {
            sizes: meta.sizes.clone(),
        };
        let mean = Mlp::new(layout, params).map_err(|e| E::Params(e.to_string()))?;
        for (name, v, n) in [
            ("log_std", &log_std, meta.act_dim),
            ("obs_mean", &obs_mean, meta.obs_dim),
            ("obs_std", &obs_std, meta.obs_dim),
        ] {
            if v.len() != n {
                return Err(E::Length {
                    name,
                    got: v.len(),
                    want: n,
                });
            }
            if let Some(index) = v.iter().position(|x| !x.is_finite()) {
                let value = v[index];
                return Err(E::NotFinite { name, index, value });
            }
        }
        if let Some(index) = obs_std.iter().position(|&s| s <= 0.0) {
            let value = obs_std[index];
            return Err(E::StdNotPositive { index, value });
        }
        if let Some(index) = mean.params().iter().position(|x| !x.is_finite()) {
            let value = mean.params()[index];
            return Err(E::NotFinite {
                name: "params",
                index,
                value,
            });
        }
        Ok(Self {
            meta,
            mean,
            log_std,
            obs_mean,
            obs_std,
        })
    }

    /// The observation normalisation `(mean, std)` it was trained with.
    pub fn obs_stats(&self) -> (&[f32], &[f32]) {
        (&self.obs_mean, &self.obs_std)
    }

    /// The mean network's flat parameters.
    pub fn params(&self) -> &[f32] {
        self.mean.params()
    }

    /// Serialises to safetensors bytes (see the module docs).
    pub fn to_bytes(&self) -> Result<Vec<u8>, ExpertFileError> {
        let container = |e: &dyn std::fmt::Display| ExpertFileError::Container(e.to_string());
        let meta =
            serde_json::to_string(&self.meta).map_err(|e| ExpertFileError::Meta(e.to_string()))?;
        let raw: Vec<(&str, Vec<u8>, usize)> = [
            ("params", self.mean.params()),
            ("log_std", &self.log_std[..]),
            ("obs_mean", &self.obs_mean[..]),
            ("obs_std", &self.obs_std[..]),
        ]
        .into_iter()
        .map(|(n, v)| (n, v.iter().flat_map(|x| x.to_le_bytes()).collect(), v.len()))
        .collect();
        let mut views = Vec::new();
        for (name, bytes, n) in &raw {
            let view = TensorView::new(Dtype::F32, vec![*n], bytes).map_err(|e| container(&e))?;
            views.push((*name, view));
        }
        let mut header: HashMap<String, String> = [
            ("format".to_owned(), FORMAT.to_owned()),
            ("format_version".to_owned(), FORMAT_VERSION.to_string()),
            ("meta".to_owned(), meta),
        ]
        .into_iter()
        .collect();
        ess_proto::checksum::seal(&mut header, views.iter().map(|(n, v)| (*n, v)));
        safetensors::serialize(views, Some(header)).map_err(|e| container(&e))
    }

    /// Writes the expert to `path` atomically.
    pub fn save(&self, path: &Path) -> Result<(), ExpertError> {
        let bytes = self.to_bytes().map_err(|source| ExpertError::Invalid {
            path: path.to_owned(),
            source,
        })?;
        crate::write_atomic(path, &bytes).map_err(|(path, source)| ExpertError::Io { path, source })
    }

    /// Reads and validates an expert file.
    pub fn load(path: &Path) -> Result<Self, ExpertError> {
        let bytes = crate::read::read_regular(path).map_err(|source| ExpertError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes(&bytes).map_err(|source| ExpertError::Invalid {
            path: path.to_owned(),
            source,
        })
    }

    /// Parses and validates safetensors bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ExpertFileError> {
        use ExpertFileError as E;
        let file = ess_proto::checksum::open(bytes, FILE_FORMAT)
            .map_err(|e| E::Container(e.to_string()))?;
        let meta: ExpertMeta =
            serde_json::from_str(file.get("meta").map_err(|e| E::Container(e.to_string()))?)
                .map_err(|e| E::Meta(e.to_string()))?;
        let st = &file.tensors;
        let read = |name: &str| -> Result<Vec<f32>, ExpertFileError> {
            let t = st.tensor(name).map_err(|_| E::Missing(name.into()))?;
            if t.dtype() != Dtype::F32 || t.shape().len() != 1 {
                return Err(E::Kind {
                    name: name.into(),
                    dtype: format!("{:?}", t.dtype()),
                    shape: t.shape().to_vec(),
                });
            }
            Ok(t.data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect())
        };
        Self::new(
            meta,
            read("params")?,
            read("log_std")?,
            read("obs_mean")?,
            read("obs_std")?,
        )
    }

    /// Refuses an expert for another env, mode, mode count or shape than `spec`'s
    /// `mode`; `path` names the file in the error.
    pub fn check_fits(&self, spec: &EnvSpec, mode: usize, path: &Path) -> Result<(), ExpertError> {
        let m = &self.meta;
        let checks = [
            ("env", m.env.clone(), spec.name.clone()),
            ("mode", m.mode.to_string(), mode.to_string()),
            ("n_modes", m.n_modes.to_string(), spec.n_modes.to_string()),
            ("obs_dim", m.obs_dim.to_string(), spec.obs_dim.to_string()),
            ("act_dim", m.act_dim.to_string(), spec.act_dim.to_string()),
        ];
        for (field, file, want) in checks {
            if file != want {
                return Err(ExpertError::Mismatch {
                    path: path.to_owned(),
                    reason: format!("{field} = {file} in the file, but the env needs {want}"),
                });
            }
        }
        Ok(())
    }

    /// Buffers sized for this expert.
    pub fn scratch(&self) -> ExpertScratch {
        ExpertScratch {
            input: vec![0.0; self.meta.sizes[0]],
            out: vec![0.0; self.meta.act_dim],
            scratch: vec![0.0; self.mean.scratch_len()],
        }
    }

    /// Writes the action for `obs` into `action`: `tanh(mean + noise_scale * std * n)`
    /// (`noise_scale = 0` is the deterministic `tanh(mean)`).
    pub fn act(
        &self,
        obs: &[f32],
        noise_scale: f32,
        rng: &mut ChaCha8Rng,
        buf: &mut ExpertScratch,
        action: &mut [f32],
    ) {
        let d = self.meta.obs_dim;
        for (i, x) in buf.input[..d].iter_mut().enumerate() {
            *x = (obs[i] - self.obs_mean[i]) / self.obs_std[i];
        }
        buf.input[d..].fill(0.0);
        self.mean
            .forward(&buf.input, &mut buf.out, &mut buf.scratch);
        for ((a, m), ls) in action.iter_mut().zip(&buf.out).zip(&self.log_std) {
            let n: f32 = if noise_scale > 0.0 {
                rng.sample(StandardNormal)
            } else {
                0.0
            };
            *a = (m + noise_scale * ls.exp() * n).tanh();
        }
    }
}

/// Directory holding `<env>/mode<k>.safetensors`: `ESS_EXPERTS_DIR` if set, else the
/// repository's `deploy/experts`.
pub fn experts_dir() -> PathBuf {
    match std::env::var_os("ESS_EXPERTS_DIR") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/experts"),
    }
}

/// Path of `env`'s mode `mode` expert under `dir`.
pub fn expert_path(dir: &Path, env: &str, mode: usize) -> PathBuf {
    dir.join(env).join(format!("mode{mode}.safetensors"))
}

/// An env driven by one trained expert per mode; see the module docs.
pub struct ExpertEnv {
    env: Box<dyn Env>,
    experts: Vec<ExpertPolicy>,
    /// Scale of the experts' Gaussian noise when acting (1 = as trained).
    noise_scale: f32,
    obs: Vec<f32>,
    buf: std::sync::Mutex<Vec<ExpertScratch>>,
}

impl std::fmt::Debug for ExpertEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExpertEnv")
            .field("spec", self.env.spec())
            .field("experts", &self.experts.len())
            .field("noise_scale", &self.noise_scale)
            .finish_non_exhaustive()
    }
}

impl ExpertEnv {
    /// Wraps `env` with `experts` (one per mode, in mode order), checking each fits.
    pub fn new(
        env: Box<dyn Env>,
        experts: Vec<(PathBuf, ExpertPolicy)>,
        noise_scale: f32,
    ) -> Result<Self, ExpertError> {
        let spec = env.spec().clone();
        if experts.len() != spec.n_modes {
            return Err(ExpertError::Mismatch {
                path: experts_dir(),
                reason: format!(
                    "{} experts for an env with {} modes",
                    experts.len(),
                    spec.n_modes
                ),
            });
        }
        for (mode, (path, e)) in experts.iter().enumerate() {
            e.check_fits(&spec, mode, path)?;
        }
        let experts: Vec<ExpertPolicy> = experts.into_iter().map(|(_, e)| e).collect();
        let buf = experts.iter().map(|e| e.scratch()).collect();
        Ok(Self {
            obs: vec![0.0; spec.obs_dim],
            env,
            experts,
            noise_scale,
            buf: std::sync::Mutex::new(buf),
        })
    }

    /// Loads every mode's expert of `env` from `dir` ([`expert_path`]) and wraps it.
    pub fn load(env: Box<dyn Env>, dir: &Path) -> Result<Self, ExpertError> {
        let spec = env.spec().clone();
        let mut experts = Vec::with_capacity(spec.n_modes);
        for mode in 0..spec.n_modes {
            let path = expert_path(dir, &spec.name, mode);
            if !path.exists() {
                return Err(ExpertError::Missing {
                    env: spec.name.clone(),
                    mode,
                    path,
                });
            }
            let e = ExpertPolicy::load(&path)?;
            experts.push((path, e));
        }
        Self::new(env, experts, 1.0)
    }

    /// The wrapped env.
    pub fn inner(&self) -> &dyn Env {
        self.env.as_ref()
    }

    /// The experts, in mode order.
    pub fn experts(&self) -> &[ExpertPolicy] {
        &self.experts
    }
}

impl Env for ExpertEnv {
    fn spec(&self) -> &EnvSpec {
        self.env.spec()
    }

    fn reset(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), EnvError> {
        self.env.reset(seed, obs)?;
        self.obs.copy_from_slice(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<StepOutcome, EnvError> {
        let out = self.env.step(action, obs)?;
        self.obs.copy_from_slice(obs);
        Ok(out)
    }

    fn mode_rewards(&self, out: &mut [f32]) {
        self.env.mode_rewards(out)
    }

    fn task_rewards(&self, out: &mut [f32]) {
        self.env.task_rewards(out)
    }

    fn shared_reward(&self) -> f32 {
        self.env.shared_reward()
    }

    fn forward_velocity(&self) -> Option<f64> {
        self.env.forward_velocity()
    }

    fn scene(&self) -> Option<crate::scene::Scene> {
        self.env.scene()
    }

    fn body_poses(&self) -> Vec<crate::scene::Pose> {
        self.env.body_poses()
    }

    /// The wrapped env's state, then the last observation (what the experts act on).
    fn state(&self) -> Vec<f64> {
        let mut s = self.env.state();
        s.extend(self.obs.iter().map(|&x| f64::from(x)));
        s
    }

    fn set_state(&mut self, state: &[f64]) -> Result<(), EnvError> {
        let n = self.obs.len();
        let Some(split) = state.len().checked_sub(n) else {
            return Err(EnvError::BadState {
                env: self.env.spec().name.clone(),
                why: format!("has {} values, fewer than obs_dim = {n}", state.len()),
            });
        };
        let (inner, obs) = state.split_at(split);
        if let Some(i) = obs.iter().position(|x| !x.is_finite()) {
            return Err(EnvError::BadState {
                env: self.env.spec().name.clone(),
                why: format!("observation value {i} is {} (not finite)", obs[i]),
            });
        }
        self.env.set_state(inner)?;
        for (o, &x) in self.obs.iter_mut().zip(obs) {
            *o = x as f32;
        }
        Ok(())
    }
}

impl ScriptedExpert for ExpertEnv {
    fn expert_action(
        &self,
        mode: usize,
        rng: &mut ChaCha8Rng,
        action: &mut [f32],
    ) -> Result<(), EnvError> {
        let spec = self.env.spec();
        if mode >= spec.n_modes {
            return Err(EnvError::ModeOutOfRange {
                mode,
                n_modes: spec.n_modes,
            });
        }
        crate::env::check_action(action, spec.act_dim).or_else(|e| match e {
            // The buffer's contents are irrelevant (it is written); only its length.
            EnvError::NonFiniteAction { .. } => Ok(()),
            e => Err(e),
        })?;
        let mut bufs = self.buf.lock().unwrap_or_else(|p| p.into_inner());
        self.experts[mode].act(&self.obs, self.noise_scale, rng, &mut bufs[mode], action);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::traj2d::{Traj2D, Traj2DConfig};
    use rand::SeedableRng;

    fn toy_expert(mode: usize, seed: u64) -> ExpertPolicy {
        let spec = Traj2D::new(Traj2DConfig::default())
            .expect("env")
            .spec()
            .clone();
        let sizes = vec![spec.obs_dim + 2, 8, spec.act_dim];
        let layout = MlpLayout {
            sizes: sizes.clone(),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let params = (0..layout.n_params())
            .map(|_| rng.random_range(-0.5..0.5))
            .collect();
        let meta = ExpertMeta {
            env: spec.name.clone(),
            mode,
            n_modes: spec.n_modes,
            obs_dim: spec.obs_dim,
            act_dim: spec.act_dim,
            sizes,
            extra_inputs: 2,
            trained_steps: 10,
            mean_return: 1.5,
            generator: "test".into(),
        };
        ExpertPolicy::new(
            meta,
            params,
            vec![-1.0; spec.act_dim],
            vec![0.1; spec.obs_dim],
            vec![2.0; spec.obs_dim],
        )
        .expect("valid expert")
    }

    fn toy_env() -> Box<dyn Env> {
        Box::new(Traj2D::new(Traj2DConfig::default()).expect("env"))
    }

    #[test]
    fn an_expert_file_round_trips_exactly() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("e.safetensors");
        let e = toy_expert(1, 3);
        e.save(&path).expect("save");
        assert_eq!(ExpertPolicy::load(&path).expect("load"), e);
    }

    #[test]
    fn corrupt_or_foreign_files_are_named_errors() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("e.safetensors");
        std::fs::write(&path, b"not safetensors").expect("write");
        let msg = ExpertPolicy::load(&path).unwrap_err().to_string();
        assert!(
            msg.contains("e.safetensors") && msg.contains("corrupt"),
            "{msg}"
        );
        let bytes = toy_expert(0, 1).to_bytes().expect("bytes");
        let cut = &bytes[..bytes.len() - 7];
        let msg = ExpertPolicy::from_bytes(cut).unwrap_err().to_string();
        assert!(msg.contains("truncated"), "{msg}");
        let missing = ExpertPolicy::load(&dir.path().join("nope.safetensors"))
            .unwrap_err()
            .to_string();
        assert!(missing.contains("nope.safetensors"), "{missing}");
    }

    #[test]
    fn an_expert_for_another_env_mode_or_shape_is_refused_by_field() {
        let spec = toy_env().spec().clone();
        let e = toy_expert(2, 1);
        let p = Path::new("x.safetensors");
        e.check_fits(&spec, 2, p).expect("fits its own mode");
        let msg = e.check_fits(&spec, 1, p).unwrap_err().to_string();
        assert!(msg.contains("mode = 2") && msg.contains("needs 1"), "{msg}");
        let mut other = spec.clone();
        other.name = "walker2d".into();
        let msg = e.check_fits(&other, 2, p).unwrap_err().to_string();
        assert!(
            msg.contains("env = traj2d") && msg.contains("walker2d"),
            "{msg}"
        );
        let mut other = spec.clone();
        other.obs_dim += 1;
        let msg = e.check_fits(&other, 2, p).unwrap_err().to_string();
        assert!(msg.contains("obs_dim"), "{msg}");
    }

    #[test]
    fn inconsistent_meta_is_refused() {
        let e = toy_expert(0, 1);
        let mut meta = e.meta.clone();
        meta.extra_inputs = 0;
        let err = ExpertPolicy::new(
            meta,
            e.params().to_vec(),
            vec![0.0; 2],
            vec![0.0; 10],
            vec![1.0; 10],
        )
        .unwrap_err();
        assert!(
            matches!(err, ExpertFileError::InputWidth { first: 12, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("sizes[0]"), "{err}");
        let err = ExpertPolicy::new(
            e.meta.clone(),
            e.params().to_vec(),
            vec![0.0; 1],
            vec![0.0; 10],
            vec![0.0; 10],
        )
        .unwrap_err();
        assert!(
            matches!(err, ExpertFileError::StdNotPositive { index: 0, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("obs_std"), "{err}");
    }

    #[test]
    fn a_missing_expert_names_the_command_that_trains_it() {
        let dir = tempfile::tempdir().expect("tmp");
        let msg = ExpertEnv::load(toy_env(), dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("ess experts train --env traj2d --mode 0"),
            "{msg}"
        );
    }

    #[test]
    fn expert_env_drives_each_mode_with_its_own_expert_deterministically() {
        let dir = tempfile::tempdir().expect("tmp");
        for k in 0..4 {
            let path = expert_path(dir.path(), "traj2d", k);
            std::fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
            toy_expert(k, 10 + k as u64).save(&path).expect("save");
        }
        let mut env = ExpertEnv::load(toy_env(), dir.path()).expect("load");
        let a = crate::expert_episode(&mut env, 1, 5).expect("episode");
        let b = crate::expert_episode(&mut env, 1, 5).expect("episode");
        let c = crate::expert_episode(&mut env, 2, 5).expect("episode");
        assert_eq!(a, b);
        assert_ne!(a.act, c.act);
        assert!(a.act.iter().all(|x| x.abs() <= 1.0));
        let mut act = vec![0.0; 1];
        let err = env
            .expert_action(4, &mut ChaCha8Rng::seed_from_u64(0), &mut act)
            .unwrap_err();
        assert!(
            matches!(err, EnvError::ModeOutOfRange { mode: 4, .. }),
            "{err}"
        );
    }
}
