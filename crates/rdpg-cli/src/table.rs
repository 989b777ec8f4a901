//! `rdpg table`: rows × seeds aggregated, from a sweep's result files (`results/<sweep>/`,
//! committed, so tables regenerate on a fresh clone) or from run directories.
//!
//! Per row: each seed's stock-reward test (the chosen agent's first 100 test episodes), their
//! mean ± sample std over seeds, the interquartile mean (IQM) of the test episodes of all seeds
//! with a 95 % bootstrap confidence interval that resamples seeds (Agarwal et al. 2021:
//! runs are the unit), the paper's metrics (best R_100MA on the training reward; success over
//! the first 200 test episodes, or as many as every test ran) and, where the sweep says which
//! row is which, the paper's own Table I values. With `--versus ROW`, the IQM difference of every row to that
//! row with its 95 % CI: an ordering holds where the CI excludes 0.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::ObstacleRecord;
use rdpg_core::rng::NpRng;
use rdpg_core::stats::mean_std;
use rdpg_render::plot::{figure, LinePlot, Series, PALETTE};
use rdpg_render::save_png;

use crate::rundir::{read_json, RunDir, TestSummary};
use crate::sweep::TrialResult;

mod trials;

/// Arguments of `rdpg table`.
#[derive(Debug, Args)]
pub struct TableArgs {
    /// Result files, folders of result files (`results/<sweep>`), or run directories.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Also write the Markdown table here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write the table as CSV here.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Validation curves, one per row: the mean over seeds (PNG).
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Add the IQM difference of every row to this row, with its 95 % bootstrap CI.
    #[arg(long)]
    versus: Option<String>,
    /// Bootstrap resamples.
    #[arg(long, default_value_t = DEFAULT_RESAMPLES)]
    resamples: usize,
}

pub(crate) const DEFAULT_RESAMPLES: usize = 10_000;

/// Every bootstrap interval draws from a generator of its own with this seed, so a row's
/// interval and its difference to another row depend on their test episodes alone: the same
/// in any table that holds them, in any order, and in `rdpg claims`.
pub(crate) const BOOTSTRAP_SEED: u64 = 0;

/// Episodes of the stock-reward test.
const STOCK_TEST_EPISODES: usize = 100;

/// Every trial of `inputs`, each with the position of the input that held it.
fn read_inputs(inputs: &[PathBuf]) -> Result<Vec<(usize, TrialResult)>> {
    let mut out = Vec::new();
    for (k, p) in inputs.iter().enumerate() {
        if p.extension().is_some_and(|e| e == "toml") {
            let sweep = crate::sweep::Sweep::load(p)?;
            let got = read_inputs(std::slice::from_ref(&sweep.results)).with_context(|| {
                format!(
                    "sweep {}: no result file yet (rdpg sweep writes them)",
                    p.display()
                )
            })?;
            out.extend(got.into_iter().map(|(_, t)| (k, t)));
        } else if p.is_file() {
            out.push((k, read_json(p)?));
        } else if p.join("summary.json").exists() && p.join("config.toml").exists() {
            out.push((k, from_run(p, k)?));
        } else if p.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("reading {}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                // The sweep's ledger lies beside its result files.
                .filter(|f| {
                    f.extension().is_some_and(|e| e == "json")
                        && f.file_name().is_some_and(|n| n != "ledger.json")
                })
                .collect();
            files.sort();
            if files.is_empty() {
                bail!(
                    "{} holds no result file (*.json) and is no run",
                    p.display()
                );
            }
            for f in files {
                out.push((k, read_json(&f)?));
            }
        } else {
            bail!("{}: no such result file, folder or run", p.display());
        }
    }
    if out.is_empty() {
        bail!("no trial to tabulate");
    }
    Ok(out)
}

/// A run directory as a trial: its experiment name is the row.
fn from_run(dir: &Path, row_index: usize) -> Result<TrialResult> {
    let run = RunDir::new(dir);
    let exp = run.experiment()?;
    let summary = run.read_summary()?;
    let crate::sweep::RunRecord {
        updates,
        curve,
        versions,
    } = crate::sweep::run_record(&run)?;
    Ok(TrialResult {
        sweep: String::new(),
        row: summary.name.clone(),
        row_index,
        seed: exp.train.seed,
        paper: None,
        description: String::new(),
        versions,
        steps: summary.steps,
        frames: summary.steps * exp.train.action_repeat as u64,
        updates,
        curve,
        summary,
        command: format!("rdpg train --resume {}", dir.display()),
    })
}

