//! What a sweep leaves to commit: one result file per finished trial ([`TrialResult`]) and
//! the ledger of all its trials ([`Ledger`]).

use super::{PaperRow, Sweep};
use crate::rundir::{
    copy_file, read_json, write_json, Metric, RunDir, Summary, TestSummary, Which,
};
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A finished trial's small result file (`results/<sweep>/<row>-s<seed>.json`): what
/// `rdpg table` aggregates, with no run directory needed.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrialResult {
    /// Sweep name.
    pub sweep: String,
    /// Row name.
    pub row: String,
    /// The row's place in the sweep file (tables list rows in this order).
    pub row_index: usize,
    /// Seed.
    pub seed: u64,
    /// The paper's row it reproduces.
    pub paper: Option<PaperRow>,
    /// The description of the sweep (its shared settings).
    #[serde(default)]
    pub description: String,
    /// The run's `versions.jsonl`: the binary and commit of its start and every resume.
    pub versions: Vec<serde_json::Value>,
    /// Agent steps done.
    pub steps: u64,
    /// Frames (agent steps × action repeat).
    pub frames: u64,
    /// Learner updates done.
    pub updates: u64,
    /// The run's summary (rewards, R_100MA, wall time, machine, its test).
    pub summary: Summary,
    /// Validation evaluations: (agent step, mean stock return).
    pub curve: Vec<(u64, f64)>,
    /// The command that reproduces it.
    pub command: String,
}

impl TrialResult {
    /// The test of the chosen agent.
    pub fn test(&self) -> Option<&TestSummary> {
        self.summary.test_eval.as_ref()
    }
}

/// What a run's files say beyond its summary ([`run_record`]).
pub struct RunRecord {
    /// Learner updates done.
    pub updates: u64,
    /// Validation evaluations: (agent step, mean stock return).
    pub curve: Vec<(u64, f64)>,
    /// The `versions.jsonl` lines.
    pub versions: Vec<serde_json::Value>,
}

/// Reads a run's [`RunRecord`] from its metrics and `versions.jsonl`.
pub fn run_record(run: &RunDir) -> Result<RunRecord> {
    let metrics = run.read_metrics()?;
    let updates = metrics
        .iter()
        .map(|m| match m {
            Metric::Episode { learner, .. } => learner.updates,
            Metric::Eval { .. } => 0,
        })
        .sum();
    let curve = metrics
        .iter()
        .filter_map(|m| match *m {
            Metric::Eval {
                step, mean_return, ..
            } => Some((step, mean_return)),
            Metric::Episode { .. } => None,
        })
        .collect();
    let versions = std::fs::read_to_string(run.versions())
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    Ok(RunRecord {
        updates,
        curve,
        versions,
    })
}

/// Whether a run's summary says it ended at `budget`: its test is written, or, in a tuning
/// sweep (no test), its final validation at the budget is (the summary reaches the budget's
/// steps before that evaluation runs). The sweep's driver (`sweep.py`, `_finished`) decides
/// the same.
fn finished(summary: &Summary, budget: u64, tuning: bool) -> bool {
    summary.steps >= budget
        && if tuning {
            summary.last_eval.as_ref().is_some_and(|e| e.step >= budget)
        } else {
            summary.test_eval.is_some()
        }
}

