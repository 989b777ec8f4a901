//! `rdpg claims FILE`: the paper's claims, each checked as orderings of a sweep's rows.
//!
//! A claims file (TOML) lists claims; each names a sweep file and one or more pairs of its
//! rows, `better` above `worse`. A pair is measured by the difference of the interquartile
//! means of the two rows' stock-reward tests (the first 100 test episodes of every seed),
//! with a 95 % percentile bootstrap interval that resamples seeds ([`crate::table`], the
//! same numbers as `rdpg table --versus`). Its verdict, once both rows have every seed the
//! sweep declares: **holds** where the interval lies above 0, **does not hold** where it lies
//! below, **unresolved** otherwise; before that the numbers so far are shown as **pending**.
//! A sweep that declares fewer than [`CI_MIN_SEEDS`] seeds gets no verdict but "unresolved": its
//! rows resample too few seeds for a percentile interval (2 seeds give 3 distinct resamples
//! of a row), and the results protocol reports the IQM interval from 3 seeds on.
//! A claim holds when every one of its pairs holds, and compares rows of one budget in env
//! frames (agent steps times the action repeat). `sweep` may name several sweep files (a
//! recipe declared in a sweep of its own against a twin in another): each row is looked up
//! in the one sweep that has it, and its seeds are those that sweep declares.
//!
//! ```toml
//! [[claim]]
//! claim = "Experience injection improves RDPG"
//! paper = "Table I: R_100MA 238.5 vs 227.5, success 32.5 vs 23.5 %"
//! sweep = "sweeps/table1-cpu.toml"
//! better = ["rdpg-injection"]
//! worse = "rdpg"
//! ```

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_core::rng::NpRng;
use serde::Deserialize;

use crate::sweep::{Sweep, Trial};
use crate::table::{
    iqm_difference, load_rows, seeds_word, Row, BOOTSTRAP_SEED, CI_MIN_SEEDS, DEFAULT_RESAMPLES,
};

/// Arguments of `rdpg claims`.
#[derive(Debug, Args)]
pub struct ClaimsArgs {
    /// The claims file (TOML).
    file: PathBuf,
    /// Also write the Markdown here.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// A claims file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClaimsFile {
    #[serde(rename = "claim")]
    claims: Vec<Claim>,
}

/// One claim: `better[i]` above `worse` for every `i`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Claim {
    /// The claim, in words.
    claim: String,
    /// The paper's evidence for it.
    paper: String,
    /// The sweep file whose rows measure it, or a list of sweep files in which each of the
    /// claim's rows is found once.
    sweep: Sweeps,
    /// Rows claimed above `worse`.
    better: Vec<String>,
    /// The row claimed below each of `better`.
    worse: String,
}

/// One sweep file, or several.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum Sweeps {
    One(PathBuf),
    Many(Vec<PathBuf>),
}

impl Sweeps {
    fn paths(&self) -> &[PathBuf] {
        match self {
            Sweeps::One(p) => std::slice::from_ref(p),
            Sweeps::Many(v) => v,
        }
    }
}

/// Where one pair stands.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Verdict {
    NotRun,
    Pending,
    Holds,
    Reversed,
    Unresolved,
    /// Every declared seed has run, but the sweep declares fewer than [`CI_MIN_SEEDS`].
    TooFewSeeds,
}

/// One pair's numbers (none before both rows have a seed) and verdict.
struct Pair {
    text: Option<String>,
    verdict: Verdict,
}

/// The test returns of each seed of `row` that has them.
fn tests_of<'a>(rows: &'a [Row], row: &str) -> Vec<&'a [f64]> {
    rows.iter()
        .find(|r| r.name == row)
        .map_or_else(Vec::new, Row::tests)
}

/// `better − worse`, each row with the seeds its sweep declares.
fn measure(rows: &[Row], (better, da): (&str, usize), (worse, db): (&str, usize)) -> Pair {
    let (a, b) = (tests_of(rows, better), tests_of(rows, worse));
    if a.is_empty() || b.is_empty() {
        return Pair {
            text: None,
            verdict: Verdict::NotRun,
        };
    }
    let (d, lo, hi) = iqm_difference(
        &a,
        &b,
        DEFAULT_RESAMPLES,
        &mut NpRng::from_seed(BOOTSTRAP_SEED),
    );
    let verdict = if a.len() < da || b.len() < db {
        Verdict::Pending
    } else if da.min(db) < CI_MIN_SEEDS {
        Verdict::TooFewSeeds
    } else if lo > 0.0 {
        Verdict::Holds
    } else if hi < 0.0 {
        Verdict::Reversed
    } else {
        Verdict::Unresolved
    };
    let fewest = a.len().min(b.len());
    let interval = if fewest < CI_MIN_SEEDS {
        format!("({}: no CI)", seeds_word(fewest))
    } else {
        format!("[{lo:+.1}, {hi:+.1}]")
    };
    Pair {
        text: Some(format!("{better} − {worse}: {d:+.1} {interval}")),
        verdict,
    }
}

/// The claim's rows that have not run every declared seed: `"ddpg 0 of 3 seeds"`.
fn waiting(rows: &[Row], declared: &[(&str, usize)]) -> Vec<String> {
    declared
        .iter()
        .filter_map(|&(n, d)| {
            let done = tests_of(rows, n).len();
            (done < d).then(|| format!("{n} {done} of {d} seeds"))
        })
        .collect()
}

/// The measured cell: each pair's numbers, then the rows still waiting for seeds.
fn measured(pairs: &[Pair], waiting: &[String]) -> String {
    let mut parts: Vec<String> = pairs.iter().filter_map(|p| p.text.clone()).collect();
    if !waiting.is_empty() {
        parts.push(format!("waiting for {}", waiting.join(", ")));
    }
    parts.join("; ")
}

