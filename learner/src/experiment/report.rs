//! The report of a grid: per metric a table of mean ± sample std over seeds (with the
//! number of seeds finished) beside the paper's number, under it each column's best
//! row and the rows seeds cannot separate from it ([`super::compare`]), the cells one
//! by one, and the spec's figure as PNG. Reads each cell's `jobs/<cell>/summary.json` and
//! `metrics.csv`, however the cell was run (job queue or Slurm).

use super::compare;
use super::spec::{Axis, Cell, ExperimentSpec, Figure};
use crate::eval::metrics::mean_std;
use crate::eval::plot::{PlotError, draw_curves};
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// Where a cell's run lives under an experiment's output directory.
pub fn cell_dir(out: &Path, cell: &Cell) -> PathBuf {
    out.join("jobs").join(&cell.id)
}

/// A cell's `summary.json` when its run finished (not stopped early).
pub fn finished(out: &Path, cell: &Cell) -> Option<Value> {
    let text = std::fs::read_to_string(cell_dir(out, cell).join("summary.json")).ok()?;
    let v: Value = serde_json::from_str(&text).ok()?;
    let stopped = v.get("interrupted").and_then(Value::as_bool) == Some(true);
    (!stopped).then_some(v)
}

/// A dotted field of a summary (`encoder_accuracy.balanced`) as a number.
pub fn metric(summary: &Value, path: &str) -> Option<f64> {
    path.split('.')
        .try_fold(summary, |v, k| v.get(k))
        .and_then(Value::as_f64)
}

/// The distinct values of `axis` in the spec's order.
fn axis_values(spec: &ExperimentSpec, axis: Axis) -> Vec<String> {
    match axis {
        Axis::Preset => spec.presets.clone(),
        Axis::Env => spec.envs.clone(),
        Axis::Variant if spec.variants.is_empty() => vec!["-".into()],
        Axis::Variant => spec.variants.iter().map(|v| v.name.clone()).collect(),
    }
}

/// The report as Markdown.
pub fn markdown(spec: &ExperimentSpec, cells: &[Cell], results: &[Option<Value>]) -> String {
    let mut s = String::new();
    let done = results.iter().filter(|r| r.is_some()).count();
    let _ = writeln!(s, "# {}\n", spec.name);
    if !spec.title.is_empty() {
        let _ = writeln!(s, "{}\n", spec.title);
    }
    let _ = writeln!(
        s,
        "{done} of {} cells finished. Each entry: mean ± sample std over the finished seeds (their number in brackets); the paper's value after it where it gives one.\n",
        cells.len()
    );
    let rows = axis_values(spec, spec.rows);
    let cols = axis_values(spec, spec.columns);
    for m in &spec.metrics {
        let _ = writeln!(s, "## {m}\n");
        let _ = writeln!(s, "| | {} |", cols.join(" | "));
        let _ = writeln!(s, "|---|{}", "---|".repeat(cols.len()));
        for r in &rows {
            let mut line = format!("| {r} |");
            for c in &cols {
                let xs = scores(spec, cells, results, (r, c), m);
                let ours = if xs.is_empty() {
                    "–".to_string()
                } else {
                    let (mean, std) = mean_std(&xs);
                    format!("{mean:.3} ± {std:.3} ({})", xs.len())
                };
                let paper = paper_value(spec, r, c, m)
                    .map(|p| format!(" [paper {p:.3}]"))
                    .unwrap_or_default();
                let _ = write!(line, " {ours}{paper} |");
            }
            let _ = writeln!(s, "{line}");
        }
        let _ = writeln!(s);
        leaders(&mut s, spec, cells, results, m);
    }
    cell_list(&mut s, spec, cells, results);
    s
}

/// The finished seeds' values of `metric` in the entry `(row, column)`.
fn scores(
    spec: &ExperimentSpec,
    cells: &[Cell],
    results: &[Option<Value>],
    (row, col): (&str, &str),
    m: &str,
) -> Vec<f64> {
    cells
        .iter()
        .zip(results)
        .filter(|(cell, _)| {
            cell.axis(spec, spec.rows) == row && cell.axis(spec, spec.columns) == col
        })
        .filter_map(|(_, res)| res.as_ref().and_then(|v| metric(v, m)))
        .collect()
}

