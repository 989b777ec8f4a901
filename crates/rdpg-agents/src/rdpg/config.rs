//! Hyper-parameters of the RDPG (and feed-forward DDPG) learner.
//!
//! Defaults follow the paper's text (Song et al., ICARCV 2018, "Network structure" and Table I)
//! and the authors' released code where the text is silent: actor LSTM 256, critic LSTM 320,
//! critic action branch 64, body FC 192, 64 lidar convolution channels, Adam 1e-3 for both
//! networks, critic L2 1e-5, gamma 0.99, batch 64, optimisation/update length 8/8, scan 24 (the
//! paper's Table I run used 120), lambda 1 and no target networks (`tau = 0`).

use crate::common::config::is_f32;
use serde::{Deserialize, Serialize};

pub use super::options::{ActorWeights, CriticTarget, ScanMethod};
pub use super::sac_config::{SacConfig, TqcConfig, LOG_STD_RANGE};
use crate::common::tensor::DeviceSpec;
use crate::error::{AgentError, Result};

/// How observations are embedded before the recurrent core (the "state embedding").
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Trunk {
    /// BipedalWalker layout: the first `obs_dim - lidar_dim` values are body sensors (14 for
    /// BipedalWalker), the last `lidar_dim` values are lidar ranges (10). Lidar: 1-D
    /// convolution + ReLU + max-pool + FC(`lidar_fc`) + ReLU; body: FC(`body_fc`) + ReLU;
    /// the two are concatenated.
    Lidar,
    /// A plain multi-layer perceptron (ReLU after every layer), for tasks without lidar such as
    /// Pendulum with hidden velocity (`obs_dim = 2`).
    Mlp {
        /// Width of each hidden layer; the last one is the embedding size. Must be non-empty.
        hidden: Vec<usize>,
    },
}

/// Target policy smoothing (TD3): clipped Gaussian noise on the bootstrap action.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetNoise {
    /// Standard deviation of the Gaussian noise added to the target action.
    pub std: f64,
    /// The noise is clipped to `[-clip, clip]` before being added; the action is then clipped
    /// to `[-1, 1]`.
    pub clip: f64,
}

/// FORK's forward-looking actor (Wei & Ying, "FORK: A Forward-Looking Actor for Model-Free
/// Reinforcement Learning", 2021; TD3-FORK): a dynamics model `F(o, a) -> o'` and a reward
/// model `R(o, o', a) -> r`, both MLPs trained on every update's batch, and on the actor's
/// turn, while the dynamics model's loss is below `threshold`, an extra actor loss term that
/// looks two model steps ahead (see `fork.rs`). Feed-forward agents only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ForkConfig {
    /// Weight `w` of the forward-looking term in the actor loss. TD3-FORK: 0.5.
    pub weight: f64,
    /// The term is used on an update only when that update's dynamics-model loss (smooth L1,
    /// before the model's step) is below this. TD3-FORK: 0.02.
    pub threshold: f64,
    /// Hidden widths of the dynamics model (ReLU). TD3-FORK: 400, 300.
    pub model_hidden: Vec<usize>,
    /// Hidden widths of the reward model (ReLU). TD3-FORK: 256, 256.
    pub reward_hidden: Vec<usize>,
    /// Adam learning rate of both models. TD3-FORK: 3e-4.
    pub lr: f64,
}

impl Default for ForkConfig {
    fn default() -> Self {
        Self {
            weight: 0.5,
            threshold: 0.02,
            model_hidden: vec![400, 300],
            reward_hidden: vec![256, 256],
            lr: 3e-4,
        }
    }
}

