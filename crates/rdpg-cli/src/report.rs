//! `rdpg plot` and `rdpg compare`: learning curves and a Table-I-shaped comparison of runs.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_render::plot::{figure, LinePlot, Series, PALETTE};
use rdpg_render::save_png;

use crate::rundir::{Metric, MovingAverage, RunDir, Summary};

/// Arguments of `rdpg plot`.
#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories written by `rdpg train`, or zoo entries (their evaluations: a zoo
    /// entry ships no training episodes).
    #[arg(required = true)]
    runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long, default_value = "curves.png")]
    out: PathBuf,
}

/// Arguments of `rdpg compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Run directories written by `rdpg train`, or zoo entries.
    #[arg(required = true)]
    runs: Vec<PathBuf>,
    /// Also write the Markdown table to this file (it is always printed).
    #[arg(long)]
    out: Option<PathBuf>,
    /// The overlay plot of the runs' learning curves.
    #[arg(long, default_value = "compare.png")]
    plot: PathBuf,
}

/// What a run directory holds for reports.
struct Run {
    label: String,
    summary: Summary,
    /// `(step, return on the training reward)` of every training episode.
    episodes: Vec<(u64, f64)>,
    /// `(step, mean stock return)` of every evaluation.
    evals: Vec<(u64, f64)>,
    /// Frames per agent step (`train.action_repeat`): the steps above are agent steps.
    action_repeat: usize,
}

/// A run directory, or a zoo entry (its evaluations only: it ships no training episodes).
fn read_run(dir: &Path) -> Result<Run> {
    let run = RunDir::new(dir);
    let (summary, metrics) = if run.is_zoo_entry() {
        crate::rundir::read_as_run(&run)?
    } else {
        (run.read_summary()?, run.read_metrics()?)
    };
    let (mut episodes, mut evals) = (Vec::new(), Vec::new());
    for m in metrics {
        match m {
            Metric::Episode { step, ret, .. } => episodes.push((step, ret)),
            Metric::Eval {
                step, mean_return, ..
            } => evals.push((step, mean_return)),
        }
    }
    let mut label = if summary.name.is_empty() {
        dir.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    } else {
        summary.name.clone()
    };
    if run.is_zoo_entry() {
        label += " (zoo)";
    }
    Ok(Run {
        label,
        summary,
        episodes,
        evals,
        action_repeat: run.experiment()?.train.action_repeat,
    })
}

/// The [`MovingAverage`] of the training returns at every episode (over the episodes so far
/// before the window fills).
fn moving_average(episodes: &[(u64, f64)]) -> Vec<(f64, f64)> {
    let mut ma = MovingAverage::default();
    episodes
        .iter()
        .map(|&(step, r)| {
            ma.push(r);
            (step as f64, ma.mean().unwrap_or(r))
        })
        .collect()
}

/// The x axis of runs with these action repeats: their steps are agent steps, each of `k`
/// environment frames.
fn steps_label(repeats: impl Iterator<Item = usize>) -> String {
    let repeats: Vec<usize> = repeats.collect();
    match repeats.first() {
        Some(1) if repeats.iter().all(|&k| k == 1) => "environment steps".into(),
        Some(&k) if repeats.iter().all(|&r| r == k) => format!("agent steps ({k} frames each)"),
        _ => "agent steps (action repeats differ)".into(),
    }
}

/// Writes the two learning-curve panels of `runs` (training return, evaluation) to `out`.
fn write_curves(runs: &[Run], out: &Path) -> Result<()> {
    let rewards: Vec<&str> = runs
        .iter()
        .map(|r| r.summary.train_reward.as_str())
        .collect();
    let reward = if rewards.windows(2).all(|w| w[0] == w[1]) {
        format!("{} reward", rewards[0])
    } else {
        "training reward".into()
    };
    let x_label = steps_label(runs.iter().map(|r| r.action_repeat));
    let series = |f: &dyn Fn(&Run) -> Vec<(f64, f64)>| -> Vec<Series> {
        runs.iter()
            .enumerate()
            .map(|(i, r)| Series {
                name: r.label.clone(),
                points: f(r),
                color: PALETTE[i % PALETTE.len()],
                band: Vec::new(),
            })
            .collect()
    };
    let plots = [
        LinePlot {
            title: "Training return, 100-ep. MA".into(),
            x_label: x_label.clone(),
            y_label: format!("return, {reward}, with noise"),
            series: series(&|r| moving_average(&r.episodes)),
        },
        LinePlot {
            title: "Deterministic evaluation".into(),
            x_label,
            y_label: "mean return, stock reward".into(),
            series: series(&|r| r.evals.iter().map(|&(s, m)| (s as f64, m)).collect()),
        },
    ];
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)?;
    }
    save_png(&figure(&plots, 2, 560, 400)?, out)
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}