/// Writes the result file of every finished trial (and, with `keep_chosen_agents`, the kept run
/// directory of each that has none yet: [`keep_run`]); returns one line per file written.
pub(super) fn collect(sweep: &Sweep) -> Result<Vec<String>> {
    let mut out = Vec::new();
    for t in &sweep.trials {
        let run = RunDir::new(&t.run_dir);
        let Ok(summary) = run.read_summary() else {
            continue;
        };
        if !finished(&summary, t.steps, sweep.file.tuning) {
            continue;
        }
        let RunRecord {
            updates,
            curve,
            versions,
        } = run_record(&run)?;
        let mut command = format!("rdpg train --config {}", t.base.display());
        for s in &t.set {
            command += &format!(" --set '{s}'");
        }
        let r = TrialResult {
            sweep: sweep.file.name.clone(),
            row: t.row.clone(),
            row_index: t.row_index,
            seed: t.seed,
            paper: t.paper.clone(),
            description: sweep.file.description.clone(),
            versions,
            steps: summary.steps,
            frames: summary.steps * t.exp.train.action_repeat as u64,
            updates,
            summary,
            curve,
            command,
        };
        std::fs::create_dir_all(&sweep.results)
            .with_context(|| format!("creating {}", sweep.results.display()))?;
        let path = sweep.results.join(format!("{}.json", t.id));
        write_whole(&path, serde_json::to_string_pretty(&r)? + "\n")?;
        out.push(path.display().to_string());
        let kept = sweep.results.join("runs").join(&t.id);
        if sweep.file.keep_chosen_agents && !kept.exists() {
            keep_run(&run, &kept)?;
            out.push(kept.display().to_string());
        }
    }
    Ok(out)
}

/// Writes `contents` to `path` whole or not at all: beside it (`<name>.partial`), then renamed
/// into place, so a reader never sees half a file.
pub(super) fn write_whole(path: &Path, contents: impl AsRef<[u8]>) -> Result<()> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let partial = path.with_file_name(name);
    std::fs::write(&partial, contents).with_context(|| format!("writing {}", partial.display()))?;
    std::fs::rename(&partial, path)
        .with_context(|| format!("renaming {} to {}", partial.display(), path.display()))
}

/// Copies what `rdpg zoo`, `rdpg eval` and `rdpg render` read of a finished run to `to`: its
/// experiment, summary, metrics (with `evals.csv`), versions, teachers, and the agent chosen on
/// validation with its evaluation (`checkpoints/best/`), without the replay and optimiser state
/// of `checkpoints/latest/`. Whole or not at all: written beside and renamed into place.
fn keep_run(run: &RunDir, to: &Path) -> Result<()> {
    let mut name = to.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let partial = to.with_file_name(name);
    if partial.exists() {
        std::fs::remove_dir_all(&partial)
            .with_context(|| format!("removing {}", partial.display()))?;
    }
    std::fs::create_dir_all(&partial).with_context(|| format!("creating {}", partial.display()))?;
    let kept = RunDir::new(&partial);
    let Some(eval) = run.snapshot_agent(Which::Best, &kept.agent(Which::Best))? else {
        bail!(
            "{}: no agent chosen on validation (no eval.json) to keep",
            run.checkpoint(Which::Best).display()
        );
    };
    write_json(&kept.checkpoint(Which::Best).join("eval.json"), &eval)?;
    let mut files = vec![
        (run.config(), kept.config()),
        (run.summary(), kept.summary()),
        (run.metrics(), kept.metrics()),
        (run.versions(), kept.versions()),
        (run.root().join("evals.csv"), partial.join("evals.csv")),
    ];
    if run.teachers().exists() {
        files.push((run.teachers(), kept.teachers()));
    }
    for (from, into) in files {
        copy_file(&from, &into)?;
    }
    std::fs::rename(&partial, to)
        .with_context(|| format!("renaming {} to {}", partial.display(), to.display()))
}

/// One trial's line in the ledger.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedgerRow {
    /// `<row>-s<seed>`.
    pub trial: String,
    /// Row name.
    pub row: String,
    /// Seed.
    pub seed: u64,
    /// `finished`, `in progress` (checkpointed, not at its budget) or `not started`.
    pub status: String,
    /// Agent steps of its last checkpoint (its result's, once finished).
    pub steps: u64,
    /// Its budget.
    pub budget: u64,
    /// The binary commits that trained it (start and resumes), in order, without repeats.
    pub commits: Vec<String>,
    /// Times it started again from zero because its run directory was lost: its steps are
    /// those of the latest start, never spliced onto a lost one.
    pub restarts: u32,
    /// Unix time of its run's start (the `start` line of `versions.jsonl`): a resume keeps
    /// it, a start from zero changes it (absent until it starts, and in ledgers written
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub started: Option<u64>,
}

