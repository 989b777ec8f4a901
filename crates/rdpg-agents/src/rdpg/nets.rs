//! Actor and critic networks (paper Section III-D, "Network structure").
//!
//! * **Trunk** (state embedding, per time step): for BipedalWalker the last 10 observation
//!   values are lidar ranges and the first 14 body sensors. Lidar: 1-D convolution
//!   (1 -> 64 channels, kernel 3) + ReLU + max-pool (2) + FC 64 + ReLU; body: FC 14 -> 192 +
//!   ReLU; concatenated (256). Tasks without lidar use an MLP trunk.
//! * **Actor**: trunk -> LSTM 256 -> FC + tanh -> action.
//! * **Critic**: trunk, and an action branch FC act_dim -> 64 + ReLU, concatenated -> LSTM 320
//!   -> linear Q. With `critic_action_fc = 0` (MLP trunks only) there is no action branch: the
//!   raw action is concatenated with the observation at the trunk's input, as in the critics of
//!   TD3 (Fujimoto et al. 2018) and Stable-Baselines3.
//! * **Head options** (the project's, not the paper's): `actor_head` / `critic_head` put hidden
//!   FC + ReLU layers between the core and the output layer, and `core_skip` feeds the head the
//!   core's input beside its output, `[x_t, y_t]`, so that a recurrent network contains its
//!   feed-forward twin (trunk -> head).
//! * **Feed-forward** variants (DDPG, paper Table I): the LSTM replaced by FC + ReLU of the same
//!   width; their recurrent state is empty (zero-width) and passes through unchanged.
//!
//! The paper's text says the LSTM layer comes "with ReLU"; the LSTM output `h = o * tanh(c)` is
//! fed to the head directly here (the project's notes on the authors' released code list
//! "LSTM 256, linear + tanh"). The recurrent core and how it runs sequences and single steps
//! are in [`super::lstm`].
//!
//! Shapes: `B` batch (windows or environments), `T` time steps, `D` observation size, `A` action
//! size, `E` embedding size, `H` recurrent width. Recurrent states are `[1, B, H]` (libtorch's
//! `[layers, batch, hidden]`). Sequences are batch-first.

use tch::nn::{self, Module};
use tch::Tensor;

use super::config::{RdpgConfig, Trunk, LOG_STD_RANGE};
use super::lstm::{Core, RecState};
use crate::common::tensor::{linear_handle, Activation, Mlp, HEAD_INIT};

/// Per-step observation embedding (see the module docs).
#[derive(Debug)]
pub enum TrunkNet {
    /// Lidar convolution branch + body FC branch.
    Lidar {
        /// `Conv1d(1 -> C, k)` weights `[C, 1, k]` and bias `[C]` (stride 1, no padding).
        conv: (Tensor, Tensor),
        /// FC on the flattened pooled convolution output.
        lidar_fc: nn::Linear,
        /// FC on the body sensors.
        body_fc: nn::Linear,
        /// Number of body sensors (first values of the observation).
        body_dim: i64,
        /// Number of lidar values (last values of the observation).
        lidar_dim: i64,
    },
    /// MLP with ReLU after every layer (layers `fc0`, `fc1`, ...).
    Mlp(Mlp),
}

impl TrunkNet {
    /// A second handle on the same parameters (no copy), for another thread.
    pub fn shallow_clone(&self) -> Self {
        match self {
            TrunkNet::Lidar {
                conv,
                lidar_fc,
                body_fc,
                body_dim,
                lidar_dim,
            } => TrunkNet::Lidar {
                conv: (conv.0.shallow_clone(), conv.1.shallow_clone()),
                lidar_fc: linear_handle(lidar_fc),
                body_fc: linear_handle(body_fc),
                body_dim: *body_dim,
                lidar_dim: *lidar_dim,
            },
            TrunkNet::Mlp(m) => TrunkNet::Mlp(m.shallow_clone()),
        }
    }

