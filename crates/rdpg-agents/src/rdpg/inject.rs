//! Experience injection (paper Sec. III-D): teacher trajectories recorded to a file, loaded
//! into the replay as injected episodes, and sampled with a share of each batch that is
//! annealed to zero.
//!
//! A teacher file holds whole episodes of any trained agent (RDPG, DDPG, ...) in the
//! student's action space (`[-1, 1]`), with the rewards of the reward they were recorded on
//! and the environment id and observation mask, which a student must match.

use std::path::{Path, PathBuf};

use rdpg_core::replay::Episode;
use rdpg_envs::{EnvOptions, WalkerReward};
use serde::{Deserialize, Serialize};

use crate::common::checkpoint::{read_bin, write_bin};
use crate::common::policy::{episode_seeds, PREALLOCATED_EPISODES};
use crate::common::{to_env_action, DeterministicPolicy, TrainConfig};
use crate::error::{AgentError, Result};

const MAGIC: &str = "rdpg-teacher-v1";

/// Injection settings of a training run (`off_policy.injection`).
///
/// A share `initial_share` of the windows of every batch is drawn from the teacher episodes
/// at the start; the share falls linearly to zero at `anneal_steps` environment steps. The
/// teacher episodes may fill at most `max_fraction` of the replay (oldest injected episodes
/// are dropped beyond it), and as the agent's own episodes come in they are evicted like any
/// other old episode, so injected experience never dominates the buffer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InjectionConfig {
    /// Teacher files written by `rdpg record`.
    pub teachers: Vec<PathBuf>,
    /// Share of each batch's windows drawn from teacher episodes at step 0, in `[0, 1]`.
    pub initial_share: f64,
    /// Environment step at which the share reaches 0 (linear annealing).
    pub anneal_steps: u64,
    /// Largest fraction of the replay capacity teacher episodes may occupy, in `(0, 1]`.
    #[serde(default = "default_max_fraction")]
    pub max_fraction: f64,
}

fn default_max_fraction() -> f64 {
    rdpg_core::replay::DEFAULT_MAX_INJECTED_FRACTION
}

impl InjectionConfig {
    /// Share of teacher windows at environment step `step`:
    /// `initial_share * max(0, 1 - step / anneal_steps)`.
    pub fn share(&self, step: u64) -> f64 {
        if self.anneal_steps == 0 || step >= self.anneal_steps {
            return 0.0;
        }
        self.initial_share * (1.0 - step as f64 / self.anneal_steps as f64)
    }

    /// Checks the fields; errors name `off_policy.injection`.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| {
            Err(AgentError::Config {
                field: "off_policy.injection",
                reason,
            })
        };
        if self.teachers.is_empty() {
            return bad("lists no teacher file".into());
        }
        if !(0.0..=1.0).contains(&self.initial_share) {
            return bad(format!(
                "initial_share {} is not in [0, 1]",
                self.initial_share
            ));
        }
        if !(self.max_fraction > 0.0 && self.max_fraction <= 1.0) {
            return bad(format!(
                "max_fraction {} is not in (0, 1]",
                self.max_fraction
            ));
        }
        Ok(())
    }
}

/// Recorded teacher trajectories.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherFile {
    magic: String,
    /// Environment id.
    pub env: String,
    /// Reward the episodes' rewards are on.
    pub reward: WalkerReward,
    /// Observation components hidden when recording.
    pub hide_obs: Vec<usize>,
    /// Observation size.
    pub obs_dim: usize,
    /// Action size.
    pub act_dim: usize,
    /// Where the teacher came from (free text, e.g. its run directory).
    pub source: String,
    /// The episodes (`injected = true`, no stored states).
    pub episodes: Vec<Episode>,
}

impl TeacherFile {
    /// Writes the file (bincode).
    pub fn save(&self, path: &Path) -> Result<()> {
        write_bin(path, self)
    }

    /// Reads a file written by [`TeacherFile::save`].
    pub fn load(path: &Path) -> Result<Self> {
        let t: TeacherFile = read_bin(path).map_err(|e| match e {
            AgentError::Checkpoint(m) => AgentError::Checkpoint(format!("teacher file {m}")),
            other => other,
        })?;
        if t.magic != MAGIC {
            return Err(AgentError::Checkpoint(format!(
                "{}: not a teacher file ({:?})",
                path.display(),
                t.magic
            )));
        }
        Ok(t)
    }

