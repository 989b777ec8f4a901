//! Core abstractions of rdpg: the [`Env`] trait with Gymnasium semantics, observation and
//! action [`spaces`], the error type shared by environment implementations, the episodic
//! [`replay`] buffer and the [`SequenceBatch`] it samples, exploration [`noise`], the
//! reference critic [`targets`] of the paper, and summary [`stats`].
//!
//! This crate deliberately knows nothing about tensors or physics: it is the vocabulary the
//! environments (`rdpg-envs`) and the learners (`rdpg-agents`) share.

#![warn(missing_docs)]
// No panic reachable from a file or an argument: errors are returned; each remaining invariant
// is allowed where it holds, with its reason.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod batch;
pub mod env;
pub mod error;
pub mod fpmode;
pub mod malloc;
pub mod noise;
pub mod replay;
pub mod rng;
pub mod spaces;
pub mod spin;
pub mod stats;
pub mod targets;

pub use batch::SequenceBatch;
pub use env::{Course, Env, EnvInfo, Obstacle, Step};
pub use error::EnvError;
pub use noise::{
    action_distance, ActionNoise, AdaptiveParamNoise, Gaussian, OrnsteinUhlenbeck, OuConfig,
    ParamNoiseConfig,
};
pub use replay::{Episode, EpisodicReplay, ReplayConfig, ReplayError};
pub use rng::NpRng;
pub use spaces::BoxSpace;
pub use targets::{
    batch_tail_bootstrap_targets, critic_loss_reference, interpolated_td_weights,
    interpolated_td_weights_padded, tail_bootstrap_targets,
};
