//! `rdpg preference`: which actions a run's critics prefer along its own deterministic
//! episodes, its actor's or another run's policy's (shown the same observations, never
//! acting). A Markdown table on stdout (`--json`: one JSON object).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::checkpoint::verify_agent;
use rdpg_agents::common::Algo;
use rdpg_agents::rdpg::{critic_preference, CriticPreference, RdpgAgent};

use crate::rundir::{RunDir, Which};

/// Arguments of `rdpg preference`.
#[derive(Debug, Args)]
pub struct PreferenceArgs {
    /// The run (or zoo entry) whose agent acts and whose critics value the actions.
    #[arg(long)]
    run: PathBuf,
    /// Which agent of `--run`: best, latest, selected or the step of a kept agent.
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    /// The run (or zoo entry) whose policy's actions are valued beside the agent's own: any
    /// algorithm, on the same environment and action repeat.
    #[arg(long)]
    versus: PathBuf,
    /// Which agent of `--versus`.
    #[arg(long, default_value = "best")]
    versus_checkpoint: Which,
    /// Episodes to run.
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    /// First seed (default: the run's validation seeds, `train.eval_seed`; the test seeds are
    /// for the test alone).
    #[arg(long)]
    seed: Option<u64>,
    /// One JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// `rdpg preference`.
pub fn run(a: &PreferenceArgs) -> Result<()> {
    let run = RunDir::new(&a.run);
    let exp = run.experiment()?;
    if !matches!(exp.algo, Algo::Rdpg | Algo::Ddpg) {
        bail!(
            "{} is a {} agent: `rdpg preference` reads the critics of deterministic \
             actor-critics (rdpg, ddpg)",
            a.run.display(),
            exp.algo.as_str()
        );
    }
    let dir = run.existing_agent(a.checkpoint)?;
    verify_agent(&dir).with_context(|| format!("checking {}", dir.display()))?;
    let agent = RdpgAgent::load_weights(&dir)
        .with_context(|| format!("loading the agent of {}", dir.display()))?;
    let (other_exp, mut other) = RunDir::new(&a.versus).policy(a.versus_checkpoint)?;
    let (t, o) = (&exp.train, &other_exp.train);
    if (&t.env, t.action_repeat) != (&o.env, o.action_repeat) {
        bail!(
            "{} acts on {} with action repeat {}, {} on {} with action repeat {}: the policies \
             must act on the same steps",
            a.run.display(),
            t.env,
            t.action_repeat,
            a.versus.display(),
            o.env,
            o.action_repeat
        );
    }
    let seed = a.seed.unwrap_or(t.eval_seed);
    let p = critic_preference(&agent, other.as_mut(), t, a.episodes, seed).with_context(|| {
        format!(
            "measuring {} against {}",
            a.run.display(),
            a.versus.display()
        )
    })?;
    if a.json {
        println!("{}", serde_json::to_string(&p)?);
    } else {
        let what = format!(
            "`{}` ({} agent, {} updates) against `{}` ({} agent)",
            a.run.display(),
            a.checkpoint,
            agent.updates(),
            a.versus.display(),
            a.versus_checkpoint
        );
        print!("{}", table(&p, &what, &t.reward_label(), seed));
    }
    Ok(())
}

/// The Markdown table of `p`: a line per critic and set of steps.
fn table(p: &CriticPreference, what: &str, reward: &str, seed: u64) -> String {
    let mut md = format!(
        "Critic preference of {what}: the first's deterministic policy on {} episodes from \
         seed {seed} ({} ended at the time limit; mean return {:.1} on the training reward, \
         {reward}); at each step each critic values the first's action and the second's \
         (shown the same observations, never taken) from the same state. RMS distance \
         between the two actions: {:.3}.\n\n\
         | critic | steps of | steps | mean Q, own action | mean Q, other action | other preferred |\n\
         |---|---|---:|---:|---:|---:|\n",
        p.episodes, p.truncated, p.mean_return, p.action_rms
    );
    for l in &p.lines {
        md.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.2} | {:.1} % |\n",
            l.critic,
            l.steps_of,
            l.steps,
            l.mean_own,
            l.mean_other,
            100.0 * l.other_preferred
        ));
    }
    md
}
