//! The seed inputs of each target, made with Ess's own writers (so they are what Ess
//! really reads) and written to `fuzz/corpus/<target>/seed-*` by `ess-fuzz-seeds`.
//! The run log seeds are real runs' `run.mcap` files, copied in (see `bench/fuzz.md`).

use anyhow::{Context, Result};
use ess_proto::chunk::Chunk;
use ess_proto::config::{ConfigBuilder, LatentPrior};
use ess_proto::shm::{self, ShmChunkHeader, ShmChunkWriter, ShmEpisodeHeader, WeightsMsg};
use std::path::Path;

/// `(target, seed name, bytes)` of every in-memory seed.
pub fn all() -> Result<Vec<(&'static str, String, Vec<u8>)>> {
    let mut out = Vec::new();
    for (name, text) in configs()? {
        out.push(("config", name, text.into_bytes()));
    }
    let task = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/tasks/arm3/task.toml");
    out.push(("task_file", "arm3".into(), std::fs::read(&task)?));
    out.push(("demos", "traj2d".into(), demos()?));
    out.push(("shm", "chunk".into(), with_kind(0, chunk()?)));
    out.push(("shm", "weights".into(), with_kind(1, weights()?)));
    out.push(("shm", "episode".into(), with_kind(2, episode()?)));
    out.push(("shm", "state".into(), with_kind(3, actor_state())));
    for (name, spec) in job_specs() {
        out.push(("job_spec", name, spec));
    }
    Ok(out)
}

fn configs() -> Result<Vec<(String, String)>> {
    let default = ConfigBuilder::new().build()?.to_toml();
    let mut out = vec![("default".to_string(), default)];
    for (name, text) in ess_learner::presets::PRESETS {
        out.push((format!("preset-{name}"), text.to_string()));
    }
    out.push((
        "sets".into(),
        format!(
            "[run]\niterations = 3\n{}\nenv.name=reacher\nmethod.rim_weight=0.5\nrun.actors=0\n",
            crate::SET_MARKER
        ),
    ));
    Ok(out)
}

