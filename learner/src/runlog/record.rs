//! The run log's records: its topics, the [`Record`] each carries, and how training's
//! data becomes records (configuration, evaluation episodes, training chunks).

use ess_actor::EvalEpisode;
use ess_proto::config::LatentPrior;
use ess_proto::{CheckedConfig, Chunk, pb};
use prost::Message as _;

/// Topic of the resolved configuration ([`pb::RunConfig`]).
pub const CONFIG_TOPIC: &str = "/config";
/// Topic of the per-iteration metrics ([`pb::IterationMetrics`]).
pub const METRICS_TOPIC: &str = "/metrics";
/// Topic of the evaluation episodes' start records ([`pb::EvalEpisode`]).
pub const EVAL_EPISODE_TOPIC: &str = "/eval/episode";
/// Topic of the evaluation episodes' steps ([`pb::EvalStep`]).
pub const EVAL_STEP_TOPIC: &str = "/eval/step";
/// Topic of the sampled training chunks ([`pb::TrainingChunk`]).
pub const TRAINING_CHUNK_TOPIC: &str = "/train/chunk";

/// What the run log records, taken from the config once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogOptions {
    /// `run.log_chunks_every` (0: no chunks).
    pub chunks_every: usize,
    /// `run.log_chunk_steps`.
    pub chunk_steps: usize,
    /// `run.log_periodic_evals`.
    pub periodic_evals: bool,
    /// Latent codes K (width of `EvalStep.c`).
    pub n_codes: usize,
    /// Whether the policy gets a one-hot `c` in evaluation (not for `prior = "none"`).
    pub one_hot: bool,
}

impl LogOptions {
    /// The options `cfg` asks for.
    pub fn of(cfg: &CheckedConfig) -> Self {
        Self {
            chunks_every: cfg.run.log_chunks_every,
            chunk_steps: cfg.run.log_chunk_steps,
            periodic_evals: cfg.run.log_periodic_evals,
            n_codes: cfg.env.n_modes,
            one_hot: cfg.method.prior != LatentPrior::None,
        }
    }
}

/// Each topic with the full name of its protobuf message, in channel order.
pub const TOPICS: [(&str, &str); 5] = [
    (CONFIG_TOPIC, "ess.v1.RunConfig"),
    (METRICS_TOPIC, "ess.v1.IterationMetrics"),
    (EVAL_EPISODE_TOPIC, "ess.v1.EvalEpisode"),
    (EVAL_STEP_TOPIC, "ess.v1.EvalStep"),
    (TRAINING_CHUNK_TOPIC, "ess.v1.TrainingChunk"),
];

/// The schema and message encoding of every `ess.v1` channel.
pub(super) const PROTOBUF: &str = "protobuf";

/// One message of the run log.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// `/config`.
    Config(pb::RunConfig),
    /// `/metrics`.
    Metrics(pb::IterationMetrics),
    /// `/eval/episode`.
    EvalEpisode(pb::EvalEpisode),
    /// `/eval/step`.
    EvalStep(pb::EvalStep),
    /// `/train/chunk`.
    TrainingChunk(pb::TrainingChunk),
}

impl Record {
    /// Index into [`TOPICS`].
    pub(super) fn kind(&self) -> usize {
        match self {
            Record::Config(_) => 0,
            Record::Metrics(_) => 1,
            Record::EvalEpisode(_) => 2,
            Record::EvalStep(_) => 3,
            Record::TrainingChunk(_) => 4,
        }
    }

    /// The topic the record is written on.
    pub fn topic(&self) -> &'static str {
        TOPICS[self.kind()].0
    }

    pub(super) fn encode(&self) -> Vec<u8> {
        match self {
            Record::Config(m) => m.encode_to_vec(),
            Record::Metrics(m) => m.encode_to_vec(),
            Record::EvalEpisode(m) => m.encode_to_vec(),
            Record::EvalStep(m) => m.encode_to_vec(),
            Record::TrainingChunk(m) => m.encode_to_vec(),
        }
    }

    pub(super) fn decode(kind: usize, data: &[u8]) -> Result<Self, prost::DecodeError> {
        Ok(match kind {
            0 => Record::Config(pb::RunConfig::decode(data)?),
            1 => Record::Metrics(pb::IterationMetrics::decode(data)?),
            2 => Record::EvalEpisode(pb::EvalEpisode::decode(data)?),
            3 => Record::EvalStep(pb::EvalStep::decode(data)?),
            _ => Record::TrainingChunk(pb::TrainingChunk::decode(data)?),
        })
    }
}

