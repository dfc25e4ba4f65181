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
        /// Also print every value of both splits as JSON (floats exactly).
        #[arg(long)]
        values: bool,
    },
    /// Import demonstrations recorded elsewhere: a Minari dataset (its directory or
    /// main_data.hdf5) or a NumPy .npz.
    Import(ImportArgs),
}

#[derive(clap::Args)]
pub struct ImportArgs {
    /// The source: a Minari dataset directory, its main_data.hdf5, or a .npz file.
    pub source: PathBuf,
    /// The env the demonstrations are for: a built-in name or task:PATH.toml.
    #[arg(long)]
    pub env: String,
    /// Number of behaviour modes (default: the task file's [[modes]], else one past the
    /// largest label).
    #[arg(long)]
    pub n_modes: Option<usize>,
    /// Labeled steps as a fraction of all steps, in (0, 1].
    #[arg(long, default_value_t = 0.02)]
    pub label_ratio: f64,
    /// Per-episode labels from this field: Minari, a dataset or attribute in each
    /// episode group (e.g. infos/mode); npz, an [E] array (default episode_modes).
    #[arg(long)]
    pub labels_field: Option<String>,
    /// Per-episode labels from a text file: one line per episode, an integer, -1 or
    /// empty for unknown; lines starting with # are skipped.
    #[arg(long, conflicts_with = "labels_field")]
    pub labels_file: Option<PathBuf>,
    /// Seed of the choice of labeled episodes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output file.
    #[arg(long, default_value = "demos.safetensors")]
    pub out: PathBuf,
    /// Overwrite an existing output file.
    #[arg(long)]
    pub force: bool,
}

pub fn demos(cmd: DemosCmd) -> Result<()> {
    match cmd {
        DemosCmd::Generate { config, out } => {
            let cfg = resolve(&config)?;
            let d = generate_demos(&demo_spec(&cfg)).map_err(input_err)?;
            super::create_parent(&out)?;
            d.save(&out)?;
            println!("wrote {}", out.display());
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
        }
        DemosCmd::Inspect { path, values } => {
            let d = ess_envs::Demos::load(&path).map_err(input_err)?;
            println!("{}", serde_json::to_string_pretty(&d.meta)?);
            if values {
                println!("{}", serde_json::to_string(&split_values(&d))?);
            }
        }
        DemosCmd::Import(args) => import(&args)?,
    }
    Ok(())
}

/// Every value of both splits, as JSON (`mode` -1 where unknown).
fn split_values(d: &ess_envs::Demos) -> serde_json::Value {
    let split = |s: &ess_envs::DemoSplit| {
        let mode: Vec<i64> = s
            .mode
            .iter()
            .map(|&m| i32::try_from(m).map_or(-1, i64::from))
            .collect();
        serde_json::json!({
            "obs": s.obs, "act": s.act, "next_obs": s.next_obs,
            "reward": s.reward, "episode": s.episode, "mode": mode,
        })
    };
    serde_json::json!({ "unlabeled": split(&d.unlabeled), "labeled": split(&d.labeled) })
}

/// Reads a labels file: one line per episode (integer; -1 or empty: unknown).
fn labels_file(path: &std::path::Path) -> Result<Vec<Option<i64>>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| input_err(format!("{}: cannot read: {e}", path.display())))?;
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with('#') {
            continue;
        }
        out.push(match t {
            "" | "-1" => None,
            _ => Some(t.parse::<i64>().map_err(|_| {
                input_err(format!(
                    "{}: line {}: {t:?} is not an integer label (-1 or empty: unknown)",
                    path.display(),
                    i + 1
                ))
            })?),
        });
    }
    Ok(out)
}

/// The env's widths, episode length and mode count (None: from the labels).
fn env_facts(args: &ImportArgs) -> Result<((usize, usize), usize, Option<usize>)> {
    let task_modes = match ess_envs::task::task_path(&args.env) {
        Some(p) => Some(ess_envs::TaskFile::read(p).map_err(input_err)?.modes.len()),
        None => None,
    };
    let n_modes = match (args.n_modes, task_modes) {
        (Some(k), _) => Some(k),
        (None, Some(k)) if k > 0 => Some(k),
        (None, Some(_)) => None,
        (None, None) => {
            return Err(input_err(format!(
                "--n-modes is needed for the built-in env {:?}",
                args.env
            )));
        }
    };
    let env = ess_envs::make_plain_env(&args.env, n_modes.unwrap_or(2)).map_err(input_err)?;
    let s = env.spec();
    Ok(((s.obs_dim, s.act_dim), s.max_steps, n_modes))
}

fn import(args: &ImportArgs) -> Result<()> {
    use ess_learner::import::{Builder, ImportOptions, minari, npz, source};
    if args.out.exists() && !args.force {
        return Err(input_err(format!(
            "{} exists; pass --force to overwrite it",
            args.out.display()
        )));
    }
    let (dims, episode_len, n_modes) = env_facts(args)?;
    let side = args.labels_file.as_deref().map(labels_file).transpose()?;
    let mut extra = std::collections::BTreeMap::new();
    if let Some(f) = &args.labels_field {
        extra.insert("labels_field".to_string(), f.clone());
    }
    if let Some(f) = &args.labels_file {
        extra.insert("labels_file".to_string(), f.display().to_string());
    }
    let opts = ImportOptions {
        env: args.env.clone(),
        dims,
        episode_len,
        n_modes,
        label_ratio: args.label_ratio,
        seed: args.seed,
        extra,
    };
    let mut b = Builder::new(&args.source, opts);
    let is_npz = args.source.extension().is_some_and(|e| e == "npz");
    let src = if is_npz {
        npz::read(
            &args.source,
            &mut b,
            args.labels_field.as_deref(),
            side.as_deref(),
        )
        .map_err(input_err)?;
        source("npz", &args.source, &args.source).map_err(input_err)?
    } else {
        minari::read(
            &args.source,
            &mut b,
            args.labels_field.as_deref(),
            side.as_deref(),
        )
        .map_err(input_err)?;
        let data = minari::data_file(&args.source).map_err(input_err)?;
        source("minari", &args.source, &data).map_err(input_err)?
    };
    let demos = b.finish(src).map_err(input_err)?;
    super::create_parent(&args.out)?;
    demos.save(&args.out)?;
    println!("wrote {}", args.out.display());
    println!("{}", serde_json::to_string_pretty(&demos.meta)?);
    Ok(())
}
