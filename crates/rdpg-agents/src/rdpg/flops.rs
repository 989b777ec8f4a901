//! How far an update is from this CPU's limit: the floating-point operations each phase of
//! one update performs, counted from the networks' shapes ([`update_flops`]), and the rate
//! of plain matrix products at the networks' own layer shapes ([`gemm_reference`]), both
//! for `rdpg bench update`.
//!
//! The count is of matrix products only (a multiply-add is 2 FLOP; element-wise work, Adam
//! and the index arithmetic are left out): per layer `2 K N` per row, `[M, K] @ [K, N]`. An
//! LSTM step is one product of `[x, h]` with its stacked gate weights, `(E + H) x 4H`. A
//! backward pass with weight and input gradients counts twice its forward pass; the critic
//! in the actor's loss, held constant, once (input gradients only). Rows are those of the
//! benchmark's batches, where every window is full (`N` windows, `s` scan steps, `l`
//! optimisation steps, the critic trained on the first `u`; with shorter windows the count is
//! an upper bound). Work done on the actor's turn
//! only (its loss, critic 0's rescan, and with target networks the behaviour actor's scan and
//! states) is divided by `policy_delay`. FORK's models are not counted.

use std::time::Instant;

use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use super::config::{CriticTarget, RdpgConfig, Trunk};

/// Counted FLOP of one update (averaged over `policy_delay` updates), per phase of
/// [`super::PhaseTimes`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PhaseFlops {
    /// The scans of step 1.
    pub scan: f64,
    /// The no-gradient runs along the window (actor states, target actor, target critics).
    pub window_nograd: f64,
    /// The critics' forward and backward passes.
    pub critic_step: f64,
    /// Critic 0's scan and states after its step (on the actor's turn).
    pub critic_rescan: f64,
    /// The actor's forward and backward pass through critic 0 (on the actor's turn).
    pub actor_step: f64,
}

impl PhaseFlops {
    /// All phases together.
    pub fn total(&self) -> f64 {
        self.scan + self.window_nograd + self.critic_step + self.critic_rescan + self.actor_step
    }
}

/// The GEMM shapes `(K, N)` of one network, per row, in order: trunk, core, head.
#[derive(Debug, Clone)]
struct Net {
    trunk: Vec<(i64, i64)>,
    core: (i64, i64),
    head: Vec<(i64, i64)>,
}

fn flop(shapes: &[(i64, i64)]) -> f64 {
    shapes.iter().map(|&(k, n)| 2.0 * (k * n) as f64).sum()
}

impl Net {
    fn trunk(&self) -> f64 {
        flop(&self.trunk)
    }
    fn core(&self) -> f64 {
        flop(&[self.core])
    }
    fn head(&self) -> f64 {
        flop(&self.head)
    }
    fn all(&self) -> f64 {
        self.trunk() + self.core() + self.head()
    }
}

/// The trunk's products for an input of `input` values (the lidar convolution as the product
/// it amounts to per output position).
fn trunk_shapes(cfg: &RdpgConfig, input: i64) -> Vec<(i64, i64)> {
    match &cfg.trunk {
        Trunk::Mlp { hidden } => {
            let mut k = input;
            hidden
                .iter()
                .map(|&h| {
                    let s = (k, h as i64);
                    k = h as i64;
                    s
                })
                .collect()
        }
        Trunk::Lidar => {
            let (ld, ch, kw) = (
                cfg.lidar_dim as i64,
                cfg.lidar_channels as i64,
                cfg.lidar_kernel as i64,
            );
            let positions = ld - kw + 1;
            vec![
                (kw * positions, ch), // the convolution: positions x (kernel -> channels)
                (ch * (positions / 2), cfg.lidar_fc as i64),
                (input - ld, cfg.body_fc as i64),
            ]
        }
    }
}

