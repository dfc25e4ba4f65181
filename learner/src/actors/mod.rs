//! Actor processes: [`ShmActors`] starts and supervises `ess-actor` processes and gathers
//! their rollouts over iceoryx2 shared memory, behind the same [`RolloutSource`] seam as
//! the in-process [`ess_actor::ThreadedActors`].
//!
//! Per [`RolloutSource::collect`]: publish the weights (stamped with their version), send
//! each actor its share of the rollout ([`split_steps`]), then wait on the `wake-learner`
//! event (never spinning) for chunks and heartbeats. A chunk is accepted only if it answers
//! this rollout's request, was produced with this version, and has exactly the steps asked
//! for; anything else is dropped with a log line. An actor whose process exited, or that
//! sent no heartbeat for `heartbeat_timeout` (`run.actor_timeout_s`), is killed, reaped, restarted and asked again
//! for its whole share (a partial chunk is never published, so nothing partial is kept).
//!
//! Evaluation ([`EvalRunner`], reached through [`RolloutSource::evaluator`]) follows the
//! same pattern one episode at a time: publish the evaluated weights, hand each free
//! actor the next job, gather the episodes at their job's index, restart a dead or silent
//! actor and ask it again for the job it held.
//!
//! Checkpoints: [`RolloutSource::snapshot`] asks every actor for its state (a
//! `SNAPSHOT` request answered on the `chunks` service), and [`RolloutSource::restore`]
//! restarts every actor from a state file ([`state`]), so a resumed run with actor
//! processes continues their episodes and is bit-identical to an uninterrupted one.
//!
//! An actor's standard error passes through the learner's, and the error naming an actor
//! that exited quotes its last lines (the loader's message behind exit status 127, say).
//!
//! Children run in their own process group (a terminal Ctrl-C reaches only the learner,
//! which finishes its iteration and then stops them), and exit by themselves when the
//! learner dies. Dropping [`ShmActors`] sends a stop request, waits briefly, kills what is
//! left, reaps every child and removes the dead nodes' iceoryx2 resources; creating one
//! first removes the resources of dead nodes left by killed runs.
//!
//! Configuration: the choice of transport is `run.transport` (`threads` |
//! `processes`); `run.actors = 0` (in a config, `--set`, a job spec or `ess train
//! --actors 0`) is the single-process path, one actor thread. Actor `i` seeds its stream
//! with `ess_actor::actor_seed` on either transport, which is why `--actors 1` reproduces the
//! threaded run bit for bit. A restarted actor gets a different seed (its predecessor's
//! episodes are not replayed), so a run with a restart is
//! no longer bit-identical to one without.

mod eval;
mod state;
mod stderr;

use ess_actor::shm::{
    HEARTBEAT_PERIOD, Ipc, Request, ShmTransportError, Status, node, weights_msg,
};
use ess_actor::{ActorError, EvalRunner, LatentSpec, PolicyWeights, RolloutSource, split_steps};
use ess_proto::Chunk;
use ess_proto::shm::{read_chunk, run_id_hash, write_weights};
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};
use stderr::StderrTail;

/// Restarts of one actor within one rollout after which the rollout fails.
const MAX_RESTARTS_PER_ROLLOUT: u32 = 3;

