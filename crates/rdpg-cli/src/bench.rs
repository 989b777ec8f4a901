//! `rdpg bench`: throughput measurements printed as one JSON line.

use std::time::Instant;

use anyhow::{bail, Result};
use clap::{Args, Subcommand, ValueEnum};
use rdpg_core::rng::NpRng;
use rdpg_envs::{EnvOptions, VecEnv};
use serde::Serialize;

/// A tensor device on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DeviceArg {
    /// The CPU.
    Cpu,
    /// The first CUDA device (an error without one).
    Cuda,
    /// CUDA when available, else the CPU.
    Auto,
}

impl DeviceArg {
    /// The library's device spec.
    pub fn spec(self) -> rdpg_agents::DeviceSpec {
        match self {
            DeviceArg::Cpu => rdpg_agents::DeviceSpec::Cpu,
            DeviceArg::Cuda => rdpg_agents::DeviceSpec::Cuda,
            DeviceArg::Auto => rdpg_agents::DeviceSpec::Auto,
        }
    }
}

/// What to benchmark.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Step environments with uniform random actions, resetting on episode end.
    Env(EnvBenchArgs),
    /// Time RDPG updates on synthetic BipedalWalker-shaped batches (the paper's networks).
    Update(UpdateBenchArgs),
    /// Whole-training throughput: acting, stepping, storing and updating with the paper's
    /// networks (the counterpart of `scripts/bench/pytorch_train_bench.py`).
    Train(TrainBenchArgs),
}

/// Arguments of `rdpg bench train`.
#[derive(Debug, Args)]
pub struct TrainBenchArgs {
    /// Environment id.
    #[arg(long, default_value = "BipedalWalker-v3")]
    env: String,
    /// Environment steps (over all environments), warm-up included.
    #[arg(long, default_value_t = 3000)]
    steps: u64,
    /// Steps of uniform random actions before the first update.
    #[arg(long, default_value_t = 500)]
    warmup: u64,
    /// Updates per environment step after the warm-up.
    #[arg(long, default_value_t = 0.05)]
    ups: f64,
    /// Environments acting in parallel (batched inference).
    #[arg(long, default_value_t = 1)]
    envs: usize,
    /// Worker threads stepping them.
    #[arg(long, default_value_t = 1)]
    workers: usize,
    /// CPU threads for libtorch.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Scan length s.
    #[arg(long, default_value_t = 24)]
    scan: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Optimisation length l (= update length u).
    #[arg(long, default_value_t = 8)]
    opt: usize,
    /// Seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Serialize)]
struct TrainBenchLine<'a> {
    bench: &'static str,
    env: &'a str,
    steps: u64,
    warmup: u64,
    ups: f64,
    envs: usize,
    workers: usize,
    threads: usize,
    batch: usize,
    scan: usize,
    opt: usize,
    updates: u64,
    seconds: f64,
    update_seconds: f64,
    steps_per_sec: f64,
}

fn bench_train(a: &TrainBenchArgs) -> Result<()> {
    use rdpg_agents::rdpg::{ExplorationConfig, OffPolicyConfig, OffPolicyTrainer};
    use rdpg_agents::{DeviceSpec, Quiet, RdpgConfig, TrainConfig, Trainer};
    let train = TrainConfig {
        env: a.env.clone(),
        total_steps: a.steps,
        num_envs: a.envs,
        workers: a.workers,
        eval_every: 0,
        seed: a.seed,
        ..TrainConfig::default()
    };
    let off = OffPolicyConfig {
        warmup_steps: a.warmup,
        updates_per_step: a.ups,
        replay_capacity: 1_000_000,
        exploration: ExplorationConfig::default(),
        ..OffPolicyConfig::default()
    };
    let agent = RdpgConfig {
        scan_len: a.scan,
        batch_size: a.batch,
        opt_len: a.opt,
        update_len: a.opt,
        device: DeviceSpec::Cpu,
        num_threads: Some(a.threads),
        ..RdpgConfig::default()
    };
    let mut trainer = OffPolicyTrainer::new(train, off, agent)?;
    trainer.agent_mut().set_profiling(true);
    let start = Instant::now();
    let steps = trainer.run(a.steps, &mut Quiet)?;
    let seconds = start.elapsed().as_secs_f64();
    let p = trainer.agent().profile().unwrap_or_default();
    let line = TrainBenchLine {
        bench: "train",
        env: &a.env,
        steps,
        warmup: a.warmup,
        ups: a.ups,
        envs: a.envs,
        workers: a.workers,
        threads: a.threads,
        batch: a.batch,
        scan: a.scan,
        opt: a.opt,
        updates: trainer.agent().updates(),
        seconds,
        update_seconds: p.total(),
        steps_per_sec: steps as f64 / seconds,
    };
    println!("{}", serde_json::to_string(&line)?);
    Ok(())
}

