//! The error type of this crate.

use thiserror::Error;

/// Everything that can go wrong when building, updating, saving or loading an agent.
#[derive(Debug, Error)]
pub enum AgentError {
    /// A configuration field holds an invalid value.
    #[error("invalid config field `{field}`: {reason}")]
    Config {
        /// Name of the offending field (as spelled in the JSON config).
        field: &'static str,
        /// Why the value is rejected.
        reason: String,
    },
    /// A batch, observation or state does not have the shape the agent expects.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// An observation (or other input) is not finite.
    #[error("bad input: {0}")]
    Input(String),
    /// The networks hold non-finite values: training diverged.
    #[error(
        "training diverged: {0} (lower the learning rates, or resume from an earlier checkpoint)"
    )]
    Diverged(String),
    /// The requested device cannot be used.
    #[error("device: {0}")]
    Device(String),
    /// An environment failed (bad id, bad options, physics error).
    #[error("environment: {0}")]
    Env(#[from] rdpg_core::EnvError),
    /// A checkpoint is missing, incomplete or inconsistent with the agent.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
    /// An error raised by libtorch.
    #[error("libtorch: {0}")]
    Tch(#[from] tch::TchError),
    /// An I/O error (checkpoint files).
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// A JSON (de)serialisation error (checkpoint metadata).
    #[error("json: {0}")]
    Json(#[from] serde_json::Error),
    /// The caller asked for a stop (Ctrl-C, SIGTERM) before the work was done.
    #[error("stopped before the end")]
    Stopped,
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, AgentError>;
