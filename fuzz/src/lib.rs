//! Fuzz targets: one function per parser of input Ess does not control, each taking
//! arbitrary bytes. A target returns normally for every input the parser refuses with
//! an error, and panics only when a property a caller relies on breaks:
//!
//! | target      | parser                                              | what is checked beyond "no panic"                               |
//! |-------------|-----------------------------------------------------|-----------------------------------------------------------------|
//! | `config`    | config TOML and `--set` (`ess_proto::config`)       | errors are one line; a built config round-trips through TOML    |
//! | `task_file` | a task file's TOML (`ess_envs::task::TaskFile`)     | errors are one line                                             |
//! | `demos`     | demonstration files (`ess_envs::demos::Demos`)      | errors are one line; array lengths agree with the header        |
//! | `runlog`    | the MCAP run log reader and replay (`ess_learner::runlog`) | errors are one line; listed episodes replay or refuse    |
//! | `shm`       | shared-memory chunk, weights, episode and actor-state messages | a message read back re-encodes to the same message   |
//! | `job_spec`  | a gRPC `JobSpec` as the server decodes and validates it | errors are one line; an accepted spec's config re-parses   |
//!
//! Two drivers share these functions (so what CI replays is what the fuzzer ran):
//! `fuzz/libfuzzer`, a cargo-fuzz package for coverage-guided runs on a nightly
//! toolchain (`make fuzz`, `bench/fuzz.md`), and [`mutate`], the stable, deterministic
//! replay-and-mutate run that `make test` does: every file of `fuzz/corpus/<target>/`
//! (the seeds and every input a fuzzer ever found a bug with), then a few thousand
//! random mutations of them. The mutation run has no coverage guidance; it keeps the
//! targets and their seeds honest between the long runs.

use std::path::Path;

pub mod mutate;
pub mod seeds;

/// A fuzz target: consumes arbitrary bytes, panics only on a broken property.
pub type Target = fn(&[u8]);

/// Every target by name (the names of `fuzz/corpus/` and `fuzz/libfuzzer/fuzz_targets`).
pub const TARGETS: [(&str, Target); 6] = [
    ("config", config),
    ("task_file", task_file),
    ("demos", demos),
    ("runlog", runlog),
    ("shm", shm),
    ("job_spec", job_spec),
];

/// Panics unless `err` displays as one line: Ess reports bad input in one line.
fn one_line(what: &str, err: &dyn std::fmt::Display) {
    let msg = err.to_string();
    assert!(
        !msg.contains('\n') && !msg.trim().is_empty(),
        "{what}: the error is not one line: {msg:?}"
    );
}

/// The line of a config input that starts its `--set` overrides (one per line).
pub const SET_MARKER: &str = "#--set";

/// Config TOML, then after a [`SET_MARKER`] line `key=value` overrides as `--set`
/// takes them; a config that builds must build again, identically, from its own TOML
/// (the run directory's `config.toml` is read back that way on resume).
pub fn config(data: &[u8]) {
    use ess_proto::config::{ConfigBuilder, EnvLayer};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (toml, sets) = text.split_once(SET_MARKER).unwrap_or((text, ""));
    if let Err(e) = EnvLayer::parse("fuzz.toml", toml) {
        one_line("env layer", &e);
    }
    let mut b = ConfigBuilder::new();
    if let Err(e) = b.merge_toml("fuzz.toml", toml) {
        return one_line("config", &e);
    }
    for line in sets.lines().filter(|l| !l.is_empty()) {
        if let Err(e) = b.set(line) {
            return one_line("--set", &e);
        }
    }
    let cfg = match b.build() {
        Ok(cfg) => cfg,
        Err(e) => return one_line("config", &e),
    };
    let written = cfg.to_toml();
    let mut again = ConfigBuilder::new();
    let reread = again
        .merge_toml("config.toml", &written)
        .and_then(|b| b.build())
        .unwrap_or_else(|e| panic!("a built config does not re-read: {e}\n{written}"));
    assert_eq!(reread.to_toml(), written, "a config changed on re-reading");
}

/// A task file's text (no MJCF model is loaded).
pub fn task_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Err(e) = ess_envs::TaskFile::parse(Path::new("fuzz/task.toml"), text) {
        one_line("task file", &e);
    }
}

/// A demonstration file's bytes; what loads has arrays as long as its header says.
pub fn demos(data: &[u8]) {
    let d = match ess_envs::demos::Demos::from_bytes(data, Path::new("fuzz.safetensors")) {
        Ok(d) => d,
        Err(e) => return one_line("demos", &e),
    };
    let m = &d.meta;
    for s in [&d.unlabeled, &d.labeled] {
        let n = s.len();
        assert_eq!(s.obs.len(), n * m.obs_dim);
        assert_eq!(s.next_obs.len(), n * m.obs_dim);
        assert_eq!(s.act.len(), n * m.act_dim);
        assert_eq!((s.episode.len(), s.reward.len()), (n, n));
        assert!(s.mode.iter().all(|&k| (k as usize) < m.n_modes));
    }
}

