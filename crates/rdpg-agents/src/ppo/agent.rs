//! Proximal policy optimisation with an adaptive KL penalty: the PPO baseline of the paper's
//! Table I ("PPO with an adaptive KL penalty, feed-forward, GAE").
//!
//! * [`PpoConfig`]: hyper-parameters (serde, validated).
//! * [`PpoAgent`]: a Gaussian policy `N(mu(o), diag(sigma^2))` (tanh MLP mean, state-independent
//!   learned `log sigma`) and a separate tanh MLP value function; the update of one PPO phase on
//!   a [`PpoBatch`] ([`PpoAgent::update`]); checkpoints with optimiser moments.
//! * [`PpoTrainer`](super::PpoTrainer): the on-policy loop, a [`crate::Trainer`].
//! * [`gae`](super::gae::gae) and [`adapt_kl_coef`]: the arithmetic outside the networks, as
//!   pure functions.
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
//!    from; terminal states are not), and returns `R_t = A_t + V(s_t)` ([`gae`](super::gae::gae)).
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

use std::path::Path;

use rdpg_core::rng::NpRng;
use serde::{Deserialize, Serialize};
use tch::nn::{self, VarStore};
use tch::{Device, Kind, Tensor};

use super::config::PpoConfig;
use super::gae::adapt_kl_coef;
use crate::common::adam::{Adam, AdamConfig};
use crate::common::checkpoint::{
    check_sizes_against, ckpt_err, read_json, read_tensors, restore_vars, write_json,
    write_tensors, SEALED_AGENT_FORMAT,
};
use crate::common::tensor::{
    init_from_rng, resolve_device, tensor_to_vec, tensor_to_vec64, vars_with_prefix, Activation,
    Mlp,
};
use crate::common::{DeterministicPolicy, UpdateStats};
use crate::error::{AgentError, Result};

/// Adam's `beta1`, `beta2` and `eps` for both networks (the values of OpenAI's PPO baselines).
const ADAM: (f64, f64, f64) = (0.9, 0.999, 1e-5);

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
    /// Wall-clock seconds of the phase.
    pub seconds: f64,
}

