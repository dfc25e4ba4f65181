//! The env registry: every env file exports one [`EnvEntry`] (its name and how to build
//! it, [`crate::env::Build`]) and this file lists them. The env files depend on the
//! [`Env`] trait alone (`crate::env`), never on each other or on this list.
//!
//! Adding a task is one file plus one line here: write `mytask.rs` with a type that
//! implements [`Env`] (and [`ScriptedExpert`] if its experts are scripted), end it
//! with
//!
//! ```ignore
//! pub const ENTRY: EnvEntry = EnvEntry {
//!     name: "mytask",
//!     build: Build::Trained(|n_modes| Ok(Box::new(MyTask::new(n_modes)?))),
//! };
//! ```
//!
//! declare `pub mod mytask;` in `lib.rs`, and add `mytask::ENTRY` to [`ENVS`]. A user's
//! own MJCF task needs none of this: `task:PATH` ([`crate::task`]).

use crate::env::{Build, Env, EnvEntry, EnvError, ScriptedExpert};
use crate::{humanoid, pusher, reacher, traj2d, walker2d};

/// Every built-in env, in the order `--help` and errors list them.
pub const ENVS: &[EnvEntry] = &[
    traj2d::ENTRY,
    reacher::ENTRY,
    pusher::ENTRY,
    walker2d::ENTRY,
    humanoid::ENTRY,
];

/// The names of every built-in env.
pub fn known_envs() -> impl Iterator<Item = &'static str> {
    ENVS.iter().map(|e| e.name)
}

/// The entry named `name`, or [`EnvError::UnknownEnv`] listing the known ones.
fn entry(name: &str) -> Result<&'static EnvEntry, EnvError> {
    ENVS.iter()
        .find(|e| e.name == name)
        .ok_or_else(|| EnvError::UnknownEnv {
            name: name.to_owned(),
            known: known_envs().collect::<Vec<_>>().join(", "),
        })
}

/// Builds an env with an expert for every mode by name: `"traj2d"` and `"reacher"` have
/// scripted experts; the others are driven by their trained experts from
/// [`crate::experts_dir`] ([`crate::ExpertEnv`]). `n_modes` is the requested number of
/// behaviour modes: traj2d supports exactly 4, reacher 2 to 12 (targets); anything else
/// is [`EnvError::BadParam`] naming `n_modes`. Missing or unfit expert files are
/// [`EnvError::NoScriptedExpert`] naming the file; an unknown name is
/// [`EnvError::UnknownEnv`], listing the known ones.
pub fn make_env(name: &str, n_modes: usize) -> Result<Box<dyn ScriptedExpert>, EnvError> {
    make_env_in(name, n_modes, &crate::experts_dir())
}

/// [`make_env`] with trained experts looked up under `experts_dir`.
pub fn make_env_in(
    name: &str,
    n_modes: usize,
    experts_dir: &std::path::Path,
) -> Result<Box<dyn ScriptedExpert>, EnvError> {
    if crate::task::task_path(name).is_some() {
        return Err(EnvError::NoScriptedExpert {
            name: name.to_owned(),
            reason: "a task file has no expert; train it from imported demonstrations \
                     (`demos.path`, see `ess demos import`)"
                .into(),
        });
    }
    match entry(name)?.build {
        Build::Scripted(build) => build(n_modes),
        Build::Trained(build) => {
            let env = crate::ExpertEnv::load(build(n_modes)?, experts_dir).map_err(|e| {
                EnvError::NoScriptedExpert {
                    name: name.to_owned(),
                    reason: e.to_string(),
                }
            })?;
            Ok(Box::new(env))
        }
    }
}

/// The env as training, its actors and replay step it: a built-in env as [`make_env`]
/// builds it (with its experts, whose wrapper's state differs from the plain env's), a
/// task file (`task:PATH`, [`crate::task`]) as a plain env, since it has no expert.
pub fn make_training_env(name: &str, n_modes: usize) -> Result<Box<dyn Env>, EnvError> {
    if crate::task::task_path(name).is_some() {
        make_plain_env(name, n_modes)
    } else {
        Ok(make_env(name, n_modes)?)
    }
}

