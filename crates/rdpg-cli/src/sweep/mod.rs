//! `rdpg sweep FILE`: many runs from one command. A sweep file (TOML) names the base
//! config(s), the rows (named sets of `--set` overrides, times an optional grid), the seeds
//! and the budget; every trial (row × seed) is one `rdpg train` process with its own run
//! directory under `runs/sweeps/<name>/trials/`.
//!
//! This module parses and validates the file (every trial's resolved experiment is checked
//! before any trial starts), prints the plan with `--plan` (each row's defining settings and
//! its estimated core-hours), writes `runs/sweeps/<name>/plan.json` and hands the run to
//! `python -m rdpg.sweep` (Ray Tune: `crates/rdpg-py/python/rdpg/sweep.py`), which starts,
//! resumes or skips each trial. `--collect` writes each finished trial's small result file
//! under the sweep's `results` folder (what `rdpg table` reads and what gets committed), and
//! the ledger of all trials there (`ledger.json`, `ledger.md`; see [`results::Ledger`]).
//! A tuning sweep (`tuning = true`) never opens its trials' test seeds: its result files carry
//! no test, and `--collect` also writes the trials' validation curves and a validation table
//! (`validation.rs`).
//! `--status` tells where a running or stopped sweep stands (`status.rs`); `--stop` stops a
//! running one from any shell and waits until its trials have saved (`stop.rs`).
//!
//! ```toml
//! name = "table1-cpu"                      # default: the file's stem
//! description = "scale settings ..."       # printed above the table
//! base = "configs/hardcore-rdpg-cpu.toml"  # each row's base config unless it names its own
//! seeds = [0, 1, 2]
//! steps = 1000000                          # train.total_steps of every trial (agent steps)
//! # frames = 3000000                       # or the budget in env frames: steps = frames / action repeat
//! # tuning = true                          # tuning seeds (10+), no test; validation.md besides
//! threads = 1                              # libtorch threads per trial
//! set = ["train.test_episodes=200"]        # overrides for every row (before the row's)
//! results = "results/table1-cpu"           # default: results/<name>
//! order = "seeds"                          # every row's seed 0, then seed 1, ... (default "rows": row by row)
//! keep_chosen_agents = true                # default false: also keep each chosen agent
//! [grid]                                   # optional: every row × every combination
//! "agent.opt_len" = [4, 8]
//! [[row]]
//! name = "rdpg"
//! set = ["agent.scan_len=24"]
//! paper = { label = "Our RDPG", r100ma = 227.5, success = 23.5 }
//! ```

mod results;
mod status;
mod stop;
mod validation;

use results::{collect, write_ledger};
pub use results::{run_record, RunRecord, TrialResult};

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::Algo;
use serde::{Deserialize, Serialize};

use crate::experiment::Experiment;
use crate::rundir::write_json;

/// Arguments of `rdpg sweep`.
#[derive(Debug, Args)]
pub struct SweepArgs {
    /// The sweep file (TOML).
    file: PathBuf,
    /// Print the trials, each row's defining settings and the estimated core-hours (measured
    /// on this machine), and start nothing.
    #[arg(long, conflicts_with = "collect")]
    plan: bool,
    /// Write the result file of every finished trial and the sweep's ledger (every trial's
    /// status, steps, binary commits and restarts) under the sweep's `results` folder, and start
    /// nothing.
    #[arg(long, conflicts_with = "status")]
    collect: bool,
    /// Print where the sweep stands (each trial's state, steps, validation, speed, the
    /// running trials' time to their budget and the core-hours left, from the files its trials
    /// write), and start nothing.
    #[arg(long, conflicts_with = "plan")]
    status: bool,
    /// Stop the running sweep of this file, as Ctrl-C to its driver would (each running trial
    /// saves its checkpoint; rerun the sweep to continue), and return once it has stopped.
    #[arg(long, conflicts_with_all = ["plan", "collect", "status"])]
    stop: bool,
    /// CPUs the local Ray may use (default: all cores); at most `cpus / threads` trials run at
    /// once.
    #[arg(long)]
    cpus: Option<usize>,
    /// Run on an existing Ray cluster (e.g. `auto` or `ray://host:10001`) instead of a local
    /// Ray started for the sweep. Every node needs this binary at the same path and the
    /// sweep's folders on shared storage.
    #[arg(long)]
    address: Option<String>,
    /// The Python that has `rdpg` and `ray[tune]` (the README's set-up installs both).
    #[arg(long, default_value = ".venv/bin/python")]
    python: PathBuf,
}