/// All hyper-parameters of [`RdpgAgent`](super::RdpgAgent). Every field has a default (see
/// [`RdpgConfig::default`]); a JSON config may give any subset, unknown fields are rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RdpgConfig {
    /// Observation embedding used by both actor and critic (each has its own weights).
    pub trunk: Trunk,
    /// Number of lidar values at the end of the observation (`Lidar` trunk only). Default 10.
    pub lidar_dim: usize,
    /// Output channels of the lidar 1-D convolution (`Lidar` trunk). Paper: 64.
    pub lidar_channels: usize,
    /// Kernel size of the lidar convolution (`Lidar` trunk); max-pool has kernel = stride = 2.
    /// Default 3.
    pub lidar_kernel: usize,
    /// Width of the FC layer after the lidar convolution and pooling (`Lidar` trunk). Paper: 64.
    pub lidar_fc: usize,
    /// Width of the FC layer on the body sensors (`Lidar` trunk). Paper: 192.
    pub body_fc: usize,
    /// `true`: recurrent RDPG (LSTM cores). `false`: feed-forward DDPG, the LSTM replaced by an
    /// FC layer (+ ReLU) of the same width (paper Table I "DDPG"); scan and states are then
    /// no-ops.
    pub recurrent: bool,
    /// Added to the forget-gate bias of every LSTM at initialisation (PyTorch's init plus this
    /// constant; the bias stays trainable). 0 = PyTorch's `nn.LSTM` init (the default); the
    /// authors' TensorFlow code used `forget_bias = 1.0`, a constant added to the forget gate
    /// at every step, which this reproduces at the start of training. The `hardcore-*`
    /// configs use 1.0, the others 0.
    pub lstm_forget_bias: f64,
    /// Actor LSTM (or FC) width. Paper: 256.
    pub actor_hidden: usize,
    /// Critic LSTM (or FC) width. Paper: 320.
    pub critic_hidden: usize,
    /// Width of the critic's action branch (FC + ReLU on the action, concatenated with the
    /// trunk's embedding). Paper: 64. `0`: no branch, the raw action is concatenated with the
    /// observation at the trunk's input, as in TD3's and Stable-Baselines3's critics (needs an
    /// MLP trunk).
    pub critic_action_fc: usize,
    /// The action enters the critic after its core, beside the core's output, at the head's
    /// input (`[y_t, a_t]`, with `core_skip` `[x_t, y_t, a_t]`): the core (the LSTM) reads
    /// observations only, so the critic's state summarises the observation history, as in the
    /// public recurrent Hardcore agents (Özalp's LSTM critics). Needs `critic_action_fc = 0`
    /// (the raw action joins) and a `critic_head` (without one Q is linear in the action);
    /// any trunk.
    pub critic_action_after_core: bool,
    /// Hidden layers (FC + ReLU) between the actor's core and its output layer; empty (the
    /// default, the paper's): the output layer reads the core directly.
    pub actor_head: Vec<usize>,
    /// Hidden layers (FC + ReLU) between each critic's core and its output layer; empty by
    /// default.
    pub critic_head: Vec<usize>,
    /// The head (hidden layers or output layer) reads the core's input beside its output,
    /// `[x_t, y_t]`: a skip connection around the LSTM, so a recurrent network contains its
    /// feed-forward twin (trunk -> head) and the memory adds features to it. Default `false`.
    pub core_skip: bool,
    /// Discount factor gamma.
    pub gamma: f64,
    /// Adam learning rate of the actor.
    pub lr_actor: f64,
    /// Adam learning rate of the critic.
    pub lr_critic: f64,
    /// L2 coefficient on the critic weights, added to the gradient as `critic_l2 * w`
    /// (i.e. a loss term `critic_l2 / 2 * |w|^2`; Adam's coupled weight decay). Paper: 1e-5.
    pub critic_l2: f64,
    /// Adam beta1.
    pub adam_beta1: f64,
    /// Adam beta2.
    pub adam_beta2: f64,
    /// Adam epsilon.
    pub adam_eps: f64,
    /// Minibatch size `N` (windows per update), used by the replay sampler. Paper code: 64.
    pub batch_size: usize,
    /// Optimisation length `l`: steps per window that receive gradients (the critic
    /// back-propagates through them). Paper: 8.
    pub opt_len: usize,
    /// Update length `u <= l`: the critic loss uses the first `u` steps of each window. Paper: 8.
    /// `u = l = 1`, `s = 0` is baseline RDPG's TD(0).
    pub update_len: usize,
    /// Scan length `s`: steps before each window run without gradient to initialise the
    /// recurrent states (paper Eq. "scan"). Paper figures: 24; Table I run: 120.
    pub scan_len: usize,
    /// Lambda of the interpolated TD weighting: step `i < u` of a window has weight
    /// `lambda^i / sum_{j<u} lambda^j` (`rdpg_core::targets::interpolated_td_weights`). 1 =
    /// uniform (the authors' code); 0 keeps only the first step.
    pub lambda: f64,
    /// How the critic's targets are built: the paper's tail-step bootstrap (default) or the
    /// classic RDPG's per-step TD(0).
    pub critic_target: CriticTarget,
    /// How the actor loss weighs a window's steps: `per_window` (`1/len_n`, the default) or
    /// `per_step` (`1/l`, every replayed step alike). Window-of-k agents train the actor on
    /// each window's first step alone and refuse `per_step`.
    pub actor_weights: ActorWeights,
    /// Soft target update rate. 0 = no target networks: targets come from the behaviour networks
    /// without gradient (the authors' code). In `(0, 1]`: target networks updated by
    /// `target += tau * (online - target)` after every update.
    pub tau: f64,
    /// Back-propagate the actor loss through time over the window. Paper: off (the actor state
    /// fed to each step is treated as a constant).
    pub actor_bptt: bool,
    /// Clip the global gradient norm of each network to this value (none when `None`).
    pub grad_clip: Option<f64>,
    /// Two critics; the bootstrap uses the minimum of the two (TD3-style); the actor follows
    /// the first.
    pub twin_critic: bool,
    /// Start the actor scan from the acting-time state stored in the replay (R2D2-style) instead
    /// of zeros; with `scan_len = 0` the window itself starts from the stored state (R2D2's
    /// "stored state, no burn-in"). The critic scan always starts from zeros.
    pub burn_in_from_stored_state: bool,
    /// Window-of-k acting and training (0: off, the LSTM state is carried over the whole
    /// episode). With `k > 0` the actor acts on its last `k` observations, re-encoded from a
    /// zero state at every step, and training matches it: each window scans its `k - 1`
    /// previous steps from zero (`scan_len = k - 1`, no stored state), the critic trains on
    /// the window's first step (`update_len = 1`, the actor likewise), and the tail bootstrap
    /// re-encodes the `k - 1` steps before the tail from zero. Needs target networks and the
    /// tail bootstrap; any `opt_len` (n-step returns).
    pub act_window: usize,
    /// With `act_window`: the losses back-propagate through the whole `k`-step window, the
    /// `k - 1` history steps included, as LSTM-TD3 and SAC-LSTM train (the critic loss into
    /// the critic's encoding of the replayed history, the actor loss into the actor's). Off
    /// (the default): the history is encoded without gradient, so only the trained step's
    /// cell learns and nothing trains how the LSTM summarises the history.
    pub window_grad: bool,
    /// Target policy smoothing noise on the bootstrap action (TD3); none when `None`.
    pub target_noise: Option<TargetNoise>,
    /// TD3's delayed policy updates: the actor and the target networks are updated on every
    /// `policy_delay`-th update only (the critic on every update). 1 = every update (the
    /// paper's RDPG); TD3 uses 2.
    pub policy_delay: usize,
    /// Compute the actor gradient with the critic *after* its Adam step (Algorithm 1 order,
    /// which needs a second no-gradient critic scan). `false`: both losses from the same
    /// pre-update forward pass (cheaper).
    pub actor_uses_updated_critic: bool,
    /// How the scan handles windows with fewer than `s` real scan steps.
    pub scan_method: ScanMethod,
    /// Device: `"cpu"`, `"cuda"` or `"auto"`.
    pub device: DeviceSpec,
    /// Number of intra-op CPU threads libtorch uses (`torch.set_num_threads`); `None` leaves
    /// libtorch's default. This setting is process-wide.
    pub num_threads: Option<usize>,
    /// Run the second critic of `twin_critic` on a second thread: the two critics' scans,
    /// window runs, target values and gradients are independent of each other, so the update
    /// is bit-identical to running them one after the other, while a free core takes the
    /// second critic's half of the critic work. Meant for `num_threads = 1` (two intra-op
    /// threads and two critic threads would oversubscribe a 2-core machine). Needs twin
    /// critics, target networks and the tail-step bootstrap (the targets must be known before
    /// the behaviour critics run).
    pub parallel_twins: bool,
    /// Flush subnormal floats to zero in every thread that runs tensor kernels: the trainer's
    /// thread (set when the trainer is built, before any tensor work) and libtorch's worker
    /// threads (which inherit it when libtorch creates them). The environments' physics runs
    /// in IEEE mode whatever the thread (`rdpg_core::fpmode`). Without it, CPU updates slow
    /// down 2-3x as training drives values into the subnormal range; the numerical effect is
    /// below `f32` precision of any value that matters.
    pub flush_denormal: bool,
    /// FORK's forward-looking actor (dynamics and reward models and a two-step look-ahead
    /// term in the actor loss); none when `None`. Needs a feed-forward agent.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fork: Option<ForkConfig>,
    /// Soft actor-critic (`algo = "sac"`): a squashed-Gaussian actor, entropy-regularised
    /// targets, a temperature; `None`: the deterministic actor of RDPG / DDPG / TD3.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sac: Option<SacConfig>,
}

