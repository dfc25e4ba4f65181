//! Actor hosts on other machines (`ess actor-host`), feeding one run over zenoh.
//!
//! **Shape.** A host runs its actor processes exactly as the learner runs local ones:
//! an [`crate::actors::ShmActors`] over iceoryx2 shared memory, with its heartbeats,
//! restarts and re-asks. Between the learner and a host only whole requests travel, over
//! zenoh: the host's liveliness token `ess/hosts/<name>/actors/<n>` (joins, and leaves
//! when its session's lease runs out), and a queryable `ess/hosts/<name>/rpc` answering
//! ASSIGN (start actors with these seeds), COLLECT (weights in, one chunk per actor
//! out, in the shared-memory byte layouts of [`ess_proto::shm`]) and STOP.
//! On the learner, [`RemoteActors`] wraps the run's local [`RolloutSource`] behind the
//! same seam: actor indices run over local actors first, then the hosts named in
//! `remote.hosts` in that order, then hosts that joined later; every actor gets the seed
//! of its global index and the rollout is split over all of them as
//! [`ess_actor::split_steps`] splits it locally, so a run with hosts collects the same
//! chunks as the same number of actors on one machine. A host that is lost (its token
//! expires, its answer fails) is dropped with a warning and its share is split again over
//! the local actors and the hosts that answered; a host may join at any rollout.
//!
//! **Why zenoh directly, not iceoryx2's zenoh tunnel.** The tunnel is not published for
//! iceoryx2 0.10 (the last one, `iceoryx2-services-tunnel` 0.9.3, cannot open 0.10's
//! shared memory: iceoryx2 refuses other versions); it forwards every service of a
//! machine (no filter), carries publish-subscribe and events only, and copies samples
//! one by one with a 10-sample buffer: our chunks, heartbeats and wake-up events would
//! each cross the network, with the per-actor protocol's timing tuned for shared memory.
//! One request per host and rollout is fewer, larger messages, and keeps the shared-
//! memory protocol where it is fast.
//!
//! **Credentials.** Links are TLS only, mutual: the learner listens on `remote.listen`
//! (`tls/ADDR:PORT`) with `remote.tls_cert`/`tls_key`, and accepts only hosts presenting
//! a certificate signed by `remote.tls_ca`; hosts check the learner's certificate
//! against the same CA and the dialled address. Multicast scouting is off: nothing is
//! discovered on the network, hosts dial the configured endpoint only (they are zenoh
//! clients, which take no part in gossip).
//!
//! **Limits.** Evaluation episodes run on the local actors. A checkpoint of a run with
//! hosts keeps no actor states (hosts' episodes are not carried), so its resume starts
//! fresh episodes instead of being bit-identical. Chunks are copied into zenoh's buffers
//! (not zero-copy across hosts); a host's whole answer crosses the network once per
//! rollout.

mod host;
mod learner;
mod wire;

pub use host::{HostArgs, run_host};
pub use learner::{RemoteActors, RemoteSetup};
pub use wire::Assign;

use std::path::Path;
use std::time::Duration;

/// Errors of the remote transport.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    /// A TLS file that does not exist or cannot be read.
    #[error("{field} {}: {why}", path.display())]
    TlsFile {
        /// The setting or flag that named it.
        field: &'static str,
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        why: String,
    },
    /// A zenoh call failed.
    #[error("zenoh: {what}: {why}")]
    Zenoh {
        /// What was attempted.
        what: String,
        /// zenoh's error.
        why: String,
    },
    /// A host answered with something else than asked.
    #[error("host {host}: {why}")]
    Host {
        /// The host.
        host: String,
        /// Why.
        why: String,
    },
}

/// A zenoh error as [`RemoteError::Zenoh`], for `map_err`.
pub(crate) fn zerr<E: std::fmt::Display>(what: impl Into<String>) -> impl FnOnce(E) -> RemoteError {
    let what = what.into();
    move |e| RemoteError::Zenoh {
        what,
        why: e.to_string(),
    }
}

