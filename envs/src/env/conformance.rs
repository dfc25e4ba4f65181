//! The [`Env`] conformance suite. Every environment's tests call [`check_env`] with a
//! builder; it checks the contract the actors, demonstrations and evaluation rely on:
//! determinism per seed, finite observations of `obs_dim`, finite rewards of `n_modes`,
//! `terminated` vs `truncated` at `max_steps`, errors for stepping before reset or
//! after the end, and errors (not panics) for bad buffers and non-finite actions.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::env::{Env, EnvError, StepOutcome};

/// Builds a fresh env for one check.
pub(crate) type Build<'a> = &'a dyn Fn() -> Box<dyn Env>;

/// Rolls one episode with uniformly random actions; returns all observations (the
/// reset one first) and every step's outcome.
pub(crate) fn random_rollout(env: &mut dyn Env, seed: u64) -> (Vec<f32>, Vec<StepOutcome>) {
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    let mut act = vec![0.0; spec.act_dim];
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xabcdef);
    env.reset(seed, &mut obs).expect("reset");
    let mut all = obs.clone();
    let mut outcomes = Vec::new();
    loop {
        for a in &mut act {
            *a = rng.random_range(-1.0..=1.0);
        }
        let out = env.step(&act, &mut obs).expect("step");
        all.extend_from_slice(&obs);
        outcomes.push(out);
        if out.done() {
            break;
        }
    }
    (all, outcomes)
}

/// Runs every check of the suite on envs from `build`; `name` labels failures.
pub(crate) fn check_env(name: &str, build: Build) {
    same_seed_gives_the_same_trajectory(name, build);
    observations_and_rewards_are_finite(name, build);
    episodes_end_terminated_or_truncated_at_max_steps(name, build);
    stepping_after_the_episode_ended_is_an_error(name, build);
    stepping_before_reset_is_an_error(name, build);
    wrong_buffer_lengths_and_non_finite_actions_are_errors(name, build);
    a_restored_state_continues_bit_identically(name, build);
    states_that_do_not_fit_are_errors(name, build);
}

fn same_seed_gives_the_same_trajectory(name: &str, build: Build) {
    let (a, _) = random_rollout(build().as_mut(), 7);
    let (b, _) = random_rollout(build().as_mut(), 7);
    let (c, _) = random_rollout(build().as_mut(), 8);
    assert_eq!(a, b, "{name}: same seed, different trajectory");
    assert_ne!(a, c, "{name}: different seeds should differ");
    // Reusing one env gives the same as a fresh one.
    let mut env = build();
    random_rollout(env.as_mut(), 3);
    let (d, _) = random_rollout(env.as_mut(), 7);
    assert_eq!(a, d, "{name}: a reset does not fully restart the episode");
}

fn observations_and_rewards_are_finite(name: &str, build: Build) {
    let mut env = build();
    let spec = env.spec().clone();
    for seed in 0..3 {
        let (all, outcomes) = random_rollout(env.as_mut(), seed);
        assert_eq!(all.len(), (outcomes.len() + 1) * spec.obs_dim, "{name}");
        assert!(all.iter().all(|x| x.is_finite()), "{name}: non-finite obs");
        let mut r = vec![f32::NAN; spec.n_modes];
        env.mode_rewards(&mut r);
        assert!(r.iter().all(|x| x.is_finite()), "{name}: {r:?}");
        let mut t = vec![f32::NAN; spec.n_modes];
        env.task_rewards(&mut t);
        assert!(t.iter().all(|x| x.is_finite()), "{name}: {t:?}");
        if let Some(v) = env.forward_velocity() {
            assert!(v.is_finite(), "{name}: forward velocity {v}");
        }
    }
}

fn episodes_end_terminated_or_truncated_at_max_steps(name: &str, build: Build) {
    let mut env = build();
    let max = env.spec().max_steps;
    for seed in [11, 12, 13] {
        let (_, outcomes) = random_rollout(env.as_mut(), seed);
        let n = outcomes.len();
        assert!(n >= 1 && n <= max, "{name}: {n} steps, max_steps {max}");
        assert!(
            outcomes[..n - 1].iter().all(|o| !o.done()),
            "{name}: a step before the last reported done"
        );
        let last = outcomes[n - 1];
        assert!(
            last.terminated != last.truncated,
            "{name}: the last step must be exactly one of terminated / truncated: {last:?}"
        );
        if last.truncated {
            assert_eq!(n, max, "{name}: truncated before max_steps");
        }
    }
}

