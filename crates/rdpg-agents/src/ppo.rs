//! Proximal policy optimisation with an adaptive KL penalty: the PPO baseline of the paper's
//! Table I ("PPO with an adaptive KL penalty, feed-forward, GAE").
//!
//! * [`PpoConfig`]: hyper-parameters (serde, validated).
//! * [`PpoAgent`]: a Gaussian policy `N(mu(o), diag(sigma^2))` (tanh MLP mean, state-independent
//!   learned `log sigma`) and a separate tanh MLP value function; the update of one PPO phase on
//!   a [`PpoBatch`] ([`PpoAgent::update`]); checkpoints with optimiser moments.
//! * [`PpoTrainer`]: the on-policy loop on a vector env, with the same API as
//!   [`crate::train::Trainer`] (observer callbacks, evaluation, bit-identical resume).
//! * [`gae`] and [`adapt_kl_coef`]: the two pieces of arithmetic outside the networks, as pure
//!   functions.
//!
//! # The algorithm
//!
//! Each iteration collects `rollout_steps` steps from each of the `N` environments with the
//! current policy: `a_t ~ pi_old(.|o_t)` (the unclipped sample is what the policy "did"; the
//! environment receives it clipped to `[-1, 1]` and mapped to its bounds). Then:
//!
//! 1. **GAE** (Schulman et al. 2016, "High-dimensional continuous control using generalized
//!    advantage estimation", Eq. 10 for `delta`, Eq. 16 for the estimator; the truncated form
//!    is Eqs. 11-12 of the PPO paper): `delta_t = r_t + gamma (1 - term_t) V(s_{t+1}) - V(s_t)`
//!    and `A_t = delta_t + gamma lambda (1 - end_t) A_{t+1}`, where `s_{t+1}` is the true next
//!    state (the last observation of an episode cut by the time limit, which is bootstrapped
//!    from; terminal states are not), and returns `R_t = A_t + V(s_t)` ([`gae`]).
//! 2. **Policy**: `epochs` passes of shuffled minibatches maximising the KL-penalised surrogate of
//!    Schulman et al. 2017 ("Proximal Policy Optimization Algorithms"), section 4, Eq. (8):
//!    `L^KLPEN(theta) = E_t[ r_t(theta) A_t - beta KL[pi_old(.|s_t), pi_theta(.|s_t)] ]` with
//!    `r_t(theta) = pi_theta(a_t|s_t) / pi_old(a_t|s_t)` (Eq. (6)).
//! 3. **Value**: the same minibatches minimise `E_t[(V(s_t) - R_t)^2]` (separate network and
//!    optimiser).
//! 4. **beta adaptation** (section 4, after Eq. (8)): `d = E_t[KL[pi_old, pi_theta]]` over the
//!    phase's batch with the final parameters; `beta <- beta / factor` if `d < d_targ / 1.5`,
//!    `beta <- beta * factor` if `d > 1.5 d_targ` ([`adapt_kl_coef`]; the paper uses 2).
//!
//! There is no clipping of the ratio (that is the other PPO variant) and no entropy bonus.

use std::collections::HashMap;
use std::path::Path;

use rdpg_core::rng::NpRng;
use rdpg_envs::VecEnv;
use serde::{Deserialize, Serialize};
use tch::nn::{self, Module, VarStore};
use tch::{Device, Kind, Tensor};

use crate::adam::{Adam, AdamConfig};
use crate::nets::init_from_rng;
use crate::rdpg::{resolve_device, sorted_vars, tensor_to_vec};
use crate::train::{
    evaluate_policy, read_bin, to_env_action, write_bin, DeterministicPolicy, EpisodeRecord,
    EvalRecord, TrainConfig, TrainObserver,
};
use crate::{AgentError, DeviceSpec, Result, UpdateStats};

// ---------------------------------------------------------------------------------------------
// Configuration
// ---------------------------------------------------------------------------------------------