/// Builds any known env by name as a plain [`Env`] (no expert), with its default
/// configuration, or a user's task file named `task:PATH` ([`crate::task`]): traj2d
/// (exactly 4 modes), reacher (2 to 12), pusher (2 to 6 goals), walker2d and humanoid
/// (exactly 3: forward, backward, balance). A bad `n_modes` is [`EnvError::BadParam`]
/// naming it; an unknown name is [`EnvError::UnknownEnv`].
pub fn make_plain_env(name: &str, n_modes: usize) -> Result<Box<dyn Env>, EnvError> {
    if let Some(path) = crate::task::task_path(name) {
        return Ok(Box::new(crate::task::TaskEnv::load(path, n_modes)?));
    }
    match entry(name)?.build {
        Build::Scripted(build) => Ok(build(n_modes)?),
        Build::Trained(build) => build(n_modes),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::conformance::check_env;
    use crate::env::{Env, EnvError};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// Every (name, n_modes) built through `make_env` that the suite runs against.
    const ALL_ENVS: &[(&str, usize)] = &[
        ("traj2d", 4),
        ("reacher", 2),
        ("reacher", 6),
        ("pusher", 6),
        ("walker2d", 3),
        ("humanoid", 3),
    ];

    #[test]
    fn every_make_env_env_passes_the_conformance_suite() {
        for &(name, k) in ALL_ENVS {
            check_env(name, &|| {
                let env: Box<dyn Env> = make_env(name, k).expect("known env builds");
                env
            });
        }
    }

    #[test]
    fn expert_rejects_an_out_of_range_mode() {
        for &(name, k) in ALL_ENVS {
            let mut env = make_env(name, k).expect("env");
            let spec = env.spec().clone();
            let mut obs = vec![0.0; spec.obs_dim];
            env.reset(0, &mut obs).expect("reset");
            let mut rng = ChaCha8Rng::seed_from_u64(0);
            let mut act = vec![0.0; spec.act_dim];
            let err = env.expert_action(k, &mut rng, &mut act).unwrap_err();
            assert!(
                matches!(err, EnvError::ModeOutOfRange { mode, n_modes } if mode == k && n_modes == k),
                "{name}: {err}"
            );
        }
    }

    #[test]
    fn make_env_lists_known_envs_for_an_unknown_name() {
        let err = make_env("cartpole", 2).err().expect("unknown env");
        let msg = err.to_string();
        assert!(msg.contains("cartpole") && msg.contains("traj2d"), "{msg}");
    }

    #[test]
    fn make_env_rejects_an_unsupported_mode_count() {
        let err = make_env("traj2d", 6).err().expect("bad n_modes");
        assert!(
            matches!(
                err,
                EnvError::BadParam {
                    field: "n_modes",
                    ..
                }
            ),
            "{err}"
        );
        assert!(err.to_string().contains("n_modes = 6"), "{err}");
        for k in [1, 13] {
            let err = make_env("reacher", k).err().expect("bad n_modes");
            assert!(err.to_string().contains(&format!("n_modes = {k}")), "{err}");
        }
    }

    #[test]
    fn make_plain_env_builds_every_known_env() {
        for (name, k) in [
            ("traj2d", 4),
            ("reacher", 6),
            ("walker2d", 3),
            ("humanoid", 3),
        ] {
            let env = make_plain_env(name, k).expect(name);
            assert_eq!((env.spec().name.as_str(), env.spec().n_modes), (name, k));
            assert!(known_envs().any(|n| n == name), "{name}");
        }
        let err = make_plain_env("cartpole", 3).err().expect("unknown env");
        assert!(matches!(err, EnvError::UnknownEnv { .. }), "{err}");
    }

    #[test]
    fn make_plain_env_rejects_a_locomotion_mode_count_other_than_three() {
        for k in [0, 2, 4] {
            for name in ["walker2d", "humanoid"] {
                let err = make_plain_env(name, k).err().expect("bad n_modes");
                assert!(
                    matches!(
                        err,
                        EnvError::BadParam {
                            field: "n_modes",
                            ..
                        }
                    ),
                    "{err}"
                );
                assert!(err.to_string().contains(&format!("n_modes = {k}")), "{err}");
            }
        }
    }

    #[test]
    fn make_env_builds_reacher_with_the_requested_number_of_targets() {
        for k in 2..=12 {
            let env = make_env("reacher", k).expect("reacher");
            assert_eq!(env.spec().n_modes, k);
            assert_eq!(env.spec().name, "reacher");
        }
    }

    #[test]
    fn make_env_without_trained_experts_names_the_missing_file() {
        let dir = tempfile::tempdir().expect("tmp");
        for (env, k) in [("pusher", 6), ("walker2d", 3), ("humanoid", 3)] {
            let err = make_env_in(env, k, dir.path()).err().expect("no expert");
            assert!(
                matches!(&err, EnvError::NoScriptedExpert { name, .. } if name == env),
                "{err}"
            );
            let msg = err.to_string();
            assert!(
                msg.contains("mode0.safetensors")
                    && msg.contains(&format!("ess experts train --env {env}")),
                "{msg}"
            );
        }
    }

    #[test]
    fn make_plain_env_builds_every_known_env_including_pusher() {
        for (name, k) in [("traj2d", 4), ("reacher", 6), ("pusher", 6), ("pusher", 2)] {
            assert!(known_envs().any(|n| n == name));
            let env = make_plain_env(name, k).expect("known env builds");
            assert_eq!((env.spec().name.as_str(), env.spec().n_modes), (name, k));
        }
        check_env("pusher via make_plain_env", &|| {
            make_plain_env("pusher", 6).expect("pusher")
        });
    }

    #[test]
    fn make_plain_env_validates_names_and_mode_counts() {
        for k in [1, 7] {
            let err = make_plain_env("pusher", k).err().expect("bad n_modes");
            assert!(
                matches!(
                    err,
                    EnvError::BadParam {
                        field: "n_modes",
                        ..
                    }
                ),
                "{err}"
            );
        }
        let err = make_plain_env("traj2d", 6).err().expect("bad n_modes");
        assert!(err.to_string().contains("n_modes = 6"), "{err}");
        let err = make_plain_env("cartpole", 2).err().expect("unknown env");
        assert!(matches!(err, EnvError::UnknownEnv { .. }), "{err}");
        assert!(err.to_string().contains("pusher"), "{err}");
    }
}
