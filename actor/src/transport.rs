//! The seam between the learner and its actors.
//!
//! [`RolloutSource`] is what the learner calls once per iteration: publish the current
//! weights, get back exactly `steps` transitions as one chunk per actor. The threaded
//! implementation here is the in-process path and the test double of the shared-memory
//! transport between processes (`ess_learner::actors::ShmActors`, over [`crate::shm`]):
//! with the same per-actor seeds both produce the same chunks.

use crate::policy::{LatentSpec, PolicyWeights};
use crate::rollout::{ActorError, EvalEpisode, Worker, WorkerState, eval_episode};
use ess_envs::Env;
use ess_proto::Chunk;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

/// Where the learner gets its rollouts from.
pub trait RolloutSource: Send {
    /// Number of actors.
    fn n_actors(&self) -> usize;
    /// Collects exactly `steps` transitions under `weights`, one chunk per actor in
    /// actor order (actor `i` produces `steps / n + (i < steps % n)` of them).
    fn collect(
        &mut self,
        weights: Arc<PolicyWeights>,
        steps: usize,
    ) -> Result<Vec<Chunk>, ActorError>;

    /// Where evaluation episodes run: `None` (the default) runs them in the learner
    /// process ([`LocalEval`], the threaded path); actor processes run them themselves.
    fn evaluator(&mut self) -> Option<&mut dyn EvalRunner> {
        None
    }

    /// Every actor's complete state between two rollouts, in actor order (checkpoints);
    /// `None` where the transport does not carry actor states (actor processes).
    fn snapshot(&mut self) -> Result<Option<Vec<WorkerState>>, ActorError>;

    /// Restores one [`RolloutSource::snapshot`] state per actor, so that the next
    /// rollouts continue those the snapshot was taken between.
    fn restore(&mut self, states: &[WorkerState]) -> Result<(), ActorError>;
}

/// One evaluation episode to run: deterministic policy with one-hot code `code`, latent
/// noise `eps`, env reset with `seed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalJob {
    /// One-hot code index.
    pub code: usize,
    /// Latent noise.
    pub eps: f32,
    /// Env reset seed.
    pub seed: u64,
}

/// Runs evaluation episodes ([`eval_episode`]) and returns them in job order, whoever
/// runs them; the seam behind which `ess_learner::eval::evaluate` does not care.
pub trait EvalRunner {
    /// Runs `jobs` with `w`; episode `i` of the result answers `jobs[i]`.
    fn run_eval(
        &mut self,
        w: &PolicyWeights,
        latent: &LatentSpec,
        jobs: &[EvalJob],
    ) -> Result<Vec<EvalEpisode>, ActorError>;
}

/// Evaluation in this process on one env, one episode after the other.
pub struct LocalEval<'a>(pub &'a mut dyn Env);

impl EvalRunner for LocalEval<'_> {
    fn run_eval(
        &mut self,
        w: &PolicyWeights,
        latent: &LatentSpec,
        jobs: &[EvalJob],
    ) -> Result<Vec<EvalEpisode>, ActorError> {
        jobs.iter()
            .map(|j| eval_episode(self.0, w, latent, j.code, j.eps, j.seed))
            .collect()
    }
}

/// Seed of actor `i`'s random stream in a run seeded `seed`: the same on every
/// transport (threads, processes, remote hosts), so one actor process reproduces one
/// actor thread step for step.
pub fn actor_seed(seed: u64, i: usize) -> u64 {
    seed.wrapping_mul(1_000_003).wrapping_add(i as u64)
}

/// Steps each actor takes for a rollout of `steps`.
pub fn split_steps(steps: usize, n: usize) -> Vec<usize> {
    (0..n)
        .map(|i| steps / n + usize::from(i < steps % n))
        .collect()
}

enum Job {
    Collect(Arc<PolicyWeights>, usize),
    Snapshot,
    Restore(Box<WorkerState>),
}

enum Reply {
    Chunk(Box<Result<Chunk, ActorError>>),
    State(Box<WorkerState>),
    Restored(Result<(), ActorError>),
}

struct Handle {
    jobs: Sender<Job>,
    results: Receiver<Reply>,
    thread: Option<JoinHandle<()>>,
}