/// Hyper-parameters of [`PpoAgent`] and [`PpoTrainer`]. Every field has a default (see
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
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if self.hidden.contains(&0) {
            return bad("ppo.hidden", format!("{:?} has a zero width", self.hidden));
        }
        if !self.log_std_init.is_finite() {
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
        for (field, v) in [
            ("ppo.rollout_steps", self.rollout_steps),
            ("ppo.epochs", self.epochs),
            ("ppo.minibatch_size", self.minibatch_size),
        ] {
            if v == 0 {
                return bad(field, "must be positive".into());
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
        if !(self.kl_adapt_factor.is_finite() && self.kl_adapt_factor > 1.0) {
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
        if self.num_threads == Some(0) {
            return bad("ppo.num_threads", "must be at least 1".into());
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Pure arithmetic: GAE and the beta rule
// ---------------------------------------------------------------------------------------------

/// Generalised advantage estimates (Schulman et al. 2016, Eqs. 10 and 16) of one environment's
/// sequence of `T` consecutive steps, which may span several episodes.
///
/// For step `t`: `rewards[t]` is `r_t`, `values[t]` is `V(s_t)`, `next_values[t]` is `V` of the
/// true next state `s_{t+1}` (for a step that ended an episode by the time limit, the episode's
/// last observation; for the last step of the sequence, the observation after it; ignored when
/// `terminated[t]`), `terminated[t]` says `s_{t+1}` is terminal (no bootstrap) and `ended[t]`
/// that an episode ended on step `t` (terminated or truncated: the advantage does not flow back
/// across it). Returns `A_t` for every step, from
///
/// `delta_t = r_t + gamma (1 - terminated_t) V(s_{t+1}) - V(s_t)`,
/// `A_t = delta_t + gamma lambda (1 - ended_t) A_{t+1}`, `A_T = 0`.
///
/// The value targets are `R_t = A_t + V(s_t)`.
///
/// # Panics
/// If the slices have different lengths.
pub fn gae(
    rewards: &[f64],
    values: &[f64],
    next_values: &[f64],
    terminated: &[bool],
    ended: &[bool],
    gamma: f64,
    lambda: f64,
) -> Vec<f64> {
    let t = rewards.len();
    assert!(
        values.len() == t && next_values.len() == t && terminated.len() == t && ended.len() == t,
        "gae: slices of different lengths"
    );
    let mut adv = vec![0.0; t];
    let mut next_adv = 0.0;
    for k in (0..t).rev() {
        let boot = if terminated[k] { 0.0 } else { next_values[k] };
        let delta = rewards[k] + gamma * boot - values[k];
        let carry = if ended[k] { 0.0 } else { next_adv };
        adv[k] = delta + gamma * lambda * carry;
        next_adv = adv[k];
    }
    adv
}

/// The adaptive KL penalty rule of Schulman et al. 2017, section 4: given the mean KL `kl`
/// measured after an update phase, returns the next `beta`: `beta / factor` if
/// `kl < target / 1.5`, `beta * factor` if `kl > 1.5 target`, else `beta`.
pub fn adapt_kl_coef(beta: f64, kl: f64, target: f64, factor: f64) -> f64 {
    if kl < target / 1.5 {
        beta / factor
    } else if kl > target * 1.5 {
        beta * factor
    } else {
        beta
    }
}

// ---------------------------------------------------------------------------------------------
// The agent
// ---------------------------------------------------------------------------------------------

/// Adam's `beta1`, `beta2` and `eps` for both networks (the values of OpenAI's PPO baselines).
const ADAM: (f64, f64, f64) = (0.9, 0.999, 1e-5);

/// A tanh MLP: `hidden` layers `l0, l1, ...` with tanh, then a linear `head`.
#[derive(Debug)]
struct Mlp {
    layers: Vec<nn::Linear>,
    head: nn::Linear,
}

impl Mlp {
    fn new(p: &nn::Path, input: usize, hidden: &[usize], output: usize) -> Self {
        let mut layers = Vec::new();
        let mut width = input as i64;
        for (i, &h) in hidden.iter().enumerate() {
            layers.push(nn::linear(
                p / format!("l{i}"),
                width,
                h as i64,
                Default::default(),
            ));
            width = h as i64;
        }
        let head = nn::linear(p / "head", width, output as i64, Default::default());
        Self { layers, head }
    }

    /// `x [B, in] -> [B, out]`.
    fn forward(&self, x: &Tensor) -> Tensor {
        let mut h = x.shallow_clone();
        for l in &self.layers {
            h = l.forward(&h).tanh();
        }
        self.head.forward(&h)
    }
}

/// One update phase's data, all row-major `f32`, `N` samples.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PpoBatch {
    /// Observations `[N, obs_dim]`.
    pub obs: Vec<f32>,
    /// The actions taken, as sampled (unclipped), `[N, act_dim]`.
    pub actions: Vec<f32>,
    /// Advantage estimates `A_t`, `[N]` (normalised inside the update when configured).
    pub advantages: Vec<f32>,
    /// Value targets `R_t = A_t + V_old(s_t)`, `[N]`.
    pub returns: Vec<f32>,
}

/// What one update phase ([`PpoAgent::update`]) did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PpoStats {
    /// Mean over the minibatches of the policy loss `-mean(r A) + beta mean(KL)`.
    pub policy_loss: f64,
    /// Mean over the minibatches of the value loss `mean((V - R)^2)`.
    pub value_loss: f64,
    /// Mean value prediction over the minibatches.
    pub value_mean: f64,
    /// `d = E_t[KL[pi_old, pi_theta]]` over the batch after the phase.
    pub kl: f64,
    /// beta used in this phase's loss.
    pub kl_coef: f64,
    /// beta after the adaptation (used by the next phase).
    pub next_kl_coef: f64,
    /// Minibatch steps taken.
    pub minibatches: usize,
}

impl From<PpoStats> for UpdateStats {
    /// The trainer-facing summary: `critic_loss` is the value loss, `actor_loss` the policy
    /// loss (KL term included), `q_mean` the mean value prediction.
    fn from(s: PpoStats) -> Self {
        UpdateStats {
            critic_loss: s.value_loss,
            actor_loss: s.policy_loss,
            q_mean: s.value_mean,
        }
    }
}

/// Metadata written next to the weights by [`PpoAgent::save`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AgentMeta {
    format: u32,
    config: PpoConfig,
    obs_dim: usize,
    act_dim: usize,
    seed: u64,
    kl_coef: f64,
    updates: u64,
}

const AGENT_FORMAT: u32 = 1;

/// A feed-forward Gaussian policy and value function trained with PPO (adaptive KL penalty).
///
/// Variables (one var store, f32): `policy.l{i}.*`, `policy.head.*` (the mean),
/// `policy.log_std` `[act_dim]`, `value.l{i}.*`, `value.head.*` (`[1]` output). The weights
/// come from the seed alone ([`init_from_rng`]: uniform `±1/sqrt(fan_in)`, heads `±3e-3`), the
/// log std starts at `log_std_init`.
pub struct PpoAgent {
    cfg: PpoConfig,
    obs_dim: usize,
    act_dim: usize,
    seed: u64,
    device: Device,
    vs: VarStore,
    policy: Mlp,
    /// `[A]`, shallow handle to `policy.log_std`.
    log_std: Tensor,
    value: Mlp,
    policy_opt: Adam,
    value_opt: Adam,
    kl_coef: f64,
    updates: u64,
}

impl std::fmt::Debug for PpoAgent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PpoAgent")
            .field("obs_dim", &self.obs_dim)
            .field("act_dim", &self.act_dim)
            .field("device", &self.device)
            .field("kl_coef", &self.kl_coef)
            .field("updates", &self.updates)
            .finish_non_exhaustive()
    }
}

/// Variables whose name starts with `prefix`, sorted by name.
fn vars_with_prefix(vs: &VarStore, prefix: &str) -> Vec<(String, Tensor)> {
    sorted_vars(vs)
        .into_iter()
        .filter(|(n, _)| n.starts_with(prefix))
        .collect()
}

fn ckpt_err(path: &Path, e: impl std::fmt::Display) -> AgentError {
    AgentError::Checkpoint(format!("{}: {e}", path.display()))
}

