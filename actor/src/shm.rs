//! The iceoryx2 side of actor processes: service names and quality of service shared by
//! the learner and its actors, the small fixed-size control messages, and the actor
//! process's main loop ([`run_actor`]).
//!
//! Services of one run, all named `ess/<run id>/...` so two runs on one machine never see
//! each other:
//!
//! | service | pattern | payload | direction |
//! |---|---|---|---|
//! | `weights` | publish-subscribe, history 1 | `[u64]`: [`ess_proto::shm`] weights layout | learner -> actors |
//! | `requests` | publish-subscribe | [`Request`] | learner -> actors |
//! | `chunks` | publish-subscribe | `[u64]`: [`ess_proto::shm`] chunk or evaluation-episode layout | actors -> learner |
//! | `status` | publish-subscribe | [`Status`] (heartbeat) | actors -> learner |
//! | `wake-actors` / `wake-learner` | event | event id = actor index | both ways |
//!
//! Every wait is a [`iceoryx2::port::listener::Listener::timed_wait`] on an event service:
//! nobody spins. Requests and statuses are the only control flow: an actor that reports
//! itself idle while the learner still waits for its chunk gets the request (and, if its
//! weights are older than the request, the weights) again, so a restarted actor or a lost
//! notification costs one heartbeat period, never a hang.
//!
//! Evaluation: a [`Request::EVALUATE`] names one episode (code, eps, reset seed, job
//! index); the actor runs it on a second env of its own (built on first use, so its
//! rollout episode carries over untouched) and publishes it as one episode sample on the
//! `chunks` service. One episode in flight per actor keeps within the subscriber's buffer.
//!
//! Memory: each actor's chunk publisher reserves 5 samples (subscriber buffer 2, one loan,
//! iceoryx2's bookkeeping) of its largest chunk, measured 76 MB of `/dev/shm` (apparent
//! size; pages count once written) for one Humanoid actor taking a whole 5000-step rollout.
//!
//! Why the control messages live here and not in `ess-proto`: they are fixed-size
//! `#[repr(C)]` structs sent as iceoryx2 payloads, which need iceoryx2's `ZeroCopySend`
//! derive, and `ess-proto` stays free of transport crates. The variable-size layouts
//! (chunks, weights) are plain bytes and live in [`ess_proto::shm`].

use crate::policy::{LatentSpec, PolicyWeights};
use crate::rollout::{ActorError, Worker};
use ess_envs::Env;
use ess_proto::shm::{
    EpisodeArrays, ShmChunkHeader, ShmChunkLayout, ShmChunkWriter, ShmEpisodeHeader,
    ShmEpisodeLayout, ShmError, WeightsMsg, read_weights, run_id_hash, write_episode,
};
use ess_proto::weights::MlpLayout;
use ess_proto::{Mlp, Step, StepSink};
use iceoryx2::node::NodeView;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::time::{Duration, Instant};

/// The iceoryx2 service kind of every port: inter-process, with thread-safe handles so
/// the learner's ports can live in a `Send` [`crate::RolloutSource`] (same shared-memory
/// resources as `ipc::Service`).
pub type Ipc = iceoryx2::service::ipc_threadsafe::Service;

/// How often an actor reports that it is alive, idle or busy.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(200);

/// Errors of the shared-memory transport.
#[derive(Debug, thiserror::Error)]
pub enum ShmTransportError {
    /// An iceoryx2 call failed.
    #[error("iceoryx2 {op} on `{service}` failed: {why}")]
    Ipc {
        /// What was attempted.
        op: &'static str,
        /// The service (or node) involved.
        service: String,
        /// The iceoryx2 error.
        why: String,
    },
    /// A run id that cannot be part of a service name.
    #[error("run id `{run_id}` is not usable in a service name: {why}")]
    BadRunId {
        /// The run id.
        run_id: String,
        /// Why.
        why: String,
    },
    /// A shared-memory buffer was refused.
    #[error(transparent)]
    Layout(#[from] ShmError),
    /// Acting failed.
    #[error(transparent)]
    Actor(#[from] ActorError),
    /// The evaluation env could not be built.
    #[error("building the evaluation env: {0}")]
    EvalEnv(String),
    /// Weights that do not form a policy.
    #[error("weights version {version} do not form a policy: {why}")]
    BadWeights {
        /// Version received.
        version: u64,
        /// Why.
        why: String,
    },
}

fn ipc<'a, E: std::fmt::Debug>(
    op: &'static str,
    service: &'a str,
) -> impl FnOnce(E) -> ShmTransportError + 'a {
    move |e| ShmTransportError::Ipc {
        op,
        service: service.to_owned(),
        why: format!("{e:?}"),
    }
}

