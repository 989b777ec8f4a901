//! `rdpg table`'s per-trial table: what the results protocol asks of every number (its
//! steps, updates, wall time, machine, binaries, the agent chosen on validation, its test and
//! its training reward), one line per row and seed, from the same result files as the table.

use std::fmt::Write as _;

use super::{Row, STOCK_TEST_EPISODES};
use crate::sweep::TrialResult;

/// The per-trial table of `rows` (Markdown, with its heading sentence).
pub(super) fn trial_table(rows: &[Row]) -> String {
    let mut md = String::from(
        "Each trial (row and seed): agent steps and frames done, learner updates, training wall \
         time and the machine of its last session, the binaries it ran on (its start, then \
         each resume's, in order), the step of the agent chosen on validation and its \
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
                t.test()
                    .filter(|x| !x.successes.is_empty())
                    .map_or("–".into(), |x| {
                        let n = x.successes.iter().filter(|&&b| b).count();
                        format!(
                            "{:.1} % of {}",
                            100.0 * n as f64 / x.successes.len() as f64,
                            x.successes.len()
                        )
                    }),
                t.summary
                    .best_r100_train_reward
                    .map_or("n/a (< 100 episodes)".into(), |v| format!("{v:.1}")),
            );
        }
    }
    md
}

/// `"2 h 41 min"`, `"52 min"`.
fn wall(seconds: f64) -> String {
    let minutes = (seconds / 60.0).round() as u64;
    match minutes / 60 {
        0 => format!("{minutes} min"),
        h => format!("{h} h {:02} min", minutes % 60),
    }
}

/// The commits of the trial's start and resumes, shortened, each once, in order
/// (`"9d11ecb, 32ed845"`); `–` where the run recorded none.
fn binaries(t: &TrialResult) -> String {
    let mut commits: Vec<String> = Vec::new();
    for v in &t.versions {
        let Some(c) = v.get("commit").and_then(|c| c.as_str()) else {
            continue;
        };
        let (hash, dirty) = c.split_once('+').map_or((c, ""), |(h, d)| (h, d));
        let short = match dirty {
            "" => hash.chars().take(7).collect(),
            d => format!("{}+{d}", hash.chars().take(7).collect::<String>()),
        };
        if !commits.contains(&short) {
            commits.push(short);
        }
    }
    if commits.is_empty() {
        "–".into()
    } else {
        commits.join(", ")
    }
}

/// Mean ± std of the chosen agent's first 100 test episodes (the population std over
/// episodes, as `rdpg eval` and the run's summary give it).
fn stock_test(t: &TrialResult) -> String {
    match t.test() {
        Some(x) if !x.returns.is_empty() => {
            let first = &x.returns[..x.returns.len().min(STOCK_TEST_EPISODES)];
            let n = first.len() as f64;
            let m = first.iter().sum::<f64>() / n;
            let s = (first.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n).sqrt();
            format!("{m:.1} ± {s:.1}")
        }
        Some(x) => format!("{:.1} ± {:.1}", x.mean_stock_return, x.std_stock_return),
        None => "– (not tested)".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A committed result file's line, checked against the values its run recorded.
    #[test]
    fn a_trials_line_gives_its_budget_binaries_choice_and_test() {
        let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
        let t: TrialResult =
            crate::rundir::read_json(&root.join("results/table1-cpu-recipes/rdpg-l128-s0.json"))
                .unwrap();
        let mut untested = t.clone();
        untested.seed = 1;
        untested.summary.test_eval = None;
        untested.summary.best_r100_train_reward = None;
        untested.versions.clear();
        let rows = [Row {
            name: "rdpg-l128".into(),
            trials: vec![t, untested],
        }];
        let md = trial_table(&rows);
        let lines: Vec<&str> = md.lines().filter(|l| l.starts_with('|')).collect();
        assert_eq!(lines.len(), 4);
        assert_eq!(
            lines[2],
            "| rdpg-l128 | 0 | 500000 (1500000) | 244707 | 2 h 41 min | x86_64, 2 CPUs (Intel(R) \
             Xeon(R) Processor), 24 GiB RAM | c0fe54b+dirty, 9d11ecb | 425000 (-9.3) | -50.0 ± \
             67.7 | 0.0 % of 200 | 109.8 |"
        );
        assert!(
            lines[3].ends_with("| – | 425000 (-9.3) | – (not tested) | – | n/a (< 100 episodes) |"),
            "{}",
            lines[3]
        );
    }

    #[test]
    fn wall_time_reads_in_hours_and_minutes() {
        assert_eq!(wall(52.4 * 60.0), "52 min");
        assert_eq!(wall(9662.2), "2 h 41 min");
        assert_eq!(wall(7200.0), "2 h 00 min");
    }
}