impl PpoAgent {
    /// A new agent for `obs_dim` observations and `act_dim` actions; the weights are drawn from
    /// an [`NpRng`] seeded with `seed` (same seed, same weights).
    pub fn new(cfg: PpoConfig, obs_dim: usize, act_dim: usize, seed: u64) -> Result<Self> {
        cfg.validate()?;
        if obs_dim == 0 || act_dim == 0 {
            return Err(AgentError::Shape(format!(
                "obs_dim {obs_dim} and act_dim {act_dim} must be positive"
            )));
        }
        if let Some(n) = cfg.num_threads {
            crate::set_num_threads(n);
        }
        let device = resolve_device(cfg.device)?;
        let vs = VarStore::new(device);
        let root = vs.root();
        let policy = Mlp::new(&(&root / "policy"), obs_dim, &cfg.hidden, act_dim);
        let mut log_std =
            (&root / "policy").var("log_std", &[act_dim as i64], nn::Init::Const(0.0));
        let value = Mlp::new(&(&root / "value"), obs_dim, &cfg.hidden, 1);
        init_from_rng(&vs, &mut NpRng::from_seed(seed));
        tch::no_grad(|| {
            let _ = log_std.fill_(cfg.log_std_init);
        });
        let adam = |lr| AdamConfig {
            lr,
            beta1: ADAM.0,
            beta2: ADAM.1,
            eps: ADAM.2,
            weight_decay: 0.0,
        };
        let policy_opt = Adam::new(adam(cfg.lr_policy), vars_with_prefix(&vs, "policy."));
        let value_opt = Adam::new(adam(cfg.lr_value), vars_with_prefix(&vs, "value."));
        Ok(Self {
            kl_coef: cfg.kl_coef_init,
            cfg,
            obs_dim,
            act_dim,
            seed,
            device,
            vs,
            policy,
            log_std,
            value,
            policy_opt,
            value_opt,
            updates: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &PpoConfig {
        &self.cfg
    }

    /// Observation size.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Action size.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// The device the networks live on.
    pub fn device(&self) -> Device {
        self.device
    }

    /// The current KL penalty coefficient beta.
    pub fn kl_coef(&self) -> f64 {
        self.kl_coef
    }

    /// Update phases made so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// The policy's log standard deviations, `[act_dim]`.
    pub fn log_std(&self) -> Vec<f32> {
        tensor_to_vec(&self.log_std)
    }

    /// `obs` (`[n, obs_dim]` row-major) as a tensor on the agent's device.
    fn obs_tensor(&self, obs: &[f32]) -> Tensor {
        assert!(
            obs.len() % self.obs_dim == 0,
            "{} observation values are not a multiple of obs_dim {}",
            obs.len(),
            self.obs_dim
        );
        let n = (obs.len() / self.obs_dim) as i64;
        Tensor::from_slice(obs)
            .view([n, self.obs_dim as i64])
            .to_device(self.device)
    }

    /// The policy means `mu(o)` (unclamped) of a batch of `n` observations (`[n, obs_dim]`
    /// row-major): `[n, act_dim]`.
    ///
    /// # Panics
    /// If `obs.len()` is not a multiple of `obs_dim`.
    pub fn policy_mean(&self, obs: &[f32]) -> Vec<f32> {
        let o = self.obs_tensor(obs);
        tensor_to_vec(&tch::no_grad(|| self.policy.forward(&o)))
    }

    /// The deterministic actions of `n` observations: the policy means clamped to `[-1, 1]`,
    /// `[n, act_dim]`.
    ///
    /// # Panics
    /// If `obs.len()` is not a multiple of `obs_dim`.
    pub fn act_deterministic(&self, obs: &[f32]) -> Vec<f32> {
        let mut a = self.policy_mean(obs);
        for x in &mut a {
            *x = x.clamp(-1.0, 1.0);
        }
        a
    }

    /// Samples `a = mu(o) + sigma * eps`, `eps ~ N(0, I)` from `rng` (environment-major, then
    /// action dimension), for `n` observations: `[n, act_dim]`, not clipped (clip before
    /// acting; the update needs the sample itself).
    ///
    /// # Panics
    /// If `obs.len()` is not a multiple of `obs_dim`.
    pub fn sample(&self, obs: &[f32], rng: &mut NpRng) -> Vec<f32> {
        let mean = self.policy_mean(obs);
        let std: Vec<f64> = self.log_std().iter().map(|&l| f64::from(l).exp()).collect();
        mean.iter()
            .enumerate()
            .map(|(k, &m)| (f64::from(m) + std[k % self.act_dim] * rng.standard_normal()) as f32)
            .collect()
    }

    /// Value predictions `V(o)` of `n` observations, `[n]`.
    ///
    /// # Panics
    /// If `obs.len()` is not a multiple of `obs_dim`.
    pub fn values(&self, obs: &[f32]) -> Vec<f32> {
        let o = self.obs_tensor(obs);
        tensor_to_vec(&tch::no_grad(|| self.value.forward(&o)))
    }

    /// Checks a batch's array lengths against each other and the agent.
    pub fn check_batch(&self, b: &PpoBatch) -> Result<()> {
        let n = b.advantages.len();
        if n == 0
            || b.returns.len() != n
            || b.obs.len() != n * self.obs_dim
            || b.actions.len() != n * self.act_dim
        {
            return Err(AgentError::Shape(format!(
                "PPO batch: {} obs values, {} action values, {} advantages, {} returns \
                 (obs_dim {}, act_dim {}; needs at least one sample)",
                b.obs.len(),
                b.actions.len(),
                n,
                b.returns.len(),
                self.obs_dim,
                self.act_dim
            )));
        }
        Ok(())
    }

    /// One PPO update phase on `batch` (collected with the current parameters, which are
    /// `theta_old`): `epochs` passes of minibatches shuffled with `rng`, then the beta
    /// adaptation. See the module docs for the equations. Flushes denormals on the calling
    /// thread ([`crate::set_flush_denormal`]).
    ///
    /// Shapes: `N` samples, `M` minibatch rows, `D` observation size, `A` action size.
    pub fn update(&mut self, batch: &PpoBatch, rng: &mut NpRng) -> Result<PpoStats> {
        // The advantages are GAE estimates (Schulman et al. 2016 Eq. 16; PPO paper Eqs. 11-12),
        // computed by [`gae`] with the value network of theta_old.
        crate::set_flush_denormal(true);
        self.check_batch(batch)?;
        let c = self.cfg.clone();
        let (n, a_dim) = (batch.advantages.len(), self.act_dim as i64);
        let dev = self.device;

        // --- The batch on the device.
        let obs = self.obs_tensor(&batch.obs); // [N, D]
        let act = Tensor::from_slice(&batch.actions)
            .view([n as i64, a_dim])
            .to_device(dev); // [N, A]
        let mut adv = Tensor::from_slice(&batch.advantages).to_device(dev); // [N]
        let ret = Tensor::from_slice(&batch.returns).to_device(dev); // [N]

        // --- The old policy pi_old = pi_{theta_old}: fixed for the whole phase.
        let (mu_old, log_std_old) = tch::no_grad(|| {
            (self.policy.forward(&obs), self.log_std.detach().copy()) // [N, A], [A]
        });
        // log N(a | mu, sigma^2) summed over action dimensions: [M, A] -> [M].
        let log_prob =
            |mu: &Tensor, log_std: &Tensor, a: &Tensor| -> Tensor {
                let z = (a - mu) * (-log_std).exp(); // (a - mu) / sigma, [M, A]
                (z.square() * -0.5 - log_std - 0.5 * (2.0 * std::f64::consts::PI).ln())
                    .sum_dim_intlist(-1, false, Kind::Float)
            };
        // KL[N(mu_old, s_old^2) || N(mu, s^2)] per sample, summed over action dimensions:
        // log(s / s_old) + (s_old^2 + (mu_old - mu)^2) / (2 s^2) - 1/2, [M, A] -> [M].
        let kl_old_new = |mu_o: &Tensor, mu: &Tensor, log_std: &Tensor| -> Tensor {
            let var = (log_std * 2.0).exp(); // s^2, [A]
            let var_old = (&log_std_old * 2.0).exp(); // s_old^2, [A]
            ((log_std - &log_std_old) + (var_old + (mu_o - mu).square()) / (var * 2.0) - 0.5)
                .sum_dim_intlist(-1, false, Kind::Float)
        };
        let logp_old = tch::no_grad(|| log_prob(&mu_old, &log_std_old, &act)); // [N]

        // --- Advantage normalisation over the batch (optional): A <- (A - mean) / (std + 1e-8).
        if c.normalize_advantages && n > 1 {
            adv = (&adv - adv.mean(Kind::Float)) / (adv.std(true) + 1e-8);
        }

        // --- epochs x shuffled minibatches.
        let beta = self.kl_coef;
        let mut order: Vec<i64> = (0..n as i64).collect();
        let (mut sum_pl, mut sum_vl, mut sum_v) = (
            Tensor::zeros([], (Kind::Float, dev)),
            Tensor::zeros([], (Kind::Float, dev)),
            Tensor::zeros([], (Kind::Float, dev)),
        );
        let mut minibatches = 0usize;
        for _ in 0..c.epochs {
            // Fisher-Yates shuffle with the caller's generator.
            for i in (1..n).rev() {
                let j = rng.integers(0, i as i64 + 1) as usize;
                order.swap(i, j);
            }
            for chunk in order.chunks(c.minibatch_size) {
                let idx = Tensor::from_slice(chunk).to_device(dev); // [M]
                let o = obs.index_select(0, &idx); // [M, D]
                let a = act.index_select(0, &idx); // [M, A]
                let adv_m = adv.index_select(0, &idx); // [M]
                let ret_m = ret.index_select(0, &idx); // [M]

                // Policy: r_t(theta) = exp(log pi_theta(a_t|s_t) - log pi_old(a_t|s_t)) (Eq. 6).
                let mu = self.policy.forward(&o); // [M, A]
                let logp = log_prob(&mu, &self.log_std, &a); // [M]
                let ratio = (logp - logp_old.index_select(0, &idx)).exp(); // [M]

                // KL[pi_old(.|s_t), pi_theta(.|s_t)], [M]
                let kl = kl_old_new(&mu_old.index_select(0, &idx), &mu, &self.log_std);
                // -L^KLPEN = -E[r_t A_t] + beta E[KL[pi_old, pi_theta]] (Eq. 8, negated).
                let policy_loss = -(ratio * &adv_m).mean(Kind::Float) + kl.mean(Kind::Float) * beta;
                self.policy_opt.zero_grad();
                policy_loss.backward();
                if let Some(g) = c.grad_clip {
                    let _ = self.policy_opt.clip_grad_norm(g);
                }
                self.policy_opt.step();

                // Value: E[(V(s_t) - R_t)^2].
                let v = self.value.forward(&o).squeeze_dim(-1); // [M]
                let value_loss = (&v - ret_m).square().mean(Kind::Float);
                self.value_opt.zero_grad();
                value_loss.backward();
                if let Some(g) = c.grad_clip {
                    let _ = self.value_opt.clip_grad_norm(g);
                }
                self.value_opt.step();

                sum_pl += policy_loss.detach();
                sum_vl += value_loss.detach();
                sum_v += v.detach().mean(Kind::Float);
                minibatches += 1;
            }
        }

        // --- beta adaptation: d = E_t[KL[pi_old, pi_theta]] over the batch, final parameters.
        let d = tch::no_grad(|| {
            kl_old_new(&mu_old, &self.policy.forward(&obs), &self.log_std).mean(Kind::Float)
        })
        .double_value(&[]);
        let next = adapt_kl_coef(beta, d, c.kl_target, c.kl_adapt_factor);
        self.kl_coef = next;
        self.updates += 1;
        let m = minibatches.max(1) as f64;
        Ok(PpoStats {
            policy_loss: sum_pl.double_value(&[]) / m,
            value_loss: sum_vl.double_value(&[]) / m,
            value_mean: sum_v.double_value(&[]) / m,
            kl: d,
            kl_coef: beta,
            next_kl_coef: next,
            minibatches,
        })
    }

    /// All weights (log std included) flattened to f64, by name (sorted); for tests and
    /// diagnostics.
    pub fn weights(&self) -> Vec<(String, Vec<f64>)> {
        vars_with_prefix(&self.vs, "")
            .into_iter()
            .map(|(n, t)| (n, tensor_to_vec(&t).into_iter().map(f64::from).collect()))
            .collect()
    }

    /// Writes the networks (`weights.safetensors`), the optimiser moments
    /// (`optim.safetensors`) and the config, sizes, seed, beta and update count (`agent.json`)
    /// to `dir`. [`PpoAgent::load`] continues bit-identically.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir)?;
        let cpu = |t: &Tensor| t.detach().to_device(Device::Cpu).contiguous();
        let weights: Vec<(String, Tensor)> = vars_with_prefix(&self.vs, "")
            .into_iter()
            .map(|(n, t)| (n, cpu(&t)))
            .collect();
        Tensor::write_safetensors(&weights, dir.join("weights.safetensors"))?;
        let mut optim = self.policy_opt.state("policy_opt.");
        optim.extend(self.value_opt.state("value_opt."));
        let optim: Vec<(String, Tensor)> = optim.into_iter().map(|(n, t)| (n, cpu(&t))).collect();
        Tensor::write_safetensors(&optim, dir.join("optim.safetensors"))?;
        let meta = AgentMeta {
            format: AGENT_FORMAT,
            config: self.cfg.clone(),
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            seed: self.seed,
            kl_coef: self.kl_coef,
            updates: self.updates,
        };
        std::fs::write(dir.join("agent.json"), serde_json::to_string_pretty(&meta)?)?;
        Ok(())
    }

    /// Restores an agent written by [`PpoAgent::save`]. Missing, truncated or inconsistent files
    /// give an [`AgentError::Checkpoint`] naming the file.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref();
        let meta_path = dir.join("agent.json");
        let text = std::fs::read_to_string(&meta_path).map_err(|e| ckpt_err(&meta_path, e))?;
        let meta: AgentMeta = serde_json::from_str(&text).map_err(|e| ckpt_err(&meta_path, e))?;
        if meta.format != AGENT_FORMAT {
            return Err(ckpt_err(
                &meta_path,
                format!("unknown format {} (expected {AGENT_FORMAT})", meta.format),
            ));
        }
        if !(meta.kl_coef.is_finite() && meta.kl_coef > 0.0) {
            return Err(ckpt_err(
                &meta_path,
                format!("bad kl_coef {}", meta.kl_coef),
            ));
        }
        let mut agent = Self::new(meta.config, meta.obs_dim, meta.act_dim, meta.seed)?;
        let read = |file: &str| -> Result<HashMap<String, Tensor>> {
            let path = dir.join(file);
            if !path.is_file() {
                return Err(ckpt_err(&path, "missing"));
            }
            Ok(Tensor::read_safetensors(&path)
                .map_err(|e| ckpt_err(&path, format!("truncated or corrupt: {e}")))?
                .into_iter()
                .collect())
        };
        let weights = read("weights.safetensors")?;
        for (name, mut var) in vars_with_prefix(&agent.vs, "") {
            let src = weights
                .get(&name)
                .ok_or_else(|| AgentError::Checkpoint(format!("missing weight `{name}`")))?;
            if src.size() != var.size() || src.kind() != Kind::Float {
                return Err(AgentError::Checkpoint(format!(
                    "weight `{name}` has shape {:?} ({:?}), expected {:?} (Float)",
                    src.size(),
                    src.kind(),
                    var.size()
                )));
            }
            tch::no_grad(|| var.copy_(&src.to_device(agent.device)));
        }
        let optim = read("optim.safetensors")?;
        agent.policy_opt.load_state("policy_opt.", &optim)?;
        agent.value_opt.load_state("value_opt.", &optim)?;
        agent.kl_coef = meta.kl_coef;
        agent.updates = meta.updates;
        Ok(agent)
    }
}

impl DeterministicPolicy for PpoAgent {
    /// Feed-forward: nothing to reset.
    fn begin_episode(&mut self) {}
    /// The policy mean clamped to `[-1, 1]`.
    fn act(&mut self, obs: &[f32]) -> Vec<f32> {
        self.act_deterministic(obs)
    }
}

// ---------------------------------------------------------------------------------------------
// The trainer
// ---------------------------------------------------------------------------------------------

/// The steps collected since the last update phase, `len` vector steps of `n` environments,
/// step-major (`[len, n, ...]`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Rollout {
    /// Vector steps collected.
    len: usize,
    /// Observations acted on, `[len, n, D]`.
    obs: Vec<f32>,
    /// Sampled (unclipped) actions, `[len, n, A]`.
    actions: Vec<f32>,
    /// Training rewards, `[len, n]`.
    rewards: Vec<f64>,
    /// The step reached a terminal state, `[len, n]`.
    terminated: Vec<bool>,
    /// An episode ended on the step (terminated or truncated), `[len, n]`.
    ended: Vec<bool>,
    /// `(t * n + i, last observation)` of every episode cut by the time limit (not terminal):
    /// the state its last step bootstraps from.
    truncated_obs: Vec<(usize, Vec<f32>)>,
}

