//! Round trips and refusals of every layout.

use super::chunk::HEADER_BYTES;
use super::*;
use crate::chunk::{Chunk, Step};
use crate::config::LatentPrior;
use proptest::prelude::*;

/// An 8-aligned byte buffer of `bytes` (rounded up to 8).
fn aligned(bytes: usize) -> Vec<u64> {
    vec![0u64; bytes.div_ceil(8)]
}

fn arb_chunk() -> impl Strategy<Value = (Chunk, u64, u32, u64)> {
    (0usize..6, 1usize..4, 0usize..5, 0usize..20).prop_flat_map(|(od, ad, k, n)| {
        let f = |m: usize| proptest::collection::vec(any::<f32>(), m);
        let b = |m: usize| proptest::collection::vec(any::<bool>(), m);
        (
            (f(n * od), f(n * od), f(n * ad), f(n * ad), f(n)),
            (f(n * k), f(n * k), f(n), b(n), b(n), f(n)),
            any::<u64>(),
            any::<u64>(),
            any::<u32>(),
            any::<u64>(),
        )
            .prop_map(
                move |(
                    (obs, next_obs, pre_tanh, act, logp),
                    (code, gumbel, eps, terminated, truncated, env_reward),
                    version,
                    run,
                    actor,
                    req,
                )| {
                    (
                        Chunk {
                            policy_version: version,
                            obs_dim: od,
                            act_dim: ad,
                            n_codes: k,
                            obs,
                            next_obs,
                            pre_tanh,
                            act,
                            logp,
                            code,
                            gumbel,
                            eps,
                            terminated,
                            truncated,
                            env_reward,
                        },
                        run,
                        actor,
                        req,
                    )
                },
            )
    })
}

/// Bitwise equality, so NaNs of any payload count as round-tripped.
fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same(a: &Chunk, b: &Chunk) {
    assert_eq!(
        (a.policy_version, a.obs_dim, a.act_dim, a.n_codes),
        (b.policy_version, b.obs_dim, b.act_dim, b.n_codes)
    );
    for (x, y) in [
        (&a.obs, &b.obs),
        (&a.next_obs, &b.next_obs),
        (&a.pre_tanh, &b.pre_tanh),
        (&a.act, &b.act),
        (&a.logp, &b.logp),
        (&a.code, &b.code),
        (&a.gumbel, &b.gumbel),
        (&a.eps, &b.eps),
        (&a.env_reward, &b.env_reward),
    ] {
        assert_eq!(bits(x), bits(y));
    }
    assert_eq!(a.terminated, b.terminated);
    assert_eq!(a.truncated, b.truncated);
}

proptest! {
    #[test]
    fn chunk_roundtrip_preserves_every_field((c, run, actor, req) in arb_chunk()) {
        let layout = ShmChunkLayout::new(c.obs_dim, c.act_dim, c.n_codes, c.len());
        let mut words = aligned(layout.bytes());
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
        let header = ShmChunkHeader {
            run_id_hash: run,
            actor,
            request_id: req,
            policy_version: c.policy_version,
            len: c.len() as u64,
            obs_dim: c.obs_dim as u32,
            act_dim: c.act_dim as u32,
            n_codes: c.n_codes as u32,
            ..Default::default()
        };
        let mut w = ShmChunkWriter::new(buf, header).unwrap();
        w.write_chunk(&c).unwrap();
        prop_assert!(w.is_complete());
        let (h, back) = read_chunk(bytemuck::cast_slice(&words)).unwrap();
        prop_assert_eq!(h.run_id_hash, run);
        prop_assert_eq!(h.actor, actor);
        prop_assert_eq!(h.request_id, req);
        prop_assert_eq!(h.len, c.len() as u64);
        assert_same(&c, &back);
    }

    #[test]
    fn weights_roundtrip_preserves_every_field(
        sizes in proptest::collection::vec(1usize..6, 2..5),
        k in 0usize..4,
        act in 1usize..3,
        version: u64,
        run: u64,
        tau: f32,
        use_eps: bool,
        prior in 0u32..3,
        seed: u32,
    ) {
        let f = |n: usize, s: u32| (0..n).map(|i| (i as f32) * 0.5 - s as f32).collect::<Vec<f32>>();
        let od = 3;
        let n_params: usize = sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum();
        let w = WeightsMsg {
            run_id_hash: run,
            version,
            params: f(n_params, seed),
            log_std: f(act, seed ^ 1),
            prior_logits: f(k, seed ^ 2),
            obs_mean: f(od, seed ^ 3),
            obs_std: f(od, seed ^ 4),
            sizes,
            prior: [LatentPrior::None, LatentPrior::Uniform, LatentPrior::Gumbel][prior as usize],
            tau,
            use_eps,
        };
        let mut words = aligned(w.bytes());
        write_weights(bytemuck::cast_slice_mut(&mut words), &w).unwrap();
        let back = read_weights(bytemuck::cast_slice(&words)).unwrap();
        prop_assert_eq!(bits(&[back.tau]), bits(&[w.tau]));
        let (mut a, mut b) = (back.clone(), w.clone());
        a.tau = 0.0;
        b.tau = 0.0;
        prop_assert_eq!(a, b);
    }
}

