//! Errors raised by environments.

use thiserror::Error;

/// What can go wrong when talking to an environment.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum EnvError {
    /// The action does not have as many components as the action space.
    #[error("action has {got} components, the action space has {expected}")]
    ActionLength {
        /// Components the action space expects.
        expected: usize,
        /// Components the caller passed.
        got: usize,
    },
    /// An action component is NaN or infinite.
    #[error("action component {index} is not finite ({value})")]
    NonFiniteAction {
        /// Index of the offending component.
        index: usize,
        /// Its value.
        value: f32,
    },
    /// `step` was called before the first `reset`, or after the episode ended.
    #[error("step called on an environment that needs a reset ({0})")]
    NeedsReset(&'static str),
    /// An environment id that the registry does not know.
    #[error("unknown environment id {0:?} (known: {1})")]
    UnknownId(String, String),
    /// The physics engine rejected an operation (a bug, reported rather than a crash).
    #[error("physics engine error: {0}")]
    Physics(String),
    /// A wrapper or environment was configured with invalid parameters.
    #[error("invalid environment configuration: {0}")]
    Config(String),
}
