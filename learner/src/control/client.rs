//! The client side of the control plane (`ess job ...`): connecting with a bearer token,
//! and rendering jobs, events and metrics for people (one line each) and for tools
//! (JSON objects with the proto's field names).

use ess_proto::pb;
use ess_proto::pb::job_service_client::JobServiceClient;
use serde_json::{Value, json};
use std::path::Path;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;

/// Adds `authorization: Bearer <token>` to every call, when there is a token.
#[derive(Clone)]
pub struct BearerToken {
    header: Option<tonic::metadata::MetadataValue<tonic::metadata::Ascii>>,
}

impl tonic::service::Interceptor for BearerToken {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(h) = &self.header {
            req.metadata_mut().insert("authorization", h.clone());
        }
        Ok(req)
    }
}

/// A JobService client that sends the token.
pub type Client = JobServiceClient<InterceptedService<Channel, BearerToken>>;

/// A token file that cannot serve as one.
#[derive(Debug, thiserror::Error)]
pub enum TokenFileError {
    /// Unreadable.
    #[error("cannot read token file {}: {source}", path.display())]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Whitespace only.
    #[error("token file {} is empty", path.display())]
    Empty {
        /// The file.
        path: std::path::PathBuf,
    },
    /// Characters an HTTP header cannot carry.
    #[error("token file {}: the token must be printable ASCII without spaces", path.display())]
    NotPrintable {
        /// The file.
        path: std::path::PathBuf,
    },
}

/// Reads a token file: its content with surrounding whitespace trimmed. An unreadable
/// or empty file, or one holding characters a header cannot carry, is an error naming
/// the file.
pub fn read_token_file(path: &Path) -> Result<String, TokenFileError> {
    let path_buf = || path.to_path_buf();
    let text = std::fs::read_to_string(path).map_err(|source| TokenFileError::Read {
        path: path_buf(),
        source,
    })?;
    let token = text.trim();
    if token.is_empty() {
        return Err(TokenFileError::Empty { path: path_buf() });
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(TokenFileError::NotPrintable { path: path_buf() });
    }
    Ok(token.to_string())
}

/// Connects to `url` (`http://HOST:PORT`, or `https://HOST:PORT` with `tls`), sending
/// `token` with every call. TLS settings with an `http://` URL, or an `https://` URL
/// without them, are refused before connecting.
pub async fn connect(
    url: &str,
    token: Option<&str>,
    tls: Option<tonic::transport::ClientTlsConfig>,
) -> anyhow::Result<Client> {
    use anyhow::Context;
    let header = token
        .map(|t| format!("Bearer {t}").parse())
        .transpose()
        .context("the token is not a valid header value")?;
    let mut endpoint = tonic::transport::Endpoint::from_shared(url.to_string())
        .with_context(|| format!("bad server URL `{url}`"))?;
    let https = endpoint.uri().scheme_str() == Some("https");
    match (https, tls) {
        (true, Some(tls)) => {
            endpoint = endpoint
                .tls_config(tls)
                .with_context(|| format!("TLS settings for {url}"))?;
        }
        (true, None) => anyhow::bail!("{url}: an https:// server needs TLS settings"),
        (false, Some(_)) => anyhow::bail!("{url}: TLS settings need an https:// URL"),
        (false, None) => {}
    }
    let channel = endpoint
        .connect()
        .await
        .map_err(|e| anyhow::anyhow!("cannot connect to {url}: {}", error_chain(&e)))?;
    Ok(JobServiceClient::with_interceptor(
        channel,
        BearerToken { header },
    ))
}

/// An error and its causes on one line (a failed TLS handshake's reason sits three
/// levels under tonic's "transport error").
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut parts = vec![e.to_string()];
    let mut cur = e.source();
    while let Some(c) = cur {
        let s = c.to_string();
        if !parts.iter().any(|p| p.contains(&s)) {
            parts.push(s);
        }
        cur = c.source();
    }
    parts.join(": ")
}