/// Errors starting or running actor processes.
#[derive(Debug, thiserror::Error)]
pub enum ShmActorsError {
    /// The `ess-actor` binary is not where it was looked for.
    #[error(
        "actor binary `{}` not found (build it with `cargo build -p ess-actor --bin ess-actor`, or set ESS_ACTOR_BIN)",
        path.display()
    )]
    BinaryMissing {
        /// Where it was looked for.
        path: PathBuf,
    },
    /// Spawning an actor failed.
    #[error("starting actor {index} (`{}`): {source}", path.display())]
    Spawn {
        /// Actor index.
        index: usize,
        /// The binary.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Settings that cannot work.
    #[error("actor processes: {field} = {value}: {reason}")]
    BadSetting {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: String,
        /// Why.
        reason: &'static str,
    },
    /// The transport failed.
    #[error(transparent)]
    Transport(#[from] ShmTransportError),
}

/// The `ess-actor` binary: `$ESS_ACTOR_BIN`, else `ess-actor` beside the current
/// executable. Checked to exist.
pub fn actor_binary() -> Result<PathBuf, ShmActorsError> {
    let path = match std::env::var_os("ESS_ACTOR_BIN") {
        Some(p) => PathBuf::from(p),
        None => std::env::current_exe()
            .ok()
            .and_then(|e| e.parent().map(|d| d.join("ess-actor")))
            .unwrap_or_else(|| PathBuf::from("ess-actor")),
    };
    if !path.is_file() {
        return Err(ShmActorsError::BinaryMissing { path });
    }
    Ok(path)
}

/// How to start the actors.
#[derive(Debug, Clone)]
pub struct ShmActorsConfig {
    /// Run id, unique on the machine (see [`new_run_id`]).
    pub run_id: String,
    /// The `ess-actor` binary.
    pub binary: PathBuf,
    /// Env name.
    pub env: String,
    /// Env modes.
    pub n_modes: usize,
    /// Latent spec (number of codes).
    pub latent: LatentSpec,
    /// Seed of each actor's random stream (its length is the number of actors).
    pub seeds: Vec<u64>,
    /// Most steps one request asks of one actor.
    pub max_steps: usize,
    /// An actor silent this long is restarted.
    pub heartbeat_timeout: Duration,
    /// A newly started actor gets this long before its first heartbeat.
    pub startup_timeout: Duration,
    /// Build envs without their experts (`make_plain_env`, expert training).
    pub plain_env: bool,
    /// Record this mode's task reward as the env reward (expert training).
    pub task_mode: Option<usize>,
}

/// A run id unique on this machine: learner pid and start time.
pub fn new_run_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("{}-{:x}", std::process::id(), nanos & 0xffff_ffff_ffff)
}

struct Proc {
    child: Child,
    pid: u32,
    started: Instant,
    last_seen: Option<Instant>,
    last_status: Option<Status>,
    last_resend: Instant,
    /// Its first heartbeat just arrived: it may have missed what was sent before it
    /// subscribed, so resend at once rather than after the resend period.
    just_started: bool,
    restarts: u32,
    /// Its standard error's last lines, for the error that names it dead.
    stderr: StderrTail,
}

/// Actors as `ess-actor` processes over iceoryx2 shared memory.
pub struct ShmActors {
    cfg: ShmActorsConfig,
    hash: u64,
    procs: Vec<Proc>,
    request_id: u64,
    /// Last rollout's caller version (must increase).
    weights_version: u64,
    /// Version stamped on the wire: increases with every publish (rollouts and
    /// evaluations), since an evaluation's weights may carry the caller version of the
    /// rollout before them while holding different parameters.
    wire_version: u64,
    weights: Publisher<Ipc, [u64], ()>,
    requests: Publisher<Ipc, Request, ()>,
    chunks: Subscriber<Ipc, [u64], ()>,
    status: Subscriber<Ipc, Status, ()>,
    wake_actors: Notifier<Ipc>,
    wake_me: Listener<Ipc>,
    _services: ess_actor::shm::Services,
    node: Node<Ipc>,
}

fn tr<E: std::fmt::Debug>(
    op: &'static str,
    service: &'static str,
) -> impl FnOnce(E) -> ShmActorsError {
    move |e| {
        ShmActorsError::Transport(ShmTransportError::Ipc {
            op,
            service: service.to_owned(),
            why: format!("{e:?}"),
        })
    }
}

fn gone(index: usize, why: String) -> ActorError {
    ActorError::WorkerGone { index, why }
}

fn transport(what: String) -> ActorError {
    ActorError::Transport { what }
}

impl ShmActors {
    /// Cleans up stale iceoryx2 resources of dead runs, creates this run's services and
    /// starts one process per seed.
    pub fn new(cfg: ShmActorsConfig) -> Result<Self, ShmActorsError> {
        let n = cfg.seeds.len();
        if n == 0 || n > 256 {
            return Err(ShmActorsError::BadSetting {
                field: "actors",
                value: n.to_string(),
                reason: "must be in 1..=256",
            });
        }
        if !cfg.binary.is_file() {
            return Err(ShmActorsError::BinaryMissing {
                path: cfg.binary.clone(),
            });
        }
        let node = node(&format!("ess-learner-{}", cfg.run_id))?;
        let cleaned = node.try_cleanup_dead_nodes();
        if cleaned.cleanups > 0 || cleaned.failed_cleanups > 0 {
            tracing::info!(
                cleaned = cleaned.cleanups,
                failed = cleaned.failed_cleanups,
                "removed iceoryx2 resources of dead processes"
            );
        }
        let svc = ess_actor::shm::Services::open(&node, &cfg.run_id, n)?;
        let weights = svc
            .weights
            .publisher_builder()
            .initial_max_slice_len(4096)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(tr("publisher", "weights"))?;
        let requests = svc
            .requests
            .publisher_builder()
            .create()
            .map_err(tr("publisher", "requests"))?;
        let chunks = svc
            .chunks
            .subscriber_builder()
            .create()
            .map_err(tr("subscriber", "chunks"))?;
        let status = svc
            .status
            .subscriber_builder()
            .create()
            .map_err(tr("subscriber", "status"))?;
        let wake_actors = svc
            .wake_actors
            .notifier_builder()
            .create()
            .map_err(tr("notifier", "wake-actors"))?;
        let wake_me = svc
            .wake_learner
            .listener_builder()
            .create()
            .map_err(tr("listener", "wake-learner"))?;
        let mut me = Self {
            hash: run_id_hash(&cfg.run_id),
            procs: Vec::with_capacity(n),
            request_id: 0,
            weights_version: 0,
            wire_version: 0,
            weights,
            requests,
            chunks,
            status,
            wake_actors,
            wake_me,
            _services: svc,
            node,
            cfg,
        };
        for i in 0..n {
            let p = me.spawn(i, 0, None)?;
            me.procs.push(p);
        }
        Ok(me)
    }

