//! Checkpoints of an [`RdpgAgent`]: `agent.json` (format, config, sizes, seed, update count,
//! the agent's generator), `weights.safetensors` (networks, target networks prefixed
//! `target.`; FORK's models; SAC's `log_alpha`) and `optim.safetensors` (Adam moments). Loading continues bit-identically.

use std::path::Path;

use rdpg_core::rng::NpRng;
use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor};

use super::agent::RdpgAgent;
use super::config::RdpgConfig;
use crate::common::checkpoint::{
    check_sizes_against, ckpt_err, read_json, read_tensors, restore_vars, write_json,
    write_tensors, SEALED_AGENT_FORMAT,
};
use crate::common::tensor::{sorted_vars, DeviceSpec};
use crate::error::Result;

/// Metadata written next to the weights by [`RdpgAgent::save`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CheckpointMeta {
    format: u32,
    config: RdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    seed: u64,
    double: bool,
    updates: u64,
    rng: NpRng,
    /// FORK's observation bounds (agents with `config.fork`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fork_bounds: Option<(f64, f64)>,
}

/// The format written: [`SEALED_AGENT_FORMAT`] (format 1 agents load too).
const CHECKPOINT_FORMAT: u32 = SEALED_AGENT_FORMAT;

impl RdpgAgent {
    /// Writes networks (target networks included), optimiser moments, the update count and the
    /// agent's generator to `dir` (`agent.json`, `weights.safetensors`, `optim.safetensors`).
    /// [`RdpgAgent::load`] then continues bit-identically.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| ckpt_err(dir, e))?;
        let mut weights: Vec<(String, Tensor)> = Vec::new();
        for vs in std::iter::once(&self.actor_vs).chain(&self.critic_vs) {
            weights.extend(sorted_vars(vs));
        }
        if let Some(t) = &self.targets {
            for vs in t.actor.iter().map(|(vs, _)| vs).chain(&t.critic_vs) {
                weights.extend(
                    sorted_vars(vs)
                        .into_iter()
                        .map(|(n, t)| (format!("target.{n}"), t)),
                );
            }
        }
        if let Some(f) = &self.fork {
            weights.extend(f.vars());
        }
        if let Some(t) = &self.sac {
            weights.extend(sorted_vars(&t.vs));
        }
        write_tensors(&dir.join("weights.safetensors"), &weights)?;
        let mut optim = self.actor_opt.state("actor_opt.");
        optim.extend(self.critic_opt.state("critic_opt."));
        if let Some(f) = &self.fork {
            optim.extend(f.dynamics_opt.state("fork_dynamics_opt."));
            optim.extend(f.reward_opt.state("fork_reward_opt."));
        }
        if let Some(t) = &self.sac {
            optim.extend(t.opt.state("alpha_opt."));
        }
        write_tensors(&dir.join("optim.safetensors"), &optim)?;
        let meta = CheckpointMeta {
            format: CHECKPOINT_FORMAT,
            config: self.cfg.clone(),
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            seed: self.seed,
            double: self.kind == Kind::Double,
            updates: self.updates,
            rng: self.rng.clone(),
            fork_bounds: self.fork.as_ref().map(|f| f.bounds),
        };
        write_json(&dir.join("agent.json"), &meta)?;
        crate::common::checkpoint::seal(dir)
    }

    /// Restores an agent written by [`RdpgAgent::save`], on the device its config names.
    /// Missing, truncated or inconsistent files give an
    /// [`AgentError::Checkpoint`](crate::AgentError::Checkpoint) naming the file.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_with(dir, None)
    }

    /// Like [`RdpgAgent::load`], overriding the device (e.g. resume a GPU run on the CPU).
    pub fn load_with(dir: impl AsRef<Path>, device: Option<DeviceSpec>) -> Result<Self> {
        Self::load_impl(dir.as_ref(), device, true)
    }

    /// The networks of an agent written by [`RdpgAgent::save`], without its optimiser state
    /// (a shipped agent, e.g. a zoo entry, holds none): for acting or evaluating; training it
    /// further starts with fresh Adam moments.
    pub fn load_weights(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_impl(dir.as_ref(), None, false)
    }

    fn load_impl(dir: &Path, device: Option<DeviceSpec>, with_optim: bool) -> Result<Self> {
        let meta_path = dir.join("agent.json");
        let meta: CheckpointMeta = read_json(&meta_path)?;
        if !(1..=CHECKPOINT_FORMAT).contains(&meta.format) {
            return Err(ckpt_err(
                &meta_path,
                format!(
                    "agent format {}, this build reads format {CHECKPOINT_FORMAT}",
                    meta.format
                ),
            ));
        }
        crate::common::checkpoint::check_counter(&meta_path, "updates", meta.updates)?;
        let mut cfg = meta.config;
        if let Some(d) = device {
            cfg.device = d;
        }
        let kind = if meta.double {
            Kind::Double
        } else {
            Kind::Float
        };
        let weights_path = dir.join("weights.safetensors");
        check_sizes_against(
            &weights_path,
            &meta_path,
            cfg.param_count(meta.obs_dim, meta.act_dim),
        )?;
        let mut agent = Self::new_with_kind(cfg, meta.obs_dim, meta.act_dim, meta.seed, kind)?;
        let weights = read_tensors(&weights_path)?;
        let nets = std::iter::once(&agent.actor_vs).chain(&agent.critic_vs);
        for vs in nets {
            restore_vars(vs, &weights, "")?;
        }
        if let Some(t) = &agent.targets {
            for vs in t.actor.iter().map(|(vs, _)| vs).chain(&t.critic_vs) {
                restore_vars(vs, &weights, "target.")?;
            }
        }
        if let Some(f) = &mut agent.fork {
            restore_vars(&f.dynamics_vs, &weights, "")?;
            restore_vars(&f.reward_vs, &weights, "")?;
            f.bounds = meta
                .fork_bounds
                .ok_or_else(|| ckpt_err(&meta_path, "a FORK agent without its fork_bounds"))?;
        }
        if let Some(t) = &agent.sac {
            restore_vars(&t.vs, &weights, "")?;
        }
        if with_optim {
            let optim = read_tensors(&dir.join("optim.safetensors"))?;
            agent.actor_opt.load_state("actor_opt.", &optim)?;
            agent.critic_opt.load_state("critic_opt.", &optim)?;
            if let Some(f) = &mut agent.fork {
                f.dynamics_opt.load_state("fork_dynamics_opt.", &optim)?;
                f.reward_opt.load_state("fork_reward_opt.", &optim)?;
            }
            if let Some(t) = &mut agent.sac {
                t.opt.load_state("alpha_opt.", &optim)?;
            }
        }
        agent.updates = meta.updates;
        agent.rng = meta.rng;
        Ok(agent)
    }
}
