//! What `--collect` writes of a tuning sweep (`tuning = true`), whose trials are never tested:
//! each started trial's validation curve (`<trial>-evals.csv`, running trials included) and one
//! table of every trial's validation at eighths of its budget (`validation.md`).

use super::results::{write_whole, TrialResult};
use super::{run_record, Budget, Sweep, Trial};
use crate::rundir::{read_json, RunDir};
use crate::zoo::steps_k;
use anyhow::{Context, Result};

/// Validation points: (agent step, mean stock return).
type Curve = Vec<(u64, f64)>;

/// A trial's validations so far: agent steps done and its curve; `None` before it starts.
fn progress(sweep: &Sweep, t: &Trial) -> Result<Option<(u64, Curve)>> {
    let run = RunDir::new(&t.run_dir);
    if let Ok(summary) = run.read_summary() {
        return Ok(Some((summary.steps, run_record(&run)?.curve)));
    }
    let result = sweep.results.join(format!("{}.json", t.id));
    if result.exists() {
        let r: TrialResult = read_json(&result)?;
        return Ok(Some((r.steps, r.curve)));
    }
    // Started, no summary written yet.
    Ok(run.root().exists().then(|| (0, Vec::new())))
}

/// The validation at `mark` agent steps: the last point at or before it, once the curve has
/// reached it.
fn at_mark(curve: &[(u64, f64)], mark: u64) -> Option<f64> {
    if curve.last().is_none_or(|&(s, _)| s < mark) {
        return None;
    }
    curve
        .iter()
        .rev()
        .find(|&&(s, _)| s <= mark)
        .map(|&(_, v)| v)
}

/// The best validation within the budget and its step.
fn best(curve: &[(u64, f64)], budget: u64) -> Option<(u64, f64)> {
    curve
        .iter()
        .filter(|&&(s, _)| s <= budget)
        .copied()
        .reduce(|a, b| if b.1 > a.1 { b } else { a })
}

/// `v` to one decimal, never `-0.0`.
fn one_decimal(v: f64) -> String {
    let s = format!("{v:.1}");
    if s == "-0.0" {
        "0.0".into()
    } else {
        s
    }
}

/// The validation table (Markdown): one line per trial, its validation mean at each eighth of
/// its budget and its best within the budget.
pub(super) fn validation_table(sweep: &Sweep) -> Result<String> {
    const MARKS: u64 = 8;
    let budget = sweep.budget;
    let unit = match budget {
        Budget::Steps(_) => "agent steps",
        Budget::Frames(_) => "frames",
    };
    let total = match budget {
        Budget::Steps(n) | Budget::Frames(n) => n,
    };
    let mut md = format!(
        "# Validation of tuning sweep `{}`\n\n{}\n\nWritten by `rdpg sweep <file> --collect`: \
         each trial's mean stock return over its validation episodes at each eighth of its \
         budget ({unit}; empty: not reached, or no validation yet), and its best within the budget. Tuning trials \
         are never tested: these numbers choose a recipe, they are no result.\n\n| trial | \
         agent steps done |",
        sweep.file.name, sweep.file.description
    );
    for k in 1..=MARKS {
        md += &format!(" {} |", steps_k(total * k / MARKS));
    }
    md += " best (agent step) |\n|---|---:|";
    md += &"---:|".repeat(MARKS as usize + 1);
    md += "\n";
    for t in &sweep.trials {
        let Some((steps, curve)) = progress(sweep, t)? else {
            md += &format!(
                "| {} | not started |{}\n",
                t.id,
                " |".repeat(MARKS as usize + 1)
            );
            continue;
        };
        md += &format!("| {} | {} / {} |", t.id, steps, t.steps);
        for k in 1..=MARKS {
            let v = at_mark(&curve, t.steps * k / MARKS);
            md += &v.map_or(" |".into(), |v| format!(" {} |", one_decimal(v)));
        }
        md += &best(&curve, t.steps).map_or(" – |".into(), |(s, v)| {
            format!(" {} ({}) |", one_decimal(v), steps_k(s))
        });
        md += "\n";
    }
    Ok(md)
}

/// Writes each started trial's `<trial>-evals.csv` and the sweep's `validation.md` under its
/// results folder; returns the paths written.
pub(super) fn write_validation(sweep: &Sweep) -> Result<Vec<String>> {
    std::fs::create_dir_all(&sweep.results)
        .with_context(|| format!("creating {}", sweep.results.display()))?;
    let mut out = Vec::new();
    for t in &sweep.trials {
        let from = t.run_dir.join("evals.csv");
        if from.exists() {
            let to = sweep.results.join(format!("{}-evals.csv", t.id));
            let csv =
                std::fs::read(&from).with_context(|| format!("reading {}", from.display()))?;
            write_whole(&to, csv)?;
            out.push(to.display().to_string());
        }
    }
    let path = sweep.results.join("validation.md");
    write_whole(&path, validation_table(sweep)?)?;
    out.push(path.display().to_string());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marks_read_the_last_validation_at_or_before_them_once_reached() {
        let curve = [(25, -10.0), (50, -5.0), (75, 3.0)];
        assert_eq!(at_mark(&curve, 50), Some(-5.0));
        assert_eq!(
            at_mark(&curve, 60),
            Some(-5.0),
            "between points: the last before"
        );
        assert_eq!(at_mark(&curve, 75), Some(3.0));
        assert_eq!(at_mark(&curve, 100), None, "not reached yet");
        assert_eq!(at_mark(&curve, 10), None, "no point before it");
        assert_eq!(at_mark(&[], 10), None);
        assert_eq!(best(&curve, 60), Some((50, -5.0)), "within the budget only");
        assert_eq!(best(&curve, 100), Some((75, 3.0)));
        assert_eq!(best(&[], 100), None);
        assert_eq!(one_decimal(-0.04), "0.0");
        assert_eq!(one_decimal(-0.05), "-0.1");
    }
}
