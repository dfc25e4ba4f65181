//! An experiment spec (`deploy/experiments/*.toml`): the grid presets x envs x variants
//! x seeds, the report's layout, and the paper's numbers to print beside ours. Parsing
//! checks every cell's configuration before anything runs, so a bad spec is one line
//! naming its file and field and nothing is submitted.

use crate::presets::{ConfigLayers, Layer};
use ess_proto::pb;
use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// An experiment spec that cannot be used; the message names the file and the field.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct SpecError {
    /// The spec file.
    pub file: PathBuf,
    /// What is wrong, naming the field.
    pub message: String,
}

/// One axis of the grid, as the report's rows and columns name them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Axis {
    /// The method preset.
    Preset,
    /// The task.
    Env,
    /// The spec's `[[variants]]`.
    Variant,
}

impl Axis {
    /// The name a spec uses for it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Preset => "preset",
            Self::Env => "env",
            Self::Variant => "variant",
        }
    }
}

/// What the report draws besides its table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Figure {
    /// No figure.
    #[default]
    None,
    /// `figure_metric` (a `metrics.csv` column) over env steps, one line per row of the
    /// table, mean over seeds (the paper's Fig. 5).
    Curves,
    /// `figure_metric` (a `summary.json` field) against each variant's `x`, one line per
    /// column of the table (the paper's Fig. 6).
    Variants,
}

/// A named set of overrides: one value of the variant axis.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Variant {
    /// Name (letters, digits, `-`, `_`); part of the cell ids.
    pub name: String,
    /// Position on the x axis of a `variants` figure.
    #[serde(default)]
    pub x: Option<f64>,
    /// `key=value` overrides, applied after the spec's `set`.
    #[serde(default)]
    pub set: Vec<String>,
}

/// The spec file's contents.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentSpec {
    /// Name (the report's heading and the Slurm job name).
    pub name: String,
    /// One line saying what the grid reproduces.
    #[serde(default)]
    pub title: String,
    /// Method presets (`ess presets`).
    pub presets: Vec<String>,
    /// Tasks.
    pub envs: Vec<String>,
    /// Seeds of every cell, unless `seeds_by_env` names the env.
    pub seeds: Vec<u64>,
    /// Seeds per env, where they differ from `seeds`.
    #[serde(default)]
    pub seeds_by_env: BTreeMap<String, Vec<u64>>,
    /// `key=value` overrides of every cell.
    #[serde(default)]
    pub set: Vec<String>,
    /// Override sets, one per value of the variant axis (none: one cell per preset,
    /// env and seed).
    #[serde(default)]
    pub variants: Vec<Variant>,
    /// The table's rows.
    #[serde(default = "default_rows")]
    pub rows: Axis,
    /// The table's columns.
    #[serde(default = "default_columns")]
    pub columns: Axis,
    /// `summary.json` fields reported per cell (dotted paths).
    #[serde(default = "default_metrics")]
    pub metrics: Vec<String>,
    /// The figure drawn beside the table.
    #[serde(default)]
    pub figure: Figure,
    /// The metric of the figure.
    #[serde(default)]
    pub figure_metric: String,
    /// The paper's numbers: `"<row>/<column>" = { metric = value }`.
    #[serde(default)]
    pub paper: BTreeMap<String, BTreeMap<String, f64>>,
}

fn default_rows() -> Axis {
    Axis::Preset
}
fn default_columns() -> Axis {
    Axis::Env
}
fn default_metrics() -> Vec<String> {
    vec!["nmi".into(), "ent".into(), "normalized_reward".into()]
}

/// The `summary.json` fields a report may name.
pub const METRICS: &[&str] = &[
    "nmi",
    "ent",
    "normalized_reward",
    "prior_tv",
    "classifier_accuracy",
    "encoder_accuracy.overall",
    "encoder_accuracy.balanced",
    "env_steps_per_second",
    "wall_seconds",
];

