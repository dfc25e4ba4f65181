//! `ess job`: the job server's client (submit, list, get, watch, stop, resume).

use super::{ConfigArgs, input_err};
use anyhow::Result;
use clap::{Args, Subcommand};
use ess_learner::control::client;
use ess_proto::pb;
use std::path::PathBuf;

#[derive(Args)]
pub struct JobArgs {
    /// Server URL (default: $ESS_SERVER, else http://127.0.0.1:50551).
    #[arg(long, global = true)]
    server: Option<String>,
    /// File holding the server's bearer token (default: $ESS_TOKEN_FILE, if set).
    #[arg(long, global = true)]
    token_file: Option<PathBuf>,
    /// With an https:// server: PEM file of the CA that signed the server's certificate
    /// (default: $ESS_TLS_CA, else the system's trusted roots).
    #[arg(long, global = true)]
    tls_ca: Option<PathBuf>,
    /// PEM certificate (chain) this client presents, for a server that asks for one
    /// (`ess serve --tls-client-ca`); default: $ESS_TLS_CERT. Needs --tls-key.
    #[arg(long, global = true)]
    tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert (default: $ESS_TLS_KEY).
    #[arg(long, global = true)]
    tls_key: Option<PathBuf>,
    /// Print JSON (one object per line for `watch`) instead of text.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    cmd: JobCmd,
}

#[derive(Subcommand)]
pub enum JobCmd {
    /// Validate and queue a job (the config flags of `ess train`).
    Submit {
        #[command(flatten)]
        config: ConfigArgs,
        /// Then watch it until it ends.
        #[arg(long)]
        watch: bool,
    },
    /// List jobs (oldest first).
    List {
        /// Only jobs in this state (repeatable): queued, running, stopping, stopped,
        /// succeeded, failed.
        #[arg(long)]
        state: Vec<String>,
    },
    /// Show one job.
    Get {
        /// Job id.
        id: String,
    },
    /// Print a job's iterations as they finish, then its result; exits 1 if it failed.
    Watch {
        /// Job id.
        id: String,
    },
    /// Stop a job gracefully (it checkpoints and ends STOPPED).
    Stop {
        /// Job id.
        id: String,
    },
    /// Continue a STOPPED or FAILED job from its last checkpoint.
    Resume {
        /// Job id.
        id: String,
        /// Then watch it until it ends.
        #[arg(long)]
        watch: bool,
    },
}

/// A failed call as an error: the caller's fault (exit 2) or the server's (exit 1).
pub fn status_err(s: tonic::Status) -> anyhow::Error {
    use tonic::Code;
    let mut msg = format!("{:?}: {}", s.code(), s.message());
    // A transport failure's reason (a refused client certificate, say) is in its causes.
    if let Some(cause) = std::error::Error::source(&s) {
        let chain = client::error_chain(cause);
        if chain.starts_with(s.message()) {
            msg = format!("{:?}: {chain}", s.code());
        } else if !msg.contains(&chain) {
            msg = format!("{msg}: {chain}");
        }
    }
    match s.code() {
        Code::InvalidArgument
        | Code::NotFound
        | Code::FailedPrecondition
        | Code::Unauthenticated
        | Code::PermissionDenied => input_err(msg),
        _ => anyhow::anyhow!(msg),
    }
}

pub fn parse_state(s: &str) -> Result<ess_proto::pb::JobState> {
    use ess_proto::pb::JobState;
    Ok(match s.to_ascii_lowercase().as_str() {
        "queued" => JobState::Queued,
        "running" => JobState::Running,
        "stopping" => JobState::Stopping,
        "stopped" => JobState::Stopped,
        "succeeded" => JobState::Succeeded,
        "failed" => JobState::Failed,
        _ => {
            return Err(input_err(format!(
                "--state `{s}`: expected queued, running, stopping, stopped, succeeded or failed"
            )));
        }
    })
}

/// An environment variable's value; an empty one counts as unset (`ESS_TOKEN_FILE=`
/// clears a default rather than naming the file "").
fn env_set(name: &str) -> Option<std::ffi::OsString> {
    std::env::var_os(name).filter(|v| !v.is_empty())
}

/// The client's TLS settings: only for an https:// server (an http:// one given TLS
/// files is an input error rather than a silent plain-text connection).
fn client_tls(a: &JobArgs, server: &str) -> Result<Option<tonic::transport::ClientTlsConfig>> {
    let pick = |flag: &Option<PathBuf>, var: &str| {
        flag.clone().or_else(|| env_set(var).map(PathBuf::from))
    };
    let ca = pick(&a.tls_ca, "ESS_TLS_CA");
    let cert = pick(&a.tls_cert, "ESS_TLS_CERT");
    let key = pick(&a.tls_key, "ESS_TLS_KEY");
    if !server.starts_with("https://") {
        if a.tls_ca.is_some() || a.tls_cert.is_some() || a.tls_key.is_some() {
            return Err(input_err(format!(
                "--tls-ca/--tls-cert/--tls-key need an https:// server, not `{server}`"
            )));
        }
        return Ok(None);
    }
    ess_learner::control::tls::client_config(ca.as_deref(), cert.as_deref(), key.as_deref())
        .map(Some)
        .map_err(input_err)
}

/// The server URL and bearer token the flags (or their environment variables) name.
fn server_and_token(a: &JobArgs) -> Result<(String, Option<String>)> {
    let server = a
        .server
        .clone()
        .or_else(|| env_set("ESS_SERVER").and_then(|v| v.into_string().ok()))
        .unwrap_or_else(|| format!("http://{}", ess_learner::control::serve::DEFAULT_LISTEN));
    let token_file = a
        .token_file
        .clone()
        .or_else(|| env_set("ESS_TOKEN_FILE").map(PathBuf::from));
    let token = token_file
        .as_deref()
        .map(client::read_token_file)
        .transpose()
        .map_err(input_err)?;
    Ok((server, token))
}

