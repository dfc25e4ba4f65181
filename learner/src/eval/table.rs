//! `ess report RUN_DIR...`: the Table 1 view of finished runs. Reads each run's
//! `summary.json`, prints one row per run and, per (env, method), the mean and sample
//! standard deviation over seeds beside the paper's Table 1 value (the paper reports
//! means over 10 seeds).

use crate::eval::metrics::mean_std;
use crate::presets::paper_table1;
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What the table needs from one run's `summary.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRow {
    /// Run directory.
    pub dir: PathBuf,
    /// Environment.
    pub env: String,
    /// Method (preset) name.
    pub method: String,
    /// Training seed.
    pub seed: u64,
    /// Final NMI.
    pub nmi: f64,
    /// Final ENT.
    pub ent: f64,
    /// Final normalised task reward.
    pub normalized_reward: f64,
    /// Training env steps.
    pub env_steps: u64,
    /// Training wall seconds.
    pub wall_seconds: f64,
    /// Stopped early.
    pub interrupted: bool,
    /// Final normalised reward of each code (`eval.normalized_reward_per_code`; empty
    /// in summaries that predate it).
    pub reward_per_code: Vec<f64>,
    /// The mode each code is matched to (`eval.assignment`; empty where absent).
    pub assignment: Vec<usize>,
}

/// A `summary.json` that cannot be used, with the file and the field named.
#[derive(Debug, thiserror::Error)]
pub enum TableError {
    /// The file is missing or unreadable.
    #[error("cannot read {path}: {message}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// Not JSON, or a field is missing or of the wrong type.
    #[error("{path}: {message}")]
    Field {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// Reads `<dir>/summary.json`.
pub fn read_run(dir: &Path) -> Result<RunRow, TableError> {
    let path = dir.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|e| TableError::Read {
        path: path.clone(),
        message: e.to_string(),
    })?;
    let v: Value = serde_json::from_str(&text).map_err(|e| TableError::Field {
        path: path.clone(),
        message: format!("not JSON: {e}"),
    })?;
    let field = |name: &str| {
        v.get(name).ok_or_else(|| TableError::Field {
            path: path.clone(),
            message: format!("missing field `{name}`"),
        })
    };
    let wrong = |name: &str, want: &str| TableError::Field {
        path: path.clone(),
        message: format!("field `{name}` is not {want}"),
    };
    let num = |name: &str| field(name)?.as_f64().ok_or_else(|| wrong(name, "a number"));
    let string = |name: &str| {
        field(name)?
            .as_str()
            .map(str::to_string)
            .ok_or_else(|| wrong(name, "a string"))
    };
    let int = |name: &str| {
        field(name)?
            .as_u64()
            .ok_or_else(|| wrong(name, "a non-negative integer"))
    };
    Ok(RunRow {
        dir: dir.to_path_buf(),
        env: string("env")?,
        method: string("method")?,
        seed: int("seed")?,
        nmi: num("nmi")?,
        ent: num("ent")?,
        normalized_reward: num("normalized_reward")?,
        env_steps: int("env_steps")?,
        wall_seconds: num("wall_seconds")?,
        interrupted: v
            .get("interrupted")
            .and_then(Value::as_bool)
            .unwrap_or(false),
        reward_per_code: v
            .pointer("/eval/normalized_reward_per_code")
            .and_then(Value::as_array)
            .map(|a| a.iter().filter_map(Value::as_f64).collect())
            .unwrap_or_default(),
        assignment: v
            .pointer("/eval/assignment")
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_u64().map(|m| m as usize))
                    .collect()
            })
            .unwrap_or_default(),
    })
}

/// The report as Markdown: a row per run, then a row per (env, method) with mean ± std.
pub fn markdown(rows: &[RunRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| run | env | method | seed | NMI | ENT | norm. reward | env steps | wall s |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {}{} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {} | {:.0} |",
            r.dir.display(),
            if r.interrupted { " (stopped)" } else { "" },
            r.env,
            r.method,
            r.seed,
            r.nmi,
            r.ent,
            r.normalized_reward,
            r.env_steps,
            r.wall_seconds
        );
    }
    let mut groups: BTreeMap<(&str, &str), Vec<&RunRow>> = BTreeMap::new();
    for r in rows {
        groups.entry((&r.env, &r.method)).or_default().push(r);
    }
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "| env | method | seeds | NMI | ENT | norm. reward | paper NMI | paper ENT |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for ((env, method), g) in groups {
        let col = |f: fn(&RunRow) -> f64| {
            let (m, sd) = mean_std(&g.iter().map(|r| f(r)).collect::<Vec<_>>());
            format!("{m:.3} ± {sd:.3}")
        };
        let (pn, pe) = paper_table1(env, method)
            .map(|(n, e)| (format!("{n:.3}"), format!("{e:.3}")))
            .unwrap_or_else(|| ("-".into(), "-".into()));
        let _ = writeln!(
            s,
            "| {env} | {method} | {} | {} | {} | {} | {pn} | {pe} |",
            g.len(),
            col(|r| r.nmi),
            col(|r| r.ent),
            col(|r| r.normalized_reward),
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("summary.json"), text).unwrap();
    }

    fn summary(method: &str, seed: u64, nmi: f64) -> String {
        format!(
            r#"{{"method":"{method}","env":"reacher","seed":{seed},"nmi":{nmi},"ent":0.5,
            "normalized_reward":0.8,"env_steps":2000000,"wall_seconds":100.0,"interrupted":false}}"#
        )
    }

    #[test]
    fn groups_runs_by_env_and_method_with_mean_and_std() {
        let d = tempfile::tempdir().unwrap();
        let mut rows = Vec::new();
        for (i, (m, nmi)) in [("ess-infogail", 0.6), ("ess-infogail", 0.7), ("gail", 0.2)]
            .iter()
            .enumerate()
        {
            let dir = d.path().join(format!("r{i}"));
            write(&dir, &summary(m, i as u64, *nmi));
            rows.push(read_run(&dir).unwrap());
        }
        let md = markdown(&rows);
        // Mean 0.65, sample std 0.0707 over the two ess-infogail seeds, beside the paper.
        assert!(
            md.contains("| reacher | ess-infogail | 2 | 0.650 ± 0.071 |"),
            "{md}"
        );
        assert!(md.contains("| 0.662 | 0.587 |"), "{md}");
        assert!(
            md.contains("| reacher | gail | 1 | 0.200 ± 0.000 |"),
            "{md}"
        );
    }

    #[test]
    fn a_bad_summary_names_the_file_and_the_field() {
        let d = tempfile::tempdir().unwrap();
        let e = read_run(&d.path().join("none")).unwrap_err().to_string();
        assert!(e.contains("none/summary.json"), "{e}");
        write(
            d.path(),
            r#"{"method":"gail","env":"reacher","seed":0,"nmi":"high"}"#,
        );
        let e = read_run(d.path()).unwrap_err().to_string();
        assert!(e.contains("summary.json") && e.contains("`nmi`"), "{e}");
        write(d.path(), "{not json");
        let e = read_run(d.path()).unwrap_err().to_string();
        assert!(e.contains("not JSON"), "{e}");
    }
}
