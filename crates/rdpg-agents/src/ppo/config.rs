//! Hyper-parameters of PPO with an adaptive KL penalty ([`PpoConfig`], the `[ppo]` section of
//! an experiment file).

use crate::common::config::is_f32;
use serde::{Deserialize, Serialize};

use crate::common::DeviceSpec;
use crate::error::{AgentError, Result};

/// Hyper-parameters of [`PpoAgent`](super::PpoAgent) and [`PpoTrainer`](super::PpoTrainer). Every field has a default (see
/// [`PpoConfig::default`]: the settings of Schulman et al. 2017's MuJoCo experiments where they
/// apply); a JSON config may give any subset, unknown fields are rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PpoConfig {
    /// Hidden layer widths of both the policy and the value MLP (tanh after each; separate
    /// weights). Empty: linear networks. Default `[64, 64]`.
    pub hidden: Vec<usize>,
    /// Initial value of the state-independent log standard deviation of every action
    /// dimension (learned). Default -0.5.
    pub log_std_init: f64,
    /// Discount factor gamma. Default 0.99.
    pub gamma: f64,
    /// GAE lambda. Default 0.95.
    pub gae_lambda: f64,
    /// Steps collected per environment before each update phase (the batch is
    /// `rollout_steps * num_envs`). Default 2048.
    pub rollout_steps: usize,
    /// Passes over the batch per update phase. Default 10.
    pub epochs: usize,
    /// Minibatch size (the last minibatch of a pass may be smaller). Default 64.
    pub minibatch_size: usize,
    /// Adam learning rate of the policy (mean network and log std). Default 3e-4.
    pub lr_policy: f64,
    /// Adam learning rate of the value network. Default 1e-3.
    pub lr_value: f64,
    /// Target KL divergence `d_targ` per update phase. Default 0.01.
    pub kl_target: f64,
    /// Initial KL penalty coefficient beta. Default 1.0.
    pub kl_coef_init: f64,
    /// beta is multiplied by this when the phase's KL exceeds `1.5 * kl_target` and divided by
    /// it when the KL is below `kl_target / 1.5`. Must be > 1. Default 2.0.
    pub kl_adapt_factor: f64,
    /// Maximum global L2 norm of the gradients of each network (policy, value) before each Adam
    /// step; `None`: no clipping. Default 0.5.
    pub grad_clip: Option<f64>,
    /// Normalise the advantages of each update phase to zero mean and unit standard deviation
    /// (over the whole batch). Default true.
    pub normalize_advantages: bool,
    /// Device: `"cpu"`, `"cuda"` or `"auto"`. Default CPU (the networks are tiny).
    pub device: DeviceSpec,
    /// Number of intra-op CPU threads libtorch uses (process-wide); `None` leaves libtorch's
    /// default.
    pub num_threads: Option<usize>,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            hidden: vec![64, 64],
            log_std_init: -0.5,
            gamma: 0.99,
            gae_lambda: 0.95,
            rollout_steps: 2048,
            epochs: 10,
            minibatch_size: 64,
            lr_policy: 3e-4,
            lr_value: 1e-3,
            kl_target: 0.01,
            kl_coef_init: 1.0,
            kl_adapt_factor: 2.0,
            grad_clip: Some(0.5),
            normalize_advantages: true,
            device: DeviceSpec::Cpu,
            num_threads: None,
        }
    }
}

