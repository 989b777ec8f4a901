//! Core abstractions of rdpg: the [`Env`] trait with Gymnasium semantics, observation and
//! action [`spaces`], and the error type shared by environment implementations.
//!
//! This crate deliberately knows nothing about tensors or physics: it is the vocabulary the
//! environments (`rdpg-envs`) and the learners (`rdpg-agents`) share.

pub mod env;
pub mod error;
pub mod rng;
pub mod spaces;

pub use env::{Env, EnvInfo, Step};
pub use error::EnvError;
pub use spaces::BoxSpace;
