//! SAC's replay buffer: a ring of raw transitions (only the observation entries the
//! networks read), saved on stop and loaded on `--resume`, and the normalised gather a
//! minibatch is drawn with.

use crate::train::nets::tensor_2d;
use anyhow::{Context, Result, bail};
use std::collections::HashMap;
use std::path::Path;
use tch::{Kind, Tensor};

/// Transitions, raw observations (the first `od` entries: the prefix the networks
/// read), in a ring.
pub(super) struct Replay {
    pub(super) od: usize,
    pub(super) ad: usize,
    pub(super) cap: usize,
    pub(super) len: usize,
    pub(super) next: usize,
    pub(super) obs: Vec<f32>,
    pub(super) next_obs: Vec<f32>,
    pub(super) act: Vec<f32>,
    pub(super) rew: Vec<f32>,
    /// 1 where the transition did not end in a terminal state.
    pub(super) live: Vec<f32>,
}

impl Replay {
    pub(super) fn new(cap: usize, od: usize, ad: usize) -> Self {
        Self {
            od,
            ad,
            cap,
            len: 0,
            next: 0,
            obs: vec![0.0; cap * od],
            next_obs: vec![0.0; cap * od],
            act: vec![0.0; cap * ad],
            rew: vec![0.0; cap],
            live: vec![0.0; cap],
        }
    }

    pub(super) fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        rew: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (i, od, ad) = (self.next, self.od, self.ad);
        self.obs[i * od..(i + 1) * od].copy_from_slice(obs);
        self.next_obs[i * od..(i + 1) * od].copy_from_slice(next_obs);
        self.act[i * ad..(i + 1) * ad].copy_from_slice(act);
        self.rew[i] = rew;
        self.live[i] = if terminated { 0.0 } else { 1.0 };
        self.next = (i + 1) % self.cap;
        self.len = (self.len + 1).min(self.cap);
    }

    /// Index of the `back`-th newest transition (0: the newest).
    pub(super) fn newest(&self, back: usize) -> usize {
        (self.next + self.cap - 1 - back) % self.cap
    }

    /// Writes the filled rows and the ring position to `path` (via a temporary file, so
    /// a stop mid-write leaves the old file), tagged with the run's `env_steps`.
    pub(super) fn save(&self, path: &Path, env_steps: u64) -> Result<()> {
        let n = self.len;
        let rows = |v: &[f32], w: usize| Tensor::from_slice(&v[..n * w]).view([n as i64, w as i64]);
        let meta = [self.cap, self.next, self.od, self.ad, env_steps as usize].map(|v| v as i64);
        let named = [
            ("meta", Tensor::from_slice(&meta)),
            ("obs", rows(&self.obs, self.od)),
            ("next_obs", rows(&self.next_obs, self.od)),
            ("act", rows(&self.act, self.ad)),
            ("rew", rows(&self.rew, 1)),
            ("live", rows(&self.live, 1)),
        ];
        write_via_tmp(&named, path, "SAC replay")
    }

    /// Reads what [`Replay::save`] wrote, for a run with capacity `cap`, `od` observed
    /// entries and `ad` action entries; returns it and the `env_steps` it was saved at.
    /// A file of another shape is refused naming the file, the field and both values.
    pub(super) fn load(path: &Path, cap: usize, od: usize, ad: usize) -> Result<(Self, u64)> {
        let what = || format!("SAC replay {}", path.display());
        let tensors = read_named(path, &what())?;
        let get = |name: &str| {
            tensors
                .get(name)
                .with_context(|| format!("{}: no tensor {name}", what()))
        };
        let meta = Vec::<i64>::try_from(get("meta")?)
            .ok()
            .filter(|m| m.len() == 5 && m.iter().all(|&v| v >= 0))
            .with_context(|| format!("{}: meta is not 5 non-negative integers", what()))?;
        let [fcap, next, fod, fad, steps] = [meta[0], meta[1], meta[2], meta[3], meta[4]];
        let hint =
            "(resume with the settings it was saved with, or delete the file to refill the buffer)";
        for (field, file, run) in [
            ("sac.buffer", fcap, cap),
            ("observed entries (sac.obs_prefix)", fod, od),
            ("action entries", fad, ad),
        ] {
            if file as usize != run {
                bail!(
                    "{}: {field} is {file} there, {run} in this run {hint}",
                    what()
                );
            }
        }
        let mut r = Self::new(cap, od, ad);
        let rows = get("rew")?.size().first().copied().unwrap_or(-1);
        if rows < 0 || rows as usize > cap || next as usize >= cap.max(1) {
            bail!(
                "{}: {rows} rows, ring position {next}, capacity {cap}",
                what()
            );
        }
        let n = rows as usize;
        if n < cap && next as usize != n {
            bail!(
                "{}: a ring of {n} < {cap} rows must continue at {n}, not {next}",
                what()
            );
        }
        for (name, dst, w) in [
            ("obs", &mut r.obs, od),
            ("next_obs", &mut r.next_obs, od),
            ("act", &mut r.act, ad),
            ("rew", &mut r.rew, 1),
            ("live", &mut r.live, 1),
        ] {
            let t = get(name)?;
            if t.size() != [n as i64, w as i64] || t.kind() != Kind::Float {
                bail!(
                    "{}: {name} is {:?} {:?}, expected [{n}, {w}] Float",
                    what(),
                    t.kind(),
                    t.size()
                );
            }
            let v = Vec::<f32>::try_from(&t.flatten(0, -1))
                .with_context(|| format!("{}: reading {name}", what()))?;
            dst[..n * w].copy_from_slice(&v);
        }
        r.len = n;
        r.next = next as usize;
        Ok((r, steps as u64))
    }
}

/// Normalises the first `p` entries of rows of `od` floats at `idx` of `src`.
pub(super) fn gather_norm(
    src: &[f32],
    od: usize,
    p: usize,
    idx: &[usize],
    mean: &[f32],
    std: &[f32],
) -> Tensor {
    let mut v = Vec::with_capacity(idx.len() * p);
    for &i in idx {
        let row = &src[i * od..i * od + p];
        v.extend(row.iter().zip(mean).zip(std).map(|((x, m), s)| (x - m) / s));
    }
    tensor_2d(&v, p)
}

/// Writes `named` to `path` atomically and with checksums ([`crate::tensor_file`]), so a
/// stop mid-write leaves the old file; errors name `what` and the file.
pub(super) fn write_via_tmp<S: AsRef<str>>(
    named: &[(S, Tensor)],
    path: &Path,
    what: &str,
) -> Result<()> {
    crate::tensor_file::save(path, named, HashMap::new()).with_context(|| format!("writing {what}"))
}

/// Every tensor of the safetensors file at `path` by name, checked against its
/// checksums; an error says "reading `what`".
pub(super) fn read_named(path: &Path, what: &str) -> Result<HashMap<String, Tensor>> {
    Ok(crate::tensor_file::load(path)
        .with_context(|| format!("reading {what}"))?
        .0)
}
