//! Actor and critic networks (paper Section III-D, "Network structure").
//!
//! * **Trunk** (state embedding, per time step): for BipedalWalker the last 10 observation
//!   values are lidar ranges and the first 14 body sensors. Lidar: 1-D convolution
//!   (1 -> 64 channels, kernel 3) + ReLU + max-pool (2) + FC 64 + ReLU; body: FC 14 -> 192 +
//!   ReLU; concatenated (256). Tasks without lidar use an MLP trunk.
//! * **Actor**: trunk -> LSTM 256 -> FC + tanh -> action.
//! * **Critic**: trunk, and an action branch FC act_dim -> 64 + ReLU, concatenated -> LSTM 320
//!   -> linear Q.
//! * **Feed-forward** variants (DDPG, paper Table I): the LSTM replaced by FC + ReLU of the same
//!   width; their recurrent state is empty (zero-width) and passes through unchanged.
//!
//! The paper's text says the LSTM layer comes "with ReLU"; the LSTM output `h = o * tanh(c)` is
//! fed to the head directly here (the project's notes on the authors' released code list
//! "LSTM 256, linear + tanh"). Sequences use libtorch's fused LSTM kernel ([`Lstm::seq`]); single steps (acting, the
//! per-step actor gradient, the states along the window) use `lstm_cell` ([`Lstm::cell`]),
//! measured faster for one step and cheaper in backward.
//!
//! Shapes: `B` batch (windows or environments), `T` time steps, `D` observation size, `A` action
//! size, `E` embedding size, `H` recurrent width. Recurrent states are `[1, B, H]` (libtorch's
//! `[layers, batch, hidden]`). Sequences are batch-first.

use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

use rdpg_core::rng::NpRng;

use crate::config::{RdpgConfig, Trunk};

/// Output layers start small (uniform in `±3e-3`), as in DDPG, so that initial actions and
/// Q-values are near zero.
const HEAD_INIT: f64 = 3e-3;

/// The state of an LSTM core: `h` and `c`, each `[1, B, H]` (zero-width `[1, B, 0]` for a
/// feed-forward core).
#[derive(Debug)]
pub struct RecState {
    /// Hidden state (also the LSTM output), `[1, B, H]`.
    pub h: Tensor,
    /// Cell state, `[1, B, H]`.
    pub c: Tensor,
}

impl RecState {
    /// All-zero state for `batch` sequences of width `hidden`.
    pub fn zeros(batch: i64, hidden: i64, kind: Kind, device: Device) -> Self {
        let z = Tensor::zeros([1, batch, hidden], (kind, device));
        Self { h: z.copy(), c: z }
    }

    /// A second handle to the same tensors.
    pub fn shallow_clone(&self) -> Self {
        Self {
            h: self.h.shallow_clone(),
            c: self.c.shallow_clone(),
        }
    }

    /// The same values, cut from the autograd graph.
    pub fn detach(&self) -> Self {
        Self {
            h: self.h.detach(),
            c: self.c.detach(),
        }
    }

    /// A deep copy.
    pub fn copy(&self) -> Self {
        Self {
            h: self.h.copy(),
            c: self.c.copy(),
        }
    }

    /// Batch size `B`.
    pub fn batch(&self) -> i64 {
        self.h.size()[1]
    }
}

/// A single-layer LSTM on libtorch's fused kernel (oneDNN on CPU, cuDNN on GPU).
///
/// Weights are named and initialised as PyTorch's `nn.LSTM` (`weight_ih_l0 [4H, in]`,
/// `weight_hh_l0 [4H, H]`, two biases `[4H]`, all uniform in `±1/sqrt(H)`; gate order i, f, g, o).
#[derive(Debug)]
pub struct Lstm {
    w_ih: Tensor,
    w_hh: Tensor,
    b_ih: Tensor,
    b_hh: Tensor,
    hidden: i64,
}

