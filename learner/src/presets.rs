//! Method presets (`deploy/presets/*.toml`), embedded so the binary works from anywhere.
//! A preset only selects the latent prior and the objective terms' weights.
//! [`ConfigLayers::resolve`] layers presets, env defaults, a config file and overrides
//! into a checked configuration, for `ess train` and for `ess serve`'s job specs alike.

use ess_proto::config::ConfigError;

/// `(name, toml)` of every preset, in the paper's Table 1 order.
pub const PRESETS: &[(&str, &str)] = &[
    ("gail", include_str!("../../deploy/presets/gail.toml")),
    (
        "infogail",
        include_str!("../../deploy/presets/infogail.toml"),
    ),
    ("acgail", include_str!("../../deploy/presets/acgail.toml")),
    (
        "elastic-infogail",
        include_str!("../../deploy/presets/elastic-infogail.toml"),
    ),
    (
        "ess-infogail-no-gs",
        include_str!("../../deploy/presets/ess-infogail-no-gs.toml"),
    ),
    (
        "ess-infogail-no-rim",
        include_str!("../../deploy/presets/ess-infogail-no-rim.toml"),
    ),
    (
        "ess-infogail",
        include_str!("../../deploy/presets/ess-infogail.toml"),
    ),
];

/// `(env, toml)`: per-environment defaults (`deploy/envs/*.toml`): mode count and the
/// paper's label ratio. They apply over the built-in defaults and under the method
/// preset, the config file and `--set`; their `[per_method.<name>]` tables apply over
/// that method's preset (still under the file and `--set`).
pub const ENV_DEFAULTS: &[(&str, &str)] = &[
    ("traj2d", include_str!("../../deploy/envs/traj2d.toml")),
    ("reacher", include_str!("../../deploy/envs/reacher.toml")),
    ("pusher", include_str!("../../deploy/envs/pusher.toml")),
    ("walker2d", include_str!("../../deploy/envs/walker2d.toml")),
    ("humanoid", include_str!("../../deploy/envs/humanoid.toml")),
];

/// The defaults layer of `env`, if it has one.
pub fn env_defaults(env: &str) -> Option<&'static str> {
    ENV_DEFAULTS
        .iter()
        .find(|(n, _)| *n == env)
        .map(|(_, t)| *t)
}

/// A preset name or an env defaults layer that is not one.
#[derive(Debug, thiserror::Error)]
pub enum PresetError {
    /// No preset of that name.
    #[error(
        "unknown preset `{}`; known presets: {known}",
        ess_proto::text::printable(name)
    )]
    Unknown {
        /// The name asked for.
        name: String,
        /// The known presets, comma-separated.
        known: String,
    },
    /// The layer's TOML does not parse or has a field of the wrong shape.
    #[error(transparent)]
    Layer(#[from] ess_proto::config::ConfigError),
    /// A `[per_method.<name>]` table names no preset.
    #[error("{layer}: `per_method.{method}` is not a method; known methods: {known}")]
    NotAMethod {
        /// The layer (`env defaults <env>`).
        layer: String,
        /// The table's method name.
        method: String,
        /// The known methods, comma-separated.
        known: String,
    },
}

fn known_presets() -> String {
    PRESETS
        .iter()
        .map(|(n, _)| *n)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Parses the defaults layer of `env`, checking that each of its `[per_method.<name>]`
/// tables names a known preset.
pub fn parse_env_layer(env: &str, text: &str) -> Result<ess_proto::config::EnvLayer, PresetError> {
    let layer_name = format!("env defaults {env}");
    let layer = ess_proto::config::EnvLayer::parse(&layer_name, text)?;
    if let Some(bad) = layer.methods().find(|m| preset(m).is_err()) {
        return Err(PresetError::NotAMethod {
            layer: layer_name,
            method: bad.to_string(),
            known: known_presets(),
        });
    }
    Ok(layer)
}

/// The TOML of preset `name`, or an error listing the known ones.
pub fn preset(name: &str) -> Result<&'static str, PresetError> {
    PRESETS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .ok_or_else(|| PresetError::Unknown {
            name: name.to_string(),
            known: known_presets(),
        })
}

