//! Actor processes' states for checkpoints: [`ShmActors::snapshot_states`] asks each
//! actor for its [`WorkerState`] (a [`Request::SNAPSHOT`], answered with one
//! [`ess_actor::state_msg`] sample on the `chunks` service) and
//! [`ShmActors::restore_states`] restarts each actor from its state, written to a file
//! that `ess-actor --restore-state` reads before its first heartbeat.
//!
//! A snapshot is taken between rollouts, when the actors are idle. An actor that dies or
//! goes silent during it fails the snapshot (the checkpoint then holds no actor states
//! and says so) rather than being restarted: a replacement's state is not the one the
//! run would have continued with.

use super::{ShmActors, gone, transport};
use ess_actor::shm::{HEARTBEAT_PERIOD, Request, Status};
use ess_actor::state_msg::{self, StateMsg};
use ess_actor::{ActorError, WorkerState};
use std::path::PathBuf;
use std::time::Instant;

impl ShmActors {
    /// Every actor's state, in actor order.
    pub(super) fn snapshot_states(&mut self) -> Result<Vec<WorkerState>, ActorError> {
        let n = self.procs.len();
        self.request_id += 1;
        let rid = self.request_id;
        let request = |i: usize| Request {
            actor: i as u32,
            kind: Request::SNAPSHOT,
            request_id: rid,
            ..Default::default()
        };
        for i in 0..n {
            self.send_request(request(i))?;
            self.procs[i].last_resend = Instant::now();
        }
        let mut out: Vec<Option<WorkerState>> = vec![None; n];
        while out.iter().any(Option::is_none) {
            let now = self.wait_and_drain_status()?;
            while let Some(sample) = self
                .chunks
                .receive()
                .map_err(|e| transport(format!("receiving an actor state: {e:?}")))?
            {
                match state_msg::decode(sample.payload()) {
                    Ok(m) if m.run_id_hash == self.hash && m.request_id == rid => {
                        if let Some(slot) = out.get_mut(m.actor as usize) {
                            *slot = Some(m.state);
                        }
                    }
                    Ok(m) => tracing::warn!(
                        actor = m.actor,
                        request = m.request_id,
                        "dropping an actor state that answers no request of this run"
                    ),
                    Err(e) => tracing::warn!("dropping a sample: {e}"),
                }
            }
            for i in (0..n).filter(|&i| out[i].is_none()) {
                self.fail_if_lost(i, now, "a snapshot of its state")?;
                let p = &mut self.procs[i];
                let idle_without = p
                    .last_status
                    .is_some_and(|s| s.state == Status::IDLE && s.last_done < rid);
                if idle_without && now.duration_since(p.last_resend) > 2 * HEARTBEAT_PERIOD {
                    p.last_resend = now;
                    self.send_request(request(i))?;
                }
            }
        }
        Ok(out.into_iter().flatten().collect())
    }

    /// Restarts every actor from `states` (one per actor, in order) and waits for each
    /// restored actor's first heartbeat.
    pub(super) fn restore_states(&mut self, states: &[WorkerState]) -> Result<(), ActorError> {
        let n = self.procs.len();
        if states.len() != n {
            return Err(transport(format!(
                "{} actor states for {n} actor processes",
                states.len()
            )));
        }
        let dir = std::env::temp_dir().join(format!("ess-restore-{}", self.cfg.run_id));
        let written = self.write_state_files(&dir, states);
        let result = written.and_then(|files| self.restart_from(&files));
        let _ = std::fs::remove_dir_all(&dir);
        result
    }

    fn write_state_files(
        &self,
        dir: &std::path::Path,
        states: &[WorkerState],
    ) -> Result<Vec<PathBuf>, ActorError> {
        let io = |e: std::io::Error| transport(format!("{}: {e}", dir.display()));
        std::fs::create_dir_all(dir).map_err(io)?;
        let mut files = Vec::with_capacity(states.len());
        for (i, s) in states.iter().enumerate() {
            let words = state_msg::encode(&StateMsg {
                run_id_hash: self.hash,
                actor: i as u32,
                request_id: 0,
                state: s.clone(),
            });
            let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
            let path = dir.join(format!("actor-{i}.state"));
            std::fs::write(&path, bytes).map_err(io)?;
            files.push(path);
        }
        Ok(files)
    }

    fn restart_from(&mut self, files: &[PathBuf]) -> Result<(), ActorError> {
        for (i, file) in files.iter().enumerate() {
            let p = &mut self.procs[i];
            let _ = p.child.kill();
            let _ = p.child.wait();
            let restarts = p.restarts;
            self.node.try_cleanup_dead_nodes();
            self.procs[i] = self
                .spawn(i, restarts, Some(file))
                .map_err(|e| gone(i, format!("restoring: {e}")))?;
        }
        while self.procs.iter().any(|p| p.last_seen.is_none()) {
            let now = self.wait_and_drain_status()?;
            for i in 0..files.len() {
                self.fail_if_lost(i, now, "its restore")?;
            }
        }
        Ok(())
    }

    /// An error if actor `i` exited or went silent during `what`.
    fn fail_if_lost(&mut self, i: usize, now: Instant, what: &str) -> Result<(), ActorError> {
        match self.lost(i, now) {
            Some(why) => Err(gone(i, format!("{why} during {what}"))),
            None => Ok(()),
        }
    }
}