/// The actor's and the critic's shapes.
fn nets(cfg: &RdpgConfig, obs_dim: usize, act_dim: usize) -> (Net, Net) {
    let (d, a) = (obs_dim as i64, act_dim as i64);
    let e = cfg.embed_dim() as i64;
    let core = |input: i64, h: usize| {
        let h = h as i64;
        if cfg.recurrent {
            (input + h, 4 * h)
        } else {
            (input, h)
        }
    };
    // The head's layers from the core's output (and input, with `core_skip`) to `out`.
    let head = |x: i64, y: usize, hidden: &[usize], out: i64| {
        let mut k = y as i64 + if cfg.core_skip { x } else { 0 };
        let mut shapes: Vec<(i64, i64)> = hidden
            .iter()
            .map(|&h| {
                let s = (k, h as i64);
                k = h as i64;
                s
            })
            .collect();
        shapes.push((k, out));
        shapes
    };
    let actor = Net {
        trunk: trunk_shapes(cfg, d),
        core: core(e, cfg.actor_hidden),
        // A SAC actor's output layer gives the mean and the log standard deviation.
        head: head(
            e,
            cfg.actor_hidden,
            &cfg.actor_head,
            if cfg.sac.is_some() { 2 * a } else { a },
        ),
    };
    let af = cfg.critic_action_fc as i64;
    let q_out = cfg.critic_outputs() as i64;
    let critic = if cfg.critic_action_after_core {
        // The raw action joins the core's output at the head's input.
        Net {
            trunk: trunk_shapes(cfg, d),
            core: core(e, cfg.critic_hidden),
            head: head(e, cfg.critic_hidden + act_dim, &cfg.critic_head, q_out),
        }
    } else {
        let mut trunk = trunk_shapes(cfg, if af == 0 { d + a } else { d });
        if af > 0 {
            trunk.push((a, af));
        }
        Net {
            trunk,
            core: core(e + af, cfg.critic_hidden),
            head: head(e + af, cfg.critic_hidden, &cfg.critic_head, q_out),
        }
    };
    (actor, critic)
}

/// Counted FLOP of one update of an agent with `cfg` on environment sizes `obs_dim`,
/// `act_dim` (see the module docs for what is counted).
pub fn update_flops(cfg: &RdpgConfig, obs_dim: usize, act_dim: usize) -> PhaseFlops {
    let (actor, critic) = nets(cfg, obs_dim, act_dim);
    let n = cfg.batch_size as f64;
    let (s, l) = (cfg.scan_len as f64, cfg.opt_len as f64);
    let u = cfg.update_len.min(cfg.opt_len) as f64;
    let twins = if cfg.twin_critic { 2.0 } else { 1.0 };
    let targets = cfg.tau > 0.0;
    let rec = cfg.recurrent;
    let per_step = cfg.critic_target == CriticTarget::PerStepTd0;
    let turn = 1.0 / cfg.policy_delay as f64;
    if cfg.sac.is_some() {
        return sac_flops(cfg, &actor, &critic);
    }

    // With target networks the behaviour actor's scan and states serve the actor's turn only.
    let behaviour = if targets { turn } else { 1.0 };
    // 1. Scans: every network over N s rows (recurrent cores only).
    let mut f = PhaseFlops::default();
    if rec && s > 0.0 {
        let (actors, critics) = if targets {
            (behaviour + 1.0, 2.0 * twins)
        } else {
            (1.0, twins)
        };
        f.scan = n
            * s
            * (actors * (actor.trunk() + actor.core())
                + critics * (critic.trunk() + critic.core()));
    }
    // 2a. No gradient along the window: the behaviour actor's states (per-step actor gradient),
    // mu' and Q' at the tail, or the per-step TD(0) targets (mu' along the window, each target
    // critic along the replayed actions and one cell step on (o_{i+1}, mu'(o_{i+1}))).
    let states = if rec && !cfg.actor_bptt && !cfg.window_grad {
        n * l * actor.trunk() + n * (l - 1.0) * actor.core()
    } else {
        0.0
    };
    // Rows of a recurrent network along the window (l + 1 slots), or the tail alone.
    let along = if rec { n * (l + 1.0) } else { n };
    f.window_nograd = if per_step {
        behaviour * states
            + n * (l + 1.0) * actor.all()
            + twins * (n * l * (critic.trunk() + critic.core()) + n * l * critic.all())
    } else if targets {
        behaviour * states + along * actor.all() + twins * along * critic.all()
    } else {
        n * (l + 1.0) * actor.all() // the behaviour actor's run gives states and mu'(o_tail)
    };
    // 2b. The critics: forward on the trained steps (through the tail without targets),
    // backward twice that.
    let rows = if targets || per_step {
        n * u
    } else {
        n * (l + 1.0)
    };
    f.critic_step = 3.0 * twins * rows * critic.all();
    // The actor reading critic 0 before its step: its states along the window, taken then.
    if rec && !cfg.actor_uses_updated_critic {
        f.critic_step += turn * (n * l * critic.trunk() + n * (l - 1.0) * critic.core());
    }
    // 3. Actor's turn: critic 0 rescanned after its step, the actor's loss.
    if rec && cfg.actor_uses_updated_critic {
        f.critic_rescan = turn
            * (n * s * (critic.trunk() + critic.core())
                + n * l * critic.trunk()
                + n * (l - 1.0) * critic.core());
    }
    f.actor_step = turn * n * l * (3.0 * actor.all() + 2.0 * critic.all());
    f
}