/// Arguments of `rdpg bench update`.
#[derive(Debug, Args)]
pub struct UpdateBenchArgs {
    /// Time the update of this experiment's agent (its `[agent]` networks and every update
    /// setting, on its environment's sizes) instead of the paper's networks; `--threads` and
    /// `--device` still apply.
    #[arg(long, conflicts_with_all = ["scan", "batch", "opt"])]
    config: Option<std::path::PathBuf>,
    /// Time the update of a stopped training run as it stands (its agent, optimiser state and
    /// replay from `RUN/checkpoints/latest`, or from RUN itself when it is a checkpoint): one
    /// thread, two threads and, where the agent allows, `parallel_twins`, interleaved over
    /// `--rounds` rounds of `--iters` updates. One JSON line per mode.
    #[arg(long, conflicts_with_all = ["config", "scan", "batch", "opt", "threads", "device"])]
    run: Option<std::path::PathBuf>,
    /// Rounds over the modes with `--run`.
    #[arg(long, default_value_t = 3, requires = "run")]
    rounds: usize,
    /// Scan length s (steps before the optimisation part, no gradient).
    #[arg(long, default_value_t = 24)]
    scan: usize,
    /// Windows per batch.
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Optimisation length l (= update length u).
    #[arg(long, default_value_t = 8)]
    opt: usize,
    /// Timed updates (after 3 warm-up updates).
    #[arg(long, default_value_t = 30)]
    iters: usize,
    /// CPU threads for libtorch.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Device.
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    device: DeviceArg,
}

#[derive(Serialize)]
struct UpdateBenchLine {
    bench: &'static str,
    device: String,
    batch: usize,
    scan: usize,
    opt: usize,
    iters: usize,
    threads: usize,
    #[serde(flatten)]
    ms: PhaseMs,
    #[serde(flatten)]
    flop: PhaseFlop,
    updates_per_sec: f64,
    /// Milliseconds per update (all phases).
    ms_per_update: f64,
    /// Counted GFLOP per update and the rate achieved over the update.
    gflop: f64,
    gflops: f64,
    /// GFLOP/s of plain matrix products at the networks' layer shapes (same run), and the
    /// milliseconds the update's counted FLOP would take at that rate.
    gemm_ref_gflops: f64,
    ms_at_gemm_ref: f64,
}

/// Counted GFLOP per update in each phase, and GFLOP/s achieved in it
/// (`rdpg_agents::rdpg::flops`).
#[derive(Serialize)]
struct PhaseFlop {
    gflop_scan: f64,
    gflop_window_nograd: f64,
    gflop_critic_step: f64,
    gflop_critic_rescan: f64,
    gflop_actor_step: f64,
    gflops_scan: f64,
    gflops_window_nograd: f64,
    gflops_critic_step: f64,
    gflops_critic_rescan: f64,
    gflops_actor_step: f64,
}

impl PhaseFlop {
    fn new(f: &rdpg_agents::rdpg::flops::PhaseFlops, t: &rdpg_agents::rdpg::PhaseTimes) -> Self {
        let rate = |flop: f64, secs: f64| if secs > 0.0 { flop / secs / 1e9 } else { 0.0 };
        Self {
            gflop_scan: f.scan / 1e9,
            gflop_window_nograd: f.window_nograd / 1e9,
            gflop_critic_step: f.critic_step / 1e9,
            gflop_critic_rescan: f.critic_rescan / 1e9,
            gflop_actor_step: f.actor_step / 1e9,
            gflops_scan: rate(f.scan, t.scan),
            gflops_window_nograd: rate(f.window_nograd, t.window_nograd),
            gflops_critic_step: rate(f.critic_step, t.critic_step),
            gflops_critic_rescan: rate(f.critic_rescan, t.critic_rescan),
            gflops_actor_step: rate(f.actor_step, t.actor_step),
        }
    }
}

/// Milliseconds per update in each phase of the update.
#[derive(Serialize)]
struct PhaseMs {
    ms_scan: f64,
    ms_window_nograd: f64,
    ms_critic_step: f64,
    /// FORK's model steps (agents with `agent.fork`; ~0 otherwise).
    ms_models: f64,
    ms_critic_rescan: f64,
    ms_actor_step: f64,
    ms_other: f64,
}