impl Default for RdpgConfig {
    fn default() -> Self {
        Self {
            trunk: Trunk::Lidar,
            lidar_dim: 10,
            lidar_channels: 64,
            lidar_kernel: 3,
            lidar_fc: 64,
            body_fc: 192,
            recurrent: true,
            lstm_forget_bias: 0.0,
            actor_hidden: 256,
            critic_hidden: 320,
            critic_action_fc: 64,
            critic_action_after_core: false,
            actor_head: Vec::new(),
            critic_head: Vec::new(),
            core_skip: false,
            gamma: 0.99,
            lr_actor: 1e-3,
            lr_critic: 1e-3,
            critic_l2: 1e-5,
            adam_beta1: 0.9,
            adam_beta2: 0.999,
            adam_eps: 1e-8,
            batch_size: 64,
            opt_len: 8,
            update_len: 8,
            scan_len: 24,
            lambda: 1.0,
            critic_target: CriticTarget::TailBootstrap,
            actor_weights: ActorWeights::PerWindow,
            tau: 0.0,
            actor_bptt: false,
            grad_clip: None,
            twin_critic: false,
            burn_in_from_stored_state: false,
            act_window: 0,
            window_grad: false,
            target_noise: None,
            policy_delay: 1,
            actor_uses_updated_critic: true,
            scan_method: ScanMethod::Grouped,
            device: DeviceSpec::Auto,
            num_threads: None,
            parallel_twins: false,
            flush_denormal: true,
            fork: None,
            sac: None,
        }
    }
}