fn stepping_after_the_episode_ended_is_an_error(name: &str, build: Build) {
    let mut env = build();
    let spec = env.spec().clone();
    random_rollout(env.as_mut(), 1);
    let mut obs = vec![0.0; spec.obs_dim];
    let err = env.step(&vec![0.0; spec.act_dim], &mut obs).unwrap_err();
    assert!(
        matches!(err, EnvError::StepAfterDone { .. }),
        "{name}: {err}"
    );
    // A reset starts a fresh episode.
    env.reset(2, &mut obs).expect("reset");
    env.step(&vec![0.0; spec.act_dim], &mut obs)
        .expect("step after reset");
}

fn stepping_before_reset_is_an_error(name: &str, build: Build) {
    let mut env = build();
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    let err = env.step(&vec![0.0; spec.act_dim], &mut obs).unwrap_err();
    assert!(matches!(err, EnvError::NotReset), "{name}: {err}");
}

fn wrong_buffer_lengths_and_non_finite_actions_are_errors(name: &str, build: Build) {
    let mut env = build();
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    let err = env.reset(0, &mut vec![0.0; spec.obs_dim + 1]).unwrap_err();
    assert!(matches!(err, EnvError::BadObsLen { .. }), "{name}: {err}");
    env.reset(0, &mut obs).expect("reset");
    let err = env
        .step(&vec![0.0; spec.act_dim + 1], &mut obs)
        .unwrap_err();
    assert!(
        matches!(err, EnvError::BadActionLen { expected, got } if expected == spec.act_dim && got == spec.act_dim + 1),
        "{name}: {err}"
    );
    assert!(err.to_string().contains("act_dim"), "{err}");
    let err = env
        .step(&vec![f32::NAN; spec.act_dim], &mut obs)
        .unwrap_err();
    assert!(
        matches!(err, EnvError::NonFiniteAction { index: 0, .. }),
        "{name}: {err}"
    );
    let err = env
        .step(&vec![0.0; spec.act_dim], &mut vec![0.0; spec.obs_dim + 2])
        .unwrap_err();
    assert!(matches!(err, EnvError::BadObsLen { .. }), "{name}: {err}");
    // Failed steps do not consume the episode.
    env.step(&vec![0.0; spec.act_dim], &mut obs)
        .expect("valid step");
}

/// Steps `env` with random actions from `rng` until it is done or `limit` steps were
/// taken; returns every observation, outcome, per-mode eval and task reward and forward
/// velocity, for bitwise comparison.
fn trace(env: &mut dyn Env, rng: &mut ChaCha8Rng, limit: usize) -> Vec<String> {
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    let mut act = vec![0.0f32; spec.act_dim];
    let mut r = vec![0.0; spec.n_modes];
    let mut t = vec![0.0; spec.n_modes];
    let mut out = Vec::new();
    for _ in 0..limit {
        for a in &mut act {
            *a = rng.random_range(-1.0..=1.0);
        }
        let o = env.step(&act, &mut obs).expect("step");
        env.mode_rewards(&mut r);
        env.task_rewards(&mut t);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        out.push(format!(
            "{:?} {:?} {:?} {:?} {:?}",
            bits(&obs),
            o,
            bits(&r),
            bits(&t),
            env.forward_velocity().map(f64::to_bits)
        ));
        if o.done() {
            break;
        }
    }
    out
}

fn a_restored_state_continues_bit_identically(name: &str, build: Build) {
    let mut a = build();
    let spec = a.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    a.reset(5, &mut obs).expect("reset");
    let mut rng = ChaCha8Rng::seed_from_u64(55);
    let head = trace(a.as_mut(), &mut rng, 7);
    assert!(!head.is_empty(), "{name}");
    let saved = a.state();
    assert!(
        saved.iter().all(|x| x.is_finite()),
        "{name}: non-finite state"
    );
    // Into an env mid-way through another episode, and into one never reset.
    let mut b = build();
    b.reset(99, &mut obs).expect("reset");
    trace(b.as_mut(), &mut ChaCha8Rng::seed_from_u64(1), 3);
    b.set_state(&saved).expect("set_state");
    let mut c = build();
    c.set_state(&saved).expect("set_state on a fresh env");
    for (label, env) in [("mid-episode env", &b), ("fresh env", &c)] {
        assert_eq!(
            env.state(),
            saved,
            "{name}: {label}: state() after set_state"
        );
        let (mut ra, mut re) = (vec![0.0; spec.n_modes], vec![0.0; spec.n_modes]);
        a.mode_rewards(&mut ra);
        env.mode_rewards(&mut re);
        assert_eq!(ra, re, "{name}: {label}: rewards of the restored last step");
    }
    let tail_a = trace(a.as_mut(), &mut rng.clone(), spec.max_steps);
    let tail_b = trace(b.as_mut(), &mut rng.clone(), spec.max_steps);
    let tail_c = trace(c.as_mut(), &mut rng, spec.max_steps);
    assert_eq!(tail_a, tail_b, "{name}: restored mid-episode env diverged");
    assert_eq!(tail_a, tail_c, "{name}: restored fresh env diverged");
    // A finished episode's state restores as finished.
    let mut d = build();
    d.set_state(&a.state()).expect("set_state");
    let err = d.step(&vec![0.0; spec.act_dim], &mut obs).unwrap_err();
    assert!(
        matches!(err, EnvError::StepAfterDone { .. }),
        "{name}: {err}"
    );
}