/// What the learner asks of one actor.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("EssRequest")]
pub struct Request {
    /// Actor index this request is for.
    pub actor: u32,
    /// [`Request::COLLECT`], [`Request::EVALUATE`], [`Request::SNAPSHOT`] or
    /// [`Request::STOP`].
    pub kind: u32,
    /// Increases with every rollout or evaluation job (resends keep it).
    pub request_id: u64,
    /// Weights version the steps must be taken with.
    pub policy_version: u64,
    /// Steps to take ([`Request::COLLECT`]).
    pub steps: u64,
    /// One-hot code of the evaluation episode ([`Request::EVALUATE`]).
    pub code: u32,
    /// `f32::to_bits` of its latent noise eps.
    pub eps_bits: u32,
    /// Its env reset seed.
    pub seed: u64,
    /// Its index in the learner's list of evaluation jobs (echoed in the episode).
    pub job: u64,
}

impl Request {
    /// Take `steps` steps and publish them as one chunk.
    pub const COLLECT: u32 = 0;
    /// Exit cleanly.
    pub const STOP: u32 = 1;
    /// Run one deterministic evaluation episode ([`crate::eval_episode`]) with `code`,
    /// `eps_bits`, `seed` and publish it as one episode sample
    /// ([`ess_proto::shm::write_episode`]) on the `chunks` service.
    pub const EVALUATE: u32 = 2;
    /// Publish this actor's [`crate::WorkerState`] as one sample on the `chunks`
    /// service ([`crate::state_msg`]); needs no weights.
    pub const SNAPSHOT: u32 = 3;
}

/// An actor's heartbeat.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("EssStatus")]
pub struct Status {
    /// Actor index.
    pub actor: u32,
    /// [`Status::IDLE`] or [`Status::BUSY`].
    pub state: u32,
    /// Process id (tells a restarted actor from its dead predecessor).
    pub pid: u32,
    /// Reserved, 0.
    pub reserved: u32,
    /// Last request whose chunk was published (0: none).
    pub last_done: u64,
    /// Version of the weights held (0: none yet).
    pub weights_version: u64,
    /// Steps taken so far by this process.
    pub steps: u64,
}

impl Status {
    /// Waiting for a request (or for the weights it needs).
    pub const IDLE: u32 = 0;
    /// Collecting steps.
    pub const BUSY: u32 = 1;
}

/// Service name `ess/<run id>/<what>`.
pub fn service_name(run_id: &str, what: &str) -> Result<ServiceName, ShmTransportError> {
    let name = format!("ess/{run_id}/{what}");
    name.as_str()
        .try_into()
        .map_err(|e| ShmTransportError::BadRunId {
            run_id: run_id.to_owned(),
            why: format!("{e:?}"),
        })
}

/// Creates an iceoryx2 node; signal handling stays with the program (the learner has its
/// own Ctrl-C handler; actors are stopped by the learner).
///
/// iceoryx2's own log goes to stderr at level error unless `IOX2_LOG_LEVEL` says otherwise
/// (its default, warn, prints a notice about the absent config file on every start).
pub fn node(name: &str) -> Result<Node<Ipc>, ShmTransportError> {
    set_log_level_from_env_or(LogLevel::Error);
    let node_name = NodeName::new(name).map_err(ipc("node name", name))?;
    NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(ipc("node create", name))
}

/// Names of the iceoryx2 nodes on this machine whose name contains `part` (learner
/// nodes are `ess-learner-<run id>`, actor nodes `ess-actor-<run id>-<index>`), with
/// `true` for a live node and `false` for a dead one whose resources are not cleaned up.
pub fn nodes_named(part: &str) -> Result<Vec<(String, bool)>, ShmTransportError> {
    let mut out = Vec::new();
    Node::<Ipc>::list(Config::global_config(), |state| {
        let (details, alive) = match &state {
            NodeState::Alive(v) => (v.details().clone(), true),
            NodeState::Dead(v) => (v.details().clone(), false),
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => (None, false),
        };
        if let Some(d) = details {
            let name = d.name().to_string();
            if name.contains(part) {
                out.push((name, alive));
            }
        }
        CallbackProgression::Continue
    })
    .map_err(ipc("list nodes", part))?;
    Ok(out)
}

