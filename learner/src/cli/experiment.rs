//! `ess experiment SPEC`: run a grid of training runs and report it
//! (`ess_learner::experiment`).

use super::{input_err, runtime, shutdown_signal};
use anyhow::{Context, Result, bail};
use clap::Args;
use ess_learner::experiment::report::{figure, finished, markdown};
use ess_learner::experiment::run::{run_local, sbatch_script, submit_slurm, train_args};
use ess_learner::experiment::{Cell, ExperimentSpec};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct ExperimentArgs {
    /// The grid's spec (TOML; see deploy/experiments/).
    spec: PathBuf,
    /// Output directory: `jobs/<cell>/` per cell, `report.md`, the figure (default:
    /// `experiments/<spec name>`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Cores the cells may hold together here (default: this machine's); with
    /// --slurm, the cores each array task asks for (default 2).
    #[arg(long)]
    cores: Option<usize>,
    /// Submit the unfinished cells to Slurm as one job array (`sbatch --array`) and,
    /// unless --no-wait, wait for it and write the report.
    #[arg(long)]
    slurm: bool,
    /// With --slurm: return once the array is submitted (`--report` later).
    #[arg(long, requires = "slurm")]
    no_wait: bool,
    /// With --slurm: an argument passed to sbatch (repeatable), e.g.
    /// `--sbatch-arg=--partition=long`.
    #[arg(long = "sbatch-arg", requires = "slurm", allow_hyphen_values = true)]
    sbatch_args: Vec<String>,
    /// Only write the report from the cells finished so far.
    #[arg(long, conflicts_with_all = ["slurm", "cell", "list"])]
    report: bool,
    /// Run the cell at this index (in `--list` order) here in the foreground: what
    /// each Slurm array task runs.
    #[arg(long, conflicts_with_all = ["slurm", "list"])]
    cell: Option<usize>,
    /// List the cells, each with its index and whether it has finished.
    #[arg(long, conflicts_with = "slurm")]
    list: bool,
}

impl ExperimentArgs {
    /// `--list` and `--report` only print; the other modes run cells.
    pub fn only_prints(&self) -> bool {
        self.list || self.report
    }
}

pub fn experiment(a: ExperimentArgs) -> Result<()> {
    let spec = ExperimentSpec::load(&a.spec).map_err(input_err)?;
    let out = absolute(
        a.out
            .clone()
            .unwrap_or_else(|| Path::new("experiments").join(&spec.name)),
    )?;
    let cells = spec.cells();
    if a.list {
        for (i, c) in cells.iter().enumerate() {
            let state = if finished(&out, c).is_some() {
                "finished"
            } else {
                "to run"
            };
            println!("{i:4}  {:48} {state}", c.id);
        }
        return Ok(());
    }
    if let Some(i) = a.cell {
        let cell = cells.get(i).ok_or_else(|| {
            input_err(format!(
                "--cell {i}: {} has {} cells (0..{})",
                a.spec.display(),
                cells.len(),
                cells.len()
            ))
        })?;
        return run_cell(cell, &out);
    }
    if !a.report {
        if a.slurm {
            let waited = slurm(&a, &spec, &cells, &out)?;
            if !waited {
                return Ok(());
            }
        } else {
            local(&a, &cells, &out)?;
        }
    }
    report(&spec, &cells, &out)
}

/// Runs the unfinished cells here; an error when some failed or a signal stopped it.
fn local(a: &ExperimentArgs, cells: &[Cell], out: &Path) -> Result<()> {
    let exe = std::env::current_exe().context("locating the ess binary to run cells with")?;
    let cores = match a.cores {
        Some(0) => return Err(input_err("--cores 0: give at least 1")),
        Some(c) => c,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    eprintln!(
        "ess: {} cells in {} ({} cores)",
        cells.len(),
        out.display(),
        cores
    );
    let o = runtime()?.block_on(run_local(cells, out, cores, exe, shutdown_signal()))?;
    eprintln!(
        "ess: {} cells finished before, {} now, {} failed",
        o.skipped,
        o.succeeded,
        o.failed.len()
    );
    if o.interrupted {
        bail!("stopped: the running cells checkpointed; run the same command again to go on");
    }
    if !o.failed.is_empty() {
        let names: Vec<&str> = o.failed.iter().map(|(c, _)| c.as_str()).collect();
        eprintln!(
            "ess: failed cells (logs in {}/jobs/<cell>/train.log): {}",
            out.display(),
            names.join(", ")
        );
    }
    Ok(())
}

/// Submits the unfinished cells as one Slurm array; whether it waited for them.
fn slurm(a: &ExperimentArgs, spec: &ExperimentSpec, cells: &[Cell], out: &Path) -> Result<bool> {
    let todo: Vec<usize> = (0..cells.len())
        .filter(|&i| finished(out, &cells[i]).is_none())
        .collect();
    if todo.is_empty() {
        eprintln!("ess: every cell has finished; nothing to submit");
        return Ok(true);
    }
    let exe = std::env::current_exe().context("locating the ess binary for the array tasks")?;
    let spec_path = absolute(a.spec.clone())?;
    let cpus = a.cores.unwrap_or(2).max(1);
    let script = sbatch_script(spec, &spec_path, out, &exe, &todo, cpus);
    let wait = !a.no_wait;
    let id = submit_slurm(out, &script, &a.sbatch_args, wait)?;
    eprintln!(
        "ess: Slurm job {id}: {} array tasks{}",
        todo.len(),
        if wait { ", all ended" } else { "" }
    );
    Ok(wait)
}

/// Runs `ess train` for one cell in the foreground (resuming it from its checkpoint).
fn run_cell(cell: &Cell, out: &Path) -> Result<()> {
    if finished(out, cell).is_some() {
        eprintln!("ess: cell {} has finished already", cell.id);
        return Ok(());
    }
    let exe = std::env::current_exe().context("locating the ess binary")?;
    let status = std::process::Command::new(exe)
        .args(train_args(cell, out))
        .status()
        .context("starting ess train")?;
    if !status.success() {
        bail!("cell {}: ess train {status}", cell.id);
    }
    Ok(())
}

/// Writes `report.md` (also printed) and the figure from the finished cells.
fn report(spec: &ExperimentSpec, cells: &[Cell], out: &Path) -> Result<()> {
    let results: Vec<_> = cells.iter().map(|c| finished(out, c)).collect();
    let md = markdown(spec, cells, &results);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let path = out.join("report.md");
    ess_envs::write_atomic(&path, md.as_bytes())
        .map_err(|(p, e)| anyhow::anyhow!("writing {}: {e}", p.display()))?;
    print!("{md}");
    if let Some(fig) = figure(spec, out, cells, &results)? {
        eprintln!("ess: figure {}", fig.display());
    }
    eprintln!("ess: report {}", path.display());
    Ok(())
}

fn absolute(p: PathBuf) -> Result<PathBuf> {
    if p.is_absolute() {
        return Ok(p);
    }
    Ok(std::env::current_dir()
        .context("reading the working directory")?
        .join(p))
}
