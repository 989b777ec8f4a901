//! The settings of a training run that every algorithm shares: environment, reward, budget,
//! parallel environments, evaluation and seeds ([`TrainConfig`], the `[train]` section of an
//! experiment file), and the algorithm names ([`Algo`]).

use rdpg_envs::{EnvOptions, WalkerReward};
use serde::{Deserialize, Serialize};

use crate::error::{AgentError, Result};

/// The learning algorithms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Algo {
    /// Recurrent deterministic policy gradient (the off-policy learner, LSTM cores).
    Rdpg,
    /// DDPG: the same off-policy learner with feed-forward networks.
    Ddpg,
    /// PPO with an adaptive KL penalty (feed-forward, GAE).
    Ppo,
    /// Soft actor-critic on the off-policy learner (recurrent or feed-forward).
    Sac,
}

impl Algo {
    /// The name used in experiment files, summaries and tables (`rdpg`, `ddpg`, `ppo`, `sac`).
    pub fn as_str(self) -> &'static str {
        match self {
            Algo::Rdpg => "rdpg",
            Algo::Ddpg => "ddpg",
            Algo::Ppo => "ppo",
            Algo::Sac => "sac",
        }
    }
}

/// Everything about a training run that does not depend on the algorithm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Environment id (see `rdpg_envs::ENV_IDS`).
    pub env: String,
    /// Observation components hidden from the agent (indices into the env's observation).
    pub hide_obs: Vec<usize>,
    /// Walkers: reward used for learning (`stock` or `paper`); evaluation always reports the
    /// stock return.
    pub reward: WalkerReward,
    /// Walkers: the training reward of a fall becomes this (stock −100, paper −20), as public
    /// Hardcore solutions train (e.g. −10 or 0). Evaluation pays the stock reward. `None`: the
    /// reward's own.
    pub fall_penalty: Option<f64>,
    /// Each agent action is held for this many frames, rewards summed (frame skip; public
    /// Hardcore solutions use 3). It changes the time scale, so evaluation, rendering and
    /// recording use it too (the policy acts at that rate); the time limit still counts frames,
    /// and the step counts (budget, `eval_every`, replay) count agent steps. 1: none.
    pub action_repeat: usize,
    /// The agent's previous action in front of each observation, `[a_{t-1}, o_t]` (zeros after
    /// a reset): the input recurrent off-policy agents commonly read next to the observation
    /// (R2D2; Ni et al. 2022). Part of the agent's view, so evaluation, rendering and
    /// recording use it too; the Python `Policy` adds it itself.
    pub prev_action_obs: bool,
    /// The agent sees its last this many views side by side, oldest first, zeros before the
    /// episode's first (a frame stack, as Stable-Baselines3's `VecFrameStack`): memory for a
    /// feed-forward agent, the control for what a recurrent one remembers. Part of the agent's
    /// view, like `prev_action_obs` (each view with its previous action in front). 1: none.
    pub frame_stack: usize,
    /// Budget in environment steps (over all environments).
    pub total_steps: u64,
    /// Environments acting in parallel.
    pub num_envs: usize,
    /// Worker threads stepping them.
    pub workers: usize,
    /// Evaluate every this many environment steps (0: only at the end).
    pub eval_every: u64,
    /// Deterministic evaluation episodes.
    pub eval_episodes: usize,
    /// First seed of the validation episodes (episode k uses `eval_seed + k`): the periodic
    /// evaluations during training, which choose the best agent. Never used for the reported
    /// test score.
    pub eval_seed: u64,
    /// First seed of the test episodes (`test_seed + k`), disjoint from the validation ones:
    /// the final evaluation of the chosen agent and `rdpg eval`'s default.
    pub test_seed: u64,
    /// Episodes of the final test evaluation; 0: no final test, the test seeds stay unopened
    /// (a tuning run, chosen on validation only).
    pub test_episodes: usize,
    /// Master seed of the run.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            env: "PendulumNoVel-v1".into(),
            hide_obs: Vec::new(),
            reward: WalkerReward::Stock,
            fall_penalty: None,
            action_repeat: 1,
            prev_action_obs: false,
            frame_stack: 1,
            total_steps: 50_000,
            num_envs: 1,
            workers: 1,
            eval_every: 5_000,
            eval_episodes: 10,
            eval_seed: 1_000_000,
            test_seed: 3_000_000,
            test_episodes: 100,
            seed: 0,
        }
    }
}

/// Whether a setting is a finite number that also fits the networks' `f32` tensors (a value
/// past `f32::MAX` would become infinite, or be refused by libtorch, inside an update).
pub fn is_f32(v: f64) -> bool {
    v.is_finite() && v.abs() <= f64::from(f32::MAX)
}