/// [`update_flops`] for SAC (`sac.rs`): the actor, every critic and every target critic
/// scanned; the actor along the window and the target critics at the tail; the critics'
/// forward and backward passes; every critic rescanned after its step; the actor's loss
/// through every critic.
fn sac_flops(cfg: &RdpgConfig, actor: &Net, critic: &Net) -> PhaseFlops {
    let n = cfg.batch_size as f64;
    let (s, l) = (cfg.scan_len as f64, cfg.opt_len as f64);
    let u = cfg.update_len.min(cfg.opt_len) as f64;
    let twins = if cfg.twin_critic { 2.0 } else { 1.0 };
    let mut f = PhaseFlops::default();
    let along = if cfg.recurrent { n * (l + 1.0) } else { n };
    if cfg.recurrent {
        f.scan =
            n * s * (actor.trunk() + actor.core() + 2.0 * twins * (critic.trunk() + critic.core()));
        f.critic_rescan = twins
            * (n * s * (critic.trunk() + critic.core())
                + n * l * critic.trunk()
                + n * (l - 1.0) * critic.core());
    }
    f.window_nograd = n * (l + 1.0) * (actor.trunk() + actor.core())
        + n * actor.head()
        + twins * along * critic.all();
    f.critic_step = 3.0 * twins * n * u * critic.all();
    f.actor_step = n * l * (3.0 * actor.all() + 2.0 * twins * critic.all());
    f
}

