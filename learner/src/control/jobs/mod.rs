//! The job manager behind `ess serve`: validates job specs, queues them against a core
//! budget, runs each as an `ess train --progress jsonl` child process, follows its
//! progress, and fans events out to any number of watchers.
//!
//! - **Runs**: a job's run directory is `<data_dir>/jobs/<id>/`; it holds the job record
//!   `job.json`, the resolved configuration `job-config.toml` the child is started with
//!   (`ess train --preset P --config job-config.toml --out <run dir>`), the child's
//!   stderr `train.log`, and everything `ess train` writes. A resumed job runs
//!   `ess train --resume <run dir>` when the run holds a checkpoint
//!   (`checkpoints/iter-*`), else it starts over.
//! - **Core budget**: a job holds `max(run.actors, run.torch_threads, 1)` cores (at
//!   most the whole budget) while it runs; a job with `run.torch_threads = 0` (auto) is
//!   given `torch_threads = cores` so that it does not spread over the whole machine.
//!   With the default `run.actors` (one per core) a job holds the whole budget.
//!   Queued jobs start in submission order (FIFO; a large job at the head waits rather
//!   than being overtaken).
//! - **Stop**: SIGTERM to the child, which finishes its iteration, checkpoints, writes
//!   `summary.json` with `"interrupted": true` and exits 0: the job ends STOPPED. A
//!   queued job is stopped at once. Children run in their own process group, so a
//!   terminal's Ctrl-C reaches only the server, which stops them once.
//! - **Records** are rewritten at each state change and iteration; a server started on
//!   the same data dir lists past jobs, queues the ones that were queued, and marks the
//!   ones that were running FAILED (resumable). A record's run directory is where it is
//!   found, so a data dir may be moved or copied between runs.
//! - **Watchers** subscribe to a per-job `tokio::sync::broadcast` channel; a watcher
//!   that falls behind (lags) is caught up from the job's in-memory iteration history,
//!   so slow watchers never block the job and still see every iteration.

mod follow;
mod record;
mod spec;

pub use record::{Error, State};
use record::{JobRecord, io_err, now_ms, persist};
use spec::log_tail;
pub use spec::{Validated, has_checkpoint, validate};

use crate::progress::ProgressEvent;
use ess_proto::pb;
use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::process::Stdio;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::AsyncBufReadExt;
use tokio::sync::{broadcast, watch};

/// How the manager runs jobs.
#[derive(Debug, Clone)]
pub struct ManagerConfig {
    /// Data directory: `jobs/<id>/` per job.
    pub data_dir: PathBuf,
    /// Cores that running jobs may hold together.
    pub cores: usize,
    /// The `ess` binary jobs run as (`std::env::current_exe()` for `ess serve`).
    pub exe: PathBuf,
    /// How long a shutting-down server waits for its stopped jobs before killing them.
    pub stop_grace: Duration,
}

/// One broadcast item: a job event, with its index in the job's iteration history when
/// it carries metrics.
#[derive(Debug, Clone)]
struct Broadcast {
    seq: Option<usize>,
    event: Arc<pb::JobEvent>,
}

struct Entry {
    rec: JobRecord,
    tx: broadcast::Sender<Broadcast>,
    /// Every iteration's metrics since the server started (all runs of the job).
    history: Vec<pb::IterationMetrics>,
    pid: Option<u32>,
}

struct Inner {
    jobs: BTreeMap<String, Entry>,
    queue: VecDeque<String>,
    used_cores: usize,
    running: usize,
    next_seq: u64,
    shutting_down: bool,
}

/// Capacity of each job's broadcast channel; a watcher further behind is caught up from
/// the history.
const BROADCAST_CAPACITY: usize = 256;

/// The jobs of one server; cheap to share (`Arc`).
pub struct Manager {
    cfg: ManagerConfig,
    inner: Mutex<Inner>,
    /// Wakes [`Manager::shutdown`] when a job process ends.
    ended: tokio::sync::Notify,
    /// Set once the server stops: open watch streams end.
    closing: watch::Sender<bool>,
}