/// Opens (or creates) every service of a run with `n_actors` actors. Learner and actors
/// call this with the same `n_actors` so the quality of service matches.
pub struct Services {
    /// Run id.
    pub run_id: String,
    /// `weights` service.
    pub weights: iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [u64], ()>,
    /// `requests` service.
    pub requests: iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, Request, ()>,
    /// `chunks` service.
    pub chunks: iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [u64], ()>,
    /// `status` service.
    pub status: iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, Status, ()>,
    /// `wake-actors` event.
    pub wake_actors: iceoryx2::service::port_factory::event::PortFactory<Ipc>,
    /// `wake-learner` event.
    pub wake_learner: iceoryx2::service::port_factory::event::PortFactory<Ipc>,
}

impl Services {
    /// Opens or creates the run's services on `node`.
    pub fn open(
        node: &Node<Ipc>,
        run_id: &str,
        n_actors: usize,
    ) -> Result<Self, ShmTransportError> {
        // Room for every actor twice over: a killed actor's ports count until its dead
        // node is cleaned up.
        let ports = 2 * n_actors + 2;
        let name = |what| service_name(run_id, what);
        let n = name("weights")?;
        let weights = node
            .service_builder(&n)
            .publish_subscribe::<[u64]>()
            .max_publishers(1)
            .max_subscribers(ports)
            .history_size(1)
            .subscriber_max_buffer_size(2)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        let n = name("requests")?;
        let requests = node
            .service_builder(&n)
            .publish_subscribe::<Request>()
            .max_publishers(1)
            .max_subscribers(ports)
            .history_size(0)
            .subscriber_max_buffer_size(4 * n_actors + 8)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        let n = name("chunks")?;
        let chunks = node
            .service_builder(&n)
            .publish_subscribe::<[u64]>()
            .max_publishers(ports)
            .max_subscribers(1)
            .history_size(0)
            .subscriber_max_buffer_size(2)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        let n = name("status")?;
        let status = node
            .service_builder(&n)
            .publish_subscribe::<Status>()
            .max_publishers(ports)
            .max_subscribers(1)
            .history_size(0)
            .subscriber_max_buffer_size(16)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        let n = name("wake-actors")?;
        let wake_actors = node
            .service_builder(&n)
            .event()
            .max_notifiers(1)
            .max_listeners(ports)
            .event_id_max_value(n_actors + 1)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        let n = name("wake-learner")?;
        let wake_learner = node
            .service_builder(&n)
            .event()
            .max_notifiers(ports)
            .max_listeners(1)
            .event_id_max_value(n_actors + 1)
            .open_or_create()
            .map_err(ipc("open_or_create", n.as_str()))?;
        Ok(Self {
            run_id: run_id.to_owned(),
            weights,
            requests,
            chunks,
            status,
            wake_actors,
            wake_learner,
        })
    }
}

/// Flattens `w` and `latent` into what travels on the `weights` service.
pub fn weights_msg(w: &PolicyWeights, latent: &LatentSpec, run_id: &str) -> WeightsMsg {
    WeightsMsg {
        run_id_hash: run_id_hash(run_id),
        version: w.version,
        sizes: w.mean.layout().sizes.clone(),
        params: w.mean.params().to_vec(),
        log_std: w.log_std.clone(),
        prior_logits: w.prior_logits.clone(),
        obs_mean: w.obs_mean.clone(),
        obs_std: w.obs_std.clone(),
        prior: latent.prior,
        tau: latent.tau,
        use_eps: latent.use_eps,
    }
}

/// The policy and latent spec a [`WeightsMsg`] carries.
pub fn policy_from_msg(m: WeightsMsg) -> Result<(PolicyWeights, LatentSpec), ShmTransportError> {
    let bad = |why: String| ShmTransportError::BadWeights {
        version: m.version,
        why,
    };
    let layout = MlpLayout {
        sizes: m.sizes.clone(),
    };
    let mean = Mlp::new(layout, m.params.clone()).map_err(|e| bad(e.to_string()))?;
    let latent = LatentSpec {
        prior: m.prior,
        n_codes: m.prior_logits.len(),
        tau: m.tau,
        use_eps: m.use_eps,
    };
    Ok((
        PolicyWeights {
            version: m.version,
            mean,
            log_std: m.log_std,
            prior_logits: m.prior_logits,
            obs_mean: m.obs_mean,
            obs_std: m.obs_std,
        },
        latent,
    ))
}