/// Mean of `xs` trimmed by a quarter on each side (the interquartile mean; fractional ends
/// weighted, so that every sample size has one).
pub fn iqm(xs: &[f64]) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len() as f64;
    let (lo, hi) = (0.25 * n, 0.75 * n);
    let mut sum = 0.0;
    for (i, x) in v.iter().enumerate() {
        // The share of sample i's unit interval [i, i + 1) inside [lo, hi).
        let w = ((i as f64 + 1.0).min(hi) - (i as f64).max(lo)).max(0.0);
        sum += w * x;
    }
    sum / (hi - lo)
}

/// 95 % percentile bootstrap interval of `stat` over runs: each resample draws as many runs as
/// there are, with replacement, and pools their episodes.
fn bootstrap_ci(
    runs: &[&[f64]],
    resamples: usize,
    rng: &mut NpRng,
    stat: &dyn Fn(&[f64]) -> f64,
) -> (f64, f64) {
    let mut stats: Vec<f64> = (0..resamples)
        .map(|_| {
            let mut pooled = Vec::new();
            for _ in 0..runs.len() {
                let k = rng.integers(0, runs.len() as i64) as usize;
                pooled.extend_from_slice(runs[k]);
            }
            stat(&pooled)
        })
        .collect();
    stats.sort_by(f64::total_cmp);
    let at = |q: f64| stats[((q * (stats.len() - 1) as f64).round() as usize).min(stats.len() - 1)];
    (at(0.025), at(0.975))
}

/// One row of the table.
pub(crate) struct Row {
    /// The row's name.
    pub(crate) name: String,
    /// Its trials, by seed.
    pub(crate) trials: Vec<TrialResult>,
}

/// The trials of `inputs` (result files, folders of them, sweep files or run directories)
/// grouped into rows, each row's trials by seed, the rows in the order of the inputs and,
/// within one input, in its sweep's order.
pub(crate) fn load_rows(inputs: &[PathBuf]) -> Result<Vec<Row>> {
    // (first input holding the row, its index in that sweep, the row)
    let mut rows: Vec<(usize, usize, Row)> = Vec::new();
    for (input, t) in read_inputs(inputs)? {
        match rows.iter_mut().find(|(_, _, r)| r.name == t.row) {
            Some((first, index, r)) => {
                if r.trials.iter().any(|x| x.seed == t.seed) {
                    bail!("row {:?} has seed {} twice", t.row, t.seed);
                }
                if (input, t.row_index) < (*first, *index) {
                    (*first, *index) = (input, t.row_index);
                }
                r.trials.push(t);
            }
            None => rows.push((
                input,
                t.row_index,
                Row {
                    name: t.row.clone(),
                    trials: vec![t],
                },
            )),
        }
    }
    rows.sort_by_key(|&(input, index, _)| (input, index));
    Ok(rows
        .into_iter()
        .map(|(_, _, mut r)| {
            r.trials.sort_by_key(|t| t.seed);
            r
        })
        .collect())
}

/// The fewest seeds whose percentile bootstrap over seeds gives a confidence interval: one
/// seed has no spread to resample and two give 3 distinct resamples of a row; the results
/// protocol reports the IQM's interval from 3 seeds on.
pub(crate) const CI_MIN_SEEDS: usize = 3;

/// `"one seed"`, `"2 seeds"`.
pub(crate) fn seeds_word(n: usize) -> String {
    match n {
        1 => "one seed".into(),
        n => format!("{n} seeds"),
    }
}