    /// Process ids of the actors (for tests and logs).
    pub fn pids(&self) -> Vec<u32> {
        self.procs.iter().map(|p| p.pid).collect()
    }

    /// The run id.
    pub fn run_id(&self) -> &str {
        &self.cfg.run_id
    }

    /// Starts actor `index` (its `restarts`-th replacement), from the state in `restore`
    /// when given.
    fn spawn(
        &self,
        index: usize,
        restarts: u32,
        restore: Option<&std::path::Path>,
    ) -> Result<Proc, ShmActorsError> {
        // A restarted actor must not replay its predecessor's episodes.
        let seed =
            self.cfg.seeds[index] ^ (u64::from(restarts)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let mut cmd = Command::new(&self.cfg.binary);
        if self.cfg.plain_env {
            cmd.arg("--plain-env");
        }
        if let Some(k) = self.cfg.task_mode {
            cmd.arg("--task-mode").arg(k.to_string());
        }
        if let Some(p) = restore {
            cmd.arg("--restore-state").arg(p);
        }
        let mut child = cmd
            .arg("--run-id")
            .arg(&self.cfg.run_id)
            .arg("--index")
            .arg(index.to_string())
            .arg("--n-actors")
            .arg(self.cfg.seeds.len().to_string())
            .arg("--env")
            .arg(&self.cfg.env)
            .arg("--n-modes")
            .arg(self.cfg.n_modes.to_string())
            .arg("--n-codes")
            .arg(self.cfg.latent.n_codes.to_string())
            .arg("--seed")
            .arg(seed.to_string())
            .arg("--max-steps")
            .arg(self.cfg.max_steps.to_string())
            .arg("--parent-pid")
            .arg(std::process::id().to_string())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .process_group(0)
            .spawn()
            .map_err(|source| ShmActorsError::Spawn {
                index,
                path: self.cfg.binary.clone(),
                source,
            })?;
        let stderr = child
            .stderr
            .take()
            .map(StderrTail::follow)
            .unwrap_or_default();
        let now = Instant::now();
        Ok(Proc {
            pid: child.id(),
            child,
            started: now,
            last_seen: None,
            last_status: None,
            last_resend: now,
            just_started: false,
            restarts,
            stderr,
        })
    }

    /// Publishes `w` stamped with wire version `version`.
    fn publish_weights(&self, w: &PolicyWeights, version: u64) -> Result<(), ActorError> {
        let mut m = weights_msg(w, &self.cfg.latent, &self.cfg.run_id);
        m.version = version;
        let words = m.bytes() / 8;
        let mut sample = self
            .weights
            .loan_slice(words)
            .map_err(|e| transport(format!("loaning a weights sample: {e:?}")))?;
        write_weights(bytemuck::cast_slice_mut(sample.payload_mut()), &m)?;
        sample
            .send()
            .map_err(|e| transport(format!("publishing weights: {e:?}")))?;
        Ok(())
    }

    fn send_request(&self, r: Request) -> Result<(), ActorError> {
        self.requests
            .send_copy(r)
            .map_err(|e| gone(r.actor as usize, format!("sending a request: {e:?}")))?;
        self.wake_actors
            .notify()
            .map_err(|e| gone(r.actor as usize, format!("waking actors: {e:?}")))?;
        Ok(())
    }

    /// Kills (if needed), reaps and restarts actor `i`.
    fn restart(&mut self, i: usize, why: &str) -> Result<(), ActorError> {
        let p = &mut self.procs[i];
        let _ = p.child.kill();
        let status = p.child.wait();
        tracing::warn!(
            actor = i,
            pid = p.pid,
            ?status,
            "actor {i} (pid {}) {why}; restarted it and requested its share of this rollout again",
            p.pid
        );
        let restarts = p.restarts + 1;
        // Its ports stay registered until the dead node is cleaned up.
        self.node.try_cleanup_dead_nodes();
        let fresh = self
            .spawn(i, restarts, None)
            .map_err(|e| gone(i, format!("restarting: {e}")))?;
        self.procs[i] = fresh;
        Ok(())
    }

    /// Waits up to half a heartbeat period for an actor's event, then takes in every
    /// status (heartbeats, exits) that arrived; returns the time it did so.
    fn wait_and_drain_status(&mut self) -> Result<Instant, ActorError> {
        match self.wake_me.timed_wait(|_| {}, HEARTBEAT_PERIOD / 2) {
            // A signal (SIGTERM, Ctrl-C) cut the wait short: the learner's handler has
            // recorded it and the iteration still finishes, so this is a wake-up.
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
            Err(e) => return Err(transport(format!("waiting for actors: {e:?}"))),
        }
        let now = Instant::now();
        self.drain_status(now)?;
        Ok(now)
    }

    /// Takes every heartbeat that arrived: who is alive, who is idle.
    fn drain_status(&mut self, now: Instant) -> Result<(), ActorError> {
        while let Some(s) = self
            .status
            .receive()
            .map_err(|e| transport(format!("receiving status: {e:?}")))?
        {
            let s = *s.payload();
            let Some(p) = self.procs.get_mut(s.actor as usize) else {
                continue;
            };
            if s.pid != p.pid {
                continue; // from a dead predecessor
            }
            p.just_started |= p.last_status.is_none();
            p.last_seen = Some(now);
            p.last_status = Some(s);
        }
        Ok(())
    }

    /// Restarts actor `i` if its process exited or it sent no heartbeat in time; true if
    /// it was restarted (its request then goes out again once the new one reports idle).
    fn supervise(
        &mut self,
        i: usize,
        now: Instant,
        restarts_now: &mut [u32],
    ) -> Result<bool, ActorError> {
        let Some(why) = self.lost(i, now) else {
            return Ok(false);
        };
        restarts_now[i] += 1;
        if restarts_now[i] > MAX_RESTARTS_PER_ROLLOUT {
            return Err(gone(
                i,
                format!("{why}, after {MAX_RESTARTS_PER_ROLLOUT} restarts in one rollout"),
            ));
        }
        self.restart(i, &why)?;
        Ok(true)
    }

    /// Why actor `i` counts as lost at `now` (its process exited, with its last output,
    /// or it sent no heartbeat in time); `None` while it is alive and beating.
    fn lost(&mut self, i: usize, now: Instant) -> Option<String> {
        let p = &mut self.procs[i];
        let exited = match p.child.try_wait() {
            Ok(Some(st)) => Some(p.stderr.explain(format!("exited ({st})"))),
            Ok(None) => None,
            Err(e) => Some(format!("cannot be waited on ({e})")),
        };
        let silent = match p.last_seen {
            Some(t) => now.duration_since(t) > self.cfg.heartbeat_timeout,
            None => now.duration_since(p.started) > self.cfg.startup_timeout,
        };
        match (exited, silent) {
            (Some(w), _) => Some(w),
            (None, true) => Some(format!(
                "sent no heartbeat for {:?}",
                self.cfg.heartbeat_timeout
            )),
            (None, false) => None,
        }
    }

    /// Sends request `r` again if its actor reports itself idle without having answered
    /// it (a restarted actor, a lost notification), with the weights if it lacks them.
    fn resend_if_idle(
        &mut self,
        r: Request,
        w: &PolicyWeights,
        now: Instant,
    ) -> Result<(), ActorError> {
        let p = &mut self.procs[r.actor as usize];
        if let Some(s) = p.last_status
            && s.state == Status::IDLE
            && s.last_done < r.request_id
            && (p.just_started || now.duration_since(p.last_resend) > 2 * HEARTBEAT_PERIOD)
        {
            p.last_resend = now;
            p.just_started = false;
            if s.weights_version != r.policy_version {
                self.publish_weights(w, r.policy_version)?;
            }
            self.send_request(r)?;
        }
        Ok(())
    }

    /// Stops every actor: a stop request, a short grace period, then kill; reaps all.
    fn stop_all(&mut self) {
        let _ = self.send_request(Request {
            kind: Request::STOP,
            ..Default::default()
        });
        let deadline = Instant::now() + Duration::from_secs(2);
        for p in &mut self.procs {
            loop {
                match p.child.try_wait() {
                    Ok(Some(_)) | Err(_) => break,
                    Ok(None) if Instant::now() >= deadline => {
                        let _ = p.child.kill();
                        let _ = p.child.wait();
                        break;
                    }
                    Ok(None) => std::thread::sleep(Duration::from_millis(10)),
                }
            }
        }
        self.node.try_cleanup_dead_nodes();
    }
}

impl RolloutSource for ShmActors {
    fn n_actors(&self) -> usize {
        self.procs.len()
    }