/// What an actor process needs besides its environment.
#[derive(Debug, Clone)]
pub struct ActorSettings {
    /// Run id (service names).
    pub run_id: String,
    /// This actor's index.
    pub index: usize,
    /// Actors in the run (quality of service of the services).
    pub n_actors: usize,
    /// Most steps one request asks for (sizes the chunk publisher).
    pub max_steps: usize,
    /// Number of latent codes (sizes the chunk publisher).
    pub n_codes: usize,
    /// Exit when the parent process goes away (the learner was killed).
    pub parent_pid: Option<u32>,
}

/// Builds the env evaluation episodes run on (a second env of the actor, so that its
/// rollout episode carries over untouched); called once, at the first evaluation request.
pub type EvalEnvFactory<'a> = &'a mut dyn FnMut() -> Result<Box<dyn Env>, String>;

/// The actor side of one process: ports plus the state reported in heartbeats.
struct ActorPorts {
    weights: Subscriber<Ipc, [u64], ()>,
    requests: Subscriber<Ipc, Request, ()>,
    chunks: Publisher<Ipc, [u64], ()>,
    status: Publisher<Ipc, Status, ()>,
    wake_learner: Notifier<Ipc>,
    wake_me: Listener<Ipc>,
    index: u32,
    pid: u32,
    last_beat: Instant,
    last_done: u64,
    weights_version: u64,
    steps: u64,
    run_id: String,
}

impl ActorPorts {
    fn beat(&mut self, state: u32) -> Result<(), ShmTransportError> {
        let st = Status {
            actor: self.index,
            state,
            pid: self.pid,
            reserved: 0,
            last_done: self.last_done,
            weights_version: self.weights_version,
            steps: self.steps,
        };
        let svc = &self.run_id;
        self.status.send_copy(st).map_err(ipc("send status", svc))?;
        self.wake_learner
            .notify_with_custom_event_id(EventId::new(self.index as usize))
            .map_err(ipc("notify learner", svc))?;
        self.last_beat = Instant::now();
        Ok(())
    }
}

/// A [`StepSink`] that writes into the loaned sample and beats the heartbeat while a long
/// collection runs (a hung env therefore stops the heartbeat, as it should).
struct BeatingSink<'a, 'b> {
    writer: ShmChunkWriter<'a>,
    ports: &'b mut ActorPorts,
    beat_error: Option<ShmTransportError>,
}

impl StepSink for BeatingSink<'_, '_> {
    type Error = ShmError;
    fn push(&mut self, s: &Step<'_>) -> Result<(), ShmError> {
        self.writer.try_push(s)?;
        self.ports.steps += 1;
        if self.writer.written().is_multiple_of(64)
            && self.ports.last_beat.elapsed() >= HEARTBEAT_PERIOD
            && let Err(e) = self.ports.beat(Status::BUSY)
        {
            self.beat_error = Some(e);
        }
        Ok(())
    }
}

fn parent_gone(parent: Option<u32>) -> bool {
    parent.is_some_and(|p| std::os::unix::process::parent_id() != p)
}

impl ActorPorts {
    /// This actor's ports on the run's services; `max_words` sizes the chunk publisher
    /// for the largest request.
    fn open(
        svc: &Services,
        settings: &ActorSettings,
        max_words: usize,
    ) -> Result<Self, ShmTransportError> {
        Ok(ActorPorts {
            weights: svc
                .weights
                .subscriber_builder()
                .create()
                .map_err(ipc("subscriber", "weights"))?,
            requests: svc
                .requests
                .subscriber_builder()
                .create()
                .map_err(ipc("subscriber", "requests"))?,
            chunks: svc
                .chunks
                .publisher_builder()
                .initial_max_slice_len(max_words)
                .allocation_strategy(AllocationStrategy::PowerOfTwo)
                .max_loaned_samples(1)
                .create()
                .map_err(ipc("publisher", "chunks"))?,
            status: svc
                .status
                .publisher_builder()
                .create()
                .map_err(ipc("publisher", "status"))?,
            wake_learner: svc
                .wake_learner
                .notifier_builder()
                .create()
                .map_err(ipc("notifier", "wake-learner"))?,
            wake_me: svc
                .wake_actors
                .listener_builder()
                .create()
                .map_err(ipc("listener", "wake-actors"))?,
            index: settings.index as u32,
            pid: std::process::id(),
            last_beat: Instant::now(),
            last_done: 0,
            weights_version: 0,
            steps: 0,
            run_id: settings.run_id.clone(),
        })
    }

