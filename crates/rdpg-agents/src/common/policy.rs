//! Trained policies acting deterministically, whatever the algorithm, and their evaluation.

use crate::common::config::TrainConfig;
use std::collections::BTreeMap;

use crate::common::trainer::{EvalRecord, ObstacleRecord};
use crate::error::{AgentError, Result};

/// A trained policy acting deterministically on one environment (evaluation, recording,
/// rendering), whatever the algorithm.
pub trait DeterministicPolicy {
    /// Starts a new episode (e.g. zeroes the recurrent state).
    fn begin_episode(&mut self);
    /// The action in `[-1, 1]^act_dim` for one observation; an observation of the wrong size
    /// or with a non-finite value is an error.
    fn act(&mut self, obs: &[f32]) -> Result<Vec<f32>>;
    /// What the policy carries from one step to the next (a recurrent state, a window of
    /// observations) as flat values, for [`DeterministicPolicy::set_state`]; empty for a
    /// stateless policy.
    fn state(&self) -> Vec<f32> {
        Vec::new()
    }
    /// Continues from a state [`DeterministicPolicy::state`] gave; a state of the wrong size
    /// or out of range is an error and changes nothing.
    fn set_state(&mut self, state: &[f32]) -> Result<()> {
        if state.is_empty() {
            return Ok(());
        }
        Err(AgentError::Shape(format!(
            "a state of {} values for a stateless policy",
            state.len()
        )))
    }
    /// From the next episode on, acts remembering at most the last `k` observations (the
    /// current one included), its recurrent state re-encoded from zero over them at every
    /// step: a probe of how far back the policy's memory matters. A policy with no memory
    /// refuses.
    fn limit_memory(&mut self, k: usize) -> Result<()> {
        Err(AgentError::Config {
            field: "memory",
            reason: format!("this policy carries no memory to limit to {k} observation(s)"),
        })
    }
}

/// `a` unchanged if every component is finite, else [`AgentError::Diverged`] saying `what`
/// produced it: the networks hold NaN or inf.
pub fn check_action_finite(a: Vec<f32>, what: &str) -> Result<Vec<f32>> {
    if a.iter().any(|x| !x.is_finite()) {
        return Err(AgentError::Diverged(format!(
            "{what} is not finite (the weights or state hold NaN or inf)"
        )));
    }
    Ok(a)
}

/// The seeds of `episodes` episodes from `seed` on (`seed`, `seed + 1`, ...), or an error when
/// they would run past the largest seed.
pub fn episode_seeds(seed: u64, episodes: usize) -> Result<impl Iterator<Item = u64>> {
    let ok = (episodes as u64)
        .checked_sub(1)
        .is_none_or(|k| seed.checked_add(k).is_some());
    if !ok {
        return Err(AgentError::Input(format!(
            "{episodes} episodes from seed {seed} run past the largest seed ({})",
            u64::MAX
        )));
    }
    Ok((0..episodes as u64).map(move |k| seed + k))
}

/// Room for at most this many per-episode results up front (the counts come from the user).
pub(crate) const PREALLOCATED_EPISODES: usize = 4096;

/// Maps an action in the agent's `[-1, 1]` space to the env's bounds (clipping first).
pub fn to_env_action(a: &[f32], low: &[f32], high: &[f32]) -> Vec<f32> {
    a.iter()
        .zip(low.iter().zip(high))
        .map(|(&x, (&lo, &hi))| lo + (x.clamp(-1.0, 1.0) + 1.0) * 0.5 * (hi - lo))
        .collect()
}

/// One finished evaluation episode, as handed to the observer of
/// [`evaluate_policy_traced`].
#[derive(Debug, Clone)]
pub struct EpisodeTrace<'a> {
    /// The episode's reset seed.
    pub seed: u64,
    /// Its stock return.
    pub ret: f64,
    /// The actions given to the environment (within its bounds), one per step: replaying
    /// the episodes in order in one Gymnasium env, each from `reset(seed)`, with these
    /// actions as `float32`, gives the same episodes.
    pub actions: &'a [Vec<f32>],
}