/// The committed record of a sweep's trials: what ran, how far, on which binary, and which
/// trials restarted after a lost machine (`results/<sweep>/ledger.json`, with a Markdown
/// view `ledger.md`). Each `--collect` rebuilds it from the run directories and the previous
/// ledger.
#[derive(Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ledger {
    /// Sweep name.
    pub sweep: String,
    /// One row per trial, in the sweep's order.
    pub trials: Vec<LedgerRow>,
}

fn unique_commits(versions: &[serde_json::Value]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for v in versions {
        if let Some(full) = v["commit"].as_str() {
            // The short hash, and `+dirty` for a binary built from changed files.
            let mut c: String = full.chars().take(12).collect();
            if full.ends_with("+dirty") {
                c += "+dirty";
            }
            if out.last() != Some(&c) {
                out.push(c);
            }
        }
    }
    out
}

/// Unix time of the `start` event among a run's version records.
fn start_time(versions: &[serde_json::Value]) -> Option<u64> {
    versions
        .iter()
        .find(|v| v["event"] == "start")
        .and_then(|v| v["unix_time"].as_u64())
}

/// Whether a trial, now at `steps` from a run started at `started` by `commits`, started
/// again from zero since its ledger row `old`: its steps went back (its run directory is
/// gone), or its run is another start than the row's — a later start time, or, for a row
/// written before start times were recorded, another first commit.
fn restarted(old: &LedgerRow, steps: u64, started: Option<u64>, commits: &[String]) -> bool {
    steps < old.steps
        || match (old.started, started) {
            (Some(then), Some(now)) => then != now,
            (None, Some(_)) => old
                .commits
                .first()
                .is_some_and(|c| Some(c) != commits.first()),
            _ => false,
        }
}

/// The ledger now, from the trials' result files and run directories and the ledger before
/// (its restart counts, and steps to compare with).
fn ledger(sweep: &Sweep, before: &Ledger) -> Result<Ledger> {
    let mut trials = Vec::new();
    for t in &sweep.trials {
        let old = before.trials.iter().find(|r| r.trial == t.id);
        let result = sweep.results.join(format!("{}.json", t.id));
        let run = RunDir::new(&t.run_dir);
        let (status, steps, versions) = if result.exists() {
            let r: TrialResult = read_json(&result)?;
            ("finished", r.steps, r.versions)
        } else if let Ok(summary) = run.read_summary() {
            ("in progress", summary.steps, run_record(&run)?.versions)
        } else {
            ("not started", 0, Vec::new())
        };
        let (commits, started) = (unique_commits(&versions), start_time(&versions));
        let again = old.is_some_and(|o| restarted(o, steps, started, &commits));
        trials.push(LedgerRow {
            trial: t.id.clone(),
            row: t.row.clone(),
            seed: t.seed,
            status: status.into(),
            steps,
            budget: t.steps,
            commits,
            restarts: old.map_or(0, |o| o.restarts) + u32::from(again),
            started,
        });
    }
    Ok(Ledger {
        sweep: sweep.file.name.clone(),
        trials,
    })
}

/// The ledger as a Markdown table.
fn ledger_markdown(l: &Ledger) -> String {
    let mut md = format!(
        "# Ledger of sweep `{}`\n\nWritten by `rdpg sweep <file> --collect` from the run \
         directories; a restarted trial started again from zero after its run directory was \
         lost.\n\n| trial | row | seed | status | steps | budget | commits | restarts |\n\
         |---|---|---:|---|---:|---:|---|---:|\n",
        l.sweep
    );
    for r in &l.trials {
        md += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.trial,
            r.row,
            r.seed,
            r.status,
            r.steps,
            r.budget,
            r.commits.join(", "),
            r.restarts
        );
    }
    md
}

