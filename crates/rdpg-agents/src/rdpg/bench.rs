//! Synthetic BipedalWalker-shaped batches and an update-throughput benchmark (the counterpart
//! of `scripts/bench/pytorch_update_bench.py`).

use std::time::Instant;

use rdpg_core::rng::NpRng;
use rdpg_core::SequenceBatch;
use serde::{Deserialize, Serialize};

use super::agent::RdpgAgent;
use super::config::RdpgConfig;
use super::update::PhaseTimes;
use crate::error::Result;

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
        agent.update(b);
    }
    agent.set_profiling(true);
    let t0 = Instant::now();
    for i in 0..iters {
        agent.update(&batches[i % batches.len()]);
    }
    let secs = t0.elapsed().as_secs_f64();
    let mut p = agent.profile().unwrap_or_default();
    let k = iters.max(1) as f64;
    for v in [
        &mut p.prepare,
        &mut p.scan,
        &mut p.window_nograd,
        &mut p.critic_step,
        &mut p.critic_rescan,
        &mut p.actor_step,
        &mut p.other,
    ] {
        *v /= k;
    }
    Ok(BenchResult {
        updates_per_sec: iters as f64 / secs,
        per_update: p,
    })
}

/// Updates per second at BipedalWalker sizes (obs 24, act 4, the paper's networks, CPU, 2
/// threads) with scan length `scan`, `batch` windows and optimisation length `opt`, over
/// `iters` timed updates on full windows.
///
/// # Panics
/// If the agent cannot be built (invalid sizes).
pub fn bench_update(scan: usize, batch: usize, opt: usize, iters: usize) -> f64 {
    let cfg = RdpgConfig {
        scan_len: scan,
        batch_size: batch,
        opt_len: opt,
        update_len: opt,
        device: crate::common::DeviceSpec::Cpu,
        num_threads: Some(2),
        ..Default::default()
    };
    bench_update_with(&cfg, 24, 4, 0.0, iters)
        .expect("bench agent")
        .updates_per_sec
}
