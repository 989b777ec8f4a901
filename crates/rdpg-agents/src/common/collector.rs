//! The collection plumbing both trainers share: a [`VecEnv`] stepped with actions in the
//! agent's `[-1, 1]` space, one seed per episode from a schedule
//! ([`rdpg_envs::vector::episode_seed`]), the episodes in progress (their env actions and
//! returns), the step counter and the evaluation schedule, and resume by replaying actions.
//!
//! Everything here is deterministic: the environments are seeded by the schedule, so an
//! episode in progress at a checkpoint is rebuilt exactly by resetting its environment with
//! its seed and replaying its actions ([`Collector::restore`]), and the observation reached is
//! checked against the saved one.

use rdpg_envs::vector::VecStep;
use rdpg_envs::{EnvOptions, VecEnv};
use serde::{Deserialize, Serialize};

use crate::common::config::TrainConfig;
use crate::common::policy::to_env_action;
use crate::common::trainer::EpisodeRecord;
use crate::error::{AgentError, Result};

/// An episode in progress.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct OpenEpisode {
    /// Actions as sent to the env (to rebuild the episode on resume).
    env_actions: Vec<Vec<f32>>,
    /// Return on the training reward so far.
    ret: f64,
    /// Return on the stock reward so far.
    stock_ret: f64,
}

/// What a checkpoint keeps of a [`Collector`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CollectorState {
    steps: u64,
    next_eval: u64,
    open: Vec<OpenEpisode>,
    episode_index: Vec<u64>,
    /// The observation each env acts on next (checked against the rebuilt env on resume).
    obs: Vec<Vec<f32>>,
}

/// One environment's transition of a vector step.
#[derive(Debug)]
pub struct Transition {
    /// The environment's step: the next observation (the reset one after an episode end),
    /// reward, `terminated`, `truncated`, the final observation of an ended episode, info.
    pub step: VecStep,
    /// The finished episode, when this step ended one.
    pub finished: Option<EpisodeRecord>,
}

/// N environments stepped together, with their episodes in progress and the run's counters.
pub struct Collector {
    eval_every: u64,
    venv: VecEnv,
    low: Vec<f32>,
    high: Vec<f32>,
    st: CollectorState,
}

impl Collector {
    /// The environments of `cfg`, reset to the first episode of the seed schedule.
    pub fn new(cfg: &TrainConfig) -> Result<Self> {
        let (mut venv, low, high) = make_envs(cfg)?;
        let n = cfg.num_envs;
        let obs = venv.reset_scheduled(cfg.seed, &vec![0; n])?;
        let st = CollectorState {
            steps: 0,
            next_eval: if cfg.eval_every > 0 {
                cfg.eval_every
            } else {
                u64::MAX
            },
            open: vec![OpenEpisode::default(); n],
            episode_index: vec![0; n],
            obs,
        };
        Ok(Self {
            eval_every: cfg.eval_every,
            venv,
            low,
            high,
            st,
        })
    }

    /// Rebuilds the environments of a checkpoint: each is reset with its episode's seed and
    /// its actions are replayed; the observation reached must equal the saved one.
    pub fn restore(cfg: &TrainConfig, st: CollectorState) -> Result<Self> {
        let (mut venv, low, high) = make_envs(cfg)?;
        let n = cfg.num_envs;
        let d = venv.obs_dim();
        if st.open.len() != n
            || st.episode_index.len() != n
            || st.obs.len() != n
            || st.obs.iter().any(|o| o.len() != d)
        {
            return Err(AgentError::Checkpoint(format!(
                "the collector state does not match train.num_envs = {n} or the env's \
                 observation size {d}"
            )));
        }
        venv.reset_scheduled(cfg.seed, &st.episode_index)?;
        for (i, ep) in st.open.iter().enumerate() {
            let o = venv.restore(i, ep.env_actions.clone())?;
            if o != st.obs[i] {
                return Err(AgentError::Checkpoint(format!(
                    "env {i}: rebuilt episode differs from the checkpoint (another \
                     environment build?)"
                )));
            }
        }
        Ok(Self {
            eval_every: cfg.eval_every,
            venv,
            low,
            high,
            st,
        })
    }

    /// The state to checkpoint.
    pub fn state(&self) -> &CollectorState {
        &self.st
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.st.obs.len()
    }

    /// Observation size.
    pub fn obs_dim(&self) -> usize {
        self.venv.obs_dim()
    }

    /// Action size.
    pub fn act_dim(&self) -> usize {
        self.venv.act_dim()
    }

    /// The observation each environment acts on next.
    pub fn obs(&self) -> &[Vec<f32>] {
        &self.st.obs
    }

    /// Environment steps taken so far (over all environments).
    pub fn steps(&self) -> u64 {
        self.st.steps
    }

    /// Steps every environment once with `actions` (one per environment, in the agent's
    /// `[-1, 1]` space; clipped and mapped to the env's bounds), counts the steps and keeps
    /// the episodes in progress. Returns each environment's transition in order.
    pub fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<Transition>> {
        let env_actions: Vec<Vec<f32>> = actions
            .iter()
            .map(|a| to_env_action(a, &self.low, &self.high))
            .collect();
        let steps = self.venv.step(&env_actions)?;
        self.st.steps += steps.len() as u64;
        let mut out = Vec::with_capacity(steps.len());
        for (i, (s, env_action)) in steps.into_iter().zip(env_actions).enumerate() {
            let ep = &mut self.st.open[i];
            ep.env_actions.push(env_action);
            ep.ret += s.reward;
            ep.stock_ret += s.info.stock_reward.unwrap_or(s.reward);
            let finished = s.final_obs.is_some().then(|| {
                let done = std::mem::take(ep);
                EpisodeRecord {
                    step: self.st.steps,
                    env: i,
                    ret: done.ret,
                    stock_return: done.stock_ret,
                    len: done.env_actions.len(),
                    success: s.info.success,
                }
            });
            self.st.obs[i] = s.obs.clone();
            out.push(Transition { step: s, finished });
        }
        self.st.episode_index = self.venv.episode_indices();
        Ok(out)
    }

    /// Whether an evaluation is due at the current step; if so, schedules the next one.
    pub fn eval_due(&mut self) -> bool {
        if self.st.steps < self.st.next_eval {
            return false;
        }
        self.st.next_eval = self.st.next_eval.saturating_add(self.eval_every);
        true
    }
}

/// The vector env of a run and the action bounds of its environments.
fn make_envs(cfg: &TrainConfig) -> Result<(VecEnv, Vec<f32>, Vec<f32>)> {
    let probe = rdpg_envs::make_with(&cfg.env, &cfg.env_options())?;
    let space = probe.action_space();
    // Each training episode depends on its seed and actions alone (a walker builds a new
    // Box2D world at each reset): a checkpoint can then rebuild the episodes in progress.
    let opts = EnvOptions {
        fresh_world: true,
        ..cfg.env_options()
    };
    let venv = VecEnv::make(&cfg.env, &opts, cfg.num_envs, cfg.workers)?;
    Ok((venv, space.low.clone(), space.high.clone()))
}
