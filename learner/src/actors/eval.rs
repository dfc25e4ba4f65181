//! Evaluation episodes in the actor processes: [`EvalRunner`] for [`ShmActors`].

use super::{ShmActors, transport};
use ess_actor::shm::Request;
use ess_actor::{ActorError, EvalEpisode, EvalJob, EvalRunner, LatentSpec, PolicyWeights};
use ess_proto::shm::read_episode;
use std::time::Instant;

impl EvalRunner for ShmActors {
    /// Hands the jobs out one at a time to whichever actor is free (one episode in
    /// flight per actor, so the `chunks` service's per-actor buffer never overflows),
    /// and puts every episode back at its job's index: the result depends neither on the
    /// number of actors nor on who ran what. An actor that dies or goes silent is
    /// restarted and asked again for the job it held, as during rollouts.
    fn run_eval(
        &mut self,
        w: &PolicyWeights,
        _latent: &LatentSpec,
        jobs: &[EvalJob],
    ) -> Result<Vec<EvalEpisode>, ActorError> {
        let n = self.procs.len();
        self.wire_version += 1;
        let wire = self.wire_version;
        self.publish_weights(w, wire)?;
        let (od, ad) = (w.obs_mean.len(), w.log_std.len());
        let mut out: Vec<Option<EvalEpisode>> = (0..jobs.len()).map(|_| None).collect();
        let mut held: Vec<Option<Request>> = vec![None; n];
        let mut next = 0;
        let mut restarts_now = vec![0u32; n];
        loop {
            for (i, slot) in held.iter_mut().enumerate() {
                if slot.is_none() && next < jobs.len() {
                    let j = jobs[next];
                    self.request_id += 1;
                    let r = Request {
                        actor: i as u32,
                        kind: Request::EVALUATE,
                        request_id: self.request_id,
                        policy_version: wire,
                        code: j.code as u32,
                        eps_bits: j.eps.to_bits(),
                        seed: j.seed,
                        job: next as u64,
                        ..Default::default()
                    };
                    self.send_request(r)?;
                    self.procs[i].last_resend = Instant::now();
                    *slot = Some(r);
                    next += 1;
                }
            }
            if held.iter().all(Option::is_none) {
                break;
            }
            let now = self.wait_and_drain_status()?;
            while let Some(sample) = self
                .chunks
                .receive()
                .map_err(|e| transport(format!("receiving an episode: {e:?}")))?
            {
                let (h, e) = match read_episode(bytemuck::cast_slice(sample.payload())) {
                    Ok(x) => x,
                    Err(e) => {
                        tracing::warn!("dropping a sample that is no evaluation episode: {e}");
                        continue;
                    }
                };
                let i = h.actor as usize;
                let job = h.job as usize;
                let fits = h.run_id_hash == self.hash
                    && i < n
                    && held[i].is_some_and(|r| r.request_id == h.request_id && r.job == h.job)
                    && h.policy_version == wire
                    && (od, ad) == (h.obs_dim as usize, h.act_dim as usize)
                    && job < jobs.len()
                    && out[job].is_none();
                if !fits {
                    tracing::warn!(
                        actor = i,
                        request = h.request_id,
                        job,
                        "dropping an episode that does not answer a pending job"
                    );
                    continue;
                }
                out[job] = Some(EvalEpisode {
                    code: h.code as usize,
                    eps: f32::from_bits(h.eps_bits),
                    reset_seed: jobs[job].seed,
                    start_obs: e.start_obs,
                    start_state: e.start_state,
                    states: e.states,
                    state_dim: h.state_dim as usize,
                    obs: e.obs,
                    act: e.act,
                    next_obs: e.next_obs,
                    n_modes: h.n_modes as usize,
                    mode_rewards: e.mode_rewards,
                });
                held[i] = None;
            }
            for (i, job) in held.iter().enumerate() {
                if self.supervise(i, now, &mut restarts_now)? {
                    continue;
                }
                if let Some(r) = *job {
                    self.resend_if_idle(r, w, now)?;
                }
            }
        }
        out.into_iter()
            .enumerate()
            .map(|(j, e)| e.ok_or_else(|| transport(format!("evaluation job {j} has no episode"))))
            .collect()
    }
}
