//! `rdpg preference`: which actions a run's critics prefer along its own deterministic
//! episodes, its actor's or another run's policy's (shown the same observations, never
//! acting). A Markdown table on stdout (`--json`: one JSON object).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::rdpg::{critic_preference, CriticPreference};

use crate::bias::EpisodeArgs;
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
    #[command(flatten)]
    episodes: EpisodeArgs,
}

/// `rdpg preference`.
pub fn run(a: &PreferenceArgs) -> Result<()> {
    let (exp, agent) = crate::bias::actor_critic(&a.run, a.checkpoint, "preference")?;
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
    let e = &a.episodes;
    let seed = e.seed.unwrap_or(t.eval_seed);
    let p = critic_preference(&agent, other.as_mut(), t, e.episodes, seed).with_context(|| {
        format!(
            "measuring {} against {}",
            a.run.display(),
            a.versus.display()
        )
    })?;
    if e.json {
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