/// Plain matrix products `[M, K] @ [K, N]` at every layer shape of the agent's networks, on
/// the calling thread's libtorch settings: FLOP per second over all layers together, each
/// weighted by its FLOP per row. `M` is the update's: `rows` (a window's steps over the
/// batch) for the trunk, the head and an LSTM's input weights; `batch` for an LSTM's
/// recurrent weights, which multiply one step's states at a time. After a warm-up, over at
/// least `min_secs`.
pub fn gemm_reference(
    cfg: &RdpgConfig,
    obs_dim: usize,
    act_dim: usize,
    (rows, batch): (i64, i64),
    min_secs: f64,
) -> f64 {
    let (actor, critic) = nets(cfg, obs_dim, act_dim);
    let mut shapes: Vec<(i64, i64, i64)> = Vec::new(); // (M, K, N)
    for net in [&actor, &critic] {
        shapes.extend(net.trunk.iter().map(|&(k, n)| (rows, k, n)));
        let (k, n) = net.core;
        if cfg.recurrent {
            let h = n / 4;
            shapes.push((rows, k - h, n)); // x W_ih^T over all steps
            shapes.push((batch, h, n)); // h W_hh^T, one step at a time
        } else {
            shapes.push((rows, k, n));
        }
        shapes.extend(net.head.iter().map(|&(k, n)| (rows, k, n)));
    }
    let opts = (Kind::Float, Device::Cpu);
    let pairs: Vec<(Tensor, Tensor)> = shapes
        .iter()
        .map(|&(m, k, n)| (Tensor::randn([m, k], opts), Tensor::randn([k, n], opts)))
        .collect();
    // Seconds per window row of each layer, from its own rate.
    let time = |(a, b): &(Tensor, Tensor)| {
        for _ in 0..20 {
            let _ = a.matmul(b);
        }
        let (t0, mut calls) = (Instant::now(), 0u64);
        while calls < 20 || t0.elapsed().as_secs_f64() < min_secs / shapes.len() as f64 {
            let _ = a.matmul(b);
            calls += 1;
        }
        t0.elapsed().as_secs_f64() / (calls as f64 * a.size()[0] as f64)
    };
    let secs_per_row: f64 = pairs.iter().map(time).sum();
    let flop_per_row: f64 = shapes.iter().map(|&(_, k, n)| 2.0 * (k * n) as f64).sum();
    flop_per_row / secs_per_row
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The counts by hand for a feed-forward TD3 critic with n-step returns (l = 3, u = 1)
    /// and a recurrent agent.
    #[test]
    fn counts_by_hand() {
        let ff = RdpgConfig {
            trunk: Trunk::Mlp { hidden: vec![8] },
            recurrent: false,
            critic_action_fc: 0,
            actor_hidden: 8,
            critic_hidden: 8,
            opt_len: 3,
            update_len: 1,
            scan_len: 0,
            twin_critic: true,
            tau: 0.005,
            policy_delay: 2,
            batch_size: 10,
            ..RdpgConfig::default()
        };
        let f = update_flops(&ff, 4, 2);
        // actor per row: 2(4*8 + 8*8 + 8*2) = 224; critic: 2(6*8 + 8*8 + 8*1) = 240.
        assert_eq!(f.scan, 0.0);
        assert_eq!(f.window_nograd, 10.0 * 224.0 + 2.0 * 10.0 * 240.0);
        assert_eq!(f.critic_step, 3.0 * 2.0 * 10.0 * 240.0); // the first step only
        assert_eq!(f.critic_rescan, 0.0);
        assert_eq!(f.actor_step, 0.5 * 30.0 * (3.0 * 224.0 + 2.0 * 240.0));

        let rec = RdpgConfig {
            recurrent: true,
            scan_len: 2,
            opt_len: 3,
            update_len: 3,
            ..ff
        };
        let f = update_flops(&rec, 4, 2);
        // actor: trunk 64, core 2*16*32 = 1024, head 32; critic: trunk 96, core 1024, head 16.
        let (at, ac, ah, ct, cc, ch) = (64.0, 1024.0, 32.0, 96.0, 1024.0, 16.0);
        // The behaviour actor's scan and states on every second update (policy delay 2).
        assert_eq!(
            f.scan,
            10.0 * 2.0 * 1.5 * (at + ac) + 10.0 * 2.0 * 4.0 * (ct + cc)
        );
        let states = 0.5 * (10.0 * 3.0 * at + 10.0 * 2.0 * ac);
        let win = states + 40.0 * (at + ac + ah) + 2.0 * 40.0 * (ct + cc + ch);
        assert_eq!(f.window_nograd, win);
        assert_eq!(f.critic_step, 3.0 * 2.0 * 30.0 * (ct + cc + ch));
        // The classic RDPG's per-step TD(0) targets instead of the tail bootstrap.
        let per_step = RdpgConfig {
            critic_target: CriticTarget::PerStepTd0,
            ..rec.clone()
        };
        let targets = 40.0 * (at + ac + ah) + 2.0 * (30.0 * (ct + cc) + 30.0 * (ct + cc + ch));
        assert_eq!(
            update_flops(&per_step, 4, 2).window_nograd,
            states + targets
        );
        assert_eq!(
            f.critic_rescan,
            0.5 * (20.0 * (ct + cc) + 30.0 * ct + 20.0 * cc)
        );
    }
}