fn demos() -> Result<Vec<u8>> {
    let spec = ess_envs::demos::DemoSpec {
        env: "traj2d".into(),
        n_modes: 4,
        label_ratio: 0.05,
        imbalance_ratio: 2.0,
        majority_episodes: 1,
        seed: 1,
    };
    let d = ess_envs::demos::generate_demos(&spec)?;
    let dir = std::env::temp_dir().join(format!("ess-fuzz-seed-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("demos.safetensors");
    d.save(&path)?;
    let bytes = std::fs::read(&path)?;
    std::fs::remove_dir_all(&dir)?;
    Ok(bytes)
}

fn with_kind(kind: u8, mut body: Vec<u8>) -> Vec<u8> {
    body.insert(0, kind);
    body
}

fn chunk() -> Result<Vec<u8>> {
    let (obs, act, codes, len) = (3, 2, 4, 2);
    let mut c = Chunk::with_capacity(obs, act, codes, len);
    let ramp = |n: usize| (0..n).map(|i| i as f32 * 0.25 - 1.0).collect::<Vec<_>>();
    c.obs = ramp(len * obs);
    c.next_obs = ramp(len * obs);
    c.pre_tanh = ramp(len * act);
    c.act = ramp(len * act);
    c.logp = ramp(len);
    c.code = ramp(len * codes);
    c.gumbel = ramp(len * codes);
    c.eps = ramp(len);
    c.terminated = vec![false, true];
    c.truncated = vec![false, false];
    c.env_reward = ramp(len);
    c.policy_version = 7;
    let header = ShmChunkHeader {
        run_id_hash: shm::run_id_hash("fuzz"),
        len: len as u64,
        obs_dim: obs as u32,
        act_dim: act as u32,
        n_codes: codes as u32,
        policy_version: 7,
        ..Default::default()
    };
    let layout = shm::ShmChunkLayout::new(obs, act, codes, len);
    let mut words = vec![0u64; layout.words()];
    ShmChunkWriter::new(bytemuck::cast_slice_mut(&mut words), header)?.write_chunk(&c)?;
    Ok(bytemuck::cast_slice(&words).to_vec())
}

fn weights() -> Result<Vec<u8>> {
    let w = WeightsMsg {
        run_id_hash: shm::run_id_hash("fuzz"),
        version: 3,
        sizes: vec![3, 4, 2],
        params: (0..(3 * 4 + 4 + 4 * 2 + 2))
            .map(|i| i as f32 / 10.0)
            .collect(),
        log_std: vec![-0.5, -0.5],
        prior_logits: vec![0.0; 4],
        obs_mean: vec![0.0; 3],
        obs_std: vec![1.0; 3],
        prior: LatentPrior::Gumbel,
        tau: 0.5,
        use_eps: true,
    };
    let mut words = vec![0u64; w.bytes() / 8];
    shm::write_weights(bytemuck::cast_slice_mut(&mut words), &w)?;
    Ok(bytemuck::cast_slice(&words).to_vec())
}

fn episode() -> Result<Vec<u8>> {
    let l = shm::ShmEpisodeLayout {
        obs_dim: 2,
        act_dim: 1,
        n_modes: 2,
        state_dim: 2,
        len: 2,
    };
    let header = ShmEpisodeHeader {
        len: l.len as u64,
        obs_dim: l.obs_dim as u32,
        act_dim: l.act_dim as u32,
        n_modes: l.n_modes as u32,
        state_dim: l.state_dim as u32,
        ..Default::default()
    };
    let e = shm::EpisodeArrays {
        start_state: vec![0.1, 0.2],
        states: vec![0.3, 0.4, 0.5, 0.6],
        start_obs: vec![1.0, 2.0],
        obs: vec![1.0, 2.0, 3.0, 4.0],
        act: vec![0.5, -0.5],
        next_obs: vec![3.0, 4.0, 5.0, 6.0],
        mode_rewards: vec![1.0, 0.0, 0.0, 1.0],
    };
    let mut words = vec![0u64; l.words()];
    shm::write_episode(bytemuck::cast_slice_mut(&mut words), header, &e)?;
    Ok(bytemuck::cast_slice(&words).to_vec())
}

fn actor_state() -> Vec<u8> {
    use ess_actor::state_msg::{StateMsg, encode};
    let m = StateMsg {
        run_id_hash: shm::run_id_hash("fuzz"),
        actor: 1,
        request_id: 5,
        state: ess_actor::WorkerState {
            rng_seed: [7; 32],
            rng_stream: 2,
            rng_word_pos: 1234,
            obs: vec![0.5, -0.5],
            code: vec![0.0, 1.0],
            gumbel: vec![0.1, -0.2],
            eps: 0.25,
            in_episode: true,
            env: vec![1.0, 2.0, 3.0],
        },
    };
    bytemuck::cast_slice(&encode(&m)).to_vec()
}

fn job_specs() -> Vec<(String, Vec<u8>)> {
    use ess_proto::pb::{JobSpec, Override};
    use prost::Message;
    let spec = |preset: &str, env: &str, overrides: &[(&str, &str)], config: &str| JobSpec {
        preset: preset.into(),
        env: env.into(),
        config_toml: config.into(),
        overrides: overrides
            .iter()
            .map(|(k, v)| Override {
                key: (*k).into(),
                value: (*v).into(),
            })
            .collect(),
        ..Default::default()
    };
    vec![
        ("plain".into(), spec("ess-infogail", "traj2d", &[], "")),
        (
            "overrides".into(),
            spec(
                "gail",
                "reacher",
                &[("run.iterations", "2"), ("run.transport", "\"threads\"")],
                "[run]\nactors = 1\n",
            ),
        ),
    ]
    .into_iter()
    .map(|(n, s)| (n, s.encode_to_vec()))
    .collect()
}

/// Writes every seed into `dir/<target>/seed-<name>`, and each of `run_logs` (real
/// run logs) as `dir/runlog/seed-<file name>`.
pub fn write(dir: &Path, run_logs: &[std::path::PathBuf]) -> Result<usize> {
    let mut n = 0;
    for (target, name, bytes) in all()? {
        let d = dir.join(target);
        std::fs::create_dir_all(&d)?;
        std::fs::write(d.join(format!("seed-{name}")), bytes)?;
        n += 1;
    }
    for log in run_logs {
        let d = dir.join("runlog");
        std::fs::create_dir_all(&d)?;
        let name = log
            .file_name()
            .context("a run log path ends in a file name")?;
        let to = d.join(format!("seed-{}", name.to_string_lossy()));
        std::fs::copy(log, to).with_context(|| log.display().to_string())?;
        n += 1;
    }
    Ok(n)
}