impl PpoConfig {
    /// Checks every field; the error names the offending one (`ppo.<field>`).
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(AgentError::Config { field, reason });
        let pos = |v: f64| is_f32(v) && v > 0.0;
        let max = crate::rdpg::config::MAX_WIDTH;
        if self.hidden.len() > 64 || self.hidden.iter().any(|h| !(1..=max).contains(h)) {
            return bad(
                "ppo.hidden",
                format!("{:?} is not 0 to 64 widths from 1 to {max}", self.hidden),
            );
        }
        if !is_f32(self.log_std_init) {
            return bad(
                "ppo.log_std_init",
                format!("{} is not finite", self.log_std_init),
            );
        }
        if !(0.0..=1.0).contains(&self.gamma) {
            return bad("ppo.gamma", format!("{} is not in [0, 1]", self.gamma));
        }
        if !(0.0..=1.0).contains(&self.gae_lambda) {
            return bad(
                "ppo.gae_lambda",
                format!("{} is not in [0, 1]", self.gae_lambda),
            );
        }
        // Sizes within what a run can do: a file asking for more is refused, not obeyed.
        for (field, v, most) in [
            ("ppo.rollout_steps", self.rollout_steps, 1 << 24),
            ("ppo.epochs", self.epochs, 10_000),
            ("ppo.minibatch_size", self.minibatch_size, 1 << 22),
        ] {
            if !(1..=most).contains(&v) {
                return bad(field, format!("{v} is not from 1 to {most}"));
            }
        }
        for (field, v) in [
            ("ppo.lr_policy", self.lr_policy),
            ("ppo.lr_value", self.lr_value),
            ("ppo.kl_target", self.kl_target),
            ("ppo.kl_coef_init", self.kl_coef_init),
        ] {
            if !pos(v) {
                return bad(field, format!("{v} is not a positive number"));
            }
        }
        if !(is_f32(self.kl_adapt_factor) && self.kl_adapt_factor > 1.0) {
            return bad(
                "ppo.kl_adapt_factor",
                format!("{} is not a number > 1", self.kl_adapt_factor),
            );
        }
        if let Some(c) = self.grad_clip {
            if !pos(c) {
                return bad("ppo.grad_clip", format!("{c} is not a positive number"));
            }
        }
        if self
            .num_threads
            .is_some_and(|n| n == 0 || n > crate::common::tensor::MAX_THREADS)
        {
            return bad(
                "ppo.num_threads",
                format!(
                    "must be 1 to {} when given",
                    crate::common::tensor::MAX_THREADS
                ),
            );
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_validation_names_the_field() {
        let field = |c: PpoConfig| match c.validate() {
            Err(AgentError::Config { field, .. }) => field,
            other => panic!("expected a config error, got {other:?}"),
        };
        assert!(PpoConfig::default().validate().is_ok());
        let d = PpoConfig::default;
        assert_eq!(
            field(PpoConfig {
                hidden: vec![64, 0],
                ..d()
            }),
            "ppo.hidden"
        );
        assert_eq!(field(PpoConfig { gamma: 1.5, ..d() }), "ppo.gamma");
        assert_eq!(
            field(PpoConfig {
                gae_lambda: -0.1,
                ..d()
            }),
            "ppo.gae_lambda"
        );
        assert_eq!(
            field(PpoConfig {
                rollout_steps: 0,
                ..d()
            }),
            "ppo.rollout_steps"
        );
        assert_eq!(field(PpoConfig { epochs: 0, ..d() }), "ppo.epochs");
        assert_eq!(
            field(PpoConfig {
                minibatch_size: 0,
                ..d()
            }),
            "ppo.minibatch_size"
        );
        assert_eq!(
            field(PpoConfig {
                lr_policy: 0.0,
                ..d()
            }),
            "ppo.lr_policy"
        );
        assert_eq!(
            field(PpoConfig {
                lr_value: f64::NAN,
                ..d()
            }),
            "ppo.lr_value"
        );
        assert_eq!(
            field(PpoConfig {
                kl_target: 0.0,
                ..d()
            }),
            "ppo.kl_target"
        );
        assert_eq!(
            field(PpoConfig {
                kl_coef_init: -1.0,
                ..d()
            }),
            "ppo.kl_coef_init"
        );
        assert_eq!(
            field(PpoConfig {
                kl_adapt_factor: 1.0,
                ..d()
            }),
            "ppo.kl_adapt_factor"
        );
        assert_eq!(
            field(PpoConfig {
                grad_clip: Some(0.0),
                ..d()
            }),
            "ppo.grad_clip"
        );
        assert_eq!(
            field(PpoConfig {
                num_threads: Some(0),
                ..d()
            }),
            "ppo.num_threads"
        );
        assert_eq!(
            field(PpoConfig {
                log_std_init: f64::INFINITY,
                ..d()
            }),
            "ppo.log_std_init"
        );
        // Unknown JSON fields are rejected, missing ones default.
        assert!(serde_json::from_str::<PpoConfig>(r#"{"clip": 0.2}"#).is_err());
        let c: PpoConfig = serde_json::from_str(r#"{"epochs": 3}"#).unwrap();
        assert_eq!(c, PpoConfig { epochs: 3, ..d() });
    }
}
