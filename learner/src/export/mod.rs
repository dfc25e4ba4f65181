//! `ess export RUN_DIR --onnx FILE`: a trained policy for where the robot runs.
//!
//! [`run_policy`] rebuilds the policy of a run directory's latest checkpoint exactly as
//! the actors run it (the observation normaliser is recomputed from the run's
//! demonstrations, as `--resume` does); [`onnx`] writes it as a standard ONNX model.

pub mod onnx;

use std::path::Path;

use anyhow::{Context, Result};
use ess_actor::PolicyWeights;
use ess_proto::CheckedConfig;

use crate::train::checkpoint;
use crate::train::data::{Dims, load_or_generate_demos};
use crate::train::nets::export_policy;
use crate::train::setup::{Nets, rollout_env};

/// The policy of the run in `out` at its latest checkpoint, its config and the
/// checkpoint's directory.
pub fn run_policy(out: &Path) -> Result<(PolicyWeights, CheckedConfig, std::path::PathBuf)> {
    let cfg = crate::train::run_config(out)?;
    let dir = checkpoint::latest(&out.join("checkpoints"))?.with_context(|| {
        format!(
            "{}: no checkpoint to export (has the run saved one?)",
            out.display()
        )
    })?;
    let spec = rollout_env(&cfg)?.spec().clone();
    let demos = load_or_generate_demos(&cfg)?;
    let (mean, std) = crate::eval::classifier::feature_stats(&demos.unlabeled.obs, spec.obs_dim);
    let dims = Dims::new(&cfg, &spec.name, spec.obs_dim, spec.act_dim)?;
    let mut nets = Nets::new(&cfg, dims)?;
    for (vs, name) in [(&mut nets.vs, "policy"), (&mut nets.prior_vs, "prior")] {
        let p = dir.join(format!("{name}.safetensors"));
        crate::tensor_file::load_var_store(vs, &p)
            .with_context(|| format!("loading {}", p.display()))?;
    }
    let p = &nets.ppo;
    let w = export_policy(&p.policy, &p.prior_logits, &mean, &std, 0)?;
    Ok((w, cfg, dir))
}

/// Writes the ONNX model of the run in `out` to `path` (atomically); returns the
/// checkpoint it came from.
pub fn export_onnx(out: &Path, path: &Path) -> Result<std::path::PathBuf> {
    let (w, cfg, dir) = run_policy(out)?;
    let mut prior = w.prior_logits.clone();
    ess_actor::policy::softmax_in_place(&mut prior);
    let meta = vec![
        ("ess.method".to_string(), cfg.method.name.clone()),
        ("ess.env".to_string(), cfg.env.name.clone()),
        ("ess.n_codes".to_string(), cfg.env.n_modes.to_string()),
        ("ess.use_eps".to_string(), cfg.method.use_eps.to_string()),
        ("ess.checkpoint".to_string(), dir.display().to_string()),
        ("ess.prior".to_string(), format!("{:?}", prior)),
    ];
    let model = onnx::policy_model(&w, &meta);
    let bytes = prost::Message::encode_to_vec(&model);
    ess_envs::write_atomic(path, &bytes)
        .map_err(|(p, e)| anyhow::anyhow!("writing {}: {e}", p.display()))?;
    Ok(dir)
}
