//! `ess actor-host`: one machine's actor processes serving learners elsewhere, one run
//! after another. The host dials the learner (mutual TLS), announces itself with a
//! liveliness token carrying its name and actor count, and answers the learner's
//! requests until the run ends (STOP) or the learner is lost (its token expires). Then
//! it stops that run's actors and dials again for the next run, until Ctrl-C; with
//! `once` it exits instead (0 after STOP, an error when the learner was lost). Its
//! actors are an [`ShmActors`] like the learner's own, so they are supervised the same
//! way.
//!
//! Only the first dial is held to `connect` (a wrong address or a certificate the
//! learner refuses is an error); between runs the host keeps dialling in short tries,
//! so it waits for the next learner as long as it runs. After STOP it first waits for
//! the ended learner to leave, so it does not join that one again.

use super::wire::{Assign, HOST_TOKENS, LEARNER_TOKEN, Rpc, encode_chunk, host_token, rpc_key};
use super::{RemoteError, Side, TlsFiles, session_config, zerr};
use crate::actors::{ShmActors, ShmActorsConfig, actor_binary, new_run_id};
use ess_actor::RolloutSource;
use ess_actor::shm::policy_from_msg;
use ess_proto::shm::ShmChunkHeader;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::query::Query;
use zenoh::sample::{Sample, SampleKind};

/// What `ess actor-host` was given.
#[derive(Debug, Clone)]
pub struct HostArgs {
    /// The learner's zenoh endpoint, `tls/ADDR:PORT`.
    pub learner: String,
    /// This host's name (the learner's `remote.hosts` names it).
    pub name: String,
    /// Actor processes to run here.
    pub actors: usize,
    /// CA, this host's certificate and key (PEM).
    pub tls_ca: PathBuf,
    /// This host's certificate.
    pub tls_cert: PathBuf,
    /// This host's key.
    pub tls_key: PathBuf,
    /// How long to keep dialling the learner before giving up.
    pub connect: Duration,
    /// Silence after which the learner counts as lost (zenoh's lease).
    pub timeout: Duration,
    /// Serve one run and exit, instead of waiting for the next.
    pub once: bool,
}

/// How long one wait for a request lasts before the host looks at the learner's token
/// and its stop flag again.
const POLL: Duration = Duration::from_millis(200);

/// How long one dial lasts while the host waits for the next run.
const REDIAL: Duration = Duration::from_secs(2);
/// Longest wait after STOP for the ended learner to leave.
const LEAVE_GRACE: Duration = Duration::from_secs(60);

/// How one run's session ended.
enum RunEnd {
    /// The learner sent STOP.
    Stopped,
    /// `stop` was set (Ctrl-C).
    Interrupted,
}

/// Serves runs until `stop` is set (or, with `once`, one run); see the module doc.
pub fn run_host(a: &HostArgs, stop: &AtomicBool) -> Result<(), RemoteError> {
    let mut session = dial(a, a.connect)?;
    loop {
        let end = serve_run(a, &session, stop);
        let _ = session.close().wait();
        match end {
            Ok(RunEnd::Interrupted) => return Ok(()),
            Ok(RunEnd::Stopped) if a.once => return Ok(()),
            Err(e) if a.once => return Err(e),
            Ok(RunEnd::Stopped) => {}
            Err(e) => {
                tracing::warn!(host = %a.name, "the run ended without STOP: {e}");
                std::thread::sleep(REDIAL);
            }
        }
        tracing::info!(host = %a.name, learner = %a.learner, "waiting for the next run");
        session = loop {
            if stop.load(Ordering::Relaxed) {
                return Ok(());
            }
            match dial(a, REDIAL) {
                Ok(s) => break s,
                // A dial that fails at once (a TLS file gone) must not spin.
                Err(_) => std::thread::sleep(POLL),
            }
        };
    }
}

/// A session with the learner at `a.learner`, dialled for at most `connect`.
fn dial(a: &HostArgs, connect: Duration) -> Result<zenoh::Session, RemoteError> {
    let tls = TlsFiles {
        ca: &a.tls_ca,
        cert: &a.tls_cert,
        key: &a.tls_key,
    };
    let side = Side::Host {
        learner: &a.learner,
        connect,
    };
    let fields = ["--tls-ca", "--tls-cert", "--tls-key"];
    let cfg = session_config(side, &tls, fields, a.timeout)?;
    zenoh::open(cfg).wait().map_err(zerr(format!(
        "reaching the learner at {} (nothing listens there, or the TLS handshake failed: \
         check that --tls-cert is signed by the run's CA)",
        a.learner
    )))
}