/// GAE over a rollout of `n` environments: `values` is `V` of the rollout's observations
/// (`[len, n]`), `last_values` of the observations after the rollout (`[n]`), and
/// `trunc_values` of `ro.truncated_obs` (same order). Returns the advantages, `[len, n]`.
fn rollout_advantages(
    ro: &Rollout,
    n: usize,
    values: &[f64],
    last_values: &[f64],
    trunc_values: &[f64],
    gamma: f64,
    lambda: f64,
) -> Vec<f64> {
    let t_len = ro.len;
    // V(s_{t+1}) of every step: the next observation of the same env, the one after the
    // rollout for the last step, the episode's last observation after a truncation (after a
    // termination it is unused).
    let mut next = vec![0.0; t_len * n];
    for t in 0..t_len {
        for i in 0..n {
            next[t * n + i] = if t + 1 < t_len {
                values[(t + 1) * n + i]
            } else {
                last_values[i]
            };
        }
    }
    for ((k, _), &v) in ro.truncated_obs.iter().zip(trunc_values) {
        next[*k] = v;
    }
    let mut adv = vec![0.0; t_len * n];
    for i in 0..n {
        let col = |x: &[f64]| -> Vec<f64> { (0..t_len).map(|t| x[t * n + i]).collect() };
        let colb = |x: &[bool]| -> Vec<bool> { (0..t_len).map(|t| x[t * n + i]).collect() };
        let a = gae(
            &col(&ro.rewards),
            &col(values),
            &col(&next),
            &colb(&ro.terminated),
            &colb(&ro.ended),
            gamma,
            lambda,
        );
        for (t, x) in a.into_iter().enumerate() {
            adv[t * n + i] = x;
        }
    }
    adv
}