/// A sweep file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepFile {
    /// Sweep name (default: the file's stem): its folders are `runs/sweeps/<name>/` and
    /// `results/<name>/`.
    #[serde(default)]
    pub name: String,
    /// What the rows share (scale settings, budget), printed above the table.
    #[serde(default)]
    pub description: String,
    /// Base experiment file of the rows that name none.
    pub base: Option<PathBuf>,
    /// Seeds of every row, declared before the runs.
    pub seeds: Vec<u64>,
    /// Budget: `train.total_steps` of every trial (agent steps). Give this or `frames`.
    pub steps: Option<u64>,
    /// Budget in env frames instead: each trial gets `frames / action_repeat` agent steps
    /// (its own action repeat; it must divide `frames`), so rows with different action
    /// repeats compare at equal frames.
    pub frames: Option<u64>,
    /// A tuning sweep: its trials choose a recipe and are never results. Its seeds are tuning
    /// seeds (10 and up: the results protocol keeps 0–9 for declared runs), every trial runs
    /// with `train.test_episodes = 0` (the test seeds stay closed), and `--collect` writes the
    /// trials' validation curves (`<trial>-evals.csv`, running trials included) and a
    /// validation table (`validation.md`) beside the ledger.
    #[serde(default)]
    pub tuning: bool,
    /// libtorch threads per trial (`agent.num_threads` / `ppo.num_threads`).
    #[serde(default = "one")]
    pub threads: usize,
    /// Overrides applied to every row, before the row's own.
    #[serde(default)]
    pub set: Vec<String>,
    /// Optional grid: key → values; every row runs at every combination.
    #[serde(default)]
    pub grid: BTreeMap<String, Vec<toml::Value>>,
    /// Where the per-trial result files go (default: `results/<name>`).
    pub results: Option<PathBuf>,
    /// The order trials start in.
    #[serde(default)]
    pub order: TrialOrder,
    /// Also keep each finished trial's agent chosen on validation as a small run directory
    /// `<results>/runs/<trial>/` (its experiment, summary, metrics, versions and that agent: no
    /// replay, no optimiser state; about 2 MB for a walker), which `rdpg zoo`, `rdpg eval` and
    /// `rdpg render` read: once committed, the agent outlives the machine that trained it.
    #[serde(default)]
    pub keep_chosen_agents: bool,
    /// The rows.
    #[serde(default, rename = "row")]
    pub rows: Vec<RowSpec>,
}

fn one() -> usize {
    1
}

/// The lowest tuning seed: the results protocol keeps the seeds below for declared runs.
pub const TUNING_SEEDS: u64 = 10;

/// A sweep's budget, as its file gives it.
#[derive(Debug, Clone, Copy)]
enum Budget {
    /// Agent steps, every trial alike.
    Steps(u64),
    /// Env frames: agent steps times each trial's action repeat.
    Frames(u64),
}

/// The order a sweep's trials start in (the table shows the rows in file order either way).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TrialOrder {
    /// Row by row: every seed of the first row, then the next row.
    #[default]
    Rows,
    /// Seed by seed: every row at the first seed, then every row at the next seed, so a
    /// sweep stopped early has compared its rows on the same seeds.
    Seeds,
}