fn bad(field: &'static str, reason: impl Into<String>) -> AgentError {
    AgentError::Config {
        field,
        reason: reason.into(),
    }
}

/// The widest layer a config may ask for (a file asking for more is refused, not built).
pub const MAX_WIDTH: usize = 1 << 14;

/// The most window steps (`batch_size × (scan_len + opt_len + 1)`) one batch may hold.
pub const MAX_BATCH_STEPS: usize = 1 << 22;

fn positive(field: &'static str, v: usize) -> Result<()> {
    if v == 0 {
        return Err(bad(field, "must be at least 1"));
    }
    Ok(())
}

/// A layer width: 1 to [`MAX_WIDTH`].
fn width(field: &'static str, v: usize) -> Result<()> {
    if !(1..=MAX_WIDTH).contains(&v) {
        return Err(bad(field, format!("{v} is not from 1 to {MAX_WIDTH}")));
    }
    Ok(())
}

fn finite_pos(field: &'static str, v: f64) -> Result<()> {
    if !(is_f32(v) && v > 0.0) {
        return Err(bad(field, format!("must be finite and > 0, got {v}")));
    }
    Ok(())
}

impl RdpgConfig {
    /// The feed-forward DDPG variant of this config (LSTM replaced by FC, no scan, `l = u = 1`).
    pub fn ddpg(mut self) -> Self {
        self.recurrent = false;
        self.opt_len = 1;
        self.update_len = 1;
        self.scan_len = 0;
        self
    }

