//! `rdpg rollout`: replays a fixed action sequence, for debugging and for cross-checking
//! against another implementation (e.g. Gymnasium).
//!
//! Contract: `rdpg rollout --env ID --seed N --actions FILE`, FILE holding one action per line
//! as comma-separated numbers (blank lines and lines starting with `#` are skipped). Output on
//! stdout, one JSON object per line: first `{"step":0,"obs":[...]}` for the reset, then
//! `{"step":k,"obs":[...],"reward":r,"terminated":b,"truncated":b}` per action until the
//! episode ends or the actions run out. Observations are printed as the shortest decimal that
//! parses back to the same f32; rewards as the shortest that parses back to the same f64.

use std::io::{BufWriter, Write};
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use serde::Serialize;

/// Arguments of `rdpg rollout`.
#[derive(Debug, Args)]
pub struct RolloutArgs {
    /// Environment id, e.g. BipedalWalker-v3.
    #[arg(long)]
    env: String,
    /// Seed passed to reset.
    #[arg(long)]
    seed: u64,
    /// File with one action per line, components separated by commas.
    #[arg(long)]
    actions: PathBuf,
}

#[derive(Serialize)]
struct ResetLine<'a> {
    step: usize,
    obs: &'a [f32],
}

#[derive(Serialize)]
struct StepLine<'a> {
    step: usize,
    obs: &'a [f32],
    reward: f64,
    terminated: bool,
    truncated: bool,
}

/// Parses an actions file: one action of `dim` finite numbers per line.
pub fn parse_actions(text: &str, dim: usize) -> Result<Vec<Vec<f32>>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let action: Vec<f32> = line
            .split(',')
            .map(|v| {
                let v = v.trim();
                v.parse::<f32>()
                    .with_context(|| format!("line {}: {v:?} is not a number", n + 1))
            })
            .collect::<Result<_>>()?;
        if action.len() != dim {
            bail!(
                "line {}: {} numbers, the action space has {dim}",
                n + 1,
                action.len()
            );
        }
        if let Some(v) = action.iter().find(|v| !v.is_finite()) {
            bail!("line {}: non-finite action component {v}", n + 1);
        }
        out.push(action);
    }
    Ok(out)
}

/// Runs `rdpg rollout`.
pub fn run(args: &RolloutArgs) -> Result<()> {
    let mut env = rdpg_envs::make(&args.env)?;
    let text = std::fs::read_to_string(&args.actions)
        .with_context(|| format!("cannot read actions file {}", args.actions.display()))?;
    let actions = parse_actions(&text, env.action_space().dim())
        .with_context(|| format!("in actions file {}", args.actions.display()))?;
    let stdout = std::io::stdout();
    let mut out = BufWriter::new(stdout.lock());
    let (obs, _) = env.reset(Some(args.seed))?;
    serde_json::to_writer(&mut out, &ResetLine { step: 0, obs: &obs })?;
    writeln!(out)?;
    for (k, a) in actions.iter().enumerate() {
        let s = env.step(a)?;
        let line = StepLine {
            step: k + 1,
            obs: &s.obs,
            reward: s.reward,
            terminated: s.terminated,
            truncated: s.truncated,
        };
        serde_json::to_writer(&mut out, &line)?;
        writeln!(out)?;
        if s.done() {
            break;
        }
    }
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects_clearly() {
        let a = parse_actions("# header\n0.5, -1, 0,1e-3\n\n1,1,1,1\n", 4).unwrap();
        assert_eq!(a, vec![vec![0.5, -1.0, 0.0, 1e-3], vec![1.0; 4]]);
        let e = parse_actions("1,2,3\n", 4).unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("3 numbers"), "{e}");
        let e = parse_actions("1,2,x,4\n", 4).unwrap_err().to_string();
        assert!(e.contains("\"x\""), "{e}");
        assert!(parse_actions("1,2,NaN,4\n", 4).is_err());
    }
}
