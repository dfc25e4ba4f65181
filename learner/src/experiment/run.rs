//! Running a grid's unfinished cells: on this machine through the job manager of
//! `ess serve` (its queue, core budget, stop and resume), or on a Slurm cluster as one
//! job array whose tasks each run one cell with `ess experiment SPEC --cell I`.

use super::report::{cell_dir, finished};
use super::spec::{Cell, ExperimentSpec};
use crate::control::jobs::{Error as JobError, Manager, ManagerConfig};
use ess_proto::pb;
use std::future::Future;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// What went wrong running a grid.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The job manager refused or failed.
    #[error("cell {cell}")]
    Job {
        /// The cell.
        cell: String,
        /// Why.
        #[source]
        source: JobError,
    },
    /// Opening the manager on the output directory failed.
    #[error("opening {dir}")]
    Open {
        /// The experiment's output directory.
        dir: PathBuf,
        /// Why.
        #[source]
        source: JobError,
    },
    /// A file or a child process failed.
    #[error("{context}")]
    Io {
        /// What was being done.
        context: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A cell's job succeeded earlier but its summary is gone.
    #[error(
        "cell {cell} succeeded earlier but {dir} holds no summary.json: remove that directory to run it again"
    )]
    NoSummary {
        /// The cell.
        cell: String,
        /// Its run directory.
        dir: String,
    },
    /// `sbatch` refused the array.
    #[error("sbatch failed ({status}): {stderr}")]
    Sbatch {
        /// Its exit status.
        status: String,
        /// What it said.
        stderr: String,
    },
}

/// How a local run ended.
#[derive(Debug, Default)]
pub struct LocalOutcome {
    /// Cells finished before this run started.
    pub skipped: usize,
    /// Cells that finished now.
    pub succeeded: usize,
    /// `(cell, why)` of the cells that failed.
    pub failed: Vec<(String, String)>,
    /// Stopped by a signal before every cell ended (run the command again to go on).
    pub interrupted: bool,
}

/// Queues every unfinished cell in a job manager whose data directory is `out`
/// (`out/jobs/<cell>/`), resuming the cells an interrupted run left behind, and waits
/// for them; on `shutdown` stops the running ones at their next iteration (they
/// checkpoint) and returns.
pub async fn run_local(
    cells: &[Cell],
    out: &Path,
    cores: usize,
    exe: PathBuf,
    shutdown: impl Future<Output = ()>,
) -> Result<LocalOutcome, RunError> {
    let manager = Manager::open(ManagerConfig {
        data_dir: out.to_path_buf(),
        cores,
        exe,
        stop_grace: Duration::from_secs(60),
    })
    .map_err(|source| RunError::Open {
        dir: out.to_path_buf(),
        source,
    })?;
    let mut outcome = LocalOutcome::default();
    let mut waiting = Vec::new();
    for cell in cells {
        if finished(out, cell).is_some() {
            outcome.skipped += 1;
            continue;
        }
        queue_cell(&manager, cell).await?;
        waiting.push(cell.id.clone());
    }
    tokio::pin!(shutdown);
    while !waiting.is_empty() {
        tokio::select! {
            () = &mut shutdown => {
                manager.shutdown().await;
                outcome.interrupted = true;
                return Ok(outcome);
            }
            () = tokio::time::sleep(Duration::from_millis(500)) => {}
        }
        waiting.retain(|id| match manager.get(id) {
            Ok(job) => !settle(&job, &mut outcome),
            Err(e) => {
                outcome.failed.push((id.clone(), e.to_string()));
                false
            }
        });
    }
    manager.shutdown().await;
    Ok(outcome)
}

/// Submits `cell` as job `cell.id`, or resumes it if an earlier run left it stopped or
/// failed; leaves it alone if it is queued or running.
async fn queue_cell(manager: &Arc<Manager>, cell: &Cell) -> Result<(), RunError> {
    use pb::JobState as S;
    let job_err = |source| RunError::Job {
        cell: cell.id.clone(),
        source,
    };
    let r = match manager.get(&cell.id) {
        Ok(job) => match S::try_from(job.state) {
            Ok(S::Stopped | S::Failed) => manager.resume(&cell.id).map(drop),
            Ok(S::Succeeded) => {
                return Err(RunError::NoSummary {
                    cell: cell.id.clone(),
                    dir: job.run_dir,
                });
            }
            _ => Ok(()),
        },
        Err(JobError::NotFound { .. }) => manager
            .submit_as(cell.job_spec(), Some(&cell.id))
            .await
            .map(drop),
        Err(e) => Err(e),
    };
    r.map_err(job_err)
}

