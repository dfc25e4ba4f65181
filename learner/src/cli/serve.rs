//! `ess serve`: the gRPC job server.

use super::{input_err, shutdown_signal};
use anyhow::{Context, Result};
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct ServeArgs {
    /// Address to listen on (IP:PORT; port 0 picks a free one). The bound address is
    /// printed as the first line of stdout. A non-loopback address needs TLS
    /// (--tls-cert, --tls-key) and a way to authenticate clients (--token-file and/or
    /// --tls-client-ca).
    #[arg(long, default_value = ess_learner::control::serve::DEFAULT_LISTEN)]
    listen: String,
    /// File holding the bearer token every JobService call must carry
    /// (`authorization: Bearer <token>`). Without it, calls are not authenticated.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// PEM certificate (chain) of this server: serve over TLS (with --tls-key).
    #[arg(long)]
    tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long)]
    tls_key: Option<PathBuf>,
    /// PEM CA certificate(s): every client must present a certificate they signed
    /// (mutual TLS); others are refused at the handshake.
    #[arg(long)]
    tls_client_ca: Option<PathBuf>,
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
    /// Also serve the browser dashboard on this address (IP:PORT; port 0 picks one),
    /// printed as the second line of stdout: the jobs, their live curves, cancel,
    /// requeue and submit. Same token (a login sets a cookie) and TLS as gRPC.
    #[arg(long)]
    dashboard: Option<String>,
}

/// `--dashboard`'s listener, bound, with the server's TLS when it has TLS; the same
/// rule as `--listen` off loopback.
fn dashboard_listener(
    a: &ServeArgs,
    server_tls: Option<&ess_learner::control::tls::ServerTls>,
    token: bool,
) -> Result<Option<ess_learner::control::serve::DashboardListener>> {
    let Some(text) = &a.dashboard else {
        return Ok(None);
    };
    let addr: std::net::SocketAddr = text.parse().map_err(|e| {
        input_err(format!(
            "--dashboard `{text}`: expected IP:PORT (e.g. 127.0.0.1:8080): {e}"
        ))
    })?;
    let tls = server_tls
        .map(ess_learner::control::tls::ServerTls::https)
        .transpose()
        .map_err(input_err)?;
    if !addr.ip().is_loopback() && (tls.is_none() || !(token || a.tls_client_ca.is_some())) {
        return Err(input_err(format!(
            "--dashboard {addr} is reachable from other machines: give --tls-cert, --tls-key and --token-file (or --tls-client-ca)"
        )));
    }
    let listener = std::net::TcpListener::bind(addr)
        .with_context(|| format!("cannot listen on {addr} (--dashboard)"))?;
    Ok(Some(ess_learner::control::serve::DashboardListener {
        listener,
        tls,
    }))
}

/// The server's TLS settings, checked as tonic will use them (a key that does not match
/// its certificate is refused here, naming both files, not at the first handshake).
fn server_tls(a: &ServeArgs) -> Result<Option<ess_learner::control::tls::ServerTls>> {
    let tls = ess_learner::control::tls::server_config(
        a.tls_cert.as_deref(),
        a.tls_key.as_deref(),
        a.tls_client_ca.as_deref(),
    )
    .map_err(input_err)?;
    if let (Some(t), Some(cert), Some(key)) = (&tls, &a.tls_cert, &a.tls_key) {
        tonic::transport::Server::builder()
            .tls_config(t.grpc.clone())
            .map_err(|e| {
                input_err(format!(
                    "--tls-cert {} / --tls-key {}: {}",
                    cert.display(),
                    key.display(),
                    ess_learner::control::client::error_chain(&e)
                ))
            })?;
    }
    Ok(tls)
}

/// How clients are checked, for the start-up line.
fn auth_line(token: bool, tls: bool, client_ca: bool) -> String {
    let transport = if tls {
        "TLS"
    } else {
        "plain HTTP/2 (loopback only)"
    };
    let who = match (token, client_ca) {
        (true, true) => "client certificate and bearer token required",
        (false, true) => "client certificate required",
        (true, false) => "bearer token required",
        (false, false) => "no authentication",
    };
    format!("{transport}, {who}")
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
    let tls = server_tls(&a)?;
    if !addr.ip().is_loopback() {
        if tls.is_none() {
            return Err(input_err(format!(
                "--listen {addr} is reachable from other machines: give --tls-cert and --tls-key so that tokens and job data do not cross the network in plain text"
            )));
        }
        if token.is_none() && a.tls_client_ca.is_none() {
            return Err(input_err(format!(
                "--listen {addr} is reachable from other machines: give --token-file or --tls-client-ca so that only known clients control jobs"
            )));
        }
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
    let dashboard = dashboard_listener(&a, tls.as_ref(), token.is_some())?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {bound}")?;
        if let Some(d) = &dashboard {
            let scheme = if d.tls.is_some() { "https" } else { "http" };
            let at = d
                .listener
                .local_addr()
                .context("reading the dashboard's address")?;
            writeln!(out, "dashboard on {scheme}://{at}/")?;
        }
        out.flush()?;
    }
    eprintln!(
        "ess serve: {} cores for jobs, data in {}, {}",
        cores,
        a.data_dir.display(),
        auth_line(token.is_some(), tls.is_some(), a.tls_client_ca.is_some())
    );
    let cfg = ServeConfig {
        manager: ManagerConfig {
            data_dir: a.data_dir,
            cores,
            exe,
            stop_grace: std::time::Duration::from_secs_f64(a.stop_grace_s),
        },
        token,
        tls: tls.map(|t| t.grpc),
        dashboard,
    };
    ess_learner::control::serve::serve(listener, cfg, shutdown_signal()).await
}
