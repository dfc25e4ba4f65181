//! Checking a job spec before it queues: it must resolve like `ess train`'s flags, and
//! it holds `max(run.actors, run.torch_threads, 1)` cores; what a run directory holds.

use super::record::Error;
use crate::presets::{ConfigLayers, Layer, ResolveError};
use ess_proto::pb;
use std::path::Path;

/// Whether `run_dir` holds a complete checkpoint to resume from.
pub fn has_checkpoint(run_dir: &Path) -> bool {
    std::fs::read_dir(run_dir.join("checkpoints"))
        .map(|d| {
            d.flatten().any(|e| {
                let n = e.file_name();
                let n = n.to_string_lossy();
                n.starts_with("iter-") && !n.ends_with(".tmp") && e.path().is_dir()
            })
        })
        .unwrap_or(false)
}

/// The last non-empty lines of a job's `train.log`, to say why it failed.
pub(super) fn log_tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut tail: Vec<&str> = text
        .lines()
        .rev()
        .filter(|l| !l.trim().is_empty())
        .take(lines)
        .collect();
    tail.reverse();
    tail.join(" | ")
}

/// The request field a [`ResolveError`] is blamed on.
pub(super) fn spec_field(e: &ResolveError) -> String {
    match e.layer {
        Layer::Preset => "spec.preset".into(),
        Layer::EnvDefaults | Layer::Env => "spec.env".into(),
        Layer::Config => "spec.config_toml".into(),
        Layer::Seed => "spec.seed".into(),
        Layer::Set(i) if e.bad_key => format!("spec.overrides[{i}].key"),
        Layer::Set(i) => format!("spec.overrides[{i}].value"),
    }
}

/// A spec validated: its resolved config and what the job holds.
pub struct Validated {
    pub(super) preset: String,
    pub(super) config_toml: String,
    pub(super) iterations: u32,
    pub(super) cores: usize,
    pub(super) torch_threads: Option<usize>,
}

impl Validated {
    /// The resolved configuration as TOML (what the job's run directory gets).
    pub fn config_toml(&self) -> &str {
        &self.config_toml
    }
}