/// The `metrics.csv` columns a `curves` figure may draw.
pub const CURVE_METRICS: &[&str] = &["nmi", "ent", "normalized_reward"];

/// One run of the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// `<preset>.<env>[.<variant>].s<seed>`: the job id and run directory name.
    pub id: String,
    /// Preset.
    pub preset: String,
    /// Task.
    pub env: String,
    /// Index into the spec's variants, if it has any.
    pub variant: Option<usize>,
    /// Seed.
    pub seed: u64,
    /// Overrides: the spec's, then the variant's.
    pub set: Vec<String>,
}

impl Cell {
    /// The job that runs this cell.
    pub fn job_spec(&self) -> pb::JobSpec {
        let overrides = self
            .set
            .iter()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| pb::Override {
                key: k.trim().into(),
                value: v.trim().into(),
            })
            .collect();
        pb::JobSpec {
            preset: self.preset.clone(),
            env: self.env.clone(),
            seed: Some(self.seed),
            overrides,
            ..Default::default()
        }
    }

    /// This cell's value on `axis` (the variant's name, or "-" without variants).
    pub fn axis<'a>(&'a self, spec: &'a ExperimentSpec, axis: Axis) -> &'a str {
        match axis {
            Axis::Preset => &self.preset,
            Axis::Env => &self.env,
            Axis::Variant => self
                .variant
                .and_then(|v| spec.variants.get(v))
                .map_or("-", |v| v.name.as_str()),
        }
    }
}