/// A state's short name (`RUNNING`).
pub fn state_name(state: i32) -> &'static str {
    match pb::JobState::try_from(state) {
        Ok(pb::JobState::Queued) => "QUEUED",
        Ok(pb::JobState::Running) => "RUNNING",
        Ok(pb::JobState::Stopping) => "STOPPING",
        Ok(pb::JobState::Stopped) => "STOPPED",
        Ok(pb::JobState::Succeeded) => "SUCCEEDED",
        Ok(pb::JobState::Failed) => "FAILED",
        _ => "UNSPECIFIED",
    }
}

/// `preset env seed` of a spec, with defaults spelled out.
fn spec_brief(spec: Option<&pb::JobSpec>) -> String {
    let s = spec.cloned().unwrap_or_default();
    let preset = if s.preset.is_empty() {
        "ess-infogail".to_string()
    } else {
        s.preset
    };
    let mut out = preset;
    if !s.env.is_empty() {
        out.push(' ');
        out.push_str(&s.env);
    }
    if let Some(seed) = s.seed {
        out.push_str(&format!(" seed {seed}"));
    }
    if !s.overrides.is_empty() {
        out.push_str(&format!(" +{} overrides", s.overrides.len()));
    }
    out
}

/// One line per job (`ess job list`).
pub fn job_line(j: &pb::Job) -> String {
    let mut line = format!(
        "{:<10} {:<9} {:>5}/{:<5} it {:>9} steps  {}",
        j.id,
        state_name(j.state),
        j.iteration,
        j.iterations,
        j.env_steps,
        spec_brief(j.spec.as_ref())
    );
    if let Some(r) = &j.result {
        line.push_str(&format!(
            "  NMI {:.3} ENT {:.3} norm.reward {:.2}",
            r.nmi, r.ent, r.normalized_reward
        ));
    }
    if !j.error.is_empty() {
        line.push_str(&format!("  error: {}", j.error));
    }
    line
}

/// A job in full (`ess job get`, `submit`, `stop`, `resume`).
pub fn job_detail(j: &pb::Job) -> String {
    let mut out = format!(
        "id          {}\nstate       {}{}\nspec        {}\nprogress    {}/{} iterations, {} env steps\ncores       {}\nrun dir     {}\nresumes     {}\n",
        j.id,
        state_name(j.state),
        if j.phase.is_empty() {
            String::new()
        } else {
            format!(" ({})", j.phase)
        },
        spec_brief(j.spec.as_ref()),
        j.iteration,
        j.iterations,
        j.env_steps,
        j.cores,
        j.run_dir,
        j.resumes
    );
    if let Some(r) = &j.result {
        out.push_str(&format!(
            "result      NMI {:.3}  ENT {:.3}  normalized reward {:.3}  ({} env steps, {:.1} s)\n",
            r.nmi, r.ent, r.normalized_reward, r.env_steps, r.wall_seconds
        ));
    }
    if !j.error.is_empty() {
        out.push_str(&format!("error       {}\n", j.error));
    }
    out
}

/// One line per iteration (`ess job watch`).
pub fn iteration_line(m: &pb::IterationMetrics, iterations: u32) -> String {
    let mut line = format!(
        "iter {:>4}/{}  {:>8} steps  {:6.1}s  D(exp) {:.2} D(pol) {:.2}  reward {:+.3}",
        m.iteration,
        iterations,
        m.env_steps,
        m.wall_s,
        m.d_acc_expert,
        m.d_acc_policy,
        m.reward_mean
    );
    if let (Some(n), Some(e), Some(r)) = (m.nmi, m.ent, m.normalized_reward) {
        line.push_str(&format!("  NMI {n:.3} ENT {e:.3} norm.reward {r:.2}"));
    }
    line
}

