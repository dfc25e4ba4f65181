//! `ess serve`: the gRPC job server.

use super::{input_err, shutdown_signal};
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct ServeArgs {
    /// Address to listen on (IP:PORT; port 0 picks a free one). The bound address is
    /// printed as the first line of stdout. A non-loopback address needs --token-file.
    #[arg(long, default_value = ess_learner::control::serve::DEFAULT_LISTEN)]
    listen: String,
    /// File holding the bearer token every JobService call must carry
    /// (`authorization: Bearer <token>`). Without it, calls are not authenticated.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Data directory: one `jobs/<id>/` per job (record, config, log, run outputs).
    #[arg(long, default_value = "ess-jobs")]
    data_dir: PathBuf,
    /// Cores running jobs may hold together (default: the machine's). A job holds
    /// max(run.actors, run.torch_threads, 1) of them; the rest queue.
    #[arg(long)]
    cores: Option<usize>,
    /// Seconds a shutting-down server waits for its stopped jobs before killing them.
    #[arg(long, default_value_t = 600.0)]
    stop_grace_s: f64,
}

pub async fn serve(a: ServeArgs) -> Result<()> {
    use ess_learner::control::jobs::ManagerConfig;
    use ess_learner::control::serve::ServeConfig;
    let addr: std::net::SocketAddr = a.listen.parse().map_err(|e| {
        input_err(format!(
            "--listen `{}`: expected IP:PORT (e.g. 127.0.0.1:50551): {e}",
            a.listen
        ))
    })?;
    let token = a
        .token_file
        .as_deref()
        .map(ess_learner::control::client::read_token_file)
        .transpose()
        .map_err(input_err)?;
    if !addr.ip().is_loopback() {
        if token.is_none() {
            return Err(input_err(format!(
                "--listen {addr} is reachable from other machines: give --token-file so that only token holders control jobs"
            )));
        }
        eprintln!(
            "ess serve: WARNING: listening on {addr} without TLS: the token and job data cross the network in plain text"
        );
    }
    let cores = match a.cores {
        Some(0) => return Err(input_err("--cores must be at least 1")),
        Some(n) => n,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    if !(a.stop_grace_s.is_finite() && a.stop_grace_s >= 0.0) {
        return Err(input_err(format!(
            "--stop-grace-s {} must be a number of seconds >= 0",
            a.stop_grace_s
        )));
    }
    let exe = std::env::current_exe().context("locating the ess binary to run jobs with")?;
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let bound = listener.local_addr().context("reading the bound address")?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {bound}")?;
        out.flush()?;
    }
    eprintln!(
        "ess serve: {} cores for jobs, data in {}, {}",
        cores,
        a.data_dir.display(),
        if token.is_some() {
            "bearer token required"
        } else {
            "no token (loopback only)"
        }
    );
    let cfg = ServeConfig {
        manager: ManagerConfig {
            data_dir: a.data_dir,
            cores,
            exe,
            stop_grace: std::time::Duration::from_secs_f64(a.stop_grace_s),
        },
        token,
    };
    ess_learner::control::serve::serve(listener, cfg, shutdown_signal()).await
}