/// The claim's verdict from its pairs'.
fn overall(pairs: &[Pair], declared: usize) -> String {
    let any = |v: Verdict| pairs.iter().any(|p| p.verdict == v);
    if any(Verdict::NotRun) {
        "not measured yet".into()
    } else if any(Verdict::Pending) {
        "pending (seeds still running)".into()
    } else if pairs.iter().all(|p| p.verdict == Verdict::Holds) {
        "**holds**".into()
    } else if any(Verdict::Reversed) {
        "**does not hold**".into()
    } else if any(Verdict::TooFewSeeds) {
        format!("unresolved at {declared} seeds (a verdict needs {CI_MIN_SEEDS})")
    } else {
        format!("unresolved at {declared} seeds")
    }
}

/// `rdpg claims`.
pub fn run(a: &ClaimsArgs) -> Result<()> {
    let text = std::fs::read_to_string(&a.file)
        .with_context(|| format!("reading {}", a.file.display()))?;
    let file: ClaimsFile = toml::from_str(&text)
        .with_context(|| format!("invalid claims file {}", a.file.display()))?;
    if file.claims.is_empty() {
        bail!("{}: no [[claim]]", a.file.display());
    }
    let mut md = String::from(
        "| claim | the paper's evidence | measured: IQM difference of the stock tests [95 % CI] | verdict | where |\n|---|---|---|---|---|\n",
    );
    for c in &file.claims {
        if c.better.is_empty() {
            bail!("claim {:?}: `better` names no row", c.claim);
        }
        let sweeps = c
            .sweep
            .paths()
            .iter()
            .map(|p| Sweep::load(p).with_context(|| format!("claim {:?}", c.claim)))
            .collect::<Result<Vec<_>>>()?;
        if sweeps.is_empty() {
            bail!("claim {:?}: `sweep` names no sweep file", c.claim);
        }
        // Each named row, with the seeds its own sweep declares.
        let mut declared: Vec<(&str, usize)> = Vec::new();
        // The first row's budget in env frames, which every other row must train too.
        let mut budget: Option<(&str, u64)> = None;
        for row in c.better.iter().chain([&c.worse]) {
            // Each sweep holding the row, with one of the row's trials.
            let holders: Vec<(&Sweep, &Trial)> = sweeps
                .iter()
                .filter_map(|s| Some((s, s.trials.iter().find(|t| &t.row == row)?)))
                .collect();
            match holders[..] {
                [(s, trial)] => {
                    let frames = trial.frames();
                    match budget {
                        Some((first, f)) if f != frames => bail!(
                            "claim {:?}: row {first:?} trains {f} env frames and row {row:?} \
                             {frames}; a claim compares rows at an equal budget",
                            c.claim
                        ),
                        Some(_) => {}
                        None => budget = Some((row, frames)),
                    }
                    declared.push((row, s.file.seeds.len()));
                }
                [] => bail!(
                    "claim {:?}: no row {row:?} in {}",
                    c.claim,
                    c.sweep
                        .paths()
                        .iter()
                        .map(|p| p.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                _ => bail!(
                    "claim {:?}: row {row:?} is in more than one of its sweeps ({})",
                    c.claim,
                    holders
                        .iter()
                        .map(|(s, _)| s.file.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            }
        }
        let dirs: Vec<PathBuf> = sweeps
            .iter()
            .map(|s| s.results.clone())
            .filter(|d| has_results(d))
            .collect();
        let rows = if dirs.is_empty() {
            Vec::new()
        } else {
            load_rows(&dirs)?
        };
        let worse = *declared.last().expect("the worse row is pushed last");
        let pairs: Vec<Pair> = declared[..declared.len() - 1]
            .iter()
            .map(|&b| measure(&rows, b, worse))
            .collect();
        let fewest = declared.iter().map(|d| d.1).min().unwrap_or(0);
        let links = sweeps
            .iter()
            .zip(c.sweep.paths())
            .map(|(s, path)| {
                // The sweep's table once `rdpg table` has made one, else its ledger (what has
                // run so far), else the sweep file itself: never a link to nothing.
                let target = ["table.md", "ledger.md"]
                    .iter()
                    .map(|f| s.results.join(f))
                    .find(|p| p.is_file())
                    .unwrap_or_else(|| path.clone());
                format!("[{}]({})", s.file.name, target.display())
            })
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {links} |",
            c.claim,
            c.paper,
            measured(&pairs, &waiting(&rows, &declared)),
            overall(&pairs, fewest),
        );
    }
    md += "\nEach claim as orderings of a sweep's rows, or of the rows of sweeps of one budget \
           (`better − worse`): the difference of the \
           interquartile means of their stock-reward tests (each seed's first 100 test \
           episodes, pooled), its 95 % CI a percentile bootstrap over seeds, drawn as `rdpg table` \
           draws it. Holds: every \
           interval above 0; does not hold: one below 0; unresolved: otherwise, once every \
           declared seed has run, and wherever the sweep declares fewer than 3 seeds (a \
           bootstrap over 2 seeds has 3 distinct resamples per row); pending: the numbers so \
           far.\n";
    let _ = writeln!(md, "\nMade by `rdpg claims {}`.", a.file.display());
    print!("{md}");
    if let Some(out) = &a.out {
        std::fs::write(out, &md).with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(())
}

/// Whether `dir` holds a trial's result file yet.
fn has_results(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries.flatten().any(|e| {
            let p = e.path();
            p.extension().is_some_and(|x| x == "json")
                && p.file_name().is_some_and(|n| n != "ledger.json")
        })
    })
}