/// A job as JSON (proto field names; the state as its name).
pub fn job_json(j: &pb::Job) -> Value {
    let spec = j.spec.clone().unwrap_or_default();
    json!({
        "id": j.id,
        "state": state_name(j.state),
        "phase": j.phase,
        "spec": {
            "preset": spec.preset,
            "env": spec.env,
            "seed": spec.seed,
            "overrides": spec.overrides.iter().map(|o| json!({"key": o.key, "value": o.value})).collect::<Vec<_>>(),
            "config_toml": spec.config_toml,
        },
        "iteration": j.iteration,
        "iterations": j.iterations,
        "env_steps": j.env_steps,
        "cores": j.cores,
        "run_dir": j.run_dir,
        "created_unix_ms": j.created_unix_ms,
        "started_unix_ms": j.started_unix_ms,
        "finished_unix_ms": j.finished_unix_ms,
        "error": j.error,
        "result": j.result.as_ref().map(|r| json!({
            "nmi": r.nmi,
            "ent": r.ent,
            "normalized_reward": r.normalized_reward,
            "env_steps": r.env_steps,
            "wall_seconds": r.wall_seconds,
        })),
        "resumes": j.resumes,
    })
}

/// Iteration metrics as JSON (the fields of `ess.v1.IterationMetrics`).
pub fn metrics_json(m: &pb::IterationMetrics) -> Value {
    json!({
        "iteration": m.iteration,
        "env_steps": m.env_steps,
        "wall_s": m.wall_s,
        "rollout_s": m.rollout_s,
        "disc_s": m.disc_s,
        "ppo_s": m.ppo_s,
        "disc_bce": m.disc_bce,
        "d_acc_expert": m.d_acc_expert,
        "d_acc_policy": m.d_acc_policy,
        "qc_labeled": m.qc_labeled,
        "qc_generated": m.qc_generated,
        "qeps": m.qeps,
        "rim_entropy": m.rim_entropy,
        "rim_kl": m.rim_kl,
        "contrastive": m.contrastive,
        "reward_mean": m.reward_mean,
        "policy_loss": m.policy_loss,
        "value_loss": m.value_loss,
        "entropy": m.entropy,
        "approx_kl": m.approx_kl,
        "prior": m.prior,
        "nmi": m.nmi,
        "ent": m.ent,
        "normalized_reward": m.normalized_reward,
    })
}

/// A watch event as JSON: `{"job": ..., "metrics": ...}` (metrics null for state
/// changes).
pub fn event_json(ev: &pb::JobEvent) -> Value {
    json!({
        "job": ev.job.as_ref().map(job_json),
        "metrics": ev.metrics.as_ref().map(metrics_json),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn token_files_must_hold_a_printable_token() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("tok");
        std::fs::write(&f, "  abc123\n").unwrap();
        assert_eq!(read_token_file(&f).unwrap(), "abc123");
        std::fs::write(&f, "\n \n").unwrap();
        assert!(
            read_token_file(&f)
                .unwrap_err()
                .to_string()
                .contains("is empty")
        );
        std::fs::write(&f, "two words").unwrap();
        assert!(
            read_token_file(&f)
                .unwrap_err()
                .to_string()
                .contains("printable")
        );
        let e = read_token_file(&dir.path().join("nope"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("cannot read token file") && e.contains("nope"),
            "{e}"
        );
    }

    #[test]
    fn job_renderings_name_state_and_result() {
        let j = pb::Job {
            id: "job-3".into(),
            state: pb::JobState::Succeeded.into(),
            iteration: 2,
            iterations: 2,
            result: Some(pb::JobResult {
                nmi: 0.5,
                ..Default::default()
            }),
            ..Default::default()
        };
        let line = job_line(&j);
        assert!(
            line.starts_with("job-3") && line.contains("SUCCEEDED") && line.contains("NMI 0.500"),
            "{line}"
        );
        let v = job_json(&j);
        assert_eq!(v["state"], "SUCCEEDED");
        assert_eq!(v["result"]["nmi"], 0.5);
        assert_eq!(v["spec"]["preset"], "");
    }
}
