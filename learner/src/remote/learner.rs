//! The learner's side: [`RemoteActors`], the run's local actors plus the hosts that
//! joined, behind one [`RolloutSource`].

use super::wire::{
    Assign, HOST_TOKENS, LEARNER_TOKEN, Rpc, decode_chunk, parse_host_token, rpc_key,
};
use super::{LEARNER_FIELDS, RemoteError, Side, learner_tls, session_config, zerr};
use ess_actor::actor_seed;
use ess_actor::shm::weights_msg;
use ess_actor::{ActorError, EvalRunner, PolicyWeights, RolloutSource, split_steps};
use ess_proto::Chunk;
use ess_proto::config::RemoteConfig;
use ess_proto::shm::run_id_hash;
use std::sync::Arc;
use std::time::{Duration, Instant};
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::query::{ConsolidationMode, Reply};
use zenoh::sample::{Sample, SampleKind};

/// Longest a host may take to start its actors or answer one rollout. A lost host is
/// noticed sooner, by its token (`remote.timeout_s`).
const ANSWER_TIMEOUT: Duration = Duration::from_secs(600);
/// How long a joining host's request queryable may take to become reachable.
const JOIN_GRACE: Duration = Duration::from_secs(5);
/// How long the end of a run keeps asking a host to stop.
const STOP_GRACE: Duration = Duration::from_secs(3);
/// How often a wait for answers looks at the hosts' tokens.
const POLL: Duration = Duration::from_millis(100);

/// What the run tells its hosts, besides their seeds.
#[derive(Debug, Clone)]
pub struct RemoteSetup {
    /// `[remote]` of the run's config.
    pub remote: RemoteConfig,
    /// The run's seed (actor `i` seeds with `actor_seed(seed, i)`).
    pub run_seed: u64,
    /// Env, latent spec and limits; `first_actor` and `seeds` are filled per host.
    pub template: Assign,
}

struct Host {
    name: String,
    actors: usize,
    /// Global index of its first actor (stamped in its chunks; fixed at its join, while
    /// its place in the rollout's split moves up when a host before it is lost).
    first: usize,
}

/// Local actors plus remote hosts (see the module doc of [`super`]).
pub struct RemoteActors {
    local: Box<dyn RolloutSource>,
    hosts: Vec<Host>,
    /// Global index the next joining host's first actor gets.
    next_actor: usize,
    setup: RemoteSetup,
    request_id: u64,
    /// Token events seen while waiting for answers, handled at the next rollout.
    backlog: Vec<Sample>,
    joins: Subscriber<FifoChannelHandler<Sample>>,
    _token: LivelinessToken,
    session: zenoh::Session,
}

fn transport(what: String) -> ActorError {
    ActorError::Transport { what }
}

impl RemoteActors {
    /// Listens on `remote.listen`, waits up to `remote.wait_s` for the hosts it names,
    /// and starts their actors.
    pub fn start(local: Box<dyn RolloutSource>, setup: RemoteSetup) -> Result<Self, RemoteError> {
        let r = &setup.remote;
        let tls = learner_tls(r);
        let lease = Duration::from_secs_f64(r.timeout_s);
        let side = Side::Learner { listen: &r.listen };
        let cfg = session_config(side, &tls, LEARNER_FIELDS, lease)?;
        let session = zenoh::open(cfg)
            .wait()
            .map_err(zerr(format!("listening on {}", r.listen)))?;
        let joins = session
            .liveliness()
            .declare_subscriber(HOST_TOKENS)
            .history(true)
            .wait()
            .map_err(zerr("subscribing to host tokens"))?;
        let token = session
            .liveliness()
            .declare_token(LEARNER_TOKEN)
            .wait()
            .map_err(zerr("declaring the learner's token"))?;
        let mut me = Self {
            next_actor: local.n_actors(),
            local,
            hosts: Vec::new(),
            setup,
            request_id: 0,
            backlog: Vec::new(),
            joins,
            _token: token,
            session,
        };
        let announced = me.wait_for_named()?;
        for (name, n) in announced {
            me.assign(&name, n);
        }
        Ok(me)
    }

    /// The hosts announced within `remote.wait_s`: the named ones first, in their
    /// order, then the others in the order they came.
    fn wait_for_named(&mut self) -> Result<Vec<(String, usize)>, RemoteError> {
        let r = &self.setup.remote;
        let deadline = Instant::now() + Duration::from_secs_f64(r.wait_s);
        let mut seen: Vec<(String, usize)> = Vec::new();
        let all_named =
            |seen: &[(String, usize)]| r.hosts.iter().all(|h| seen.iter().any(|(n, _)| n == h));
        while !all_named(&seen) && Instant::now() < deadline {
            if let Some(s) = self.joins.recv_timeout(POLL).map_err(zerr("host tokens"))? {
                track(&mut seen, &s);
            }
        }
        while let Some(s) = self.joins.try_recv().map_err(zerr("host tokens"))? {
            track(&mut seen, &s);
        }
        for h in r
            .hosts
            .iter()
            .filter(|h| !seen.iter().any(|(n, _)| n == *h))
        {
            tracing::warn!(host = %h, wait_s = r.wait_s, "named host did not join in time; starting without it");
        }
        let rank = |n: &String| r.hosts.iter().position(|h| h == n).unwrap_or(usize::MAX);
        seen.sort_by_key(|(n, _)| rank(n));
        Ok(seen)
    }

