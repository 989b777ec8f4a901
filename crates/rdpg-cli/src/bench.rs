//! `rdpg bench`: throughput measurements printed as one JSON line.

use std::time::Instant;

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use rdpg_core::rng::NpRng;
use rdpg_envs::{EnvOptions, VecEnv};
use serde::Serialize;

/// What to benchmark.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Step environments with uniform random actions, resetting on episode end.
    Env(EnvBenchArgs),
}

/// Arguments of `rdpg bench env`.
#[derive(Debug, Args)]
pub struct EnvBenchArgs {
    /// Environment id.
    #[arg(long, default_value = "BipedalWalker-v3")]
    env: String,
    /// Total environment steps (over all environments).
    #[arg(long, default_value_t = 20_000)]
    steps: usize,
    /// Worker threads. Without it, one environment is stepped on the calling thread.
    #[arg(long)]
    workers: Option<usize>,
    /// Environments in the vector env (default: one per worker).
    #[arg(long)]
    envs: Option<usize>,
    /// Seed of the environments and of the actions.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Serialize)]
struct EnvBenchLine<'a> {
    bench: &'static str,
    env: &'a str,
    workers: usize,
    envs: usize,
    steps: usize,
    episodes: usize,
    seconds: f64,
    steps_per_sec: f64,
}

/// Runs a benchmark.
pub fn run(cmd: &BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Env(a) => bench_env(a),
    }
}

fn bench_env(a: &EnvBenchArgs) -> Result<()> {
    if a.steps == 0 {
        bail!("--steps must be positive");
    }
    let mut rng = NpRng::from_seed(a.seed);
    let (workers, envs, episodes, seconds) = match a.workers {
        None => {
            let mut env = rdpg_envs::make(&a.env)?;
            let dim = env.action_space().dim();
            let (lo, hi) = (
                env.action_space().low.clone(),
                env.action_space().high.clone(),
            );
            let actions: Vec<Vec<f32>> = (0..a.steps)
                .map(|_| {
                    (0..dim)
                        .map(|i| rng.uniform(lo[i] as f64, hi[i] as f64) as f32)
                        .collect()
                })
                .collect();
            let start = Instant::now();
            env.reset(Some(a.seed))?;
            let mut episodes = 0;
            for act in &actions {
                if env.step(act)?.done() {
                    episodes += 1;
                    env.reset(None)?;
                }
            }
            (0, 1, episodes, start.elapsed().as_secs_f64())
        }
        Some(w) => {
            let w = w.max(1);
            let n = a.envs.unwrap_or(w).max(1);
            let mut venv = VecEnv::make(&a.env, &EnvOptions::default(), n, w)?;
            let rounds = a.steps.div_ceil(n);
            let dim = venv.act_dim();
            let actions: Vec<Vec<Vec<f32>>> = (0..rounds)
                .map(|_| {
                    (0..n)
                        .map(|_| (0..dim).map(|_| rng.uniform(-1.0, 1.0) as f32).collect())
                        .collect()
                })
                .collect();
            let start = Instant::now();
            venv.reset(Some(a.seed))?;
            let mut episodes = 0;
            for acts in &actions {
                episodes += venv
                    .step(acts)?
                    .iter()
                    .filter(|s| s.final_obs.is_some())
                    .count();
            }
            (w, n, episodes, start.elapsed().as_secs_f64())
        }
    };
    let steps = if a.workers.is_some() {
        a.steps.div_ceil(envs) * envs
    } else {
        a.steps
    };
    let line = EnvBenchLine {
        bench: "env",
        env: &a.env,
        workers,
        envs,
        steps,
        episodes,
        seconds,
        steps_per_sec: steps as f64 / seconds,
    };
    println!("{}", serde_json::to_string(&line)?);
    Ok(())
}