/// The three PEM files of one side of a mutual TLS link.
#[derive(Debug, Clone)]
pub struct TlsFiles<'a> {
    /// CA that signed both sides.
    pub ca: &'a Path,
    /// This side's certificate.
    pub cert: &'a Path,
    /// This side's key.
    pub key: &'a Path,
}

impl TlsFiles<'_> {
    /// Checks that each file is readable PEM, so a wrong path is one line naming it
    /// (zenoh would fail later, at the first handshake, without the path).
    fn check(&self, fields: [&'static str; 3]) -> Result<(), RemoteError> {
        for (field, path) in fields.into_iter().zip([self.ca, self.cert, self.key]) {
            let text = std::fs::read(path).map_err(|e| RemoteError::TlsFile {
                field,
                path: path.to_path_buf(),
                why: format!("cannot read it: {e}"),
            })?;
            if !text.windows(11).any(|w| w == b"-----BEGIN ") {
                return Err(RemoteError::TlsFile {
                    field,
                    path: path.to_path_buf(),
                    why: "not PEM (no -----BEGIN line)".into(),
                });
            }
        }
        Ok(())
    }
}

/// The learner's TLS files of `[remote]` (when it is on), read and checked, so a wrong
/// path is refused before the run prepares its data.
pub fn check_files(r: &ess_proto::config::RemoteConfig) -> Result<(), RemoteError> {
    if !r.enabled() {
        return Ok(());
    }
    learner_tls(r).check(LEARNER_FIELDS)
}

/// The learner's side of the link, from `[remote]`.
fn learner_tls(r: &ess_proto::config::RemoteConfig) -> TlsFiles<'_> {
    TlsFiles {
        ca: Path::new(&r.tls_ca),
        cert: Path::new(&r.tls_cert),
        key: Path::new(&r.tls_key),
    }
}

/// The learner's TLS settings, as errors name them.
const LEARNER_FIELDS: [&str; 3] = ["remote.tls_ca", "remote.tls_cert", "remote.tls_key"];

/// Which end of the link a session is.
enum Side<'a> {
    /// The learner: a peer listening on the endpoint.
    Learner { listen: &'a str },
    /// A host: a client dialling the learner for at most `connect` before giving up.
    Host { learner: &'a str, connect: Duration },
}

/// A zenoh session config: mutual TLS with `tls`, no multicast scouting, `lease` as the time after
/// which a silent peer's session (and its liveliness tokens) ends.
fn session_config(
    side: Side<'_>,
    tls: &TlsFiles<'_>,
    fields: [&'static str; 3],
    lease: Duration,
) -> Result<zenoh::Config, RemoteError> {
    tls.check(fields)?;
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let (mode, endpoints) = match &side {
        Side::Learner { listen } => (
            "peer",
            serde_json::json!({"listen": {"endpoints": [listen]}}),
        ),
        Side::Host { learner, connect } => (
            "client",
            serde_json::json!({"connect": {
                "endpoints": [learner],
                "timeout_ms": connect.as_millis() as i64,
                "exit_on_failure": true,
            }}),
        ),
    };
    let side_keys = match side {
        Side::Learner { .. } => ("listen_certificate", "listen_private_key"),
        Side::Host { .. } => ("connect_certificate", "connect_private_key"),
    };
    let mut tls_conf = serde_json::json!({
        "root_ca_certificate": abs(tls.ca),
        "enable_mtls": true,
    });
    tls_conf[side_keys.0] = serde_json::json!(abs(tls.cert));
    tls_conf[side_keys.1] = serde_json::json!(abs(tls.key));
    let mut conf = serde_json::json!({
        "mode": mode,
        "scouting": {"multicast": {"enabled": false}},
        "transport": {"link": {
            "tls": tls_conf,
            "tx": {"lease": lease.as_millis().max(500) as u64},
        }},
    });
    if let (Some(c), Some(e)) = (conf.as_object_mut(), endpoints.as_object()) {
        c.extend(e.clone());
    }
    zenoh::Config::from_json5(&conf.to_string()).map_err(zerr("config"))
}