/// The paper's Table 1 `(NMI, ENT)` for `env` and `method`, where it reports one.
pub fn paper_table1(env: &str, method: &str) -> Option<(f64, f64)> {
    let col = ["traj2d", "reacher", "pusher", "walker2d", "humanoid"]
        .iter()
        .position(|e| *e == env)?;
    let row: [(f64, f64); 5] = match method {
        "gail" => [
            (0.392, 0.529),
            (0.153, 1.055),
            (0.376, 0.723),
            (0.439, 0.406),
            (0.388, 0.597),
        ],
        "infogail" => [
            (0.742, 0.371),
            (0.301, 1.113),
            (0.604, 0.551),
            (0.657, 0.284),
            (0.550, 0.487),
        ],
        "acgail" => [
            (0.783, 0.324),
            (0.537, 0.781),
            (0.754, 0.409),
            (0.658, 0.340),
            (0.544, 0.478),
        ],
        "elastic-infogail" => [
            (0.773, 0.330),
            (0.311, 1.101),
            (0.650, 0.537),
            (0.615, 0.351),
            (0.503, 0.498),
        ],
        "ess-infogail-no-gs" => [
            (0.892, 0.157),
            (0.607, 0.661),
            (0.857, 0.194),
            (0.740, 0.262),
            (0.638, 0.360),
        ],
        "ess-infogail-no-rim" => [
            (0.893, 0.159),
            (0.575, 0.725),
            (0.875, 0.188),
            (0.715, 0.274),
            (0.642, 0.347),
        ],
        "ess-infogail" => [
            (0.910, 0.131),
            (0.662, 0.587),
            (0.906, 0.144),
            (0.755, 0.237),
            (0.696, 0.206),
        ],
        _ => return None,
    };
    Some(row[col])
}

/// The layers a configuration is resolved from: the flags of `ess train` or a job spec
/// of `ess serve`. Precedence, lowest first: built-in defaults < the env's defaults layer
/// < preset < the env layer's `[per_method.<preset>]` table < `config` < `set` (in order)
/// < `env` < `seed`.
#[derive(Debug, Clone, Default)]
pub struct ConfigLayers {
    /// Preset name (see [`PRESETS`]), or with `preset_files` a path to a preset TOML file
    /// (a name ending in `.toml` or holding a `/`). Empty: `ess-infogail`.
    pub preset: String,
    /// Whether `preset` may name a file (the CLI); a job spec only takes names.
    pub preset_files: bool,
    /// `(source name, TOML text)` of a config file applied over the preset.
    pub config: Option<(String, String)>,
    /// `key=value` overrides, applied in order.
    pub set: Vec<String>,
    /// Environment name (overrides `env.name`).
    pub env: Option<String>,
    /// Training seed (overrides `run.seed`).
    pub seed: Option<u64>,
}

/// Which of a [`ConfigLayers`]' layers an error is blamed on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layer {
    /// The preset (its name, its file, or a value it sets).
    Preset,
    /// The env's built-in defaults layer.
    EnvDefaults,
    /// The config file.
    Config,
    /// The override at this index of [`ConfigLayers::set`].
    Set(usize),
    /// [`ConfigLayers::env`] (or the env named by the layers, when none set it).
    Env,
    /// [`ConfigLayers::seed`].
    Seed,
}

/// A configuration that cannot be resolved: the message (naming the key, value, file),
/// the layer it is blamed on, and whether the override's key (rather than its value) is
/// the problem.
#[derive(Debug, Clone, thiserror::Error)]
#[error("{message}")]
pub struct ResolveError {
    /// What is wrong, naming the key, value or file.
    pub message: String,
    /// The layer that brought the bad key or value.
    pub layer: Layer,
    /// True when the key itself is bad (unknown, or not `key=value`); false when its
    /// value is.
    pub bad_key: bool,
}

impl ConfigLayers {
    /// The checked configuration, resolved exactly as `ess train` does: a first pass
    /// learns which env the layers select, a second puts that env's defaults layer under
    /// them; the env must be constructible. Only the second pass is checked, so a key
    /// that is valid only beside the env's defaults (Humanoid's
    /// `method.qc_reward_floor`, which needs its `qc_reward_entropy`) is accepted.
    pub fn resolve(&self) -> Result<ess_proto::CheckedConfig, ResolveError> {
        let first = self.layered(None)?;
        let layer = first.env_name().and_then(|e| Some((e, env_defaults(e)?)));
        let cfg = match layer {
            Some(layer) => self.build(&self.layered(Some(layer))?)?,
            None => self.build(&first)?,
        };
        if let Err(e) = ess_envs::make_plain_env(&cfg.env.name, cfg.env.n_modes) {
            let key = match &e {
                ess_envs::EnvError::BadParam { field, .. } if field.contains("mode") => {
                    "env.n_modes"
                }
                _ => "env.name",
            };
            return Err(self.blame_key(key, e.to_string()));
        }
        Ok(cfg)
    }

    fn preset_name(&self) -> &str {
        if self.preset.is_empty() {
            "ess-infogail"
        } else {
            &self.preset
        }
    }

