//! The RDPG learner: acting, the update of Algorithm 1, checkpoints.
//!
//! # The update, top to bottom
//!
//! A [`SequenceBatch`] holds `N` windows; window `n` has `scan_len[n] <= s` real scan steps
//! (left-padded), `len_n = opt_len[n] <= l` real optimisation steps (right-padded) and the
//! bootstrap ("tail") observation `o_tail` right after its last real step.
//!
//! 1. **Scan** (paper Eq. (scan)): `h_{-1} = f((o_t, a_t)_{t = -scan_len..-1} | h_init)` for the
//!    actor (observations) and the critic (observation-action pairs), without gradient, from
//!    `h_init = 0` (or the acting-time state stored in the replay, actor only). Padding never
//!    touches the state ([`scan_state`]).
//! 2. **Critic** (paper Eq. (unsyncedinterpolatedTD), Algorithm 1 line "Get TD gradient"): the
//!    tail-step bootstrap
//!    `y_i = sum_{k=i}^{len-1} gamma^{k-i} r_k + gamma^{len-i} Q'(o_tail, mu'(o_tail)) (1 - term)`,
//!    i.e. every step bootstraps from the single Q at the window's tail (`^{(l-i)}TD_i`);
//!    `Q'`, `mu'` are the target networks when `tau > 0`, else the behaviour networks without
//!    gradient; both run along the window from their scanned states. Loss:
//!    `1/N sum_n sum_{i < min(u, len_n)} w_i (y_i - Q(o_i, a_i | h_{i-1}))^2` with
//!    `w_i = lambda^i / sum_{j<u} lambda^j` (uniform for `lambda = 1`; the same for every
//!    window, not renormalised for short windows: `rdpg_core::targets`); the critic is
//!    back-propagated through time over the window (the "optimisation length"). Adam with L2.
//! 3. **Actor** (paper Eq. (DPG), Algorithm 1 line "Get Actor gradient"):
//!    `J = -1/N sum_n 1/len_n sum_{i < len_n} Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})`. Without
//!    BPTT (paper Section III-A.3, the default) the actor state `h^A_{i-1}` fed to step `i` is a
//!    constant: the actor is run along the window without gradient to get the states, then every
//!    step is recomputed from its detached previous state in one batched call over `N * l`.
//!    The critic states `h^C_{i-1}` come from the critic's scan and its run along the replayed
//!    actions (after the critic's Adam step by default, as Algorithm 1 orders it).
//! 4. **Targets**: `theta' <- theta' + tau (theta - theta')` when `tau > 0`.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use rdpg_core::rng::NpRng;
use rdpg_core::targets::interpolated_td_weights_padded;
use rdpg_core::SequenceBatch;
use serde::{Deserialize, Serialize};
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use crate::adam::{Adam, AdamConfig};
use crate::config::{DeviceSpec, RdpgConfig, ScanMethod};
use crate::error::{AgentError, Result};
use crate::nets::{init_from_rng, Actor, Core, Critic, RecState};

// ---------------------------------------------------------------------------------------------
// Public value types
// ---------------------------------------------------------------------------------------------

/// Losses of one update.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct UpdateStats {
    /// Critic loss (weighted squared TD error; the sum over both critics when twin).
    pub critic_loss: f64,
    /// Actor loss `-Q(o, mu(o))` averaged over real steps.
    pub actor_loss: f64,
    /// Mean `Q(o_i, a_i)` of the (first) critic over the real optimisation steps.
    pub q_mean: f64,
}

/// Wall-clock seconds spent in each phase of the updates since profiling was switched on
/// (meaningful on the CPU, where libtorch runs synchronously).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PhaseTimes {
    /// Updates measured.
    pub updates: u64,
    /// Batch upload and index tensors.
    pub prepare: f64,
    /// The no-gradient scans of step 1 (all networks, target networks included).
    pub scan: f64,
    /// No-gradient runs along the window: tail action, actor states, target critics.
    pub window_nograd: f64,
    /// Critic forward with gradient, backward, clipping and Adam step.
    pub critic_step: f64,
    /// The critic rescan and state run after its step (`actor_uses_updated_critic`).
    pub critic_rescan: f64,
    /// Actor forward, backward and Adam step.
    pub actor_step: f64,
    /// Soft target update and statistics.
    pub other: f64,
}

/// The recurrent state of the actor for a batch of environments, carried between
/// [`RdpgAgent::act`] calls. Feed-forward agents carry an empty (zero-width) state.
#[derive(Debug)]
pub struct ActorState {
    state: RecState,
    n_envs: usize,
    hidden: usize,
}

impl ActorState {
    /// Number of environments.
    pub fn n_envs(&self) -> usize {
        self.n_envs
    }

    /// Size of one environment's state as stored in the replay (`2 * hidden`: `h` then `c`).
    pub fn state_dim(&self) -> usize {
        2 * self.hidden
    }

    /// Zeroes every environment's state.
    pub fn reset(&mut self) {
        tch::no_grad(|| {
            let _ = self.state.h.zero_();
            let _ = self.state.c.zero_();
        });
    }

    /// Zeroes environment `env`'s state (call when its episode ends).
    pub fn reset_env(&mut self, env: usize) {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        tch::no_grad(|| {
            let _ = self.state.h.select(1, env as i64).zero_();
            let _ = self.state.c.select(1, env as i64).zero_();
        });
    }

    /// Environment `env`'s state, `[h (hidden), c (hidden)]`: what the replay stores as the
    /// acting-time state of a step (take it *before* acting on that step).
    pub fn env_state(&self, env: usize) -> Vec<f32> {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        let hc = Tensor::cat(
            &[
                self.state.h.select(1, env as i64),
                self.state.c.select(1, env as i64),
            ],
            1,
        );
        tensor_to_vec(&hc)
    }

    /// All states, `[n_envs, 2 * hidden]` row-major (`h` then `c` per environment).
    pub fn to_vec(&self) -> Vec<f32> {
        tensor_to_vec(&Tensor::cat(
            &[self.state.h.squeeze_dim(0), self.state.c.squeeze_dim(0)],
            1,
        ))
    }

    /// Overwrites environment `env`'s state with `[h, c]` (`2 * hidden` values), e.g. the
    /// random Gaussian start the authors' code used when acting.
    pub fn set_env_state(&mut self, env: usize, hc: &[f32]) {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        assert_eq!(hc.len(), 2 * self.hidden, "state size");
        let h = self.hidden as i64;
        let t = Tensor::from_slice(hc)
            .to_kind(self.state.h.kind())
            .to_device(self.state.h.device());
        tch::no_grad(|| {
            self.state
                .h
                .select(1, env as i64)
                .squeeze_dim(0)
                .copy_(&t.narrow(0, 0, h));
            self.state
                .c
                .select(1, env as i64)
                .squeeze_dim(0)
                .copy_(&t.narrow(0, h, h));
        });
    }
}

