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
    fn unknown_preset_lists_the_known_ones() {
        let e = preset("gale").unwrap_err();
        assert!(e.contains("`gale`") && e.contains("ess-infogail"), "{e}");
    }
}
