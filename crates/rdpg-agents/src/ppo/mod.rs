//! Proximal policy optimisation with an adaptive KL penalty: the PPO baseline of the paper's
//! Table I ("PPO with an adaptive KL penalty, feed-forward, GAE").
//!
//! * [`config`]: [`PpoConfig`]; [`gae`](mod@gae): GAE and the β rule as pure functions.
//! * [`agent`]: [`PpoAgent`], the Gaussian policy, value function and the update phase.
//! * [`trainer`]: [`PpoTrainer`], the on-policy loop on the shared collector.

pub mod agent;
pub mod config;
pub mod gae;
pub mod trainer;

pub use agent::{PpoAgent, PpoBatch, PpoStats};
pub use config::PpoConfig;
pub use gae::{adapt_kl_coef, gae};
pub use trainer::PpoTrainer;
