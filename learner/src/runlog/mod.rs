//! The MCAP run log `<out>/run.mcap` of a training run, and its reader.
//!
//! `ess train` writes one [`RunLog`] per run. Every channel carries protobuf messages of
//! package `ess.v1` (`proto/proto/ess/v1/runlog.proto` and `metrics.proto`): schema
//! encoding `protobuf` with the encoded `FileDescriptorSet`
//! ([`ess_proto::FILE_DESCRIPTOR_SET`]) as schema data, message encoding `protobuf`, so
//! Foxglove and the `mcap` CLI decode and plot them.
//!
//! | topic | message | when |
//! |---|---|---|
//! | `/config` | `ess.v1.RunConfig` | first: the resolved config as TOML, method, env, seed |
//! | `/metrics` | `ess.v1.IterationMetrics` | after every iteration; the final evaluation repeats the last iteration (iteration 0 if none ran) with its `nmi`, `ent`, `normalized_reward` |
//! | `/eval/episode` | `ess.v1.EvalEpisode` | one per evaluation episode (final evaluation; periodic ones with `run.log_periodic_evals`): code, eps, reset seed, start state, length, returns |
//! | `/eval/step` | `ess.v1.EvalStep` | each step of that episode: obs, action, c, eps, mode rewards, next obs, the env state after the step |
//! | `/train/chunk` | `ess.v1.TrainingChunk` | every `run.log_chunks_every` iterations, the first `run.log_chunk_steps` steps of each actor's chunk with the policy reward |
//! | `/scene`, `/tf` | `foxglove.SceneUpdate`, `foxglove.FrameTransforms` | the logged evaluation episodes of a MuJoCo env as a moving robot ([`scene`]) |
//!
//! Log times are wall-clock nanoseconds since the Unix epoch, never decreasing; an
//! evaluation episode's steps are stamped the env's step duration apart from its start.
//!
//! Files are zstd-chunked with message indexes, chunk indexes, statistics and a summary
//! section written by [`RunLog::finish`] (also run on drop, so error paths and Ctrl-C /
//! SIGTERM, which end `train::run` normally, close the file). The writer closes its
//! current chunk after every iteration ([`RunLog::iteration`]) and evaluation, so a
//! process killed with SIGKILL loses at most the iteration in progress: [`read`] streams
//! the records of a possibly truncated file and returns every complete message before
//! the cut ([`RunLogContents::truncated`] says why it stopped).
//!
//! Resume: [`RunLog::reopen`] rewrites an existing (possibly truncated) log keeping the
//! messages of iterations up to the checkpoint's, drops the interrupted run's final
//! evaluation, and continues writing, so a resumed run's log reads like an
//! uninterrupted one.

pub mod behaviour;
mod read;
mod record;
pub mod replay;
pub mod scene;

pub use read::{Logged, MAX_RECORD_BYTES, RunLogContents, SceneMessage, read, read_from};
pub use record::{
    CONFIG_TOPIC, EVAL_EPISODE_TOPIC, EVAL_STEP_TOPIC, LogOptions, METRICS_TOPIC, Record, TOPICS,
    TRAINING_CHUNK_TOPIC, config_record, episode_records,
};
use record::{PROTOBUF, chunk_record};

use crate::train::IterationLog;
use ess_actor::EvalEpisode;
use ess_envs::scene::Scene;
use ess_proto::{CheckedConfig, Chunk, FILE_DESCRIPTOR_SET};
use prost::Message as _;
use std::collections::{BTreeMap, HashSet};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Errors of writing and reading run logs; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum RunLogError {
    /// The file could not be created, opened, read, written or renamed.
    #[error("{}: {what}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The MCAP writer refused a record.
    #[error("{}: writing MCAP: {}", path.display(), mcap_reason(source))]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The writer's error.
        #[source]
        source: Box<mcap::McapError>,
    },
    /// The file does not start with the MCAP magic.
    #[error("{} is not an MCAP file (it does not start with the MCAP magic bytes)", path.display())]
    NotMcap {
        /// The file.
        path: PathBuf,
    },
    /// A known topic with another schema or encoding than the run log's.
    #[error(
        "{}: topic {topic} has {found}, expected schema `{expected}` with protobuf encodings: not an Ess run log of this version",
        path.display()
    )]
    WrongSchema {
        /// The file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// The schema name and encodings found.
        found: String,
        /// The schema name expected.
        expected: &'static str,
    },
    /// A complete message that does not decode as its schema.
    #[error("{}: message {index} (on {topic}) does not decode as {schema}: {source}", path.display())]
    Decode {
        /// The file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// Index of the message in the file.
        index: usize,
        /// The expected message.
        schema: &'static str,
        /// prost's error.
        #[source]
        source: prost::DecodeError,
    },
}

