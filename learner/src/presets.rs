//! Method presets (`deploy/presets/*.toml`), embedded so the binary works from anywhere.
//! A preset only selects the latent prior and the objective terms' weights.

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

/// Parses the defaults layer of `env`, checking that each of its `[per_method.<name>]`
/// tables names a known preset.
pub fn parse_env_layer(env: &str, text: &str) -> Result<ess_proto::config::EnvLayer, String> {
    let source = format!("env defaults {env}");
    let layer = ess_proto::config::EnvLayer::parse(&source, text).map_err(|e| e.to_string())?;
    if let Some(bad) = layer.methods().find(|m| preset(m).is_err()) {
        let known: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
        return Err(format!(
            "{source}: `per_method.{bad}` is not a method; known methods: {}",
            known.join(", ")
        ));
    }
    Ok(layer)
}

/// The TOML of preset `name`, or an error listing the known ones.
pub fn preset(name: &str) -> Result<&'static str, String> {
    PRESETS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, t)| *t)
        .ok_or_else(|| {
            let known: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
            format!(
                "unknown preset `{name}`; known presets: {}",
                known.join(", ")
            )
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
        .unwrap_err();
        assert!(
            e.contains("per_method.essinfogail") && e.contains("env defaults reacher"),
            "{e}"
        );
        let e = parse_env_layer("reacher", "per_method = 3\n").unwrap_err();
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
        let e = preset("gale").unwrap_err();
        assert!(e.contains("`gale`") && e.contains("ess-infogail"), "{e}");
    }
}