    /// The policy of the newest weights message of this run, when it is new.
    fn newest_policy(
        &mut self,
        hash: u64,
    ) -> Result<Option<(PolicyWeights, LatentSpec)>, ShmTransportError> {
        let mut newest = None;
        while let Some(s) = self.weights.receive().map_err(ipc("receive", "weights"))? {
            let m = read_weights(bytemuck::cast_slice(s.payload()))?;
            if m.run_id_hash == hash && m.version != self.weights_version {
                self.weights_version = m.version;
                newest = Some(policy_from_msg(m)?);
            }
        }
        Ok(newest)
    }

    /// Reads the waiting requests: a snapshot is answered at once, the newest collect
    /// or evaluate request for this actor goes to `pending`; true on a stop request.
    fn take_requests(
        &mut self,
        worker: &mut Worker,
        hash: u64,
        pending: &mut Option<Request>,
    ) -> Result<bool, ShmTransportError> {
        while let Some(r) = self
            .requests
            .receive()
            .map_err(ipc("receive", "requests"))?
        {
            let r = *r.payload();
            if r.kind == Request::STOP {
                return Ok(true);
            }
            if r.actor == self.index && r.request_id > self.last_done {
                if r.kind == Request::SNAPSHOT {
                    publish_state(self, worker, &r, hash)?;
                } else {
                    *pending = Some(r);
                }
            }
        }
        Ok(false)
    }
}

/// The actor process's loop: wait for weights and requests, collect, publish, repeat,
/// until a stop request or the parent's death. `worker` acts; its episode carries over
/// from one request to the next exactly as on the threaded path.
pub fn run_actor(
    settings: &ActorSettings,
    worker: &mut Worker,
    make_eval_env: EvalEnvFactory<'_>,
) -> Result<(), ShmTransportError> {
    let run = settings.run_id.as_str();
    let node = node(&format!("ess-actor-{run}-{}", settings.index))?;
    let svc = Services::open(&node, run, settings.n_actors)?;
    let spec = worker.env().spec().clone();
    // Sized for the largest request; grows (power of two) should one ask for more.
    let max_words = ShmChunkLayout::new(
        spec.obs_dim,
        spec.act_dim,
        settings.n_codes,
        settings.max_steps,
    )
    .words()
    .max(16);
    let mut ports = ActorPorts::open(&svc, settings, max_words)?;
    let hash = run_id_hash(run);
    let mut policy: Option<(PolicyWeights, LatentSpec)> = None;
    let mut pending: Option<Request> = None;
    let mut eval_env: Option<Box<dyn Env>> = None;
    ports.beat(Status::IDLE)?;
    loop {
        if parent_gone(settings.parent_pid) {
            tracing::warn!(actor = settings.index, "learner is gone; exiting");
            return Ok(());
        }
        if let Some(p) = ports.newest_policy(hash)? {
            policy = Some(p);
        }
        if ports.take_requests(worker, hash, &mut pending)? {
            tracing::debug!(actor = settings.index, "stop requested");
            return Ok(());
        }
        let ready = match (&pending, &policy) {
            (Some(r), Some((w, _))) => {
                if w.version > r.policy_version {
                    // The learner has moved on; this request is stale.
                    pending = None;
                    false
                } else {
                    w.version == r.policy_version
                }
            }
            _ => false,
        };
        if let (true, Some(r), Some((w, latent))) = (ready, pending.take(), policy.as_ref()) {
            if r.kind == Request::EVALUATE {
                let env = match &mut eval_env {
                    Some(e) => e,
                    None => eval_env.insert(make_eval_env().map_err(ShmTransportError::EvalEnv)?),
                };
                evaluate_and_publish(&mut ports, env.as_mut(), w, latent, &r, hash)?;
            } else {
                collect_and_publish(&mut ports, worker, w, latent, &r, hash)?;
            }
            continue;
        }
        if ports.last_beat.elapsed() >= HEARTBEAT_PERIOD {
            ports.beat(Status::IDLE)?;
        }
        match ports.wake_me.timed_wait(|_| {}, HEARTBEAT_PERIOD) {
            // A signal cut the wait short (the actor's own handling decides what it
            // means); waking early is harmless.
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
            Err(e) => return Err(ipc("wait", "wake-actors")(e)),
        }
    }
}