// ---------------------------------------------------------------------------------------------
// The agent
// ---------------------------------------------------------------------------------------------

/// Target copies of the networks (only when `tau > 0`).
struct Targets {
    actor_vs: VarStore,
    actor: Actor,
    critic_vs: Vec<VarStore>,
    critics: Vec<Critic>,
    /// (target variable, online variable) pairs for the soft update.
    pairs: Vec<(Tensor, Tensor)>,
}

/// Recurrent deterministic policy gradient agent (or feed-forward DDPG when
/// `config.recurrent` is false).
pub struct RdpgAgent {
    cfg: RdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    seed: u64,
    device: Device,
    kind: Kind,
    actor_vs: VarStore,
    actor: Actor,
    critic_vs: Vec<VarStore>,
    critics: Vec<Critic>,
    targets: Option<Targets>,
    actor_opt: Adam,
    critic_opt: Adam,
    rng: NpRng,
    updates: u64,
    profile: Option<PhaseTimes>,
    /// A copy of the actor with perturbed parameters that [`RdpgAgent::act`] uses instead of
    /// the actor (parameter-space exploration); not trained, not checkpointed.
    acting: Option<(VarStore, Actor)>,
}

impl std::fmt::Debug for RdpgAgent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RdpgAgent")
            .field("obs_dim", &self.obs_dim)
            .field("act_dim", &self.act_dim)
            .field("device", &self.device)
            .field("updates", &self.updates)
            .finish_non_exhaustive()
    }
}

/// The tch device of a [`DeviceSpec`]; `cuda` without a CUDA device is an error.
pub(crate) fn resolve_device(spec: DeviceSpec) -> Result<Device> {
    match spec {
        DeviceSpec::Cpu => Ok(Device::Cpu),
        DeviceSpec::Cuda => {
            if tch::Cuda::is_available() {
                Ok(Device::Cuda(0))
            } else {
                Err(AgentError::Device(
                    "device \"cuda\" requested but libtorch sees no CUDA device (is the binary \
                     linked with libtorch_cuda?)"
                        .into(),
                ))
            }
        }
        DeviceSpec::Auto => Ok(Device::cuda_if_available()),
    }
}