    fn collect(
        &mut self,
        weights: Arc<PolicyWeights>,
        steps: usize,
    ) -> Result<Vec<Chunk>, ActorError> {
        let n = self.procs.len();
        // A version may repeat (the overlap pipeline collects iterations 1 and 2 under
        // the initial weights) but never go back.
        if weights.version < self.weights_version {
            return Err(transport(format!(
                "weights version {} is older than the last one ({})",
                weights.version, self.weights_version
            )));
        }
        let split = split_steps(steps, n);
        self.weights_version = weights.version;
        self.wire_version += 1;
        let wire = self.wire_version;
        self.publish_weights(&weights, wire)?;
        self.request_id += 1;
        let rid = self.request_id;
        let (od, ad, k) = (
            weights.obs_mean.len(),
            weights.log_std.len(),
            weights.prior_logits.len(),
        );
        let mut out: Vec<Option<Chunk>> = split
            .iter()
            .map(|&s| {
                (s == 0).then(|| {
                    let mut c = Chunk::with_capacity(od, ad, k, 0);
                    c.policy_version = weights.version;
                    c
                })
            })
            .collect();
        let request = |i: usize| Request {
            actor: i as u32,
            kind: Request::COLLECT,
            request_id: rid,
            policy_version: wire,
            steps: split[i] as u64,
            ..Default::default()
        };
        for i in (0..n).filter(|&i| split[i] > 0) {
            self.send_request(request(i))?;
            self.procs[i].last_resend = Instant::now();
        }
        let mut restarts_now = vec![0u32; n];
        while out.iter().any(Option::is_none) {
            let now = self.wait_and_drain_status()?;
            // Chunks.
            while let Some(sample) = self
                .chunks
                .receive()
                .map_err(|e| transport(format!("receiving a chunk: {e:?}")))?
            {
                let (h, mut chunk) = match read_chunk(bytemuck::cast_slice(sample.payload())) {
                    Ok(x) => x,
                    Err(e) => {
                        tracing::warn!("dropping a malformed chunk: {e}");
                        continue;
                    }
                };
                let i = h.actor as usize;
                let fits = h.run_id_hash == self.hash
                    && i < n
                    && h.request_id == rid
                    && h.policy_version == wire
                    && h.len as usize == split[i]
                    && (od, ad, k) == (chunk.obs_dim, chunk.act_dim, chunk.n_codes);
                if !fits || out[i].is_some() {
                    tracing::warn!(
                        actor = i,
                        request = h.request_id,
                        version = h.policy_version,
                        "dropping a chunk that does not answer this rollout's request"
                    );
                    continue;
                }
                chunk.policy_version = weights.version;
                out[i] = Some(chunk);
            }
            // Faults, and actors that missed their request or weights.
            for (i, done) in out.iter().enumerate() {
                if self.supervise(i, now, &mut restarts_now)? || done.is_some() {
                    continue;
                }
                self.resend_if_idle(request(i), &weights, now)?;
            }
        }
        Ok(out.into_iter().flatten().collect())
    }

    fn evaluator(&mut self) -> Option<&mut dyn EvalRunner> {
        Some(self)
    }

    /// Every actor's state, asked over shared memory ([`state`]).
    fn snapshot(&mut self) -> Result<Option<Vec<ess_actor::WorkerState>>, ActorError> {
        self.snapshot_states().map(Some)
    }

    /// Restarts every actor from its state ([`state`]).
    fn restore(&mut self, states: &[ess_actor::WorkerState]) -> Result<(), ActorError> {
        self.restore_states(states)
    }
}

impl Drop for ShmActors {
    fn drop(&mut self) {
        self.stop_all();
    }
}
