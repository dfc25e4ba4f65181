//! `ess actor-host`: this machine's actor processes for learners on other machines, one
//! run after another (`ess_learner::remote`).

use super::{ctrl_c_flag, input_err};
use anyhow::Result;
use clap::Args;
use ess_learner::remote::{HostArgs, RemoteError, run_host};
use ess_proto::config::{is_tls_endpoint, valid_host_name};
use std::path::PathBuf;
use std::time::Duration;

#[derive(Args)]
pub struct ActorHostArgs {
    /// The learner's zenoh endpoint (its `remote.listen` as dialled from here), e.g.
    /// `tls/10.0.0.1:7447`.
    #[arg(long)]
    learner: String,
    /// This host's name, as the run's `remote.hosts` lists it (default: the hostname).
    #[arg(long)]
    name: Option<String>,
    /// Actor processes to run here (default: one per core).
    #[arg(long)]
    actors: Option<usize>,
    /// PEM: the CA that signed the learner's certificate and this host's.
    #[arg(long)]
    tls_ca: PathBuf,
    /// PEM: this host's certificate (signed by the run's CA).
    #[arg(long)]
    tls_cert: PathBuf,
    /// PEM: this host's private key.
    #[arg(long)]
    tls_key: PathBuf,
    /// Seconds to keep dialling the learner before giving up.
    #[arg(long, default_value_t = 60.0)]
    connect_s: f64,
    /// Seconds of silence after which the learner counts as lost.
    #[arg(long, default_value_t = 5.0)]
    timeout_s: f64,
    /// Serve one run and exit (0 when the run ended, 1 when the learner was lost),
    /// instead of waiting for the next run until Ctrl-C (e.g. a batch job's step).
    #[arg(long)]
    once: bool,
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_owned())
        .unwrap_or_default()
}

fn seconds(flag: &str, v: f64) -> Result<Duration> {
    if v.is_finite() && (0.5..=86400.0).contains(&v) {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(input_err(format!("{flag} {v}: must be in 0.5..=86400")))
    }
}

pub fn actor_host(a: ActorHostArgs) -> Result<()> {
    let name = a.name.unwrap_or_else(hostname);
    if !valid_host_name(&name) {
        return Err(input_err(format!(
            "--name `{}`: a host name is 1-64 of A-Z a-z 0-9 - _ .",
            ess_proto::text::printable(&name)
        )));
    }
    let actors = a.actors.unwrap_or_else(ess_proto::config::default_actors);
    if !(1..=256).contains(&actors) {
        return Err(input_err(format!("--actors {actors}: must be in 1..=256")));
    }
    if !is_tls_endpoint(&a.learner) {
        return Err(input_err(format!(
            "--learner `{}`: must be a zenoh TLS endpoint, tls/ADDR:PORT",
            ess_proto::text::printable(&a.learner)
        )));
    }
    let args = HostArgs {
        learner: a.learner,
        name,
        actors,
        tls_ca: a.tls_ca,
        tls_cert: a.tls_cert,
        tls_key: a.tls_key,
        connect: seconds("--connect-s", a.connect_s)?,
        timeout: seconds("--timeout-s", a.timeout_s)?,
        once: a.once,
    };
    let stop = ctrl_c_flag()?;
    run_host(&args, &stop).map_err(|e| match e {
        RemoteError::TlsFile { .. } => input_err(e),
        e => e.into(),
    })
}