/// Under a metric's table, each column's best row and the rows its seeds cannot
/// separate from it ([`compare::leader`]); nothing for a table of one row.
fn leaders(
    s: &mut String,
    spec: &ExperimentSpec,
    cells: &[Cell],
    results: &[Option<Value>],
    m: &str,
) {
    let rows = axis_values(spec, spec.rows);
    if rows.len() < 2 {
        return;
    }
    let better = if compare::higher_is_better(m) {
        "highest"
    } else {
        "lowest"
    };
    let _ = writeln!(
        s,
        "Best mean per column ({better}), and the rows an exact two-sided permutation test over seeds cannot separate from it (p >= {}):\n",
        compare::ALPHA
    );
    let mut starred = false;
    for c in axis_values(spec, spec.columns) {
        let entries: Vec<(String, Vec<f64>)> = rows
            .iter()
            .map(|r| (r.clone(), scores(spec, cells, results, (r, &c), m)))
            .collect();
        let Some(l) = compare::leader(m, &entries) else {
            continue;
        };
        let tied: Vec<String> = l
            .tied
            .iter()
            .map(|t| {
                let star = if t.beyond_reach() { "*" } else { "" };
                format!("{} {:.3} (p = {:.2}{star})", t.row, t.mean, t.p)
            })
            .collect();
        starred |= l.tied.iter().any(compare::Tied::beyond_reach);
        let tied = if tied.is_empty() {
            "none".to_string()
        } else {
            tied.join(", ")
        };
        let _ = writeln!(s, "- {c}: {} {:.3}; not separated: {tied}", l.row, l.mean);
    }
    if starred {
        let _ = writeln!(
            s,
            "\n\\* the two rows' seed counts cannot give p < {} whatever the scores (3 against 3: p >= 0.10).",
            compare::ALPHA
        );
    }
    let _ = writeln!(s);
}

/// The paper's number for a table entry: the spec's `[paper]`, else the built-in
/// Table 1 for a preset x env table.
fn paper_value(spec: &ExperimentSpec, row: &str, col: &str, metric: &str) -> Option<f64> {
    if let Some(v) = spec
        .paper
        .get(&format!("{row}/{col}"))
        .and_then(|t| t.get(metric))
    {
        return Some(*v);
    }
    let (preset, env) = match (spec.rows, spec.columns) {
        (Axis::Preset, Axis::Env) => (row, col),
        (Axis::Env, Axis::Preset) => (col, row),
        _ => return None,
    };
    if !spec.variants.is_empty() {
        return None;
    }
    let (nmi, ent) = crate::presets::paper_table1(env, preset)?;
    match metric {
        "nmi" => Some(nmi),
        "ent" => Some(ent),
        _ => None,
    }
}

fn cell_list(s: &mut String, spec: &ExperimentSpec, cells: &[Cell], results: &[Option<Value>]) {
    let _ = writeln!(s, "## Cells\n");
    let _ = writeln!(s, "| cell | {} | wall s |", spec.metrics.join(" | "));
    let _ = writeln!(s, "|---|{}---|", "---|".repeat(spec.metrics.len()));
    for (c, r) in cells.iter().zip(results) {
        let vals: Vec<String> = spec
            .metrics
            .iter()
            .map(|m| match r.as_ref().and_then(|v| metric(v, m)) {
                Some(x) => format!("{x:.3}"),
                None => "–".into(),
            })
            .collect();
        let wall = r
            .as_ref()
            .and_then(|v| metric(v, "wall_seconds"))
            .map_or("not finished".into(), |w| format!("{w:.0}"));
        let _ = writeln!(s, "| {} | {} | {wall} |", c.id, vals.join(" | "));
    }
}

