//! `rdpg select`: model selection on more validation episodes than the periodic evaluations.
//!
//! A run's `checkpoints/best` is the agent of the best periodic evaluation, usually 10
//! episodes: on a task whose returns spread widely (Hardcore: ±100 between episodes) that pick
//! is noisy. With `run.keep_agents_every` set, a run keeps its agents (weights only) in
//! `checkpoints/agents/<step>/`; `rdpg select` evaluates each of them, and `best`, on the same
//! N validation episodes (default 50, from the run's validation seeds `train.eval_seed`), and
//! writes the winner to `checkpoints/selected/`:
//! - `agent/`: a copy of the chosen agent (sealed);
//! - `eval.json`: its selection evaluation (an [`EvalRecord`], N episodes);
//! - `selection.json` ([`Selection`]): every candidate's evaluation, the seeds and the choice.
//!
//! The test seeds stay unseen: a `--seed` whose episodes would overlap them is refused.
//! `rdpg eval --checkpoint selected` tests the choice and `rdpg zoo --checkpoint selected`
//! ships it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::checkpoint::seal;
use rdpg_agents::common::evaluate_policy;
use rdpg_agents::EvalRecord;
use serde::{Deserialize, Serialize};

use crate::rundir::{copy_agent, eval_metric, read_json, RunDir, Which};

/// Arguments of `rdpg select`.
#[derive(Debug, Args)]
pub struct SelectArgs {
    /// Run directory written by `rdpg train` (with `run.keep_agents_every` set).
    #[arg(long)]
    run: PathBuf,
    /// Validation episodes per candidate.
    #[arg(long, default_value_t = 50)]
    episodes: usize,
    /// First validation seed (default: the run's `train.eval_seed`). Episodes may not reach
    /// the test seeds.
    #[arg(long)]
    seed: Option<u64>,
    /// Only kept agents from this step on (`best` is always a candidate).
    #[arg(long, default_value_t = 0)]
    from: u64,
}

/// One candidate's selection evaluation in [`Selection`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Candidate {
    /// The checkpoint: `best` or the step of a kept agent.
    pub checkpoint: String,
    /// Environment steps of training when the agent was saved.
    pub step: u64,
    /// Mean stock return over the selection episodes.
    pub mean_stock_return: f64,
    /// Its standard deviation over episodes.
    pub std_stock_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
}

/// `checkpoints/selected/selection.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Selection {
    /// Episodes per candidate.
    pub episodes: usize,
    /// First validation seed (episode k uses `first_seed + k`).
    pub first_seed: u64,
    /// What the means are.
    pub metric: String,
    /// The step of the chosen agent: the highest mean (the earliest one on a tie).
    pub chosen_step: u64,
    /// Every candidate, in step order.
    pub candidates: Vec<Candidate>,
}

/// `rdpg select`.
pub fn run(a: &SelectArgs) -> Result<()> {
    let run = RunDir::new(&a.run);
    if run.is_zoo_entry() {
        bail!(
            "{} is a zoo entry: it ships one agent, there is nothing to select",
            a.run.display()
        );
    }
    if a.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let exp = run.experiment()?;
    let t = &exp.train;
    let seed = a.seed.unwrap_or(t.eval_seed);
    let (lo, hi) = (seed, seed.saturating_add(a.episodes as u64));
    let (tlo, thi) = (
        t.test_seed,
        t.test_seed.saturating_add(t.test_episodes as u64),
    );
    if lo < thi && tlo < hi {
        bail!(
            "the selection seeds {lo}..{hi} overlap the run's test seeds {tlo}..{thi}: \
             selection must not see the seeds its agent is tested on (pick another --seed)"
        );
    }
    // Candidates: the kept agents from `--from` on, and `best` unless a kept agent has its step.
    let mut candidates: Vec<(Which, u64)> = run
        .kept_steps()?
        .into_iter()
        .filter(|&s| s >= a.from)
        .map(|s| (Which::Kept(s), s))
        .collect();
    let best_eval = run.checkpoint(Which::Best).join("eval.json");
    if best_eval.exists() {
        let e: EvalRecord = read_json(&best_eval)?;
        if !candidates.iter().any(|&(_, s)| s == e.step) {
            candidates.push((Which::Best, e.step));
            candidates.sort_by_key(|&(_, s)| s);
        }
    }
    if candidates.is_empty() {
        bail!(
            "{} holds no agent to select from: no kept agents from step {} \
             (set run.keep_agents_every, a resume may add it) and no best agent",
            a.run.display(),
            a.from
        );
    }
    eprintln!(
        "selecting among {} agents of {} on {} validation episodes (seeds {lo}..{hi}, stock reward)",
        candidates.len(),
        a.run.display(),
        a.episodes
    );
    let mut evaluated = Vec::with_capacity(candidates.len());
    for &(which, step) in &candidates {
        let (_, mut policy) = run.policy(which)?;
        let mut r = evaluate_policy(policy.as_mut(), t, a.episodes, seed)
            .with_context(|| format!("evaluating the agent {which}"))?;
        r.step = step;
        eprintln!(
            "  {:>10} (step {step}): {:.1} ± {:.1}, success {:.0} %",
            which.to_string(),
            r.mean_return,
            r.std_return,
            100.0 * r.success_rate
        );
        evaluated.push((which, r));
    }
    // The highest mean; on a tie the earliest (fewest steps).
    let (chosen, chosen_eval) = evaluated
        .iter()
        .rev()
        .max_by(|x, y| x.1.mean_return.total_cmp(&y.1.mean_return))
        .expect("at least one candidate");
    let selection = Selection {
        episodes: a.episodes,
        first_seed: seed,
        metric: eval_metric(t),
        chosen_step: chosen_eval.step,
        candidates: evaluated
            .iter()
            .map(|(w, r)| Candidate {
                checkpoint: w.to_string(),
                step: r.step,
                mean_stock_return: r.mean_return,
                std_stock_return: r.std_return,
                success_rate: r.success_rate,
            })
            .collect(),
    };
    // Written whole, then moved into place.
    let dst = run.checkpoint(Which::Selected);
    let tmp = run.fresh_partial(&dst)?;
    copy_agent(&run.agent(*chosen), &tmp.join("agent"))?;
    write_json(&tmp.join("eval.json"), chosen_eval)?;
    write_json(&tmp.join("selection.json"), &selection)?;
    seal(&tmp)?;
    run.commit(&tmp, &dst)?;
    eprintln!(
        "chose the agent {chosen} (step {}): {:.1} ± {:.1} -> {}",
        chosen_eval.step,
        chosen_eval.mean_return,
        chosen_eval.std_return,
        dst.display()
    );
    println!("{}", serde_json::to_string(&selection)?);
    Ok(())
}

fn write_json<T: Serialize>(path: &Path, v: &T) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)? + "\n")
        .with_context(|| format!("writing {}", path.display()))
}