    /// Every layer merged, with `env_layer` (env name, text) under them, unchecked.
    fn layered(
        &self,
        env_layer: Option<(&str, &str)>,
    ) -> Result<ess_proto::config::ConfigBuilder, ResolveError> {
        let err = |layer: Layer, e: &dyn std::fmt::Display| ResolveError {
            message: e.to_string(),
            layer,
            bad_key: false,
        };
        let mut b = ess_proto::config::ConfigBuilder::new();
        let env_layer = env_layer
            .map(|(env, text)| parse_env_layer(env, text))
            .transpose()
            .map_err(|e| err(Layer::EnvDefaults, &e))?;
        if let Some(layer) = &env_layer {
            b.merge_env_layer(layer)
                .map_err(|e| err(Layer::EnvDefaults, &e))?;
        }
        let name = self.preset_name();
        let (source, text) = if self.preset_files && (name.ends_with(".toml") || name.contains('/'))
        {
            let text = std::fs::read_to_string(name).map_err(|e| {
                err(
                    Layer::Preset,
                    &format!("cannot read preset file {name}: {e}"),
                )
            })?;
            (name.to_string(), text)
        } else {
            let text = preset(name).map_err(|e| err(Layer::Preset, &e))?;
            (format!("preset {name}"), text.to_string())
        };
        b.merge_toml(&source, &text)
            .map_err(|e| err(Layer::Preset, &e))?;
        if let Some(layer) = &env_layer {
            b.merge_env_method_layer(layer)
                .map_err(|e| err(Layer::EnvDefaults, &e))?;
        }
        if let Some((source, text)) = &self.config {
            b.merge_toml(source, text)
                .map_err(|e| err(Layer::Config, &e))?;
        }
        for (i, s) in self.set.iter().enumerate() {
            b.set(s).map_err(|e| ResolveError {
                bad_key: matches!(
                    e,
                    ConfigError::UnknownKey { .. } | ConfigError::BadOverride { .. }
                ),
                message: e.to_string(),
                layer: Layer::Set(i),
            })?;
        }
        if let Some(env) = &self.env {
            b.set(&format!("env.name={}", toml::Value::from(env.as_str())))
                .map_err(|e| err(Layer::Env, &e))?;
        }
        if let Some(seed) = self.seed {
            b.set(&format!("run.seed={seed}"))
                .map_err(|e| err(Layer::Seed, &e))?;
        }
        Ok(b)
    }

    /// Deserializes and checks `b`, blaming the layer that set the failing key.
    fn build(
        &self,
        b: &ess_proto::config::ConfigBuilder,
    ) -> Result<ess_proto::CheckedConfig, ResolveError> {
        b.build().map_err(|e| match &e {
            ConfigError::OutOfRange { key, .. }
            | ConfigError::UnknownKey { key, .. }
            | ConfigError::WrongType { key, .. } => self.blame_key(key, e.to_string()),
            _ => self.blame_message(e.to_string()),
        })
    }

    /// Blames the layer with the highest precedence that sets `key`.
    pub fn blame_key(&self, key: &str, message: String) -> ResolveError {
        let layer = if key == "run.seed" && self.seed.is_some() {
            Layer::Seed
        } else if key == "env.name" && self.env.is_some() {
            Layer::Env
        } else if let Some(i) = self
            .set
            .iter()
            .rposition(|s| s.split_once('=').is_some_and(|(k, _)| k.trim() == key))
        {
            Layer::Set(i)
        } else if self
            .config
            .as_ref()
            .is_some_and(|(_, text)| toml_sets(text, key))
        {
            Layer::Config
        } else if key == "env.name" {
            Layer::Env
        } else {
            Layer::Preset
        };
        ResolveError {
            message,
            layer,
            bad_key: false,
        }
    }

    /// Blames a message without a key (a value serde rejected) on the last override
    /// whose value it quotes, else on the config file, else on the preset.
    fn blame_message(&self, message: String) -> ResolveError {
        let quoted = |v: &str| {
            let v = v.trim().trim_matches('"');
            !v.is_empty() && message.contains(&format!("`{v}`"))
        };
        let layer = if let Some(i) = self
            .set
            .iter()
            .rposition(|s| s.split_once('=').is_some_and(|(_, v)| quoted(v)))
        {
            Layer::Set(i)
        } else if self.config.is_some() {
            Layer::Config
        } else {
            Layer::Preset
        };
        ResolveError {
            message,
            layer,
            bad_key: false,
        }
    }
}