fn states_that_do_not_fit_are_errors(name: &str, build: Build) {
    let mut env = build();
    let spec = env.spec().clone();
    let mut obs = vec![0.0; spec.obs_dim];
    env.reset(3, &mut obs).expect("reset");
    let good = env.state();
    let mut longer = good.clone();
    longer.push(0.0);
    let mut nan = good.clone();
    nan[0] = f64::NAN;
    for (what, bad) in [
        ("short", &good[..good.len() - 1]),
        ("long", &longer[..]),
        ("NaN", &nan[..]),
        ("empty", &[][..]),
    ] {
        let err = build().set_state(bad).unwrap_err();
        assert!(
            matches!(&err, EnvError::BadState { env, .. } if *env == spec.name),
            "{name}: {what}: {err}"
        );
    }
    // A refused state leaves the env as it was.
    let _ = env.set_state(&nan);
    assert_eq!(env.state(), good, "{name}: a refused state changed the env");
}

/// A bad-config case: the field, and how it spoils the default config.
pub(crate) type BadParamCase<C> = (&'static str, fn(&mut C));

/// Asserts that building from each case's config fails with [`EnvError::BadParam`]
/// naming the case's field, in the variant and in the message.
pub(crate) fn assert_bad_params<C: Default, T>(
    build: impl Fn(C) -> Result<T, EnvError>,
    cases: &[BadParamCase<C>],
) {
    for (field, spoil) in cases {
        let mut cfg = C::default();
        spoil(&mut cfg);
        let Err(err) = build(cfg) else {
            panic!("{field}: a bad config was accepted");
        };
        assert!(
            matches!(err, EnvError::BadParam { field: f, .. } if f == *field),
            "{field}: {err}"
        );
        assert!(err.to_string().contains(field), "{err}");
    }
}

/// Asserts that `from_mjcf` turns a malformed MJCF string into [`EnvError::Model`] with
/// our prefix, then MuJoCo's own parse message.
pub(crate) fn assert_malformed_mjcf<T>(from_mjcf: impl Fn(&str) -> Result<T, EnvError>) {
    let Err(err) = from_mjcf("<mujoco><worldbody><body>") else {
        panic!("a malformed MJCF string was accepted");
    };
    assert!(matches!(err, EnvError::Model { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.starts_with("invalid MJCF model: ") && msg.len() > 30,
        "{msg}"
    );
}

/// Asserts that `from_mjcf` rejects each case's MJCF with [`EnvError::Model`] whose
/// message contains the case's text (what is wrong with the model).
pub(crate) fn assert_wrong_shape_mjcf<T>(
    from_mjcf: impl Fn(&str) -> Result<T, EnvError>,
    cases: &[(String, &str)],
) {
    for (xml, want) in cases {
        let Err(err) = from_mjcf(xml) else {
            panic!("{want}: a model of the wrong shape was accepted");
        };
        assert!(matches!(err, EnvError::Model { .. }), "{want}: {err}");
        assert!(err.to_string().contains(want), "{want}: {err}");
    }
}

/// Runs `episodes` episodes of random controls (uniform on even seeds, bang-bang
/// +-1 on odd ones) to their end: every observation stays finite and `warnings(env)`
/// (the env's MuJoCo warning counters) stays all zero.
pub(crate) fn assert_random_controls_raise_no_warning<E: Env>(
    env: &mut E,
    episodes: u64,
    warnings: impl Fn(&E) -> Vec<i32>,
) {
    let (obs_dim, act_dim) = (env.spec().obs_dim, env.spec().act_dim);
    let mut obs = vec![0.0; obs_dim];
    let mut a = vec![0.0f32; act_dim];
    for ep in 0..episodes {
        let mut rng = ChaCha8Rng::seed_from_u64(ep);
        env.reset(ep, &mut obs).expect("reset");
        loop {
            for x in a.iter_mut() {
                *x = if ep % 2 == 0 {
                    rng.random_range(-1.0..=1.0)
                } else if rng.random::<bool>() {
                    1.0
                } else {
                    -1.0
                };
            }
            let out = env.step(&a, &mut obs).expect("step raises no warning");
            assert!(obs.iter().all(|x| x.is_finite()));
            if out.done() {
                break;
            }
        }
        assert!(warnings(env).iter().all(|&n| n == 0), "episode {ep}");
    }
}