    /// Gives host `name` the next `n` actor indices and has it start its actors; a host
    /// that refuses is left out with a warning.
    fn assign(&mut self, name: &str, n: usize) {
        if self.hosts.iter().any(|h| h.name == name) {
            return;
        }
        let first = self.next_actor;
        let asg = Assign {
            first_actor: first,
            seeds: (first..first + n)
                .map(|i| actor_seed(self.setup.run_seed, i))
                .collect(),
            ..self.setup.template.clone()
        };
        match self.ask_once(name, &Rpc::Assign(asg), ANSWER_TIMEOUT, JOIN_GRACE) {
            Ok(()) => {
                tracing::info!(host = %name, first, actors = n, "actor host joined");
                self.next_actor += n;
                self.hosts.push(Host {
                    name: name.to_owned(),
                    actors: n,
                    first,
                });
            }
            Err(e) => tracing::warn!(host = %name, error = %e, "actor host left out"),
        }
    }

    /// Sends `rpc` to `host` and waits for its one answer. A query that reaches no
    /// queryable ends at once without an answer: a host's token can arrive before its
    /// queryable's declaration has been routed (seen in a fresh-clone run), so that is
    /// retried for `grace`; an answer may take `timeout`.
    fn ask_once(
        &self,
        host: &str,
        rpc: &Rpc,
        timeout: Duration,
        grace: Duration,
    ) -> Result<(), RemoteError> {
        let bad = |why: String| RemoteError::Host {
            host: host.to_owned(),
            why,
        };
        let deadline = Instant::now() + grace;
        let reply = loop {
            match self.query(host, rpc, timeout)?.recv() {
                Ok(r) => break r,
                Err(_) if Instant::now() < deadline => std::thread::sleep(POLL),
                Err(_) => return Err(bad("no answer".into())),
            }
        };
        match reply.result() {
            Ok(_) => Ok(()),
            Err(e) => Err(bad(
                String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()
            )),
        }
    }

    fn query(
        &self,
        host: &str,
        rpc: &Rpc,
        timeout: Duration,
    ) -> Result<FifoChannelHandler<Reply>, RemoteError> {
        let bytes = rpc.encode().map_err(|e| RemoteError::Host {
            host: host.to_owned(),
            why: e.to_string(),
        })?;
        self.session
            .get(rpc_key(host))
            .payload(bytes)
            .consolidation(ConsolidationMode::None)
            .timeout(timeout)
            .wait()
            .map_err(zerr(format!("asking host {host}")))
    }

    /// Joins and leaves since the last rollout.
    fn handle_tokens(&mut self) -> Result<(), ActorError> {
        let mut events = std::mem::take(&mut self.backlog);
        while let Some(s) = self
            .joins
            .try_recv()
            .map_err(|e| transport(format!("host tokens: {e}")))?
        {
            events.push(s);
        }
        for s in events {
            let Some((name, n)) = parse_host_token(s.key_expr().as_str()) else {
                continue;
            };
            match s.kind() {
                SampleKind::Put => self.assign(&name, n),
                SampleKind::Delete => self.drop_host(&name, "its session ended"),
            }
        }
        Ok(())
    }

    fn drop_host(&mut self, name: &str, why: &str) {
        if let Some(i) = self.hosts.iter().position(|h| h.name == name) {
            self.hosts.remove(i);
            tracing::warn!(host = %name, "actor host lost ({why}); the other actors take its share");
        }
    }

    /// Every chunk of host `name`'s answer, its actor `first + j` (global index) in slot
    /// `j`, checked against `split` (its actors' shares); an error once the host's token
    /// goes or its answer fails.
    fn gather(
        &mut self,
        name: &str,
        rx: &FifoChannelHandler<Reply>,
        first: usize,
        split: &[usize],
        w: &PolicyWeights,
    ) -> Result<Vec<Chunk>, String> {
        let mut slots: Vec<Option<Chunk>> = vec![None; split.len()];
        let run_hash = run_id_hash(&self.setup.template.run);
        loop {
            let reply = match rx.recv_timeout(POLL) {
                Ok(Some(r)) => r,
                Ok(None) => {
                    self.watch_tokens(name)?;
                    continue;
                }
                Err(_) => break,
            };
            let sample = reply
                .result()
                .map_err(|e| String::from_utf8_lossy(&e.payload().to_bytes()).into_owned())?;
            let (h, chunk) =
                decode_chunk(&sample.payload().to_bytes()).map_err(|e| e.to_string())?;
            let j = (h.actor as usize).wrapping_sub(first);
            let fits = j < split.len()
                && h.run_id_hash == run_hash
                && h.request_id == self.request_id
                && h.policy_version == w.version
                && h.len as usize == split[j]
                && chunk.obs_dim == w.obs_mean.len()
                && chunk.n_codes == self.setup.template.n_codes;
            if !fits || slots[j].is_some() {
                return Err(format!(
                    "a chunk that does not answer this rollout (actor {})",
                    h.actor
                ));
            }
            slots[j] = Some(chunk);
        }
        let got = slots.iter().flatten().count();
        if got < slots.len() {
            return Err(format!(
                "its answer ended after {got} of {} chunks (link lost?)",
                slots.len()
            ));
        }
        Ok(slots.into_iter().flatten().collect())
    }

