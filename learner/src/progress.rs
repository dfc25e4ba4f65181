//! Machine-readable training progress: `ess train --progress jsonl` writes one
//! [`ProgressEvent`] per line on stdout (set-up messages, every iteration's metrics, the
//! final result); `ess serve` reads them back from its job processes.

use crate::train::{IterationLog, Progress, Summary};
use ess_proto::pb;
use serde::{Deserialize, Serialize};
use std::io::Write;

/// One line of `--progress jsonl`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ProgressEvent {
    /// A set-up phase began (`demonstrations`, `behaviour classifier`, `training`, `final
    /// evaluation`); `training` means the first rollout starts now.
    Message {
        /// The phase or status text.
        message: String,
    },
    /// One iteration finished.
    Iteration(pb::IterationMetrics),
    /// Training ended (also when stopped early); `summary.json` holds the rest.
    Summary(FinalRecord),
}

/// The final result of a run (the headline of `summary.json`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FinalRecord {
    /// Final NMI.
    pub nmi: f64,
    /// Final ENT.
    pub ent: f64,
    /// Final normalised task reward.
    pub normalized_reward: f64,
    /// Environment steps of training.
    pub env_steps: u64,
    /// Iterations run.
    pub iterations: u32,
    /// Wall seconds of training.
    pub wall_seconds: f64,
    /// Whether the run was stopped early (SIGTERM, Ctrl-C).
    pub interrupted: bool,
}

impl From<&Summary> for FinalRecord {
    fn from(s: &Summary) -> Self {
        Self {
            nmi: s.nmi,
            ent: s.ent,
            normalized_reward: s.normalized_reward,
            env_steps: s.env_steps as u64,
            iterations: u32::try_from(s.iterations).unwrap_or(u32::MAX),
            wall_seconds: s.wall_seconds,
            interrupted: s.interrupted,
        }
    }
}

/// A [`Progress`] writing [`ProgressEvent`] lines to `W` (stdout for `--progress jsonl`),
/// flushed per line so a reader sees each event as it happens. When the reader is gone
/// (a broken pipe: the `ess serve` that ran the job died), it sets the flag given to
/// [`JsonlProgress::stop_when_reader_gone`], so the run stops gracefully after the
/// iteration (checkpoint, final evaluation, files) instead of running on unwatched;
/// other write errors are ignored.
pub struct JsonlProgress<W: Write> {
    out: W,
    stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
}

impl<W: Write> JsonlProgress<W> {
    /// Writes to `out`.
    pub fn new(out: W) -> Self {
        Self { out, stop: None }
    }

    /// Sets `flag` (the run's shutdown flag) once a line cannot be written because the
    /// reader closed the pipe.
    pub fn stop_when_reader_gone(
        mut self,
        flag: std::sync::Arc<std::sync::atomic::AtomicBool>,
    ) -> Self {
        self.stop = Some(flag);
        self
    }

    /// Writes one event line.
    pub fn emit(&mut self, ev: &ProgressEvent) {
        let mut line = match serde_json::to_vec(ev) {
            Ok(line) => line,
            Err(e) => {
                tracing::debug!(error = %e, "progress event not serialised");
                return;
            }
        };
        line.push(b'\n');
        let r = self.out.write_all(&line).and_then(|()| self.out.flush());
        if let Err(e) = r {
            if e.kind() == std::io::ErrorKind::BrokenPipe
                && let Some(flag) = &self.stop
                && !flag.swap(true, std::sync::atomic::Ordering::SeqCst)
            {
                tracing::warn!("the progress reader is gone; stopping after this iteration");
            } else {
                tracing::debug!(error = %e, "progress line not written");
            }
        }
    }
}

impl<W: Write> Progress for JsonlProgress<W> {
    fn iteration(&mut self, it: &IterationLog) {
        self.emit(&ProgressEvent::Iteration(it.metrics()));
    }

    fn message(&mut self, msg: &str) {
        self.emit(&ProgressEvent::Message {
            message: msg.to_string(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pipe whose reader has gone.
    struct ClosedPipe;
    impl Write for ClosedPipe {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::ErrorKind::BrokenPipe.into())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_closed_progress_pipe_asks_the_run_to_stop() {
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut p = JsonlProgress::new(ClosedPipe).stop_when_reader_gone(flag.clone());
        p.message("demonstrations");
        assert!(flag.load(std::sync::atomic::Ordering::SeqCst));
        // Without the flag a closed pipe is only logged.
        JsonlProgress::new(ClosedPipe).message("demonstrations");
    }

    #[test]
    fn jsonl_lines_parse_back_to_the_events_written() {
        let mut p = JsonlProgress::new(Vec::new());
        let log = IterationLog {
            iteration: 3,
            env_steps: 1200,
            disc_bce: 0.5,
            prior: "0.25;0.75".into(),
            nmi: Some(0.9),
            ..Default::default()
        };
        p.message("training");
        p.iteration(&log);
        let fin = FinalRecord {
            nmi: 0.8,
            iterations: 3,
            interrupted: true,
            ..Default::default()
        };
        p.emit(&ProgressEvent::Summary(fin.clone()));
        let text = String::from_utf8(p.out).unwrap();
        let events: Vec<ProgressEvent> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(events.len(), 3);
        assert_eq!(
            events[0],
            ProgressEvent::Message {
                message: "training".into()
            }
        );
        let ProgressEvent::Iteration(r) = &events[1] else {
            panic!("{events:?}")
        };
        assert_eq!(r.iteration, 3);
        assert_eq!(r.env_steps, 1200);
        assert_eq!(r.prior, vec![0.25, 0.75]);
        assert_eq!(r.nmi, Some(0.9));
        assert_eq!(r.ent, None);
        assert_eq!(r.disc_bce, 0.5);
        assert_eq!(events[2], ProgressEvent::Summary(fin));
    }
}
