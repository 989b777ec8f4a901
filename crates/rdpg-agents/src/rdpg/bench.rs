//! Synthetic BipedalWalker-shaped batches and an update-throughput benchmark (the counterpart
//! of `scripts/bench/pytorch_update_bench.py`).

use std::path::Path;
use std::time::Instant;

use rdpg_core::rng::NpRng;
use rdpg_core::SequenceBatch;
use serde::{Deserialize, Serialize};

use super::agent::RdpgAgent;
use super::config::RdpgConfig;
use super::flops::{gemm_reference, update_flops, PhaseFlops};
use super::profile::PhaseTimes;
use super::trainer::OffPolicyTrainer;
use crate::error::{AgentError, Result};

/// A random but well-formed batch: `n` windows of `scan + opt` steps, observations of size
/// `obs_dim` (the last 10 values in `[0, 1]` like lidar ranges, the rest standard normal),
/// actions uniform in `[-1, 1]`, rewards `N(0, 0.1^2)`.
///
/// A fraction `short` of the windows get a random shorter scan (`0..scan`) and, independently,
/// a random shorter optimisation part (`1..opt`, half of those terminated); the others are
/// full. Padding is zero with `mask = 0`, the tail observation sits at `scan + opt_len`.
pub fn synthetic_batch(
    n: usize,
    scan: usize,
    opt: usize,
    obs_dim: usize,
    act_dim: usize,
    short: f64,
    rng: &mut NpRng,
) -> SequenceBatch {
    let t = scan + opt;
    let mut b = SequenceBatch {
        n,
        scan,
        opt,
        obs_dim,
        act_dim,
        obs: vec![0.0; n * (t + 1) * obs_dim],
        actions: vec![0.0; n * t * act_dim],
        rewards: vec![0.0; n * t],
        mask: vec![0.0; n * t],
        scan_len: vec![scan; n],
        opt_len: vec![opt; n],
        tail_terminated: vec![0.0; n],
        injected: vec![0.0; n],
        stored_state: None,
        state_dim: 0,
    };
    let lidar_from = obs_dim.saturating_sub(10);
    for i in 0..n {
        if rng.random() < short && scan > 0 {
            b.scan_len[i] = rng.integers(0, scan as i64) as usize;
        }
        if rng.random() < short && opt > 1 {
            b.opt_len[i] = rng.integers(1, opt as i64) as usize;
            if rng.random() < 0.5 {
                b.tail_terminated[i] = 1.0;
            }
        }
        let first = scan - b.scan_len[i];
        let last = scan + b.opt_len[i]; // exclusive; the tail observation is at `last`
        for j in first..=last {
            for k in 0..obs_dim {
                b.obs[(i * (t + 1) + j) * obs_dim + k] = if k >= lidar_from {
                    rng.random() as f32
                } else {
                    rng.standard_normal() as f32
                };
            }
        }
        for j in first..last {
            b.mask[i * t + j] = 1.0;
            b.rewards[i * t + j] = rng.normal(0.0, 0.1) as f32;
            for k in 0..act_dim {
                b.actions[(i * t + j) * act_dim + k] = rng.uniform(-1.0, 1.0) as f32;
            }
        }
    }
    b
}

/// The result of [`bench_update_with`].
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct BenchResult {
    /// Updates per second over the timed iterations.
    pub updates_per_sec: f64,
    /// Seconds per update spent in each phase (averaged; CPU timings).
    pub per_update: PhaseTimes,
    /// Counted FLOP per update in each phase ([`super::flops`]).
    pub flops: PhaseFlops,
    /// FLOP per second of plain matrix products at the networks' layer shapes, measured in
    /// the same run right after the updates, on the same thread settings (CPU).
    pub gemm_flops_per_sec: f64,
}

/// Times `iters` updates (after 3 warm-up updates) of an agent built from `cfg` on synthetic
/// batches of `cfg.batch_size` windows with `cfg.scan_len` / `cfg.opt_len`, `short` as in
/// [`synthetic_batch`]. Returns throughput and the per-phase split.
pub fn bench_update_with(
    cfg: &RdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    short: f64,
    iters: usize,
) -> Result<BenchResult> {
    let mut agent = RdpgAgent::new(cfg.clone(), obs_dim, act_dim, 0)?;
    let mut rng = NpRng::from_seed(0);
    let batches: Vec<SequenceBatch> = (0..4)
        .map(|_| {
            let mut b = synthetic_batch(
                cfg.batch_size,
                cfg.scan_len,
                cfg.opt_len,
                obs_dim,
                act_dim,
                short,
                &mut rng,
            );
            // A replay that stores acting-time states hands them over with each window.
            if cfg.burn_in_from_stored_state {
                b.state_dim = agent.state_dim();
                let states = (0..b.n * b.state_dim).map(|_| rng.uniform(-0.5, 0.5) as f32);
                b.stored_state = Some(states.collect());
            }
            b
        })
        .collect();
    for b in batches.iter().take(3) {
        agent.update(b)?;
    }
    agent.set_profiling(true);
    let t0 = Instant::now();
    for i in 0..iters {
        agent.update(&batches[i % batches.len()])?;
    }
    let secs = t0.elapsed().as_secs_f64();
    let rows = ((cfg.batch_size * cfg.opt_len) as i64, cfg.batch_size as i64);
    Ok(BenchResult {
        updates_per_sec: iters as f64 / secs,
        per_update: agent.profile().unwrap_or_default().per_update(),
        flops: update_flops(cfg, obs_dim, act_dim),
        gemm_flops_per_sec: gemm_reference(cfg, obs_dim, act_dim, rows, 1.0),
    })
}

