//! `rdpg select`: model selection on more validation episodes than the periodic evaluations.
//!
//! A run's `checkpoints/best` is the agent of the best periodic evaluation, usually 10
//! episodes: on a task whose returns spread widely (Hardcore: ±100 between episodes) that pick
//! is noisy. With `run.keep_agents_every` set, a run keeps its agents (weights only) in
//! `checkpoints/agents/<step>/`; `rdpg select` evaluates each of them, and `best`, on the same
//! N validation episodes (default 50, from the run's validation seeds `train.eval_seed`), and
//! writes the winner to `checkpoints/selected/`:
//! - `agent/`: a copy of the chosen agent (sealed);
//! - `eval.json`: its selection evaluation (an [`rdpg_agents::EvalRecord`], N episodes);
//! - `selection.json` ([`Selection`]): every candidate's evaluation, the seeds and the choice.
//!
//! The test seeds stay unseen: a `--seed` whose episodes would overlap them is refused.
//! `rdpg eval --checkpoint selected` tests the choice and `rdpg zoo --checkpoint selected`
//! ships it.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::checkpoint::seal;
use rdpg_agents::common::evaluate_policy;
use serde::{Deserialize, Serialize};

use crate::rundir::{copy_agent, eval_metric, write_json, RunDir, Which};

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
    let bad_seed = || anyhow::anyhow!("--seed {seed} + {} episodes overflows", a.episodes);
    let (lo, hi) = (
        seed,
        seed.checked_add(a.episodes as u64).ok_or_else(bad_seed)?,
    );
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
    // A `select` interrupted while it saved leaves `selected.previous`: put it back first.
    let dst = run.checkpoint(Which::Selected);
    run.recover_one(&dst)?;
    // Everything is written into `selected.partial`, then moved into place.
    let tmp = run.fresh_partial(&dst)?;
    // Candidates (name, step, agent directory): the kept agents from `--from` on (they never
    // change), and a snapshot of `best` (a running `rdpg train` may replace it meanwhile)
    // unless a kept agent has its step.
    let mut candidates: Vec<(Which, u64, PathBuf)> = run
        .kept_steps()?
        .into_iter()
        .filter(|&s| s >= a.from)
        .map(|s| (Which::Kept(s), s, run.agent(Which::Kept(s))))
        .collect();
    if let Some(step) = run
        .snapshot_agent(Which::Best, &tmp.join("best"))?
        .map(|e| e.step)
    {
        if candidates.iter().any(|c| c.1 == step) {
            std::fs::remove_dir_all(tmp.join("best"))
                .with_context(|| format!("removing {}", tmp.join("best").display()))?;
        } else {
            candidates.push((Which::Best, step, tmp.join("best")));
            candidates.sort_by_key(|c| c.1);
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
    for (which, step, dir) in &candidates {
        let mut policy = rdpg_agents::load_policy(exp.algo, dir)
            .with_context(|| format!("loading {}", dir.display()))?;
        let mut r = evaluate_policy(policy.as_mut(), t, a.episodes, seed)
            .with_context(|| format!("evaluating the agent {which}"))?;
        r.step = *step;
        eprintln!(
            "  {:>10} (step {step}): {:.1} ± {:.1}, success {:.0} %",
            which.to_string(),
            r.mean_return,
            r.std_return,
            100.0 * r.success_rate
        );
        evaluated.push(r);
    }
    // The highest mean; on a tie the earliest (fewest steps).
    let (k, chosen_eval) = evaluated
        .iter()
        .enumerate()
        .rev()
        .max_by(|x, y| x.1.mean_return.total_cmp(&y.1.mean_return))
        .expect("at least one candidate");
    let (chosen, _, chosen_dir) = &candidates[k];
    let selection = Selection {
        episodes: a.episodes,
        first_seed: seed,
        metric: eval_metric(t),
        chosen_step: chosen_eval.step,
        candidates: candidates
            .iter()
            .zip(&evaluated)
            .map(|((w, ..), r)| Candidate {
                checkpoint: w.to_string(),
                step: r.step,
                mean_stock_return: r.mean_return,
                std_stock_return: r.std_return,
                success_rate: r.success_rate,
            })
            .collect(),
    };
    copy_agent(chosen_dir, &tmp.join("agent"))?;
    if tmp.join("best").exists() {
        std::fs::remove_dir_all(tmp.join("best"))
            .with_context(|| format!("removing {}", tmp.join("best").display()))?;
    }
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
