//! `rdpg zoo`: ships a run's best (or `rdpg select`ed) agent as a zoo entry, small enough for
//! git.
//!
//! A zoo entry `zoo/<name>/` holds:
//! - `agent/`: the agent's `agent.json` and `weights.safetensors` (no optimiser state, no
//!   replay), sealed by `manifest.json` (sizes and CRC-32s, checked on every load);
//! - `config.toml`: the run's resolved experiment;
//! - `summary.json` ([`ZooSummary`]): the test evaluation (stock reward, test seeds, which model
//!   selection never saw), when the agent was taken (steps, updates, wall time), the whole run,
//!   the machine and the command that reproduces it;
//! - `evals.csv` and `curves.png`: the run's evaluations and learning curves;
//! - `episode.gif`: the agent on the first test seed.
//!
//! `rdpg eval --run zoo/<name>` and `rdpg render --run zoo/<name>` read it as a run directory
//! whose `best` agent is `agent/`; `rdpg plot` and `rdpg compare` through [`read_as_run`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::evaluate_policy;
use serde::{Deserialize, Serialize};

use crate::render::{render_run, RenderTarget};
use crate::rundir::{
    copy_file, machine_description, read_json, write_json, EvalSummary, Metric, RunDir, Summary,
    TeacherSummary, TestSummary, Which,
};

/// Arguments of `rdpg zoo`.
#[derive(Debug, Args)]
pub struct ZooArgs {
    /// Run directory written by `rdpg train`; its agent `--checkpoint` (chosen on the
    /// validation seeds) is shipped.
    #[arg(long)]
    run: PathBuf,
    /// The agent to ship: `best` (the best periodic evaluation) or `selected` (chosen by
    /// `rdpg select` on more validation episodes).
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    /// The zoo entry to create, e.g. `zoo/walker-td3`. Must not exist.
    #[arg(long)]
    out: PathBuf,
    /// Test episodes (default: the run's `train.test_episodes`), from the run's test seeds.
    #[arg(long)]
    episodes: Option<usize>,
    /// The command that reproduces the run, shown in the summary and the README's zoo table
    /// (default: `rdpg train --config configs/<name>.toml`).
    #[arg(long)]
    command: Option<String>,
    /// Steps of the GIF (it shows the first test episode up to here).
    #[arg(long, default_value_t = 1000)]
    gif_steps: usize,
}

/// `summary.json` of a zoo entry.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooSummary {
    /// The experiment's name.
    pub name: String,
    /// Algorithm.
    pub algo: String,
    /// Environment id.
    pub env: String,
    /// The reward the agent was trained on, with every option that changes the reward or the
    /// time scale.
    pub training_reward: String,
    /// The reward of every evaluation here: always `stock`.
    pub evaluation_reward: String,
    /// Deterministic test evaluation of the shipped agent.
    pub test: ZooTest,
    /// When the shipped agent was taken.
    pub agent: ZooAgent,
    /// The whole training run.
    pub training: ZooTraining,
    /// The machine of the training run's last session.
    pub machine: String,
    /// The command that reproduces the run.
    pub reproduce: String,
    /// Sizes in bytes of the entry's files.
    pub files: Vec<(String, u64)>,
    /// The teachers of experience injection (none without injection).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub teachers: Vec<TeacherSummary>,
}

/// The test evaluation in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooTest {
    /// Episodes.
    pub episodes: usize,
    /// First seed (episode k uses `first_seed + k`); the run's test seeds.
    pub first_seed: u64,
    /// Mean stock return.
    pub mean_return: f64,
    /// Standard deviation over episodes.
    pub std_return: f64,
    /// Share of episodes that reached the end of the course without falling.
    pub success_rate: f64,
    /// Every episode's stock return.
    pub returns: Vec<f64>,
}

/// The shipped agent in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooAgent {
    /// Environment steps of training when it was evaluated and kept.
    pub steps: u64,
    /// Learner updates it had received.
    pub updates: u64,
    /// Wall-clock seconds of training until then.
    pub wall_seconds: Option<f64>,
    /// Its validation evaluation (the one that chose it): mean stock return.
    pub validation_mean_return: f64,
    /// Its standard deviation over the validation episodes (entries before 2026-12-03: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_std_return: Option<f64>,
    /// Its success share on the validation episodes (entries before 2026-12-03: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_success_rate: Option<f64>,
    /// Validation episodes: the periodic evaluation's (`best`), or `rdpg select`'s
    /// (`selected`).
    pub validation_episodes: usize,
}