/// `IQM(a) - IQM(b)` of the pooled test episodes of runs `a` and `b`, with its 95 % percentile
/// bootstrap interval: each draw resamples the runs of `a`, then of `b` (seeds are the unit).
pub(crate) fn iqm_difference(
    a: &[&[f64]],
    b: &[&[f64]],
    resamples: usize,
    rng: &mut NpRng,
) -> (f64, f64, f64) {
    let pooled = |runs: &[&[f64]]| {
        runs.iter()
            .flat_map(|x| x.iter().copied())
            .collect::<Vec<_>>()
    };
    let d = iqm(&pooled(a)) - iqm(&pooled(b));
    let mut draws: Vec<f64> = (0..resamples)
        .map(|_| {
            let (x, _) = bootstrap_ci(a, 1, rng, &iqm);
            let (y, _) = bootstrap_ci(b, 1, rng, &iqm);
            x - y
        })
        .collect();
    draws.sort_by(f64::total_cmp);
    let at = |q: f64| draws[(q * (draws.len() - 1) as f64).round() as usize];
    (d, at(0.025), at(0.975))
}

impl Row {
    /// Each seed's stock-test returns (the first 100 test episodes).
    pub(crate) fn tests(&self) -> Vec<&[f64]> {
        self.trials.iter().filter_map(stock_returns).collect()
    }
}

/// A trial's stock-test returns: its chosen agent's first 100 test episodes (`None` without
/// a test that recorded its episodes).
fn stock_returns(t: &TrialResult) -> Option<&[f64]> {
    let x = t.test()?;
    let first = &x.returns[..x.returns.len().min(STOCK_TEST_EPISODES)];
    (!first.is_empty()).then_some(first)
}

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or("–".into(), |x| format!("{x:.1}"))
}

