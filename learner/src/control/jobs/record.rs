//! A job's persisted record (`job.json`), its states, and the manager's errors.

use crate::progress::FinalRecord;
use ess_proto::pb;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What can go wrong serving a request; one `From<Error> for tonic::Status`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The request is malformed; `field` names the offending field (`spec.preset`,
    /// `spec.overrides[2].key`, ...).
    #[error("{field}: {}", ess_proto::text::printable(message))]
    InvalidArgument {
        /// Path of the field in the request.
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// No job with this id.
    #[error("no job `{}`", ess_proto::text::printable(id))]
    NotFound {
        /// The id asked for.
        id: String,
    },
    /// The job is in a state that does not allow the action.
    #[error(
        "job `{}` is {state}: cannot {action} it",
        ess_proto::text::printable(id)
    )]
    FailedPrecondition {
        /// The job.
        id: String,
        /// Its state.
        state: &'static str,
        /// What was asked.
        action: &'static str,
    },
    /// The server is shutting down and takes no new work.
    #[error("the server is shutting down")]
    ShuttingDown,
    /// A file of the data dir could not be read or written.
    #[error("{context}: {source}")]
    Io {
        /// What was being done, naming the file.
        context: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

impl From<Error> for tonic::Status {
    fn from(e: Error) -> Self {
        let msg = e.to_string();
        match e {
            Error::InvalidArgument { .. } => tonic::Status::invalid_argument(msg),
            Error::NotFound { .. } => tonic::Status::not_found(msg),
            Error::FailedPrecondition { .. } => tonic::Status::failed_precondition(msg),
            Error::ShuttingDown => tonic::Status::unavailable(msg),
            Error::Io { .. } => tonic::Status::internal(msg),
        }
    }
}

pub(super) fn io_err(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> Error {
    let context = context.into();
    move |source| Error::Io { context, source }
}

/// A job's state (the persisted form of `ess.v1.JobState`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    /// Waiting for cores.
    Queued,
    /// Its process runs.
    Running,
    /// Asked to stop; its process finishes the iteration and checkpoints.
    Stopping,
    /// Stopped before the end (resumable).
    Stopped,
    /// Ran to the end.
    Succeeded,
    /// Its process failed (resumable).
    Failed,
}

impl State {
    pub(super) fn name(self) -> &'static str {
        match self {
            State::Queued => "QUEUED",
            State::Running => "RUNNING",
            State::Stopping => "STOPPING",
            State::Stopped => "STOPPED",
            State::Succeeded => "SUCCEEDED",
            State::Failed => "FAILED",
        }
    }

    /// Whether the job has ended (no more events until it is resumed).
    pub fn is_final(self) -> bool {
        matches!(self, State::Stopped | State::Succeeded | State::Failed)
    }

    pub(super) fn pb(self) -> pb::JobState {
        match self {
            State::Queued => pb::JobState::Queued,
            State::Running => pb::JobState::Running,
            State::Stopping => pb::JobState::Stopping,
            State::Stopped => pb::JobState::Stopped,
            State::Succeeded => pb::JobState::Succeeded,
            State::Failed => pb::JobState::Failed,
        }
    }

    pub(super) fn from_pb(s: pb::JobState) -> Option<Self> {
        Some(match s {
            pb::JobState::Unspecified => return None,
            pb::JobState::Queued => State::Queued,
            pb::JobState::Running => State::Running,
            pb::JobState::Stopping => State::Stopping,
            pb::JobState::Stopped => State::Stopped,
            pb::JobState::Succeeded => State::Succeeded,
            pb::JobState::Failed => State::Failed,
        })
    }
}

/// A job spec as persisted.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(super) struct SpecRecord {
    pub(super) preset: String,
    pub(super) env: String,
    pub(super) seed: Option<u64>,
    pub(super) overrides: Vec<(String, String)>,
    pub(super) config_toml: String,
}