#[test]
fn short_misaligned_or_foreign_buffers_are_refused_naming_why() {
    let mut words = aligned(256);
    let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
    assert!(matches!(
        read_chunk(buf),
        Err(ShmError::BadHeader { what: "chunk", .. })
    ));
    let header = ShmChunkHeader {
        len: 100,
        obs_dim: 4,
        act_dim: 1,
        n_codes: 2,
        ..Default::default()
    };
    assert!(matches!(
        ShmChunkWriter::new(buf, header),
        Err(ShmError::TooShort { what: "chunk", .. })
    ));
    assert!(matches!(
        ShmChunkWriter::new(&mut buf[1..], header),
        Err(ShmError::Misaligned { what: "chunk" })
    ));
    let header = ShmChunkHeader { len: 1, ..header };
    let mut w = ShmChunkWriter::new(buf, header).unwrap();
    let z = [0.0f32; 4];
    let step = Step {
        obs: &z,
        next_obs: &z,
        pre_tanh: &z[..1],
        act: &z[..1],
        logp: 0.0,
        code: &z[..2],
        gumbel: &z[..2],
        eps: 0.0,
        terminated: false,
        truncated: true,
        env_reward: 0.0,
    };
    let short = Step {
        obs: &z[..3],
        ..step
    };
    assert!(matches!(
        w.try_push(&short),
        Err(ShmError::BadField { field: "obs", .. })
    ));
    w.try_push(&step).unwrap();
    assert_eq!(w.try_push(&step), Err(ShmError::Full { capacity: 1 }));
    // A header claiming more steps than the buffer holds is refused, not over-read.
    let h: &mut ShmChunkHeader = bytemuck::from_bytes_mut(&mut buf[..HEADER_BYTES]);
    h.len = 1_000;
    assert!(matches!(
        read_chunk(buf),
        Err(ShmError::TooShort { what: "chunk", .. })
    ));
}

#[test]
fn episode_roundtrip_preserves_every_field_and_refuses_chunks() {
    let (od, ad, nm, n) = (3, 2, 4, 7);
    let f = |m: usize, s: f32| (0..m).map(|i| i as f32 * 0.25 - s).collect::<Vec<f32>>();
    let sd = 5;
    let e = EpisodeArrays {
        start_state: (0..sd).map(|i| i as f64 * 0.1 + 1e-12).collect(),
        states: (0..n * sd).map(|i| -(i as f64) * 0.3).collect(),
        start_obs: f(od, 0.5),
        obs: f(n * od, 1.0),
        act: f(n * ad, 2.0),
        next_obs: f(n * od, 3.0),
        mode_rewards: f(n * nm, 4.0),
    };
    let h = ShmEpisodeHeader {
        run_id_hash: 9,
        actor: 2,
        code: 3,
        request_id: 5,
        policy_version: 6,
        job: 11,
        len: n as u64,
        obs_dim: od as u32,
        act_dim: ad as u32,
        n_modes: nm as u32,
        eps_bits: 0.5f32.to_bits(),
        state_dim: sd as u32,
        ..Default::default()
    };
    let l = ShmEpisodeLayout {
        obs_dim: od,
        act_dim: ad,
        n_modes: nm,
        state_dim: sd,
        len: n,
    };
    let mut words = aligned(l.bytes());
    let short = l.bytes() - 8;
    assert!(matches!(
        write_episode(&mut bytemuck::cast_slice_mut(&mut words)[..short], h, &e),
        Err(ShmError::TooShort {
            what: "episode",
            ..
        })
    ));
    write_episode(bytemuck::cast_slice_mut(&mut words), h, &e).unwrap();
    let (h2, back) = read_episode(bytemuck::cast_slice(&words)).unwrap();
    assert_eq!(
        (h2.job, h2.code, h2.eps_bits, h2.len),
        (11, 3, h.eps_bits, 7)
    );
    assert_eq!(back, e);
    // A chunk is not an episode, and an episode is not a chunk.
    assert!(matches!(
        read_chunk(bytemuck::cast_slice(&words)),
        Err(ShmError::BadHeader { .. })
    ));
    assert!(matches!(
        read_episode(&bytemuck::cast_slice::<u64, u8>(&words)[..l.bytes() - 8]),
        Err(ShmError::TooShort { .. })
    ));
}

#[test]
fn run_id_hash_differs_between_runs() {
    assert_ne!(run_id_hash("123-a"), run_id_hash("123-b"));
}