/// `rdpg table`.
pub fn run(a: &TableArgs) -> Result<()> {
    if a.resamples < 100 {
        bail!("--resamples must be at least 100");
    }
    let rows = load_rows(&a.inputs)?;
    let versus = match &a.versus {
        Some(name) => Some(
            rows.iter()
                .find(|r| &r.name == name)
                .with_context(|| format!("--versus {name:?}: no such row"))?
                .tests()
                .into_iter()
                .map(<[f64]>::to_vec)
                .collect::<Vec<_>>(),
        ),
        None => None,
    };
    if versus.as_ref().is_some_and(Vec::is_empty) {
        bail!(
            "--versus {:?}: that row has no test episodes to compare with",
            a.versus.as_deref().unwrap_or_default()
        );
    }
    let mut md = String::new();
    // Each sweep the rows come from, once, in the rows' order.
    let mut sweeps: Vec<&TrialResult> = Vec::new();
    for t in rows.iter().flat_map(|r| &r.trials) {
        if !t.sweep.is_empty() && sweeps.iter().all(|s| s.sweep != t.sweep) {
            sweeps.push(t);
        }
    }
    for t in sweeps {
        let _ = writeln!(md, "Sweep `{}`. {}\n", t.sweep, t.description);
    }
    // Success over the first `n_success` test episodes of every seed: the paper's 200 where
    // every test ran that many, else as many as every test ran.
    let n_success = rows
        .iter()
        .flat_map(|r| &r.trials)
        .filter_map(|t| t.test().map(|x| x.successes.len()))
        .filter(|&n| n > 0)
        .min()
        .map_or(200, |n| n.min(200));
    let _ = write!(
        md,
        "| row | paper's row | seeds | agent steps (frames) | test per seed (stock, 100 ep.) | mean ± std over seeds | IQM [95 % CI] | success % ({n_success} test ep.) | R_100MA (training reward) | paper R_100MA | paper success % |"
    );
    if a.versus.is_some() {
        md += " IQM − versus [95 % CI] |";
    }
    md += "\n|---|---|---|---|---|---|---|---|---|---|---|";
    if a.versus.is_some() {
        md += "---|";
    }
    md += "\n";
    let mut csv = String::from(
        "row,paper_row,seeds,steps,frames,test_means,mean,std,iqm,iqm_lo,iqm_hi,success,success_episodes,r100ma_mean,r100ma_std,paper_r100ma,paper_success,versus_diff,versus_lo,versus_hi\n",
    );
    for r in &rows {
        let tests = r.tests();
        let means: Vec<f64> = tests.iter().map(|x| mean_std(x).0).collect();
        let seeds: Vec<String> = r.trials.iter().map(|t| t.seed.to_string()).collect();
        let (m, s) = if means.is_empty() {
            (f64::NAN, f64::NAN)
        } else {
            mean_std(&means)
        };
        let pooled: Vec<f64> = tests.iter().flat_map(|x| x.iter().copied()).collect();
        let (iq, (lo, hi)) = if pooled.is_empty() {
            (f64::NAN, (f64::NAN, f64::NAN))
        } else {
            (
                iqm(&pooled),
                bootstrap_ci(
                    &tests,
                    a.resamples,
                    &mut NpRng::from_seed(BOOTSTRAP_SEED),
                    &iqm,
                ),
            )
        };
        // Success over the first `n_success` test episodes of each seed.
        let success = r
            .trials
            .iter()
            .map(|t| {
                t.test()
                    .filter(|x| x.successes.len() >= n_success)
                    .map(|x| {
                        let n = x.successes[..n_success].iter().filter(|&&b| b).count();
                        100.0 * n as f64 / n_success as f64
                    })
            })
            .collect::<Option<Vec<f64>>>()
            .map(|v| mean_std(&v).0);
        let r100: Vec<f64> = r
            .trials
            .iter()
            .filter_map(|t| t.summary.best_r100_train_reward)
            .collect();
        let (r100m, r100s) = if r100.is_empty() {
            (None, None)
        } else {
            let (m, s) = mean_std(&r100);
            (Some(m), Some(s))
        };
        let paper = r.trials[0].paper.clone();
        let steps: Vec<u64> = r.trials.iter().map(|t| t.steps).collect();
        let frames: Vec<u64> = r.trials.iter().map(|t| t.frames).collect();
        let steps_label = if steps.windows(2).all(|w| w[0] == w[1]) {
            format!("{} ({})", steps[0], frames[0])
        } else {
            format!("{steps:?} (runs differ)")
        };
        let diff = versus.as_ref().filter(|_| !pooled.is_empty()).map(|v| {
            let vs: Vec<&[f64]> = v.iter().map(Vec::as_slice).collect();
            iqm_difference(
                &tests,
                &vs,
                a.resamples,
                &mut NpRng::from_seed(BOOTSTRAP_SEED),
            )
        });
        let per_seed: Vec<String> = means.iter().map(|x| format!("{x:.1}")).collect();
        let _ = write!(
            md,
            "| {}{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.name,
            r.trials[0]
                .summary
                .teachers
                .iter()
                .map(|t| format!(" (taught by {})", t.label()))
                .collect::<String>(),
            paper.as_ref().map_or("–", |p| p.label.as_str()),
            seeds.join(", "),
            steps_label,
            if per_seed.is_empty() {
                "– (no test episodes)".into()
            } else {
                per_seed.join(" / ")
            },
            match means.len() {
                0 => "–".into(),
                1 => format!("{m:.1} (one seed)"),
                _ => format!("{m:.1} ± {s:.1}"),
            },
            match tests.len() {
                0 => "–".into(),
                n if n < CI_MIN_SEEDS => format!("{iq:.1} ({}: no CI)", seeds_word(n)),
                _ => format!("{iq:.1} [{lo:.1}, {hi:.1}]"),
            },
            fmt_opt(success),
            match (r100m, r100s) {
                (Some(m), Some(_)) if r100.len() == 1 => format!("{m:.1}"),
                (Some(m), Some(s)) => format!("{m:.1} ± {s:.1}"),
                _ => "n/a (< 100 episodes)".into(),
            },
            paper.as_ref().map_or("–".into(), |p| p
                .r100ma
                .map_or("N/A".into(), |v| format!("{v:.1}"))),
            paper.as_ref().map_or("–".into(), |p| fmt_opt(p.success)),
        );
        if a.versus.is_some() {
            let cell = if a.versus.as_ref() == Some(&r.name) {
                "(reference)".into()
            } else {
                let fewest = versus
                    .as_ref()
                    .map_or(tests.len(), |v| v.len().min(tests.len()));
                diff.map_or("–".into(), |(d, l, h)| {
                    if fewest < CI_MIN_SEEDS {
                        format!("{d:+.1} ({}: no CI)", seeds_word(fewest))
                    } else {
                        format!("{d:+.1} [{l:+.1}, {h:+.1}]")
                    }
                })
            };
            let _ = write!(md, " {cell} |");
        }
        md += "\n";
        let o = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x}"));
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{m},{s},{iq},{lo},{hi},{},{n_success},{},{},{},{},{},{},{}",
            r.name,
            paper.as_ref().map_or("", |p| p.label.as_str()),
            seeds.join(";"),
            steps[0],
            frames[0],
            means
                .iter()
                .map(|x| x.to_string())
                .collect::<Vec<_>>()
                .join(";"),
            o(success),
            o(r100m),
            o(r100s),
            o(paper.as_ref().and_then(|p| p.r100ma)),
            o(paper.as_ref().and_then(|p| p.success)),
            o(diff.map(|d| d.0)),
            o(diff.map(|d| d.1)),
            o(diff.map(|d| d.2)),
        );
    }
    md += "\nTest: each seed's agent chosen on validation episodes, on its first 100 test \
           episodes (stock reward); mean ± sample std over seeds of the per-seed means. IQM: \
           interquartile mean of all seeds' test episodes; its 95 % CI resamples seeds (a \
           percentile bootstrap). Success: share of the first test episodes (as many as the \
           header says: the paper's 200 where every test ran them) that reached the end \
           without a fall, mean over seeds. R_100MA: best 100-episode moving average of \
           training returns (with exploration noise) on the training reward, the paper's \
           metric.\n";
    if let Some(t) = obstacle_table(&rows) {
        md += "\n";
        md += &t;
    }
    md += "\n";
    md += &trials::trial_table(&rows);
    let mut command = String::from("rdpg table");
    for i in &a.inputs {
        command += &format!(" {}", i.display());
    }
    if let Some(v) = &a.versus {
        command += &format!(" --versus {v}");
    }
    if a.resamples != DEFAULT_RESAMPLES {
        command += &format!(" --resamples {}", a.resamples);
    }
    let _ = writeln!(md, "\nMade by `{command}`.");
    print!("{md}");
    if let Some(out) = &a.out {
        std::fs::write(out, &md).with_context(|| format!("writing {}", out.display()))?;
    }
    if let Some(out) = &a.csv {
        std::fs::write(out, &csv).with_context(|| format!("writing {}", out.display()))?;
    }
    if let Some(out) = &a.plot {
        plot_rows(&rows, out)?;
    }
    Ok(())
}