    /// Builds the trunk for observations of size `obs_dim`.
    #[allow(
        clippy::expect_used,
        reason = "the lidar convolution is built with a bias"
    )]
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64) -> Self {
        match &cfg.trunk {
            Trunk::Lidar => {
                let lidar_dim = cfg.lidar_dim as i64;
                let ch = cfg.lidar_channels as i64;
                let k = cfg.lidar_kernel as i64;
                let c = nn::conv1d(p / "lidar_conv", 1, ch, k, Default::default());
                let conv = (c.ws, c.bs.expect("a convolution with bias"));
                let pooled = (lidar_dim - k + 1) / 2;
                let lidar_fc = nn::linear(
                    p / "lidar_fc",
                    ch * pooled,
                    cfg.lidar_fc as i64,
                    Default::default(),
                );
                let body_dim = obs_dim - lidar_dim;
                let body_fc = nn::linear(
                    p / "body_fc",
                    body_dim,
                    cfg.body_fc as i64,
                    Default::default(),
                );
                TrunkNet::Lidar {
                    conv,
                    lidar_fc,
                    body_fc,
                    body_dim,
                    lidar_dim,
                }
            }
            Trunk::Mlp { hidden } => TrunkNet::Mlp(Mlp::new(
                p,
                obs_dim as usize,
                hidden,
                "fc",
                None,
                Activation::Relu,
            )),
        }
    }

    /// `obs [N, D]` -> embedding `[N, E]`.
    pub fn forward(&self, obs: &Tensor) -> Tensor {
        match self {
            TrunkNet::Lidar {
                conv,
                lidar_fc,
                body_fc,
                body_dim,
                lidar_dim,
            } => {
                let body = obs.narrow(1, 0, *body_dim); // [N, 14]
                let lidar = obs.narrow(1, *body_dim, *lidar_dim).unsqueeze(1); // [N, 1, 10]
                let l = lidar
                    .conv1d(&conv.0, Some(&conv.1), [1], [0], [1], 1) // [N, C, 10 - k + 1]
                    .relu()
                    .max_pool1d([2], [2], [0], [1], false) // [N, C, (10 - k + 1) / 2]
                    .flatten(1, 2); // [N, C * P]
                let l = lidar_fc.forward(&l).relu(); // [N, 64]
                let b = body_fc.forward(&body).relu(); // [N, 192]
                Tensor::cat(&[l, b], 1) // [N, 256]
            }
            TrunkNet::Mlp(mlp) => mlp.forward(obs),
        }
    }

    /// `obs [B, T, D]` -> `[B, T, E]`.
    pub fn forward_seq(&self, obs: &Tensor) -> Tensor {
        let s = obs.size();
        let e = self.forward(&obs.reshape([s[0] * s[1], s[2]]));
        let e_dim = e.size()[1];
        e.reshape([s[0], s[1], e_dim])
    }
}

/// The head's input: the core's output `y [.., H]`, after its input `x [.., E]` with
/// `core_skip` (`[.., E + H]`).
fn head_input(skip: bool, x: &Tensor, y: &Tensor) -> Tensor {
    if skip {
        Tensor::cat(&[x, y], -1)
    } else {
        y.shallow_clone()
    }
}

/// A network's head under `p`: hidden layers `head_mlp.fc{i}` (FC + ReLU, `hidden` widths)
/// from the core's output of width `h` (with `skip`, `e + h`: its input too; plus `extra`
/// inputs, a critic's action after its core), then the output layer `head` to `out`.
fn head_layers(
    p: &nn::Path,
    skip: bool,
    (e, h, extra): (i64, i64, i64),
    hidden: &[usize],
    out: i64,
) -> (Mlp, nn::Linear) {
    let input = h + extra + if skip { e } else { 0 };
    let mlp = Mlp::new(
        &(p / "head_mlp"),
        input as usize,
        hidden,
        "fc",
        None,
        Activation::Relu,
    );
    let last = hidden.last().map_or(input, |&w| w as i64);
    (mlp, head_linear(p / "head", last, out))
}

fn head_linear(p: nn::Path, in_dim: i64, out_dim: i64) -> nn::Linear {
    let init = nn::Init::Uniform {
        lo: -HEAD_INIT,
        up: HEAD_INIT,
    };
    nn::linear(
        p,
        in_dim,
        out_dim,
        nn::LinearConfig {
            ws_init: init,
            bs_init: Some(init),
            bias: true,
        },
    )
}

