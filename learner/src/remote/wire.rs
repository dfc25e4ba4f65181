//! What travels between the learner and an actor host over zenoh: key expressions and
//! the three requests a host answers. Chunks and weights keep the byte layouts of the
//! shared-memory services ([`ess_proto::shm`]: fixed little-endian headers, checked on
//! read), so a remote chunk is read by the same code as a local one; the assignment is
//! JSON (once per host and run).

use ess_actor::LatentSpec;
use ess_proto::Chunk;
use ess_proto::config::LatentPrior;
use ess_proto::shm::{
    ShmChunkHeader, ShmChunkLayout, ShmChunkWriter, ShmError, WeightsMsg, read_chunk, read_weights,
    write_weights,
};
use serde::{Deserialize, Serialize};

/// The learner's liveliness token: hosts stop their actors when it goes.
pub const LEARNER_TOKEN: &str = "ess/learner";
/// Every host's liveliness token, for the learner's subscriber.
pub const HOST_TOKENS: &str = "ess/hosts/*/actors/*";

/// A host's liveliness token, `ess/hosts/<name>/actors/<n>`: its name and actor count.
pub fn host_token(name: &str, actors: usize) -> String {
    format!("ess/hosts/{name}/actors/{actors}")
}

/// `(name, actors)` of a host token.
pub fn parse_host_token(key: &str) -> Option<(String, usize)> {
    let rest = key.strip_prefix("ess/hosts/")?;
    let (name, n) = rest.split_once("/actors/")?;
    Some((name.to_owned(), n.parse().ok().filter(|&n| n >= 1)?))
}

/// The key a host answers requests on.
pub fn rpc_key(name: &str) -> String {
    format!("ess/hosts/{name}/rpc")
}

/// A host's part of the run: what its actor processes need to start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Assign {
    /// The learner's run id (logs).
    pub run: String,
    /// Env name and modes.
    pub env: String,
    /// Env modes.
    pub n_modes: usize,
    /// Build envs without experts (task files).
    pub plain_env: bool,
    /// Latent prior, codes, temperature, whether eps is fed.
    pub prior: LatentPrior,
    /// Number of codes K.
    pub n_codes: usize,
    /// Gumbel-softmax temperature.
    pub tau: f32,
    /// Whether eps is fed.
    pub use_eps: bool,
    /// Global index of the host's first actor.
    pub first_actor: usize,
    /// One seed per actor (the learner's `actor_seed` of its global index).
    pub seeds: Vec<u64>,
    /// Most steps one request asks of one actor.
    pub max_steps: usize,
    /// An actor silent this long is restarted by its host.
    pub actor_timeout_s: f64,
}

impl Assign {
    /// The latent spec the host's actors sample (c, eps) with.
    pub fn latent(&self) -> LatentSpec {
        LatentSpec {
            prior: self.prior,
            n_codes: self.n_codes,
            tau: self.tau,
            use_eps: self.use_eps,
        }
    }
}

/// A request to a host.
#[derive(Debug, Clone, PartialEq)]
pub enum Rpc {
    /// Start the actors for this run.
    Assign(Assign),
    /// Collect `steps` under the weights; answer one chunk per actor.
    Collect {
        /// Steps over all of the host's actors.
        steps: u64,
        /// Stamped into every chunk's header.
        request_id: u64,
        /// The policy (and latent spec) to act with.
        weights: WeightsMsg,
    },
    /// The run is over: stop the actors.
    Stop,
}

const ASSIGN: u64 = 1;
const COLLECT: u64 = 2;
const STOP: u64 = 3;

/// A request that is not one.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    /// Too short, unknown kind, bad JSON.
    #[error("malformed request: {0}")]
    Malformed(String),
    /// A layout refused by [`ess_proto::shm`].
    #[error(transparent)]
    Layout(#[from] ShmError),
}

/// `words` as bytes (little-endian: the layouts are defined on x86_64 and aarch64 alike).
fn bytes_of(words: &[u64]) -> Vec<u8> {
    bytemuck::cast_slice(words).to_vec()
}

/// `bytes` copied into 8-byte aligned words (what the layout readers require).
fn aligned(bytes: &[u8]) -> Vec<u64> {
    let mut w = vec![0u64; bytes.len().div_ceil(8)];
    bytemuck::cast_slice_mut::<u64, u8>(&mut w)[..bytes.len()].copy_from_slice(bytes);
    w
}

impl Rpc {
    /// The request as bytes: a u64 kind, then its body.
    pub fn encode(&self) -> Result<Vec<u8>, WireError> {
        match self {
            Rpc::Assign(a) => {
                let mut out = ASSIGN.to_le_bytes().to_vec();
                out.extend(serde_json::to_vec(a).map_err(|e| WireError::Malformed(e.to_string()))?);
                Ok(out)
            }
            Rpc::Collect {
                steps,
                request_id,
                weights,
            } => {
                let mut w = vec![0u64; 3 + weights.bytes() / 8];
                w[..3].copy_from_slice(&[COLLECT, *steps, *request_id]);
                write_weights(bytemuck::cast_slice_mut(&mut w[3..]), weights)?;
                Ok(bytes_of(&w))
            }
            Rpc::Stop => Ok(STOP.to_le_bytes().to_vec()),
        }
    }