/// A run log's bytes, read as `ess replay` reads it; its first listed episode replayed.
pub fn runlog(data: &[u8]) {
    use ess_learner::runlog::{self, replay};
    let path = Path::new("fuzz.mcap");
    let contents = match runlog::read_from(path, data) {
        Ok(c) => c,
        Err(e) => return one_line("run log", &e),
    };
    let rec = match replay::recording(path, contents) {
        Ok(r) => r,
        Err(e) => return one_line("recording", &e),
    };
    if let Some(first) = replay::list(&rec).first()
        && let Err(e) = replay::replay(&rec, first.episode)
    {
        one_line("replay", &e);
    }
}

/// Shared-memory messages: the first byte picks chunk, weights, episode or actor
/// state; the rest is the buffer (copied to 8-byte alignment, as a loaned sample is).
pub fn shm(data: &[u8]) {
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    let mut words = vec![0u64; body.len().div_ceil(8)];
    let buf = &mut bytemuck_bytes(&mut words)[..body.len()];
    buf.copy_from_slice(body);
    match kind % 4 {
        0 => shm_chunk(buf),
        1 => shm_weights(buf),
        2 => shm_episode(buf),
        _ => actor_state(&words[..body.len() / 8]),
    }
}

fn bytemuck_bytes(words: &mut [u64]) -> &mut [u8] {
    bytemuck::cast_slice_mut(words)
}

/// Equal as their `Debug` text: a message holding NaN equals itself.
fn same<T: std::fmt::Debug>(what: &str, a: &T, b: &T) {
    let (a, b) = (format!("{a:?}"), format!("{b:?}"));
    assert!(a == b, "{what} changed on re-encoding:\n{a}\n{b}");
}

fn shm_chunk(buf: &[u8]) {
    use ess_proto::shm::{ShmChunkWriter, read_chunk};
    let (h, c) = match read_chunk(buf) {
        Ok(x) => x,
        Err(e) => return one_line("chunk", &e),
    };
    let mut again = vec![0u64; buf.len().div_ceil(8)];
    let out = &mut bytemuck_bytes(&mut again)[..buf.len()];
    let mut w = ShmChunkWriter::new(out, h).expect("a header that was read lays out");
    w.write_chunk(&c)
        .expect("a chunk that was read is written back");
    let (h2, c2) = read_chunk(out).expect("a chunk written back reads");
    same("chunk", &(h2, c2), &(h, c));
}

fn shm_weights(buf: &[u8]) {
    use ess_proto::shm::{read_weights, write_weights};
    let w = match read_weights(buf) {
        Ok(w) => w,
        Err(e) => return one_line("weights", &e),
    };
    let mut again = vec![0u64; w.bytes() / 8];
    write_weights(bytemuck_bytes(&mut again), &w).expect("weights read are written back");
    let w2 = read_weights(bytemuck_bytes(&mut again)).expect("weights written back read");
    same("weights", &w2, &w);
}

fn shm_episode(buf: &[u8]) {
    use ess_proto::shm::{read_episode, write_episode};
    let (h, e) = match read_episode(buf) {
        Ok(x) => x,
        Err(e) => return one_line("episode", &e),
    };
    let mut again = vec![0u64; buf.len().div_ceil(8)];
    let out = &mut bytemuck_bytes(&mut again)[..buf.len()];
    write_episode(out, h, &e).expect("an episode read is written back");
    let (h2, e2) = read_episode(out).expect("an episode written back reads");
    same("episode", &(h2, e2), &(h, e));
}

fn actor_state(words: &[u64]) {
    use ess_actor::state_msg::{decode, encode};
    match decode(words) {
        Ok(m) => assert_eq!(encode(&m), words, "an actor state re-encodes differently"),
        Err(e) => one_line("actor state", &e),
    }
}

/// A `JobSpec` as `ess serve` receives it: protobuf bytes, decoded and validated.
pub fn job_spec(data: &[u8]) {
    use prost::Message;
    let Ok(spec) = ess_proto::pb::JobSpec::decode(data) else {
        return;
    };
    match ess_learner::control::jobs::validate(&spec, 2) {
        Ok(v) => {
            let toml = v.config_toml();
            ess_proto::config::ConfigBuilder::new()
                .merge_toml("job config.toml", toml)
                .and_then(|b| b.build())
                .unwrap_or_else(|e| panic!("an accepted job's config does not re-read: {e}"));
        }
        Err(e) => one_line("job spec", &e),
    }
}