/// The policy `mu(o_t | h_{t-1})`: trunk -> core -> FC + tanh. A SAC actor (`gaussian`) is a
/// squashed Gaussian: its output layer gives `[m, log s]` (`2A` values) and its deterministic
/// action is `tanh(m)`.
#[derive(Debug)]
pub struct Actor {
    /// Observation embedding.
    pub trunk: TrunkNet,
    /// LSTM (or FC) core.
    pub core: Core,
    /// Hidden layers between the core and the output layer (`actor_head`; none by default).
    pub head_mlp: Mlp,
    /// Whether the head reads the core's input beside its output (`core_skip`).
    pub skip: bool,
    /// Output layer (before tanh).
    pub head: nn::Linear,
    /// Whether the output layer gives a Gaussian's mean and log standard deviation (SAC).
    pub gaussian: bool,
    /// Action size `A`.
    pub act_dim: i64,
}

impl Actor {
    /// A second handle on the same parameters (no copy), for another thread.
    pub fn shallow_clone(&self) -> Self {
        Self {
            trunk: self.trunk.shallow_clone(),
            core: self.core.shallow_clone(),
            head_mlp: self.head_mlp.shallow_clone(),
            skip: self.skip,
            head: linear_handle(&self.head),
            gaussian: self.gaussian,
            act_dim: self.act_dim,
        }
    }

    /// Builds the actor's variables under `p`.
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64, act_dim: i64) -> Self {
        let trunk = TrunkNet::new(&(p / "trunk"), cfg, obs_dim);
        let e = cfg.embed_dim() as i64;
        let h = cfg.actor_hidden as i64;
        let core = Core::new(&(p / "core"), cfg.recurrent, e, h);
        let gaussian = cfg.sac.is_some();
        let out = if gaussian { 2 * act_dim } else { act_dim };
        let (head_mlp, head) = head_layers(p, cfg.core_skip, (e, h, 0), &cfg.actor_head, out);
        Self {
            trunk,
            core,
            head_mlp,
            skip: cfg.core_skip,
            head,
            gaussian,
            act_dim,
        }
    }

    /// Core input for a sequence: `obs [B, T, D]` -> `[B, T, E]`.
    pub fn input_seq(&self, obs: &Tensor) -> Tensor {
        self.trunk.forward_seq(obs)
    }

    /// Core input and output -> action: `x [.., E]`, `y [.., H]` -> `[.., A]` in `(-1, 1)`
    /// (`x` is read only with `core_skip`).
    /// For a SAC actor, the deterministic action `tanh(m)`.
    pub fn head(&self, x: &Tensor, y: &Tensor) -> Tensor {
        let out = self
            .head
            .forward(&self.head_mlp.forward(&head_input(self.skip, x, y)));
        match self.gaussian {
            true => out.narrow(-1, 0, self.act_dim).tanh(),
            false => out.tanh(),
        }
    }

    /// A SAC actor's Gaussian before the squashing: `x [.., E]`, `y [.., H]` -> (mean
    /// `[.., A]`, log standard deviation `[.., A]` clamped to [`LOG_STD_RANGE`]).
    pub fn gaussian(&self, x: &Tensor, y: &Tensor) -> (Tensor, Tensor) {
        debug_assert!(self.gaussian, "a deterministic actor has no Gaussian");
        let out = self
            .head
            .forward(&self.head_mlp.forward(&head_input(self.skip, x, y)));
        let (lo, hi) = LOG_STD_RANGE;
        (
            out.narrow(-1, 0, self.act_dim),
            out.narrow(-1, self.act_dim, self.act_dim).clamp(lo, hi),
        )
    }

    /// Actions along a sequence: `obs [B, T, D]` from `h0` -> (`[B, T, A]`, final state).
    pub fn forward_seq(&self, obs: &Tensor, h0: &RecState) -> (Tensor, RecState) {
        let x = self.input_seq(obs);
        let (y, s) = self.core.seq(&x, h0);
        (self.head(&x, &y), s)
    }

    /// One step for a batch of environments: `obs [B, D]` -> (`[B, A]`, next state).
    pub fn step(&self, obs: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (x, y, s) = self.features(obs, s);
        (self.head(&x, &y), s)
    }

    /// One step's core input and output: `obs [B, D]` -> (`x [B, E]`, `y [B, H]`, next
    /// state), what [`Actor::head`] and [`Actor::gaussian`] read.
    pub fn features(&self, obs: &Tensor, s: &RecState) -> (Tensor, Tensor, RecState) {
        let x = self.trunk.forward(obs);
        let (y, s) = self.core.step(&x, s);
        (x, y, s)
    }
}