/// Variables of a var store as (name, tensor), sorted by name (a stable order).
pub(crate) fn sorted_vars(vs: &VarStore) -> Vec<(String, Tensor)> {
    let mut v: Vec<_> = vs.variables().into_iter().collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// A tensor's values as `f32`, flattened row-major (copied to the CPU).
pub(crate) fn tensor_to_vec(t: &Tensor) -> Vec<f32> {
    let t = t
        .detach()
        .to_kind(Kind::Float)
        .to_device(Device::Cpu)
        .contiguous()
        .view([-1]);
    Vec::<f32>::try_from(&t).expect("tensor to Vec<f32>")
}

/// Metadata written next to the weights by [`RdpgAgent::save`].
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CheckpointMeta {
    format: u32,
    config: RdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    seed: u64,
    double: bool,
    updates: u64,
    rng: NpRng,
}

const CHECKPOINT_FORMAT: u32 = 1;

impl RdpgAgent {
    /// A new agent with freshly initialised networks (f32). `seed` seeds the agent's own
    /// [`NpRng`], which draws the initial weights ([`init_from_rng`]: independent of libtorch's
    /// process-wide generator) and then the target policy noise.
    pub fn new(cfg: RdpgConfig, obs_dim: usize, act_dim: usize, seed: u64) -> Result<Self> {
        Self::new_with_kind(cfg, obs_dim, act_dim, seed, Kind::Float)
    }

    /// Like [`RdpgAgent::new`] with a chosen floating-point kind (`Kind::Double` for gradient
    /// checks).
    pub fn new_with_kind(
        cfg: RdpgConfig,
        obs_dim: usize,
        act_dim: usize,
        seed: u64,
        kind: Kind,
    ) -> Result<Self> {
        cfg.validate()?;
        cfg.check_dims(obs_dim, act_dim)?;
        if !matches!(kind, Kind::Float | Kind::Double) {
            return Err(AgentError::Config {
                field: "kind",
                reason: "Float or Double".into(),
            });
        }
        if let Some(n) = cfg.num_threads {
            tch::set_num_threads(n as i32);
        }
        let device = resolve_device(cfg.device)?;
        let (d, a) = (obs_dim as i64, act_dim as i64);
        let n_critics = if cfg.twin_critic { 2 } else { 1 };
        let critic_name = |i: usize| {
            if i == 0 {
                "critic".to_string()
            } else {
                format!("critic{}", i + 1)
            }
        };

        let mut rng = NpRng::from_seed(seed);
        let mut build = |device, init: bool| {
            let mut actor_vs = VarStore::new(device);
            let actor = Actor::new(&(actor_vs.root() / "actor"), &cfg, d, a);
            let mut critic_vs = Vec::new();
            let mut critics = Vec::new();
            for i in 0..n_critics {
                let mut vs = VarStore::new(device);
                critics.push(Critic::new(&(vs.root() / critic_name(i)), &cfg, d, a));
                if kind == Kind::Double {
                    vs.double();
                }
                critic_vs.push(vs);
            }
            if kind == Kind::Double {
                actor_vs.double();
            }
            if init {
                init_from_rng(&actor_vs, &mut rng);
                for vs in &critic_vs {
                    init_from_rng(vs, &mut rng);
                }
            }
            (actor_vs, actor, critic_vs, critics)
        };
        let (actor_vs, actor, critic_vs, critics) = build(device, true);
        let targets = if cfg.tau > 0.0 {
            let (mut t_actor_vs, t_actor, mut t_critic_vs, t_critics) = build(device, false);
            t_actor_vs.copy(&actor_vs)?;
            for (t, s) in t_critic_vs.iter_mut().zip(&critic_vs) {
                t.copy(s)?;
            }
            let mut pairs = Vec::new();
            let mut push = |t: &VarStore, s: &VarStore| {
                let sv = s.variables();
                for (name, tv) in sorted_vars(t) {
                    pairs.push((tv, sv[&name].shallow_clone()));
                }
            };
            push(&t_actor_vs, &actor_vs);
            for (t, s) in t_critic_vs.iter().zip(&critic_vs) {
                push(t, s);
            }
            // Target networks never need gradients.
            t_actor_vs.freeze();
            for vs in &mut t_critic_vs {
                vs.freeze();
            }
            Some(Targets {
                actor_vs: t_actor_vs,
                actor: t_actor,
                critic_vs: t_critic_vs,
                critics: t_critics,
                pairs,
            })
        } else {
            None
        };

        let adam = |lr, wd| AdamConfig {
            lr,
            beta1: cfg.adam_beta1,
            beta2: cfg.adam_beta2,
            eps: cfg.adam_eps,
            weight_decay: wd,
        };
        let actor_opt = Adam::new(adam(cfg.lr_actor, 0.0), sorted_vars(&actor_vs));
        let critic_params: Vec<_> = critic_vs.iter().flat_map(sorted_vars).collect();
        let critic_opt = Adam::new(adam(cfg.lr_critic, cfg.critic_l2), critic_params);

        Ok(Self {
            rng,
            cfg,
            obs_dim,
            act_dim,
            seed,
            device,
            kind,
            actor_vs,
            actor,
            critic_vs,
            critics,
            targets,
            actor_opt,
            critic_opt,
            updates: 0,
            profile: None,
            acting: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &RdpgConfig {
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

    /// Number of updates performed (restored by [`RdpgAgent::load`]).
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Size of one stored acting-time state (`2 * actor_hidden`, 0 for feed-forward agents):
    /// the `state_dim` a replay storing states must use.
    pub fn state_dim(&self) -> usize {
        2 * self.actor.core.state_width() as usize
    }

    /// The actor network.
    pub fn actor(&self) -> &Actor {
        &self.actor
    }

    /// The critic networks (one, or two when `twin_critic`).
    pub fn critics(&self) -> &[Critic] {
        &self.critics
    }

    /// A zero actor state for `n_envs` environments.
    pub fn initial_state(&self, n_envs: usize) -> ActorState {
        let hidden = self.actor.core.state_width();
        ActorState {
            state: RecState::zeros(n_envs as i64, hidden, self.kind, self.device),
            n_envs,
            hidden: hidden as usize,
        }
    }

    /// Zeroes the state of environment `env` (`None`: all environments), at an episode start.
    pub fn reset_state(&self, state: &mut ActorState, env: Option<usize>) {
        match env {
            Some(e) => state.reset_env(e),
            None => state.reset(),
        }
    }

    /// Deterministic actions `mu(o_t | h_{t-1})` for a batch of environments: `obs` is
    /// `[n_envs, obs_dim]` row-major, the result `[n_envs, act_dim]` in `[-1, 1]`; `state`
    /// advances by one step. Exploration noise is the caller's business; after
    /// [`RdpgAgent::set_acting_params`] the perturbed copy of the actor acts.
    ///
    /// # Panics
    /// If `obs.len() != state.n_envs() * obs_dim`.
    pub fn act(&mut self, obs: &[f32], state: &mut ActorState) -> Vec<f32> {
        let actor = self.acting.as_ref().map_or(&self.actor, |(_, a)| a);
        self.act_with(actor, obs, state)
    }

    /// Like [`RdpgAgent::act`] but always with the trained actor, ignoring
    /// [`RdpgAgent::set_acting_params`] (e.g. to measure the action distance that adapts
    /// parameter noise, or to evaluate).
    ///
    /// # Panics
    /// If `obs.len() != state.n_envs() * obs_dim`.
    pub fn act_unperturbed(&mut self, obs: &[f32], state: &mut ActorState) -> Vec<f32> {
        self.act_with(&self.actor, obs, state)
    }

    fn act_with(&self, actor: &Actor, obs: &[f32], state: &mut ActorState) -> Vec<f32> {
        let n = state.n_envs;
        assert_eq!(
            obs.len(),
            n * self.obs_dim,
            "act: obs has {} values, expected n_envs {n} x obs_dim {}",
            obs.len(),
            self.obs_dim
        );
        let a = tch::no_grad(|| {
            let o = Tensor::from_slice(obs)
                .view([n as i64, self.obs_dim as i64])
                .to_kind(self.kind)
                .to_device(self.device);
            let (a, s) = actor.step(&o, &state.state);
            state.state = s;
            a
        });
        tensor_to_vec(&a)
    }

    /// Number of actor parameters (the length of [`RdpgAgent::actor_params`]).
    pub fn actor_param_count(&self) -> usize {
        sorted_vars(&self.actor_vs)
            .iter()
            .map(|(_, t)| t.numel())
            .sum()
    }

    /// The actor's parameters as one vector: variables in name order, each row-major. The
    /// layout `rdpg_core::noise::AdaptiveParamNoise::perturb` works on.
    pub fn actor_params(&self) -> Vec<f32> {
        sorted_vars(&self.actor_vs)
            .iter()
            .flat_map(|(_, t)| tensor_to_vec(t))
            .collect()
    }

    /// Parameter-space exploration (paper Sec. II-B, Plappert et al. 2018): from now on
    /// [`RdpgAgent::act`] uses a copy of the actor with these parameters (layout of
    /// [`RdpgAgent::actor_params`], e.g. perturbed by
    /// `rdpg_core::noise::AdaptiveParamNoise::perturb`); `None` acts with the trained actor
    /// again. The copy is neither trained nor checkpointed: perturb again after updates.
    pub fn set_acting_params(&mut self, params: Option<&[f32]>) -> Result<()> {
        let Some(params) = params else {
            self.acting = None;
            return Ok(());
        };
        if params.len() != self.actor_param_count() {
            return Err(AgentError::Shape(format!(
                "acting params: {} values, the actor has {}",
                params.len(),
                self.actor_param_count()
            )));
        }
        if self.acting.is_none() {
            let mut vs = VarStore::new(self.device);
            let actor = Actor::new(
                &(vs.root() / "actor"),
                &self.cfg,
                self.obs_dim as i64,
                self.act_dim as i64,
            );
            if self.kind == Kind::Double {
                vs.double();
            }
            vs.freeze();
            self.acting = Some((vs, actor));
        }
        let (vs, _) = self.acting.as_ref().expect("acting actor");
        let mut offset = 0;
        for (_, mut var) in sorted_vars(vs) {
            let k = var.numel();
            let src = Tensor::from_slice(&params[offset..offset + k])
                .view(var.size().as_slice())
                .to_kind(self.kind)
                .to_device(self.device);
            tch::no_grad(|| var.copy_(&src));
            offset += k;
        }
        Ok(())
    }

    /// Checks a batch against this agent (sizes, lengths, mask, stored state).
    pub fn check_batch(&self, b: &SequenceBatch) -> Result<()> {
        let err = |m: String| Err(AgentError::Shape(m));
        let t = b.scan + b.opt;
        if b.obs_dim != self.obs_dim || b.act_dim != self.act_dim {
            return err(format!(
                "batch obs/act dims {}/{} but agent {}/{}",
                b.obs_dim, b.act_dim, self.obs_dim, self.act_dim
            ));
        }
        if b.n == 0 || b.opt == 0 {
            return err("batch needs n >= 1 and opt >= 1".into());
        }
        if b.obs.len() != b.n * (t + 1) * b.obs_dim
            || b.actions.len() != b.n * t * b.act_dim
            || b.rewards.len() != b.n * t
            || b.mask.len() != b.n * t
            || b.scan_len.len() != b.n
            || b.opt_len.len() != b.n
            || b.tail_terminated.len() != b.n
        {
            return err("batch array lengths do not match n, scan, opt, dims".into());
        }
        for i in 0..b.n {
            let (k, len) = (b.scan_len[i], b.opt_len[i]);
            if k > b.scan || len == 0 || len > b.opt {
                return err(format!(
                    "window {i}: scan_len {k} / opt_len {len} out of range"
                ));
            }
            for j in 0..t {
                let real = if j < b.scan {
                    j >= b.scan - k
                } else {
                    j - b.scan < len
                };
                if (b.mask[i * t + j] != 0.0) != real {
                    return err(format!(
                        "window {i}: mask at step {j} disagrees with lengths"
                    ));
                }
            }
        }
        if self.cfg.burn_in_from_stored_state && b.scan > 0 {
            match &b.stored_state {
                Some(s) if b.state_dim == self.state_dim() && s.len() == b.n * b.state_dim => {}
                _ => {
                    return err(format!(
                        "burn_in_from_stored_state needs stored states of size {}",
                        self.state_dim()
                    ))
                }
            }
        }
        Ok(())
    }

    /// Switches per-phase timing on (resetting it) or off.
    pub fn set_profiling(&mut self, on: bool) {
        self.profile = on.then(PhaseTimes::default);
    }

    /// The per-phase timings accumulated since profiling was switched on.
    pub fn profile(&self) -> Option<PhaseTimes> {
        self.profile
    }

    /// One RDPG update (Algorithm 1, `Update`) on `batch`. See the module docs for the steps.
    ///
    /// # Panics
    /// If the batch does not fit the agent ([`RdpgAgent::check_batch`] fails).
    pub fn update(&mut self, batch: &SequenceBatch) -> UpdateStats {
        if let Err(e) = self.check_batch(batch) {
            panic!("RdpgAgent::update: {e}");
        }
        if self.cfg.flush_denormal {
            crate::set_flush_denormal(true);
        }
        let mut clock = Clock::new(self.profile.is_some());
        let p = self.prepare(batch);
        clock.lap(|t| &mut t.prepare);

        // ---- 1. Scan: h_{-1} for every network, no gradient (paper Eq. (scan)). -------------
        let sc = tch::no_grad(|| self.scan_all(&p));
        clock.lap(|t| &mut t.scan);

        // ---- 2a. Along the window without gradient: the behaviour actor's states (for the
        // per-step actor gradient) and the bootstrap action mu'(o_tail) (+ smoothing noise);
        // with target networks also Q'(o_tail, mu'(o_tail)). -----------------------------------
        let (actor_states, mut a_tail) = tch::no_grad(|| self.actor_window(&p, &sc));
        if let Some(noise) = self.cfg.target_noise {
            a_tail = self.smooth_target_action(&a_tail, noise.std, noise.clip);
        }
        let target_q_tail = tch::no_grad(|| self.target_tail_q(&p, &sc, &a_tail));
        clock.lap(|t| &mut t.window_nograd);

        // ---- 2b. Critic: tail-step bootstrap of the interpolated TD (Eq. (unsynced...)). ---
        let (q_sa, q_tail) = self.critic_forward(&p, &sc, &a_tail, target_q_tail);
        let y = tch::no_grad(|| td_targets(&p, &q_tail)); // [N, l]
        let critic_loss = q_sa
            .iter()
            .map(|q| critic_loss_from(&p, q, &y))
            .reduce(|a, b| a + b)
            .expect("at least one critic");
        self.critic_opt.zero_grad();
        critic_loss.backward();
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.critic_opt.clip_grad_norm(c);
        }
        let updated_critic = self.cfg.actor_uses_updated_critic;
        // Critic states h^C_{i-1} along the window for the actor loss: from the pre-update
        // critic, or (Algorithm 1 order) rescanned after its Adam step.
        let critic_states_old =
            (!updated_critic).then(|| tch::no_grad(|| self.critic_states(&p, &sc.critics[0])));
        if updated_critic {
            self.critic_opt.step();
        }
        clock.lap(|t| &mut t.critic_step);

        // ---- 3. Actor: deterministic policy gradient (Eq. (DPG)), no BPTT by default. ------
        let critic_states = match critic_states_old {
            Some(s) => s,
            None => tch::no_grad(|| {
                let h = self.scan_critic(&self.critics[0], &p);
                self.critic_states(&p, &h)
            }),
        };
        clock.lap(|t| &mut t.critic_rescan);
        let actor_in = match &actor_states {
            Some((hb, cb)) => ActorInput::Detached { h: hb, c: cb },
            None => ActorInput::Bptt { h0: &sc.actor },
        };
        // The critic is a constant here: no gradients are computed or accumulated for it.
        for vs in &mut self.critic_vs {
            vs.freeze();
        }
        let actor_loss = actor_loss(&self.actor, &self.critics[0], &p, actor_in, &critic_states);
        self.actor_opt.zero_grad();
        actor_loss.backward();
        for vs in &mut self.critic_vs {
            vs.unfreeze();
        }
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.actor_opt.clip_grad_norm(c);
        }
        if !updated_critic {
            self.critic_opt.step();
        }
        self.actor_opt.step();
        clock.lap(|t| &mut t.actor_step);

        // ---- 4. Soft target update theta' <- theta' + tau (theta - theta'). ---------------
        if let Some(t) = &mut self.targets {
            let tau = self.cfg.tau;
            tch::no_grad(|| {
                for (tv, sv) in &mut t.pairs {
                    let _ = tv.lerp_(sv, tau);
                }
            });
        }
        self.updates += 1;
        let q_mean = tch::no_grad(|| (&q_sa[0] * &p.mask).sum(self.kind) / p.mask.sum(self.kind));
        let stats = UpdateStats {
            critic_loss: critic_loss.double_value(&[]),
            actor_loss: actor_loss.double_value(&[]),
            q_mean: q_mean.double_value(&[]),
        };
        clock.lap(|t| &mut t.other);
        if let Some(pt) = &mut self.profile {
            clock.add_into(pt);
            pt.updates += 1;
        }
        stats
    }

    /// Step 2a (call without gradient): runs the behaviour actor along the window (`l + 1`
    /// slots) from its scanned state. Returns its states before each optimisation step
    /// (`[N, l, H]` each; only when the actor gradient is per step, i.e. no BPTT) and the
    /// bootstrap action `mu'(o_tail)`, `[N, A]` (from the target actor when there is one).
    fn actor_window(&self, p: &Prepared, sc: &Scanned) -> (Option<(Tensor, Tensor)>, Tensor) {
        let need_states = self.actor.core.is_recurrent() && !self.cfg.actor_bptt;
        let xa = self.actor.input_seq(&p.obs_win); // [N, l+1, E]
        let (ya, states) = if need_states {
            let (ya, hb, cb, _) = self.actor.core.stepwise(&xa, &sc.actor);
            (ya, Some((hb.narrow(1, 0, p.l), cb.narrow(1, 0, p.l))))
        } else {
            (self.actor.core.seq(&xa, &sc.actor).0, None)
        };
        let a_tail = match (&self.targets, &sc.target_actor) {
            (Some(t), Some(h)) => tail_action(&t.actor, p, h),
            // The output at the tail slot `len_n` is mu(o_tail | h_{len-1}).
            _ => (self.actor.head(&ya) * p.tail_onehot.unsqueeze(-1))
                .sum_dim_intlist(1, false, self.kind),
        };
        (states, a_tail)
    }

    /// With target networks (`tau > 0`): `Q'(o_tail, a_tail)` from the target critics' own
    /// scans and window runs, the minimum over twin critics, `[N]`; `None` without targets.
    fn target_tail_q(&self, p: &Prepared, sc: &Scanned, a_tail: &Tensor) -> Option<Tensor> {
        self.targets.as_ref().map(|t| {
            let qs: Vec<Tensor> = t
                .critics
                .iter()
                .zip(&sc.target_critics)
                .map(|(c, h)| tail_q(p, &critic_window(c, p, h, Some(a_tail))))
                .collect();
            min_all(&qs)
        })
    }

    /// Step 2b's forward pass (with gradient): `Q(o_i, a_i | h_{i-1})` of every critic along
    /// the window, `[N, l]` each, and the bootstrap value `[N]`. Without target networks each
    /// critic's run continues one step into the tail slot with `a_tail`; that output,
    /// detached (minimum over twins), is the bootstrap.
    fn critic_forward(
        &self,
        p: &Prepared,
        sc: &Scanned,
        a_tail: &Tensor,
        target_q_tail: Option<Tensor>,
    ) -> (Vec<Tensor>, Tensor) {
        let with_tail = target_q_tail.is_none();
        let qs: Vec<Tensor> = self
            .critics
            .iter()
            .zip(&sc.critics)
            .map(|(c, h)| critic_window(c, p, h, with_tail.then_some(a_tail)))
            .collect(); // each [N, l (+1)]
        let q_tail = match target_q_tail {
            Some(q) => q,
            None => min_all(&qs.iter().map(|q| tail_q(p, q).detach()).collect::<Vec<_>>()),
        };
        (qs.iter().map(|q| q.narrow(1, 0, p.l)).collect(), q_tail)
    }

    /// Clipped Gaussian noise on the bootstrap action (target policy smoothing), drawn from the
    /// agent's own generator so that checkpoints resume identically.
    fn smooth_target_action(&mut self, a: &Tensor, std: f64, clip: f64) -> Tensor {
        let n = a.numel();
        let noise: Vec<f32> = (0..n)
            .map(|_| (self.rng.normal(0.0, std)).clamp(-clip, clip) as f32)
            .collect();
        let noise = Tensor::from_slice(&noise)
            .view(a.size().as_slice())
            .to_kind(self.kind)
            .to_device(self.device);
        (a + noise).clamp(-1.0, 1.0)
    }

    /// Uploads the batch and builds the small index/weight tensors of the update.
    fn prepare(&self, b: &SequenceBatch) -> Prepared {
        let (n, s, l) = (b.n as i64, b.scan as i64, b.opt as i64);
        let (d, a) = (b.obs_dim as i64, b.act_dim as i64);
        let up = |v: &[f32], shape: &[i64]| -> Tensor {
            Tensor::from_slice(v)
                .view(shape)
                .to_kind(self.kind)
                .to_device(self.device)
        };
        let up64 = |v: Vec<f64>, shape: &[i64]| -> Tensor {
            Tensor::from_slice(&v)
                .view(shape)
                .to_kind(self.kind)
                .to_device(self.device)
        };
        let obs = up(&b.obs, &[n, s + l + 1, d]);
        let actions = up(&b.actions, &[n, s + l, a]);
        let rewards = up(&b.rewards, &[n, s + l]);
        let gamma = self.cfg.gamma;
        let u = self.cfg.update_len.min(b.opt);
        let (nn, ll) = (b.n, b.opt);
        // lambda^i / sum_{j<u} lambda^j on the first u steps, shared by all windows (padded
        // steps drop out, short windows are not renormalised): rdpg-core's reference.
        let td_w = interpolated_td_weights_padded(ll, u, self.cfg.lambda);
        let mut onehot = vec![0.0; nn * (ll + 1)];
        let mut mask = vec![0.0; nn * ll];
        let mut boot_coef = vec![0.0; nn * ll];
        let mut critic_w = vec![0.0; nn * ll];
        let mut actor_w = vec![0.0; nn * ll];
        let mut not_term = vec![0.0; nn];
        for i in 0..nn {
            let len = b.opt_len[i];
            onehot[i * (ll + 1) + len] = 1.0;
            not_term[i] = 1.0 - f64::from(b.tail_terminated[i]);
            for j in 0..len {
                mask[i * ll + j] = 1.0;
                boot_coef[i * ll + j] = gamma.powi((len - j) as i32);
                actor_w[i * ll + j] = 1.0 / len as f64;
                critic_w[i * ll + j] = td_w[j];
            }
        }
        // disc[k, i] = gamma^(k - i) for k >= i: (r * mask) @ disc = discounted reward sums.
        let mut disc = vec![0.0; ll * ll];
        for k in 0..ll {
            for i in 0..=k {
                disc[k * ll + i] = gamma.powi((k - i) as i32);
            }
        }
        let stored = match (&b.stored_state, self.cfg.burn_in_from_stored_state) {
            (Some(st), true) if s > 0 => {
                let h = self.actor.core.state_width();
                let t = up(st, &[n, 2 * h]);
                Some(RecState {
                    h: t.narrow(1, 0, h).unsqueeze(0).contiguous(),
                    c: t.narrow(1, h, h).unsqueeze(0).contiguous(),
                })
            }
            _ => None,
        };
        Prepared {
            n,
            s,
            l,
            obs_scan: obs.narrow(1, 0, s),
            act_scan: actions.narrow(1, 0, s),
            obs_win: obs.narrow(1, s, l + 1),
            act_win: actions.narrow(1, s, l),
            rew: rewards.narrow(1, s, l),
            mask: up64(mask, &[n, l]),
            tail_onehot: up64(onehot, &[n, l + 1]),
            not_term: up64(not_term, &[n]),
            boot_coef: up64(boot_coef, &[n, l]),
            disc: up64(disc, &[l, l]),
            critic_w: up64(critic_w, &[n, l]),
            actor_w: up64(actor_w, &[n, l]),
            scan_len: b.scan_len.clone(),
            stored,
        }
    }

    /// Step 1 for every network (call without gradient).
    fn scan_all(&self, p: &Prepared) -> Scanned {
        let actor_init = match &p.stored {
            Some(st) => st.shallow_clone(),
            None => self.actor.core.zero_state(p.n, self.kind, self.device),
        };
        let actor = self.scan_actor(&self.actor, p, &actor_init);
        let critics = self
            .critics
            .iter()
            .map(|c| self.scan_critic(c, p))
            .collect();
        let (target_actor, target_critics) = match &self.targets {
            Some(t) => (
                Some(self.scan_actor(&t.actor, p, &actor_init)),
                t.critics.iter().map(|c| self.scan_critic(c, p)).collect(),
            ),
            None => (None, Vec::new()),
        };
        Scanned {
            actor,
            critics,
            target_actor,
            target_critics,
        }
    }

    fn scan_actor(&self, actor: &Actor, p: &Prepared, init: &RecState) -> RecState {
        if p.s == 0 || !actor.core.is_recurrent() {
            return init.shallow_clone();
        }
        let x = actor.input_seq(&p.obs_scan);
        scan_state(&actor.core, &x, &p.scan_len, init, self.cfg.scan_method)
    }

    fn scan_critic(&self, critic: &Critic, p: &Prepared) -> RecState {
        let init = critic.core.zero_state(p.n, self.kind, self.device);
        if p.s == 0 || !critic.core.is_recurrent() {
            return init;
        }
        let x = critic.input_seq(&p.obs_scan, &p.act_scan);
        scan_state(&critic.core, &x, &p.scan_len, &init, self.cfg.scan_method)
    }

    /// The critic's states before each optimisation step along the replayed actions
    /// (`h_{i-1}`, `c_{i-1}`, each `[N, l, H]`), from its scanned state (call without
    /// gradient).
    fn critic_states(&self, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
        let critic = &self.critics[0];
        let x = critic.input_seq(&p.obs_win.narrow(1, 0, p.l), &p.act_win);
        let (_, hb, cb, _) = critic.core.stepwise(&x, h);
        (hb, cb)
    }

    // -----------------------------------------------------------------------------------------
    // Checkpoints
    // -----------------------------------------------------------------------------------------

    /// Writes networks (target networks included), optimiser moments, the update count and the
    /// agent's generator to `dir` (`agent.json`, `weights.safetensors`, `optim.safetensors`).
    /// [`RdpgAgent::load`] then continues bit-identically.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir)?;
        let cpu = |t: &Tensor| t.detach().to_device(Device::Cpu).contiguous();
        let mut weights: Vec<(String, Tensor)> = Vec::new();
        for vs in std::iter::once(&self.actor_vs).chain(&self.critic_vs) {
            weights.extend(sorted_vars(vs).into_iter().map(|(n, t)| (n, cpu(&t))));
        }
        if let Some(t) = &self.targets {
            for vs in std::iter::once(&t.actor_vs).chain(&t.critic_vs) {
                weights.extend(
                    sorted_vars(vs)
                        .into_iter()
                        .map(|(n, t)| (format!("target.{n}"), cpu(&t))),
                );
            }
        }
        Tensor::write_safetensors(&weights, dir.join("weights.safetensors"))?;
        let mut optim = self.actor_opt.state("actor_opt.");
        optim.extend(self.critic_opt.state("critic_opt."));
        let optim: Vec<(String, Tensor)> = optim.into_iter().map(|(n, t)| (n, cpu(&t))).collect();
        Tensor::write_safetensors(&optim, dir.join("optim.safetensors"))?;
        let meta = CheckpointMeta {
            format: CHECKPOINT_FORMAT,
            config: self.cfg.clone(),
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            seed: self.seed,
            double: self.kind == Kind::Double,
            updates: self.updates,
            rng: self.rng.clone(),
        };
        std::fs::write(dir.join("agent.json"), serde_json::to_string_pretty(&meta)?)?;
        Ok(())
    }

    /// Restores an agent written by [`RdpgAgent::save`], on the device its config names.
    pub fn load(dir: impl AsRef<Path>) -> Result<Self> {
        Self::load_with(dir, None)
    }

    /// Like [`RdpgAgent::load`], overriding the device (e.g. resume a GPU run on the CPU).
    pub fn load_with(dir: impl AsRef<Path>, device: Option<DeviceSpec>) -> Result<Self> {
        let dir = dir.as_ref();
        let meta: CheckpointMeta =
            serde_json::from_str(&std::fs::read_to_string(dir.join("agent.json"))?)?;
        if meta.format != CHECKPOINT_FORMAT {
            return Err(AgentError::Checkpoint(format!(
                "unknown format {}",
                meta.format
            )));
        }
        let mut cfg = meta.config;
        if let Some(d) = device {
            cfg.device = d;
        }
        let kind = if meta.double {
            Kind::Double
        } else {
            Kind::Float
        };
        let mut agent = Self::new_with_kind(cfg, meta.obs_dim, meta.act_dim, meta.seed, kind)?;
        let weights: HashMap<String, Tensor> =
            Tensor::read_safetensors(dir.join("weights.safetensors"))?
                .into_iter()
                .collect();
        let restore = |vs: &VarStore, prefix: &str| -> Result<()> {
            for (name, mut var) in sorted_vars(vs) {
                let key = format!("{prefix}{name}");
                let src = weights
                    .get(&key)
                    .ok_or_else(|| AgentError::Checkpoint(format!("missing weight `{key}`")))?;
                if src.size() != var.size() {
                    return Err(AgentError::Checkpoint(format!(
                        "weight `{key}` has the wrong shape"
                    )));
                }
                tch::no_grad(|| var.copy_(&src.to_kind(kind).to_device(agent.device)));
            }
            Ok(())
        };
        restore(&agent.actor_vs, "")?;
        for vs in &agent.critic_vs {
            restore(vs, "")?;
        }
        if let Some(t) = &agent.targets {
            restore(&t.actor_vs, "target.")?;
            for vs in &t.critic_vs {
                restore(vs, "target.")?;
            }
        }
        let optim: HashMap<String, Tensor> =
            Tensor::read_safetensors(dir.join("optim.safetensors"))?
                .into_iter()
                .collect();
        agent.actor_opt.load_state("actor_opt.", &optim)?;
        agent.critic_opt.load_state("critic_opt.", &optim)?;
        agent.updates = meta.updates;
        agent.rng = meta.rng;
        Ok(agent)
    }

    /// All network weights (targets included, prefixed `target.`) flattened to f64, by name;
    /// for tests and diagnostics.
    pub fn weights(&self) -> Vec<(String, Vec<f64>)> {
        let mut out = Vec::new();
        let mut add = |vs: &VarStore, prefix: &str| {
            for (n, t) in sorted_vars(vs) {
                let t = t
                    .detach()
                    .to_kind(Kind::Double)
                    .to_device(Device::Cpu)
                    .contiguous()
                    .view([-1]);
                out.push((
                    format!("{prefix}{n}"),
                    Vec::<f64>::try_from(&t).expect("to vec"),
                ));
            }
        };
        add(&self.actor_vs, "");
        for vs in &self.critic_vs {
            add(vs, "");
        }
        if let Some(t) = &self.targets {
            add(&t.actor_vs, "target.");
            for vs in &t.critic_vs {
                add(vs, "target.");
            }
        }
        out
    }
}

// ---------------------------------------------------------------------------------------------
// The pieces of the update
// ---------------------------------------------------------------------------------------------

/// The batch on the device, split into the scan part and the optimisation window.
struct Prepared {
    n: i64,
    s: i64,
    l: i64,
    /// `[N, s, D]`, `[N, s, A]`: the scan part.
    obs_scan: Tensor,
    act_scan: Tensor,
    /// `[N, l + 1, D]`: the window's observations plus the slot that holds `o_tail` for
    /// full windows (shorter windows have it at `len`, inside the window).
    obs_win: Tensor,
    /// `[N, l, A]`, `[N, l]`: replayed actions and rewards of the window.
    act_win: Tensor,
    rew: Tensor,
    /// `[N, l]`: 1 on real steps.
    mask: Tensor,
    /// `[N, l + 1]`: 1 at the tail position `len_n`.
    tail_onehot: Tensor,
    /// `[N]`: `1 - tail_terminated`.
    not_term: Tensor,
    /// `[N, l]`: `gamma^(len - i)` on real steps.
    boot_coef: Tensor,
    /// `[l, l]`: `gamma^(k - i)` for `k >= i`.
    disc: Tensor,
    /// `[N, l]`: `lambda^i / sum_{j<u} lambda^j` on real steps among the first `u`.
    critic_w: Tensor,
    /// `[N, l]`: `1 / len` on real steps.
    actor_w: Tensor,
    scan_len: Vec<usize>,
    /// Stored acting-time actor states `[1, N, H]` (when burning in from them).
    stored: Option<RecState>,
}

/// `h_{-1}` of every network.
struct Scanned {
    actor: RecState,
    critics: Vec<RecState>,
    target_actor: Option<RecState>,
    target_critics: Vec<RecState>,
}

/// The state after exactly `scan_len[n]` real steps of window `n` from `init`: the scan
/// inputs `x [N, s, in]` are left-padded (the last `scan_len[n]` steps are real) and the
/// padding never enters the state. `method` chooses how (see [`ScanMethod`]). Feed-forward
/// cores and `s = 0` return `init`.
pub fn scan_state(
    core: &Core,
    x: &Tensor,
    scan_len: &[usize],
    init: &RecState,
    method: ScanMethod,
) -> RecState {
    let s = x.size()[1] as usize;
    if !core.is_recurrent() || s == 0 {
        return init.shallow_clone();
    }
    match method {
        ScanMethod::Grouped => {
            if scan_len.iter().all(|&k| k == s) {
                return core.seq(x, init).1; // the common case: one fused call
            }
            let (mut h, mut c) = (init.h.copy(), init.c.copy());
            let pick = |want: &dyn Fn(usize) -> bool| -> Vec<i64> {
                (0..scan_len.len())
                    .filter(|&i| want(scan_len[i]))
                    .map(|i| i as i64)
                    .collect()
            };
            // Full scans: one fused call over all s steps.
            let full = pick(&|k| k == s);
            if !full.is_empty() {
                let it = Tensor::from_slice(&full).to_device(x.device());
                let st0 = RecState {
                    h: init.h.index_select(1, &it),
                    c: init.c.index_select(1, &it),
                };
                let (_, st) = core.seq(&x.index_select(0, &it), &st0);
                h = h.index_copy(1, &it, &st.h);
                c = c.index_copy(1, &it, &st.c);
            }
            // Shorter scans (windows near an episode start): masked cell loop on that subset.
            // Windows with no real scan step keep `init`.
            let short = pick(&|k| 0 < k && k < s);
            if !short.is_empty() {
                let it = Tensor::from_slice(&short).to_device(x.device());
                let ks: Vec<usize> = short.iter().map(|&i| scan_len[i as usize]).collect();
                let st0 = RecState {
                    h: init.h.index_select(1, &it),
                    c: init.c.index_select(1, &it),
                };
                let st = masked_cell_loop(core, &x.index_select(0, &it), &ks, &st0);
                h = h.index_copy(1, &it, &st.h);
                c = c.index_copy(1, &it, &st.c);
            }
            RecState { h, c }
        }
        ScanMethod::MaskedLoop => masked_cell_loop(core, x, scan_len, init),
    }
}

/// The scan as a loop of LSTM cell steps over `x [m, s, in]`, keeping each window's state
/// unchanged (`where`) while it is still in its left padding. Steps before the longest real
/// scan are skipped.
fn masked_cell_loop(core: &Core, x: &Tensor, scan_len: &[usize], init: &RecState) -> RecState {
    let (m, s) = (x.size()[0], x.size()[1] as usize);
    let longest = scan_len.iter().copied().max().unwrap_or(0);
    let real: Vec<u8> = scan_len
        .iter()
        .flat_map(|&k| (0..s).map(move |t| u8::from(t >= s - k)))
        .collect();
    let real = Tensor::from_slice(&real)
        .view([m, s as i64])
        .to_device(x.device())
        .to_kind(Kind::Bool);
    let mut st = init.shallow_clone();
    for t in (s - longest) as i64..s as i64 {
        let (_, next) = core.step(&x.select(1, t), &st);
        let keep = real.select(1, t).view([1, m, 1]);
        st = RecState {
            h: next.h.where_self(&keep, &st.h),
            c: next.c.where_self(&keep, &st.c),
        };
    }
    st
}

/// The critic along the window from its scanned state: `Q(o_i, a_i | h_{i-1})` for the
/// replayed actions, `[N, l]`; with `a_tail`, one more slot where the tail position `len_n`
/// holds `Q(o_tail, a_tail | h_{len-1})`, `[N, l + 1]`.
fn critic_window(critic: &Critic, p: &Prepared, h: &RecState, a_tail: Option<&Tensor>) -> Tensor {
    let (obs, act) = match a_tail {
        Some(at) => {
            let n = p.n;
            let a_dim = p.act_win.size()[2];
            let pad = Tensor::zeros([n, 1, a_dim], (p.act_win.kind(), p.act_win.device()));
            let ext = Tensor::cat(&[&p.act_win, &pad], 1); // [N, l+1, A], zero past len
            let oh = p.tail_onehot.unsqueeze(-1); // [N, l+1, 1]
            (
                p.obs_win.shallow_clone(),
                &ext * (1.0 - &oh) + at.unsqueeze(1) * oh,
            )
        }
        None => (p.obs_win.narrow(1, 0, p.l), p.act_win.shallow_clone()),
    };
    critic.forward_seq(&obs, &act, h).0
}

/// The value at each window's tail position: `q_ext [N, l + 1]` -> `[N]`.
fn tail_q(p: &Prepared, q_ext: &Tensor) -> Tensor {
    (q_ext * &p.tail_onehot).sum_dim_intlist(1, false, q_ext.kind())
}

/// `mu'(o_tail)` of `actor` from its scanned state: `[N, A]`.
fn tail_action(actor: &Actor, p: &Prepared, h: &RecState) -> Tensor {
    let (mu, _) = actor.forward_seq(&p.obs_win, h); // [N, l+1, A]
    (mu * p.tail_onehot.unsqueeze(-1)).sum_dim_intlist(1, false, p.obs_win.kind())
}

/// Element-wise minimum of one or two tensors.
fn min_all(ts: &[Tensor]) -> Tensor {
    let mut m = ts[0].shallow_clone();
    for t in &ts[1..] {
        m = m.minimum(t);
    }
    m
}

/// Tail-step bootstrap targets, `[N, l]`:
/// `y_i = sum_{k=i}^{len-1} gamma^{k-i} r_k + gamma^{len-i} q_tail (1 - term)` on real steps,
/// 0 on padding.
fn td_targets(p: &Prepared, q_tail: &Tensor) -> Tensor {
    let returns = (&p.rew * &p.mask).matmul(&p.disc); // [N, l]
    returns + &p.boot_coef * (q_tail * &p.not_term).unsqueeze(1)
}

/// `1/N sum_n sum_i w_{n,i} (y_{n,i} - q_{n,i})^2` (paper Eq. (unsyncedinterpolatedTD)).
fn critic_loss_from(p: &Prepared, q_sa: &Tensor, y: &Tensor) -> Tensor {
    (&p.critic_w * (y - q_sa).square()).sum(q_sa.kind()) / p.n as f64
}

/// Where the actor's recurrent input comes from in the actor loss.
enum ActorInput<'a> {
    /// No BPTT: the states before each step (`[N, l, H]`), constants.
    Detached { h: &'a Tensor, c: &'a Tensor },
    /// BPTT: run the actor with gradient along the window from its scanned state.
    Bptt { h0: &'a RecState },
}

/// `-1/N sum_n 1/len_n sum_i Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})` (paper Eq. (DPG)).
/// `critic_states` are the critic's `(h_{i-1}, c_{i-1})`, `[N, l, Hc]`.
fn actor_loss(
    actor: &Actor,
    critic: &Critic,
    p: &Prepared,
    input: ActorInput<'_>,
    critic_states: &(Tensor, Tensor),
) -> Tensor {
    let (n, l) = (p.n, p.l);
    let obs = p.obs_win.narrow(1, 0, l); // [N, l, D]
    let d = obs.size()[2];
    let obs_flat = obs.reshape([n * l, d]); // [N*l, D]
    let a = match input {
        ActorInput::Detached { h, c } => {
            // Every step from its own (constant) previous state: one batched LSTM cell over
            // N*l rows.
            let ha = h.size()[2];
            let st = RecState {
                h: h.reshape([1, n * l, ha]),
                c: c.reshape([1, n * l, ha]),
            };
            let (y, _) = actor.core.step(&actor.trunk.forward(&obs_flat), &st);
            actor.head(&y) // [N*l, A]
        }
        ActorInput::Bptt { h0 } => {
            let (a, _) = actor.forward_seq(&obs, h0); // [N, l, A]
            let a_dim = a.size()[2];
            a.reshape([n * l, a_dim])
        }
    };
    // Q(o_i, a_i | h^C_{i-1}): one critic cell step per (window, step) from its carried state.
    let hc = critic_states.0.size()[2];
    let stc = RecState {
        h: critic_states.0.reshape([1, n * l, hc]),
        c: critic_states.1.reshape([1, n * l, hc]),
    };
    let (q, _) = critic.step(&obs_flat, &a, &stc); // [N*l]
    -(q.reshape([n, l]) * &p.actor_w).sum(a.kind()) / n as f64
}

/// Per-phase stopwatch (no-op when profiling is off).
struct Clock {
    on: bool,
    last: Instant,
    acc: PhaseTimes,
}

impl Clock {
    fn new(on: bool) -> Self {
        Self {
            on,
            last: Instant::now(),
            acc: PhaseTimes::default(),
        }
    }

    fn lap(&mut self, field: impl FnOnce(&mut PhaseTimes) -> &mut f64) {
        if self.on {
            let now = Instant::now();
            *field(&mut self.acc) += (now - self.last).as_secs_f64();
            self.last = now;
        }
    }

    fn add_into(&self, t: &mut PhaseTimes) {
        t.prepare += self.acc.prepare;
        t.scan += self.acc.scan;
        t.window_nograd += self.acc.window_nograd;
        t.critic_step += self.acc.critic_step;
        t.critic_rescan += self.acc.critic_rescan;
        t.actor_step += self.acc.actor_step;
        t.other += self.acc.other;
    }
}

#[cfg(test)]
mod tests;