/// Rebuilds and writes the sweep's ledger (JSON and Markdown); returns the JSON's path.
pub(super) fn write_ledger(sweep: &Sweep) -> Result<PathBuf> {
    let path = sweep.results.join("ledger.json");
    let before: Ledger = if path.exists() {
        read_json(&path)?
    } else {
        Ledger::default()
    };
    let l = ledger(sweep, &before)?;
    std::fs::create_dir_all(&sweep.results)
        .with_context(|| format!("creating {}", sweep.results.display()))?;
    write_whole(&path, serde_json::to_string_pretty(&l)? + "\n")?;
    write_whole(&sweep.results.join("ledger.md"), ledger_markdown(&l))?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(steps: u64, started: Option<u64>, commits: &[&str]) -> LedgerRow {
        LedgerRow {
            trial: "a-s0".into(),
            row: "a".into(),
            seed: 0,
            status: "in progress".into(),
            steps,
            budget: 1000,
            commits: commits.iter().map(|c| c.to_string()).collect(),
            restarts: 0,
            started,
        }
    }

    #[test]
    fn a_run_is_finished_by_its_test_or_in_tuning_its_last_validation() {
        let summary = |steps: u64, last_eval: Option<u64>, tested: bool| -> Summary {
            let eval = |step: u64| {
                serde_json::json!({ "step": step, "mean_stock_return": 1.0,
                                    "std_stock_return": 0.0, "success_rate": 0.0 })
            };
            serde_json::from_value(serde_json::json!({
                "name": "a", "algo": "rdpg", "env": "CueMemory-v0", "train_reward": "stock",
                "steps": steps, "episodes": 1, "wall_seconds": 1.0,
                "last_eval": last_eval.map(eval),
                "test_eval": tested.then(|| serde_json::json!({
                    "step": steps, "episodes": 1, "first_seed": 3, "mean_stock_return": 1.0,
                    "std_stock_return": 0.0, "success_rate": 0.0
                })),
            }))
            .unwrap()
        };
        // At its budget's steps before its final validation: not finished yet.
        assert!(!finished(&summary(800, Some(600), false), 800, true));
        assert!(finished(&summary(800, Some(800), false), 800, true));
        assert!(!finished(&summary(600, Some(600), false), 800, true));
        // A declared trial needs its test.
        assert!(!finished(&summary(800, Some(800), false), 800, false));
        assert!(finished(&summary(800, Some(800), true), 800, false));
    }

    #[test]
    fn ledger_commits_are_short_and_keep_dirty() {
        let v = |c: &str| serde_json::json!({ "commit": c });
        let a = "0123456789abcdef0123";
        let dirty = format!("{a}+dirty");
        assert_eq!(
            unique_commits(&[v(a), v(a), v(&dirty)]),
            ["0123456789ab", "0123456789ab+dirty"]
        );
    }

    #[test]
    fn a_restart_is_seen_even_once_it_has_passed_the_lost_runs_steps() {
        let c = |v: &[&str]| v.iter().map(|c| c.to_string()).collect::<Vec<_>>();
        let old = row(500, Some(7), &["aaa"]);
        // Resumed, on the same or another binary: the same start.
        assert!(!restarted(&old, 600, Some(7), &c(&["aaa", "bbb"])));
        // Lost: not started again yet, or started again and still behind, or already past.
        assert!(restarted(&old, 0, None, &[]));
        assert!(restarted(&old, 200, Some(9), &c(&["aaa"])));
        assert!(restarted(&old, 700, Some(9), &c(&["aaa"])));
        // A row written before start times: another first commit is another start.
        let legacy = row(357, None, &["aaa"]);
        assert!(restarted(&legacy, 400, Some(9), &c(&["bbb"])));
        assert!(!restarted(&legacy, 400, Some(9), &c(&["aaa", "bbb"])));
        // Counted when it was lost (steps went back to 0): its next start is not counted again.
        assert!(!restarted(&row(0, None, &[]), 50, Some(9), &c(&["bbb"])));
    }
}