impl From<PpoStats> for UpdateStats {
    /// The trainer-facing summary: `critic_loss` is the value loss, `actor_loss` the policy
    /// loss (KL term included), `q_mean` the mean value prediction.
    fn from(s: PpoStats) -> Self {
        UpdateStats {
            critic_loss: s.value_loss,
            actor_loss: Some(s.policy_loss),
            q_mean: s.value_mean,
            injected_share: 0.0,
            seconds: s.seconds,
            extra: Default::default(),
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

/// The format written: [`SEALED_AGENT_FORMAT`] (format 1 agents load too).
const AGENT_FORMAT: u32 = SEALED_AGENT_FORMAT;

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
            crate::common::tensor::set_num_threads(n);
        }
        let device = resolve_device(cfg.device)?;
        let vs = VarStore::new(device);
        let root = vs.root();
        let policy = Mlp::new(
            &(&root / "policy"),
            obs_dim,
            &cfg.hidden,
            "l",
            Some(act_dim),
            Activation::Tanh,
        );
        let mut log_std =
            (&root / "policy").var("log_std", &[act_dim as i64], nn::Init::Const(0.0));
        let value = Mlp::new(
            &(&root / "value"),
            obs_dim,
            &cfg.hidden,
            "l",
            Some(1),
            Activation::Tanh,
        );
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
            obs.len().is_multiple_of(self.obs_dim),
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
        let started = std::time::Instant::now();
        crate::common::tensor::set_flush_denormal(true);
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
            seconds: started.elapsed().as_secs_f64(),
        })
    }

    /// All weights (log std included) flattened to f64, by name (sorted); for tests and
    /// diagnostics.
    pub fn weights(&self) -> Vec<(String, Vec<f64>)> {
        vars_with_prefix(&self.vs, "")
            .into_iter()
            .map(|(n, t)| (n, tensor_to_vec64(&t)))
            .collect()
    }

    /// Writes the networks (`weights.safetensors`), the optimiser moments
    /// (`optim.safetensors`) and the config, sizes, seed, beta and update count (`agent.json`)
    /// to `dir`. [`PpoAgent::load`] continues bit-identically.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| ckpt_err(dir, e))?;
        write_tensors(
            &dir.join("weights.safetensors"),
            &vars_with_prefix(&self.vs, ""),
        )?;
        let mut optim = self.policy_opt.state("policy_opt.");
        optim.extend(self.value_opt.state("value_opt."));
        write_tensors(&dir.join("optim.safetensors"), &optim)?;
        let meta = AgentMeta {
            format: AGENT_FORMAT,
            config: self.cfg.clone(),
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            seed: self.seed,
            kl_coef: self.kl_coef,
            updates: self.updates,
        };
        write_json(&dir.join("agent.json"), &meta)?;
        crate::common::checkpoint::seal(dir)
    }

    /// Restores an agent written by [`PpoAgent::save`]. Missing, truncated or inconsistent files
    /// give an [`AgentError::Checkpoint`] naming the file.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_impl(dir.as_ref(), true)
    }

    /// The networks of an agent written by [`PpoAgent::save`], without its optimiser state
    /// (a shipped agent holds none): for acting or evaluating.
    pub fn load_weights(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_impl(dir.as_ref(), false)
    }

    fn load_impl(dir: &Path, with_optim: bool) -> Result<Self> {
        let meta_path = dir.join("agent.json");
        let meta: AgentMeta = read_json(&meta_path)?;
        if !(1..=AGENT_FORMAT).contains(&meta.format) {
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
        // Before any network is built: the policy and value MLPs and log_std, counted.
        let mlp = |out: usize| {
            let mut i = meta.obs_dim as f64;
            let mut n = 0.0;
            for &h in meta.config.hidden.iter().chain([&out]) {
                n += i * h as f64 + h as f64;
                i = h as f64;
            }
            n
        };
        let expected = mlp(meta.act_dim) + meta.act_dim as f64 + mlp(1);
        check_sizes_against(&dir.join("weights.safetensors"), &meta_path, expected)?;
        let mut agent = Self::new(meta.config, meta.obs_dim, meta.act_dim, meta.seed)?;
        let weights = read_tensors(&dir.join("weights.safetensors"))?;
        if let Some((name, t)) = weights.iter().find(|(_, t)| t.kind() != Kind::Float) {
            return Err(ckpt_err(
                &dir.join("weights.safetensors"),
                format!("weight `{name}` is {:?}, expected Float", t.kind()),
            ));
        }
        restore_vars(&agent.vs, &weights, "")?;
        if with_optim {
            let optim = read_tensors(&dir.join("optim.safetensors"))?;
            agent.policy_opt.load_state("policy_opt.", &optim)?;
            agent.value_opt.load_state("value_opt.", &optim)?;
        }
        crate::common::checkpoint::check_counter(&meta_path, "updates", meta.updates)?;
        if !(crate::common::config::is_f32(meta.kl_coef) && meta.kl_coef >= 0.0) {
            return Err(ckpt_err(
                &meta_path,
                format!("kl_coef {} is not a finite number >= 0", meta.kl_coef),
            ));
        }
        agent.kl_coef = meta.kl_coef;
        agent.updates = meta.updates;
        Ok(agent)
    }
}

impl DeterministicPolicy for PpoAgent {
    /// Feed-forward: nothing to reset.
    fn begin_episode(&mut self) {}
    /// The policy mean clamped to `[-1, 1]`.
    fn act(&mut self, obs: &[f32]) -> Result<Vec<f32>> {
        if obs.len() != self.obs_dim {
            return Err(AgentError::Shape(format!(
                "act: {} observation values, expected obs_dim {}",
                obs.len(),
                self.obs_dim
            )));
        }
        if let Some(k) = obs.iter().position(|x| !x.is_finite()) {
            return Err(AgentError::Input(format!(
                "observation component {k} is {}",
                obs[k]
            )));
        }
        crate::common::policy::check_action_finite(
            self.act_deterministic(obs),
            "the policy's mean action",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let untimed = |s: PpoStats| PpoStats { seconds: 0.0, ..s };
        let s1 = untimed(agent.update(&batch, &mut r1).unwrap());
        let s2 = untimed(back.update(&batch, &mut r2).unwrap());
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