    /// Checks every field; the error names the first offending field.
    pub fn validate(&self) -> Result<()> {
        match &self.trunk {
            Trunk::Lidar => {
                width("lidar_dim", self.lidar_dim)?;
                width("lidar_channels", self.lidar_channels)?;
                width("lidar_kernel", self.lidar_kernel)?;
                width("lidar_fc", self.lidar_fc)?;
                width("body_fc", self.body_fc)?;
                if self.lidar_kernel > self.lidar_dim {
                    return Err(bad("lidar_kernel", "must not exceed lidar_dim"));
                }
                if (self.lidar_dim - self.lidar_kernel + 1) < 2 {
                    return Err(bad(
                        "lidar_kernel",
                        "the convolution output must have length >= 2 for the max-pool",
                    ));
                }
            }
            Trunk::Mlp { hidden } => {
                if hidden.is_empty() {
                    return Err(bad("trunk", "mlp.hidden must list at least one layer"));
                }
                if hidden.len() > 64 || hidden.iter().any(|h| !(1..=MAX_WIDTH).contains(h)) {
                    return Err(bad(
                        "trunk",
                        format!("mlp.hidden must list 1 to 64 widths from 1 to {MAX_WIDTH}"),
                    ));
                }
            }
        }
        if !is_f32(self.lstm_forget_bias) {
            return Err(bad("lstm_forget_bias", "must be finite"));
        }
        if !self.recurrent && self.lstm_forget_bias != 0.0 {
            return Err(bad("lstm_forget_bias", "needs a recurrent agent (an LSTM)"));
        }
        width("actor_hidden", self.actor_hidden)?;
        width("critic_hidden", self.critic_hidden)?;
        for (field, head) in [
            ("actor_head", &self.actor_head),
            ("critic_head", &self.critic_head),
        ] {
            if head.len() > 64 || head.iter().any(|h| !(1..=MAX_WIDTH).contains(h)) {
                return Err(bad(
                    field,
                    format!("must list at most 64 widths from 1 to {MAX_WIDTH}"),
                ));
            }
        }
        if self.critic_action_fc > MAX_WIDTH {
            return Err(bad(
                "critic_action_fc",
                format!("must be at most {MAX_WIDTH}"),
            ));
        }
        // Without a head, Q = w·y + v·a + b: dQ/da = v in every state, so the actor is pushed the
        // same way everywhere (it saturates, and a walker falls at once).
        if self.critic_action_after_core
            && (self.critic_action_fc != 0 || self.critic_head.is_empty())
        {
            return Err(bad(
                "critic_action_after_core",
                "needs critic_action_fc = 0 (the raw action joins the core's output) and a critic \
                 head, e.g. critic_head = [128] (without one Q is linear in the action)",
            ));
        }
        if self.critic_action_fc == 0
            && !self.critic_action_after_core
            && !matches!(self.trunk, Trunk::Mlp { .. })
        {
            return Err(bad(
                "critic_action_fc",
                "0 (the action at the critic's input) needs an MLP trunk; the lidar trunk takes \
                 observations only, so give it an action branch (e.g. 64)",
            ));
        }
        if !(is_f32(self.gamma) && (0.0..=1.0).contains(&self.gamma)) {
            return Err(bad(
                "gamma",
                format!("must be in [0, 1], got {}", self.gamma),
            ));
        }
        finite_pos("lr_actor", self.lr_actor)?;
        finite_pos("lr_critic", self.lr_critic)?;
        if !(is_f32(self.critic_l2) && self.critic_l2 >= 0.0) {
            return Err(bad("critic_l2", "must be finite and >= 0"));
        }
        if !(0.0..1.0).contains(&self.adam_beta1) {
            return Err(bad("adam_beta1", "must be in [0, 1)"));
        }
        if !(0.0..1.0).contains(&self.adam_beta2) {
            return Err(bad("adam_beta2", "must be in [0, 1)"));
        }
        finite_pos("adam_eps", self.adam_eps)?;
        positive("batch_size", self.batch_size)?;
        positive("policy_delay", self.policy_delay)?;
        positive("opt_len", self.opt_len)?;
        positive("update_len", self.update_len)?;
        let steps = self
            .scan_len
            .saturating_add(self.opt_len)
            .saturating_add(1)
            .saturating_mul(self.batch_size);
        if steps > MAX_BATCH_STEPS {
            return Err(bad(
                "batch_size",
                format!(
                    "{} windows of scan_len + opt_len + 1 = {} steps hold more than \
                     {MAX_BATCH_STEPS} steps",
                    self.batch_size,
                    self.scan_len.saturating_add(self.opt_len).saturating_add(1)
                ),
            ));
        }
        if self.policy_delay > 1_000_000 {
            return Err(bad("policy_delay", "must be at most 1000000"));
        }
        if self.update_len > self.opt_len {
            return Err(bad(
                "update_len",
                format!(
                    "u = {} must not exceed opt_len l = {}",
                    self.update_len, self.opt_len
                ),
            ));
        }
        if !self.recurrent && self.burn_in_from_stored_state {
            return Err(bad("burn_in_from_stored_state", "needs a recurrent agent"));
        }
        if self.window_grad && self.act_window == 0 {
            return Err(bad(
                "window_grad",
                "needs a window-of-k agent (act_window >= 2): without one the scan is a \
                 burn-in, never back-propagated",
            ));
        }
        if self.act_window > 0 && self.actor_weights == ActorWeights::PerStep {
            return Err(bad(
                "actor_weights",
                "per_step does not apply to a window-of-k agent (act_window > 0): its actor \
                 trains on each window's first step alone",
            ));
        }
        if self.act_window > 0 {
            let k = self.act_window;
            let needs = |what: String| Err(bad("act_window", format!("k = {k} needs {what}")));
            if k < 2 || !self.recurrent {
                return needs("k >= 2 and a recurrent agent".into());
            }
            if self.scan_len != k - 1 || self.update_len != 1 {
                return needs(format!(
                    "scan_len = {} and update_len = 1 (got {} and {})",
                    k - 1,
                    self.scan_len,
                    self.update_len
                ));
            }
            if self.burn_in_from_stored_state
                || self.tau == 0.0
                || self.critic_target != CriticTarget::TailBootstrap
            {
                return needs(
                    "burn_in_from_stored_state = false, target networks (tau > 0) and \
                     critic_target = \"tail_bootstrap\""
                        .into(),
                );
            }
        }
        if !(is_f32(self.lambda) && self.lambda >= 0.0) {
            return Err(bad(
                "lambda",
                format!("must be finite and >= 0, got {}", self.lambda),
            ));
        }
        if !(is_f32(self.tau) && (0.0..=1.0).contains(&self.tau)) {
            return Err(bad("tau", format!("must be in [0, 1], got {}", self.tau)));
        }
        if let Some(c) = self.grad_clip {
            finite_pos("grad_clip", c)?;
        }
        if let Some(n) = self.target_noise {
            if !(is_f32(n.std) && n.std >= 0.0) {
                return Err(bad("target_noise", "std must be finite and >= 0"));
            }
            if !(is_f32(n.clip) && n.clip >= 0.0) {
                return Err(bad("target_noise", "clip must be finite and >= 0"));
            }
        }
        if self.parallel_twins
            && !(self.twin_critic
                && self.tau > 0.0
                && self.critic_target == CriticTarget::TailBootstrap)
        {
            return Err(bad(
                "parallel_twins",
                "needs twin_critic = true, target networks (tau > 0) and critic_target = \"tail_bootstrap\"",
            ));
        }
        if self
            .num_threads
            .is_some_and(|n| n == 0 || n > crate::common::tensor::MAX_THREADS)
        {
            return Err(bad(
                "num_threads",
                format!(
                    "must be 1 to {} when given",
                    crate::common::tensor::MAX_THREADS
                ),
            ));
        }
        if let Some(f) = &self.fork {
            if self.recurrent {
                return Err(bad(
                    "fork",
                    "needs a feed-forward agent (recurrent = false): its models map one \
                     observation and action to the next",
                ));
            }
            if !(is_f32(f.weight) && f.weight >= 0.0) {
                return Err(bad("fork", "weight must be finite and >= 0"));
            }
            if !(is_f32(f.threshold) && f.threshold > 0.0) {
                return Err(bad("fork", "threshold must be finite and > 0"));
            }
            if f.model_hidden.is_empty()
                || f.model_hidden.iter().any(|h| !(1..=MAX_WIDTH).contains(h))
            {
                return Err(bad(
                    "fork",
                    format!("model_hidden must list widths from 1 to {MAX_WIDTH}"),
                ));
            }
            if f.reward_hidden.is_empty()
                || f.reward_hidden.iter().any(|h| !(1..=MAX_WIDTH).contains(h))
            {
                return Err(bad(
                    "fork",
                    format!("reward_hidden must list widths from 1 to {MAX_WIDTH}"),
                ));
            }
            finite_pos("fork", f.lr)?;
        }
        if let Some(sac) = &self.sac {
            self.validate_sac(sac)?;
        }
        Ok(())
    }