/// Resolves `spec` exactly as `ess train` resolves its flags; errors name the field.
pub fn validate(spec: &pb::JobSpec, budget: usize) -> Result<Validated, Error> {
    let invalid = |field: String, message: String| Error::InvalidArgument { field, message };
    let mut set = Vec::with_capacity(spec.overrides.len());
    for (i, o) in spec.overrides.iter().enumerate() {
        let key = o.key.trim();
        if key.is_empty() || key.contains('=') || key.contains(char::is_whitespace) {
            return Err(invalid(
                format!("spec.overrides[{i}].key"),
                format!("`{}` is not a dotted config key", o.key),
            ));
        }
        if o.value.trim().is_empty() {
            return Err(invalid(
                format!("spec.overrides[{i}].value"),
                format!("empty value for `{key}`"),
            ));
        }
        set.push(format!("{key}={}", o.value));
    }
    if spec.preset.contains('/') || spec.preset.ends_with(".toml") {
        return Err(invalid(
            "spec.preset".into(),
            format!(
                "`{}`: a job takes a preset name (`ess presets`); send a file's contents as config_toml",
                spec.preset
            ),
        ));
    }
    let layers = ConfigLayers {
        preset: spec.preset.clone(),
        preset_files: false,
        config: (!spec.config_toml.trim().is_empty())
            .then(|| ("spec.config_toml".to_string(), spec.config_toml.clone())),
        set,
        env: (!spec.env.is_empty()).then(|| spec.env.clone()),
        seed: spec.seed,
    };
    let cfg = layers
        .resolve()
        .map_err(|e| invalid(spec_field(&e), e.message.clone()))?;
    if cfg.run.transport == ess_proto::config::ActorTransport::Processes
        && let Err(e) = crate::actors::actor_binary()
    {
        let blamed = layers.blame_key("run.transport", e.to_string());
        return Err(invalid(spec_field(&blamed), blamed.message));
    }
    let cores = cfg
        .run
        .actors
        .max(cfg.run.torch_threads)
        .max(1)
        .min(budget.max(1));
    Ok(Validated {
        preset: if spec.preset.is_empty() {
            "ess-infogail".into()
        } else {
            spec.preset.clone()
        },
        config_toml: cfg.to_toml(),
        iterations: u32::try_from(cfg.run.iterations).unwrap_or(u32::MAX),
        cores,
        torch_threads: (cfg.run.torch_threads == 0).then_some(cores),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(preset: &str, overrides: &[(&str, &str)]) -> pb::JobSpec {
        pb::JobSpec {
            preset: preset.into(),
            overrides: overrides
                .iter()
                .map(|(k, v)| pb::Override {
                    key: (*k).into(),
                    value: (*v).into(),
                })
                .collect(),
            ..Default::default()
        }
    }

    fn field_of(s: &pb::JobSpec) -> String {
        match validate(s, 2) {
            Err(Error::InvalidArgument { field, .. }) => field,
            Err(e) => panic!("{e}"),
            Ok(_) => panic!("accepted"),
        }
    }

    #[test]
    fn malformed_specs_name_the_offending_field() {
        assert_eq!(field_of(&spec("gial", &[])), "spec.preset");
        assert_eq!(field_of(&spec("deploy/x.toml", &[])), "spec.preset");
        let ok = ("run.iterations", "2");
        assert_eq!(
            field_of(&spec("", &[ok, ("ppo.lrr", "1")])),
            "spec.overrides[1].key"
        );
        assert_eq!(
            field_of(&spec("", &[ok, ok, ("run.iterations", "lots")])),
            "spec.overrides[2].value"
        );
        assert_eq!(
            field_of(&spec("", &[("demos.label_ratio", "1.5")])),
            "spec.overrides[0].value"
        );
        assert_eq!(
            field_of(&spec("", &[("run.transport", "\"pigeons\"")])),
            "spec.overrides[0].value"
        );
        assert_eq!(field_of(&spec("", &[("", "1")])), "spec.overrides[0].key");
        let mut s = spec("", &[]);
        s.env = "mars".into();
        assert_eq!(field_of(&s), "spec.env");
        let mut s = spec("", &[]);
        s.config_toml = "[run]\nseeds = 3\n".into();
        assert_eq!(field_of(&s), "spec.config_toml");
        let mut s = spec("", &[]);
        s.config_toml = "[demos]\nlabel_ratio = 7.0\n".into();
        assert_eq!(field_of(&s), "spec.config_toml");
        // The later layer is blamed: the override, not the file.
        s.overrides.push(pb::Override {
            key: "demos.label_ratio".into(),
            value: "9.0".into(),
        });
        assert_eq!(field_of(&s), "spec.overrides[0].value");
    }

    #[test]
    fn a_valid_spec_resolves_like_ess_train_and_holds_its_cores() {
        // Threads: a unit test has no `ess-actor` binary beside it to validate.
        let threads = ("run.transport", "\"threads\"");
        let v = validate(&spec("gail", &[("run.actors", "3"), threads]), 2).unwrap();
        assert_eq!(v.preset, "gail");
        // Three actors on a two-core budget hold the whole budget; auto torch threads
        // follow the cores held.
        assert_eq!(v.cores, 2);
        assert_eq!(v.torch_threads, Some(2));
        assert!(
            v.config_toml.contains("name = \"gail\""),
            "{}",
            v.config_toml
        );
        let v = validate(
            &spec(
                "",
                &[("run.torch_threads", "1"), ("run.actors", "1"), threads],
            ),
            8,
        )
        .unwrap();
        assert_eq!((v.cores, v.torch_threads), (1, None));
        // By default a job has an actor per core of the machine, and holds them.
        let v = validate(&spec("", &[threads]), 64).unwrap();
        assert_eq!(v.cores, ess_proto::config::default_actors());
    }
}
