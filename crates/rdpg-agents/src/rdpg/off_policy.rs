//! The settings of the off-policy loop (the `[off_policy]` section of an experiment file):
//! warm-up, update rate, replay, exploration (action and parameter noise) and experience
//! injection. The run itself (environment, budget, evaluation, seeds) is the shared
//! [`TrainConfig`](crate::TrainConfig).

use crate::common::config::is_f32;
use rdpg_core::noise::ParamNoiseConfig;
use serde::{Deserialize, Serialize};

use super::inject::InjectionConfig;
use crate::error::{AgentError, Result};

/// Exploration noise added to the deterministic policy's actions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ExplorationConfig {
    /// No noise.
    None,
    /// Ornstein–Uhlenbeck noise, reset at every episode start.
    Ou {
        /// Mean-reversion rate θ.
        theta: f64,
        /// Scale σ.
        sigma: f64,
    },
    /// Independent Gaussian noise of standard deviation `sigma`.
    Gaussian {
        /// Standard deviation.
        sigma: f64,
    },
}

impl Default for ExplorationConfig {
    fn default() -> Self {
        Self::Ou {
            theta: 0.15,
            sigma: 0.2,
        }
    }
}

/// When the exploring copy of the actor is re-perturbed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum PerturbSchedule {
    /// At the start of every episode (of any environment): Algorithm 1's `Noise()` per
    /// episode, and what Plappert et al. do.
    Episode,
    /// Every this many environment steps (over all environments).
    Steps(u64),
}

/// Adaptive parameter-space noise on the actor (paper Sec. II-B and Algorithm 1's `Noise()` /
/// `Denoise()`; Plappert et al. 2018), on top of the action noise.
///
/// The environments act with a copy of the trained actor whose every parameter got
/// `N(0, σ²)` noise, re-drawn on the `perturb` schedule; updates always train the unperturbed
/// actor (the "denoise before Update()" of Algorithm 1), and evaluations use it too. Every
/// `adapt_every_updates` updates, σ adapts as in Plappert et al.: a *fresh* perturbation of
/// the *current* actor with the current σ is compared with the actor on observations sampled
/// from the replay (zero recurrent state), and σ is multiplied by `adoption_coefficient` when
/// the RMS action distance is below `desired_action_stddev`, divided by it otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamNoiseSpec {
    /// Initial σ of the parameter perturbation.
    pub initial_stddev: f64,
    /// Target RMS distance between perturbed and unperturbed actions (in `[-1, 1]` units).
    pub desired_action_stddev: f64,
    /// Multiplicative step of σ's adaptation (`> 1`).
    pub adoption_coefficient: f64,
    /// Updates between two adaptations of σ (Plappert et al.: 50).
    pub adapt_every_updates: u64,
    /// When the acting copy is re-perturbed.
    pub perturb: PerturbSchedule,
}

impl Default for ParamNoiseSpec {
    fn default() -> Self {
        let c = ParamNoiseConfig::default();
        Self {
            initial_stddev: c.initial_stddev,
            desired_action_stddev: c.desired_action_stddev,
            adoption_coefficient: c.adoption_coefficient,
            adapt_every_updates: 50,
            perturb: PerturbSchedule::Episode,
        }
    }
}

/// The most gradient updates per environment step a run may ask for (REDQ-style agents use
/// 20; more is a typo or a file that would keep a run busy for ever).
pub const MAX_UPDATES_PER_STEP: f64 = 1000.0;

/// The off-policy loop's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OffPolicyConfig {
    /// Steps of uniform random actions before the first update.
    pub warmup_steps: u64,
    /// Gradient updates per environment step (fractional values accumulate).
    pub updates_per_step: f64,
    /// Replay capacity in transitions (whole episodes are evicted oldest first).
    pub replay_capacity: usize,
    /// Exploration noise on the actions.
    pub exploration: ExplorationConfig,
    /// Parameter-space noise on the actor, in addition to `exploration`; none when absent.
    pub param_noise: Option<ParamNoiseSpec>,
    /// Experience injection from teacher files (paper Sec. III-D); none when absent.
    pub injection: Option<InjectionConfig>,
}

impl Default for OffPolicyConfig {
    fn default() -> Self {
        Self {
            warmup_steps: 2_000,
            updates_per_step: 1.0,
            replay_capacity: 100_000,
            exploration: ExplorationConfig::default(),
            param_noise: None,
            injection: None,
        }
    }
}

impl OffPolicyConfig {
    /// Checks every field; the error names the offending one (`off_policy.<field>`).
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(AgentError::Config { field, reason });
        if !(0.0..=MAX_UPDATES_PER_STEP).contains(&self.updates_per_step) {
            return bad(
                "off_policy.updates_per_step",
                format!(
                    "{} is not a number from 0 to {MAX_UPDATES_PER_STEP}",
                    self.updates_per_step
                ),
            );
        }
        if self.replay_capacity == 0 {
            return bad("off_policy.replay_capacity", "must be positive".into());
        }
        if let Some(inj) = &self.injection {
            inj.validate()?;
        }
        if let Some(p) = &self.param_noise {
            let ok = is_f32(p.initial_stddev)
                && p.initial_stddev > 0.0
                && is_f32(p.desired_action_stddev)
                && p.desired_action_stddev > 0.0
                && is_f32(p.adoption_coefficient)
                && p.adoption_coefficient > 1.0
                && p.adapt_every_updates > 0
                && p.perturb != PerturbSchedule::Steps(0);
            if !ok {
                return bad(
                    "off_policy.param_noise",
                    format!(
                        "needs initial_stddev > 0, desired_action_stddev > 0, \
                         adoption_coefficient > 1, adapt_every_updates > 0 and a positive \
                         perturb.steps (got {p:?})"
                    ),
                );
            }
        }
        match self.exploration {
            ExplorationConfig::Ou { theta, sigma }
                if !(is_f32(theta) && is_f32(sigma) && theta > 0.0 && sigma >= 0.0) =>
            {
                bad(
                    "off_policy.exploration",
                    format!("OU needs finite theta > 0 and sigma >= 0 (got {theta}, {sigma})"),
                )
            }
            ExplorationConfig::Gaussian { sigma } if !(is_f32(sigma) && sigma >= 0.0) => bad(
                "off_policy.exploration",
                format!("Gaussian needs a finite sigma >= 0 (got {sigma})"),
            ),
            _ => Ok(()),
        }
    }
}
