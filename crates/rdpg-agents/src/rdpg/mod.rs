//! The recurrent deterministic policy gradient (RDPG) of Song et al. (ICARCV 2018), its
//! feed-forward DDPG variant (the same agent with `recurrent = false`) and soft actor-critic
//! on the same machinery (`config.sac`, recurrent or not).
//!
//! * [`config`]: the learner's hyper-parameters ([`RdpgConfig`]);
//!   [`off_policy`]: the loop's ([`OffPolicyConfig`]: warm-up, replay, noise, injection).
//! * [`lstm`]: the recurrent core and the no-gradient scan it drives; [`nets`]: trunks, actor
//!   and critic.
//! * [`agent`]: [`RdpgAgent`], acting with the trained actor or its exploring copy.
//! * [`update`]: Algorithm 1's `Update()`, top to bottom (its two-thread schedule in
//!   `twins.rs`, the batch it reads in `prepared.rs`); [`profile`]: its per-phase times;
//!   [`fork`]: FORK's models and forward-looking actor term (feed-forward agents);
//!   `sac.rs`: soft actor-critic's update, top to bottom (`tqc.rs`: its truncated quantile
//!   critics);
//!   [`checkpoint`]: save and load.
//! * [`trainer`]: [`OffPolicyTrainer`], Algorithm 1's outer loop; [`inject`]: experience
//!   injection from teacher files.
//! * [`staleness`], [`bias`] and [`preference`]: diagnostics of a trained agent (the
//!   recurrent states its updates start from; its critics' estimation bias; which actions its
//!   critics prefer, its actor's or another policy's).
//! * [`bench`](mod@bench): synthetic batches and the update benchmark; [`flops`]: the
//!   update's counted FLOP and a matrix-product reference at its layer shapes.

mod acting;
pub mod agent;
pub mod bench;
pub mod bias;
pub mod checkpoint;
pub mod config;
pub mod flops;
pub mod fork;
pub mod inject;
pub mod lstm;
pub mod nets;
pub mod off_policy;
mod options;
pub mod preference;
mod prepared;
pub mod profile;
mod sac;
mod sac_config;
pub mod staleness;
mod tqc;
pub mod trainer;
mod twins;
pub mod update;

pub use agent::{ActorState, RdpgAgent};
pub use bias::{estimation_bias, CriticBias, EpisodeBias, EstimationBias};
pub use config::{
    memory_task_config, ActorWeights, CriticTarget, ForkConfig, RdpgConfig, SacConfig, ScanMethod,
    TargetNoise, TqcConfig, Trunk,
};
pub use off_policy::{ExplorationConfig, OffPolicyConfig, ParamNoiseSpec, PerturbSchedule};
pub use preference::{critic_preference, CriticPreference, PreferenceLine};
pub use profile::PhaseTimes;
pub use staleness::{state_staleness, Staleness, StartGap};
pub use trainer::{OffPolicyTrainer, RdpgPolicy};

#[cfg(test)]
mod tests;
