//! `rdpg bias`: a run's critics against the returns they predict (TD3's estimation bias): the
//! deterministic policy's episodes on its training reward, each critic's `Q(o_t, a_t)` along
//! them against the discounted return of the rest of the episode. A Markdown table on stdout
//! (`--json`: one JSON object).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::checkpoint::verify_agent;
use rdpg_agents::common::Algo;
use rdpg_agents::rdpg::{estimation_bias, EstimationBias, RdpgAgent};

use crate::experiment::Experiment;
use crate::rundir::{RunDir, Which};

/// Arguments of `rdpg bias`.
#[derive(Debug, Args)]
pub struct BiasArgs {
    /// Run directory written by `rdpg train`, or a zoo entry.
    #[arg(long)]
    run: PathBuf,
    /// Which agent of the run: best, latest, selected or the step of a kept agent.
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    #[command(flatten)]
    episodes: EpisodeArgs,
}

/// The episodes a measurement of a run's critics runs, and its output.
#[derive(Debug, Args)]
pub struct EpisodeArgs {
    /// Episodes to run.
    #[arg(long, default_value_t = 10)]
    pub episodes: usize,
    /// First seed (default: the run's validation seeds, `train.eval_seed`; the test seeds are
    /// for the test alone).
    #[arg(long)]
    pub seed: Option<u64>,
    /// One JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// The experiment and agent `which` of the deterministic actor-critic run (or zoo entry)
/// `path`, whose critics `command` reads; another algorithm is refused.
pub fn actor_critic(path: &Path, which: Which, command: &str) -> Result<(Experiment, RdpgAgent)> {
    let run = RunDir::new(path);
    let exp = run.experiment()?;
    if !matches!(exp.algo, Algo::Rdpg | Algo::Ddpg) {
        bail!(
            "{} is a {} agent: `rdpg {command}` reads the critics of deterministic actor-critics \
             (rdpg, ddpg), which estimate the deterministic policy's return",
            path.display(),
            exp.algo.as_str()
        );
    }
    let dir = run.existing_agent(which)?;
    verify_agent(&dir).with_context(|| format!("checking {}", dir.display()))?;
    let agent = RdpgAgent::load_weights(&dir)
        .with_context(|| format!("loading the agent of {}", dir.display()))?;
    Ok((exp, agent))
}

/// `rdpg bias`.
pub fn run(a: &BiasArgs) -> Result<()> {
    let (exp, agent) = actor_critic(&a.run, a.checkpoint, "bias")?;
    let e = &a.episodes;
    let seed = e.seed.unwrap_or(exp.train.eval_seed);
    let b = estimation_bias(&agent, &exp.train, e.episodes, seed)
        .with_context(|| format!("measuring {}", a.run.display()))?;
    if e.json {
        println!("{}", serde_json::to_string(&b)?);
    } else {
        let what = format!(
            "`{}` ({} agent, {} updates)",
            a.run.display(),
            a.checkpoint,
            agent.updates()
        );
        print!("{}", table(&b, &what, &exp.train.reward_label(), seed));
    }
    Ok(())
}

/// The Markdown table of `b`: a line per critic.
fn table(b: &EstimationBias, what: &str, reward: &str, seed: u64) -> String {
    let n = b.episodes.len();
    let terminated = b.episodes.iter().filter(|e| e.terminated).count();
    let mean_return = b.episodes.iter().map(|e| e.train_return).sum::<f64>() / n as f64;
    let mut md = format!(
        "Estimation bias of {what}: its deterministic policy on {n} episodes from seed {seed} \
         ({terminated} terminated, {} truncated; mean return {mean_return:.1} on the training \
         reward, {reward}); each critic's Q(o_t, a_t) along them, its state from the episode \
         start, against the discounted return of the rest of the episode (gamma {}), over \
         {} steps (a truncated episode's last {} left out). Relative: the mean bias over the \
         mean |G|; across episodes: the standard deviation of the episodes' mean biases.\n\n\
         | critic | mean Q | mean G | mean bias | relative | RMSE | across episodes |\n\
         |---|---:|---:|---:|---:|---:|---:|\n",
        n - terminated,
        b.gamma,
        b.steps_measured,
        b.truncated_tail
    );
    for c in &b.critics {
        md.push_str(&format!(
            "| {} | {:.2} | {:.2} | {:+.2} | {:+.1} % | {:.2} | {:.2} |\n",
            c.critic,
            c.mean_q,
            c.mean_return,
            c.mean_bias,
            100.0 * c.relative_bias,
            c.rmse,
            c.episode_std
        ));
    }
    md
}