/// How an update uses the CPU: what [`bench_update_on_run`] compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ThreadMode {
    /// One libtorch thread.
    OneThread,
    /// Two libtorch (intra-op) threads.
    TwoThreads,
    /// One libtorch thread each on two threads: the second critic's work on the second
    /// (`agent.parallel_twins`).
    ParallelTwins,
}

/// One mode's result in [`bench_update_on_run`].
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct ModeResult {
    /// The thread mode.
    pub mode: ThreadMode,
    /// Updates per second over all its timed updates.
    pub updates_per_sec: f64,
    /// Seconds per update in each phase.
    pub per_update: PhaseTimes,
}

/// Times the update of a stopped training run, as it stands: the agent, its optimiser state
/// and its replay from the trainer checkpoint `checkpoint` (e.g. `RUN/checkpoints/latest`),
/// on 16 batches sampled from that replay (seed 0). This is the update a long run makes
/// after `updates` updates (the first value returned), with its trained weights and Adam
/// moments, where a small-batch synthetic benchmark cannot see effects that grow with
/// training (subnormal floats). Each of the modes the agent allows ([`ThreadMode`];
/// `ParallelTwins` needs twin critics and target networks) runs `iters` updates per round,
/// modes interleaved over `rounds` rounds so that the machine's drift hits all alike; the
/// agent keeps learning through all of them (nothing is saved).
pub fn bench_update_on_run(
    checkpoint: &Path,
    iters: usize,
    rounds: usize,
) -> Result<(u64, Vec<ModeResult>)> {
    crate::common::checkpoint::verify(checkpoint)?;
    let mut trainer = OffPolicyTrainer::load(checkpoint)?;
    let c = trainer.agent().config().clone();
    let (b, s, l) = (c.batch_size, c.scan_len, c.opt_len);
    let mut rng = NpRng::from_seed(0);
    let batches = (0..16)
        .map(|_| trainer.replay().sample(&mut rng, b, s, l))
        .collect::<Option<Vec<SequenceBatch>>>()
        .ok_or_else(|| {
            AgentError::Checkpoint(format!(
                "{}: the replay has too few transitions for a batch of {b}",
                checkpoint.display()
            ))
        })?;
    let updates_before = trainer.agent().updates();
    let agent = trainer.agent_mut();
    let twins_ok = agent.set_parallel_twins(true).is_ok();
    let mut modes = vec![ThreadMode::OneThread, ThreadMode::TwoThreads];
    if twins_ok {
        modes.push(ThreadMode::ParallelTwins);
    }
    let set_mode = |agent: &mut RdpgAgent, m: ThreadMode| -> Result<()> {
        tch::set_num_threads(if m == ThreadMode::TwoThreads { 2 } else { 1 });
        agent.set_parallel_twins(m == ThreadMode::ParallelTwins && twins_ok)
    };
    let mut total: Vec<(f64, PhaseTimes)> = vec![(0.0, PhaseTimes::default()); modes.len()];
    let mut k = 0;
    for &m in &modes {
        set_mode(agent, m)?;
        for _ in 0..3 {
            agent.update(&batches[k % batches.len()])?;
            k += 1;
        }
    }
    for _ in 0..rounds {
        for (i, &m) in modes.iter().enumerate() {
            set_mode(agent, m)?;
            agent.set_profiling(true);
            let t0 = Instant::now();
            for _ in 0..iters {
                agent.update(&batches[k % batches.len()])?;
                k += 1;
            }
            total[i].0 += t0.elapsed().as_secs_f64();
            let p = agent.profile().unwrap_or_default();
            total[i].1.add(&p);
        }
    }
    agent.set_profiling(false);
    let out = modes
        .iter()
        .zip(total)
        .map(|(&mode, (secs, p))| ModeResult {
            mode,
            updates_per_sec: p.updates as f64 / secs.max(1e-12),
            per_update: p.per_update(),
        })
        .collect();
    Ok((updates_before, out))
}