impl From<&pb::JobSpec> for SpecRecord {
    fn from(s: &pb::JobSpec) -> Self {
        Self {
            preset: s.preset.clone(),
            env: s.env.clone(),
            seed: s.seed,
            overrides: s
                .overrides
                .iter()
                .map(|o| (o.key.clone(), o.value.clone()))
                .collect(),
            config_toml: s.config_toml.clone(),
        }
    }
}

impl From<&SpecRecord> for pb::JobSpec {
    fn from(s: &SpecRecord) -> Self {
        Self {
            preset: s.preset.clone(),
            env: s.env.clone(),
            seed: s.seed,
            overrides: s
                .overrides
                .iter()
                .map(|(key, value)| pb::Override {
                    key: key.clone(),
                    value: value.clone(),
                })
                .collect(),
            config_toml: s.config_toml.clone(),
        }
    }
}

/// `job.json`: everything about a job that outlives the server.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct JobRecord {
    pub(super) id: String,
    /// Submission order (ids are `job-<seq>`).
    pub(super) seq: u64,
    pub(super) spec: SpecRecord,
    /// The resolved preset name (`--preset` of the child).
    pub(super) preset: String,
    pub(super) state: State,
    pub(super) iteration: u32,
    pub(super) iterations: u32,
    pub(super) env_steps: u64,
    pub(super) cores: u32,
    /// `run.torch_threads` forced on the child (auto configs), if any.
    pub(super) torch_threads: Option<usize>,
    pub(super) run_dir: PathBuf,
    pub(super) created_unix_ms: i64,
    pub(super) started_unix_ms: i64,
    pub(super) finished_unix_ms: i64,
    pub(super) error: String,
    pub(super) result: Option<FinalRecord>,
    pub(super) resumes: u32,
    /// Whether the next start continues from the run's checkpoint.
    pub(super) resume_next: bool,
    /// A stop was asked for (the child's exit then means STOPPED).
    pub(super) stop_requested: bool,
    #[serde(skip)]
    pub(super) phase: String,
}

impl JobRecord {
    pub(super) fn to_pb(&self) -> pb::Job {
        pb::Job {
            id: self.id.clone(),
            spec: Some((&self.spec).into()),
            state: self.state.pb().into(),
            iteration: self.iteration,
            iterations: self.iterations,
            env_steps: self.env_steps,
            cores: self.cores,
            run_dir: self.run_dir.display().to_string(),
            created_unix_ms: self.created_unix_ms,
            started_unix_ms: self.started_unix_ms,
            finished_unix_ms: self.finished_unix_ms,
            error: self.error.clone(),
            result: self.result.as_ref().map(|r| pb::JobResult {
                nmi: r.nmi,
                ent: r.ent,
                normalized_reward: r.normalized_reward,
                env_steps: r.env_steps,
                wall_seconds: r.wall_seconds,
            }),
            resumes: self.resumes,
            phase: self.phase.clone(),
        }
    }

    pub(super) fn record_path(&self) -> PathBuf {
        self.run_dir.join("job.json")
    }

    pub(super) fn config_path(&self) -> PathBuf {
        self.run_dir.join("job-config.toml")
    }
}

pub(super) fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
        .unwrap_or(0)
}

/// Writes `job.json` atomically ([`ess_envs::write_atomic`]).
pub(super) fn persist(rec: &JobRecord) -> Result<(), Error> {
    let path = rec.record_path();
    let text = serde_json::to_vec_pretty(rec).map_err(|e| Error::Io {
        context: format!("encoding {}", path.display()),
        source: std::io::Error::other(e),
    })?;
    ess_envs::write_atomic(&path, &text).map_err(|(p, source)| Error::Io {
        context: format!("writing {}", p.display()),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_codes_follow_the_error() {
        let s: tonic::Status = Error::NotFound { id: "job-9".into() }.into();
        assert_eq!(s.code(), tonic::Code::NotFound);
        assert!(s.message().contains("job-9"));
        let s: tonic::Status = Error::InvalidArgument {
            field: "spec.preset".into(),
            message: "unknown".into(),
        }
        .into();
        assert_eq!(s.code(), tonic::Code::InvalidArgument);
        assert!(s.message().starts_with("spec.preset: "));
    }
}