/// Answers a [`Request::SNAPSHOT`]: the worker's state as one `chunks` sample.
fn publish_state(
    ports: &mut ActorPorts,
    worker: &Worker,
    r: &Request,
    hash: u64,
) -> Result<(), ShmTransportError> {
    let words = crate::state_msg::encode(&crate::state_msg::StateMsg {
        run_id_hash: hash,
        actor: ports.index,
        request_id: r.request_id,
        state: worker.snapshot(),
    });
    let mut sample = ports
        .chunks
        .loan_slice(words.len())
        .map_err(ipc("loan", "chunks"))?;
    sample.payload_mut().copy_from_slice(&words);
    sample.send().map_err(ipc("send", "chunks"))?;
    ports.last_done = r.request_id;
    ports.beat(Status::IDLE)
}

fn collect_and_publish(
    ports: &mut ActorPorts,
    worker: &mut Worker,
    w: &PolicyWeights,
    latent: &LatentSpec,
    r: &Request,
    hash: u64,
) -> Result<(), ShmTransportError> {
    let spec = worker.env().spec().clone();
    let n = r.steps as usize;
    let layout = ShmChunkLayout::new(spec.obs_dim, spec.act_dim, latent.n_codes, n);
    // Loaned zero-filled (a memset of the sample, not a copy); the steps are then written
    // into it in place.
    let mut sample = ports
        .chunks
        .loan_slice(layout.words())
        .map_err(ipc("loan", "chunks"))?;
    let header = ShmChunkHeader {
        run_id_hash: hash,
        actor: ports.index,
        request_id: r.request_id,
        policy_version: w.version,
        len: n as u64,
        obs_dim: spec.obs_dim as u32,
        act_dim: spec.act_dim as u32,
        n_codes: latent.n_codes as u32,
        ..Default::default()
    };
    let writer = ShmChunkWriter::new(bytemuck::cast_slice_mut(sample.payload_mut()), header)?;
    let mut sink = BeatingSink {
        writer,
        ports,
        beat_error: None,
    };
    worker.collect_into(w, latent, n, &mut sink)?;
    if let Some(e) = sink.beat_error.take() {
        return Err(e);
    }
    let complete = sink.writer.is_complete();
    drop(sink);
    if !complete {
        return Err(ShmError::Full { capacity: n }.into());
    }
    sample.send().map_err(ipc("send", "chunks"))?;
    ports.last_done = r.request_id;
    ports.beat(Status::IDLE)
}

/// Runs one evaluation episode and publishes it. The episode is built in owned `Vec`s by
/// [`crate::eval_episode`] (the same function as the in-process path) and copied once into
/// the loaned sample; an episode is short next to a rollout, so that copy is accepted. A
/// heartbeat goes out before and after: one episode must take less than the learner's
/// heartbeat timeout.
fn evaluate_and_publish(
    ports: &mut ActorPorts,
    env: &mut dyn Env,
    w: &PolicyWeights,
    latent: &LatentSpec,
    r: &Request,
    hash: u64,
) -> Result<(), ShmTransportError> {
    ports.beat(Status::BUSY)?;
    let ep = crate::eval_episode(
        env,
        w,
        latent,
        r.code as usize,
        f32::from_bits(r.eps_bits),
        r.seed,
    )?;
    let spec = env.spec();
    let layout = ShmEpisodeLayout {
        obs_dim: spec.obs_dim,
        act_dim: spec.act_dim,
        n_modes: ep.n_modes,
        state_dim: ep.state_dim,
        len: ep.len(),
    };
    let header = ShmEpisodeHeader {
        run_id_hash: hash,
        actor: ports.index,
        code: ep.code as u32,
        request_id: r.request_id,
        policy_version: w.version,
        job: r.job,
        len: ep.len() as u64,
        obs_dim: spec.obs_dim as u32,
        act_dim: spec.act_dim as u32,
        n_modes: ep.n_modes as u32,
        eps_bits: ep.eps.to_bits(),
        state_dim: ep.state_dim as u32,
        ..Default::default()
    };
    let arrays = EpisodeArrays {
        start_state: ep.start_state,
        states: ep.states,
        start_obs: ep.start_obs,
        obs: ep.obs,
        act: ep.act,
        next_obs: ep.next_obs,
        mode_rewards: ep.mode_rewards,
    };
    let mut sample = ports
        .chunks
        .loan_slice(layout.words())
        .map_err(ipc("loan", "chunks"))?;
    write_episode(
        bytemuck::cast_slice_mut(sample.payload_mut()),
        header,
        &arrays,
    )?;
    sample.send().map_err(ipc("send", "chunks"))?;
    ports.steps += header.len;
    ports.last_done = r.request_id;
    ports.beat(Status::IDLE)
}
