//! FORK's forward-looking actor (Wei & Ying 2021, "FORK: A Forward-Looking Actor for Model-Free
//! Reinforcement Learning"; the TD3-FORK of its authors' code), for feed-forward agents.
//!
//! Two models learn from every update's batch (steps flattened to `M = N * l` rows; padded
//! rows weigh 0, real rows equally):
//!
//! 1. **Dynamics** `F(o, a) -> o'`: an MLP on `o ++ a` (`model_hidden`, ReLU), its prediction
//!    clamped to `[lo, hi]`, the running minimum and maximum of every observation value the
//!    batches have shown (TD3-FORK tracks the same two scalars while acting). Loss: smooth L1
//!    (`beta = 1`) between `F(o_i, a_i)` and `o_{i+1}`, averaged over real rows and components.
//! 2. **Reward** `R(o, o', a) -> r`: an MLP on `o ++ o' ++ a` (`reward_hidden`, ReLU). Loss:
//!    `(R(o_i, o_{i+1}, a_i) - r_i)^2` averaged over real rows (the training reward).
//!
//! Both are initialised like the agent's networks (PyTorch's default bounds, the output layer
//! within ±3e-3; TD3-FORK starts its dynamics model with Xavier weights). The bounds come from
//! the sampled batches (injected teacher windows included), so early in a run they can be
//! narrower than TD3-FORK's, which sees every observation while acting.
//!
//! Each takes one Adam step per update. On the actor's turn, when this update's dynamics
//! loss (before the model's step) is below `threshold`, the actor loss gains `w * J_fork`,
//!
//! ```text
//! J_fork = -sum_i w_i [ R(o_i, ô1, mu(o_i)) + gamma R(ô1, ô2, mu(ô1)) + gamma^2 Q_1(ô2, mu(ô2)) ]
//! ô1 = F(o_i, mu(o_i)),  ô2 = F(ô1, mu(ô1))   (clamped; constants)
//! ```
//!
//! with `w_i` the actor loss's per-step weights (`1 / (N len_n)`) and `Q_1` the first critic.
//! TD3-FORK detaches the predicted observations wherever they reach the loss, so the actor's
//! gradient flows only through the three actions (into `R` and `Q_1`); the models and the
//! critic are constants here (`fork_term_equals_the_reference_formulation` checks this
//! against the authors' placement of `detach`).

use tch::nn::VarStore;
use tch::{Kind, Reduction, Tensor};

use super::config::ForkConfig;
use super::nets::{Actor, Critic};
use super::prepared::Prepared;
use crate::common::adam::{Adam, AdamConfig};
use crate::common::tensor::{init_from_rng, sorted_vars, Activation, Mlp};
use rdpg_core::rng::NpRng;

/// FORK's dynamics and reward models, their optimisers and the observation bounds.
pub(super) struct ForkModels {
    pub(super) cfg: ForkConfig,
    pub(super) dynamics_vs: VarStore,
    dynamics: Mlp,
    pub(super) reward_vs: VarStore,
    reward: Mlp,
    pub(super) dynamics_opt: Adam,
    pub(super) reward_opt: Adam,
    /// `(lo, hi)`: the smallest and largest observation value seen in the update batches
    /// (from `(0, 0)`); predictions are clamped to them. Checkpointed.
    pub(super) bounds: (f64, f64),
}

/// What one update's model step reports.
pub(super) struct ModelStep {
    /// The dynamics model's loss on the batch, before its step.
    pub(super) dynamics_loss: f64,
    /// Whether the forward-looking term may be used (`dynamics_loss < threshold`).
    pub(super) use_term: bool,
}

impl ForkModels {
    /// New models for `obs_dim`/`act_dim`, initialised from `rng` (after the agent's own
    /// networks: agents without FORK draw the same numbers as before). `adam` carries the
    /// agent's betas and epsilon; the models use `cfg.lr` and no weight decay.
    pub(super) fn new(
        cfg: &ForkConfig,
        obs_dim: i64,
        act_dim: i64,
        kind: Kind,
        device: tch::Device,
        adam: AdamConfig,
        rng: &mut NpRng,
    ) -> Self {
        let (d, a) = (obs_dim as usize, act_dim as usize);
        let mut dynamics_vs = VarStore::new(device);
        let dynamics = Mlp::new(
            &(dynamics_vs.root() / "fork_dynamics"),
            d + a,
            &cfg.model_hidden,
            "fc",
            Some(d),
            Activation::Relu,
        );
        let mut reward_vs = VarStore::new(device);
        let reward = Mlp::new(
            &(reward_vs.root() / "fork_reward"),
            2 * d + a,
            &cfg.reward_hidden,
            "fc",
            Some(1),
            Activation::Relu,
        );
        if kind == Kind::Double {
            dynamics_vs.double();
            reward_vs.double();
        }
        init_from_rng(&dynamics_vs, rng);
        init_from_rng(&reward_vs, rng);
        let adam = AdamConfig {
            lr: cfg.lr,
            weight_decay: 0.0,
            ..adam
        };
        Self {
            cfg: cfg.clone(),
            dynamics_opt: Adam::new(adam, sorted_vars(&dynamics_vs)),
            reward_opt: Adam::new(adam, sorted_vars(&reward_vs)),
            dynamics_vs,
            dynamics,
            reward_vs,
            reward,
            bounds: (0.0, 0.0),
        }
    }

