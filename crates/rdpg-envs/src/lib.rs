//! Environments for rdpg.
//!
//! - [`BipedalWalker`]: BipedalWalker-v3 / BipedalWalkerHardcore-v3, bit-identical to
//!   Gymnasium 1.4 (same Box2D, same seeds, same observations and rewards).
//! - [`Pendulum`]: Gymnasium's Pendulum-v1, and its partially observable variant with the
//!   angular velocity hidden (the standard small memory task).
//! - [`wrappers`]: time limit (the only source of `truncated`), observation masks, fall penalty
//!   and action repeat.
//! - [`vector`]: N environments stepped on worker threads with auto-reset.
//! - [`make`]: builds a registered environment by id, with its time limit.

#![warn(missing_docs)]
// No panic reachable from a file or an argument: errors are returned; each remaining invariant
// is allowed where it holds, with its reason.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

pub mod bipedal;
pub mod cue;
pub mod pendulum;
pub mod registry;
pub mod vector;
pub mod wrappers;

pub use bipedal::{BipedalWalker, WalkerConfig, WalkerReward};
pub use cue::CueMemory;
pub use pendulum::Pendulum;
pub use registry::{make, make_with, EnvOptions, ENV_IDS};
pub use vector::VecEnv;
pub use wrappers::{ActionRepeat, FallPenalty, FrameStack, ObsMask, PrevAction, TimeLimit};

/// An environment that can draw its current state as a [`rdpg_render::Scene`].
pub trait Renderable {
    /// The current frame.
    fn scene(&self) -> rdpg_render::Scene;
}
