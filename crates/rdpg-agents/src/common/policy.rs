//! Trained policies acting deterministically, whatever the algorithm, and their evaluation.

use rdpg_envs::{EnvOptions, WalkerReward};

use crate::common::config::TrainConfig;
use crate::common::trainer::EvalRecord;
use crate::error::Result;

/// A trained policy acting deterministically on one environment (evaluation, recording,
/// rendering), whatever the algorithm.
pub trait DeterministicPolicy {
    /// Starts a new episode (e.g. zeroes the recurrent state).
    fn begin_episode(&mut self);
    /// The action in `[-1, 1]^act_dim` for one observation; an observation of the wrong size
    /// or with a non-finite value is an error.
    fn act(&mut self, obs: &[f32]) -> Result<Vec<f32>>;
}

/// Maps an action in the agent's `[-1, 1]` space to the env's bounds (clipping first).
pub fn to_env_action(a: &[f32], low: &[f32], high: &[f32]) -> Vec<f32> {
    a.iter()
        .zip(low.iter().zip(high))
        .map(|(&x, (&lo, &hi))| lo + (x.clamp(-1.0, 1.0) + 1.0) * 0.5 * (hi - lo))
        .collect()
}

/// Deterministic evaluation of `policy` on `episodes` episodes of `cfg`'s environment (its
/// observation mask included) with seeds `seed, seed + 1, ...`, scored on the stock reward,
/// each episode from a fresh state. `step` of the record is 0.
pub fn evaluate_policy(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<EvalRecord> {
    let opts = EnvOptions {
        reward: WalkerReward::Stock,
        ..cfg.env_options()
    };
    let mut env = rdpg_envs::make_with(&cfg.env, &opts)?;
    let space = env.action_space().clone();
    let mut returns = Vec::with_capacity(episodes);
    let mut successes = 0;
    for k in 0..episodes {
        let (mut obs, _) = env.reset(Some(seed + k as u64))?;
        policy.begin_episode();
        let mut ret = 0.0;
        loop {
            let a = policy.act(&obs)?;
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            ret += s.reward;
            if s.done() {
                successes += s.info.success as usize;
                break;
            }
            obs = s.obs;
        }
        returns.push(ret);
    }
    let m = returns.len().max(1) as f64;
    let mean = returns.iter().sum::<f64>() / m;
    let std = (returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / m).sqrt();
    Ok(EvalRecord {
        step: 0,
        mean_return: mean,
        std_return: std,
        success_rate: successes as f64 / m,
        returns,
    })
}