    /// Reads a request, checked.
    pub fn decode(bytes: &[u8]) -> Result<Rpc, WireError> {
        let w = aligned(bytes);
        let kind = *w
            .first()
            .ok_or_else(|| WireError::Malformed("empty".into()))?;
        match kind {
            ASSIGN => serde_json::from_slice(&bytes[8..])
                .map(Rpc::Assign)
                .map_err(|e| WireError::Malformed(format!("assignment: {e}"))),
            COLLECT if w.len() > 3 => Ok(Rpc::Collect {
                steps: w[1],
                request_id: w[2],
                weights: read_weights(&bytemuck::cast_slice(&w[3..])[..bytes.len() - 24])?,
            }),
            STOP => Ok(Rpc::Stop),
            k => Err(WireError::Malformed(format!("kind {k}"))),
        }
    }
}

/// One chunk in the `chunks` service's layout, with `header`'s actor, request and
/// version (its dims and length are the chunk's).
pub fn encode_chunk(c: &Chunk, header: ShmChunkHeader) -> Result<Vec<u8>, ShmError> {
    let layout = ShmChunkLayout::new(c.obs_dim, c.act_dim, c.n_codes, c.len());
    let mut w = vec![0u64; layout.words()];
    let header = ShmChunkHeader {
        len: c.len() as u64,
        obs_dim: c.obs_dim as u32,
        act_dim: c.act_dim as u32,
        n_codes: c.n_codes as u32,
        ..header
    };
    ShmChunkWriter::new(bytemuck::cast_slice_mut(&mut w), header)?.write_chunk(c)?;
    Ok(bytes_of(&w))
}

/// Reads a chunk sent by [`encode_chunk`], checked as a shared-memory one.
pub fn decode_chunk(bytes: &[u8]) -> Result<(ShmChunkHeader, Chunk), ShmError> {
    let w = aligned(bytes);
    read_chunk(&bytemuck::cast_slice(&w)[..bytes.len()])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn weights() -> WeightsMsg {
        WeightsMsg {
            run_id_hash: 7,
            version: 3,
            sizes: vec![4, 2],
            params: (0..10).map(|i| i as f32).collect(),
            log_std: vec![-0.5; 2],
            prior_logits: vec![0.0; 2],
            obs_mean: vec![0.0; 1],
            obs_std: vec![1.0; 1],
            prior: LatentPrior::Gumbel,
            tau: 0.5,
            use_eps: true,
        }
    }

    #[test]
    fn requests_round_trip_and_garbage_is_refused() {
        let collect = Rpc::Collect {
            steps: 1234,
            request_id: 9,
            weights: weights(),
        };
        // From an odd offset too: zenoh's buffers carry no alignment.
        let mut odd = vec![0u8];
        odd.extend(collect.encode().unwrap());
        assert_eq!(Rpc::decode(&odd[1..]).unwrap(), collect);
        assert_eq!(
            Rpc::decode(&Rpc::Stop.encode().unwrap()).unwrap(),
            Rpc::Stop
        );
        for bad in [
            &[][..],
            &[9, 0, 0, 0, 0, 0, 0, 0][..],
            &[1, 0, 0, 0, 0, 0, 0, 0, b'{'][..],
        ] {
            assert!(Rpc::decode(bad).is_err(), "{bad:?}");
        }
        let mut cut = collect.encode().unwrap();
        cut.truncate(cut.len() - 8);
        assert!(Rpc::decode(&cut).is_err());
    }

    #[test]
    fn a_chunk_round_trips_in_the_shared_memory_layout() {
        let mut c = Chunk::with_capacity(2, 1, 2, 3);
        for t in 0..3 {
            let f = t as f32;
            c.obs.extend([f, -f]);
            c.next_obs.extend([f + 1.0, -f]);
            c.pre_tanh.push(0.1 * f);
            c.act.push((0.1 * f).tanh());
            c.logp.push(-f);
            c.code.extend([1.0, 0.0]);
            c.gumbel.extend([0.3, 0.7]);
            c.eps.push(0.5);
            c.terminated.push(t == 2);
            c.truncated.push(false);
            c.env_reward.push(f);
        }
        let h = ShmChunkHeader {
            run_id_hash: 7,
            actor: 5,
            request_id: 2,
            policy_version: 3,
            ..Default::default()
        };
        let bytes = encode_chunk(&c, h).unwrap();
        let (got_h, got) = decode_chunk(&bytes).unwrap();
        assert_eq!((got_h.actor, got_h.len, got_h.request_id), (5, 3, 2));
        assert_eq!(got.obs, c.obs);
        assert_eq!(got.terminated, c.terminated);
        assert!(decode_chunk(&bytes[..bytes.len() - 8]).is_err());
    }
}