/// The training run in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooTraining {
    /// Environment steps of the whole run.
    pub steps: u64,
    /// Training episodes.
    pub episodes: u64,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// The run's seed.
    pub seed: u64,
    /// The paper's R_100MA on the training reward (with exploration noise).
    pub best_r100_train_reward: Option<f64>,
}

/// `rdpg zoo`.
pub fn run(a: &ZooArgs) -> Result<()> {
    let run = RunDir::new(&a.run);
    if run.is_zoo_entry() {
        bail!("{} is already a zoo entry", a.run.display());
    }
    if a.out.exists() {
        bail!(
            "{} exists: remove it first (a zoo entry is written whole)",
            a.out.display()
        );
    }
    if a.episodes == Some(0) {
        bail!("--episodes must be at least 1");
    }
    if !matches!(a.checkpoint, Which::Best | Which::Selected) {
        bail!(
            "--checkpoint {}: a zoo entry ships an agent chosen on the validation seeds, \
             `best` or `selected` (`rdpg select` chooses among kept agents)",
            a.checkpoint
        );
    }
    let exp = run.experiment()?;
    let summary = run.read_summary()?;
    // Write into a temporary sibling, then rename: no half-written entry is left behind.
    let mut tmp_name = a.out.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(".partial");
    let tmp = a.out.with_file_name(tmp_name);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    // Copy first, then test the copy: what ships is what was tested, even if the run is
    // still training and commits a new best meanwhile.
    let agent_dir = run.agent(a.checkpoint);
    let Some(chosen) = run.snapshot_agent(a.checkpoint, &tmp.join("agent"))? else {
        // The message of a missing agent, with its hint.
        run.policy(a.checkpoint)?;
        bail!(
            "{} has no eval.json: not an agent chosen on the validation seeds",
            run.checkpoint(a.checkpoint).display()
        );
    };
    copy_file(&run.config(), &tmp.join("config.toml"))?;
    copy_file(&a.run.join("evals.csv"), &tmp.join("evals.csv"))?;
    let agent_meta: serde_json::Value = read_json(&tmp.join("agent").join("agent.json"))?;
    let updates = agent_meta["updates"].as_u64().with_context(|| {
        format!(
            "{}: no `updates` count",
            agent_dir.join("agent.json").display()
        )
    })?;
    // The run's clock when the agent was saved: its evaluation's row, or (a kept agent
    // between evaluations) the last row before it.
    let metrics = run.read_metrics()?;
    let wall_at_best = metrics
        .iter()
        .find(|m| matches!(m, Metric::Eval { step, .. } if *step == chosen.step))
        .or_else(|| metrics.iter().rev().find(|m| m.step() <= chosen.step))
        .map(Metric::wall);
    let entry = RunDir::new(&tmp);
    let (_, mut policy) = entry.policy(Which::Best)?;
    let t = &exp.train;
    let episodes = a.episodes.unwrap_or(t.test_episodes);
    let test = evaluate_policy(policy.as_mut(), t, episodes, t.test_seed)?;
    crate::report::plot_runs(std::slice::from_ref(&a.run), &tmp.join("curves.png"))?;
    let target = RenderTarget {
        gif: tmp.join("episode.gif"),
        png_dir: None,
        every: 4,
        scale_down: 2,
        max_steps: Some(a.gif_steps),
    };
    render_run(&entry, Which::Best, t.test_seed, &target)?;

    let mut files = Vec::new();
    for f in [
        "agent/agent.json",
        "agent/weights.safetensors",
        "agent/manifest.json",
        "config.toml",
        "evals.csv",
        "curves.png",
        "episode.gif",
    ] {
        let p = tmp.join(f);
        let len = std::fs::metadata(&p)
            .with_context(|| format!("{}", p.display()))?
            .len();
        files.push((f.to_string(), len));
    }
    let name = if exp.name.is_empty() {
        a.out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    } else {
        exp.name.clone()
    };
    let zs = ZooSummary {
        reproduce: a
            .command
            .clone()
            .unwrap_or_else(|| format!("rdpg train --config configs/{name}.toml")),
        name,
        algo: exp.algo.as_str().into(),
        env: t.env.clone(),
        training_reward: summary.train_reward.clone(),
        evaluation_reward: summary.eval_reward.clone(),
        test: ZooTest {
            episodes,
            first_seed: t.test_seed,
            mean_return: test.mean_return,
            std_return: test.std_return,
            success_rate: test.success_rate,
            returns: test.returns.clone(),
        },
        agent: ZooAgent {
            steps: chosen.step,
            updates,
            wall_seconds: wall_at_best,
            validation_mean_return: chosen.mean_return,
            validation_std_return: Some(chosen.std_return),
            validation_success_rate: Some(chosen.success_rate),
            validation_episodes: chosen.returns.len(),
        },
        training: ZooTraining {
            steps: summary.steps,
            episodes: summary.episodes,
            wall_seconds: summary.wall_seconds,
            seed: t.seed,
            best_r100_train_reward: summary.best_r100_train_reward,
        },
        machine: summary.machine.clone().unwrap_or_else(|| {
            format!(
                "{} (the machine that ran `rdpg zoo`; the run did not record its own)",
                machine_description()
            )
        }),
        files,
        teachers: summary.teachers.clone(),
    };
    write_json(&tmp.join("summary.json"), &zs)?;
    std::fs::rename(&tmp, &a.out)
        .with_context(|| format!("renaming {} to {}", tmp.display(), a.out.display()))?;
    println!("{}", serde_json::to_string(&zs)?);
    Ok(())
}