type McapWriter = mcap::Writer<BufWriter<File>>;

/// The writer of a run log (see the module docs for topics and guarantees).
pub struct RunLog {
    path: PathBuf,
    writer: Option<McapWriter>,
    /// Channel id of each entry of [`TOPICS`].
    channels: [u16; 5],
    /// Channel id of each entry of [`scene::SCENE_TOPICS`].
    scene_channels: [u16; 2],
    sequence: u32,
    last_time: u64,
    next_episode: u32,
    options: LogOptions,
}

impl std::fmt::Debug for RunLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunLog")
            .field("path", &self.path)
            .field("open", &self.writer.is_some())
            .field("options", &self.options)
            .finish()
    }
}

impl RunLog {
    /// Creates (truncating) the log at `path` and writes `cfg` on `/config`.
    pub fn create(path: &Path, cfg: &CheckedConfig) -> Result<Self, RunLogError> {
        let mut log = Self::open_writer(path, LogOptions::of(cfg))?;
        log.record(&Record::Config(config_record(cfg)))?;
        log.flush()?;
        Ok(log)
    }

    /// A log at `path` with every channel registered and nothing written yet.
    pub fn open_writer(path: &Path, options: LogOptions) -> Result<Self, RunLogError> {
        let file = File::create(path).map_err(|source| RunLogError::Io {
            path: path.to_path_buf(),
            what: "creating the run log",
            source,
        })?;
        let mcap_err = |source: mcap::McapError| RunLogError::Mcap {
            path: path.to_path_buf(),
            source: Box::new(source),
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .use_chunks(true)
            .emit_summary_records(true)
            .emit_message_indexes(true)
            .emit_chunk_indexes(true)
            .emit_statistics(true)
            // Single-threaded compression: the learner's cores are busy training.
            .compression_threads(0)
            .profile("")
            .create(BufWriter::new(file))
            .map_err(mcap_err)?;
        let mut channels = [0u16; 5];
        for (ch, (topic, schema)) in channels.iter_mut().zip(TOPICS) {
            let schema_id = writer
                .add_schema(schema, PROTOBUF, FILE_DESCRIPTOR_SET)
                .map_err(mcap_err)?;
            *ch = writer
                .add_channel(schema_id, topic, PROTOBUF, &BTreeMap::new())
                .map_err(mcap_err)?;
        }
        let mut scene_channels = [0u16; 2];
        for (ch, (topic, schema)) in scene_channels.iter_mut().zip(scene::SCENE_TOPICS) {
            let fds = ess_proto::FOXGLOVE_DESCRIPTOR_SET;
            let schema_id = writer.add_schema(schema, PROTOBUF, fds).map_err(mcap_err)?;
            *ch = writer
                .add_channel(schema_id, topic, PROTOBUF, &BTreeMap::new())
                .map_err(mcap_err)?;
        }
        Ok(Self {
            path: path.to_path_buf(),
            writer: Some(writer),
            channels,
            scene_channels,
            sequence: 0,
            last_time: 0,
            next_episode: 0,
            options,
        })
    }

    /// Rewrites the log at `path` for a run resumed from the checkpoint of iteration
    /// `upto_iteration` and returns it open for writing.
    ///
    /// Kept: every complete message of the existing file (which may be truncated) that
    /// belongs to iterations `<= upto_iteration` with its original log time: `/config`,
    /// `/metrics` (the first message of each iteration `1..=upto_iteration`),
    /// `/train/chunk`, and the periodic evaluations' episodes and steps with their
    /// `/scene` and `/tf` messages. Dropped: later
    /// iterations and the interrupted run's final evaluation (episodes marked
    /// `final_eval`, the `/metrics` message repeating an iteration, iteration 0). A
    /// `/config` record of `cfg` is appended when its TOML differs from the last kept
    /// one (or none was kept). A missing file starts a new log. The rewrite goes to
    /// `<path>.reopen` first and replaces `path` by a rename.
    pub fn reopen(
        path: &Path,
        cfg: &CheckedConfig,
        upto_iteration: usize,
    ) -> Result<Self, RunLogError> {
        if !path.exists() {
            tracing::warn!(path = %path.display(), "no run log to reopen; starting a new one");
            return Self::create(path, cfg);
        }
        let old = read(path)?;
        if let Some(why) = &old.truncated {
            tracing::warn!(path = %path.display(), why, "reopening a truncated run log");
        }
        let tmp = path.with_extension("mcap.reopen");
        let mut log = Self::open_writer(&tmp, LogOptions::of(cfg))?;
        let upto = upto_iteration as u64;
        let mut seen_iterations = HashSet::new();
        let mut kept_episodes = HashSet::new();
        let mut last_toml: Option<String> = None;
        let mut scene = old.scene.iter().peekable();
        for (i, entry) in old.records.iter().enumerate() {
            let keep = match &entry.record {
                Record::Config(c) => {
                    last_toml = Some(c.toml.clone());
                    true
                }
                Record::Metrics(m) => {
                    m.iteration >= 1
                        && u64::from(m.iteration) <= upto
                        && seen_iterations.insert(m.iteration)
                }
                Record::EvalEpisode(e) => {
                    let keep = !e.final_eval && u64::from(e.iteration) <= upto;
                    if keep {
                        kept_episodes.insert(e.episode);
                        log.next_episode = log.next_episode.max(e.episode + 1);
                    }
                    keep
                }
                Record::EvalStep(s) => kept_episodes.contains(&s.episode),
                Record::TrainingChunk(c) => u64::from(c.iteration) <= upto,
            };
            if keep {
                log.write_at(entry.log_time, &entry.record)?;
            }
            // A kept episode's robot: the scene messages written right after its
            // records, at their times.
            let drawn =
                keep && matches!(entry.record, Record::EvalEpisode(_) | Record::EvalStep(_));
            while let Some(m) = scene.next_if(|m| m.after <= i + 1) {
                if drawn && m.after == i + 1 && m.log_time == entry.log_time {
                    log.write_raw(log.scene_channels[m.topic], m.log_time, &m.data)?;
                }
            }
        }
        let cfg_record = config_record(cfg);
        if last_toml.as_deref() != Some(cfg_record.toml.as_str()) {
            log.record(&Record::Config(cfg_record))?;
        }
        log.flush()?;
        std::fs::rename(&tmp, path).map_err(|source| RunLogError::Io {
            path: path.to_path_buf(),
            what: "replacing the run log with its rewrite",
            source,
        })?;
        log.path = path.to_path_buf();
        Ok(log)
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes `rec` stamped with the current time.
    pub fn record(&mut self, rec: &Record) -> Result<(), RunLogError> {
        self.write_at(now_ns(), rec)
    }

    /// Writes `rec` with log time `log_time` (ns since the Unix epoch; raised to the
    /// last one written, so times never decrease).
    pub fn write_at(&mut self, log_time: u64, rec: &Record) -> Result<(), RunLogError> {
        self.write_raw(self.channels[rec.kind()], log_time, &rec.encode())
    }

    /// Writes encoded `data` on channel `channel_id` at `log_time` (raised to the last
    /// time written).
    fn write_raw(
        &mut self,
        channel_id: u16,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), RunLogError> {
        let t = log_time.max(self.last_time);
        self.last_time = t;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        let path = &self.path;
        let w = self.writer.as_mut().ok_or_else(|| RunLogError::Io {
            path: path.clone(),
            what: "writing after finish",
            source: std::io::Error::other("the run log is closed"),
        })?;
        w.write_to_known_channel(&header, data)
            .map_err(|source| RunLogError::Mcap {
                path: path.clone(),
                source: Box::new(source),
            })
    }

    /// Closes the current chunk and hands it to the OS, so that a killed process keeps
    /// everything written so far.
    pub fn flush(&mut self) -> Result<(), RunLogError> {
        if let Some(w) = self.writer.as_mut() {
            w.flush().map_err(|source| RunLogError::Mcap {
                path: self.path.clone(),
                source: Box::new(source),
            })?;
        }
        Ok(())
    }

    /// Logs one iteration's metrics on `/metrics` and flushes.
    pub fn iteration(&mut self, log: &IterationLog) -> Result<(), RunLogError> {
        self.record(&Record::Metrics(log.metrics()))?;
        self.flush()
    }

    /// Whether evaluation episodes of this kind are logged (`final_eval`: always;
    /// periodic ones only with `run.log_periodic_evals`).
    pub fn logs_episodes(&self, final_eval: bool) -> bool {
        final_eval || self.options.periodic_evals
    }

    /// Logs evaluation episodes of the policy of `iteration` (when
    /// [`RunLog::logs_episodes`]) on `/eval/episode` and `/eval/step`, with each
    /// episode's robot on `/scene` and `/tf` when `scene` gives the env's bodies and the
    /// episodes' poses (one [`scene::EpisodePoses`] per episode); flushes.
    pub fn eval_episodes(
        &mut self,
        iteration: usize,
        final_eval: bool,
        episodes: &[EvalEpisode],
        scene: Option<(&Scene, &[scene::EpisodePoses])>,
    ) -> Result<(), RunLogError> {
        if !self.logs_episodes(final_eval) {
            return Ok(());
        }
        for (i, ep) in episodes.iter().enumerate() {
            let id = self.next_episode;
            self.next_episode += 1;
            let t0 = now_ns().max(self.last_time.saturating_add(1));
            let drawn = scene.and_then(|(s, p)| Some((s, p.get(i)?)));
            // Steps `dt` apart, so playback runs at the simulation's speed.
            let dt = drawn.map_or(0, |(s, _)| (s.dt * 1e9) as u64);
            // Each step's record and the robot's poses after it at one time.
            let records = episode_records(id, iteration, final_eval, ep, &self.options);
            for (k, rec) in records.iter().enumerate() {
                let t = t0 + dt * k as u64;
                self.write_at(t, rec)?;
                if let Some((s, poses)) = drawn {
                    self.scene_at(s, poses, k, t, (id, ep.code))?;
                }
            }
        }
        self.flush()
    }

    /// One replayed episode's robot as a run log of its own: `config`'s `/config`
    /// record, then the bodies on `/scene` and their poses on `/tf`, stamped the env's
    /// step duration apart from now (what `ess replay --mcap` writes; Foxglove and
    /// Lichtblick play it, `ess replay` reads its config).
    pub fn write_scene_file(
        path: &Path,
        config: &ess_proto::pb::RunConfig,
        s: &Scene,
        poses: &scene::EpisodePoses,
        (episode, code): (u32, usize),
    ) -> Result<(), RunLogError> {
        let options = LogOptions {
            chunks_every: 0,
            chunk_steps: 0,
            periodic_evals: false,
            n_codes: config.n_modes as usize,
            one_hot: true,
        };
        let mut log = Self::open_writer(path, options)?;
        let t0 = now_ns();
        log.write_at(t0, &Record::Config(config.clone()))?;
        let dt = (s.dt * 1e9) as u64;
        for k in 0..poses.0.len() {
            log.scene_at(s, poses, k, t0 + dt * k as u64, (episode, code))?;
        }
        log.close()
    }

    /// An episode's robot at its `k`-th record (0: the start, with the `/scene`
    /// entities), time `t`.
    fn scene_at(
        &mut self,
        s: &Scene,
        poses: &scene::EpisodePoses,
        k: usize,
        t: u64,
        (id, code): (u32, usize),
    ) -> Result<(), RunLogError> {
        let [scene_ch, tf_ch] = self.scene_channels;
        if k == 0 {
            let up = scene::scene_update(s, t, id, code).encode_to_vec();
            self.write_raw(scene_ch, t, &up)?;
        }
        if let Some(p) = poses.0.get(k) {
            let tf = scene::transforms(s, p, t).encode_to_vec();
            self.write_raw(tf_ch, t, &tf)?;
        }
        Ok(())
    }

    /// Logs a sample of iteration `iteration`'s rollout `chunks` on `/train/chunk` when
    /// `run.log_chunks_every` asks for this iteration: the first `run.log_chunk_steps`
    /// steps of each chunk. `rewards` are the policy rewards of all chunks' steps in
    /// order (left out of the records when its length does not match).
    pub fn chunks(
        &mut self,
        iteration: usize,
        chunks: &[Chunk],
        rewards: &[f32],
    ) -> Result<(), RunLogError> {
        let every = self.options.chunks_every;
        if every == 0 || !iteration.is_multiple_of(every) {
            return Ok(());
        }
        let total: usize = chunks.iter().map(Chunk::len).sum();
        let rewards = (rewards.len() == total).then_some(rewards);
        let mut offset = 0;
        for (actor, c) in chunks.iter().enumerate() {
            let n = c.len().min(self.options.chunk_steps);
            let rec = chunk_record(
                iteration,
                actor,
                c,
                n,
                rewards.map(|r| &r[offset..offset + n]),
            );
            self.record(&Record::TrainingChunk(rec))?;
            offset += c.len();
        }
        Ok(())
    }

    /// Writes the summary section and footer and closes the file.
    pub fn finish(mut self) -> Result<(), RunLogError> {
        self.close()
    }

    fn close(&mut self) -> Result<(), RunLogError> {
        let Some(mut w) = self.writer.take() else {
            return Ok(());
        };
        w.finish().map_err(|source| RunLogError::Mcap {
            path: self.path.clone(),
            source: Box::new(source),
        })?;
        w.into_inner().flush().map_err(|source| RunLogError::Io {
            path: self.path.clone(),
            what: "writing the run log's summary",
            source,
        })
    }
}

/// Wall-clock nanoseconds since the Unix epoch.
fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// The mcap crate's error, with the OS error its I/O variant hides ("No space left on
/// device" rather than "I/O error from writing, or reading a compression stream").
fn mcap_reason(e: &mcap::McapError) -> String {
    match e {
        mcap::McapError::Io(io) => io.to_string(),
        other => other.to_string(),
    }
}

impl Drop for RunLog {
    /// Finishes the file on every path out of `train::run`, errors included.
    fn drop(&mut self) {
        if let Err(e) = self.close() {
            tracing::warn!("closing the run log: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ess_proto::pb;
    use proptest::prelude::*;

    fn opts() -> LogOptions {
        LogOptions {
            chunks_every: 1,
            chunk_steps: 8,
            periodic_evals: true,
            n_codes: 3,
            one_hot: true,
        }
    }

    fn floats(n: usize) -> impl Strategy<Value = Vec<f32>> {
        prop::collection::vec(-1e6f32..1e6, 0..n)
    }

    fn doubles(n: usize) -> impl Strategy<Value = Vec<f64>> {
        prop::collection::vec(-1e9f64..1e9, 0..n)
    }

    fn metrics() -> impl Strategy<Value = pb::IterationMetrics> {
        (
            any::<u32>(),
            any::<u64>(),
            prop::array::uniform16(-1e9f64..1e9),
            floats(6),
            prop::option::of(-1.0f64..2.0),
            prop::option::of(0.0f64..3.0),
            prop::option::of(-5.0f64..5.0),
        )
            .prop_map(|(iteration, env_steps, v, prior, nmi, ent, nr)| {
                pb::IterationMetrics {
                    iteration,
                    env_steps,
                    wall_s: v[0],
                    rollout_s: v[1],
                    disc_s: v[2],
                    ppo_s: v[3],
                    disc_bce: v[4],
                    d_acc_expert: v[5],
                    d_acc_policy: v[6],
                    qc_labeled: v[7],
                    qc_generated: v[8],
                    qeps: v[9],
                    rim_entropy: v[10],
                    rim_kl: v[11],
                    contrastive: v[12],
                    reward_mean: v[13],
                    policy_loss: v[14],
                    value_loss: v[15],
                    entropy: -v[0],
                    approx_kl: -v[1],
                    prior,
                    nmi,
                    ent,
                    normalized_reward: nr,
                }
            })
    }

    fn eval_step() -> impl Strategy<Value = pb::EvalStep> {
        (
            (any::<u32>(), any::<u32>(), any::<bool>(), -1f32..1.0),
            (floats(12), floats(4), floats(4), floats(5), floats(12)),
            doubles(40),
        )
            .prop_map(
                |((episode, step, done, eps), (obs, action, c, mode_rewards, next_obs), state)| {
                    pb::EvalStep {
                        episode,
                        step,
                        obs,
                        action,
                        c,
                        eps,
                        mode_rewards,
                        next_obs,
                        state,
                        done,
                    }
                },
            )
    }

    fn eval_episode() -> impl Strategy<Value = pb::EvalEpisode> {
        (
            (any::<u32>(), any::<u32>(), any::<bool>(), any::<u32>()),
            (-1f32..1.0, any::<u64>(), any::<u32>()),
            (doubles(40), floats(12), doubles(5)),
        )
            .prop_map(
                |(
                    (episode, iteration, final_eval, code),
                    (eps, reset_seed, length),
                    (start_state, start_obs, mode_returns),
                )| pb::EvalEpisode {
                    episode,
                    iteration,
                    final_eval,
                    code,
                    eps,
                    reset_seed,
                    start_state,
                    start_obs,
                    length,
                    mode_returns,
                    obs_dim: 12,
                    act_dim: 4,
                },
            )
    }

    fn training_chunk() -> impl Strategy<Value = pb::TrainingChunk> {
        (
            (any::<u32>(), any::<u64>(), any::<u32>(), any::<u32>()),
            (floats(64), floats(16), floats(16), floats(16)),
            (
                floats(8),
                floats(8),
                prop::collection::vec(any::<bool>(), 0..8),
            ),
            (floats(8), floats(64)),
        )
            .prop_map(
                |(
                    (iteration, policy_version, actor, len),
                    (obs, act, code, gumbel),
                    (eps, reward, done),
                    (logp, next_obs),
                )| pb::TrainingChunk {
                    iteration,
                    policy_version,
                    actor,
                    len,
                    obs_dim: 8,
                    act_dim: 2,
                    n_codes: 2,
                    obs,
                    act,
                    code,
                    gumbel,
                    eps,
                    reward,
                    done,
                    logp,
                    next_obs,
                },
            )
    }

    fn record() -> impl Strategy<Value = Record> {
        prop_oneof![
            metrics().prop_map(Record::Metrics),
            eval_step().prop_map(Record::EvalStep),
            eval_episode().prop_map(Record::EvalEpisode),
            training_chunk().prop_map(Record::TrainingChunk),
            ("[a-z =\n]{0,40}", any::<u64>()).prop_map(|(toml, seed)| Record::Config(
                pb::RunConfig {
                    toml,
                    method: "m".into(),
                    env: "traj2d".into(),
                    n_modes: 4,
                    seed,
                }
            )),
        ]
    }

    /// Writes `records` (log time = index) flushing after each group of `group`
    /// messages; returns the finished file's bytes and, per flush, (file length,
    /// messages written so far).
    fn write_file(dir: &Path, records: &[Record], group: usize) -> (Vec<u8>, Vec<(u64, usize)>) {
        let path = dir.join("run.mcap");
        let mut log = RunLog::open_writer(&path, opts()).unwrap();
        let mut flushed = Vec::new();
        for (i, r) in records.iter().enumerate() {
            log.write_at(i as u64, r).unwrap();
            if (i + 1) % group.max(1) == 0 {
                log.flush().unwrap();
                flushed.push((std::fs::metadata(&path).unwrap().len(), i + 1));
            }
        }
        log.finish().unwrap();
        (std::fs::read(&path).unwrap(), flushed)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        #[test]
        fn every_message_written_is_read_back_equal(
            records in prop::collection::vec(record(), 0..40),
            group in 1usize..10,
        ) {
            let dir = tempfile::tempdir().unwrap();
            let (bytes, _) = write_file(dir.path(), &records, group);
            let back = read_from(Path::new("mem"), bytes.as_slice()).unwrap();
            prop_assert_eq!(&back.truncated, &None);
            prop_assert_eq!(back.unknown, 0);
            let got: Vec<Record> = back.messages().cloned().collect();
            prop_assert_eq!(&got, &records);
            let times: Vec<u64> = back.records.iter().map(|l| l.log_time).collect();
            prop_assert_eq!(times, (0..records.len() as u64).collect::<Vec<_>>());
        }

        #[test]
        fn a_file_cut_anywhere_yields_its_complete_prefix(
            records in prop::collection::vec(record(), 1..30),
            group in 1usize..6,
            cuts in prop::collection::vec(0.0f64..1.0, 8),
        ) {
            let dir = tempfile::tempdir().unwrap();
            let (bytes, flushed) = write_file(dir.path(), &records, group);
            for f in cuts {
                let cut = ((bytes.len() as f64) * f) as usize;
                let back = read_from(Path::new("cut"), &bytes[..cut]).unwrap();
                let got: Vec<Record> = back.messages().cloned().collect();
                // Every message read is the one written at its place...
                prop_assert!(got.len() <= records.len());
                prop_assert_eq!(&got[..], &records[..got.len()]);
                // ...and every message flushed before the cut is there.
                let complete = flushed
                    .iter()
                    .filter(|(len, _)| *len as usize <= cut)
                    .map(|(_, n)| *n)
                    .max()
                    .unwrap_or(0);
                prop_assert!(got.len() >= complete, "cut {cut}: {} < {complete}", got.len());
                prop_assert!(back.truncated.is_some() || cut == bytes.len());
            }
        }
    }

    #[test]
    fn iteration_log_maps_every_field_into_iteration_metrics() {
        let l = IterationLog {
            iteration: 7,
            env_steps: 700,
            wall_s: 1.5,
            disc_bce: 0.6,
            rim_kl: 0.01,
            prior: "0.2500;0.7500".into(),
            nmi: Some(0.9),
            ..Default::default()
        };
        let m = l.metrics();
        assert_eq!((m.iteration, m.env_steps), (7, 700));
        assert_eq!((m.wall_s, m.disc_bce, m.rim_kl), (1.5, 0.6, 0.01));
        assert_eq!(m.prior, vec![0.25, 0.75]);
        assert_eq!((m.nmi, m.ent), (Some(0.9), None));
    }

    fn metrics_of(it: u32, nmi: Option<f64>) -> Record {
        Record::Metrics(pb::IterationMetrics {
            iteration: it,
            nmi,
            ..Default::default()
        })
    }

    fn episode_of(id: u32, it: u32, final_eval: bool) -> [Record; 2] {
        [
            Record::EvalEpisode(pb::EvalEpisode {
                episode: id,
                iteration: it,
                final_eval,
                length: 1,
                ..Default::default()
            }),
            Record::EvalStep(pb::EvalStep {
                episode: id,
                ..Default::default()
            }),
        ]
    }

    #[test]
    fn reopen_keeps_the_periodic_episodes_robot_and_drops_the_final_evaluations() {
        use ess_envs::scene::{Body, Pose, Scene};
        let mut b = ess_proto::config::ConfigBuilder::new();
        b.set("run.log_periodic_evals=true").unwrap();
        let cfg = b.build().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let scene = Scene {
            bodies: vec![
                Body {
                    name: "world".into(),
                    geoms: Vec::new(),
                },
                Body {
                    name: "torso".into(),
                    geoms: Vec::new(),
                },
            ],
            dt: 0.01,
        };
        let pose = |x: f64| Pose {
            pos: [x, 0.0, 0.0],
            quat: [1.0, 0.0, 0.0, 0.0],
        };
        // Two steps: the start and two poses, one transform set each.
        let ep = EvalEpisode {
            n_modes: 1,
            mode_rewards: vec![0.5, 0.5],
            obs: vec![0.0; 2],
            act: vec![0.0; 2],
            next_obs: vec![0.0; 2],
            start_obs: vec![0.0],
            ..Default::default()
        };
        let poses = |x: f64| scene::EpisodePoses(vec![vec![pose(0.0), pose(x)]; 3]);
        let mut log = RunLog::create(&path, &cfg).unwrap();
        let drawn = |x| (scene.clone(), vec![poses(x)]);
        let (s1, p1) = drawn(1.0);
        log.eval_episodes(1, false, std::slice::from_ref(&ep), Some((&s1, &p1)))
            .unwrap();
        log.iteration(&IterationLog {
            iteration: 1,
            ..Default::default()
        })
        .unwrap();
        let (s2, p2) = drawn(2.0);
        log.eval_episodes(2, true, std::slice::from_ref(&ep), Some((&s2, &p2)))
            .unwrap();
        log.finish().unwrap();
        let before = read(&path).unwrap();
        // Per episode: one /scene entity set and a transform set per record.
        assert_eq!(before.scene.len(), 2 * (1 + ep.len() + 1));

        RunLog::reopen(&path, &cfg, 1).unwrap().finish().unwrap();
        let after = read(&path).unwrap();
        let kept: Vec<&SceneMessage> = before.scene.iter().take(1 + ep.len() + 1).collect();
        assert_eq!(
            after.scene.len(),
            kept.len(),
            "the final evaluation's robot is gone"
        );
        for (a, b) in after.scene.iter().zip(kept) {
            assert_eq!(
                (a.topic, a.log_time, &a.data),
                (b.topic, b.log_time, &b.data)
            );
        }
    }

    #[test]
    fn reopen_keeps_iterations_up_to_the_checkpoint_and_drops_the_final_evaluation() {
        let cfg = ess_proto::config::ConfigBuilder::new().build().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let chunk = |it| {
            Record::TrainingChunk(pb::TrainingChunk {
                iteration: it,
                ..Default::default()
            })
        };
        let mut written = vec![Record::Config(config_record(&cfg))];
        for it in 1..=4 {
            written.push(chunk(it));
            written.push(metrics_of(it, None));
            if it % 2 == 0 {
                written.extend(episode_of(it / 2 - 1, it, false));
            }
        }
        // The interrupted run's final evaluation at iteration 4.
        written.extend(episode_of(2, 4, true));
        written.push(metrics_of(4, Some(0.5)));
        let mut log = RunLog::open_writer(&path, LogOptions::of(&cfg)).unwrap();
        for r in &written {
            log.record(r).unwrap();
        }
        // Killed: the file is left without its summary, cut inside the last chunk.
        log.flush().unwrap();
        let tail = metrics_of(5, None);
        log.record(&tail).unwrap();
        log.flush().unwrap();
        drop(log);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 60]).unwrap();

        let mut log = RunLog::reopen(&path, &cfg, 3).unwrap();
        log.iteration(&IterationLog {
            iteration: 4,
            ..Default::default()
        })
        .unwrap();
        log.eval_episodes(
            4,
            true,
            &[EvalEpisode {
                n_modes: 1,
                mode_rewards: vec![1.0],
                ..Default::default()
            }],
            None,
        )
        .unwrap();
        log.finish().unwrap();

        let back = read(&path).unwrap();
        assert_eq!(back.truncated, None);
        let got: Vec<Record> = back.messages().cloned().collect();
        let mut want: Vec<Record> = written[..1].to_vec();
        for it in 1..=3 {
            want.push(chunk(it));
            want.push(metrics_of(it, None));
            if it == 2 {
                want.extend(episode_of(0, 2, false));
            }
        }
        want.push(Record::Metrics(
            IterationLog {
                iteration: 4,
                ..Default::default()
            }
            .metrics(),
        ));
        assert_eq!(got[..want.len()], want[..]);
        // The new final evaluation continues the episode numbering after the kept one.
        match &got[want.len()] {
            Record::EvalEpisode(e) => assert_eq!((e.episode, e.final_eval), (1, true)),
            other => panic!("expected an episode, got {other:?}"),
        }
        assert_eq!(got.len(), want.len() + 2);
        assert!(!dir.path().join("run.mcap.reopen").exists());
    }

    #[test]
    fn a_file_that_is_not_mcap_is_refused_with_its_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("notes.mcap");
        std::fs::write(&path, "iteration,env_steps\n1,100\n").unwrap();
        let e = read(&path).unwrap_err();
        assert!(matches!(e, RunLogError::NotMcap { .. }), "{e}");
        assert!(e.to_string().contains("notes.mcap"), "{e}");
        let missing = dir.path().join("missing.mcap");
        let e = read(&missing).unwrap_err().to_string();
        assert!(e.contains("missing.mcap"), "{e}");
    }

    #[test]
    fn a_known_topic_with_a_foreign_schema_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("foreign.mcap");
        let mut w = mcap::Writer::new(BufWriter::new(File::create(&path).unwrap())).unwrap();
        let schema = w.add_schema("foo.Bar", "jsonschema", b"{}").unwrap();
        let ch = w
            .add_channel(schema, METRICS_TOPIC, "json", &BTreeMap::new())
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: 0,
                publish_time: 0,
            },
            b"{}",
        )
        .unwrap();
        w.finish().unwrap();
        drop(w);
        let e = read(&path).unwrap_err();
        assert!(matches!(e, RunLogError::WrongSchema { .. }), "{e}");
        let e = e.to_string();
        assert!(e.contains("foreign.mcap") && e.contains("foo.Bar"), "{e}");
    }

    #[test]
    fn channels_embed_the_protobuf_descriptor_set_as_schema() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let mut log = RunLog::open_writer(&path, opts()).unwrap();
        log.iteration(&IterationLog::default()).unwrap();
        log.finish().unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let summary = mcap::Summary::read(&bytes)
            .unwrap()
            .expect("a summary section");
        assert!(!summary.chunk_indexes.is_empty());
        assert_eq!(
            summary.chunk_indexes[0].compression, "zstd",
            "chunks are zstd-compressed"
        );
        let topics: Vec<(&str, &str)> = summary
            .channels
            .values()
            .map(|c| {
                let s = c.schema.as_ref().expect("schema");
                assert_eq!(
                    (s.encoding.as_str(), c.message_encoding.as_str()),
                    ("protobuf", "protobuf")
                );
                let scene = scene::SCENE_TOPICS.iter().any(|(t, _)| *t == c.topic);
                let fds = if scene {
                    ess_proto::FOXGLOVE_DESCRIPTOR_SET
                } else {
                    FILE_DESCRIPTOR_SET
                };
                assert_eq!(&s.data[..], fds, "{}", c.topic);
                (c.topic.as_str(), s.name.as_str())
            })
            .collect();
        for t in TOPICS.iter().chain(&scene::SCENE_TOPICS) {
            assert!(topics.contains(t), "{t:?} missing from {topics:?}");
        }
        // The schema names resolve in the embedded descriptor sets.
        let fds = prost_types_names(FILE_DESCRIPTOR_SET);
        for (_, name) in TOPICS {
            assert!(fds.contains(&name.to_string()), "{name} not in {fds:?}");
        }
        let fox = prost_types_names(ess_proto::FOXGLOVE_DESCRIPTOR_SET);
        for (_, name) in scene::SCENE_TOPICS {
            assert!(fox.contains(&name.to_string()), "{name} not in {fox:?}");
        }
    }

    /// Full names of the messages of an encoded `FileDescriptorSet`, decoded by hand
    /// (field 1: file; in a file, field 2: package, field 4: message_type; in a
    /// message, field 1: name).
    fn prost_types_names(fds: &[u8]) -> Vec<String> {
        #[derive(Clone, PartialEq, prost::Message)]
        struct Fds {
            #[prost(message, repeated, tag = "1")]
            file: Vec<Fdp>,
        }
        #[derive(Clone, PartialEq, prost::Message)]
        struct Fdp {
            #[prost(string, optional, tag = "2")]
            package: Option<String>,
            #[prost(message, repeated, tag = "4")]
            message_type: Vec<Dp>,
        }
        #[derive(Clone, PartialEq, prost::Message)]
        struct Dp {
            #[prost(string, optional, tag = "1")]
            name: Option<String>,
        }
        let set = Fds::decode(fds).unwrap();
        set.file
            .iter()
            .flat_map(|f| {
                f.message_type.iter().map(move |m| {
                    format!(
                        "{}.{}",
                        f.package.clone().unwrap_or_default(),
                        m.name.clone().unwrap_or_default()
                    )
                })
            })
            .collect()
    }
}