impl ExperimentSpec {
    /// Reads and checks `path` (see [`ExperimentSpec::check`]).
    pub fn load(path: &Path) -> Result<Self, SpecError> {
        let err = |message: String| SpecError {
            file: path.to_path_buf(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let spec: Self = toml::from_str(&text).map_err(|e| err(one_line(&e.to_string())))?;
        spec.check().map_err(err)?;
        Ok(spec)
    }

    /// The cells in a fixed order: variant, preset, env, seed.
    pub fn cells(&self) -> Vec<Cell> {
        let variants: Vec<Option<usize>> = if self.variants.is_empty() {
            vec![None]
        } else {
            (0..self.variants.len()).map(Some).collect()
        };
        let mut cells = Vec::new();
        for &v in &variants {
            for preset in &self.presets {
                for env in &self.envs {
                    for &seed in self.seeds_of(env) {
                        let mut set = self.set.clone();
                        let mut id = format!("{preset}.{env}");
                        if let Some(v) = v.and_then(|v| self.variants.get(v)) {
                            set.extend(v.set.iter().cloned());
                            id = format!("{id}.{}", v.name);
                        }
                        cells.push(Cell {
                            id: format!("{id}.s{seed}"),
                            preset: preset.clone(),
                            env: env.clone(),
                            variant: v,
                            seed,
                            set,
                        });
                    }
                }
            }
        }
        cells
    }

    fn seeds_of(&self, env: &str) -> &[u64] {
        self.seeds_by_env.get(env).unwrap_or(&self.seeds)
    }

    /// Every rule a spec must keep, then every cell's configuration resolved as
    /// `ess train` would resolve it; the error names the field.
    pub fn check(&self) -> Result<(), String> {
        self.check_grid()?;
        self.check_report()?;
        self.check_cells()
    }

    fn check_grid(&self) -> Result<(), String> {
        for (field, empty) in [
            ("presets", self.presets.is_empty()),
            ("envs", self.envs.is_empty()),
            ("seeds", self.seeds.is_empty()),
        ] {
            if empty {
                return Err(format!("`{field}` is empty: the grid has no cells"));
            }
        }
        duplicates("presets", &self.presets)?;
        duplicates("envs", &self.envs)?;
        duplicates("seeds", &self.seeds)?;
        for (env, seeds) in &self.seeds_by_env {
            if !self.envs.contains(env) {
                return Err(format!("`seeds_by_env.{env}`: `{env}` is not in `envs`"));
            }
            if seeds.is_empty() {
                return Err(format!("`seeds_by_env.{env}` is empty"));
            }
            duplicates(&format!("seeds_by_env.{env}"), seeds)?;
        }
        let names: Vec<&String> = self.variants.iter().map(|v| &v.name).collect();
        duplicates("variants[].name", &names)?;
        for (i, v) in self.variants.iter().enumerate() {
            let plain = !v.name.is_empty()
                && v.name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
            if !plain {
                return Err(format!(
                    "`variants[{i}].name` = \"{}\": use letters, digits, `-` and `_`",
                    v.name
                ));
            }
        }
        Ok(())
    }

    fn check_report(&self) -> Result<(), String> {
        if self.rows == self.columns {
            return Err(format!(
                "`rows` and `columns` are both {}",
                self.rows.name()
            ));
        }
        let covered = |a: Axis| self.rows == a || self.columns == a;
        for (axis, n, field) in [
            (Axis::Preset, self.presets.len(), "presets"),
            (Axis::Env, self.envs.len(), "envs"),
            (Axis::Variant, self.variants.len(), "variants"),
        ] {
            if n > 1 && !covered(axis) {
                return Err(format!(
                    "`{field}` has {n} values but neither `rows` nor `columns` is {}: their runs would be averaged together",
                    axis.name()
                ));
            }
        }
        for (i, m) in self.metrics.iter().enumerate() {
            if !METRICS.contains(&m.as_str()) {
                return Err(format!(
                    "`metrics[{i}]` = \"{m}\": not one of {}",
                    METRICS.join(", ")
                ));
            }
        }
        let fm = self.figure_metric.as_str();
        match self.figure {
            Figure::None => {}
            Figure::Curves if !CURVE_METRICS.contains(&fm) => {
                return Err(format!(
                    "`figure_metric` = \"{fm}\": a curves figure draws one of {}",
                    CURVE_METRICS.join(", ")
                ));
            }
            Figure::Variants if !METRICS.contains(&fm) => {
                return Err(format!(
                    "`figure_metric` = \"{fm}\": not one of {}",
                    METRICS.join(", ")
                ));
            }
            Figure::Variants => {
                if let Some(i) = self.variants.iter().position(|v| v.x.is_none()) {
                    return Err(format!(
                        "`variants[{i}].x` is missing: a variants figure places each variant at its x"
                    ));
                }
            }
            Figure::Curves => {}
        }
        Ok(())
    }

    /// Resolves each (preset, env, variant) once; the error names the spec field that
    /// brought the bad preset, task or key.
    fn check_cells(&self) -> Result<(), String> {
        let mut seen = BTreeSet::new();
        for c in self.cells() {
            if !seen.insert((c.preset.clone(), c.env.clone(), c.variant)) {
                continue;
            }
            let layers = ConfigLayers {
                preset: c.preset.clone(),
                preset_files: false,
                config: None,
                set: c.set.clone(),
                env: Some(c.env.clone()),
                seed: Some(c.seed),
            };
            if let Err(e) = layers.resolve() {
                let n = self.set.len();
                let field = match e.layer {
                    Layer::Preset => format!("presets (\"{}\")", c.preset),
                    Layer::Env | Layer::EnvDefaults => format!("envs (\"{}\")", c.env),
                    Layer::Set(i) if i < n => format!("set[{i}]"),
                    Layer::Set(i) => format!("variants[{}].set[{}]", c.variant.unwrap_or(0), i - n),
                    Layer::Config | Layer::Seed => "seeds".into(),
                };
                return Err(format!("`{field}`: {}", one_line(&e.message)));
            }
        }
        Ok(())
    }
}

fn duplicates<T: Ord + std::fmt::Display>(field: &str, items: &[T]) -> Result<(), String> {
    let mut seen = BTreeSet::new();
    for x in items {
        if !seen.insert(x) {
            return Err(format!("`{field}` lists {x} twice"));
        }
    }
    Ok(())
}

/// An error message on one line.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}