    /// Checks that the episodes fit a run of `cfg` (same env, observation mask and reward).
    pub fn check_fits(&self, cfg: &TrainConfig, path: &Path) -> Result<()> {
        let mismatch = |what: &str, a: String, b: String| {
            Err(AgentError::Config {
                field: "off_policy.injection",
                reason: format!(
                    "teacher {} was recorded with {what} {a}, the run uses {b}",
                    path.display()
                ),
            })
        };
        plain_env_options(cfg, "off_policy.injection")?;
        if self.env != cfg.env {
            return mismatch("env", self.env.clone(), cfg.env.clone());
        }
        if self.hide_obs != cfg.hide_obs {
            return mismatch(
                "hide_obs",
                format!("{:?}", self.hide_obs),
                format!("{:?}", cfg.hide_obs),
            );
        }
        if self.reward != cfg.reward {
            return mismatch(
                "reward",
                self.reward.as_str().into(),
                cfg.reward.as_str().into(),
            );
        }
        Ok(())
    }
}

/// Teacher files record the env, observation mask and reward only: runs that change the fall
/// penalty, the action repeat or the observation (previous action) cannot record or inject
/// them (yet).
pub(super) fn plain_env_options(cfg: &TrainConfig, field: &'static str) -> Result<()> {
    if cfg.fall_penalty.is_some() || cfg.action_repeat != 1 || cfg.prev_action_obs {
        return Err(AgentError::Config {
            field,
            reason: format!(
                "teacher files do not record a fall penalty, an action repeat or the previous \
                 action in the observation, and this run trains on \"{}\"{}",
                cfg.reward_label(),
                if cfg.prev_action_obs {
                    " with the previous action in the observation"
                } else {
                    ""
                }
            ),
        });
    }
    Ok(())
}

/// Runs `policy` (plus Gaussian action noise of `noise_sigma`, 0 for none) for `episodes`
/// episodes of `cfg`'s environment with the training reward `cfg.reward`, seeds
/// `seed, seed + 1, ...`, and returns them as a teacher file.
pub fn record(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
    noise_sigma: f64,
    source: &str,
) -> Result<TeacherFile> {
    plain_env_options(cfg, "train")?;
    let opts: EnvOptions = cfg.env_options();
    let mut env = rdpg_envs::make_with(&cfg.env, &opts)?;
    let space = env.action_space().clone();
    let obs_dim = env.observation_space().dim();
    let mut rng = rdpg_core::rng::NpRng::from_seed(seed ^ 0x7EAC_4E25);
    let mut out = Vec::with_capacity(episodes.min(PREALLOCATED_EPISODES));
    for ep_seed in episode_seeds(seed, episodes)? {
        let (mut obs, _) = env.reset(Some(ep_seed))?;
        policy.begin_episode();
        let mut ep = Episode {
            obs: obs.clone(),
            actions: Vec::new(),
            rewards: Vec::new(),
            states: Vec::new(),
            terminated: false,
            truncated: false,
            injected: true,
        };
        loop {
            let mut a = policy.act(&obs)?;
            if noise_sigma > 0.0 {
                for x in &mut a {
                    *x = (*x + (noise_sigma * rng.standard_normal()) as f32).clamp(-1.0, 1.0);
                }
            }
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            ep.actions.extend_from_slice(&a);
            ep.rewards.push(s.reward as f32);
            ep.obs.extend_from_slice(&s.obs);
            if s.done() {
                ep.terminated = s.terminated;
                ep.truncated = s.truncated && !s.terminated;
                break;
            }
            obs = s.obs;
        }
        out.push(ep);
    }
    Ok(TeacherFile {
        magic: MAGIC.into(),
        env: cfg.env.clone(),
        reward: cfg.reward,
        hide_obs: cfg.hide_obs.clone(),
        obs_dim,
        act_dim: space.dim(),
        source: source.into(),
        episodes: out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn share_anneals_linearly_to_zero() {
        let c = InjectionConfig {
            teachers: vec!["t".into()],
            initial_share: 0.5,
            anneal_steps: 1000,
            max_fraction: 0.3,
        };
        assert_eq!(c.share(0), 0.5);
        assert_eq!(c.share(500), 0.25);
        assert!((c.share(900) - 0.05).abs() < 1e-12);
        assert_eq!(c.share(1000), 0.0);
        assert_eq!(c.share(5000), 0.0);
        assert!(c.validate().is_ok());
        for bad in [
            InjectionConfig {
                initial_share: 1.5,
                ..c.clone()
            },
            InjectionConfig {
                max_fraction: 0.0,
                ..c.clone()
            },
            InjectionConfig {
                teachers: vec![],
                ..c.clone()
            },
        ] {
            assert!(matches!(
                bad.validate(),
                Err(AgentError::Config {
                    field: "off_policy.injection",
                    ..
                })
            ));
        }
    }
}
