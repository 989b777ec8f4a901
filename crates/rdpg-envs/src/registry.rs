//! Environment ids and the [`make`] factory (Gymnasium's `gym.make`).

use crate::bipedal::{BipedalWalker, WalkerConfig, WalkerReward};
use crate::wrappers::{ActionRepeat, FallPenalty, FrameStack, ObsMask, PrevAction, TimeLimit};
use crate::{CueMemory, Pendulum, Renderable};
use rdpg_core::{Env, EnvError};

/// Ids [`make`] knows.
pub const ENV_IDS: [&str; 6] = [
    "BipedalWalker-v3",
    "BipedalWalkerHardcore-v3",
    "Pendulum-v1",
    "PendulumNoVel-v1",
    "CueMemory-v0",
    "DelayedCue-v0",
];

/// An environment that can also be drawn: what [`make`] returns.
pub trait AnyEnv: Env + Renderable {}
impl<T: Env + Renderable> AnyEnv for T {}

impl Renderable for Box<dyn AnyEnv> {
    fn scene(&self) -> rdpg_render::Scene {
        (**self).scene()
    }
}

/// Options of [`make_with`]; the defaults give the registered environment unchanged.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvOptions {
    /// Walkers only: which reward `step` pays.
    pub reward: WalkerReward,
    /// Observation components to hide (e.g. velocities), applied inside the time limit.
    pub hide_obs: Vec<usize>,
    /// Overrides the registered time limit.
    pub max_episode_steps: Option<usize>,
    /// Walkers only: a new Box2D world at every reset, so that each episode depends on its
    /// seed and actions alone ([`WalkerConfig::fresh_world`]); training uses it.
    pub fresh_world: bool,
    /// Walkers only: the reward of a fall (stock −100, paper −20) becomes this
    /// ([`FallPenalty`]); `info.stock_reward` keeps the stock one.
    pub fall_penalty: Option<f64>,
    /// Each action is held for this many frames ([`ActionRepeat`]; 1: none). The time limit
    /// still counts frames.
    pub action_repeat: usize,
    /// The previous action in front of the observation ([`PrevAction`]), outside the action
    /// repeat: the
    /// agent's previous action, whatever the action repeat.
    pub prev_action: bool,
    /// The last this many observations side by side ([`FrameStack`]), outermost (each with
    /// its previous action in front, with `prev_action`). 1: none.
    pub frame_stack: usize,
}

impl Default for EnvOptions {
    fn default() -> Self {
        Self {
            reward: WalkerReward::Stock,
            hide_obs: Vec::new(),
            max_episode_steps: None,
            fresh_world: false,
            fall_penalty: None,
            action_repeat: 1,
            prev_action: false,
            frame_stack: 1,
        }
    }
}

/// Builds a registered environment with its time limit (1600 steps for BipedalWalker-v3, 2000
/// for the hardcore version, 200 for the pendulums, 6 for `CueMemory-v0`, 12 for
/// `DelayedCue-v0`).
pub fn make(id: &str) -> Result<Box<dyn AnyEnv>, EnvError> {
    make_with(id, &EnvOptions::default())
}

/// [`make`] with options. Wrapping order, inside out: the env, the observation mask, the time
/// limit, the fall penalty, the action repeat, the previous action, the frame stack.
#[allow(
    clippy::expect_used,
    reason = "every registered env has a time limit (registry test)"
)]
pub fn make_with(id: &str, opts: &EnvOptions) -> Result<Box<dyn AnyEnv>, EnvError> {
    let walker = id.starts_with("BipedalWalker");
    if opts.fall_penalty.is_some() && !walker {
        return Err(EnvError::Config(format!("{id} has no fall penalty option")));
    }
    let inner: Box<dyn AnyEnv> = match id {
        "BipedalWalker-v3" | "BipedalWalkerHardcore-v3" => {
            Box::new(BipedalWalker::new(WalkerConfig {
                hardcore: id == "BipedalWalkerHardcore-v3",
                reward: opts.reward,
                fresh_world: opts.fresh_world,
            })?)
        }
        "Pendulum-v1" | "PendulumNoVel-v1" | "CueMemory-v0" | "DelayedCue-v0" => {
            if opts.reward != WalkerReward::Stock {
                return Err(EnvError::Config(format!("{id} has no reward option")));
            }
            match id {
                "CueMemory-v0" => Box::new(CueMemory::new(crate::cue::DEFAULT_DELAY)),
                "DelayedCue-v0" => Box::new(CueMemory::delayed()),
                _ => Box::new(Pendulum::new(id == "PendulumNoVel-v1")),
            }
        }
        _ => return Err(EnvError::UnknownId(id.to_string(), ENV_IDS.join(", "))),
    };
    let limit = opts
        .max_episode_steps
        .or(inner.max_episode_steps())
        .expect("registered envs have a time limit");
    let masked: Box<dyn AnyEnv> = if opts.hide_obs.is_empty() {
        inner
    } else {
        Box::new(ObsMask::hiding(inner, &opts.hide_obs)?)
    };
    let mut env: Box<dyn AnyEnv> = Box::new(TimeLimit::new(masked, limit)?);
    if let Some(p) = opts.fall_penalty {
        env = Box::new(FallPenalty::new(env, p)?);
    }
    if opts.action_repeat != 1 {
        env = Box::new(ActionRepeat::new(env, opts.action_repeat)?);
    }
    if opts.prev_action {
        env = Box::new(PrevAction::new(env));
    }
    if opts.frame_stack != 1 {
        env = Box::new(FrameStack::new(env, opts.frame_stack)?);
    }
    Ok(env)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_and_limits() {
        for id in ENV_IDS {
            let env = make(id).unwrap();
            assert_eq!(env.id(), id);
        }
        assert_eq!(
            make("BipedalWalker-v3").unwrap().max_episode_steps(),
            Some(1600)
        );
        assert_eq!(
            make("BipedalWalkerHardcore-v3")
                .unwrap()
                .max_episode_steps(),
            Some(2000)
        );
        assert_eq!(
            make("PendulumNoVel-v1").unwrap().observation_space().dim(),
            2
        );
        assert!(matches!(make("CartPole-v1"), Err(EnvError::UnknownId(..))));
        let falls = EnvOptions {
            fall_penalty: Some(-1.0),
            ..Default::default()
        };
        assert!(make_with("Pendulum-v1", &falls).is_err());
        let repeat = EnvOptions {
            action_repeat: 4,
            ..falls
        };
        let walker = make_with("BipedalWalkerHardcore-v3", &repeat).unwrap();
        assert_eq!(walker.max_episode_steps(), Some(500));
        let opts = EnvOptions {
            hide_obs: vec![1, 2, 3],
            ..Default::default()
        };
        assert_eq!(
            make_with("BipedalWalker-v3", &opts)
                .unwrap()
                .observation_space()
                .dim(),
            21
        );
    }
}