/// Where each row's test episodes ended, for walkers whose tests recorded it: the share that
/// finished and that ran out of time, and per obstacle kind (stump, stairs, pit, as the terrain
/// generator makes them) the obstacles passed and the episodes that fell or got stuck at one,
/// summed over the seeds that recorded it (all test episodes of each). `None` when no test did.
fn obstacle_table(rows: &[Row]) -> Option<String> {
    let rank = |k: &str| match k {
        "stump" => 0,
        "stairs" => 1,
        "pit" => 2,
        "none" => 4,
        _ => 3,
    };
    let mut kinds: Vec<&str> = rows
        .iter()
        .flat_map(|r| &r.trials)
        .filter_map(|t| t.test())
        .flat_map(|x| x.obstacles.keys().map(String::as_str))
        .collect();
    if kinds.is_empty() {
        return None;
    }
    kinds.sort_by_key(|k| (rank(k), *k));
    kinds.dedup();
    let mut md = String::from(
        "Where the test episodes ended (all test episodes of each seed that recorded it, \
         summed; passed: obstacles passed; fell / stuck: episodes that ended by a fall at one, \
         or at the time limit in front of one; `none`: away from any obstacle):\n\n\
         | row | seeds | test episodes | finished | time limit |",
    );
    for k in &kinds {
        let cells = if *k == "none" {
            "fell / stuck"
        } else {
            "passed / fell / stuck"
        };
        let _ = write!(md, " {k}: {cells} |");
    }
    md += "\n|---|---|---|---|---|";
    md += &"---|".repeat(kinds.len());
    md += "\n";
    for r in rows {
        let tests: Vec<(u64, &TestSummary)> = r
            .trials
            .iter()
            .filter_map(|t| t.test().map(|x| (t.seed, x)))
            .filter(|(_, x)| !x.obstacles.is_empty())
            .collect();
        if tests.is_empty() {
            let _ = writeln!(
                md,
                "| {} | – (not recorded) | | | |{}",
                r.name,
                " |".repeat(kinds.len())
            );
            continue;
        }
        let episodes: usize = tests.iter().map(|(_, x)| x.returns.len()).sum();
        let finished: usize = tests
            .iter()
            .map(|(_, x)| x.successes.iter().filter(|&&b| b).count())
            .sum();
        let limit: f64 = tests
            .iter()
            .map(|(_, x)| x.time_limit_rate.unwrap_or(0.0) * x.returns.len() as f64)
            .sum();
        let seeds: Vec<String> = tests.iter().map(|(s, _)| s.to_string()).collect();
        let _ = write!(
            md,
            "| {} | {} | {episodes} | {finished} | {:.0} |",
            r.name,
            seeds.join(", "),
            limit
        );
        for k in &kinds {
            let sum = |f: fn(&ObstacleRecord) -> u64| -> u64 {
                tests
                    .iter()
                    .filter_map(|(_, x)| x.obstacles.get(*k))
                    .map(f)
                    .sum()
            };
            let (passed, fell, stuck) = (sum(|o| o.passed), sum(|o| o.fell), sum(|o| o.stuck));
            if *k == "none" {
                let _ = write!(md, " {fell} / {stuck} |");
            } else {
                let _ = write!(md, " {passed} / {fell} / {stuck} |");
            }
        }
        md += "\n";
    }
    Some(md)
}