impl TrainConfig {
    /// Checks every field; the error names the offending one (`train.<field>`).
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(AgentError::Config { field, reason });
        if !rdpg_envs::ENV_IDS.contains(&self.env.as_str()) {
            return bad(
                "train.env",
                format!(
                    "unknown id {:?} (known: {})",
                    self.env,
                    rdpg_envs::ENV_IDS.join(", ")
                ),
            );
        }
        let walker = self.env.starts_with("BipedalWalker");
        if let Some(p) = self.fall_penalty {
            if !walker {
                return bad("train.fall_penalty", format!("{} has no falls", self.env));
            }
            if !p.is_finite() {
                return bad("train.fall_penalty", format!("must be finite, got {p}"));
            }
        }
        // Sizes within what a run can do: a file asking for more is refused, not obeyed.
        let within = |field: &'static str, v: usize, max: usize| {
            if (1..=max).contains(&v) {
                Ok(())
            } else {
                bad(field, format!("{v} is not from 1 to {max}"))
            }
        };
        within("train.action_repeat", self.action_repeat, 1000)?;
        within("train.frame_stack", self.frame_stack, 64)?;
        if self.total_steps == 0 {
            return bad("train.total_steps", "must be positive".into());
        }
        within("train.num_envs", self.num_envs, 4096)?;
        within(
            "train.workers",
            self.workers,
            crate::common::tensor::MAX_THREADS,
        )?;
        within("train.eval_episodes", self.eval_episodes, 1_000_000)?;
        if self.test_episodes > 1_000_000 {
            return bad(
                "train.test_episodes",
                format!("{} is not from 0 to 1000000", self.test_episodes),
            );
        }
        let overlap = |a: u64, n: usize, b: u64, m: usize| {
            a < b.saturating_add(m as u64) && b < a.saturating_add(n as u64)
        };
        if overlap(
            self.eval_seed,
            self.eval_episodes,
            self.test_seed,
            self.test_episodes,
        ) {
            return bad(
                "train.test_seed",
                format!(
                    "the test seeds {}..{} overlap the validation seeds {}..{}",
                    self.test_seed,
                    self.test_seed.saturating_add(self.test_episodes as u64),
                    self.eval_seed,
                    self.eval_seed.saturating_add(self.eval_episodes as u64)
                ),
            );
        }
        Ok(())
    }

    /// The environment options of the run (reward, observation mask), as Gymnasium's env
    /// behaves: evaluation, rendering and recording use them. The training environments add
    /// `fresh_world` (see the collector).
    pub fn env_options(&self) -> EnvOptions {
        EnvOptions {
            reward: self.reward,
            hide_obs: self.hide_obs.clone(),
            max_episode_steps: None,
            fresh_world: false,
            fall_penalty: self.fall_penalty,
            action_repeat: self.action_repeat,
            prev_action: self.prev_action_obs,
            frame_stack: self.frame_stack,
        }
    }

    /// The options of evaluation, rendering and recording: the stock reward, with the run's
    /// observation mask, previous-action input, frame stack and action repeat (the agent's view
    /// and time scale).
    pub fn eval_env_options(&self) -> EnvOptions {
        EnvOptions {
            reward: WalkerReward::Stock,
            fall_penalty: None,
            ..self.env_options()
        }
    }

    /// The training reward in words, naming every change from the stock environment that
    /// shows in a return: `stock`, `paper`, `stock, fall -10, action repeat 3`.
    pub fn reward_label(&self) -> String {
        let mut label = self.reward.as_str().to_string();
        if let Some(p) = self.fall_penalty {
            label += &format!(", fall {p}");
        }
        label + &self.repeat_label()
    }

    /// The evaluation reward in words: `stock`, or `stock, action repeat 3`.
    pub fn eval_reward_label(&self) -> String {
        format!("stock{}", self.repeat_label())
    }

    fn repeat_label(&self) -> String {
        match self.action_repeat {
            1 => String::new(),
            k => format!(", action repeat {k}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_name_every_change_that_shows_in_a_return() {
        let mut c = TrainConfig {
            env: "BipedalWalkerHardcore-v3".into(),
            ..Default::default()
        };
        assert_eq!(
            (c.reward_label(), c.eval_reward_label()),
            ("stock".into(), "stock".into())
        );
        c.reward = WalkerReward::Paper;
        c.fall_penalty = Some(-10.0);
        c.action_repeat = 3;
        c.validate().unwrap();
        assert_eq!(c.reward_label(), "paper, fall -10, action repeat 3");
        assert_eq!(c.eval_reward_label(), "stock, action repeat 3");
        // Evaluation keeps the agent's time scale and view, not its reward.
        let e = c.eval_env_options();
        assert_eq!(
            (e.reward, e.fall_penalty, e.action_repeat),
            (WalkerReward::Stock, None, 3)
        );
        let field = |c: &TrainConfig| match c.validate() {
            Err(AgentError::Config { field, .. }) => field,
            other => panic!("accepted: {other:?}"),
        };
        assert_eq!(
            field(&TrainConfig {
                fall_penalty: Some(f64::NAN),
                ..c.clone()
            }),
            "train.fall_penalty"
        );
        assert_eq!(
            field(&TrainConfig {
                frame_stack: 0,
                ..c.clone()
            }),
            "train.frame_stack"
        );
        let stacked = TrainConfig {
            frame_stack: 4,
            ..c.clone()
        };
        stacked.validate().unwrap();
        assert_eq!(stacked.eval_env_options().frame_stack, 4);
        assert_eq!(
            field(&TrainConfig {
                action_repeat: 0,
                ..c.clone()
            }),
            "train.action_repeat"
        );
        let pendulum = TrainConfig {
            fall_penalty: Some(0.0),
            ..Default::default()
        };
        assert_eq!(field(&pendulum), "train.fall_penalty");
    }
}