/// One row of a sweep file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RowSpec {
    /// Row name (letters, digits, `_`, `-`, `.`, `=`): unique in the sweep.
    pub name: String,
    /// Its base experiment file (default: the sweep's `base`).
    pub base: Option<PathBuf>,
    /// Its overrides (`key=value`, as `rdpg train --set`).
    #[serde(default)]
    pub set: Vec<String>,
    /// The paper's row this one reproduces, shown beside it in the table.
    pub paper: Option<PaperRow>,
}

/// A row of the paper's Table I.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PaperRow {
    /// The paper's name of the row.
    pub label: String,
    /// Its top R_100MA (none where the paper says N/A).
    pub r100ma: Option<f64>,
    /// Its success rate in percent.
    pub success: Option<f64>,
}

/// One trial: a row at one seed.
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    /// `<row>-s<seed>`.
    pub id: String,
    /// Row name.
    pub row: String,
    /// The row's place in the sweep (grid rows counted).
    pub row_index: usize,
    /// Seed.
    pub seed: u64,
    /// Base experiment file.
    pub base: PathBuf,
    /// Every override, in order (sweep, grid, row, then seed, budget, threads and, in a
    /// tuning sweep, `train.test_episodes=0`).
    pub set: Vec<String>,
    /// Its run directory.
    pub run_dir: PathBuf,
    /// Budget (agent steps).
    pub steps: u64,
    #[serde(skip)]
    exp: Experiment,
    #[serde(skip)]
    paper: Option<PaperRow>,
}

impl Trial {
    /// Budget in env frames: agent steps times the trial's action repeat.
    pub fn frames(&self) -> u64 {
        self.steps * self.exp.train.action_repeat as u64
    }
}

/// A parsed and checked sweep: every trial's experiment resolved.
pub struct Sweep {
    /// The file.
    pub file: SweepFile,
    /// The trials, row by row, seeds in order.
    pub trials: Vec<Trial>,
    /// `runs/sweeps/<name>`.
    pub root: PathBuf,
    /// Where result files go.
    pub results: PathBuf,
    /// The budget as the file gives it.
    budget: Budget,
}

fn check_name(what: &str, name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-.=".contains(c))
        && !name.starts_with('.');
    if !ok {
        bail!("{what} {name:?}: use letters, digits, '_', '-', '.' and '=' (it names folders)");
    }
    Ok(())
}

/// The grid's combinations as `(suffix, overrides)`: `("opt_len=4", ["agent.opt_len=4"])`.
fn grid_points(grid: &BTreeMap<String, Vec<toml::Value>>) -> Result<Vec<(String, Vec<String>)>> {
    let mut points = vec![(String::new(), Vec::new())];
    for (key, values) in grid {
        if values.is_empty() {
            bail!("grid key {key:?} lists no value");
        }
        let short = key.rsplit('.').next().unwrap_or(key);
        let mut next = Vec::new();
        for (suffix, sets) in &points {
            for v in values {
                let shown = match v {
                    toml::Value::String(s) => s.clone(),
                    other => other.to_string(),
                };
                let mut sets: Vec<String> = sets.clone();
                sets.push(format!("{key}={v}"));
                let sep = if suffix.is_empty() { "" } else { "-" };
                next.push((format!("{suffix}{sep}{short}={shown}"), sets));
            }
        }
        points = next;
    }
    Ok(points)
}