/// The validation curves of each row: the mean over seeds at the steps every seed evaluated,
/// with a band of ± one standard deviation over seeds; x in frames where rows differ in action
/// repeat.
fn plot_rows(rows: &[Row], out: &Path) -> Result<()> {
    let repeat = |t: &TrialResult| t.frames / t.steps.max(1);
    let repeats: Vec<u64> = rows
        .iter()
        .flat_map(|r| r.trials.iter().map(repeat))
        .collect();
    let in_frames = repeats.windows(2).any(|w| w[0] != w[1]);
    let series: Vec<Series> = rows
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let scale = if in_frames {
                repeat(&r.trials[0]) as f64
            } else {
                1.0
            };
            let at_steps: Vec<(f64, Vec<f64>)> = r.trials[0]
                .curve
                .iter()
                .filter_map(|&(step, _)| {
                    let at: Vec<f64> = r
                        .trials
                        .iter()
                        .filter_map(|t| t.curve.iter().find(|c| c.0 == step).map(|c| c.1))
                        .collect();
                    (at.len() == r.trials.len()).then_some((step as f64 * scale, at))
                })
                .collect();
            Series {
                name: match r.trials.len() {
                    1 => format!("{} (1 seed)", r.name),
                    n => format!("{} ({n} seeds)", r.name),
                },
                points: at_steps.iter().map(|(x, v)| (*x, mean_std(v).0)).collect(),
                color: PALETTE[i % PALETTE.len()],
                band: at_steps
                    .iter()
                    .map(|(x, v)| {
                        let (m, s) = mean_std(v);
                        (*x, m - s, m + s)
                    })
                    .collect(),
            }
        })
        .collect();
    let plot = LinePlot {
        title: "Validation return: mean and ± std over seeds".into(),
        x_label: if in_frames { "frames" } else { "agent steps" }.into(),
        y_label: "mean return, stock reward".into(),
        series,
    };
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    save_png(&figure(&[plot], 1, 720, 440)?, out)
        .with_context(|| format!("writing {}", out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iqm_trims_a_quarter_each_side_with_fractional_ends() {
        // 8 values: the middle four.
        assert_eq!(iqm(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 100.0]), 4.5);
        // 3 values: [0.75, 2.25) covers a quarter of the first, all of the second, a quarter
        // of the third: (0.25 * 1 + 1 * 2 + 0.25 * 30) / 1.5.
        assert!((iqm(&[30.0, 1.0, 2.0]) - (0.25 + 2.0 + 7.5) / 1.5).abs() < 1e-12);
        assert_eq!(iqm(&[5.0]), 5.0);
    }

    #[test]
    fn bootstrap_interval_brackets_the_statistic_and_narrows_with_agreeing_runs() {
        let mut rng = NpRng::from_seed(1);
        let a: Vec<f64> = (0..100).map(|i| i as f64).collect();
        let b: Vec<f64> = (0..100).map(|i| 200.0 + i as f64).collect();
        let (lo, hi) = bootstrap_ci(&[&a, &b], 2000, &mut rng, &iqm);
        let whole: Vec<f64> = a.iter().chain(&b).copied().collect();
        assert!(lo < iqm(&whole) && iqm(&whole) < hi, "{lo} {hi}");
        let (lo2, hi2) = bootstrap_ci(&[&a, &a], 2000, &mut rng, &iqm);
        assert_eq!((lo2, hi2), (iqm(&a), iqm(&a)));
    }

    /// Rows from several inputs come in the order of the inputs, then of their sweeps; a row
    /// in two inputs gathers its seeds from both and stands where it first appears.
    #[test]
    fn rows_follow_their_inputs_then_their_sweeps() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
        let base: TrialResult =
            read_json(&root.join("results/hardcore-1m/td3-paper-s0.json")).unwrap();
        let dir = std::env::temp_dir().join(format!("rdpg-table-inputs-{}", std::process::id()));
        let inputs = [dir.join("a"), dir.join("b")];
        // (input, row, its index in that sweep, seed)
        for (input, row, row_index, seed) in [
            (0, "x", 1, 0),
            (0, "y", 0, 0),
            (1, "z", 0, 0),
            (1, "x", 0, 1),
        ] {
            let mut t = base.clone();
            (t.row, t.row_index, t.seed) = (row.into(), row_index, seed);
            std::fs::create_dir_all(&inputs[input]).unwrap();
            let file = inputs[input].join(format!("{row}-s{seed}.json"));
            std::fs::write(file, serde_json::to_string(&t).unwrap()).unwrap();
        }
        let rows = load_rows(&inputs).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let got: Vec<(&str, Vec<u64>)> = rows
            .iter()
            .map(|r| (r.name.as_str(), r.trials.iter().map(|t| t.seed).collect()))
            .collect();
        assert_eq!(got, [("y", vec![0]), ("x", vec![0, 1]), ("z", vec![0])]);
    }

    /// The obstacle table sums each row's seeds that recorded where their test episodes
    /// ended, lists the kinds in the terrain's order (`none` last), and says which row did not.
    #[test]
    fn obstacle_table_sums_the_seeds_that_recorded_it() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
        let base: TrialResult =
            read_json(&root.join("results/hardcore-1m/td3-paper-s0.json")).unwrap();
        let trial = |row: &str, seed: u64, obstacles: &[(&str, [u64; 3])], limit: f64| {
            let mut t = base.clone();
            t.row = row.into();
            t.seed = seed;
            let test = t.summary.test_eval.as_mut().unwrap();
            test.returns = vec![0.0; 10];
            test.successes = (0..10).map(|k| k < 3).collect();
            test.time_limit_rate = Some(limit);
            test.obstacles = obstacles
                .iter()
                .map(|(k, [passed, fell, stuck])| {
                    let o = ObstacleRecord {
                        passed: *passed,
                        fell: *fell,
                        stuck: *stuck,
                    };
                    (k.to_string(), o)
                })
                .collect();
            t
        };
        let rows = [
            Row {
                name: "a".into(),
                trials: vec![
                    trial("a", 0, &[("pit", [5, 1, 0]), ("none", [0, 2, 1])], 0.2),
                    trial("a", 1, &[("stump", [7, 3, 0]), ("pit", [4, 0, 2])], 0.5),
                ],
            },
            Row {
                name: "b".into(),
                trials: vec![trial("b", 0, &[], 0.0)],
            },
        ];
        let md = obstacle_table(&rows).unwrap();
        let lines: Vec<&str> = md.lines().filter(|l| l.starts_with('|')).collect();
        assert_eq!(
            lines[0],
            "| row | seeds | test episodes | finished | time limit | stump: passed / fell / stuck \
             | pit: passed / fell / stuck | none: fell / stuck |"
        );
        assert_eq!(
            lines[2],
            "| a | 0, 1 | 20 | 6 | 7 | 7 / 3 / 0 | 9 / 1 / 2 | 2 / 1 |"
        );
        assert_eq!(lines[3], "| b | – (not recorded) | | | | | | |");
        // No test recorded any: no table.
        assert!(obstacle_table(&rows[1..]).is_none());
    }
}
