//! An actor's [`WorkerState`] as `u64` words: what an actor process answers a
//! [`crate::shm::Request::SNAPSHOT`] with (one sample on the `chunks` service), and what
//! a restarted one reads back from the file `ess-actor --restore-state FILE` names. This
//! is how a checkpoint of a run with actor processes holds their mid-episode states, so
//! that its resume is bit-identical to a run never stopped.
//!
//! Layout: `[STATE_MAGIC, run_id_hash, actor, request_id, rng_seed (4 words),
//! rng_stream, rng_word_pos low, high, eps bits, in_episode, len(obs), len(code),
//! len(gumbel), len(env), obs…, code…, gumbel…, env…]`, one value per word (`f32` and
//! `f64` as their bits).

use crate::rollout::WorkerState;

/// First word of a state message.
pub const STATE_MAGIC: u64 = u64::from_le_bytes(*b"ESSSTATE");
/// Words before the arrays.
const HEAD: usize = 17;
/// Longest array accepted (a corrupt length must not allocate gigabytes).
const MAX_LEN: u64 = 1 << 24;

/// One actor's state, addressed.
#[derive(Debug, Clone, PartialEq)]
pub struct StateMsg {
    /// Hash of the run id ([`ess_proto::shm::run_id_hash`]).
    pub run_id_hash: u64,
    /// Actor index.
    pub actor: u32,
    /// The snapshot request it answers (0 in a restore file).
    pub request_id: u64,
    /// The state.
    pub state: WorkerState,
}

/// Words that are no state message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("not an actor state message: {0}")]
pub struct StateMsgError(String);

/// The message as words.
pub fn encode(m: &StateMsg) -> Vec<u64> {
    let s = &m.state;
    let mut w =
        Vec::with_capacity(HEAD + s.obs.len() + s.code.len() + s.gumbel.len() + s.env.len());
    w.extend([STATE_MAGIC, m.run_id_hash, u64::from(m.actor), m.request_id]);
    w.extend(s.rng_seed.chunks_exact(8).map(|c| {
        let mut b = [0u8; 8];
        b.copy_from_slice(c);
        u64::from_le_bytes(b)
    }));
    w.extend([
        s.rng_stream,
        s.rng_word_pos as u64,
        (s.rng_word_pos >> 64) as u64,
        u64::from(s.eps.to_bits()),
        u64::from(s.in_episode),
    ]);
    w.extend([s.obs.len(), s.code.len(), s.gumbel.len(), s.env.len()].map(|n| n as u64));
    for v in [&s.obs, &s.code, &s.gumbel] {
        w.extend(v.iter().map(|x| u64::from(x.to_bits())));
    }
    w.extend(s.env.iter().map(|x| x.to_bits()));
    w
}

/// Reads what [`encode`] wrote; every length is checked against the words there are.
pub fn decode(w: &[u64]) -> Result<StateMsg, StateMsgError> {
    let bad = |what: &str| StateMsgError(what.to_string());
    if w.len() < HEAD || w[0] != STATE_MAGIC {
        return Err(bad("no header"));
    }
    let lens = &w[13..17];
    if lens.iter().any(|&n| n > MAX_LEN) {
        return Err(bad("an array length is out of range"));
    }
    let total: u64 = lens.iter().sum();
    if w.len() as u64 != HEAD as u64 + total {
        return Err(bad(&format!("{} words for {total} values", w.len())));
    }
    let actor = u32::try_from(w[2]).map_err(|_| bad("actor index"))?;
    let eps = u32::try_from(w[11]).map_err(|_| bad("eps"))?;
    let in_episode = match w[12] {
        0 => false,
        1 => true,
        _ => return Err(bad("in_episode")),
    };
    let mut rng_seed = [0u8; 32];
    for (i, word) in w[4..8].iter().enumerate() {
        rng_seed[i * 8..i * 8 + 8].copy_from_slice(&word.to_le_bytes());
    }
    let mut at = HEAD;
    let mut take = |n: u64| {
        let s = &w[at..at + n as usize];
        at += n as usize;
        s
    };
    let f32s = |s: &[u64]| -> Result<Vec<f32>, StateMsgError> {
        s.iter()
            .map(|&x| {
                u32::try_from(x)
                    .map(f32::from_bits)
                    .map_err(|_| bad("an f32"))
            })
            .collect()
    };
    let obs = f32s(take(lens[0]))?;
    let code = f32s(take(lens[1]))?;
    let gumbel = f32s(take(lens[2]))?;
    let env = take(lens[3]).iter().map(|&x| f64::from_bits(x)).collect();
    Ok(StateMsg {
        run_id_hash: w[1],
        actor,
        request_id: w[3],
        state: WorkerState {
            rng_seed,
            rng_stream: w[8],
            rng_word_pos: u128::from(w[9]) | (u128::from(w[10]) << 64),
            obs,
            code,
            gumbel,
            eps: f32::from_bits(eps),
            in_episode,
            env,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg() -> StateMsg {
        StateMsg {
            run_id_hash: 0xABCD,
            actor: 3,
            request_id: 17,
            state: WorkerState {
                rng_seed: std::array::from_fn(|i| i as u8 * 7),
                rng_stream: 5,
                rng_word_pos: (9u128 << 64) | 12,
                obs: vec![0.5, -1.25, f32::MIN_POSITIVE],
                code: vec![0.0, 1.0],
                gumbel: vec![-0.3, 2.5],
                eps: -0.75,
                in_episode: true,
                env: vec![1e-300, -3.5, 0.0],
            },
        }
    }

    #[test]
    fn a_state_round_trips_bit_for_bit() {
        let m = msg();
        assert_eq!(decode(&encode(&m)), Ok(m));
    }

    #[test]
    fn cut_or_inconsistent_words_are_refused() {
        let w = encode(&msg());
        assert!(decode(&w[..w.len() - 1]).is_err());
        let mut bad = w.clone();
        bad[0] ^= 1;
        assert!(decode(&bad).is_err());
        let mut bad = w.clone();
        bad[14] = u64::MAX;
        assert!(decode(&bad).is_err());
        let mut bad = w;
        bad[12] = 2;
        assert!(decode(&bad).is_err());
    }
}