impl Sweep {
    /// Reads and checks `path`: unknown keys, a budget that is not a number, duplicate rows,
    /// and every trial's experiment (a key that does not exist, a bad value) are errors.
    pub fn load(path: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut file: SweepFile = toml::from_str(&text)
            .with_context(|| format!("invalid sweep file {}", path.display()))?;
        if file.name.is_empty() {
            file.name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        check_name("sweep name", &file.name)?;
        if file.seeds.is_empty() || file.rows.is_empty() {
            bail!(
                "{}: a sweep needs seeds and at least one [[row]]",
                path.display()
            );
        }
        let budget = match (file.steps, file.frames) {
            (Some(steps), None) => Budget::Steps(steps),
            (None, Some(frames)) => Budget::Frames(frames),
            _ => bail!(
                "{}: give the budget as `steps` (agent steps) or `frames` (env frames), one of \
                 them",
                path.display()
            ),
        };
        if file.steps == Some(0) || file.frames == Some(0) || file.threads == 0 {
            bail!(
                "{}: the budget and threads must be positive",
                path.display()
            );
        }
        if file.tuning {
            if file.keep_chosen_agents {
                bail!(
                    "{}: a tuning sweep keeps no agent (`keep_chosen_agents`): its trials are \
                     never tested",
                    path.display()
                );
            }
            if let Some(s) = file.seeds.iter().find(|&&s| s < TUNING_SEEDS) {
                bail!(
                    "{}: a tuning sweep runs on tuning seeds ({TUNING_SEEDS} and up; the results \
                     protocol keeps the ones below for declared runs), not seed {s}",
                    path.display()
                );
            }
        }
        let mut seen = BTreeSet::new();
        for s in &file.seeds {
            if !seen.insert(*s) {
                bail!("{}: seed {s} is listed twice", path.display());
            }
        }
        let points = grid_points(&file.grid)?;
        let root = Path::new("runs").join("sweeps").join(&file.name);
        let results = file
            .results
            .clone()
            .unwrap_or_else(|| Path::new("results").join(&file.name));
        let mut names = BTreeSet::new();
        let mut trials = Vec::new();
        for row in &file.rows {
            check_name("row name", &row.name)?;
            let base = row.base.clone().or(file.base.clone()).with_context(|| {
                format!(
                    "row {:?} names no base config and the sweep has no `base`",
                    row.name
                )
            })?;
            for (suffix, grid_sets) in &points {
                let name = if suffix.is_empty() {
                    row.name.clone()
                } else {
                    format!("{}-{suffix}", row.name)
                };
                if !names.insert(name.clone()) {
                    bail!("{}: two rows are named {name:?}", path.display());
                }
                for &seed in &file.seeds {
                    let mut set: Vec<String> = file.set.clone();
                    set.extend(grid_sets.iter().cloned());
                    set.extend(row.set.iter().cloned());
                    set.push(format!("train.seed={seed}"));
                    let probe = Experiment::load(&base, &set)
                        .with_context(|| format!("row {name:?} (seed {seed})"))?;
                    let steps = match budget {
                        Budget::Steps(steps) => steps,
                        Budget::Frames(frames) => {
                            let repeat = probe.train.action_repeat as u64;
                            if frames % repeat != 0 {
                                bail!(
                                    "row {name:?}: frames = {frames} is no whole number of agent \
                                     steps at its action repeat {repeat}"
                                );
                            }
                            frames / repeat
                        }
                    };
                    set.push(format!("train.total_steps={steps}"));
                    set.push(match probe.algo {
                        Algo::Ppo => format!("ppo.num_threads={}", file.threads),
                        _ => format!("agent.num_threads={}", file.threads),
                    });
                    if file.tuning {
                        set.push("train.test_episodes=0".into());
                    }
                    let exp = Experiment::load(&base, &set)
                        .with_context(|| format!("row {name:?} (seed {seed})"))?;
                    if exp.train.test_episodes == 0 && !file.tuning {
                        bail!(
                            "row {name:?}: train.test_episodes = 0, but a sweep's tables need \
                             each trial's test"
                        );
                    }
                    let id = format!("{name}-s{seed}");
                    trials.push(Trial {
                        run_dir: root.join("trials").join(&id),
                        id,
                        row: name.clone(),
                        row_index: names.len() - 1,
                        seed,
                        base: base.clone(),
                        set,
                        steps,
                        exp,
                        paper: row.paper.clone(),
                    });
                }
            }
        }
        if file.order == TrialOrder::Seeds {
            // A stable sort keeps the rows in file order within each seed.
            trials.sort_by_key(|t| file.seeds.iter().position(|&s| s == t.seed));
        }
        Ok(Self {
            file,
            trials,
            root,
            results,
            budget,
        })
    }

    /// The rows in order, each with its first trial (all trials of a row share its settings
    /// but the seed).
    fn rows(&self) -> Vec<&Trial> {
        let mut seen = BTreeSet::new();
        self.trials
            .iter()
            .filter(|t| seen.insert(t.row.clone()))
            .collect()
    }
}

/// What defines a row in the paper's terms: the settings `--plan` prints.
fn defining_settings(exp: &Experiment) -> serde_json::Value {
    let t = &exp.train;
    let mut v = serde_json::json!({
        "algo": exp.algo.as_str(),
        "env": t.env,
        "train_reward": t.reward_label(),
        "action_repeat": t.action_repeat,
        "total_steps": t.total_steps,
        "frames": t.total_steps * t.action_repeat as u64,
        "seed": t.seed,
    });
    if let (Some(a), Some(o)) = (&exp.agent, &exp.off_policy) {
        let extra = serde_json::json!({
            "recurrent": a.recurrent,
            "scan_len": a.scan_len,
            "opt_len": a.opt_len,
            "update_len": a.update_len,
            "critic_target": a.critic_target,
            "lambda": a.lambda,
            "actor_bptt": a.actor_bptt,
            "burn_in_from_stored_state": a.burn_in_from_stored_state,
            "tau": a.tau,
            "twin_critic": a.twin_critic,
            "actor_hidden": a.actor_hidden,
            "critic_hidden": a.critic_hidden,
            "batch_size": a.batch_size,
            "num_threads": a.num_threads,
            "updates_per_step": o.updates_per_step,
            "replay_capacity": o.replay_capacity,
            "exploration": o.exploration,
            "param_noise": o.param_noise.is_some(),
            "injection": o.injection.as_ref().map(|i| &i.teachers),
        });
        if let (Some(m), serde_json::Value::Object(e)) = (v.as_object_mut(), extra) {
            m.extend(e);
        }
    }
    if let Some(p) = &exp.ppo {
        if let Some(m) = v.as_object_mut() {
            m.insert("ppo".into(), serde_json::to_value(p).unwrap_or_default());
        }
    }
    v
}

/// Measured cost of one trial of `exp` on this machine: seconds of one agent step (the
/// environment's frames) and of one update (`rdpg bench update` on its config and threads,
/// timed over about half a second of updates).
fn estimate_hours(exp: &Experiment, threads: usize) -> Result<(f64, &'static str)> {
    let t = &exp.train;
    let mut env = rdpg_envs::make_with(&t.env, &t.env_options())?;
    let space = env.action_space().clone();
    let mut rng = rdpg_core::rng::NpRng::from_seed(0);
    env.reset(Some(0))?;
    let (t0, mut steps) = (std::time::Instant::now(), 0usize);
    while t0.elapsed().as_secs_f64() < 0.5 {
        let a: Vec<f32> = (0..space.dim())
            .map(|i| space.low[i] + (space.high[i] - space.low[i]) * rng.random() as f32)
            .collect();
        if env.step(&a)?.done() {
            env.reset(Some(steps as u64))?;
        }
        steps += 1;
    }
    let step_secs = t0.elapsed().as_secs_f64() / steps as f64;
    let budget = t.total_steps as f64;
    match (&exp.agent, &exp.off_policy) {
        (Some(agent), Some(off)) => {
            let obs = env.observation_space().dim();
            let cfg = rdpg_agents::RdpgConfig {
                num_threads: Some(threads),
                ..agent.clone()
            };
            // A first rate from 3 updates sizes a timing of about half a second, as the env's:
            // a few updates of a few milliseconds each would swing with the machine's load.
            let bench = |iters| {
                rdpg_agents::rdpg::bench::bench_update_with(&cfg, obs, space.dim(), 0.0, iters)
            };
            let rough = bench(3)?.updates_per_sec;
            let ups = if rough > 6.0 {
                bench((rough * 0.5).min(500.0) as usize)?.updates_per_sec
            } else {
                rough
            };
            let secs = budget * (step_secs + off.updates_per_step / ups);
            Ok((
                secs * threads as f64 / 3600.0,
                "environment steps and updates",
            ))
        }
        _ => Ok((
            budget * step_secs * threads as f64 / 3600.0,
            "environment steps only (PPO's update is not benchmarked)",
        )),
    }
}

/// `rdpg sweep`.
pub fn run(a: &SweepArgs) -> Result<()> {
    let sweep = Sweep::load(&a.file)?;
    if a.plan {
        return print_plan(&sweep);
    }
    if a.status {
        print!("{}", status::report(&sweep)?);
        return Ok(());
    }
    if a.stop {
        return stop::stop(&sweep, &a.file);
    }
    if a.collect {
        for line in collect(&sweep)? {
            println!("{line}");
        }
        // The ledger is rewritten where the sweep runs (a clone without its run directories
        // keeps the committed one).
        if sweep.trials.iter().any(|t| t.run_dir.exists()) {
            println!("{}", write_ledger(&sweep)?.display());
            if sweep.file.tuning {
                for line in validation::write_validation(&sweep)? {
                    println!("{line}");
                }
            }
        }
        return Ok(());
    }
    if a.cpus == Some(0) {
        bail!("--cpus must be positive");
    }
    if !a.python.exists() {
        bail!(
            "{} not found: run the README's set-up (it installs the rdpg package and ray[tune] \
             into .venv), or name another Python with --python",
            a.python.display()
        );
    }
    std::fs::create_dir_all(&sweep.root)
        .with_context(|| format!("creating {}", sweep.root.display()))?;
    let abs = |p: &Path| -> Result<PathBuf> {
        Ok(if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir()?.join(p)
        })
    };
    let cpus = a
        .cpus
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let plan = serde_json::json!({
        "name": sweep.file.name,
        "sweep_file": abs(&a.file)?,
        "binary": std::env::current_exe()?,
        "cwd": std::env::current_dir()?,
        "storage": abs(&sweep.root)?,
        "threads": sweep.file.threads,
        "cpus": cpus,
        "address": a.address,
        "trials": sweep.trials.iter().map(|t| -> Result<serde_json::Value> {
            Ok(serde_json::json!({
                "id": t.id,
                "row": t.row,
                "seed": t.seed,
                "steps": t.steps,
                "tuning": sweep.file.tuning,
                "run_dir": abs(&t.run_dir)?,
                "result": abs(&sweep.results.join(format!("{}.json", t.id)))?,
                "base": abs(&t.base)?,
                "set": t.set,
            }))
        }).collect::<Result<Vec<_>>>()?,
    });
    let plan_path = sweep.root.join("plan.json");
    write_json(&plan_path, &plan)?;
    let err = exec_python(&a.python, &plan_path);
    Err(err).with_context(|| format!("starting {} -m rdpg.sweep", a.python.display()))
}

