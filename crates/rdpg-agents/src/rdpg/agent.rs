//! The RDPG agent (or its feed-forward DDPG variant): networks, target copies, optimisers,
//! acting with the trained actor ([`RdpgAgent::act`]) or with its exploring copy
//! ([`RdpgAgent::act_exploring`], parameter-space noise), and batch checks. The update is in
//! `update.rs`, checkpoints in `checkpoint.rs`.

use rdpg_core::rng::NpRng;
use rdpg_core::SequenceBatch;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

pub use super::acting::ActorState;
use super::acting::Window;
use super::config::RdpgConfig;
use super::config::ScanMethod;
use super::lstm::{scan_state, RecState};
use super::nets::{Actor, Critic};
use super::prepared::{BatchSpec, Prepared};
use super::profile::PhaseTimes;
use crate::common::adam::{Adam, AdamConfig};
use crate::common::tensor::{
    init_from_rng, resolve_device, sorted_vars, tensor_to_vec, tensor_to_vec64,
};
use crate::error::{AgentError, Result};

/// Target copies of the networks (only when `tau > 0`).
pub(super) struct Targets {
    /// The target actor, with the critics' (`None` for SAC, whose bootstrap samples the
    /// current policy).
    pub(super) actor: Option<(VarStore, Actor)>,
    pub(super) critic_vs: Vec<VarStore>,
    pub(super) critics: Vec<Critic>,
    /// (target variable, online variable) pairs for the soft update: the actor's, then each
    /// critic's in order (the update hands the last critic's to its second thread).
    pub(super) pairs: Vec<(Tensor, Tensor)>,
}

/// Recurrent deterministic policy gradient agent (or feed-forward DDPG when
/// `config.recurrent` is false).
pub struct RdpgAgent {
    pub(super) cfg: RdpgConfig,
    pub(super) obs_dim: usize,
    pub(super) act_dim: usize,
    pub(super) seed: u64,
    pub(super) device: Device,
    pub(super) kind: Kind,
    pub(super) actor_vs: VarStore,
    pub(super) actor: Actor,
    pub(super) critic_vs: Vec<VarStore>,
    pub(super) critics: Vec<Critic>,
    pub(super) targets: Option<Targets>,
    pub(super) actor_opt: Adam,
    pub(super) critic_opt: Adam,
    pub(super) rng: NpRng,
    pub(super) updates: u64,
    pub(super) profile: Option<PhaseTimes>,
    /// A copy of the actor with perturbed parameters that [`RdpgAgent::act_exploring`] uses
    /// (parameter-space exploration); not trained, not checkpointed.
    pub(super) exploring: Option<(VarStore, Actor)>,
    /// The update's second thread (`parallel_twins`), started by the first such update.
    pub(super) side: Option<crate::common::side_thread::SideThread>,
    /// How many of `critic_opt`'s parameters are critic 0's (they come first): where
    /// `parallel_twins` splits the critics' Adam step between the two threads.
    pub(super) critic0_params: usize,
    /// FORK's models (`config.fork`).
    pub(super) fork: Option<super::fork::ForkModels>,
    /// SAC's temperature (`config.sac`).
    pub(super) sac: Option<Temperature>,
}

/// SAC's temperature: `log alpha` (a variable of its own store, so that checkpoints hold it
/// by name) and its Adam, the target entropy.
pub(super) struct Temperature {
    pub(super) vs: VarStore,
    pub(super) log_alpha: Tensor,
    pub(super) opt: Adam,
    pub(super) target_entropy: f64,
    pub(super) learn: bool,
}