/// An episode in progress.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct OpenEpisode {
    /// Actions as sent to the env (to rebuild the episode on resume).
    env_actions: Vec<Vec<f32>>,
    ret: f64,
    stock_ret: f64,
}

/// Everything of a run besides the agent, the config and the environments: saved with a
/// checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct LoopState {
    steps: u64,
    next_eval: u64,
    rng: NpRng,
    rollout: Rollout,
    open: Vec<OpenEpisode>,
    episode_index: Vec<u64>,
    /// The observation each env acts on next (checked against the rebuilt env on resume).
    obs: Vec<Vec<f32>>,
}

/// On-policy training of a [`PpoAgent`] on a [`VecEnv`], with the API of
/// [`crate::train::Trainer`] so that the same driver (CLI, tests) can run either.
///
/// Of the [`TrainConfig`] it uses `env`, `hide_obs`, `reward`, `total_steps`, `num_envs`,
/// `workers`, `eval_every`, `eval_episodes`, `eval_seed` and `seed`; `warmup_steps`,
/// `updates_per_step`, `replay_capacity` and `exploration` do not apply (the policy explores by
/// sampling), and `injection` / `param_noise` are rejected.
///
/// Everything random is seeded: the networks (`seed`), the environments (the seed schedule of
/// [`VecEnv::reset_scheduled`] with base `seed`), the action noise and the minibatch shuffles
/// (one [`NpRng`]). [`PpoTrainer::save`] / [`PpoTrainer::load`] resume bit-identically at any
/// step, mid-rollout and mid-episode.
pub struct PpoTrainer {
    cfg: TrainConfig,
    agent: PpoAgent,
    venv: VecEnv,
    low: Vec<f32>,
    high: Vec<f32>,
    st: LoopState,
}

/// [`TrainConfig::validate`] plus the options PPO does not support.
fn validate_train(cfg: &TrainConfig) -> Result<()> {
    cfg.validate()?;
    let reason = "PPO is on-policy: it has no replay to inject into";
    if cfg.injection.is_some() {
        return Err(AgentError::Config {
            field: "train.injection",
            reason: reason.into(),
        });
    }
    if cfg.param_noise.is_some() {
        return Err(AgentError::Config {
            field: "train.param_noise",
            reason: "PPO explores by sampling its Gaussian policy; parameter noise does not apply"
                .into(),
        });
    }
    Ok(())
}