impl Lstm {
    /// Creates the four weight tensors under `p`.
    pub fn new(p: &nn::Path, in_dim: i64, hidden: i64) -> Self {
        let k = 1.0 / (hidden as f64).sqrt();
        let init = nn::Init::Uniform { lo: -k, up: k };
        let w_ih = p.var("weight_ih_l0", &[4 * hidden, in_dim], init);
        let w_hh = p.var("weight_hh_l0", &[4 * hidden, hidden], init);
        let b_ih = p.var("bias_ih_l0", &[4 * hidden], init);
        let b_hh = p.var("bias_hh_l0", &[4 * hidden], init);
        let lstm = Self {
            w_ih,
            w_hh,
            b_ih,
            b_hh,
            hidden,
        };
        lstm.flatten_for_cudnn(in_dim);
        lstm
    }

    /// On CUDA, lays the weights out in one contiguous cuDNN buffer (what PyTorch's
    /// `flatten_parameters` does); a no-op on the CPU.
    fn flatten_for_cudnn(&self, in_dim: i64) {
        if self.w_ih.device().is_cuda() && tch::Cuda::cudnn_is_available() {
            let _ = Tensor::internal_cudnn_rnn_flatten_weight(
                &[&self.w_ih, &self.w_hh, &self.b_ih, &self.b_hh],
                4,
                in_dim,
                2, // LSTM
                self.hidden,
                0,
                1,
                true,
                false,
            );
        }
    }

    /// Hidden width `H`.
    pub fn hidden(&self) -> i64 {
        self.hidden
    }

    /// Runs the fused LSTM over `x [B, T, in]` from `s`; returns the outputs `h_t` for every
    /// step, `[B, T, H]`, and the final state.
    pub fn seq(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (out, h, c) = x.lstm(
            &[&s.h, &s.c],
            &[&self.w_ih, &self.w_hh, &self.b_ih, &self.b_hh],
            true,
            1,
            0.0,
            true,
            false,
            true,
        );
        (out, RecState { h, c })
    }

    /// One step with libtorch's `lstm_cell` (composite matmuls + element-wise ops): `x [N, in]`,
    /// `h`, `c` `[N, H]` -> next `(h, c)`. For single steps this beats the fused sequence
    /// kernel, and autograd only computes the gradients actually needed (e.g. none for a
    /// detached state or frozen weights).
    pub fn cell(&self, x: &Tensor, h: &Tensor, c: &Tensor) -> (Tensor, Tensor) {
        x.lstm_cell(
            &[h, c],
            &self.w_ih,
            &self.w_hh,
            Some(&self.b_ih),
            Some(&self.b_hh),
        )
    }
}

/// The part between embedding and head: an LSTM (RDPG) or an FC layer + ReLU (DDPG).
#[derive(Debug)]
pub enum Core {
    /// Recurrent core.
    Lstm(Lstm),
    /// Feed-forward core (`width` outputs); carries no state.
    Ff(nn::Linear, i64),
}

impl Core {
    fn new(p: &nn::Path, recurrent: bool, in_dim: i64, hidden: i64) -> Self {
        if recurrent {
            Core::Lstm(Lstm::new(&(p / "lstm"), in_dim, hidden))
        } else {
            Core::Ff(
                nn::linear(p / "fc", in_dim, hidden, Default::default()),
                hidden,
            )
        }
    }

    /// Whether this core carries a recurrent state.
    pub fn is_recurrent(&self) -> bool {
        matches!(self, Core::Lstm(_))
    }

    /// Width of the recurrent state (0 for a feed-forward core).
    pub fn state_width(&self) -> i64 {
        match self {
            Core::Lstm(l) => l.hidden(),
            Core::Ff(..) => 0,
        }
    }

    /// Width of the output `H`.
    pub fn out_width(&self) -> i64 {
        match self {
            Core::Lstm(l) => l.hidden(),
            Core::Ff(_, w) => *w,
        }
    }

    /// Zero state for `batch` sequences.
    pub fn zero_state(&self, batch: i64, kind: Kind, device: Device) -> RecState {
        RecState::zeros(batch, self.state_width(), kind, device)
    }