    /// SAC's own settings, and the deterministic learner's options that do not apply to it,
    /// refused by name.
    fn validate_sac(&self, sac: &SacConfig) -> Result<()> {
        finite_pos("sac.init_alpha", sac.init_alpha)?;
        finite_pos("sac.lr_alpha", sac.lr_alpha)?;
        if sac.target_entropy.is_some_and(|h| !is_f32(h)) {
            return Err(bad("sac.target_entropy", "must be finite"));
        }
        if let Some(t) = &sac.tqc {
            if t.quantiles == 0 || t.quantiles > 1000 {
                return Err(bad("sac.tqc.quantiles", "must be in 1..=1000"));
            }
            if t.drop_per_critic >= t.quantiles {
                return Err(bad(
                    "sac.tqc.drop_per_critic",
                    format!(
                        "must be below quantiles ({}): every critic keeps an atom",
                        t.quantiles
                    ),
                ));
            }
        }
        let refuse = |field: &'static str, why: &str| {
            Err(bad(
                field,
                format!("does not apply to sac (algo = \"sac\"): {why}"),
            ))
        };
        if self.target_noise.is_some() {
            return refuse(
                "target_noise",
                "its bootstrap action is sampled from the policy",
            );
        }
        if self.policy_delay != 1 {
            return refuse(
                "policy_delay",
                "the actor and the temperature step on every update",
            );
        }
        if self.fork.is_some() {
            return refuse("fork", "FORK's term is written for a deterministic actor");
        }
        if self.parallel_twins {
            return refuse("parallel_twins", "its update runs on one thread");
        }
        if !self.actor_uses_updated_critic {
            return refuse(
                "actor_uses_updated_critic",
                "false: its actor reads the critics after their step",
            );
        }
        if self.tau == 0.0 {
            return refuse(
                "tau",
                "0 (no target critics): SAC bootstraps from target critics",
            );
        }
        if self.critic_target != CriticTarget::TailBootstrap {
            return refuse(
                "critic_target",
                "only the tail-step bootstrap (\"tail_bootstrap\") has a soft version here",
            );
        }
        Ok(())
    }

    /// Outputs of each critic: TQC's atoms per critic, or 1 (the value).
    pub fn critic_outputs(&self) -> usize {
        self.sac
            .as_ref()
            .and_then(|s| s.tqc.as_ref())
            .map_or(1, |t| t.quantiles)
    }

    /// The width of the observation embedding produced by the trunk.
    pub fn embed_dim(&self) -> usize {
        match &self.trunk {
            Trunk::Lidar => self.lidar_fc + self.body_fc,
            Trunk::Mlp { hidden } => *hidden.last().unwrap_or(&0),
        }
    }

    /// The number of values of the actor and critic(s) this config builds for an environment
    /// of these sizes, target copies and SAC's temperature included (FORK's models not counted), computed without
    /// allocating: what a loader compares with a weights file before it builds anything.
    pub fn param_count(&self, obs_dim: usize, act_dim: usize) -> f64 {
        let (d, a) = (obs_dim as f64, act_dim as f64);
        let linear = |i: f64, o: f64| i * o + o;
        let trunk = |input: f64| match &self.trunk {
            Trunk::Lidar => {
                let (ch, k) = (self.lidar_channels as f64, self.lidar_kernel as f64);
                let pooled = ((self.lidar_dim as f64 - k + 1.0) / 2.0).floor().max(0.0);
                ch * k
                    + ch
                    + linear(ch * pooled, self.lidar_fc as f64)
                    + linear(
                        (input - self.lidar_dim as f64).max(0.0),
                        self.body_fc as f64,
                    )
            }
            Trunk::Mlp { hidden } => {
                let mut n = 0.0;
                let mut i = input;
                for &h in hidden {
                    n += linear(i, h as f64);
                    i = h as f64;
                }
                n
            }
        };
        let core = |e: f64, h: f64| match self.recurrent {
            true => 4.0 * h * (e + h + 2.0),
            false => linear(e, h),
        };
        // The head's layers from the core's output (and input, with `core_skip`) to `out`.
        let head = |x: f64, y: f64, hidden: &[usize], out: f64| {
            let mut n = 0.0;
            let mut i = y + if self.core_skip { x } else { 0.0 };
            for &h in hidden {
                n += linear(i, h as f64);
                i = h as f64;
            }
            n + linear(i, out)
        };
        let e = self.embed_dim() as f64;
        let (ha, hc) = (self.actor_hidden as f64, self.critic_hidden as f64);
        // A SAC actor's output layer gives the mean and the log standard deviation.
        let out = if self.sac.is_some() { 2.0 * a } else { a };
        let actor = trunk(d) + core(e, ha) + head(e, ha, &self.actor_head, out);
        let af = self.critic_action_fc as f64;
        let q_out = self.critic_outputs() as f64;
        let critic = if self.critic_action_after_core {
            // The raw action joins the head's input: one more input to its first layer.
            trunk(d) + core(e, hc) + head(e, hc + a, &self.critic_head, q_out)
        } else {
            let input = match self.critic_action_fc {
                0 => trunk(d + a),
                _ => trunk(d) + linear(a, af),
            };
            input + core(e + af, hc) + head(e + af, hc, &self.critic_head, q_out)
        };
        let critics = if self.twin_critic { 2.0 } else { 1.0 };
        let copies = if self.tau > 0.0 { 2.0 } else { 1.0 };
        match self.sac {
            // No target actor (the bootstrap samples the policy); `log alpha`.
            Some(_) => actor + copies * critics * critic + 1.0,
            None => copies * (actor + critics * critic),
        }
    }

    /// Checks that an environment with these sizes fits the trunk.
    pub fn check_dims(&self, obs_dim: usize, act_dim: usize) -> Result<()> {
        if act_dim == 0 {
            return Err(AgentError::Shape("act_dim must be at least 1".into()));
        }
        if obs_dim == 0 {
            return Err(AgentError::Shape("obs_dim must be at least 1".into()));
        }
        if self.trunk == Trunk::Lidar && obs_dim <= self.lidar_dim {
            return Err(AgentError::Shape(format!(
                "lidar trunk needs obs_dim > lidar_dim = {} (body sensors first), got obs_dim {obs_dim}",
                self.lidar_dim
            )));
        }
        Ok(())
    }
}