impl PpoTrainer {
    /// A fresh run (validates both configs).
    pub fn new(train: TrainConfig, cfg: PpoConfig) -> Result<Self> {
        validate_train(&train)?;
        cfg.validate()?;
        let (mut venv, low, high) = train.make_envs()?;
        let agent = PpoAgent::new(cfg, venv.obs_dim(), venv.act_dim(), train.seed)?;
        let n = train.num_envs;
        let obs = venv.reset_scheduled(train.seed, &vec![0; n])?;
        let st = LoopState {
            steps: 0,
            next_eval: if train.eval_every > 0 {
                train.eval_every
            } else {
                u64::MAX
            },
            rng: NpRng::from_seed(train.seed ^ 0x9905_A11C_E5EE_D000),
            rollout: Rollout::default(),
            open: vec![OpenEpisode::default(); n],
            episode_index: vec![0; n],
            obs,
        };
        Ok(Self {
            cfg: train,
            agent,
            venv,
            low,
            high,
            st,
        })
    }

    /// The agent being trained.
    pub fn agent(&self) -> &PpoAgent {
        &self.agent
    }

    /// The agent being trained, mutably.
    pub fn agent_mut(&mut self) -> &mut PpoAgent {
        &mut self.agent
    }

    /// The run's configuration.
    pub fn config(&self) -> &TrainConfig {
        &self.cfg
    }

    /// Environment steps taken so far (over all environments).
    pub fn steps(&self) -> u64 {
        self.st.steps
    }

    /// Raises (or lowers) the budget in environment steps, e.g. to continue a finished run.
    pub fn set_total_steps(&mut self, total: u64) {
        self.cfg.total_steps = total;
    }

    /// Runs until `until` environment steps (capped by the budget) or until the observer asks
    /// to stop (asked before every vector step). Returns the step count reached. A rollout cut
    /// short here is kept and continued by the next call.
    pub fn run(&mut self, until: u64, cb: &mut dyn TrainObserver) -> Result<u64> {
        // Acting and updating share this thread; flush denormals for both, so that a resumed
        // run acts under the same floating-point mode as an uninterrupted one.
        crate::set_flush_denormal(true);
        let until = until.min(self.cfg.total_steps);
        let n = self.cfg.num_envs;
        let a_dim = self.agent.act_dim();
        while self.st.steps < until {
            if cb.should_stop(self.st.steps) {
                break;
            }
            // Acting: a_t ~ N(mu(o_t), sigma^2) per env; the env gets clip(a_t, -1, 1) mapped
            // to its bounds.
            let flat: Vec<f32> = self.st.obs.concat(); // [n, D]
            let raw = self.agent.sample(&flat, &mut self.st.rng); // [n, A]
            let env_actions: Vec<Vec<f32>> = raw
                .chunks(a_dim)
                .map(|a| to_env_action(a, &self.low, &self.high))
                .collect();
            let steps = self.venv.step(&env_actions)?;
            self.st.steps += n as u64;
            let ro = &mut self.st.rollout;
            let t = ro.len;
            ro.obs.extend_from_slice(&flat);
            ro.actions.extend_from_slice(&raw);
            for (i, (s, env_a)) in steps.into_iter().zip(env_actions).enumerate() {
                let ended = s.final_obs.is_some();
                ro.rewards.push(s.reward);
                ro.terminated.push(s.terminated);
                ro.ended.push(ended);
                let ep = &mut self.st.open[i];
                ep.env_actions.push(env_a);
                ep.ret += s.reward;
                ep.stock_ret += s.info.stock_reward.unwrap_or(s.reward);
                if let Some(last) = s.final_obs {
                    if !s.terminated {
                        ro.truncated_obs.push((t * n + i, last));
                    }
                    let done = std::mem::take(ep);
                    cb.on_episode(&EpisodeRecord {
                        step: self.st.steps,
                        env: i,
                        ret: done.ret,
                        stock_return: done.stock_ret,
                        len: done.env_actions.len(),
                        success: s.info.success,
                    });
                }
                self.st.obs[i] = s.obs;
            }
            ro.len += 1;
            self.st.episode_index = self.venv.episode_indices();
            if self.st.rollout.len >= self.agent.config().rollout_steps {
                let stats = self.update_from_rollout()?;
                cb.on_update(self.st.steps, &stats.into());
            }
            if self.st.steps >= self.st.next_eval {
                let rec = self.evaluate()?;
                cb.on_eval(&rec);
                self.st.next_eval = self.st.next_eval.saturating_add(self.cfg.eval_every);
            }
        }
        Ok(self.st.steps)
    }

    /// Ends the current rollout: values, GAE, one PPO update phase; starts a new rollout.
    fn update_from_rollout(&mut self) -> Result<PpoStats> {
        let ro = std::mem::take(&mut self.st.rollout);
        let n = self.cfg.num_envs;
        let c = self.agent.config().clone();
        // V of the rollout's observations [len * n], of the next observations [n] and of the
        // truncated episodes' last observations [k], in one forward pass.
        let mut all = ro.obs.clone();
        all.extend(self.st.obs.concat());
        for (_, o) in &ro.truncated_obs {
            all.extend_from_slice(o);
        }
        let v: Vec<f64> = self.agent.values(&all).into_iter().map(f64::from).collect();
        let m = ro.len * n;
        let (values, rest) = v.split_at(m);
        let (last_values, trunc_values) = rest.split_at(n);
        let adv = rollout_advantages(
            &ro,
            n,
            values,
            last_values,
            trunc_values,
            c.gamma,
            c.gae_lambda,
        );
        let batch = PpoBatch {
            returns: adv
                .iter()
                .zip(values)
                .map(|(a, v)| (a + v) as f32)
                .collect(),
            advantages: adv.iter().map(|&a| a as f32).collect(),
            obs: ro.obs,
            actions: ro.actions,
        };
        self.agent.update(&batch, &mut self.st.rng)
    }

    /// Deterministic evaluation (the policy mean, clamped) on the held-out seeds
    /// `eval_seed..`, on the stock reward (see [`evaluate_policy`]).
    pub fn evaluate(&mut self) -> Result<EvalRecord> {
        let (episodes, seed) = (self.cfg.eval_episodes, self.cfg.eval_seed);
        let mut rec = evaluate_policy(&mut self.agent, &self.cfg, episodes, seed)?;
        rec.step = self.st.steps;
        Ok(rec)
    }