/// The critic `Q(o_t, a_t | h_{t-1})`: (trunk ++ action FC) -> core -> linear, or with the
/// action after the core, trunk -> core -> (`[y_t, a_t]`) -> linear.
#[derive(Debug)]
pub struct Critic {
    /// Observation embedding.
    pub trunk: TrunkNet,
    /// Action branch, `A -> critic_action_fc`, ReLU; `None` when the action enters at the
    /// trunk's input (`critic_action_fc = 0`).
    pub act_fc: Option<nn::Linear>,
    /// LSTM (or FC) core.
    pub core: Core,
    /// Hidden layers between the core and the output layer (`critic_head`; none by default).
    pub head_mlp: Mlp,
    /// Whether the head reads the core's input beside its output (`core_skip`).
    pub skip: bool,
    /// Output layer `H -> M` (from the last head layer, or `E + H` with `core_skip`): `M = 1`,
    /// the value, or TQC's `M` atoms (`sac.tqc.quantiles`), whose mean is the value.
    pub head: nn::Linear,
    /// Whether the action joins after the core, at the head's input
    /// (`critic_action_after_core`) instead of before it.
    pub action_after_core: bool,
}

impl Critic {
    /// A second handle on the same parameters (no copy), for another thread: gradients of
    /// its outputs accumulate into the same parameters' gradients.
    pub fn shallow_clone(&self) -> Self {
        Self {
            trunk: self.trunk.shallow_clone(),
            act_fc: self.act_fc.as_ref().map(linear_handle),
            core: self.core.shallow_clone(),
            head_mlp: self.head_mlp.shallow_clone(),
            skip: self.skip,
            head: linear_handle(&self.head),
            action_after_core: self.action_after_core,
        }
    }

