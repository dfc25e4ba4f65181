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

/// The normalised reward of each code at every evaluation of the run in `dir` (periodic
/// and final), from `metrics.csv`'s `normalized_reward_per_code` column, as
/// `(env steps, reward per code)`. Empty when the file or the column is absent (runs
/// that predate it); a cell that is not numbers joined by `;` names the file and line.
pub fn reward_curve_per_code(dir: &Path) -> Result<Vec<(u64, Vec<f64>)>, TableError> {
    let path = dir.join("metrics.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(Vec::new());
    };
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let col = |name: &str| head.iter().position(|h| *h == name);
    let (Some(xi), Some(yi)) = (col("env_steps"), col("normalized_reward_per_code")) else {
        return Ok(Vec::new());
    };
    let mut curve = Vec::new();
    for (i, line) in lines.enumerate() {
        let cells: Vec<&str> = line.split(',').collect();
        let cell = cells.get(yi).copied().unwrap_or_default();
        if cell.is_empty() {
            continue;
        }
        let bad = |what: &str| TableError::Field {
            path: path.clone(),
            message: format!("line {}: {what}", i + 2),
        };
        let steps = cells.get(xi).and_then(|c| c.parse().ok());
        let steps = steps.ok_or_else(|| bad("`env_steps` is not a whole number"))?;
        let rewards = cell
            .split(';')
            .map(str::parse)
            .collect::<Result<Vec<f64>, _>>();
        let rewards = rewards.map_err(|_| {
            bad(&format!(
                "`normalized_reward_per_code` {cell:?} is not numbers joined by `;`"
            ))
        })?;
        curve.push((steps, rewards));
    }
    Ok(curve)
}

/// The curve of [`reward_curve_per_code`] as Markdown: a row per evaluation, a column
/// per code.
pub fn curve_markdown(dir: &Path, curve: &[(u64, Vec<f64>)]) -> String {
    let k = curve.iter().map(|(_, r)| r.len()).max().unwrap_or(0);
    let mut s = format!(
        "\n### {}: normalised reward per code against env steps (every evaluation)\n\n| env steps |",
        dir.display()
    );
    for c in 0..k {
        let _ = write!(s, " code {c} |");
    }
    let _ = write!(s, "\n|---|{}\n", "---|".repeat(k));
    for (steps, rewards) in curve {
        let _ = write!(s, "| {steps} |");
        for r in rewards {
            let _ = write!(s, " {r:.3} |");
        }
        let _ = writeln!(s);
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
    fn the_curve_per_code_reads_the_evaluated_rows_and_names_a_bad_cell() {
        let d = tempfile::tempdir().unwrap();
        assert!(
            reward_curve_per_code(d.path()).unwrap().is_empty(),
            "no file"
        );
        let csv = |rows: &str| {
            let head = "iteration,env_steps,nmi,normalized_reward_per_code";
            std::fs::write(d.path().join("metrics.csv"), format!("{head}\n{rows}")).unwrap();
        };
        csv("1,5000,,\n2,10000,0.9,0.100000;0.250000\n3,15000,0.8,0.5;1.0\n");
        let curve = reward_curve_per_code(d.path()).unwrap();
        assert_eq!(curve, [(10000, vec![0.1, 0.25]), (15000, vec![0.5, 1.0])]);
        let md = curve_markdown(d.path(), &curve);
        assert!(md.contains("| env steps | code 0 | code 1 |"), "{md}");
        assert!(md.contains("| 15000 | 0.500 | 1.000 |"), "{md}");
        csv("1,5000,0.9,0.1;high\n");
        let e = reward_curve_per_code(d.path()).unwrap_err().to_string();
        assert!(
            e.contains("metrics.csv: line 2") && e.contains("\"0.1;high\""),
            "{e}"
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
