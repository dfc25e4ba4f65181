//! `ess export`: a trained policy as a file other runtimes load.

use super::{input_err, input_if_corrupt};
use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ExportArgs {
    /// The output directory of an `ess train` run (its latest checkpoint is exported).
    pub run: PathBuf,
    /// Write the policy as an ONNX model (inputs obs, eps, c; output action).
    #[arg(long, required = true)]
    pub onnx: PathBuf,
}

pub fn export(a: ExportArgs) -> Result<()> {
    if !a.run.join("config.toml").is_file() {
        return Err(input_err(format!(
            "{}: not the output directory of an `ess train` run (no config.toml)",
            a.run.display()
        )));
    }
    super::create_parent(&a.onnx)?;
    let ckpt = ess_learner::export::export_onnx(&a.run, &a.onnx).map_err(input_if_corrupt)?;
    println!("wrote {} (from {})", a.onnx.display(), ckpt.display());
    println!(
        "inputs: obs [N, obs_dim] raw, eps [N, 1], c [N, n_codes] one-hot; output: action [N, act_dim] in [-1, 1]"
    );
    Ok(())
}