    /// Builds the critic's variables under `p`.
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64, act_dim: i64) -> Self {
        let af = cfg.critic_action_fc as i64;
        let after = cfg.critic_action_after_core;
        let (trunk, act_fc) = if after {
            (TrunkNet::new(&(p / "trunk"), cfg, obs_dim), None)
        } else if af == 0 {
            (TrunkNet::new(&(p / "trunk"), cfg, obs_dim + act_dim), None)
        } else {
            let fc = nn::linear(p / "act_fc", act_dim, af, Default::default());
            (TrunkNet::new(&(p / "trunk"), cfg, obs_dim), Some(fc))
        };
        let e = cfg.embed_dim() as i64 + af;
        let h = cfg.critic_hidden as i64;
        let core = Core::new(&(p / "core"), cfg.recurrent, e, h);
        let extra = if after { act_dim } else { 0 };
        let out = cfg.critic_outputs() as i64;
        let (head_mlp, head) = head_layers(p, cfg.core_skip, (e, h, extra), &cfg.critic_head, out);
        Self {
            trunk,
            act_fc,
            core,
            head_mlp,
            skip: cfg.core_skip,
            head,
            action_after_core: after,
        }
    }

    /// Core input: `obs [B, T, D]`, `act [B, T, A]` -> `[B, T, E + 64]` (`[B, T, E]` without
    /// an action branch, or with the action after the core, where `act` is not read).
    pub fn input_seq(&self, obs: &Tensor, act: &Tensor) -> Tensor {
        if self.action_after_core {
            return self.trunk.forward_seq(obs);
        }
        match &self.act_fc {
            Some(fc) => {
                let e = self.trunk.forward_seq(obs);
                let a = fc.forward(act).relu();
                Tensor::cat(&[e, a], 2)
            }
            None => self.trunk.forward_seq(&Tensor::cat(&[obs, act], 2)), // [B, T, D + A] in
        }
    }

    /// Core input and output (and the action) -> the output layer's `M` values: `x [.., E]`,
    /// `y [.., H]`, `act [.., A]` -> `[.., M]` (`x` is read only with `core_skip`, `act` only
    /// with the action after the core).
    pub fn atoms(&self, x: &Tensor, y: &Tensor, act: &Tensor) -> Tensor {
        let mut input = head_input(self.skip, x, y);
        if self.action_after_core {
            input = Tensor::cat(&[input, act.shallow_clone()], -1);
        }
        self.head.forward(&self.head_mlp.forward(&input))
    }

    /// The value of the output layer's values `[.., M]`: `[..]`, the one value or the mean of
    /// TQC's atoms.
    pub fn value(z: &Tensor) -> Tensor {
        if z.size().last() == Some(&1) {
            z.squeeze_dim(-1)
        } else {
            z.mean_dim(-1, false, z.kind())
        }
    }

    /// Q from the core's input and output (and the action): `[..]` (see [`Critic::atoms`]).
    pub fn head(&self, x: &Tensor, y: &Tensor, act: &Tensor) -> Tensor {
        Self::value(&self.atoms(x, y, act))
    }

    /// The output layer's values along a sequence: `obs [B, T, D]`, `act [B, T, A]` from `h0`
    /// -> (`[B, T, M]`, final state).
    pub fn atoms_seq(&self, obs: &Tensor, act: &Tensor, h0: &RecState) -> (Tensor, RecState) {
        let x = self.input_seq(obs, act);
        let (y, s) = self.core.seq(&x, h0);
        (self.atoms(&x, &y, act), s)
    }

    /// Q along a sequence: `obs [B, T, D]`, `act [B, T, A]` from `h0` -> (`[B, T]`, final
    /// state).
    pub fn forward_seq(&self, obs: &Tensor, act: &Tensor, h0: &RecState) -> (Tensor, RecState) {
        let (z, s) = self.atoms_seq(obs, act, h0);
        (Self::value(&z), s)
    }

    /// Core input for single steps: `obs [N, D]`, `act [N, A]` -> `[N, E + 64]` (`[N, E]`
    /// without an action branch, or with the action after the core).
    pub fn input(&self, obs: &Tensor, act: &Tensor) -> Tensor {
        if self.action_after_core {
            return self.trunk.forward(obs);
        }
        match &self.act_fc {
            Some(fc) => {
                let e = self.trunk.forward(obs);
                let a = fc.forward(act).relu();
                Tensor::cat(&[e, a], 1)
            }
            None => self.trunk.forward(&Tensor::cat(&[obs, act], 1)), // [N, D + A] in
        }
    }

    /// One step's output-layer values: `obs [B, D]`, `act [B, A]` -> (`[B, M]`, next state).
    pub fn atoms_step(&self, obs: &Tensor, act: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let x = self.input(obs, act);
        let (y, s) = self.core.step(&x, s);
        (self.atoms(&x, &y, act), s)
    }

    /// One step: `obs [B, D]`, `act [B, A]` -> (`[B]`, next state).
    pub fn step(&self, obs: &Tensor, act: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (z, s) = self.atoms_step(obs, act, s);
        (Self::value(&z), s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    fn cfg_small() -> RdpgConfig {
        RdpgConfig {
            lidar_channels: 4,
            lidar_fc: 5,
            body_fc: 6,
            actor_hidden: 7,
            critic_hidden: 9,
            critic_action_fc: 3,
            ..Default::default()
        }
    }

    #[test]
    fn shapes_lidar_and_mlp() {
        tch::manual_seed(0);
        for cfg in [
            cfg_small(),
            RdpgConfig {
                trunk: Trunk::Mlp { hidden: vec![8, 6] },
                ..cfg_small()
            },
            RdpgConfig {
                trunk: Trunk::Mlp { hidden: vec![8] },
                critic_action_fc: 0,
                ..cfg_small()
            },
        ] {
            for recurrent in [true, false] {
                let cfg = RdpgConfig {
                    recurrent,
                    ..cfg.clone()
                };
                let vs = nn::VarStore::new(Device::Cpu);
                let actor = Actor::new(&(vs.root() / "a"), &cfg, 24, 4);
                let critic = Critic::new(&(vs.root() / "c"), &cfg, 24, 4);
                let obs = Tensor::randn([3, 5, 24], (Kind::Float, Device::Cpu));
                let act = Tensor::randn([3, 5, 4], (Kind::Float, Device::Cpu));
                let h0 = actor.core.zero_state(3, Kind::Float, Device::Cpu);
                let (a, s) = actor.forward_seq(&obs, &h0);
                assert_eq!(a.size(), [3, 5, 4]);
                assert_eq!(s.h.size(), [1, 3, if recurrent { 7 } else { 0 }]);
                let h0 = critic.core.zero_state(3, Kind::Float, Device::Cpu);
                let (q, _) = critic.forward_seq(&obs, &act, &h0);
                assert_eq!(q.size(), [3, 5]);
                let (q1, _) = critic.step(&obs.select(1, 0), &act.select(1, 0), &h0);
                assert_eq!(q1.size(), [3]);
                assert!(q1.allclose(&q.select(1, 0), 1e-6, 1e-6, false));
            }
        }
    }

    /// `critic_action_fc = 0` is TD3's critic: the trunk's first layer reads `obs ++ act`, there
    /// is no action branch, and Q depends on the action.
    #[test]
    fn critic_with_the_action_at_its_input() {
        tch::manual_seed(1);
        let cfg = RdpgConfig {
            trunk: Trunk::Mlp { hidden: vec![8] },
            critic_action_fc: 0,
            recurrent: false,
            ..cfg_small()
        };
        cfg.validate().unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = Critic::new(&(vs.root() / "c"), &cfg, 24, 4);
        assert!(critic.act_fc.is_none());
        let vars = vs.variables();
        assert_eq!(vars["c.trunk.fc0.weight"].size(), [8, 28]);
        assert!(!vars.keys().any(|k| k.contains("act_fc")));
        let obs = Tensor::randn([5, 24], (Kind::Float, Device::Cpu));
        let act = Tensor::randn([5, 4], (Kind::Float, Device::Cpu)).set_requires_grad(true);
        let h0 = critic.core.zero_state(5, Kind::Float, Device::Cpu);
        let (q, _) = critic.step(&obs, &act, &h0);
        q.sum(Kind::Float).backward();
        assert!(f64::try_from(act.grad().abs().sum(Kind::Float)).unwrap() > 0.0);

        let lidar = RdpgConfig {
            critic_action_fc: 0,
            ..cfg_small()
        };
        let err = lidar.validate().unwrap_err().to_string();
        assert!(err.contains("critic_action_fc"), "{err}");
    }

    /// `critic_action_after_core`: the core reads observations only (its state is the same
    /// whatever the actions), the action joins at the head, and Q depends on it; with the
    /// lidar trunk too; an action branch alongside is refused, and so is a critic without a
    /// head (Q linear in the action).
    #[test]
    fn critic_with_the_action_after_its_core() {
        tch::manual_seed(2);
        let cfg = RdpgConfig {
            critic_action_fc: 0,
            critic_action_after_core: true,
            critic_head: vec![5],
            ..cfg_small()
        };
        cfg.validate().unwrap();
        let vs = nn::VarStore::new(Device::Cpu);
        let critic = Critic::new(&(vs.root() / "c"), &cfg, 24, 4);
        let vars = vs.variables();
        assert_eq!(vars["c.head_mlp.fc0.weight"].size(), [5, 9 + 4]);
        assert_eq!(vars["c.trunk.body_fc.weight"].size(), [6, 14]);
        let obs = Tensor::randn([3, 5, 24], (Kind::Float, Device::Cpu));
        let a1 = Tensor::randn([3, 5, 4], (Kind::Float, Device::Cpu));
        let a2 = Tensor::randn([3, 5, 4], (Kind::Float, Device::Cpu));
        let h0 = critic.core.zero_state(3, Kind::Float, Device::Cpu);
        let (q1, s1) = critic.forward_seq(&obs, &a1, &h0);
        let (q2, s2) = critic.forward_seq(&obs, &a2, &h0);
        assert!(s1.h.equal(&s2.h) && s1.c.equal(&s2.c));
        assert!(!q1.allclose(&q2, 1e-4, 1e-4, false));
        let (q, _) = critic.step(&obs.select(1, 0), &a1.select(1, 0), &h0);
        assert!(q.allclose(&q1.select(1, 0), 1e-6, 1e-6, false));

        let branch = RdpgConfig {
            critic_action_fc: 8,
            ..cfg.clone()
        };
        let err = branch.validate().unwrap_err().to_string();
        assert!(err.contains("critic_action_after_core"), "{err}");
        let headless = RdpgConfig {
            critic_head: vec![],
            ..cfg
        };
        let err = headless.validate().unwrap_err().to_string();
        assert!(
            err.contains("critic_action_after_core") && err.contains("linear in the action"),
            "{err}"
        );
    }
}