#[cfg(unix)]
fn exec_python(python: &Path, plan: &Path) -> std::io::Error {
    use std::os::unix::process::CommandExt;
    // Replaces this process: Ctrl-C reaches Ray's driver alone, which stops the trials (each
    // `rdpg train` saves its checkpoint) and keeps the experiment's state for a resume.
    std::process::Command::new(python)
        .args(["-m", "rdpg.sweep"])
        .arg(plan)
        .exec()
}

#[cfg(not(unix))]
fn exec_python(python: &Path, plan: &Path) -> std::io::Error {
    match std::process::Command::new(python)
        .args(["-m", "rdpg.sweep"])
        .arg(plan)
        .status()
    {
        Ok(s) => std::process::exit(s.code().unwrap_or(1)),
        Err(e) => e,
    }
}

fn print_plan(sweep: &Sweep) -> Result<()> {
    let mut rows = Vec::new();
    let mut total = 0.0;
    for first in sweep.rows() {
        let n = sweep.trials.iter().filter(|t| t.row == first.row).count();
        let (hours, basis) = estimate_hours(&first.exp, sweep.file.threads)?;
        total += hours * n as f64;
        rows.push(serde_json::json!({
            "row": first.row,
            "base": first.base,
            "set": first.set,
            "paper": first.paper,
            "trials": sweep.trials.iter().filter(|t| t.row == first.row).map(|t| &t.id).collect::<Vec<_>>(),
            "settings": defining_settings(&first.exp),
            "core_hours_per_trial": hours,
            "estimate": basis,
        }));
    }
    let plan = serde_json::json!({
        "sweep": sweep.file.name,
        "description": sweep.file.description,
        "seeds": sweep.file.seeds,
        "steps": sweep.file.steps,
        "frames": sweep.file.frames,
        "tuning": sweep.file.tuning,
        "threads_per_trial": sweep.file.threads,
        "trials": sweep.trials.len(),
        "rows": rows,
        "core_hours": total,
        "machine": crate::rundir::machine_description(),
    });
    println!("{}", serde_json::to_string_pretty(&plan)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_points_are_the_cartesian_product_named_by_short_keys() {
        let mut g = BTreeMap::new();
        g.insert(
            "agent.opt_len".to_string(),
            vec![toml::Value::Integer(4), toml::Value::Integer(8)],
        );
        g.insert(
            "train.reward".to_string(),
            vec![toml::Value::String("paper".into())],
        );
        let p = grid_points(&g).unwrap();
        let names: Vec<&str> = p.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["opt_len=4-reward=paper", "opt_len=8-reward=paper"]);
        assert_eq!(p[1].1, ["agent.opt_len=8", "train.reward=\"paper\""]);
        assert_eq!(
            grid_points(&BTreeMap::new()).unwrap(),
            [(String::new(), vec![])]
        );
    }

    #[test]
    fn trials_start_row_by_row_or_seed_by_seed() {
        let dir = std::env::temp_dir().join(format!("rdpg-sweep-order-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/cue-rdpg.toml");
        let ids = |order: &str| {
            let file = dir.join("s.toml");
            std::fs::write(
                &file,
                format!(
                    "base = {:?}\nseeds = [3, 1]\nsteps = 100\n{order}\n\
                     [[row]]\nname = \"a\"\n[[row]]\nname = \"b\"\n",
                    base.display().to_string()
                ),
            )
            .unwrap();
            let sweep = Sweep::load(&file).unwrap();
            let rows: Vec<String> = sweep.rows().iter().map(|t| t.row.clone()).collect();
            assert_eq!(rows, ["a", "b"], "the table keeps the file's row order");
            sweep
                .trials
                .iter()
                .map(|t| t.id.clone())
                .collect::<Vec<_>>()
        };
        assert_eq!(ids(""), ["a-s3", "a-s1", "b-s3", "b-s1"]);
        assert_eq!(ids("order = \"rows\""), ["a-s3", "a-s1", "b-s3", "b-s1"]);
        assert_eq!(ids("order = \"seeds\""), ["a-s3", "b-s3", "a-s1", "b-s1"]);
        let bad = dir.join("bad.toml");
        std::fs::write(
            &bad,
            format!(
                "base = {:?}\nseeds = [0]\nsteps = 100\norder = \"random\"\n[[row]]\nname = \"a\"\n",
                base.display().to_string()
            ),
        )
        .unwrap();
        let err = format!("{:#}", Sweep::load(&bad).err().unwrap());
        assert!(err.contains("unknown variant `random`"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