/// Whether `job` has ended; records and prints how.
fn settle(job: &pb::Job, outcome: &mut LocalOutcome) -> bool {
    use pb::JobState as S;
    match S::try_from(job.state) {
        Ok(S::Succeeded) => {
            outcome.succeeded += 1;
            let nmi = job.result.as_ref().map_or(f64::NAN, |r| r.nmi);
            eprintln!("ess: cell {} finished (NMI {nmi:.3})", job.id);
            true
        }
        Ok(S::Failed | S::Stopped) => {
            eprintln!(
                "ess: cell {} ended {:?}: {}",
                job.id,
                job.state(),
                job.error
            );
            outcome.failed.push((job.id.clone(), job.error.clone()));
            true
        }
        _ => false,
    }
}

/// The `ess train` arguments that run `cell` into its directory under `out` (resuming
/// it when a checkpoint is there).
pub fn train_args(cell: &Cell, out: &Path) -> Vec<String> {
    let dir = cell_dir(out, cell);
    if crate::control::jobs::has_checkpoint(&dir) {
        return vec!["train".into(), "--resume".into(), dir.display().to_string()];
    }
    let mut args = vec![
        "train".into(),
        "--preset".into(),
        cell.preset.clone(),
        "--env".into(),
        cell.env.clone(),
        "--seed".into(),
        cell.seed.to_string(),
        "--out".into(),
        dir.display().to_string(),
    ];
    for kv in &cell.set {
        args.push("--set".into());
        args.push(kv.clone());
    }
    args
}

/// The batch script of a Slurm job array over the cells at `todo` (indices into the
/// spec's cells): each task runs `ess experiment SPEC --out OUT --cell $SLURM_ARRAY_TASK_ID`.
pub fn sbatch_script(
    spec: &ExperimentSpec,
    spec_path: &Path,
    out: &Path,
    exe: &Path,
    todo: &[usize],
    cpus: usize,
) -> String {
    let list: Vec<String> = todo.iter().map(usize::to_string).collect();
    format!(
        "#!/bin/bash\n\
         #SBATCH --job-name=ess-{name}\n\
         #SBATCH --array={array}\n\
         #SBATCH --cpus-per-task={cpus}\n\
         #SBATCH --output={logs}/%A_%a.out\n\
         # Written by `ess experiment --slurm`: one array task per unfinished cell.\n\
         exec {exe} experiment {spec} --out {out} --cell \"$SLURM_ARRAY_TASK_ID\"\n",
        name = spec.name,
        array = list.join(","),
        logs = shell_quote(&out.join("slurm")),
        exe = shell_quote(exe),
        spec = shell_quote(spec_path),
        out = shell_quote(out),
    )
}

fn shell_quote(p: &Path) -> String {
    format!("'{}'", p.display().to_string().replace('\'', "'\\''"))
}

/// Writes `script` to `<out>/slurm/grid.sbatch` and submits it with `sbatch`
/// (`--wait` when `wait`, so the call returns when every task has ended), passing
/// `extra` arguments first; returns Slurm's job id.
pub fn submit_slurm(
    out: &Path,
    script: &str,
    extra: &[String],
    wait: bool,
) -> Result<String, RunError> {
    let dir = out.join("slurm");
    let io = |context: String| move |source| RunError::Io { context, source };
    std::fs::create_dir_all(&dir).map_err(io(format!("creating {}", dir.display())))?;
    let path = dir.join("grid.sbatch");
    ess_envs::write_atomic(&path, script.as_bytes()).map_err(|(p, source)| RunError::Io {
        context: format!("writing {}", p.display()),
        source,
    })?;
    let mut cmd = std::process::Command::new("sbatch");
    cmd.arg("--parsable").args(extra);
    if wait {
        cmd.arg("--wait");
    }
    let o = cmd
        .arg(&path)
        .output()
        .map_err(io("running sbatch (is Slurm installed?)".into()))?;
    let stdout = String::from_utf8_lossy(&o.stdout);
    if !o.status.success() && stdout.trim().is_empty() {
        return Err(RunError::Sbatch {
            status: o.status.to_string(),
            stderr: String::from_utf8_lossy(&o.stderr).trim().to_string(),
        });
    }
    // `--parsable` prints `jobid[;cluster]`; with `--wait` a failed task makes the exit
    // status non-zero, which the report shows cell by cell.
    Ok(stdout
        .lines()
        .next()
        .unwrap_or_default()
        .split(';')
        .next()
        .unwrap_or_default()
        .to_string())
}
