//! The subcommands of `ess`, one module each, and what they share: the config flags
//! and their layers, input errors (exit 2), the stop flag and the async runtime.

pub mod actor_host;
pub mod demos;
pub mod experiment;
pub mod experts;
pub mod export;
pub mod job;
pub mod replay;
pub mod serve;
pub mod train;

use anyhow::{Context, Result};
use clap::Args;
use ess_learner::presets::ConfigLayers;
use ess_proto::config::CheckedConfig;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Args)]
pub struct ConfigArgs {
    /// Method preset (see `ess presets`) or a path to a preset TOML file.
    #[arg(long, default_value = "ess-infogail")]
    pub preset: String,
    /// A TOML config file applied over the preset.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Environment (overrides env.name).
    #[arg(long)]
    pub env: Option<String>,
    /// Training seed (overrides run.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Override a config key, e.g. `--set run.iterations=50` (repeatable; applied last).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// An error caused by the user's input (exit code 2).
#[derive(Debug)]
pub struct InputError(String);
impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}
impl std::error::Error for InputError {}

pub fn input_err(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(InputError(e.to_string()))
}

/// Creates the directory an output file goes into (an input error when it cannot be).
pub fn create_parent(path: &std::path::Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| input_err(format!("{}: cannot create it: {e}", dir.display())))?;
    }
    Ok(())
}

/// `e` as an input error (exit 2) when it is a `T`, the library's typed input errors.
pub fn input_if<T: std::error::Error + Send + Sync + 'static>(e: anyhow::Error) -> anyhow::Error {
    if e.downcast_ref::<T>().is_some() {
        input_err(format!("{e:#}"))
    } else {
        e
    }
}

/// `e` as an input error (exit 2) when it says a file Ess wrote is corrupt.
pub fn input_if_corrupt(e: anyhow::Error) -> anyhow::Error {
    match e.downcast_ref::<ess_learner::tensor_file::TensorFileError>() {
        Some(t) if t.is_corrupt() => input_err(format!("{e:#}")),
        _ => e,
    }
}

impl ConfigArgs {
    /// The layers these flags name (reading the config file).
    fn layers(&self) -> Result<ConfigLayers> {
        let config = self
            .config
            .as_ref()
            .map(|f| {
                std::fs::read_to_string(f)
                    .map(|text| (f.display().to_string(), text))
                    .map_err(|e| input_err(format!("cannot read config file {}: {e}", f.display())))
            })
            .transpose()?;
        Ok(ConfigLayers {
            preset: self.preset.clone(),
            preset_files: true,
            config,
            set: self.set.clone(),
            env: self.env.clone(),
            seed: self.seed,
        })
    }
}

pub fn resolve(args: &ConfigArgs) -> Result<CheckedConfig> {
    args.layers()?.resolve().map_err(input_err)
}

/// A flag set by the first Ctrl-C or SIGTERM (finish the iteration, save, stop actor
/// processes); a second exits.
pub fn ctrl_c_flag() -> Result<Arc<AtomicBool>> {
    let shutdown = Arc::new(AtomicBool::new(false));
    let flag = shutdown.clone();
    ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("ess: stopping after this iteration (Ctrl-C again to abort)");
    })
    .context("installing the Ctrl-C handler")?;
    Ok(shutdown)
}

pub fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// Resolves on the first Ctrl-C or SIGTERM.
pub async fn shutdown_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(e) => {
                tracing::warn!(error = %e, "cannot listen for SIGTERM");
                std::future::pending::<()>().await;
            }
        }
    };
    tokio::select! {
        r = tokio::signal::ctrl_c() => {
            if let Err(e) = r {
                tracing::warn!(error = %e, "cannot listen for Ctrl-C");
                std::future::pending::<()>().await;
            }
        }
        () = term => {}
    }
    eprintln!("ess serve: stopping running jobs (they checkpoint), then exiting");
}