    /// `F(o, a)` clamped to the bounds: `[M, D]`, `[M, A]` -> `[M, D]`.
    pub(super) fn predict(&self, obs: &Tensor, act: &Tensor) -> Tensor {
        self.dynamics
            .forward(&Tensor::cat(&[obs, act], 1))
            .clamp(self.bounds.0, self.bounds.1)
    }

    /// `R(o, o', a)`: `[M, D]`, `[M, D]`, `[M, A]` -> `[M]`.
    pub(super) fn reward(&self, obs: &Tensor, next: &Tensor, act: &Tensor) -> Tensor {
        self.reward
            .forward(&Tensor::cat(&[obs, next, act], 1))
            .squeeze_dim(-1)
    }

    /// Steps 1 and 2 of the module docs: widens the bounds with the batch's real observations,
    /// then one Adam step for each model.
    pub(super) fn train(&mut self, p: &Prepared) -> ModelStep {
        let (n, l) = (p.n, p.l);
        let kind = p.obs_win.kind();
        let d = p.obs_win.size()[2];
        let a = p.act_win.size()[2];
        let obs = p.obs_win.narrow(1, 0, l).reshape([n * l, d]); // o_i, [M, D]
        let next = p.obs_win.narrow(1, 1, l).reshape([n * l, d]); // o_{i+1}, [M, D]
        let act = p.act_win.reshape([n * l, a]); // [M, A]
        let rew = p.rew.reshape([n * l]); // [M]
        let w = p.mask.reshape([n * l]); // [M], 1 on real rows
        let real = w.sum(kind);
        tch::no_grad(|| {
            let m = w.gt(0.0).unsqueeze(1); // [M, 1]
            let seen = Tensor::cat(&[&obs, &next], 1).masked_select(&m);
            self.bounds.0 = self.bounds.0.min(seen.min().double_value(&[]));
            self.bounds.1 = self.bounds.1.max(seen.max().double_value(&[]));
        });

        let per_row = self
            .predict(&obs, &act)
            .smooth_l1_loss(&next, Reduction::None, 1.0)
            .mean_dim(1, false, kind); // [M]
        let dyn_loss = (per_row * &w).sum(kind) / &real;
        self.dynamics_opt.zero_grad();
        dyn_loss.backward();
        self.dynamics_opt.step();

        let err = self.reward(&obs, &next, &act) - rew; // [M]
        let rew_loss = (&err * &err * &w).sum(kind) / &real;
        self.reward_opt.zero_grad();
        rew_loss.backward();
        self.reward_opt.step();

        let dynamics_loss = dyn_loss.double_value(&[]);
        ModelStep {
            dynamics_loss,
            use_term: dynamics_loss < self.cfg.threshold,
        }
    }

    /// `J_fork` of the module docs (a scalar with gradient for the actor only; multiply by
    /// the weight). `critic` is the first critic, frozen by the caller; `a0` is `mu(o_i)`
    /// with its graph, `[N*l, A]`, as the actor loss computed it.
    pub(super) fn actor_term(
        &mut self,
        actor: &Actor,
        critic: &Critic,
        p: &Prepared,
        a0: &Tensor,
        gamma: f64,
    ) -> Tensor {
        let (n, l) = (p.n, p.l);
        let kind = p.obs_win.kind();
        let d = p.obs_win.size()[2];
        let obs = p.obs_win.narrow(1, 0, l).reshape([n * l, d]); // [M, D]
        let mu = |o: &Tensor| {
            actor
                .step(o, &actor.core.zero_state(n * l, kind, o.device()))
                .0
        };
        let o1 = tch::no_grad(|| self.predict(&obs, a0)); // ô1, [M, D]
        let a1 = mu(&o1);
        let o2 = tch::no_grad(|| self.predict(&o1, &a1)); // ô2
        let a2 = mu(&o2);
        self.reward_vs.freeze();
        let r1 = self.reward(&obs, &o1, a0); // [M]
        let r2 = self.reward(&o1, &o2, &a1);
        self.reward_vs.unfreeze();
        let zero_c = critic.core.zero_state(n * l, kind, obs.device());
        let (q2, _) = critic.step(&o2, &a2, &zero_c); // [M]
        let v = r1 + r2 * gamma + q2 * (gamma * gamma);
        -(v.reshape([n, l]) * &p.actor_w).sum(kind) / n as f64
    }

    /// The models' variables by name (for checkpoints and diagnostics).
    pub(super) fn vars(&self) -> Vec<(String, Tensor)> {
        let mut v = sorted_vars(&self.dynamics_vs);
        v.extend(sorted_vars(&self.reward_vs));
        v
    }
}