impl Manager {
    /// Opens the data dir: loads the job records there (queued jobs queue again; jobs
    /// that were running are marked FAILED), and starts what fits the budget.
    pub fn open(cfg: ManagerConfig) -> Result<Arc<Self>, Error> {
        let jobs_dir = cfg.data_dir.join("jobs");
        std::fs::create_dir_all(&jobs_dir)
            .map_err(io_err(format!("creating {}", jobs_dir.display())))?;
        let mut records = Vec::new();
        for e in std::fs::read_dir(&jobs_dir)
            .map_err(io_err(format!("reading {}", jobs_dir.display())))?
            .flatten()
        {
            let path = e.path().join("job.json");
            let Ok(text) = std::fs::read_to_string(&path) else {
                continue;
            };
            match serde_json::from_str::<JobRecord>(&text) {
                // The directory the record lies in is the run's, wherever it was
                // written: a data dir copied or moved (a grid's results brought back
                // from a cluster) resumes in its new place.
                Ok(r) => records.push(JobRecord {
                    run_dir: e.path(),
                    ..r
                }),
                Err(err) => {
                    tracing::warn!(file = %path.display(), error = %err, "skipping an unreadable job record")
                }
            }
        }
        records.sort_by_key(|r| r.seq);
        let mut inner = Inner {
            jobs: BTreeMap::new(),
            queue: VecDeque::new(),
            used_cores: 0,
            running: 0,
            next_seq: records.last().map_or(1, |r| r.seq + 1),
            shutting_down: false,
        };
        let mut changed = Vec::new();
        for mut rec in records {
            match rec.state {
                State::Running | State::Stopping => {
                    rec.state = State::Failed;
                    rec.error = "the server exited while the job ran".into();
                    rec.finished_unix_ms = now_ms();
                    rec.resume_next = has_checkpoint(&rec.run_dir);
                    changed.push(rec.clone());
                }
                State::Queued => inner.queue.push_back(rec.id.clone()),
                _ => {}
            }
            let (tx, _) = broadcast::channel(BROADCAST_CAPACITY);
            inner.jobs.insert(
                rec.id.clone(),
                Entry {
                    rec,
                    tx,
                    history: Vec::new(),
                    pid: None,
                },
            );
        }
        for rec in &changed {
            persist(rec)?;
        }
        let (closing, _) = watch::channel(false);
        let m = Arc::new(Self {
            cfg,
            inner: Mutex::new(inner),
            ended: tokio::sync::Notify::new(),
            closing,
        });
        {
            let mut inner = m.lock();
            m.schedule(&mut inner);
        }
        Ok(m)
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A panic while holding the lock cannot leave the maps half-updated in a way
        // that matters more than losing the server, so poisoning is ignored.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Validates and queues a job (id `job-<n>`).
    pub async fn submit(self: &Arc<Self>, spec: pb::JobSpec) -> Result<pb::Job, Error> {
        self.submit_as(spec, None).await
    }

    /// Validates and queues a job under `id` when given (`ess experiment` names each
    /// cell's job, so that its run directory `jobs/<id>/` is found again); the id must
    /// be new and a plain file name.
    pub async fn submit_as(
        self: &Arc<Self>,
        spec: pb::JobSpec,
        id: Option<&str>,
    ) -> Result<pb::Job, Error> {
        if let Some(id) = id {
            let plain = !id.is_empty()
                && id
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c))
                && !id.starts_with('.');
            if !plain {
                return Err(Error::InvalidArgument {
                    field: "id".into(),
                    message: format!("`{id}` is not a plain file name"),
                });
            }
        }
        if self.lock().shutting_down {
            return Err(Error::ShuttingDown);
        }
        let budget = self.cfg.cores;
        let spec2 = spec.clone();
        // Resolving builds the env once (MuJoCo: parses its model): off the runtime.
        let v = tokio::task::spawn_blocking(move || validate(&spec2, budget))
            .await
            .map_err(|e| Error::Io {
                context: "validating the spec".into(),
                source: std::io::Error::other(e),
            })??;
        let mut inner = self.lock();
        if inner.shutting_down {
            return Err(Error::ShuttingDown);
        }
        let seq = inner.next_seq;
        inner.next_seq += 1;
        let id = id.map_or_else(|| format!("job-{seq}"), str::to_string);
        if inner.jobs.contains_key(&id) {
            return Err(Error::InvalidArgument {
                field: "id".into(),
                message: format!("`{id}` is taken"),
            });
        }
        let run_dir = self.cfg.data_dir.join("jobs").join(&id);
        std::fs::create_dir_all(&run_dir)
            .map_err(io_err(format!("creating {}", run_dir.display())))?;
        let rec = JobRecord {
            id: id.clone(),
            seq,
            spec: (&spec).into(),
            preset: v.preset,
            state: State::Queued,
            iteration: 0,
            iterations: v.iterations,
            env_steps: 0,
            cores: u32::try_from(v.cores).unwrap_or(u32::MAX),
            torch_threads: v.torch_threads,
            run_dir,
            created_unix_ms: now_ms(),
            started_unix_ms: 0,
            finished_unix_ms: 0,
            error: String::new(),
            result: None,
            resumes: 0,
            resume_next: false,
            stop_requested: false,
            phase: String::new(),
        };
        std::fs::write(rec.config_path(), v.config_toml)
            .map_err(io_err(format!("writing {}", rec.config_path().display())))?;
        persist(&rec)?;
        let job = rec.to_pb();
        let (tx, _) = broadcast::channel(BROADCAST_CAPACITY);
        inner.jobs.insert(
            id.clone(),
            Entry {
                rec,
                tx,
                history: Vec::new(),
                pid: None,
            },
        );
        inner.queue.push_back(id.clone());
        tracing::info!(job = %id, "queued");
        self.schedule(&mut inner);
        Ok(inner.jobs.get(&id).map_or(job, |e| e.rec.to_pb()))
    }

    /// Every job (oldest first), or those in `states`.
    pub fn list(&self, states: &[pb::JobState]) -> Vec<pb::Job> {
        let want: Vec<State> = states.iter().filter_map(|s| State::from_pb(*s)).collect();
        let inner = self.lock();
        let mut jobs: Vec<&Entry> = inner
            .jobs
            .values()
            .filter(|e| want.is_empty() || want.contains(&e.rec.state))
            .collect();
        jobs.sort_by_key(|e| e.rec.seq);
        jobs.into_iter().map(|e| e.rec.to_pb()).collect()
    }

    /// One job.
    pub fn get(&self, id: &str) -> Result<pb::Job, Error> {
        let inner = self.lock();
        inner
            .jobs
            .get(id)
            .map(|e| e.rec.to_pb())
            .ok_or_else(|| Error::NotFound { id: id.into() })
    }

    /// Stops a job: a queued one at once, a running one gracefully (SIGTERM).
    pub fn stop(self: &Arc<Self>, id: &str) -> Result<pb::Job, Error> {
        let mut inner = self.lock();
        let inner = &mut *inner;
        let entry = inner
            .jobs
            .get_mut(id)
            .ok_or_else(|| Error::NotFound { id: id.into() })?;
        match entry.rec.state {
            State::Queued => {
                inner.queue.retain(|q| q != id);
                entry.rec.state = State::Stopped;
                entry.rec.finished_unix_ms = now_ms();
                persist(&entry.rec)?;
                publish(entry, None);
            }
            State::Running => {
                entry.rec.stop_requested = true;
                entry.rec.state = State::Stopping;
                if let Some(pid) = entry.pid {
                    terminate(pid);
                }
                persist(&entry.rec)?;
                publish(entry, None);
            }
            State::Stopping => {}
            s => {
                return Err(Error::FailedPrecondition {
                    id: id.into(),
                    state: s.name(),
                    action: "stop",
                });
            }
        }
        Ok(entry.rec.to_pb())
    }

    /// Queues a STOPPED or FAILED job again; it continues from its last checkpoint.
    pub fn resume(self: &Arc<Self>, id: &str) -> Result<pb::Job, Error> {
        let mut inner = self.lock();
        if inner.shutting_down {
            return Err(Error::ShuttingDown);
        }
        let entry = inner
            .jobs
            .get_mut(id)
            .ok_or_else(|| Error::NotFound { id: id.into() })?;
        match entry.rec.state {
            State::Stopped | State::Failed => {}
            s => {
                return Err(Error::FailedPrecondition {
                    id: id.into(),
                    state: s.name(),
                    action: "resume",
                });
            }
        }
        entry.rec.resume_next = has_checkpoint(&entry.rec.run_dir);
        entry.rec.resumes += 1;
        entry.rec.state = State::Queued;
        entry.rec.error.clear();
        entry.rec.result = None;
        entry.rec.stop_requested = false;
        entry.rec.finished_unix_ms = 0;
        persist(&entry.rec)?;
        publish(entry, None);
        inner.queue.push_back(id.to_string());
        self.schedule(&mut inner);
        inner
            .jobs
            .get(id)
            .map(|e| e.rec.to_pb())
            .ok_or_else(|| Error::NotFound { id: id.into() })
    }

    /// Starts queued jobs while the budget allows (FIFO). Called with the lock held.
    fn schedule(self: &Arc<Self>, inner: &mut Inner) {
        while !inner.shutting_down {
            let Some(id) = inner.queue.front().cloned() else {
                return;
            };
            let Some(cores) = inner.jobs.get(&id).map(|e| e.rec.cores as usize) else {
                inner.queue.pop_front();
                continue;
            };
            if inner.used_cores > 0 && inner.used_cores + cores > self.cfg.cores {
                return;
            }
            inner.queue.pop_front();
            self.start(inner, &id, cores);
        }
    }

    /// Spawns job `id`'s process and the task that follows it.
    fn start(self: &Arc<Self>, inner: &mut Inner, id: &str, cores: usize) {
        let Some(entry) = inner.jobs.get_mut(id) else {
            return;
        };
        let rec = &mut entry.rec;
        let mut cmd = tokio::process::Command::new(&self.cfg.exe);
        cmd.arg("train");
        if rec.resume_next {
            cmd.arg("--resume").arg(&rec.run_dir);
        } else {
            cmd.arg("--preset")
                .arg(&rec.preset)
                .arg("--config")
                .arg(rec.config_path())
                .arg("--out")
                .arg(&rec.run_dir);
            if let Some(t) = rec.torch_threads {
                cmd.arg("--set").arg(format!("run.torch_threads={t}"));
            }
        }
        cmd.arg("--progress").arg("jsonl");
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(rec.run_dir.join("train.log"));
        let spawned = log.and_then(|log| {
            cmd.stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::from(log))
                // Own process group: a terminal's Ctrl-C reaches the server only.
                .process_group(0)
                .kill_on_drop(true)
                .spawn()
        });
        rec.started_unix_ms = now_ms();
        rec.iteration = if rec.resume_next { rec.iteration } else { 0 };
        match spawned {
            Ok(child) => {
                rec.state = State::Running;
                rec.phase = "starting".into();
                entry.pid = child.id();
                inner.used_cores += cores;
                inner.running += 1;
                tracing::info!(job = %id, pid = ?entry.pid, resume = rec.resume_next, "started");
                if let Err(e) = persist(rec) {
                    tracing::warn!(job = %id, error = %e, "job record not written");
                }
                publish(entry, None);
                let me = self.clone();
                let id = id.to_string();
                tokio::spawn(async move { me.follow(id, child, cores).await });
            }
            Err(e) => {
                rec.state = State::Failed;
                rec.error = format!("cannot start {}: {e}", self.cfg.exe.display());
                rec.finished_unix_ms = now_ms();
                if let Err(e) = persist(rec) {
                    tracing::warn!(job = %id, error = %e, "job record not written");
                }
                publish(entry, None);
            }
        }
    }

    /// Reads the child's progress lines until it exits, then records how it ended.
    async fn follow(self: Arc<Self>, id: String, mut child: tokio::process::Child, cores: usize) {
        if let Some(stdout) = child.stdout.take() {
            let mut lines = tokio::io::BufReader::new(stdout).lines();
            loop {
                match lines.next_line().await {
                    Ok(Some(line)) => self.on_line(&id, &line),
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!(job = %id, error = %e, "reading the job's progress");
                        break;
                    }
                }
            }
        }
        let status = child.wait().await;
        self.on_exit(&id, status, cores);
        self.ended.notify_waiters();
    }

    fn on_line(&self, id: &str, line: &str) {
        let ev = match serde_json::from_str::<ProgressEvent>(line) {
            Ok(ev) => ev,
            Err(e) => {
                tracing::debug!(job = %id, error = %e, line, "not a progress line");
                return;
            }
        };
        let mut inner = self.lock();
        let Some(entry) = inner.jobs.get_mut(id) else {
            return;
        };
        match ev {
            ProgressEvent::Message { message } => {
                entry.rec.phase = message;
                publish(entry, None);
            }
            ProgressEvent::Iteration(r) => {
                entry.rec.iteration = r.iteration;
                entry.rec.env_steps = r.env_steps;
                let m = r;
                entry.history.push(m.clone());
                let seq = entry.history.len() - 1;
                if let Err(e) = persist(&entry.rec) {
                    tracing::warn!(job = %id, error = %e, "job record not written");
                }
                publish(entry, Some((seq, m)));
            }
            ProgressEvent::Summary(f) => entry.rec.result = Some(f),
        }
    }

    fn on_exit(
        self: &Arc<Self>,
        id: &str,
        status: std::io::Result<std::process::ExitStatus>,
        cores: usize,
    ) {
        let mut inner = self.lock();
        inner.used_cores = inner.used_cores.saturating_sub(cores);
        inner.running = inner.running.saturating_sub(1);
        if let Some(entry) = inner.jobs.get_mut(id) {
            entry.pid = None;
            let rec = &mut entry.rec;
            rec.finished_unix_ms = now_ms();
            rec.phase.clear();
            let ok = status.as_ref().is_ok_and(|s| s.success());
            if ok && rec.result.is_none() {
                rec.result = std::fs::read_to_string(rec.run_dir.join("summary.json"))
                    .ok()
                    .and_then(|t| serde_json::from_str(&t).ok());
            }
            let interrupted = rec.result.as_ref().is_some_and(|r| r.interrupted);
            rec.state = if ok && (interrupted || rec.stop_requested) {
                State::Stopped
            } else if ok {
                State::Succeeded
            } else {
                rec.error = match &status {
                    Ok(s) => format!(
                        "ess train exited with {s}: {}",
                        log_tail(&rec.run_dir.join("train.log"), 3)
                    ),
                    Err(e) => format!("waiting for ess train: {e}"),
                };
                State::Failed
            };
            if let Some(r) = &rec.result {
                rec.env_steps = r.env_steps;
            }
            rec.resume_next = rec.state != State::Succeeded && has_checkpoint(&rec.run_dir);
            rec.stop_requested = false;
            tracing::info!(job = %id, state = rec.state.name(), "ended");
            if let Err(e) = persist(rec) {
                tracing::warn!(job = %id, error = %e, "job record not written");
            }
            publish(entry, None);
        }
        self.schedule(&mut inner);
    }

    /// Resolves once no job process is running.
    async fn all_ended(&self) {
        loop {
            let ended = self.ended.notified();
            if self.lock().running == 0 {
                return;
            }
            ended.await;
        }
    }

    /// Stops taking work, stops every running job gracefully (SIGTERM; SIGKILL after
    /// the grace period), and ends open watch streams. Queued jobs stay queued for the
    /// next server on this data dir.
    pub async fn shutdown(self: &Arc<Self>) {
        let pids: Vec<u32> = {
            let mut inner = self.lock();
            inner.shutting_down = true;
            let mut pids = Vec::new();
            for e in inner.jobs.values_mut() {
                if let Some(pid) = e.pid {
                    if e.rec.state == State::Running {
                        e.rec.state = State::Stopping;
                        e.rec.stop_requested = true;
                        if let Err(err) = persist(&e.rec) {
                            tracing::warn!(job = %e.rec.id, error = %err, "job record not written");
                        }
                        publish(e, None);
                    }
                    pids.push(pid);
                }
            }
            pids
        };
        for &pid in &pids {
            terminate(pid);
        }
        if !pids.is_empty() {
            tracing::info!(jobs = pids.len(), "stopping running jobs");
        }
        if tokio::time::timeout(self.cfg.stop_grace, self.all_ended())
            .await
            .is_err()
        {
            let left: Vec<u32> = self.lock().jobs.values().filter_map(|e| e.pid).collect();
            tracing::warn!(pids = ?left, "jobs did not stop in time; killing them");
            for pid in left {
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(pid as i32),
                    nix::sys::signal::Signal::SIGKILL,
                );
            }
            let _ = tokio::time::timeout(Duration::from_secs(10), self.all_ended()).await;
        }
        self.closing.send_replace(true);
    }
}

