//! Actor-critic learners for rdpg on libtorch (through `tch`): the recurrent deterministic
//! policy gradient (RDPG) of Song et al. (ICARCV 2018), its feed-forward DDPG variant, soft
//! actor-critic on the same sequence machinery, and the PPO-KL baseline of the paper's Table I.
//!
//! This is the only crate of the workspace that names the tensor library. One room per
//! concern:
//!
//! * [`common`]: what every algorithm shares: the run config ([`TrainConfig`]), the
//!   [`Trainer`] surface and its observers, the collector (vector env, seed schedule, resume by
//!   replaying actions), deterministic policies and their evaluation, checkpoint I/O, tensor
//!   helpers, Adam.
//! * [`rdpg`]: the RDPG/DDPG agent, Algorithm 1's update (`rdpg/update.rs`), the off-policy
//!   trainer and experience injection.
//! * [`ppo`]: PPO-KL's agent, GAE and on-policy trainer.
//!
//! A driver runs any algorithm through [`new_trainer`] / [`load_trainer`] (a
//! `Box<dyn Trainer>`) and [`load_policy`] (a `Box<dyn DeterministicPolicy>`), with no match
//! on the algorithm of its own.
//!
//! # Linking (for binary crates)
//!
//! tch links libtorch dynamically. A binary depending on this crate needs, in its own
//! `build.rs` (link arguments of a library do not reach dependents):
//!
//! ```text
//! let lib = std::env::var("DEP_RDPG_AGENTS_TORCH_LIBTORCH_LIB").unwrap();
//! println!("cargo:rustc-link-arg=-Wl,-rpath,{lib}");
//! if std::env::var("DEP_RDPG_AGENTS_TORCH_HAS_CUDA").as_deref() == Ok("1") {
//!     println!("cargo:rustc-link-arg=-Wl,--no-as-needed");
//!     println!("cargo:rustc-link-arg=-ltorch_cuda");
//! }
//! ```
//!
//! (`DEP_RDPG_AGENTS_TORCH_*` are exported by this crate's build script through
//! `links = "rdpg_agents_torch"`, to direct dependents only.) Without the `--no-as-needed
//! -ltorch_cuda` pair the linker drops `libtorch_cuda.so` and CUDA is never available.

#![warn(missing_docs)]
// No panic reachable from a file or an argument: errors are returned; each remaining invariant
// is allowed where it holds, with its reason.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod common;
pub mod error;
pub mod ppo;
pub mod rdpg;

use std::path::Path;

pub use common::tensor::{set_flush_denormal, set_num_threads, MAX_THREADS};
pub use common::{
    Algo, DeterministicPolicy, DeviceSpec, EpisodeRecord, EvalRecord, Quiet, TrainConfig,
    TrainObserver, Trainer, UpdateStats,
};
pub use error::{AgentError, Result};
pub use ppo::{PpoConfig, PpoTrainer};
pub use rdpg::{OffPolicyConfig, OffPolicyTrainer, RdpgAgent, RdpgConfig};

use common::checkpoint::{Header, TrainerKind};

/// An algorithm with its own settings: what [`new_trainer`] needs besides the run config.
#[derive(Debug, Clone, PartialEq)]
#[allow(clippy::large_enum_variant)] // built once per run; boxing would only add noise
pub enum Learner {
    /// RDPG (`agent.recurrent = true`), DDPG (`false`) or SAC (`agent.sac`): the off-policy
    /// learner and its loop.
    OffPolicy {
        /// The learner's hyper-parameters.
        agent: RdpgConfig,
        /// The loop's settings (warm-up, replay, exploration, injection).
        off_policy: OffPolicyConfig,
    },
    /// PPO with an adaptive KL penalty.
    Ppo(PpoConfig),
}

/// A fresh training run of `learner` with the run settings `train` (all configs validated).
pub fn new_trainer(train: TrainConfig, learner: Learner) -> Result<Box<dyn Trainer>> {
    Ok(match learner {
        Learner::OffPolicy { agent, off_policy } => {
            Box::new(OffPolicyTrainer::new(train, off_policy, agent)?)
        }
        Learner::Ppo(ppo) => Box::new(PpoTrainer::new(train, ppo)?),
    })
}

/// Resumes the trainer checkpoint in `dir`, whatever its algorithm (read from its
/// `checkpoint.json`). Continuing gives the same result as never having stopped.
pub fn load_trainer(dir: &Path) -> Result<Box<dyn Trainer>> {
    let header = Header::read(dir, None)?;
    // Every checkpoint of this format is sealed: a missing manifest is damage, not age.
    if !dir.join(common::checkpoint::MANIFEST).exists() {
        return Err(AgentError::Checkpoint(format!(
            "{}: no manifest.json (the checkpoint was not finished or has been altered)",
            dir.display()
        )));
    }
    common::checkpoint::verify(dir)?;
    Ok(match header.trainer {
        TrainerKind::OffPolicy => Box::new(OffPolicyTrainer::load(dir)?),
        TrainerKind::Ppo => Box::new(PpoTrainer::load(dir)?),
    })
}

/// Loads the agent saved in `dir` (by [`Trainer::save_agent`], e.g. a run's
/// `checkpoints/best/agent`) as a deterministic policy on the CPU-or-GPU device its config
/// names.
pub fn load_policy(algo: Algo, dir: &Path) -> Result<Box<dyn DeterministicPolicy>> {
    common::checkpoint::verify_agent(dir)?;
    Ok(match algo {
        Algo::Rdpg | Algo::Ddpg | Algo::Sac => {
            Box::new(rdpg::RdpgPolicy::new(RdpgAgent::load_weights(dir)?))
        }
        Algo::Ppo => Box::new(ppo::PpoAgent::load_weights(dir)?),
    })
}

/// Whether libtorch reports a usable CUDA device.
pub fn cuda_available() -> bool {
    tch::Cuda::is_available()
}

#[cfg(test)]
mod tests {
    #[test]
    fn links_and_runs() {
        let t = tch::Tensor::from_slice(&[1.0f32, 2.0]).sum(tch::Kind::Float);
        assert_eq!(t.double_value(&[]), 3.0);
        eprintln!("cuda available: {}", super::cuda_available());
    }
}