    /// One request: `split` (a share per actor: the local actors', then each host's in
    /// `hosts` order) asked of the hosts and collected locally. Returns the chunks and
    /// the steps of the hosts that failed (they are dropped).
    fn round(
        &mut self,
        weights: &Arc<PolicyWeights>,
        split: &[usize],
    ) -> Result<(Vec<Chunk>, usize), ActorError> {
        self.request_id += 1;
        let n_local = self.local.n_actors();
        let msg = weights_msg(
            weights,
            &self.setup.template.latent(),
            &self.setup.template.run,
        );
        let mut asked = Vec::new();
        let mut at = n_local;
        for h in &self.hosts {
            let share = &split[at..at + h.actors];
            at += h.actors;
            let steps = share.iter().sum::<usize>();
            if steps == 0 {
                continue;
            }
            let rpc = Rpc::Collect {
                steps: steps as u64,
                request_id: self.request_id,
                weights: msg.clone(),
            };
            let rx = self.query(&h.name, &rpc, ANSWER_TIMEOUT);
            asked.push((h.name.clone(), h.first, share.to_vec(), rx));
        }
        let local_steps = split[..n_local].iter().sum();
        let mut out = match local_steps {
            0 => Vec::new(),
            n => self.local.collect(weights.clone(), n)?,
        };
        let mut lost = 0;
        for (name, first, share, rx) in asked {
            let got = rx
                .map_err(|e| e.to_string())
                .and_then(|rx| self.gather(&name, &rx, first, &share, weights));
            match got {
                Ok(chunks) => out.extend(chunks),
                Err(why) => {
                    self.drop_host(&name, &why);
                    lost += share.iter().sum::<usize>();
                }
            }
        }
        Ok((out, lost))
    }

    /// An error if `name`'s token went; other events wait in the backlog.
    fn watch_tokens(&mut self, name: &str) -> Result<(), String> {
        while let Ok(Some(s)) = self.joins.try_recv() {
            let gone = s.kind() == SampleKind::Delete
                && parse_host_token(s.key_expr().as_str()).is_some_and(|(n, _)| n == name);
            self.backlog.push(s);
            if gone {
                return Err("its session ended (lease expired or link cut)".into());
            }
        }
        Ok(())
    }
}

/// Adds or removes the host a token event names.
fn track(seen: &mut Vec<(String, usize)>, s: &Sample) {
    let Some((name, n)) = parse_host_token(s.key_expr().as_str()) else {
        return;
    };
    seen.retain(|(h, _)| *h != name);
    if s.kind() == SampleKind::Put {
        seen.push((name, n));
    }
}

impl RolloutSource for RemoteActors {
    fn n_actors(&self) -> usize {
        self.local.n_actors() + self.hosts.iter().map(|h| h.actors).sum::<usize>()
    }

    /// The rollout split over every actor as [`split_steps`] splits it locally; the
    /// share of a host lost during it is split again over the local actors and the
    /// hosts that answered, until every step is collected.
    fn collect(
        &mut self,
        weights: Arc<PolicyWeights>,
        steps: usize,
    ) -> Result<Vec<Chunk>, ActorError> {
        self.handle_tokens()?;
        let split = split_steps(steps, self.n_actors());
        let (mut out, mut lost) = self.round(&weights, &split)?;
        while lost > 0 {
            tracing::warn!(
                steps = lost,
                hosts = self.hosts.len(),
                "collecting a lost host's share on the remaining actors"
            );
            let split = split_steps(lost, self.n_actors());
            let (more, again) = self.round(&weights, &split)?;
            out.extend(more);
            lost = again;
        }
        Ok(out)
    }

    fn evaluator(&mut self) -> Option<&mut dyn EvalRunner> {
        self.local.evaluator()
    }

    /// The local actors' states while no host takes part (hosts' episodes are not
    /// carried: see the module doc).
    fn snapshot(&mut self) -> Result<Option<Vec<ess_actor::WorkerState>>, ActorError> {
        if self.hosts.is_empty() {
            self.local.snapshot()
        } else {
            Ok(None)
        }
    }

    fn restore(&mut self, states: &[ess_actor::WorkerState]) -> Result<(), ActorError> {
        self.local.restore(states)
    }
}

impl Drop for RemoteActors {
    /// Ends the run on every host (they stop their actors and exit).
    fn drop(&mut self) {
        for h in &self.hosts {
            if let Err(e) = self.ask_once(&h.name, &Rpc::Stop, STOP_GRACE, STOP_GRACE) {
                tracing::warn!(host = %h.name, error = %e, "the host did not confirm STOP");
            }
        }
    }
}
