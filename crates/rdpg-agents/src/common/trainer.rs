//! The surface every trainer offers, so that a driver (the CLI, tests, bindings) runs any
//! algorithm the same way: [`Trainer`] (run, evaluate, save, load through
//! [`crate::load_trainer`]), the progress callbacks of [`TrainObserver`] and the records they
//! receive.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::common::config::TrainConfig;
use crate::error::Result;

/// What one update reported, in the terms every learner shares.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct UpdateStats {
    /// Critic loss (RDPG: weighted squared TD error, summed over twin critics; PPO: the value
    /// loss).
    pub critic_loss: f64,
    /// Actor loss (RDPG: `-Q(o, mu(o))` averaged over real steps, plus FORK's weighted term
    /// when it was used; PPO: the KL-penalised
    /// surrogate, negated); `None` when this update did not train the actor (TD3's
    /// `policy_delay`).
    pub actor_loss: Option<f64>,
    /// Mean value estimate (RDPG: `Q(o_i, a_i)` of the first critic over the steps its loss
    /// trains, the real ones among each window's first `update_len`; PPO: the mean value
    /// prediction).
    pub q_mean: f64,
    /// Share of the batch's windows drawn from injected (teacher) episodes (0 without
    /// injection and for on-policy learners).
    pub injected_share: f64,
    /// Wall-clock seconds the update took (speed monitoring; the only field that differs
    /// between identical runs).
    pub seconds: f64,
    /// What only some learners report, by name; the logs average each over the updates
    /// that report it. FORK: `model_loss` (its dynamics-model loss on the batch, before its
    /// step) and, on the actor's turns, `fork_share` (1 when the forward-looking term was in
    /// the actor's loss, the dynamics loss being below its threshold, else 0).
    #[serde(default)]
    pub extra: BTreeMap<String, f64>,
}

/// A finished training episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeRecord {
    /// Environment steps taken by the run when the episode ended.
    pub step: u64,
    /// Which environment of the vector env.
    pub env: usize,
    /// Sum of the training reward (with exploration noise).
    pub ret: f64,
    /// Sum of the stock reward (equals `ret` unless training on another reward).
    pub stock_return: f64,
    /// Length in steps.
    pub len: usize,
    /// Reached the end of the course without falling (walkers).
    pub success: bool,
}

/// A deterministic evaluation on held-out seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalRecord {
    /// Environment steps of the run at evaluation time.
    pub step: u64,
    /// Mean stock return.
    pub mean_return: f64,
    /// Standard deviation of the stock return.
    pub std_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
    /// Share of episodes cut by the time limit (`truncated`): neither finished nor fell. The
    /// rest ended otherwise (walkers: a fall or leaving the course).
    #[serde(default)]
    pub time_limit_rate: f64,
    /// Every episode's stock return.
    pub returns: Vec<f64>,
    /// Every episode's length in agent steps (of `train.action_repeat` frames each).
    #[serde(default)]
    pub lengths: Vec<usize>,
    /// Whether each episode reached the end of the course.
    #[serde(default)]
    pub successes: Vec<bool>,
    /// Walker courses: how the episodes fared at each kind of obstacle (`stump`, `stairs`,
    /// `pit`), and `none` for episodes that ended away from any obstacle; empty for other
    /// environments.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub obstacles: BTreeMap<String, ObstacleRecord>,
}

/// How evaluation episodes fared at one kind of obstacle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObstacleRecord {
    /// Obstacles of this kind the hull passed, over all episodes.
    pub passed: u64,
    /// Episodes that ended by a fall at one (the hull over it or just in front of it).
    pub fell: u64,
    /// Episodes cut by the time limit at one (stuck there).
    pub stuck: u64,
}

/// Receives progress from [`Trainer::run`] (metrics files, progress bars, tests).
pub trait TrainObserver {
    /// An episode finished.
    fn on_episode(&mut self, _rec: &EpisodeRecord) {}
    /// An evaluation finished.
    fn on_eval(&mut self, _rec: &EvalRecord) {}
    /// An update was made at environment step `step`.
    fn on_update(&mut self, _step: u64, _stats: &UpdateStats) {}
    /// Called before every vector step; return `true` to stop (e.g. Ctrl-C, to save first).
    fn should_stop(&mut self, _step: u64) -> bool {
        false
    }
}

/// An observer that ignores everything.
pub struct Quiet;
impl TrainObserver for Quiet {}

/// A training run of any algorithm. Build one with [`crate::new_trainer`], resume one with
/// [`crate::load_trainer`].
pub trait Trainer {
    /// Runs until `until` environment steps (capped by the budget) or until the observer asks
    /// to stop. Returns the step count reached. A call may stop anywhere (mid-episode,
    /// mid-rollout) and the next one continues as if it had not.
    fn run(&mut self, until: u64, observer: &mut dyn TrainObserver) -> Result<u64>;

    /// Deterministic evaluation (no exploration) of the current agent on the held-out seeds
    /// `eval_seed..`, on the stock reward, stamped with the current step.
    fn evaluate(&mut self) -> Result<EvalRecord>;

    /// Writes a checkpoint of the whole run to `dir` (agent, optimiser, replay or rollout,
    /// generators, environments, counters); [`crate::load_trainer`] continues it
    /// bit-identically.
    fn save(&mut self, dir: &Path) -> Result<()>;

    /// Writes the agent alone (networks, optimiser) to `dir`: what `checkpoints/best` holds
    /// and what [`crate::load_policy`] reads.
    fn save_agent(&self, dir: &Path) -> Result<()>;

    /// Environment steps taken so far (over all environments).
    fn steps(&self) -> u64;

    /// Updates made so far.
    fn updates(&self) -> u64;

    /// Raises (or lowers) the budget in environment steps, e.g. to continue a finished run.
    fn set_total_steps(&mut self, total: u64);

    /// The trainer as `Any`, for the settings of one algorithm (e.g.
    /// `OffPolicyTrainer::set_parallel_twins` on a resume): `downcast_mut` to the concrete
    /// trainer.
    fn as_any_mut(&mut self) -> &mut dyn std::any::Any;

    /// The run's settings.
    fn config(&self) -> &TrainConfig;
}
