//! The layers a configuration is built from (module doc of [`super`]): defaults <
//! preset < environment layer < user file < `--set`, merged key by key into the
//! defaults' table, so an unknown key is named with its dotted path.

use super::{CheckedConfig, ConfigError, TrainConfig};

/// An environment's defaults layer (`deploy/envs/<env>.toml`): keys that hold for every
/// method, plus optional `[per_method.<method name>.<section>]` tables that hold for one
/// method only (e.g. Reacher's information-reward weights for Ess-InfoGAIL).
#[derive(Debug, Clone)]
pub struct EnvLayer {
    source_name: String,
    base: toml::Table,
    per_method: std::collections::BTreeMap<String, toml::Table>,
}

impl EnvLayer {
    /// Parses a layer; `source_name` names it in error messages. `per_method` must be a
    /// table of tables, one per method name (the names are checked by the caller, who
    /// knows the presets).
    pub fn parse(source_name: &str, text: &str) -> Result<Self, ConfigError> {
        let mut base: toml::Table =
            text.parse()
                .map_err(|e: toml::de::Error| ConfigError::Parse {
                    source_name: source_name.to_string(),
                    message: e.message().to_string(),
                })?;
        let mut per_method = std::collections::BTreeMap::new();
        if let Some(v) = base.remove("per_method") {
            let toml::Value::Table(t) = v else {
                return Err(ConfigError::Parse {
                    source_name: source_name.to_string(),
                    message: format!("`per_method` must be a table, found {}", type_name(&v)),
                });
            };
            for (name, v) in t {
                let toml::Value::Table(m) = v else {
                    return Err(ConfigError::Parse {
                        source_name: source_name.to_string(),
                        message: format!(
                            "`per_method.{name}` must be a table, found {}",
                            type_name(&v)
                        ),
                    });
                };
                per_method.insert(name, m);
            }
        }
        Ok(Self {
            source_name: source_name.to_string(),
            base,
            per_method,
        })
    }

    /// The method names that have their own table.
    pub fn methods(&self) -> impl Iterator<Item = &str> {
        self.per_method.keys().map(String::as_str)
    }
}

/// Builds a configuration from layers of TOML tables over the defaults.
#[derive(Debug, Clone)]
pub struct ConfigBuilder {
    table: toml::Table,
}

impl Default for ConfigBuilder {
    fn default() -> Self {
        Self::new()
    }
}

impl ConfigBuilder {
    /// Starts from [`TrainConfig::default`].
    pub fn new() -> Self {
        let table =
            toml::Table::try_from(TrainConfig::default()).unwrap_or_else(|_| unreachable_table());
        Self { table }
    }

    /// Merges a TOML document (preset or file) named `source_name` in error messages.
    pub fn merge_toml(&mut self, source_name: &str, text: &str) -> Result<&mut Self, ConfigError> {
        let layer: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| ConfigError::Parse {
                source_name: source_name.to_string(),
                message: e.message().to_string(),
            })?;
        merge_table(&mut self.table, layer, "", source_name)?;
        Ok(self)
    }

    /// Merges the method-independent part of an environment's defaults layer (all of
    /// it but its `[per_method]` table).
    pub fn merge_env_layer(&mut self, layer: &EnvLayer) -> Result<&mut Self, ConfigError> {
        merge_table(&mut self.table, layer.base.clone(), "", &layer.source_name)?;
        Ok(self)
    }

    /// Merges the env layer's `[per_method.<name>]` table for the method selected so
    /// far (`method.name`, set by the preset), if it has one. Call it right after the
    /// preset: an env's tuning of one method then sits over that method's preset and
    /// under the config file and `--set`.
    pub fn merge_env_method_layer(&mut self, layer: &EnvLayer) -> Result<&mut Self, ConfigError> {
        let name = self
            .table
            .get("method")
            .and_then(|m| m.get("name"))
            .and_then(|n| n.as_str())
            .unwrap_or_default()
            .to_string();
        if let Some(t) = layer.per_method.get(&name) {
            let source = format!("{} [per_method.{name}]", layer.source_name);
            merge_table(&mut self.table, t.clone(), "", &source)?;
        }
        Ok(self)
    }

    /// Applies one `key=value` override; `value` is parsed as TOML, else taken as a string.
    pub fn set(&mut self, arg: &str) -> Result<&mut Self, ConfigError> {
        let (key, raw) = arg
            .split_once('=')
            .map(|(k, v)| (k.trim(), v.trim()))
            .filter(|(k, _)| !k.is_empty())
            .ok_or_else(|| ConfigError::BadOverride { arg: arg.into() })?;
        let value = parse_value(raw);
        let mut layer = toml::Table::new();
        let parts: Vec<&str> = key.split('.').collect();
        let mut cur = &mut layer;
        for p in &parts[..parts.len() - 1] {
            cur = cur
                .entry((*p).to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                .as_table_mut()
                .ok_or_else(|| ConfigError::BadOverride { arg: arg.into() })?;
        }
        cur.insert(parts[parts.len() - 1].to_string(), value);
        merge_table(&mut self.table, layer, "", "--set")?;
        Ok(self)
    }

    /// The `env.name` the layers merged so far select, if it is a string.
    pub fn env_name(&self) -> Option<&str> {
        self.table.get("env")?.get("name")?.as_str()
    }

    /// Deserializes and checks the merged configuration.
    pub fn build(&self) -> Result<CheckedConfig, ConfigError> {
        let cfg: TrainConfig = self
            .table
            .clone()
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Invalid {
                message: e.message().trim().to_string(),
            })?;
        cfg.check()
    }
}

fn unreachable_table() -> toml::Table {
    // TrainConfig::default always serializes; keep the builder total anyway.
    toml::Table::new()
}

fn parse_value(raw: &str) -> toml::Value {
    let doc = format!("v = {raw}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t
            .remove("v")
            .unwrap_or_else(|| toml::Value::String(raw.into())),
        Err(_) => toml::Value::String(raw.into()),
    }
}

fn type_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a float",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a datetime",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

fn merge_table(
    base: &mut toml::Table,
    layer: toml::Table,
    prefix: &str,
    source_name: &str,
) -> Result<(), ConfigError> {
    for (k, v) in layer {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        let Some(slot) = base.get_mut(&k) else {
            return Err(ConfigError::UnknownKey {
                key,
                source_name: source_name.into(),
            });
        };
        match (slot, v) {
            (toml::Value::Table(b), toml::Value::Table(l)) => merge_table(b, l, &key, source_name)?,
            (slot @ toml::Value::Float(_), toml::Value::Integer(i)) => {
                *slot = toml::Value::Float(i as f64)
            }
            // Every integer of the configuration is unsigned.
            (toml::Value::Integer(_), toml::Value::Integer(i)) if i < 0 => {
                return Err(ConfigError::OutOfRange {
                    key,
                    value: i.to_string(),
                    reason: "must be >= 0".into(),
                });
            }
            (slot, v) if std::mem::discriminant(slot) == std::mem::discriminant(&v) => *slot = v,
            (slot, v) => {
                return Err(ConfigError::WrongType {
                    key,
                    source_name: source_name.into(),
                    expected: type_name(slot).into(),
                    got: format!("{} ({v})", type_name(&v)),
                });
            }
        }
    }
    Ok(())
}