/// The learner configuration of the memory task (PendulumNoVel-v1): a small MLP trunk, LSTM 64
/// (or, with `ddpg`, the same network with the LSTM replaced by FC and `l = u = 1`, `s = 0`),
/// target networks with τ = 0.005, batch 64, `l = u = 8`, `s = 16`.
pub fn memory_task_config(ddpg: bool) -> RdpgConfig {
    let cfg = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![64] },
        actor_hidden: 64,
        critic_hidden: 64,
        critic_action_fc: 32,
        batch_size: 64,
        opt_len: 8,
        update_len: 8,
        scan_len: 16,
        tau: 0.005,
        actor_uses_updated_critic: false,
        scan_method: ScanMethod::MaskedLoop,
        device: DeviceSpec::Cpu,
        ..RdpgConfig::default()
    };
    if ddpg {
        cfg.ddpg()
    } else {
        cfg
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_roundtrip() {
        let c = RdpgConfig::default();
        c.validate().unwrap();
        let s = serde_json::to_string(&c).unwrap();
        let back: RdpgConfig = serde_json::from_str(&s).unwrap();
        assert_eq!(c, back);
        assert_eq!(c.embed_dim(), 256);
        RdpgConfig::default().ddpg().validate().unwrap();
    }

    #[test]
    fn partial_json_and_unknown_fields() {
        let c: RdpgConfig =
            serde_json::from_str(r#"{"trunk": {"mlp": {"hidden": [32]}}, "tau": 0.005}"#).unwrap();
        assert_eq!(c.trunk, Trunk::Mlp { hidden: vec![32] });
        assert_eq!(c.tau, 0.005);
        assert!(serde_json::from_str::<RdpgConfig>(r#"{"gama": 0.9}"#).is_err());
        let d: RdpgConfig = serde_json::from_str(r#"{"device": "cpu"}"#).unwrap();
        assert_eq!(d.device, DeviceSpec::Cpu);
    }

    #[test]
    fn validate_names_the_field() {
        let c = RdpgConfig {
            update_len: 9,
            ..Default::default()
        };
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("update_len"), "{e}");
        let c = RdpgConfig {
            gamma: 1.5,
            ..Default::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("gamma"));
        let c = RdpgConfig {
            trunk: Trunk::Mlp { hidden: vec![] },
            ..Default::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("trunk"));
        for (c, field) in [
            (
                RdpgConfig {
                    actor_head: vec![8, 0],
                    ..Default::default()
                },
                "actor_head",
            ),
            (
                RdpgConfig {
                    critic_head: vec![MAX_WIDTH + 1],
                    ..Default::default()
                },
                "critic_head",
            ),
        ] {
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains(field), "{e}");
        }
        // parallel_twins: twin critics, targets and the tail bootstrap, each required.
        let twins = RdpgConfig {
            parallel_twins: true,
            twin_critic: true,
            tau: 0.005,
            ..Default::default()
        };
        twins.validate().unwrap();
        for bad in [
            RdpgConfig {
                twin_critic: false,
                ..twins.clone()
            },
            RdpgConfig {
                tau: 0.0,
                ..twins.clone()
            },
            RdpgConfig {
                critic_target: CriticTarget::PerStepTd0,
                ..twins.clone()
            },
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("parallel_twins"), "{e}");
        }
        // per_step actor weights: a window-of-k actor trains on one step per window.
        let window = RdpgConfig {
            act_window: 4,
            scan_len: 3,
            update_len: 1,
            tau: 0.005,
            burn_in_from_stored_state: false,
            ..Default::default()
        };
        window.validate().unwrap();
        let e = RdpgConfig {
            actor_weights: ActorWeights::PerStep,
            ..window
        }
        .validate()
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("actor_weights") && e.contains("window-of-k"),
            "{e}"
        );
    }

    #[test]
    fn fork_needs_a_feed_forward_agent_and_sane_models() {
        let ff = RdpgConfig {
            fork: Some(ForkConfig::default()),
            ..RdpgConfig::default().ddpg()
        };
        ff.validate().unwrap();
        // From TOML-like JSON: a partial table takes the defaults for the rest.
        let c: RdpgConfig =
            serde_json::from_str(r#"{"recurrent": false, "fork": {"weight": 0.3}}"#).unwrap();
        let f = c.fork.as_ref().unwrap();
        assert_eq!((f.weight, f.threshold, f.lr), (0.3, 0.02, 3e-4));
        assert!(serde_json::from_str::<RdpgConfig>(r#"{"fork": {"wieght": 1}}"#).is_err());
        let recurrent = RdpgConfig {
            fork: Some(ForkConfig::default()),
            ..RdpgConfig::default()
        };
        for (bad, why) in [
            (recurrent, "feed-forward"),
            (ff_with(|f| f.weight = -1.0), "weight"),
            (ff_with(|f| f.threshold = 0.0), "threshold"),
            (ff_with(|f| f.model_hidden.clear()), "model_hidden"),
            (ff_with(|f| f.reward_hidden = vec![4, 0]), "reward_hidden"),
            (ff_with(|f| f.lr = f64::NAN), "fork"),
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("fork") && e.contains(why), "{e}");
        }
    }

    fn ff_with(change: impl FnOnce(&mut ForkConfig)) -> RdpgConfig {
        let mut f = ForkConfig::default();
        change(&mut f);
        RdpgConfig {
            fork: Some(f),
            ..RdpgConfig::default().ddpg()
        }
    }
}
