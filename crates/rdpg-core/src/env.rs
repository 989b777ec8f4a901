//! The environment trait, with Gymnasium's semantics.
//!
//! `terminated` (the MDP reached a terminal state: no bootstrap) and `truncated` (the episode
//! was cut, typically by a time limit: bootstrap from the next observation) are kept apart from
//! the environment all the way to the loss.

use crate::{BoxSpace, EnvError, NpRng};

/// Extra information returned by `reset` and `step`, like Gymnasium's `info` dict, restricted
/// to what rdpg's tools use.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EnvInfo {
    /// For walkers: the hull reached the end of the course without falling on this step.
    pub success: bool,
    /// The reward the stock Gymnasium environment would have given for this step, when the
    /// environment was configured with a different reward (e.g. the paper's).
    pub stock_reward: Option<f64>,
    /// For walkers: where the hull is on its course, reported with every step (the last
    /// step's tells where an episode ended).
    pub course: Option<Course>,
}

/// The kinds of obstacle on a walker's course (BipedalWalkerHardcore-v3's terrain generator).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Obstacle {
    /// A square stump, 1 or 2 terrain steps high.
    Stump = 0,
    /// A staircase of 3 or 4 steps, up or down.
    Stairs = 1,
    /// A pit between two walls.
    Pit = 2,
}

impl Obstacle {
    /// Every kind, in the order of [`Course::passed`] (`kind as usize` is its index).
    pub const ALL: [Obstacle; 3] = [Obstacle::Stump, Obstacle::Stairs, Obstacle::Pit];

    /// Lower-case name: `stump`, `stairs` or `pit`.
    pub fn as_str(self) -> &'static str {
        match self {
            Obstacle::Stump => "stump",
            Obstacle::Stairs => "stairs",
            Obstacle::Pit => "pit",
        }
    }
}

/// A walker's place on its course.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Course {
    /// Obstacles whose far end the hull has passed, per kind in [`Obstacle::ALL`]'s order.
    pub passed: [u32; 3],
    /// The obstacle the hull is over or close in front of, if any: where an episode that ends
    /// on this step ended.
    pub at: Option<Obstacle>,
}

/// The result of one [`Env::step`].
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Observation after the action.
    pub obs: Vec<f32>,
    /// Reward for the transition.
    pub reward: f64,
    /// The episode reached a terminal state of the MDP (no bootstrap past it).
    pub terminated: bool,
    /// The episode was cut short (time limit): the next state still has a value.
    pub truncated: bool,
    /// Extra information.
    pub info: EnvInfo,
}

impl Step {
    /// `terminated || truncated`: the episode is over and the env must be reset.
    pub fn done(&self) -> bool {
        self.terminated || self.truncated
    }
}

/// An episodic environment with continuous observations and actions.
pub trait Env: Send {
    /// Gymnasium-style identifier, e.g. `BipedalWalker-v3`.
    fn id(&self) -> &str;
    /// The observation space.
    fn observation_space(&self) -> &BoxSpace;
    /// The action space.
    fn action_space(&self) -> &BoxSpace;
    /// Starts a new episode. With `Some(seed)` the environment's random generator is re-seeded
    /// (as Gymnasium's `reset(seed=...)`); with `None` it continues its current stream.
    fn reset(&mut self, seed: Option<u64>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        self.reset_with(seed.map(NpRng::from_seed))
    }
    /// [`Env::reset`] with the environment's new random generator given (e.g.
    /// [`NpRng::from_seed_words`] for a seed past `u64`); `None` continues the current stream.
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError>;
    /// Advances one step with `action`.
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError>;
    /// Maximum episode length when the environment is wrapped in its registered time limit.
    fn max_episode_steps(&self) -> Option<usize> {
        None
    }
}

impl<E: Env + ?Sized> Env for Box<E> {
    fn id(&self) -> &str {
        (**self).id()
    }
    fn observation_space(&self) -> &BoxSpace {
        (**self).observation_space()
    }
    fn action_space(&self) -> &BoxSpace {
        (**self).action_space()
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        (**self).reset_with(rng)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        (**self).step(action)
    }
    fn max_episode_steps(&self) -> Option<usize> {
        (**self).max_episode_steps()
    }
}

/// Checks an action against a space's length and for finiteness: the shared validation every
/// environment runs before touching its dynamics.
pub fn validate_action(space: &BoxSpace, action: &[f32]) -> Result<(), EnvError> {
    if action.len() != space.dim() {
        return Err(EnvError::ActionLength {
            expected: space.dim(),
            got: action.len(),
        });
    }
    if let Some((index, &value)) = action.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(EnvError::NonFiniteAction { index, value });
    }
    Ok(())
}