/// Deterministic evaluation of `policy` on `episodes` episodes of `cfg`'s environment (its
/// observation mask included) with seeds `seed, seed + 1, ...`, scored on the stock reward,
/// the policy's state reset for each episode. The episodes run one after the other in one
/// environment, as in a plain Gymnasium loop (a walker keeps its Box2D world, so an episode
/// replays exactly after the same earlier ones). `step` of the record is 0.
pub fn evaluate_policy(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<EvalRecord> {
    evaluate_policy_traced(policy, cfg, episodes, seed, &mut |_| Ok(()))
}

/// [`evaluate_policy`], handing each finished episode (seed, return, actions) to `on_episode`
/// before the next one starts; an error from it stops the evaluation.
pub fn evaluate_policy_traced(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
    on_episode: &mut dyn FnMut(&EpisodeTrace<'_>) -> Result<()>,
) -> Result<EvalRecord> {
    let mut env = rdpg_envs::make_with(&cfg.env, &cfg.eval_env_options())?;
    let space = env.action_space().clone();
    let mut returns = Vec::with_capacity(episodes.min(PREALLOCATED_EPISODES));
    let mut lengths = Vec::with_capacity(episodes.min(PREALLOCATED_EPISODES));
    let mut successes = Vec::with_capacity(episodes.min(PREALLOCATED_EPISODES));
    let mut time_limits = 0;
    let mut obstacles: BTreeMap<String, ObstacleRecord> = BTreeMap::new();
    let mut actions = Vec::new();
    for ep_seed in episode_seeds(seed, episodes)? {
        let (mut obs, _) = env.reset(Some(ep_seed))?;
        policy.begin_episode();
        actions.clear();
        let mut ret = 0.0;
        loop {
            let a = to_env_action(&policy.act(&obs)?, &space.low, &space.high);
            let s = env.step(&a)?;
            actions.push(a);
            ret += s.reward;
            if s.done() {
                successes.push(s.info.success);
                time_limits += (s.truncated && !s.terminated) as usize;
                if let Some(c) = s.info.course {
                    note_course(&mut obstacles, &c, &s);
                }
                break;
            }
            obs = s.obs;
        }
        on_episode(&EpisodeTrace {
            seed: ep_seed,
            ret,
            actions: &actions,
        })?;
        returns.push(ret);
        lengths.push(actions.len());
    }
    let m = returns.len().max(1) as f64;
    let mean = returns.iter().sum::<f64>() / m;
    let std = (returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / m).sqrt();
    Ok(EvalRecord {
        step: 0,
        mean_return: mean,
        std_return: std,
        success_rate: successes.iter().filter(|&&x| x).count() as f64 / m,
        time_limit_rate: time_limits as f64 / m,
        returns,
        lengths,
        successes,
        obstacles,
    })
}

/// Adds a finished walker episode to the per-obstacle counts: the obstacles it passed, and
/// where it ended unless it finished the course (`none`: away from any obstacle).
fn note_course(
    obstacles: &mut BTreeMap<String, ObstacleRecord>,
    c: &rdpg_core::Course,
    last: &rdpg_core::Step,
) {
    for o in rdpg_core::Obstacle::ALL {
        obstacles.entry(o.as_str().into()).or_default().passed += u64::from(c.passed[o as usize]);
    }
    if !last.info.success {
        let at = c.at.map_or("none", |o| o.as_str());
        let r = obstacles.entry(at.into()).or_default();
        if last.terminated {
            r.fell += 1;
        } else {
            r.stuck += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Always the same action.
    struct Constant(Vec<f32>);

    impl DeterministicPolicy for Constant {
        fn begin_episode(&mut self) {}
        fn act(&mut self, _obs: &[f32]) -> Result<Vec<f32>> {
            Ok(self.0.clone())
        }
    }

    fn eval(env: &str, action: Vec<f32>, episodes: usize) -> EvalRecord {
        let cfg = TrainConfig {
            env: env.into(),
            ..TrainConfig::default()
        };
        evaluate_policy(&mut Constant(action), &cfg, episodes, 7).unwrap()
    }

    /// Episodes cut by the time limit are counted apart from those that end in the MDP, and
    /// every episode's length is its number of actions.
    #[test]
    fn evaluation_counts_time_limits_and_lengths() {
        // Pendulum only ends at its 200-step limit.
        let r = eval("Pendulum-v1", vec![0.0], 3);
        assert_eq!((r.time_limit_rate, r.success_rate), (1.0, 0.0));
        assert_eq!(r.lengths, [200; 3]);
        // CueMemory ends with the agent's answer, after the cue and the blank steps.
        let r = eval("CueMemory-v0", vec![1.0], 4);
        assert_eq!(r.time_limit_rate, 0.0);
        assert_eq!(r.lengths, [6; 4]);
    }

    /// On Hardcore every episode ends somewhere on the course: the per-obstacle counts of
    /// falls and stuck episodes, with the successes, add up to the episodes, and a walker
    /// that falls at once has passed nothing. Other envs report no course.
    #[test]
    fn evaluation_counts_falls_per_obstacle() {
        // Both hips and knees driven hard: the walker falls within a few steps of the start.
        let r = eval("BipedalWalkerHardcore-v3", vec![1.0, -1.0, 1.0, -1.0], 3);
        let ended: u64 = r.obstacles.values().map(|o| o.fell + o.stuck).sum();
        let successes = (r.success_rate * 3.0).round() as u64;
        assert_eq!(ended + successes, 3, "{:?}", r.obstacles);
        assert_eq!(r.obstacles["none"].fell, 3, "{:?}", r.obstacles);
        for o in ["stump", "stairs", "pit"] {
            assert_eq!(r.obstacles[o].passed, 0);
        }
        assert!(eval("Pendulum-v1", vec![0.0], 1).obstacles.is_empty());
    }
}