/// Actors as threads of this process, each owning one [`Worker`].
pub struct ThreadedActors {
    handles: Vec<Handle>,
}

impl ThreadedActors {
    /// Starts one thread per worker.
    pub fn new(workers: Vec<Worker>, latent: LatentSpec) -> Self {
        let handles = workers
            .into_iter()
            .enumerate()
            .map(|(i, mut w)| {
                let (jtx, jrx) = channel::<Job>();
                let (rtx, rrx) = channel();
                let thread = std::thread::Builder::new()
                    .name(format!("ess-actor-{i}"))
                    .spawn(move || {
                        while let Ok(job) = jrx.recv() {
                            let reply = match job {
                                Job::Collect(weights, n) => {
                                    Reply::Chunk(Box::new(w.collect(&weights, &latent, n)))
                                }
                                Job::Snapshot => Reply::State(Box::new(w.snapshot())),
                                Job::Restore(s) => Reply::Restored(w.restore(&s)),
                            };
                            if rtx.send(reply).is_err() {
                                break;
                            }
                        }
                    })
                    .ok();
                Handle {
                    jobs: jtx,
                    results: rrx,
                    thread,
                }
            })
            .collect();
        Self { handles }
    }

    /// Sends one job per actor and collects the replies in actor order.
    fn round(&self, jobs: impl Iterator<Item = Job>) -> Result<Vec<Reply>, ActorError> {
        let gone = |index: usize, why: &str| ActorError::WorkerGone {
            index,
            why: why.into(),
        };
        for (i, (h, job)) in self.handles.iter().zip(jobs).enumerate() {
            h.jobs
                .send(job)
                .map_err(|_| gone(i, "job channel closed"))?;
        }
        self.handles
            .iter()
            .enumerate()
            .map(|(i, h)| {
                h.results
                    .recv()
                    .map_err(|_| gone(i, "result channel closed"))
            })
            .collect()
    }
}

impl RolloutSource for ThreadedActors {
    fn n_actors(&self) -> usize {
        self.handles.len()
    }

    fn collect(
        &mut self,
        weights: Arc<PolicyWeights>,
        steps: usize,
    ) -> Result<Vec<Chunk>, ActorError> {
        let split = split_steps(steps, self.handles.len());
        self.round(split.iter().map(|&n| Job::Collect(weights.clone(), n)))?
            .into_iter()
            .enumerate()
            .map(|(i, r)| match r {
                Reply::Chunk(c) => *c,
                _ => Err(unexpected(i)),
            })
            .collect()
    }

    fn snapshot(&mut self) -> Result<Option<Vec<WorkerState>>, ActorError> {
        self.round(self.handles.iter().map(|_| Job::Snapshot))?
            .into_iter()
            .enumerate()
            .map(|(i, r)| match r {
                Reply::State(s) => Ok(*s),
                _ => Err(unexpected(i)),
            })
            .collect::<Result<_, _>>()
            .map(Some)
    }

    fn restore(&mut self, states: &[WorkerState]) -> Result<(), ActorError> {
        if states.len() != self.handles.len() {
            return Err(ActorError::Transport {
                what: format!(
                    "{} actor states for {} actors",
                    states.len(),
                    self.handles.len()
                ),
            });
        }
        for (i, r) in self
            .round(states.iter().map(|s| Job::Restore(Box::new(s.clone()))))?
            .into_iter()
            .enumerate()
        {
            match r {
                Reply::Restored(r) => r?,
                _ => return Err(unexpected(i)),
            }
        }
        Ok(())
    }
}

fn unexpected(index: usize) -> ActorError {
    ActorError::WorkerGone {
        index,
        why: "answered another request".into(),
    }
}

impl Drop for ThreadedActors {
    fn drop(&mut self) {
        for h in &mut self.handles {
            // Closing the job channel ends the thread's loop.
            let (tx, _) = channel();
            drop(std::mem::replace(&mut h.jobs, tx));
            if let Some(t) = h.thread.take() {
                let _ = t.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_steps_sums_to_the_rollout_size() {
        assert_eq!(split_steps(10, 3), vec![4, 3, 3]);
        assert_eq!(split_steps(5000, 2).iter().sum::<usize>(), 5000);
        assert_eq!(split_steps(1, 2), vec![1, 0]);
    }
}