    /// `x [B, T, in]` from state `s` -> (`[B, T, H]`, final state). Feed-forward: per step,
    /// the state passes through.
    pub fn seq(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        match self {
            Core::Lstm(l) => l.seq(x, s),
            Core::Ff(fc, _) => (fc.forward(x).relu(), s.shallow_clone()),
        }
    }

    /// One step for a batch: `x [N, in]` from `s` (`[1, N, Hs]`) -> (`[N, H]`, next state).
    /// Recurrent cores use [`Lstm::cell`].
    pub fn step(&self, x: &Tensor, s: &RecState) -> (Tensor, RecState) {
        match self {
            Core::Lstm(l) => {
                let (h, c) = l.cell(x, &s.h.squeeze_dim(0), &s.c.squeeze_dim(0));
                (
                    h.shallow_clone(),
                    RecState {
                        h: h.unsqueeze(0),
                        c: c.unsqueeze(0),
                    },
                )
            }
            Core::Ff(fc, _) => (fc.forward(x).relu(), s.shallow_clone()),
        }
    }

    /// Like [`Core::seq`], one step at a time, also returning the state *before* each step:
    /// `(out [B, T, H], h_before [B, T, Hs], c_before [B, T, Hs], final state)`. Used (without
    /// gradient) to get the carried states the per-step actor gradient treats as constants.
    pub fn stepwise(&self, x: &Tensor, s: &RecState) -> (Tensor, Tensor, Tensor, RecState) {
        let t_len = x.size()[1];
        let (mut h, mut c) = (s.h.squeeze_dim(0), s.c.squeeze_dim(0)); // [B, Hs]
        let mut outs = Vec::with_capacity(t_len as usize);
        let mut hs = Vec::with_capacity(t_len as usize);
        let mut cs = Vec::with_capacity(t_len as usize);
        for t in 0..t_len {
            hs.push(h.shallow_clone());
            cs.push(c.shallow_clone());
            let xt = x.select(1, t);
            match self {
                Core::Lstm(l) => {
                    (h, c) = l.cell(&xt, &h, &c);
                    outs.push(h.shallow_clone());
                }
                Core::Ff(fc, _) => outs.push(fc.forward(&xt).relu()),
            }
        }
        let fin = RecState {
            h: h.unsqueeze(0),
            c: c.unsqueeze(0),
        };
        (
            Tensor::stack(&outs, 1),
            Tensor::stack(&hs, 1),
            Tensor::stack(&cs, 1),
            fin,
        )
    }
}

/// Per-step observation embedding (see the module docs).
#[derive(Debug)]
pub enum TrunkNet {
    /// Lidar convolution branch + body FC branch.
    Lidar {
        /// `Conv1d(1 -> C, k)`.
        conv: nn::Conv1D,
        /// FC on the flattened pooled convolution output.
        lidar_fc: nn::Linear,
        /// FC on the body sensors.
        body_fc: nn::Linear,
        /// Number of body sensors (first values of the observation).
        body_dim: i64,
        /// Number of lidar values (last values of the observation).
        lidar_dim: i64,
    },
    /// MLP with ReLU after every layer.
    Mlp(Vec<nn::Linear>),
}