/// Whether TOML `text` sets the dotted `key`.
fn toml_sets(text: &str, key: &str) -> bool {
    let Ok(table) = text.parse::<toml::Table>() else {
        return false;
    };
    let mut cur = &table;
    let parts: Vec<&str> = key.split('.').collect();
    for (i, p) in parts.iter().enumerate() {
        match cur.get(*p) {
            Some(toml::Value::Table(t)) if i + 1 < parts.len() => cur = t,
            Some(_) if i + 1 == parts.len() => return true,
            _ => return false,
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use ess_proto::config::ConfigBuilder;

    #[test]
    fn every_preset_builds_a_valid_config_named_after_itself() {
        for (name, text) in PRESETS {
            let mut b = ConfigBuilder::new();
            b.merge_toml(name, text).unwrap();
            let c = b.build().unwrap();
            assert_eq!(c.method.name, *name);
        }
    }

    #[test]
    fn paper_table1_has_a_row_for_every_preset() {
        for (name, _) in PRESETS {
            assert!(paper_table1("traj2d", name).is_some(), "{name}");
        }
        assert_eq!(
            paper_table1("reacher", "ess-infogail"),
            Some((0.662, 0.587))
        );
        assert_eq!(paper_table1("mars", "gail"), None);
    }

    #[test]
    fn every_env_layer_builds_a_valid_config_under_every_preset() {
        for (env, layer_text) in ENV_DEFAULTS {
            let layer = parse_env_layer(env, layer_text).unwrap();
            for (name, text) in PRESETS {
                let mut b = ConfigBuilder::new();
                b.merge_env_layer(&layer).unwrap();
                b.merge_toml(name, text).unwrap();
                b.merge_env_method_layer(&layer).unwrap();
                let c = b.build().unwrap_or_else(|e| panic!("{env} + {name}: {e}"));
                assert_eq!(c.method.name, *name, "{env}");
            }
        }
    }

    #[test]
    fn a_set_key_may_lean_on_the_env_layer_it_sits_over() {
        // Humanoid's layer sets method.qc_reward_entropy, which the floor needs;
        // Traj2D's does not, and there the --set that asks for it is blamed.
        let layers = |env: &str| ConfigLayers {
            env: Some(env.into()),
            set: vec!["method.qc_reward_floor=true".into()],
            ..Default::default()
        };
        let c = layers("humanoid").resolve().expect("humanoid");
        assert!(c.method.qc_reward_floor && c.method.qc_reward_entropy);
        let e = layers("traj2d").resolve().unwrap_err();
        assert!(matches!(e.layer, Layer::Set(0)), "{:?}", e.layer);
        assert!(e.message.contains("qc_reward_entropy"), "{}", e.message);
    }

    #[test]
    fn a_per_method_table_applies_over_its_preset_only() {
        let text =
            "[method]\nreward_qeps = 0.3\n[per_method.ess-infogail.method]\nreward_qc = 0.7\n";
        let layer = parse_env_layer("toy", text).unwrap();
        let build = |preset_name: &str| {
            let mut b = ConfigBuilder::new();
            b.merge_env_layer(&layer).unwrap();
            b.merge_toml(preset_name, preset(preset_name).unwrap())
                .unwrap();
            b.merge_env_method_layer(&layer).unwrap();
            b.set("method.reward_qeps=0.2").unwrap();
            b.build().unwrap()
        };
        let ess = build("ess-infogail");
        assert_eq!(ess.method.reward_qc, 0.7);
        // The preset's own value wins over the method-independent env key; --set wins
        // over everything.
        assert_eq!(ess.method.reward_qeps, 0.2);
        let info = build("infogail");
        assert_ne!(info.method.reward_qc, 0.7);
    }

    #[test]
    fn a_per_method_table_for_an_unknown_method_is_named() {
        let e = parse_env_layer(
            "reacher",
            "[per_method.essinfogail.method]\nreward_qc = 1.0\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("per_method.essinfogail") && e.contains("env defaults reacher"),
            "{e}"
        );
        let e = parse_env_layer("reacher", "per_method = 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`per_method` must be a table"), "{e}");
        // A bad key inside the table is named with the table it came from.
        let layer =
            parse_env_layer("reacher", "[per_method.gail.method]\nreward_q = 1.0\n").unwrap();
        let mut b = ConfigBuilder::new();
        b.merge_toml("gail", preset("gail").unwrap()).unwrap();
        let e = b.merge_env_method_layer(&layer).unwrap_err().to_string();
        assert!(
            e.contains("method.reward_q") && e.contains("[per_method.gail]"),
            "{e}"
        );
    }

    #[test]
    fn unknown_preset_lists_the_known_ones() {
        let e = preset("gale").unwrap_err().to_string();
        assert!(e.contains("`gale`") && e.contains("ess-infogail"), "{e}");
    }
}
