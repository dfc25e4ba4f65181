//! Following a job: [`Manager::watch`] streams its state and iterations to a watcher,
//! catching a lagging watcher up from the job's in-memory history.

use super::{Error, Manager, State};
use ess_proto::pb;
use std::sync::Arc;
use tokio::sync::{broadcast, mpsc, watch};

impl Manager {
    /// A stream of `id`'s events: its current state first, then every iteration and
    /// state change until the job ends (or the server stops: `Unavailable`).
    pub fn watch(
        self: &Arc<Self>,
        id: &str,
    ) -> Result<mpsc::Receiver<Result<pb::JobEvent, tonic::Status>>, Error> {
        let (first, mut rx, mut next_seq) = {
            let inner = self.lock();
            let e = inner
                .jobs
                .get(id)
                .ok_or_else(|| Error::NotFound { id: id.into() })?;
            (
                pb::JobEvent {
                    job: Some(e.rec.to_pb()),
                    metrics: None,
                },
                e.tx.subscribe(),
                e.history.len(),
            )
        };
        let (tx, out) = mpsc::channel(16);
        let mut closing = self.closing.subscribe();
        let me = self.clone();
        let id = id.to_string();
        tokio::spawn(async move {
            let done = is_final(&first);
            if tx.send(Ok(first)).await.is_err() || done {
                return;
            }
            loop {
                let item = tokio::select! {
                    r = rx.recv() => r,
                    () = closed(&mut closing) => {
                        let _ = tx.send(Err(tonic::Status::unavailable("the server is shutting down"))).await;
                        return;
                    }
                    () = tx.closed() => return,
                };
                let batch: Vec<pb::JobEvent> = match item {
                    Ok(b) => match b.seq {
                        Some(s) if s < next_seq => continue,
                        Some(s) => {
                            next_seq = s + 1;
                            vec![(*b.event).clone()]
                        }
                        None => vec![(*b.event).clone()],
                    },
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        tracing::debug!(job = %id, missed = n, "watcher lagged; catching up");
                        match me.catch_up(&id, &mut next_seq) {
                            Some(v) => v,
                            None => return,
                        }
                    }
                    Err(broadcast::error::RecvError::Closed) => return,
                };
                for ev in batch {
                    let done = is_final(&ev);
                    if tx.send(Ok(ev)).await.is_err() || done {
                        return;
                    }
                }
            }
        });
        Ok(out)
    }

    /// The iterations of `id` from `*next_seq` on, then its current state; advances
    /// `next_seq` past them.
    fn catch_up(&self, id: &str, next_seq: &mut usize) -> Option<Vec<pb::JobEvent>> {
        let inner = self.lock();
        let e = inner.jobs.get(id)?;
        let job = e.rec.to_pb();
        let mut v: Vec<pb::JobEvent> = e
            .history
            .get(*next_seq..)
            .unwrap_or_default()
            .iter()
            .map(|m| pb::JobEvent {
                job: Some(job.clone()),
                metrics: Some(m.clone()),
            })
            .collect();
        *next_seq = e.history.len();
        v.push(pb::JobEvent {
            job: Some(job),
            metrics: None,
        });
        Some(v)
    }
}

/// Resolves once the server closes (or the manager is gone).
async fn closed(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|c| *c).await;
}

fn is_final(ev: &pb::JobEvent) -> bool {
    ev.job
        .as_ref()
        .and_then(|j| pb::JobState::try_from(j.state).ok())
        .and_then(State::from_pb)
        .is_some_and(State::is_final)
}