impl Temperature {
    /// `alpha = exp(log alpha)`.
    pub(super) fn alpha(&self) -> f64 {
        self.log_alpha.double_value(&[0]).exp()
    }
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
            crate::common::tensor::set_num_threads(n);
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
                for vs in std::iter::once(&actor_vs).chain(&critic_vs) {
                    add_forget_bias(vs, cfg.lstm_forget_bias);
                }
            }
            (actor_vs, actor, critic_vs, critics)
        };
        let (actor_vs, actor, critic_vs, critics) = build(device, true);
        let targets = if cfg.tau > 0.0 {
            let (mut t_actor_vs, t_actor, mut t_critic_vs, t_critics) = build(device, false);
            t_actor_vs.copy(&actor_vs)?;
            // SAC: no target actor (its bootstrap samples the current policy).
            let with_actor = cfg.sac.is_none();
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
            if with_actor {
                push(&t_actor_vs, &actor_vs);
            }
            for (t, s) in t_critic_vs.iter().zip(&critic_vs) {
                push(t, s);
            }
            // Target networks never need gradients.
            t_actor_vs.freeze();
            for vs in &mut t_critic_vs {
                vs.freeze();
            }
            Some(Targets {
                actor: with_actor.then_some((t_actor_vs, t_actor)),
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
        let critic0_params = sorted_vars(&critic_vs[0]).len();
        let critic_params: Vec<_> = critic_vs.iter().flat_map(sorted_vars).collect();
        let critic_opt = Adam::new(adam(cfg.lr_critic, cfg.critic_l2), critic_params);
        let fork = cfg.fork.as_ref().map(|f| {
            super::fork::ForkModels::new(f, d, a, kind, device, adam(f.lr, 0.0), &mut rng)
        });
        let sac = cfg.sac.as_ref().map(|s| {
            let mut vs = VarStore::new(device);
            let _ = vs.root().var("log_alpha", &[1], tch::nn::Init::Const(0.0));
            if kind == Kind::Double {
                vs.double();
            }
            let mut log_alpha = sorted_vars(&vs).remove(0).1;
            // Set in the agent's kind (an f32 constant would round `ln(init_alpha)`).
            let _ = tch::no_grad(|| log_alpha.fill_(s.init_alpha.ln()));
            let opt = Adam::new(adam(s.lr_alpha, 0.0), sorted_vars(&vs));
            Temperature {
                vs,
                log_alpha,
                opt,
                target_entropy: s.target_entropy(act_dim),
                learn: s.learn_alpha,
            }
        });

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
            exploring: None,
            side: None,
            critic0_params,
            fork,
            sac,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &RdpgConfig {
        &self.cfg
    }

    /// Switches `parallel_twins` (the second critic on a second thread; the updates stay
    /// bit-identical). Validated like the configuration.
    pub fn set_parallel_twins(&mut self, on: bool) -> Result<()> {
        let cfg = RdpgConfig {
            parallel_twins: on,
            ..self.cfg.clone()
        };
        cfg.validate()?;
        self.cfg = cfg;
        if !on {
            self.side = None;
        }
        Ok(())
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

    /// Switches per-phase timing on (resetting it) or off.
    pub fn set_profiling(&mut self, on: bool) {
        self.profile = on.then(PhaseTimes::default);
    }

    /// The per-phase timings accumulated since profiling was switched on.
    pub fn profile(&self) -> Option<PhaseTimes> {
        self.profile
    }

    /// What a batch is checked against and uploaded for.
    fn batch_spec(&self) -> BatchSpec<'_> {
        BatchSpec {
            cfg: &self.cfg,
            obs_dim: self.obs_dim,
            act_dim: self.act_dim,
            state_width: self.actor.core.state_width(),
            kind: self.kind,
            device: self.device,
        }
    }

    /// Checks a batch against this agent (sizes, lengths, mask, stored state).
    pub fn check_batch(&self, b: &SequenceBatch) -> Result<()> {
        self.batch_spec().check_batch(b)
    }

    /// Uploads the batch and builds the small index/weight tensors of the update.
    pub(super) fn prepare(&self, b: &SequenceBatch) -> Prepared {
        self.batch_spec().prepare(b)
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
        self.state_with_window(n_envs, self.cfg.act_window)
    }

    /// A zero actor state for `n_envs` environments that remembers at most the last `k`
    /// observations, the current one included: at every step the recurrent state is
    /// re-encoded from zero over the `k - 1` observations before it, as a window-of-k agent
    /// acts (`k = 1`: no memory at all, the state is zero at every step). A probe of how far
    /// back a trained recurrent actor's memory matters, for any recurrent agent whatever it
    /// was trained with; a feed-forward agent or `k = 0` is refused.
    pub fn initial_state_with_memory(&self, n_envs: usize, k: usize) -> Result<ActorState> {
        if k == 0 || !self.actor.core.is_recurrent() {
            return Err(AgentError::Config {
                field: "memory",
                reason: if k == 0 {
                    "remembers at least the current observation: k >= 1".into()
                } else {
                    "a feed-forward actor carries no memory to limit".into()
                },
            });
        }
        Ok(self.state_with_window(n_envs, k))
    }

    /// A zero state; a window of the last `k` observations unless `k = 0`.
    pub(crate) fn state_with_window(&self, n_envs: usize, k: usize) -> ActorState {
        let hidden = self.actor.core.state_width();
        ActorState {
            state: RecState::zeros(n_envs as i64, hidden, self.kind, self.device),
            n_envs,
            hidden: hidden as usize,
            window: (k > 0).then(|| Window {
                k,
                obs_dim: self.obs_dim,
                hist: vec![0.0; n_envs * (k - 1) * self.obs_dim],
                len: vec![0; n_envs],
            }),
        }
    }

    /// Zeroes the state of environment `env` (`None`: all environments), at an episode start.
    pub fn reset_state(&self, state: &mut ActorState, env: Option<usize>) {
        match env {
            Some(e) => state.reset_env(e),
            None => state.reset(),
        }
    }

    /// Deterministic actions `mu(o_t | h_{t-1})` of the trained actor for a batch of
    /// environments: `obs` is `[n_envs, obs_dim]` row-major, the result `[n_envs, act_dim]` in
    /// `[-1, 1]`; `state` advances by one step. Evaluation and updates use this actor. A wrong
    /// number of values or a non-finite one is an error (the state is left unchanged).
    pub fn act(&self, obs: &[f32], state: &mut ActorState) -> Result<Vec<f32>> {
        self.act_with(&self.actor, obs, state, None)
    }

    /// Like [`RdpgAgent::act`], with the exploring copy of the actor (its parameters set by
    /// [`RdpgAgent::set_exploring_params`], parameter-space noise) when there is one, else
    /// with the trained actor. Action noise is the caller's business.
    pub fn act_exploring(&self, obs: &[f32], state: &mut ActorState) -> Result<Vec<f32>> {
        let actor = self.exploring.as_ref().map_or(&self.actor, |(_, a)| a);
        self.act_with(actor, obs, state, None)
    }

    /// A SAC agent's exploring actions, sampled from its squashed Gaussian:
    /// `a = tanh(m + s * eps)` with the caller's standard normal draws `eps`
    /// (`[n_envs, act_dim]` row-major); otherwise like [`RdpgAgent::act`].
    pub fn act_sampled(
        &self,
        obs: &[f32],
        state: &mut ActorState,
        eps: &[f32],
    ) -> Result<Vec<f32>> {
        if !self.actor.gaussian {
            return Err(AgentError::Config {
                field: "sac",
                reason: "a deterministic actor has no distribution to sample".into(),
            });
        }
        if eps.len() != state.n_envs * self.act_dim {
            return Err(AgentError::Shape(format!(
                "act_sampled: {} noise values, expected {} environment(s) x act_dim {}",
                eps.len(),
                state.n_envs,
                self.act_dim
            )));
        }
        self.act_with(&self.actor, obs, state, Some(eps))
    }

    fn act_with(
        &self,
        actor: &Actor,
        obs: &[f32],
        state: &mut ActorState,
        eps: Option<&[f32]>,
    ) -> Result<Vec<f32>> {
        let n = state.n_envs;
        if obs.len() != n * self.obs_dim {
            return Err(AgentError::Shape(format!(
                "act: {} observation values, expected {n} environment(s) x obs_dim {}",
                obs.len(),
                self.obs_dim
            )));
        }
        if let Some(k) = obs.iter().position(|x| !x.is_finite()) {
            return Err(AgentError::Input(format!(
                "observation component {} of environment {} is {}",
                k % self.obs_dim,
                k / self.obs_dim,
                obs[k]
            )));
        }
        // One step: the deterministic action, or (SAC, with `eps`) a sample.
        let step = |o: &Tensor, h: &RecState| match eps {
            None => actor.step(o, h),
            Some(e) => {
                let (x, y, next) = actor.features(o, h);
                let (m, log_s) = actor.gaussian(&x, &y);
                let e = Tensor::from_slice(e)
                    .view([n as i64, self.act_dim as i64])
                    .to_kind(self.kind)
                    .to_device(self.device);
                ((m + log_s.exp() * e).tanh(), next)
            }
        };
        let (a, next) = tch::no_grad(|| {
            let o = Tensor::from_slice(obs)
                .view([n as i64, self.obs_dim as i64])
                .to_kind(self.kind)
                .to_device(self.device);
            if let Some(w) = &state.window {
                // mu(o_t | the last k - 1 observations from a zero state), as training reads it.
                let h0 = actor.core.zero_state(n as i64, self.kind, self.device);
                if w.k == 1 {
                    return step(&o, &h0);
                }
                let hist = Tensor::from_slice(&w.hist)
                    .view([n as i64, (w.k - 1) as i64, self.obs_dim as i64])
                    .to_kind(self.kind)
                    .to_device(self.device);
                let x = actor.input_seq(&hist);
                let h = scan_state(&actor.core, &x, &w.len, &h0, ScanMethod::Grouped);
                return step(&o, &h);
            }
            step(&o, &state.state)
        });
        // A finite observation far outside what the agent saw (e.g. 1e38) can overflow the
        // recurrent state: refused, with the state left as it was, rather than carried on as
        // NaN (for a window-of-k agent, the observation stays out of its window).
        if self.actor.core.is_recurrent() {
            let finite = |t: &Tensor| t.isfinite().all().int64_value(&[]) != 0;
            if !(finite(&next.h) && finite(&next.c)) {
                return Err(AgentError::Input(
                    "this observation overflows the actor's recurrent state (values far outside \
                     those it was trained on); the state is left as it was"
                        .into(),
                ));
            }
        }
        let a =
            crate::common::policy::check_action_finite(tensor_to_vec(&a), "the actor's action")?;
        match &mut state.window {
            Some(w) => w.push(obs),
            None => state.state = next,
        }
        Ok(a)
    }

    /// The trained actor's states before each of the first `n` steps of an episode whose
    /// observations are `obs` (`[>= n, obs_dim]` row-major), from a zero state at its start:
    /// `[n, state_dim]` row-major (`h` then `c`), what [`ActorState::env_state`] gives before
    /// each step when the actor acts along the episode. The replay's stored states of teacher
    /// episodes, which carry none of this actor's. Feed-forward agents: empty.
    pub fn episode_states(&self, obs: &[f32], n: usize) -> Result<Vec<f32>> {
        if obs.len() < n * self.obs_dim {
            return Err(AgentError::Shape(format!(
                "episode_states: {} observation values for {n} steps of obs_dim {}",
                obs.len(),
                self.obs_dim
            )));
        }
        if n == 0 || !self.actor.core.is_recurrent() {
            return Ok(Vec::new());
        }
        let hc = tch::no_grad(|| {
            let o = Tensor::from_slice(&obs[..n * self.obs_dim])
                .view([1, n as i64, self.obs_dim as i64])
                .to_kind(self.kind)
                .to_device(self.device);
            let x = self.actor.input_seq(&o); // [1, n, in]
            let s0 = self.actor.core.zero_state(1, self.kind, self.device);
            let (h, c) = self.actor.core.states_before(&x, &s0); // [1, n, H] each
            Tensor::cat(&[h.squeeze_dim(0), c.squeeze_dim(0)], 1) // [n, 2H]
        });
        Ok(tensor_to_vec(&hc))
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
    /// [`RdpgAgent::act_exploring`] uses a copy of the actor with these parameters (layout of
    /// [`RdpgAgent::actor_params`], e.g. perturbed by
    /// `rdpg_core::noise::AdaptiveParamNoise::perturb`); `None` explores with the trained
    /// actor again. The copy is neither trained nor checkpointed: perturb again after updates.
    #[allow(
        clippy::expect_used,
        reason = "called only while exploring parameters are set"
    )]
    pub fn set_exploring_params(&mut self, params: Option<&[f32]>) -> Result<()> {
        let Some(params) = params else {
            self.exploring = None;
            return Ok(());
        };
        if params.len() != self.actor_param_count() {
            return Err(AgentError::Shape(format!(
                "exploring params: {} values, the actor has {}",
                params.len(),
                self.actor_param_count()
            )));
        }
        if self.exploring.is_none() {
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
            self.exploring = Some((vs, actor));
        }
        let (vs, _) = self.exploring.as_ref().expect("exploring actor");
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

    /// All network weights (targets included, prefixed `target.`; FORK's models, then SAC's
    /// `log_alpha`, last)
    /// flattened to f64, by name;
    /// for tests and diagnostics.
    pub fn weights(&self) -> Vec<(String, Vec<f64>)> {
        let mut out = Vec::new();
        let mut add = |vs: &VarStore, prefix: &str| {
            for (n, t) in sorted_vars(vs) {
                out.push((format!("{prefix}{n}"), tensor_to_vec64(&t)));
            }
        };
        add(&self.actor_vs, "");
        for vs in &self.critic_vs {
            add(vs, "");
        }
        if let Some(t) = &self.targets {
            if let Some((vs, _)) = &t.actor {
                add(vs, "target.");
            }
            for vs in &t.critic_vs {
                add(vs, "target.");
            }
        }
        if let Some(f) = &self.fork {
            add(&f.dynamics_vs, "");
            add(&f.reward_vs, "");
        }
        if let Some(t) = &self.sac {
            add(&t.vs, "");
        }
        out
    }
}

/// Adds `bias` to the forget-gate slice (`[H, 2H)`, gate order i, f, g, o) of every LSTM's
/// input bias in `vs`: the trainable counterpart of TensorFlow's `forget_bias` at
/// initialisation (see [`RdpgConfig::lstm_forget_bias`]).
fn add_forget_bias(vs: &VarStore, bias: f64) {
    if bias == 0.0 {
        return;
    }
    for (name, var) in sorted_vars(vs) {
        if name.ends_with("lstm.bias_ih_l0") {
            let h = var.size()[0] / 4;
            tch::no_grad(|| {
                let _ = var.narrow(0, h, h).g_add_scalar_(bias);
            });
        }
    }
}