/// Serves the run of the learner `session` reached, until STOP, the learner's loss (an
/// error) or `stop`.
fn serve_run(
    a: &HostArgs,
    session: &zenoh::Session,
    stop: &AtomicBool,
) -> Result<RunEnd, RemoteError> {
    let learner = session
        .liveliness()
        .declare_subscriber(LEARNER_TOKEN)
        .history(true)
        .wait()
        .map_err(zerr("subscribing to the learner's token"))?;
    let rpc = session
        .declare_queryable(rpc_key(&a.name))
        .wait()
        .map_err(zerr("declaring the request queryable"))?;
    // Announced last, when requests can be answered.
    let token = session
        .liveliness()
        .declare_token(host_token(&a.name, a.actors))
        .wait()
        .map_err(zerr("declaring this host's token"))?;
    tracing::info!(learner = %a.learner, name = %a.name, actors = a.actors, tokens = HOST_TOKENS, "actor host connected");
    let mut served: Option<(ShmActors, Assign)> = None;
    while !stop.load(Ordering::Relaxed) {
        while let Some(s) = learner.try_recv().map_err(zerr("learner token"))? {
            if s.kind() == SampleKind::Delete {
                return Err(RemoteError::Host {
                    host: a.name.clone(),
                    why: "the learner was lost (its session ended without STOP)".into(),
                });
            }
        }
        let Some(q) = rpc
            .recv_timeout(POLL)
            .map_err(zerr("receiving a request"))?
        else {
            continue;
        };
        if !answer(a, &q, &mut served)? {
            // Gone from the ended run's hosts; a host that serves the next run first
            // waits for this run's learner to leave.
            drop((token, rpc));
            if !a.once {
                wait_for_leave(&learner, stop);
            }
            return Ok(RunEnd::Stopped);
        }
    }
    Ok(RunEnd::Interrupted)
}

/// Waits (at most [`LEAVE_GRACE`]) until the learner's token goes.
fn wait_for_leave(learner: &Subscriber<FifoChannelHandler<Sample>>, stop: &AtomicBool) {
    let deadline = std::time::Instant::now() + LEAVE_GRACE;
    while std::time::Instant::now() < deadline && !stop.load(Ordering::Relaxed) {
        match learner.recv_timeout(POLL) {
            Ok(Some(s)) if s.kind() == SampleKind::Delete => return,
            Ok(_) => {}
            Err(_) => return,
        }
    }
}

/// Answers one request; false once the run is over.
fn answer(
    a: &HostArgs,
    q: &Query,
    served: &mut Option<(ShmActors, Assign)>,
) -> Result<bool, RemoteError> {
    let bytes = q.payload().map(|p| p.to_bytes()).unwrap_or_default();
    let fail = |why: String| -> Result<bool, RemoteError> {
        tracing::warn!(host = %a.name, "refusing a request: {why}");
        q.reply_err(why.clone()).wait().map_err(zerr("replying"))?;
        Err(RemoteError::Host {
            host: a.name.clone(),
            why,
        })
    };
    match Rpc::decode(&bytes) {
        Err(e) => fail(e.to_string()),
        Ok(Rpc::Stop) => {
            *served = None;
            reply(q, b"stopped".to_vec())?;
            tracing::info!(host = %a.name, "the run ended");
            Ok(false)
        }
        Ok(Rpc::Assign(asg)) => match start_actors(a, &asg) {
            Ok(actors) => {
                tracing::info!(
                    run = %asg.run,
                    first = asg.first_actor,
                    actors = asg.seeds.len(),
                    "actor processes started for the run"
                );
                *served = Some((actors, asg));
                reply(q, b"ready".to_vec())?;
                Ok(true)
            }
            Err(why) => fail(why),
        },
        Ok(Rpc::Collect {
            steps,
            request_id,
            weights,
        }) => {
            let Some((actors, asg)) = served.as_mut() else {
                return fail("COLLECT before ASSIGN".into());
            };
            let hash = weights.run_id_hash;
            let (w, _) = match policy_from_msg(weights) {
                Ok(x) => x,
                Err(e) => return fail(e.to_string()),
            };
            let version = w.version;
            let chunks = match actors.collect(Arc::new(w), steps as usize) {
                Ok(c) => c,
                Err(e) => return fail(format!("collecting: {e}")),
            };
            for (j, c) in chunks.iter().enumerate() {
                let h = ShmChunkHeader {
                    run_id_hash: hash,
                    actor: (asg.first_actor + j) as u32,
                    request_id,
                    policy_version: version,
                    ..Default::default()
                };
                match encode_chunk(c, h) {
                    Ok(b) => reply(q, b)?,
                    Err(e) => return fail(e.to_string()),
                }
            }
            Ok(true)
        }
    }
}

fn reply(q: &Query, bytes: Vec<u8>) -> Result<(), RemoteError> {
    q.reply(q.key_expr().clone(), bytes)
        .wait()
        .map_err(zerr("replying"))
}

/// This host's actor processes for `asg`.
fn start_actors(a: &HostArgs, asg: &Assign) -> Result<ShmActors, String> {
    if asg.seeds.len() != a.actors {
        return Err(format!(
            "assigned {} actors, this host runs {}",
            asg.seeds.len(),
            a.actors
        ));
    }
    ShmActors::new(ShmActorsConfig {
        run_id: new_run_id(),
        binary: actor_binary().map_err(|e| e.to_string())?,
        env: asg.env.clone(),
        n_modes: asg.n_modes,
        latent: asg.latent(),
        seeds: asg.seeds.clone(),
        max_steps: asg.max_steps,
        heartbeat_timeout: Duration::from_secs_f64(asg.actor_timeout_s),
        startup_timeout: Duration::from_secs(30),
        plain_env: asg.plain_env,
        task_mode: None,
    })
    .map_err(|e| e.to_string())
}