/// `(env_steps, value)` of one `metrics.csv` column, rows where it is empty skipped.
fn csv_series(path: &Path, column: &str) -> Vec<(f64, f64)> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let (Some(xi), Some(yi)) = (
        header.iter().position(|h| *h == "env_steps"),
        header.iter().position(|h| *h == column),
    ) else {
        return Vec::new();
    };
    lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((f.get(xi)?.parse().ok()?, f.get(yi)?.parse().ok()?))
        })
        .collect()
}

/// Points averaged over the cells that have each x.
fn average(series: &[Vec<(f64, f64)>]) -> Vec<(f64, f64)> {
    let mut at: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    for s in series {
        for &(x, y) in s {
            at.entry(x as u64).or_default().push(y);
        }
    }
    at.into_iter()
        .map(|(x, ys)| (x as f64, mean_std(&ys).0))
        .collect()
}

/// Draws the spec's figure to `<out>/<name>.png`; `None` when it has none.
pub fn figure(
    spec: &ExperimentSpec,
    out: &Path,
    cells: &[Cell],
    results: &[Option<Value>],
) -> Result<Option<PathBuf>, PlotError> {
    let path = out.join(format!("{}.png", spec.name));
    let m = &spec.figure_metric;
    let series: Vec<Curve> = match spec.figure {
        Figure::None => return Ok(None),
        Figure::Curves => group(spec, cells, results, spec.rows, spec.columns)
            .into_iter()
            .map(|(name, members)| {
                let runs: Vec<_> = members
                    .iter()
                    .map(|c| csv_series(&cell_dir(out, c).join("metrics.csv"), m))
                    .collect();
                (name, average(&runs))
            })
            .collect(),
        Figure::Variants => {
            let other = if spec.rows == Axis::Variant {
                spec.columns
            } else {
                spec.rows
            };
            group(spec, cells, results, other, other)
                .into_iter()
                .map(|(name, members)| {
                    let runs: Vec<Vec<(f64, f64)>> = members
                        .iter()
                        .filter_map(|c| {
                            let x = spec.variants.get(c.variant?)?.x?;
                            let v = finished(out, c)?;
                            Some(vec![(x * 1e6, metric(&v, m)?)])
                        })
                        .collect();
                    let pts = average(&runs).into_iter().map(|(x, y)| (x / 1e6, y));
                    (name, pts.collect())
                })
                .collect()
        }
    };
    let (series, x_label) = match spec.figure {
        Figure::Curves => (series, "env steps"),
        _ => match log10_x_if_wide(&series) {
            Some(logged) => (logged, "log10 of variant x"),
            None => (series, "variant x"),
        },
    };
    draw_curves(&path, &format!("{}: {m}", spec.name), x_label, &series)?;
    Ok(Some(path))
}

/// One named line of a figure: `(x, y)` points.
type Curve = (String, Vec<(f64, f64)>);

/// The series with x as log10(x) when every x is positive and they span two decades
/// or more (Fig. 6's label ratios, 0.1% to 100%, would otherwise crowd into the first
/// pixels of a linear axis); `None` to keep them as they are.
fn log10_x_if_wide(series: &[Curve]) -> Option<Vec<Curve>> {
    let xs = || series.iter().flat_map(|(_, pts)| pts.iter().map(|p| p.0));
    let lo = xs().fold(f64::INFINITY, f64::min);
    let hi = xs().fold(f64::NEG_INFINITY, f64::max);
    if !(lo > 0.0 && hi.is_finite() && hi / lo >= 100.0) {
        return None;
    }
    let logged = series.iter().map(|(name, pts)| {
        (
            name.clone(),
            pts.iter().map(|&(x, y)| (x.log10(), y)).collect(),
        )
    });
    Some(logged.collect())
}