fn read_runs(dirs: &[PathBuf]) -> Result<Vec<Run>> {
    if dirs.len() > PALETTE.len() {
        bail!("at most {} runs at once", PALETTE.len());
    }
    let mut runs: Vec<Run> = dirs.iter().map(|d| read_run(d)).collect::<Result<_>>()?;
    // Runs of the same experiment are told apart by their directory names.
    let labels: Vec<String> = runs.iter().map(|r| r.label.clone()).collect();
    for (run, dir) in runs.iter_mut().zip(dirs) {
        if labels.iter().filter(|l| **l == run.label).count() > 1 {
            run.label = dir.display().to_string();
        }
    }
    Ok(runs)
}

/// `rdpg plot`.
pub fn plot(a: &PlotArgs) -> Result<()> {
    plot_runs(&a.runs, &a.out)?;
    println!("{}", a.out.display());
    Ok(())
}

/// The learning curves of the runs in `dirs` (training return, evaluation) as a PNG at `out`.
pub fn plot_runs(dirs: &[PathBuf], out: &Path) -> Result<()> {
    write_curves(&read_runs(dirs)?, out)
}

/// The comparison table in the shape of the paper's Table I.
fn table(runs: &[Run]) -> String {
    let mut t = String::new();
    t += "| model | env | training reward | steps | wall | R_100MA (training reward) | eval return ± std (stock reward, last) | best eval (stock) | success % (last eval) | test return ± std (stock, best agent) | test success % |\n";
    t += "|---|---|---|---|---|---|---|---|---|---|---|\n";
    for r in runs {
        let s = &r.summary;
        let r100 = s
            .best_r100_train_reward
            .map_or("n/a (< 100 episodes)".into(), |v| format!("{v:.1}"));
        let (last, success) = s.last_eval.map_or(("–".into(), "–".into()), |e| {
            (
                format!("{:.1} ± {:.1}", e.mean_stock_return, e.std_stock_return),
                format!("{:.1}", 100.0 * e.success_rate),
            )
        });
        let best = s.best_eval.map_or("–".into(), |e| {
            format!("{:.1} (step {})", e.mean_stock_return, e.step)
        });
        let (test, test_success) = s.test_eval.as_ref().map_or(("–".into(), "–".into()), |e| {
            (
                format!(
                    "{:.1} ± {:.1} ({} ep.)",
                    e.mean_stock_return, e.std_stock_return, e.episodes
                ),
                format!("{:.1}", 100.0 * e.success_rate),
            )
        });
        let _ = writeln!(
            t,
            "| {} ({}{}) | {} | {} | {} | {:.0} s | {} | {} | {} | {} | {} | {} |",
            r.label,
            s.algo,
            s.teachers
                .iter()
                .map(|t| format!("; taught by {}", t.label()))
                .collect::<String>(),
            s.env,
            if s.eval_reward == "stock" {
                s.train_reward.clone()
            } else {
                format!("{} (evaluation: {})", s.train_reward, s.eval_reward)
            },
            s.steps,
            s.wall_seconds,
            r100,
            last,
            best,
            success,
            test,
            test_success
        );
    }
    t += "\nR_100MA: best 100-episode moving average of training returns (with exploration noise) on \
          the training reward, the paper's metric. Evaluations: deterministic policy on held-out \
          validation seeds (they choose the best agent), stock Gymnasium reward. Test: the best \
          agent on separate test seeds, at the end of the run. Success: the environment's success flag (walkers: reached \
          the end of the course without falling).\n";
    t
}

/// `rdpg compare`.
pub fn compare(a: &CompareArgs) -> Result<()> {
    let runs = read_runs(&a.runs)?;
    let t = table(&runs);
    print!("{t}");
    if let Some(out) = &a.out {
        if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)?;
        }
        std::fs::write(out, &t).with_context(|| format!("writing {}", out.display()))?;
    }
    write_curves(&runs, &a.plot)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_labelled_by_action_repeat() {
        assert_eq!(steps_label([1, 1].into_iter()), "environment steps");
        assert_eq!(
            steps_label([3, 3].into_iter()),
            "agent steps (3 frames each)"
        );
        assert_eq!(
            steps_label([1, 3].into_iter()),
            "agent steps (action repeats differ)"
        );
    }

    #[test]
    fn moving_average_uses_at_most_100_episodes() {
        let eps: Vec<(u64, f64)> = (0..150)
            .map(|i| (i, if i < 50 { 0.0 } else { 1.0 }))
            .collect();
        let ma = moving_average(&eps);
        assert_eq!(ma[0], (0.0, 0.0));
        assert_eq!(ma[99].1, 0.5);
        assert_eq!(ma[149].1, 1.0);
    }
}
