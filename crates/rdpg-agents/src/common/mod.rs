//! What every learner and trainer shares: the run config, the [`Trainer`] surface and its
//! observers, the collector, deterministic policies and their evaluation, checkpoint I/O,
//! tensor helpers, Adam and the update's second thread.
//!
//! Nothing here knows a particular algorithm: `rdpg/` and `ppo/` import from here, never the
//! other way round.

pub mod adam;
pub mod checkpoint;
pub mod collector;
pub mod config;
pub mod policy;
pub mod side_thread;
pub mod tensor;
pub mod trainer;

pub use collector::{Collector, CollectorState, Transition};
pub use config::{Algo, TrainConfig};
pub use policy::{
    evaluate_policy, evaluate_policy_traced, to_env_action, DeterministicPolicy, EpisodeTrace,
};
pub use tensor::DeviceSpec;
pub use trainer::{
    EpisodeRecord, EvalRecord, ObstacleRecord, Quiet, TrainObserver, Trainer, UpdateStats,
};