    /// Writes a checkpoint to `dir`: the agent (`agent/`: networks, optimiser moments, beta),
    /// the loop state (`loop.bin`: generator, partial rollout, episodes in progress, counters)
    /// and the train config (`train.json`).
    pub fn save(&mut self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir)?;
        self.agent.save(dir.join("agent"))?;
        write_bin(&dir.join("loop.bin"), &self.st)?;
        std::fs::write(
            dir.join("train.json"),
            serde_json::to_string_pretty(&self.cfg)?,
        )?;
        Ok(())
    }

    /// Resumes a checkpoint written by [`PpoTrainer::save`]; continuing gives the same result
    /// as never having stopped. Episodes in progress are rebuilt from their seed and actions.
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join("train.json");
        let text = std::fs::read_to_string(&path).map_err(|e| ckpt_err(&path, e))?;
        let cfg: TrainConfig = serde_json::from_str(&text).map_err(|e| ckpt_err(&path, e))?;
        validate_train(&cfg)?;
        let agent = PpoAgent::load(dir.join("agent"))?;
        let st: LoopState = read_bin(&dir.join("loop.bin"))?;
        let (mut venv, low, high) = cfg.make_envs()?;
        let n = cfg.num_envs;
        let (d, a) = (venv.obs_dim(), venv.act_dim());
        if (agent.obs_dim(), agent.act_dim()) != (d, a) {
            return Err(AgentError::Checkpoint(format!(
                "agent obs/act sizes {}/{} but the env has {d}/{a}",
                agent.obs_dim(),
                agent.act_dim()
            )));
        }
        let ro = &st.rollout;
        let m = ro.len * n;
        let consistent = st.open.len() == n
            && st.episode_index.len() == n
            && st.obs.len() == n
            && ro.len < agent.config().rollout_steps
            && ro.obs.len() == m * d
            && ro.actions.len() == m * a
            && ro.rewards.len() == m
            && ro.terminated.len() == m
            && ro.ended.len() == m
            && ro
                .truncated_obs
                .iter()
                .all(|(k, o)| *k < m && ro.ended[*k] && o.len() == d);
        if !consistent {
            return Err(ckpt_err(
                &dir.join("loop.bin"),
                "loop state does not match num_envs, the env or rollout_steps",
            ));
        }
        venv.reset_scheduled(cfg.seed, &st.episode_index)?;
        for (i, ep) in st.open.iter().enumerate() {
            let o = venv.restore(i, ep.env_actions.clone())?;
            if o != st.obs[i] {
                return Err(AgentError::Checkpoint(format!(
                    "env {i}: rebuilt episode differs from the checkpoint (different \
                     environment build?)"
                )));
            }
        }
        Ok(Self {
            cfg,
            agent,
            venv,
            low,
            high,
            st,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GAE on a 5-step sequence with a termination (t = 1) and a truncation (t = 3), against
    /// values computed by hand with gamma = lambda = 0.5 (gamma lambda = 0.25):
    /// `delta = [1 + .5 - .5, 2 - 1, 3 + 1 - 1.5, 4 + 1.5 - 2, 5 + 2 - 2.5]`
    /// `= [1, 1, 2.5, 3.5, 4.5]`;
    /// `A_4 = 4.5`, `A_3 = 3.5` (episode end), `A_2 = 2.5 + .25 * 3.5 = 3.375`, `A_1 = 1`
    /// (termination: no bootstrap, no carry), `A_0 = 1 + .25 * 1 = 1.25`.
    #[test]
    fn gae_matches_hand_computation() {
        let rewards = [1.0, 2.0, 3.0, 4.0, 5.0];
        let values = [0.5, 1.0, 1.5, 2.0, 2.5];
        // V(s_{t+1}): V(s_1); unused (terminal, 99 must not leak in); V(s_3); V(final obs of
        // the truncated episode) = 3; V(obs after the sequence) = 4.
        let next = [1.0, 99.0, 2.0, 3.0, 4.0];
        let terminated = [false, true, false, false, false];
        let ended = [false, true, false, true, false];
        let adv = gae(&rewards, &values, &next, &terminated, &ended, 0.5, 0.5);
        assert_eq!(adv, vec![1.25, 1.0, 3.375, 3.5, 4.5]);
        // lambda = 0: the one-step TD errors.
        let td = gae(&rewards, &values, &next, &terminated, &ended, 0.5, 0.0);
        assert_eq!(td, vec![1.0, 1.0, 2.5, 3.5, 4.5]);
    }

    /// The rollout layout (`[len, n]`, step-major) feeds each env's own column to [`gae`], the
    /// next step's value of the same env, the post-rollout value at the end and the truncated
    /// episode's last-observation value after a truncation.
    #[test]
    fn rollout_advantages_bootstrap_per_env() {
        // 2 envs x 3 steps. Env 0: truncated at t = 1. Env 1: terminated at t = 0.
        let ro = Rollout {
            len: 3,
            rewards: vec![1.0, 10.0, 2.0, 20.0, 3.0, 30.0],
            terminated: vec![false, true, false, false, false, false],
            ended: vec![false, true, true, false, false, false],
            truncated_obs: vec![(2, vec![0.0])],
            ..Rollout::default()
        };
        let values = [0.1, 1.0, 0.2, 2.0, 0.3, 3.0];
        let (last, trunc) = ([0.4, 4.0], [7.0]);
        let (g, l) = (0.9, 0.8);
        let got = rollout_advantages(&ro, 2, &values, &last, &trunc, g, l);
        let env0 = gae(
            &[1.0, 2.0, 3.0],
            &[0.1, 0.2, 0.3],
            &[0.2, 7.0, 0.4],
            &[false, false, false],
            &[false, true, false],
            g,
            l,
        );
        let env1 = gae(
            &[10.0, 20.0, 30.0],
            &[1.0, 2.0, 3.0],
            &[2.0, 3.0, 4.0],
            &[true, false, false],
            &[true, false, false],
            g,
            l,
        );
        let want: Vec<f64> = (0..3).flat_map(|t| [env0[t], env1[t]]).collect();
        assert_eq!(got, want);
        // Env 0, t = 1 bootstraps from the truncated episode's last observation (7), not from
        // the next episode's first one (0.3).
        assert!((got[2] - (2.0 + 0.9 * 7.0 - 0.2)).abs() < 1e-12);
    }

    /// The beta rule of Schulman et al. 2017 section 4, strict thresholds at 1.5x.
    #[test]
    fn kl_coefficient_adaptation() {
        let (t, f) = (0.01, 2.0);
        assert_eq!(adapt_kl_coef(1.0, 0.02, t, f), 2.0); // > 1.5 target: double
        assert_eq!(adapt_kl_coef(1.0, 0.005, t, f), 0.5); // < target / 1.5: halve
        assert_eq!(adapt_kl_coef(1.0, 0.01, t, f), 1.0); // in between: keep
        assert_eq!(adapt_kl_coef(1.0, 0.015, t, f), 1.0); // exactly at the bounds: keep
        assert_eq!(adapt_kl_coef(1.0, 0.01 / 1.5, t, f), 1.0);
        assert_eq!(adapt_kl_coef(0.5, 1.0, t, 3.0), 1.5);
        assert_eq!(adapt_kl_coef(0.5, 0.0, t, 3.0), 0.5 / 3.0);
    }

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

    fn tiny_cfg() -> PpoConfig {
        PpoConfig {
            hidden: vec![16],
            num_threads: Some(1),
            ..PpoConfig::default()
        }
    }

    /// A one-state bandit batch: actions sampled around the current mean, advantage = +1 for
    /// actions above 0.3 and -1 below. One update phase must move the mean towards the
    /// positive-advantage side, and beta must follow [`adapt_kl_coef`] from the measured KL.
    #[test]
    fn update_moves_the_mean_towards_positive_advantages() {
        let mut agent = PpoAgent::new(tiny_cfg(), 2, 1, 3).unwrap();
        let o = [0.5f32, -0.5];
        let before = agent.policy_mean(&o)[0];
        let mut rng = NpRng::from_seed(1);
        let n = 256;
        let obs: Vec<f32> = o.iter().copied().cycle().take(2 * n).collect();
        let actions = agent.sample(&obs, &mut rng);
        let advantages: Vec<f32> = actions
            .iter()
            .map(|&a| if a > 0.3 { 1.0 } else { -1.0 })
            .collect();
        let batch = PpoBatch {
            obs,
            actions,
            returns: advantages.clone(),
            advantages,
        };
        let beta = agent.kl_coef();
        let stats = agent.update(&batch, &mut rng).unwrap();
        let after = agent.policy_mean(&o)[0];
        assert!(
            after > before + 0.05,
            "mean {before} -> {after} did not move towards the positive advantages"
        );
        assert!(stats.kl > 0.0 && stats.kl.is_finite());
        assert_eq!(stats.minibatches, 10 * 4);
        assert_eq!(stats.kl_coef, beta);
        assert_eq!(
            agent.kl_coef(),
            adapt_kl_coef(beta, stats.kl, 0.01, 2.0),
            "kl {}",
            stats.kl
        );
        assert_eq!(agent.updates(), 1);
        // A malformed batch is an error, not a panic.
        let mut bad = batch.clone();
        bad.returns.pop();
        assert!(matches!(
            agent.update(&bad, &mut rng),
            Err(AgentError::Shape(_))
        ));
    }

    /// Learning on a contextual bandit through the agent's own sampling and update: the
    /// observation is `x` uniform in `[-1, 1]`, the reward `-(a - 0.8 x)^2` (best action
    /// `0.8 x`), the advantage the reward minus the value prediction. After 30 phases of 256
    /// samples the deterministic policy's mean squared error must have dropped to a fraction
    /// of the initial one. This exercises sampling, log-probabilities, the ratio, the KL
    /// penalty and the value baseline together, in about a second.
    #[test]
    fn learns_a_contextual_bandit() {
        let cfg = PpoConfig {
            lr_policy: 3e-3,
            lr_value: 3e-3,
            ..tiny_cfg()
        };
        let mut agent = PpoAgent::new(cfg, 1, 1, 5).unwrap();
        let mut rng = NpRng::from_seed(9);
        let test_x: Vec<f32> = (0..21).map(|k| -1.0 + 0.1 * k as f32).collect();
        let mse = |agent: &PpoAgent| {
            let a = agent.act_deterministic(&test_x);
            a.iter()
                .zip(&test_x)
                .map(|(a, x)| f64::from((a - 0.8 * x).powi(2)))
                .sum::<f64>()
                / test_x.len() as f64
        };
        let start = mse(&agent);
        for _ in 0..30 {
            let obs: Vec<f32> = (0..256).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
            let actions = agent.sample(&obs, &mut rng);
            let v = agent.values(&obs);
            let rewards: Vec<f32> = actions
                .iter()
                .zip(&obs)
                .map(|(a, x)| -(a.clamp(-1.0, 1.0) - 0.8 * x).powi(2))
                .collect();
            let batch = PpoBatch {
                advantages: rewards.iter().zip(&v).map(|(r, v)| r - v).collect(),
                returns: rewards,
                obs,
                actions,
            };
            agent.update(&batch, &mut rng).unwrap();
        }
        let end = mse(&agent);
        eprintln!(
            "bandit mse {start:.4} -> {end:.4}, beta {}",
            agent.kl_coef()
        );
        assert!(end < 0.25 * start && end < 0.03, "mse {start} -> {end}");
    }

    #[test]
    fn agent_save_load_round_trip_and_errors() {
        let dir = std::env::temp_dir().join(format!("rdpg-ppo-agent-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut agent = PpoAgent::new(tiny_cfg(), 3, 2, 4).unwrap();
        let mut rng = NpRng::from_seed(0);
        let obs: Vec<f32> = (0..30).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
        let actions = agent.sample(&obs, &mut rng);
        let batch = PpoBatch {
            advantages: (0..10).map(|k| k as f32 - 4.5).collect(),
            returns: vec![1.0; 10],
            obs: obs.clone(),
            actions,
        };
        agent.update(&batch, &mut rng).unwrap();
        agent.save(&dir).unwrap();
        let mut back = PpoAgent::load(&dir).unwrap();
        assert_eq!(back.weights(), agent.weights());
        assert_eq!(back.kl_coef(), agent.kl_coef());
        assert_eq!(back.updates(), 1);
        // The optimiser moments came back too: the next update is identical.
        let (mut r1, mut r2) = (rng.clone(), rng);
        let s1 = agent.update(&batch, &mut r1).unwrap();
        let s2 = back.update(&batch, &mut r2).unwrap();
        assert_eq!(s1, s2);
        assert_eq!(back.weights(), agent.weights());

        // Corrupt and missing files give checkpoint errors naming the file.
        std::fs::write(dir.join("optim.safetensors"), b"not a safetensors file").unwrap();
        match PpoAgent::load(&dir) {
            Err(AgentError::Checkpoint(m)) => assert!(m.contains("optim.safetensors"), "{m}"),
            other => panic!("{other:?}"),
        }
        std::fs::remove_file(dir.join("weights.safetensors")).unwrap();
        match PpoAgent::load(&dir) {
            Err(AgentError::Checkpoint(m)) => assert!(m.contains("weights.safetensors"), "{m}"),
            other => panic!("{other:?}"),
        }
        std::fs::write(dir.join("agent.json"), b"{").unwrap();
        assert!(matches!(
            PpoAgent::load(&dir),
            Err(AgentError::Checkpoint(_))
        ));
        assert!(matches!(
            PpoAgent::load(dir.join("nowhere")),
            Err(AgentError::Checkpoint(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