/// Sends the job's current state (with `metrics`, the iteration that just finished).
fn publish(entry: &mut Entry, metrics: Option<(usize, pb::IterationMetrics)>) {
    let (seq, metrics) = match metrics {
        Some((s, m)) => (Some(s), Some(m)),
        None => (None, None),
    };
    // No receivers is fine: nobody watches.
    let _ = entry.tx.send(Broadcast {
        seq,
        event: Arc::new(pb::JobEvent {
            job: Some(entry.rec.to_pb()),
            metrics,
        }),
    });
}

/// SIGTERM: the child finishes its iteration, checkpoints and exits.
fn terminate(pid: u32) {
    let Ok(raw) = i32::try_from(pid) else { return };
    if let Err(e) = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(raw),
        nix::sys::signal::Signal::SIGTERM,
    ) {
        tracing::warn!(pid, error = %e, "cannot signal the job process");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stopped job's record as the manager wrote it in `old`'s data dir.
    fn stopped_record(old: &std::path::Path) -> String {
        serde_json::json!({
            "id": "gail.traj2d.s0", "seq": 1, "preset": "gail", "state": "stopped",
            "spec": {"preset": "gail", "env": "traj2d", "seed": 0, "overrides": [],
                     "config_toml": ""},
            "iteration": 3, "iterations": 10, "env_steps": 300, "cores": 1,
            "torch_threads": null, "run_dir": old.join("jobs/gail.traj2d.s0"),
            "created_unix_ms": 1, "started_unix_ms": 2, "finished_unix_ms": 3,
            "error": "", "result": null, "resumes": 0, "resume_next": false,
            "stop_requested": true,
        })
        .to_string()
    }

    #[tokio::test]
    async fn a_moved_data_dir_keeps_its_jobs_in_their_new_place() {
        let new = tempfile::tempdir().unwrap();
        let run = new.path().join("jobs/gail.traj2d.s0");
        std::fs::create_dir_all(&run).unwrap();
        let old = std::path::Path::new("/nonexistent/grid");
        std::fs::write(run.join("job.json"), stopped_record(old)).unwrap();
        let m = Manager::open(ManagerConfig {
            data_dir: new.path().to_path_buf(),
            cores: 1,
            exe: "/bin/false".into(),
            stop_grace: Duration::from_secs(1),
        })
        .unwrap();
        let job = m.get("gail.traj2d.s0").unwrap();
        assert_eq!(job.run_dir, run.display().to_string());
        // Resuming writes the record where it now lies, not under the old path.
        m.resume("gail.traj2d.s0").unwrap();
        let text = std::fs::read_to_string(run.join("job.json")).unwrap();
        assert!(text.contains(&*run.to_string_lossy()), "{text}");
        m.shutdown().await;
    }
}
