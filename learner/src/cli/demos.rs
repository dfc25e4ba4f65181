//! `ess demos`: generate and inspect demonstration datasets.

use super::{ConfigArgs, input_err, resolve};
use anyhow::Result;
use clap::Subcommand;
use ess_envs::generate_demos;
use ess_learner::train::demo_spec;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum DemosCmd {
    /// Generate an imbalanced, partly labeled dataset (safetensors).
    Generate {
        #[command(flatten)]
        config: ConfigArgs,
        /// Output file.
        #[arg(long, default_value = "demos.safetensors")]
        out: PathBuf,
    },
    /// Print a dataset's metadata (validating the whole file).
    Inspect {
        /// The dataset file.
        path: PathBuf,
    },
}

pub fn demos(cmd: DemosCmd) -> Result<()> {
    match cmd {
        DemosCmd::Generate { config, out } => {
            let cfg = resolve(&config)?;
            let d = generate_demos(&demo_spec(&cfg)).map_err(input_err)?;
            d.save(&out)?;
            println!("wrote {}", out.display());
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
        }
        DemosCmd::Inspect { path } => {
            let d = ess_envs::Demos::load(&path).map_err(input_err)?;
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
        }
    }
    Ok(())
}