/// The `/config` record of `cfg`.
pub fn config_record(cfg: &CheckedConfig) -> pb::RunConfig {
    pb::RunConfig {
        toml: cfg.to_toml(),
        method: cfg.method.name.clone(),
        env: cfg.env.name.clone(),
        n_modes: cfg.env.n_modes as u32,
        seed: cfg.run.seed,
    }
}

/// The `/eval/episode` record of `ep` followed by its `/eval/step` records.
pub fn episode_records(
    id: u32,
    iteration: usize,
    final_eval: bool,
    ep: &EvalEpisode,
    options: &LogOptions,
) -> Vec<Record> {
    let t = ep.len();
    let od = ep.obs.len().checked_div(t).unwrap_or(ep.start_obs.len());
    let ad = ep.act.len().checked_div(t).unwrap_or(0);
    let k = ep.n_modes.max(1);
    let sd = ep.state_dim;
    let mut c = vec![0.0f32; options.n_codes];
    if options.one_hot
        && let Some(x) = c.get_mut(ep.code)
    {
        *x = 1.0;
    }
    let mut out = Vec::with_capacity(t + 1);
    out.push(Record::EvalEpisode(pb::EvalEpisode {
        episode: id,
        iteration: iteration as u32,
        final_eval,
        code: ep.code as u32,
        eps: ep.eps,
        reset_seed: ep.reset_seed,
        start_state: ep.start_state.clone(),
        start_obs: ep.start_obs.clone(),
        length: t as u32,
        mode_returns: (0..ep.n_modes)
            .map(|m| f64::from(ep.mode_return(m)))
            .collect(),
        obs_dim: od as u32,
        act_dim: ad as u32,
    }));
    let rows = |v: &[f32], w: usize, i: usize| v.get(i * w..(i + 1) * w).unwrap_or(&[]).to_vec();
    for i in 0..t {
        out.push(Record::EvalStep(pb::EvalStep {
            episode: id,
            step: i as u32,
            obs: rows(&ep.obs, od, i),
            action: rows(&ep.act, ad, i),
            c: c.clone(),
            eps: ep.eps,
            mode_rewards: rows(&ep.mode_rewards, k, i),
            next_obs: rows(&ep.next_obs, od, i),
            state: ep.states.get(i * sd..(i + 1) * sd).unwrap_or(&[]).to_vec(),
            done: i + 1 == t,
        }));
    }
    out
}

/// The first `n` steps of `c` as a `/train/chunk` record.
pub(super) fn chunk_record(
    iteration: usize,
    actor: usize,
    c: &Chunk,
    n: usize,
    rewards: Option<&[f32]>,
) -> pb::TrainingChunk {
    let take = |v: &[f32], w: usize| v[..(n * w).min(v.len())].to_vec();
    pb::TrainingChunk {
        iteration: iteration as u32,
        policy_version: c.policy_version,
        actor: actor as u32,
        len: n as u32,
        obs_dim: c.obs_dim as u32,
        act_dim: c.act_dim as u32,
        n_codes: c.n_codes as u32,
        obs: take(&c.obs, c.obs_dim),
        act: take(&c.act, c.act_dim),
        code: take(&c.code, c.n_codes),
        gumbel: take(&c.gumbel, c.n_codes),
        eps: take(&c.eps, 1),
        reward: rewards.map(<[f32]>::to_vec).unwrap_or_default(),
        done: c
            .terminated
            .iter()
            .zip(&c.truncated)
            .take(n)
            .map(|(a, b)| *a || *b)
            .collect(),
        logp: take(&c.logp, 1),
        next_obs: take(&c.next_obs, c.obs_dim),
    }
}