impl TrunkNet {
    /// Builds the trunk for observations of size `obs_dim`.
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64) -> Self {
        match &cfg.trunk {
            Trunk::Lidar => {
                let lidar_dim = cfg.lidar_dim as i64;
                let ch = cfg.lidar_channels as i64;
                let k = cfg.lidar_kernel as i64;
                let conv = nn::conv1d(p / "lidar_conv", 1, ch, k, Default::default());
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
            Trunk::Mlp { hidden } => {
                let mut layers = Vec::with_capacity(hidden.len());
                let mut in_dim = obs_dim;
                for (i, &w) in hidden.iter().enumerate() {
                    layers.push(nn::linear(
                        p / format!("fc{i}"),
                        in_dim,
                        w as i64,
                        Default::default(),
                    ));
                    in_dim = w as i64;
                }
                TrunkNet::Mlp(layers)
            }
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
                let l = conv
                    .forward(&lidar) // [N, C, 10 - k + 1]
                    .relu()
                    .max_pool1d([2], [2], [0], [1], false) // [N, C, (10 - k + 1) / 2]
                    .flatten(1, 2); // [N, C * P]
                let l = lidar_fc.forward(&l).relu(); // [N, 64]
                let b = body_fc.forward(&body).relu(); // [N, 192]
                Tensor::cat(&[l, b], 1) // [N, 256]
            }
            TrunkNet::Mlp(layers) => {
                let mut x = layers[0].forward(obs).relu();
                for l in &layers[1..] {
                    x = l.forward(&x).relu();
                }
                x
            }
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

/// The policy `mu(o_t | h_{t-1})`: trunk -> core -> FC + tanh.
#[derive(Debug)]
pub struct Actor {
    /// Observation embedding.
    pub trunk: TrunkNet,
    /// LSTM (or FC) core.
    pub core: Core,
    /// Output layer (before tanh).
    pub head: nn::Linear,
}

impl Actor {
    /// Builds the actor's variables under `p`.
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64, act_dim: i64) -> Self {
        let trunk = TrunkNet::new(&(p / "trunk"), cfg, obs_dim);
        let e = cfg.embed_dim() as i64;
        let h = cfg.actor_hidden as i64;
        let core = Core::new(&(p / "core"), cfg.recurrent, e, h);
        let head = head_linear(p / "head", h, act_dim);
        Self { trunk, core, head }
    }

    /// Core input for a sequence: `obs [B, T, D]` -> `[B, T, E]`.
    pub fn input_seq(&self, obs: &Tensor) -> Tensor {
        self.trunk.forward_seq(obs)
    }

    /// Core output -> action: `[.., H]` -> `[.., A]` in `(-1, 1)`.
    pub fn head(&self, y: &Tensor) -> Tensor {
        self.head.forward(y).tanh()
    }

    /// Actions along a sequence: `obs [B, T, D]` from `h0` -> (`[B, T, A]`, final state).
    pub fn forward_seq(&self, obs: &Tensor, h0: &RecState) -> (Tensor, RecState) {
        let (y, s) = self.core.seq(&self.input_seq(obs), h0);
        (self.head(&y), s)
    }

    /// One step for a batch of environments: `obs [B, D]` -> (`[B, A]`, next state).
    pub fn step(&self, obs: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (y, s) = self.core.step(&self.trunk.forward(obs), s);
        (self.head(&y), s)
    }
}

/// The critic `Q(o_t, a_t | h_{t-1})`: (trunk ++ action FC) -> core -> linear.
#[derive(Debug)]
pub struct Critic {
    /// Observation embedding.
    pub trunk: TrunkNet,
    /// Action branch, `A -> critic_action_fc`, ReLU.
    pub act_fc: nn::Linear,
    /// LSTM (or FC) core.
    pub core: Core,
    /// Output layer `H -> 1`.
    pub head: nn::Linear,
}

impl Critic {
    /// Builds the critic's variables under `p`.
    pub fn new(p: &nn::Path, cfg: &RdpgConfig, obs_dim: i64, act_dim: i64) -> Self {
        let trunk = TrunkNet::new(&(p / "trunk"), cfg, obs_dim);
        let af = cfg.critic_action_fc as i64;
        let act_fc = nn::linear(p / "act_fc", act_dim, af, Default::default());
        let e = cfg.embed_dim() as i64 + af;
        let h = cfg.critic_hidden as i64;
        let core = Core::new(&(p / "core"), cfg.recurrent, e, h);
        let head = head_linear(p / "head", h, 1);
        Self {
            trunk,
            act_fc,
            core,
            head,
        }
    }

    /// Core input: `obs [B, T, D]`, `act [B, T, A]` -> `[B, T, E + 64]`.
    pub fn input_seq(&self, obs: &Tensor, act: &Tensor) -> Tensor {
        let e = self.trunk.forward_seq(obs);
        let a = self.act_fc.forward(act).relu();
        Tensor::cat(&[e, a], 2)
    }

    /// Core output -> Q: `[.., H]` -> `[..]`.
    pub fn head(&self, y: &Tensor) -> Tensor {
        self.head.forward(y).squeeze_dim(-1)
    }

    /// Q along a sequence: `obs [B, T, D]`, `act [B, T, A]` from `h0` -> (`[B, T]`, final
    /// state).
    pub fn forward_seq(&self, obs: &Tensor, act: &Tensor, h0: &RecState) -> (Tensor, RecState) {
        let (y, s) = self.core.seq(&self.input_seq(obs, act), h0);
        (self.head(&y), s)
    }

    /// Core input for single steps: `obs [N, D]`, `act [N, A]` -> `[N, E + 64]`.
    pub fn input(&self, obs: &Tensor, act: &Tensor) -> Tensor {
        let e = self.trunk.forward(obs);
        let a = self.act_fc.forward(act).relu();
        Tensor::cat(&[e, a], 1)
    }

    /// One step: `obs [B, D]`, `act [B, A]` -> (`[B]`, next state).
    pub fn step(&self, obs: &Tensor, act: &Tensor, s: &RecState) -> (Tensor, RecState) {
        let (y, s) = self.core.step(&self.input(obs, act), s);
        (self.head(&y), s)
    }
}

/// Re-initialises every variable of `vs` from `rng` (uniform, PyTorch's default bounds), so
/// that initial weights depend only on the seed: not on libtorch's process-wide generator,
/// other threads, or the libtorch version.
///
/// Bounds: output layers (`*.head.*`) `±3e-3`; LSTM weights and biases `±1/sqrt(H)`; other
/// weights and biases (linear, convolution) `±1/sqrt(fan_in)` with `fan_in` the product of the
/// weight's dimensions after the first. Variables are visited in name order, each filled
/// row-major.
pub fn init_from_rng(vs: &nn::VarStore, rng: &mut NpRng) {
    let vars = vs.variables();
    let mut names: Vec<&String> = vars.keys().collect();
    names.sort();
    for name in names {
        let var = &vars[name];
        let (stem, leaf) = name.rsplit_once('.').unwrap_or(("", name.as_str()));
        let bound = if stem.ends_with("head") {
            HEAD_INIT
        } else if stem.ends_with("lstm") {
            let h = var.size()[0] / 4;
            1.0 / (h as f64).sqrt()
        } else {
            let weight = if leaf == "bias" {
                &vars[&format!("{stem}.weight")]
            } else {
                var
            };
            let fan_in: i64 = weight.size()[1..].iter().product();
            1.0 / (fan_in.max(1) as f64).sqrt()
        };
        let vals: Vec<f64> = (0..var.numel())
            .map(|_| rng.uniform(-bound, bound))
            .collect();
        let t = Tensor::from_slice(&vals)
            .view(var.size().as_slice())
            .to_kind(var.kind())
            .to_device(var.device());
        let mut v = var.shallow_clone();
        tch::no_grad(|| v.copy_(&t));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn stepwise_matches_fused() {
        tch::manual_seed(1);
        let vs = nn::VarStore::new(Device::Cpu);
        let l = Lstm::new(&vs.root(), 5, 6);
        let x = Tensor::randn([2, 4, 5], (Kind::Float, Device::Cpu));
        let h0 = RecState {
            h: Tensor::randn([1, 2, 6], (Kind::Float, Device::Cpu)),
            c: Tensor::randn([1, 2, 6], (Kind::Float, Device::Cpu)),
        };
        let (out, fin) = l.seq(&x, &h0);
        let core = Core::Lstm(l);
        let (out2, hb, cb, fin2) = core.stepwise(&x, &h0);
        assert!(out.allclose(&out2, 1e-5, 1e-6, false));
        assert!(fin.c.allclose(&fin2.c, 1e-5, 1e-6, false));
        // The state before step t+1 is the output of step t.
        assert!(hb
            .narrow(1, 1, 3)
            .allclose(&out.narrow(1, 0, 3), 1e-5, 1e-6, false));
        assert!(cb
            .select(1, 0)
            .allclose(&h0.c.squeeze_dim(0), 0.0, 0.0, false));
    }
}