impl From<rdpg_agents::rdpg::PhaseTimes> for PhaseMs {
    fn from(p: rdpg_agents::rdpg::PhaseTimes) -> Self {
        Self {
            ms_scan: p.scan * 1e3,
            ms_window_nograd: p.window_nograd * 1e3,
            ms_critic_step: p.critic_step * 1e3,
            ms_models: p.models * 1e3,
            ms_critic_rescan: p.critic_rescan * 1e3,
            ms_actor_step: p.actor_step * 1e3,
            ms_other: (p.prepare + p.other) * 1e3,
        }
    }
}

#[derive(Serialize)]
struct RunUpdateBenchLine {
    bench: &'static str,
    checkpoint: String,
    updates_before: u64,
    mode: rdpg_agents::rdpg::bench::ThreadMode,
    iters: usize,
    rounds: usize,
    #[serde(flatten)]
    ms: PhaseMs,
    updates_per_sec: f64,
}

fn bench_update_on_run(run: &std::path::Path, iters: usize, rounds: usize) -> Result<()> {
    if rounds == 0 {
        bail!("--rounds must be positive");
    }
    let latest = run.join("checkpoints").join("latest");
    let ckpt = if latest.is_dir() {
        latest
    } else {
        run.to_path_buf()
    };
    let (updates_before, results) =
        rdpg_agents::rdpg::bench::bench_update_on_run(&ckpt, iters, rounds)?;
    for r in results {
        let line = RunUpdateBenchLine {
            bench: "update_run",
            checkpoint: ckpt.display().to_string(),
            updates_before,
            mode: r.mode,
            iters,
            rounds,
            ms: r.per_update.into(),
            updates_per_sec: r.updates_per_sec,
        };
        println!("{}", serde_json::to_string(&line)?);
    }
    Ok(())
}

fn bench_update(a: &UpdateBenchArgs) -> Result<()> {
    use rdpg_agents::rdpg::bench::bench_update_with;
    use rdpg_agents::{DeviceSpec, RdpgConfig};
    if a.iters == 0 || a.batch == 0 || a.opt == 0 {
        bail!("--iters, --batch and --opt must be positive");
    }
    if let Some(run) = &a.run {
        return bench_update_on_run(run, a.iters, a.rounds);
    }
    let device = a.device.spec();
    let (cfg, obs_dim, act_dim) = match &a.config {
        Some(path) => {
            let exp = crate::experiment::Experiment::load(path, &[])?;
            let Some(agent) = exp.agent.clone() else {
                bail!(
                    "{}: `rdpg bench update` times the RDPG/DDPG update; this is a {} experiment",
                    path.display(),
                    exp.algo.as_str()
                );
            };
            let env = rdpg_envs::make_with(&exp.train.env, &exp.train.env_options())?;
            let dims = (env.observation_space().dim(), env.action_space().dim());
            let cfg = RdpgConfig {
                device,
                num_threads: Some(a.threads),
                ..agent
            };
            (cfg, dims.0, dims.1)
        }
        None => {
            let cfg = RdpgConfig {
                scan_len: a.scan,
                batch_size: a.batch,
                opt_len: a.opt,
                update_len: a.opt,
                device,
                num_threads: Some(a.threads),
                ..RdpgConfig::default()
            };
            (cfg, 24, 4)
        }
    };
    let r = bench_update_with(&cfg, obs_dim, act_dim, 0.0, a.iters)?;
    let dev = if device == DeviceSpec::Cpu || !rdpg_agents::cuda_available() {
        "cpu"
    } else {
        "cuda"
    };
    let line = UpdateBenchLine {
        bench: "update",
        device: dev.into(),
        batch: cfg.batch_size,
        scan: cfg.scan_len,
        opt: cfg.opt_len,
        iters: a.iters,
        threads: a.threads,
        ms: r.per_update.into(),
        flop: PhaseFlop::new(&r.flops, &r.per_update),
        updates_per_sec: r.updates_per_sec,
        ms_per_update: 1e3 / r.updates_per_sec,
        gflop: r.flops.total() / 1e9,
        gflops: r.flops.total() * r.updates_per_sec / 1e9,
        gemm_ref_gflops: r.gemm_flops_per_sec / 1e9,
        ms_at_gemm_ref: r.flops.total() / r.gemm_flops_per_sec * 1e3,
    };
    println!("{}", serde_json::to_string(&line)?);
    Ok(())
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
        BenchCommand::Update(a) => bench_update(a),
        BenchCommand::Train(a) => bench_train(a),
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