fn print_job(j: &pb::Job, json: bool) {
    if json {
        println!("{}", client::job_json(j));
    } else {
        print!("{}", client::job_detail(j));
    }
}

fn print_jobs(jobs: &[pb::Job], json: bool) {
    if json {
        let all = jobs.iter().map(client::job_json).collect();
        println!("{}", serde_json::Value::Array(all));
    } else if jobs.is_empty() {
        println!("no jobs");
    } else {
        for j in jobs {
            println!("{}", client::job_line(j));
        }
    }
}

pub async fn job(a: JobArgs) -> Result<()> {
    let (server, token) = server_and_token(&a)?;
    let json = a.json;
    // Validate local input before connecting.
    let spec = match &a.cmd {
        JobCmd::Submit { config, .. } => Some(job_spec(config)?),
        _ => None,
    };
    let tls = client_tls(&a, &server)?;
    let mut c = client::connect(&server, token.as_deref(), tls).await?;
    let watch_id = match a.cmd {
        JobCmd::Submit { watch, .. } => {
            let j = c
                .submit_job(pb::SubmitJobRequest { spec })
                .await
                .map_err(status_err)?
                .into_inner();
            if !watch || !json {
                print_job(&j, json);
            }
            watch.then_some(j.id)
        }
        JobCmd::List { state } => {
            let states = state
                .iter()
                .map(|s| parse_state(s).map(i32::from))
                .collect::<Result<Vec<_>>>()?;
            let jobs = c
                .list_jobs(pb::ListJobsRequest { states })
                .await
                .map_err(status_err)?
                .into_inner()
                .jobs;
            print_jobs(&jobs, json);
            None
        }
        JobCmd::Get { id } => {
            let j = c.get_job(pb::GetJobRequest { id }).await;
            print_job(&j.map_err(status_err)?.into_inner(), json);
            None
        }
        JobCmd::Stop { id } => {
            let j = c.stop_job(pb::StopJobRequest { id }).await;
            print_job(&j.map_err(status_err)?.into_inner(), json);
            None
        }
        JobCmd::Resume { id, watch } => {
            let j = c
                .resume_job(pb::ResumeJobRequest { id })
                .await
                .map_err(status_err)?
                .into_inner();
            if !watch || !json {
                print_job(&j, json);
            }
            watch.then_some(j.id)
        }
        JobCmd::Watch { id } => Some(id),
    };
    match watch_id {
        Some(id) => watch(&mut c, id, json).await,
        None => Ok(()),
    }
}

/// Follows job `id` to its end: a line per iteration and per state change (or the
/// events as JSON); the exit status is the job's (failed: an error).
async fn watch(c: &mut client::Client, id: String, json: bool) -> Result<()> {
    let mut stream = c
        .watch_job(pb::WatchJobRequest { id: id.clone() })
        .await
        .map_err(status_err)?
        .into_inner();
    let mut last: Option<pb::Job> = None;
    while let Some(ev) = stream.message().await.map_err(status_err)? {
        if json {
            println!("{}", client::event_json(&ev));
        } else if let Some(m) = &ev.metrics {
            let total = ev.job.as_ref().map_or(0, |j| j.iterations);
            println!("{}", client::iteration_line(m, total));
        } else if let Some(j) = &ev.job {
            let changed = last
                .as_ref()
                .is_none_or(|l| l.state != j.state || l.phase != j.phase);
            if changed {
                let phase = if j.phase.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", j.phase)
                };
                println!("{} {}{phase}", j.id, client::state_name(j.state));
            }
        }
        if let Some(j) = ev.job {
            last = Some(j);
        }
    }
    let Some(j) = last else {
        anyhow::bail!("the server ended the watch of {id} without an event");
    };
    if !json {
        print!("{}", client::job_detail(&j));
    }
    match pb::JobState::try_from(j.state) {
        Ok(pb::JobState::Failed) => Err(anyhow::anyhow!("job {} failed: {}", j.id, j.error)),
        Ok(pb::JobState::Stopped | pb::JobState::Succeeded) => Ok(()),
        _ => Err(anyhow::anyhow!(
            "the watch of {} ended while the job is {}",
            j.id,
            client::state_name(j.state)
        )),
    }
}

/// The job spec the config flags describe (the config file's contents travel).
pub fn job_spec(c: &ConfigArgs) -> Result<pb::JobSpec> {
    if c.preset.ends_with(".toml") || c.preset.contains('/') {
        return Err(input_err(format!(
            "--preset {}: a job takes a preset name (`ess presets`); pass a file with --config",
            c.preset
        )));
    }
    let config_toml = match &c.config {
        Some(f) => std::fs::read_to_string(f)
            .map_err(|e| input_err(format!("cannot read config file {}: {e}", f.display())))?,
        None => String::new(),
    };
    let overrides = c
        .set
        .iter()
        .map(|s| {
            s.split_once('=')
                .map(|(k, v)| pb::Override {
                    key: k.trim().to_string(),
                    value: v.trim().to_string(),
                })
                .ok_or_else(|| input_err(format!("--set `{s}`: expected KEY=VALUE")))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(pb::JobSpec {
        preset: c.preset.clone(),
        env: c.env.clone().unwrap_or_default(),
        seed: c.seed,
        overrides,
        config_toml,
    })
}