/// The finished cells grouped by their values on `a` (and `b` where it differs and has
/// more than one value), named `a-value` or `a-value / b-value`.
fn group<'a>(
    spec: &ExperimentSpec,
    cells: &'a [Cell],
    results: &[Option<Value>],
    a: Axis,
    b: Axis,
) -> Vec<(String, Vec<&'a Cell>)> {
    let two = a != b && axis_values(spec, b).len() > 1;
    let mut groups: Vec<(String, Vec<&Cell>)> = Vec::new();
    for (c, r) in cells.iter().zip(results) {
        if r.is_none() {
            continue;
        }
        let name = if two {
            format!("{} / {}", c.axis(spec, a), c.axis(spec, b))
        } else {
            c.axis(spec, a).to_string()
        };
        match groups.iter_mut().find(|(n, _)| *n == name) {
            Some((_, v)) => v.push(c),
            None => groups.push((name, vec![c])),
        }
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(extra: &str) -> ExperimentSpec {
        let text = format!(
            "name = \"t\"\npresets = [\"gail\", \"ess-infogail\"]\nenvs = [\"traj2d\"]\nseeds = [0, 1]\n{extra}"
        );
        let s: ExperimentSpec = toml::from_str(&text).unwrap();
        s.check().unwrap();
        s
    }

    #[test]
    fn entries_are_mean_and_sample_std_over_finished_seeds_beside_the_paper() {
        let s = spec("metrics = [\"nmi\", \"encoder_accuracy.balanced\"]");
        let cells = s.cells();
        let v =
            |nmi: f64| Some(serde_json::json!({"nmi": nmi, "encoder_accuracy": {"balanced": 0.5}}));
        // gail s0, gail s1 (unfinished), ess s0, ess s1.
        let results = vec![v(0.2), None, v(0.8), v(0.9)];
        let md = markdown(&s, &cells, &results);
        assert!(md.contains("3 of 4 cells finished"), "{md}");
        assert!(
            md.contains("| gail | 0.200 ± 0.000 (1) [paper 0.392] |"),
            "{md}"
        );
        assert!(
            md.contains("| ess-infogail | 0.850 ± 0.071 (2) [paper 0.910] |"),
            "{md}"
        );
        assert!(md.contains("| ess-infogail | 0.500 ± 0.000 (2) |"), "{md}");
        // One finished gail seed against two: 1 of the 3 splits is as extreme.
        assert!(
            md.contains("- traj2d: ess-infogail 0.850; not separated: gail 0.200 (p = 0.33*)"),
            "{md}"
        );
        assert!(
            md.contains("\\* the two rows' seed counts cannot give p < 0.05"),
            "{md}"
        );
        assert!(
            md.contains("| gail.traj2d.s1 | – | – | not finished |"),
            "{md}"
        );
    }

    #[test]
    fn the_specs_paper_numbers_take_precedence() {
        let s = spec("[paper]\n\"gail/traj2d\" = { nmi = 0.5 }");
        assert_eq!(paper_value(&s, "gail", "traj2d", "nmi"), Some(0.5));
        assert_eq!(
            paper_value(&s, "ess-infogail", "traj2d", "nmi"),
            Some(0.910)
        );
        assert_eq!(paper_value(&s, "gail", "traj2d", "normalized_reward"), None);
    }

    #[test]
    fn variants_spanning_two_decades_are_plotted_on_log10_x() {
        let s = |xs: &[f64]| vec![("a".to_string(), xs.iter().map(|&x| (x, 1.0)).collect())];
        let logged = log10_x_if_wide(&s(&[0.1, 0.5, 1.0, 10.0, 100.0])).expect("wide");
        let xs: Vec<f64> = logged[0].1.iter().map(|p| p.0).collect();
        let want = [-1.0, 0.5f64.log10(), 0.0, 1.0, 2.0];
        assert!(
            xs.iter().zip(want).all(|(x, w)| (x - w).abs() < 1e-12),
            "{xs:?}"
        );
        assert!(log10_x_if_wide(&s(&[2.0, 4.0, 12.0])).is_none());
        assert!(log10_x_if_wide(&s(&[0.0, 10.0, 1000.0])).is_none());
        assert!(log10_x_if_wide(&[]).is_none());
    }
}
