//! Soft actor-critic's settings (`[agent.sac]`): the temperature and TQC's critics. Checked
//! with the rest of the learner's config in `RdpgConfig::validate` (`config.rs`).

use serde::{Deserialize, Serialize};

/// Soft actor-critic (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"):
/// the actor is a squashed Gaussian `a = tanh(u)`, `u ~ N(m(o), s(o)^2)`, whose output layer
/// gives the mean and the log standard deviation (clamped to [`LOG_STD_RANGE`]); the targets and
/// the actor loss carry the entropy bonus `-alpha log pi(a | o)`, and the temperature `alpha`
/// is learned towards a target entropy or held fixed (see `sac.rs`). Acting samples the policy
/// (no action noise); evaluation and a shipped policy act with the mean, `tanh(m(o))`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SacConfig {
    /// The temperature `alpha` at the start (> 0). Stable-Baselines3: 1.0.
    pub init_alpha: f64,
    /// Learn `alpha` (its logarithm, by Adam at `lr_alpha`) so that the policy's entropy
    /// tracks `target_entropy`; `false` keeps `init_alpha`.
    pub learn_alpha: bool,
    /// The entropy the temperature steers towards; `None`: `-act_dim` (Haarnoja et al.).
    pub target_entropy: Option<f64>,
    /// Adam learning rate of `log alpha`. Stable-Baselines3: the actor's (3e-4).
    pub lr_alpha: f64,
    /// Truncated quantile critics (TQC) instead of the min over twin critics; `None`: SAC's.
    pub tqc: Option<TqcConfig>,
}

/// TQC's critics (Kuznetsov et al. 2020, "Controlling Overestimation Bias with Truncated
/// Mixture of Continuous Distributional Quantile Critics"): each critic outputs `quantiles`
/// atoms of the return's distribution, trained by the quantile Huber loss towards the pooled
/// atoms of every target critic with the `drop_per_critic * critics` largest dropped; the
/// actor maximises the mean of all atoms. The critics are the agent's one or two
/// (`twin_critic`); see `tqc.rs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TqcConfig {
    /// Atoms (quantiles) per critic, `M` (>= 1). The paper and Stable-Baselines3: 25.
    pub quantiles: usize,
    /// Atoms dropped per critic from the top of the pooled target atoms, `d` (< `quantiles`).
    /// The paper: 2 for most environments; Stable-Baselines3: 2.
    pub drop_per_critic: usize,
}

impl Default for TqcConfig {
    fn default() -> Self {
        Self {
            quantiles: 25,
            drop_per_critic: 2,
        }
    }
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            init_alpha: 1.0,
            learn_alpha: true,
            target_entropy: None,
            lr_alpha: 3e-4,
            tqc: None,
        }
    }
}

impl SacConfig {
    /// The target entropy for `act_dim` actions: `target_entropy`, or `-act_dim`.
    pub fn target_entropy(&self, act_dim: usize) -> f64 {
        self.target_entropy.unwrap_or(-(act_dim as f64))
    }
}

/// The range a SAC actor's log standard deviation is clamped to (Stable-Baselines3's).
pub const LOG_STD_RANGE: (f64, f64) = (-20.0, 2.0);
