//! `rdpg staleness`: how far the recurrent states a run's updates start their replayed
//! windows from lie from the states its current networks reach along the whole episode
//! (R2D2's recurrent-state staleness), read from the run's last checkpoint: its agent and its
//! replay buffer. A Markdown table on stdout (`--json`: one JSON object).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::rdpg::trainer::load_replay;
use rdpg_agents::rdpg::{state_staleness, RdpgAgent, Staleness};

use crate::rundir::{RunDir, Which};

/// Arguments of `rdpg staleness`.
#[derive(Debug, Args)]
pub struct StalenessArgs {
    /// Run directory (its `checkpoints/latest`: the agent and the replay it learned from).
    #[arg(long)]
    run: PathBuf,
    /// Positions drawn uniformly over the replay's own transitions (and as many over its
    /// injected ones).
    #[arg(long, default_value_t = 2000)]
    positions: usize,
    /// Burn-in lengths to measure, comma-separated (default: 0 and the agent's `scan_len`).
    #[arg(long, value_delimiter = ',')]
    burn_in: Vec<usize>,
    /// Seed of the draw.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// One JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

/// `rdpg staleness`.
pub fn run(a: &StalenessArgs) -> Result<()> {
    let run = RunDir::new(&a.run);
    if run.is_zoo_entry() {
        bail!(
            "{} is a zoo entry: it ships no replay buffer; measure the run it came from",
            a.run.display()
        );
    }
    let dir = run.checkpoint(Which::Latest);
    let agent = RdpgAgent::load(dir.join("agent"))
        .with_context(|| format!("loading the agent of {}", dir.display()))?;
    let replay = load_replay(&dir).with_context(|| format!("loading {}", dir.display()))?;
    let mut burn_ins = a.burn_in.clone();
    if burn_ins.is_empty() {
        burn_ins = vec![0, agent.config().scan_len];
    }
    burn_ins.sort_unstable();
    burn_ins.dedup();
    let s = state_staleness(&agent, &replay, a.positions, &burn_ins, a.seed)
        .with_context(|| format!("measuring {}", a.run.display()))?;
    if a.json {
        println!("{}", serde_json::to_string(&s)?);
    } else {
        print!(
            "{}",
            table(&s, &a.run.display().to_string(), agent.updates())
        );
    }
    Ok(())
}

/// The Markdown table of `s`: a line per pool, network and start, a column per burn-in.
fn table(s: &Staleness, run: &str, updates: u64) -> String {
    let mut md = format!(
        "Recurrent-state staleness of `{run}` (its last checkpoint, {updates} updates): at \
         positions drawn uniformly over its replay, the gap between the state a window starts \
         from (stored: the acting-time state the replay holds; zero: the paper's h_init) \
         followed by a burn-in of k steps, and the state its current networks reach from the \
         episode start. Its updates start from {} with k = {}. Actor: RMS action difference \
         (actions in [-1, 1]); critic 0: |ΔQ| over the spread of Q ({:.1}) at the replayed \
         action. Zero with k = 0 is no memory at all: the scale of the gaps. Cells: mean (90th \
         percentile; max).\n\n| pool | net | start | positions |",
        if s.from_stored_state {
            "the stored state"
        } else {
            "a zero state"
        },
        s.scan_len,
        s.q_spread
    );
    for k in &s.burn_ins {
        md.push_str(&format!(" k = {k} |"));
    }
    md.push_str("\n|---|---|---|---:|");
    md.push_str(&"---:|".repeat(s.burn_ins.len()));
    md.push('\n');
    let mut lines: Vec<(&str, &str, &str, usize)> = Vec::new();
    for g in &s.gaps {
        let key = (
            g.pool.as_str(),
            g.net.as_str(),
            g.start.as_str(),
            g.positions,
        );
        if !lines.contains(&key) {
            lines.push(key);
        }
    }
    for (pool, net, start, positions) in lines {
        md.push_str(&format!("| {pool} | {net} | {start} | {positions} |"));
        for k in &s.burn_ins {
            match s.gaps.iter().find(|g| {
                (g.pool.as_str(), g.net.as_str(), g.start.as_str()) == (pool, net, start)
                    && g.burn_in == *k
            }) {
                Some(g) => md.push_str(&format!(" {:.3} ({:.3}; {:.3}) |", g.mean, g.p90, g.max)),
                None => md.push_str(" |"),
            }
        }
        md.push('\n');
    }
    md
}
