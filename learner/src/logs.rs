//! The logs a run keeps beside `metrics.csv`: the MCAP run log ([`crate::runlog`]) and
//! TensorBoard's event file ([`crate::tboard`]), behind the training loop's
//! [`RecordSink`].
//!
//! The loop (`train/`) hands its records to the sink and knows neither format; this
//! module sits above both and is what `ess train` passes to [`crate::train::run`]
//! ([`open`]). A run log that cannot be written stops the run (it is the run's record);
//! an event file that cannot be written is said once and training goes on.

use crate::eval::EvalResult;
use crate::runlog::{RunLog, scene};
use crate::tboard::Board;
use crate::train::{IterationLog, RecordSink, ResumedAt};
use anyhow::Result;
use ess_actor::EvalEpisode;
use ess_envs::Env;
use ess_proto::{CheckedConfig, Chunk};
use std::path::Path;

/// A run's MCAP log and TensorBoard event file.
pub struct RunLogs {
    /// Finished on every way out (drop), see [`crate::runlog`].
    runlog: RunLog,
    board: Board,
}

/// The logs of the run in `out`: created for a fresh run, reopened after the
/// checkpoint's iteration for a resumed one (an [`crate::train::OpenSink`]).
pub fn open(
    cfg: &CheckedConfig,
    out: &Path,
    resumed: Option<ResumedAt>,
) -> Result<Box<dyn RecordSink>> {
    let path = out.join("run.mcap");
    let runlog = match resumed {
        Some(at) => RunLog::reopen(&path, cfg, at.iteration)?,
        None => RunLog::create(&path, cfg)?,
    };
    let mut board = Board::open(out, resumed.map(|at| at.env_steps));
    if resumed.is_none() {
        board.config(&cfg.to_toml());
    }
    Ok(Box::new(RunLogs { runlog, board }))
}

impl RecordSink for RunLogs {
    fn iteration(&mut self, log: &IterationLog) -> Result<()> {
        Ok(self.runlog.iteration(log)?)
    }

    fn rollout(&mut self, iteration: usize, chunks: &[Chunk], rewards: &[f32]) -> Result<()> {
        Ok(self.runlog.chunks(iteration, chunks, rewards)?)
    }

    fn row(&mut self, log: &IterationLog) {
        self.board.row(log);
    }

    fn evaluation(&mut self, env_steps: usize, result: &EvalResult) {
        self.board.evaluation(env_steps, result);
    }

    /// The episodes in the run log, with the robot's poses replayed from their recorded
    /// states when the env has a body model (the 3D scene, [`crate::runlog::scene`]). A
    /// state the env refuses leaves the scene out (with a warning), never the episodes.
    fn episodes(
        &mut self,
        iteration: usize,
        final_eval: bool,
        episodes: &[EvalEpisode],
        env: &mut dyn Env,
    ) -> Result<()> {
        if !self.runlog.logs_episodes(final_eval) {
            return Ok(());
        }
        let bodies = env.scene();
        let poses = match bodies {
            Some(_) => episodes
                .iter()
                .map(|ep| scene::episode_poses(env, ep))
                .collect::<Result<Vec<_>, _>>()
                .inspect_err(|e| tracing::warn!("the run log's 3D scene is left out: {e}"))
                .ok(),
            None => None,
        };
        let drawn = bodies.as_ref().zip(poses.as_deref());
        Ok(self
            .runlog
            .eval_episodes(iteration, final_eval, episodes, drawn)?)
    }

    fn figure(&mut self, env_steps: usize, path: &Path) {
        self.board.figure(env_steps, path);
    }

    fn note(&mut self) -> Option<String> {
        self.board.failed()
    }

    fn finish(self: Box<Self>) -> Result<()> {
        Ok(self.runlog.finish()?)
    }
}
