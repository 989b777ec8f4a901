//! `rdpg table`'s per-trial table: what the results protocol asks of every number (its
//! steps, updates, wall time, machine, binaries, the agent chosen on validation, its test and
//! its training reward), one line per row and seed, from the same result files as the table.

use std::fmt::Write as _;

use super::{stock_returns, Row};
use crate::sweep::TrialResult;
use crate::zoo::wall;

/// The per-trial table of `rows` (Markdown, with its heading sentence).
pub(super) fn trial_table(rows: &[Row]) -> String {
    let mut md = String::from(
        "Each trial (row and seed): agent steps and frames done, learner updates logged up to \
         its last training episode, training wall time and the machine of its last session, \
         the binaries it ran on (its start's, then each resume's, a commit repeated by \
         consecutive sessions once), the step of the agent chosen on validation and its \
         validation mean, that agent's stock test (mean ± std over its first 100 test \
         episodes), success over all its test episodes, and R_100MA on the training reward:\n\n\
         | row | seed | agent steps (frames) | updates | wall | machine | binaries | chosen at \
         (validation) | stock test, 100 ep. | success | R_100MA (training reward) |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        for t in &r.trials {
            let _ = writeln!(
                md,
                "| {} | {} | {} ({}) | {} | {} | {} | {} | {} | {} | {} | {} |",
                r.name,
                t.seed,
                t.steps,
                t.frames,
                t.updates,
                wall(t.summary.wall_seconds),
                t.summary.machine.as_deref().unwrap_or("–"),
                binaries(t),
                t.summary.best_eval.as_ref().map_or("–".into(), |e| format!(
                    "{} ({:.1})",
                    e.step, e.mean_stock_return
                )),
                stock_test(t),
                success(t),
                t.summary
                    .best_r100_train_reward
                    .map_or("n/a (< 100 episodes)".into(), |v| format!("{v:.1}")),
            );
        }
    }
    md
}

/// The commits of the trial's start and resumes, shortened, in order, a commit repeated by
/// consecutive sessions once (`"9d11ecb, 32ed845"`); `–` where the run recorded none.
fn binaries(t: &TrialResult) -> String {
    let mut commits: Vec<String> = t
        .versions
        .iter()
        .filter_map(|v| v.get("commit").and_then(serde_json::Value::as_str))
        .map(|c| {
            // `<40 hex digits>[+dirty]`: the hash shortened, the mark kept.
            let (hash, mark) = c.find('+').map_or((c, ""), |i| c.split_at(i));
            format!("{}{mark}", hash.get(..7).unwrap_or(hash))
        })
        .collect();
    commits.dedup();
    if commits.is_empty() {
        "–".into()
    } else {
        commits.join(", ")
    }
}

/// Mean ± std of the chosen agent's first 100 test episodes (the population std over
/// episodes, as `rdpg eval` and the run's summary give it).
fn stock_test(t: &TrialResult) -> String {
    match stock_returns(t) {
        Some(first) => {
            let n = first.len() as f64;
            let m = first.iter().sum::<f64>() / n;
            let s = (first.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n).sqrt();
            format!("{m:.1} ± {s:.1}")
        }
        None if t.test().is_some() => "– (no test episodes)".into(),
        None => "– (not tested)".into(),
    }
}

/// The share of the chosen agent's test episodes that finished the course, of how many.
fn success(t: &TrialResult) -> String {
    match t.test() {
        Some(x) if !x.successes.is_empty() => {
            let n = x.successes.iter().filter(|&&b| b).count();
            let of = x.successes.len();
            format!("{:.1} % of {of}", 100.0 * n as f64 / of as f64)
        }
        _ => "–".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(path: &str) -> TrialResult {
        let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
        crate::rundir::read_json(&root.join(path)).unwrap()
    }

    /// Committed result files' lines, checked against the values their runs recorded, and
    /// the cells of trials that lack a test, its episodes, a validation or versions.
    #[test]
    fn a_trials_line_gives_its_budget_binaries_choice_and_test() {
        let t = result("results/table1-cpu-recipes/rdpg-l128-s0.json");
        let mut twin = result("results/table1-cpu-recipes/td3-paper-s0.json");
        // A session back on an earlier binary is shown as such: A, B, A.
        twin.versions = ["a", "b", "b", "a"]
            .iter()
            .map(|c| serde_json::json!({ "commit": c.repeat(40) }))
            .collect();
        let mut untested = t.clone();
        untested.seed = 1;
        untested.summary.test_eval = None;
        untested.summary.best_eval = None;
        untested.summary.best_r100_train_reward = None;
        untested.versions.clear();
        let mut no_episodes = t.clone();
        no_episodes.seed = 2;
        if let Some(x) = no_episodes.summary.test_eval.as_mut() {
            x.returns.clear();
            x.successes.clear();
        }
        let rows = [
            Row {
                name: "rdpg-l128".into(),
                trials: vec![t, untested, no_episodes],
            },
            Row {
                name: "td3-paper".into(),
                trials: vec![twin],
            },
        ];
        let md = trial_table(&rows);
        let lines: Vec<&str> = md.lines().filter(|l| l.starts_with('|')).collect();
        assert_eq!(lines.len(), 6);
        assert_eq!(
            lines[2],
            "| rdpg-l128 | 0 | 500000 (1500000) | 244707 | 2.7 h | x86_64, 2 CPUs (Intel(R) \
             Xeon(R) Processor), 24 GiB RAM | c0fe54b+dirty, 9d11ecb | 425000 (-9.3) | -50.0 ± \
             67.7 | 0.0 % of 200 | 109.8 |"
        );
        assert!(
            lines[3].ends_with("| – | – | – (not tested) | – | n/a (< 100 episodes) |"),
            "{}",
            lines[3]
        );
        assert!(
            lines[4].ends_with("| 425000 (-9.3) | – (no test episodes) | – | 109.8 |"),
            "{}",
            lines[4]
        );
        assert_eq!(
            lines[5],
            "| td3-paper | 0 | 500000 (1500000) | 244919 | 48 min | x86_64, 2 CPUs (Intel(R) \
             Xeon(R) Processor), 24 GiB RAM | aaaaaaa, bbbbbbb, aaaaaaa | 375000 (220.8) | 154.7 \
             ± 116.9 | 69.5 % of 200 | 334.8 |"
        );
    }
}