/// A zoo entry in a run's terms, for `rdpg plot` and `rdpg compare`: its summary as a run's
/// [`Summary`] (the validation evaluation that chose the agent as `best_eval`, its test as
/// `test_eval`) and its evaluations. An entry ships no training episodes, so it has no
/// training-return curve.
pub fn read_as_run(entry: &RunDir) -> Result<(Summary, Vec<Metric>)> {
    let path = entry.summary();
    let zs: ZooSummary = read_json(&path)?;
    let evals = entry.read_evals_csv()?;
    let eval_summary = |m: &Metric| match *m {
        Metric::Eval {
            step,
            mean_return,
            std_return,
            success_rate,
            ..
        } => Some(EvalSummary {
            step,
            mean_stock_return: mean_return,
            std_stock_return: std_return,
            success_rate,
        }),
        Metric::Episode { .. } => None,
    };
    // The evaluation that chose the agent: `rdpg select`'s when the entry records it,
    // otherwise the periodic one at its step.
    let selected = match (
        zs.agent.validation_std_return,
        zs.agent.validation_success_rate,
    ) {
        (Some(std), Some(success)) => Some(EvalSummary {
            step: zs.agent.steps,
            mean_stock_return: zs.agent.validation_mean_return,
            std_stock_return: std,
            success_rate: success,
        }),
        _ => None,
    };
    let best_eval = selected.or_else(|| {
        evals
            .iter()
            .filter(|m| m.step() == zs.agent.steps)
            .find_map(eval_summary)
    });
    if best_eval.is_none() {
        bail!(
            "{}: no evaluation at the shipped agent's step {} in evals.csv",
            entry.root().display(),
            zs.agent.steps
        );
    }
    let summary = Summary {
        name: zs.name,
        algo: zs.algo,
        env: zs.env,
        train_reward: zs.training_reward,
        eval_reward: zs.evaluation_reward,
        steps: zs.training.steps,
        episodes: zs.training.episodes,
        wall_seconds: zs.training.wall_seconds,
        best_r100_train_reward: zs.training.best_r100_train_reward,
        best_r100_stock_reward: None,
        last_eval: evals.last().and_then(eval_summary),
        best_eval,
        test_eval: Some(TestSummary {
            step: zs.agent.steps,
            episodes: zs.test.episodes,
            first_seed: zs.test.first_seed,
            mean_stock_return: zs.test.mean_return,
            std_stock_return: zs.test.std_return,
            success_rate: zs.test.success_rate,
            returns: zs.test.returns,
            successes: Vec::new(),
        }),
        teachers: zs.teachers,
        machine: Some(zs.machine),
    };
    Ok((summary, evals))
}
