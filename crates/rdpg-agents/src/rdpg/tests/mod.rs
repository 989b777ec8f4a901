//! Tests of the update's pieces and of the agent, one file per topic; the shared helpers
//! (tiny configs, batches, tolerances) are here.

use rdpg_core::rng::NpRng;
use rdpg_core::SequenceBatch;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use super::agent::RdpgAgent;
use super::bench::synthetic_batch;
use super::config::{ActorWeights, ForkConfig, RdpgConfig, ScanMethod, Trunk};
use super::lstm::RecState;
use super::prepared::Prepared;
use super::update::{
    actor_loss, actor_states, critic_loss_from, scan_critic, tail_action, target_q, td_targets,
    trained_q, ActorInput,
};
use crate::common::tensor::{sorted_vars, tensor_to_vec64 as to_vec64, DeviceSpec};
use crate::common::UpdateStats;

mod agent;
mod bias;
mod fork;
mod gradients;
mod preference;
mod sac;
mod sequences;
mod staleness;
mod targets;

const OBS: usize = 13; // 3 body sensors + 10 lidar values

const ACT: usize = 2;

/// A tiny lidar-trunk recurrent config (every layer kind present, small widths).
fn tiny() -> RdpgConfig {
    RdpgConfig {
        lidar_channels: 2,
        lidar_fc: 3,
        body_fc: 3,
        actor_hidden: 4,
        critic_hidden: 5,
        critic_action_fc: 2,
        opt_len: 3,
        update_len: 3,
        scan_len: 4,
        batch_size: 6,
        device: DeviceSpec::Cpu,
        ..Default::default()
    }
}

fn mlp(obs_hidden: usize) -> RdpgConfig {
    RdpgConfig {
        trunk: Trunk::Mlp {
            hidden: vec![obs_hidden],
        },
        ..tiny()
    }
}

/// `cfg` with head layers after both cores and the skip connection around them (`heads`), or
/// as it is.
fn with_heads(cfg: RdpgConfig, heads: bool) -> RdpgConfig {
    if !heads {
        return cfg;
    }
    RdpgConfig {
        actor_head: vec![3],
        critic_head: vec![4, 2],
        core_skip: true,
        ..cfg
    }
}

/// `cfg` with the critic's action joining after its core (`after`), or as it is.
fn with_action_after_core(cfg: RdpgConfig, after: bool) -> RdpgConfig {
    if !after {
        return cfg;
    }
    RdpgConfig {
        critic_action_after_core: true,
        critic_action_fc: 0,
        // (It needs a head: without one Q is linear in the action.)
        critic_head: if cfg.critic_head.is_empty() {
            vec![4]
        } else {
            cfg.critic_head.clone()
        },
        ..cfg
    }
}

fn batch(cfg: &RdpgConfig, n: usize, short: f64, seed: u64) -> SequenceBatch {
    let mut rng = NpRng::from_seed(seed);
    synthetic_batch(n, cfg.scan_len, cfg.opt_len, OBS, ACT, short, &mut rng)
}

fn assert_close(a: &[f64], b: &[f64], tol: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(
            (x - y).abs() <= tol * (1.0 + y.abs()),
            "{what}[{i}]: {x} vs {y}"
        );
    }
}

/// A hand-made batch with MLP-sized observations (obs 2, act 1).
fn hand_batch(scan: usize, opt: usize, rewards: &[&[f32]], term: &[f32]) -> SequenceBatch {
    let n = rewards.len();
    let t = scan + opt;
    let mut b = SequenceBatch {
        n,
        scan,
        opt,
        obs_dim: 2,
        act_dim: 1,
        obs: vec![0.1; n * (t + 1) * 2],
        actions: vec![0.0; n * t],
        rewards: vec![0.0; n * t],
        mask: vec![0.0; n * t],
        scan_len: vec![scan; n],
        opt_len: rewards.iter().map(|r| r.len()).collect(),
        tail_terminated: term.to_vec(),
        injected: vec![0.0; n],
        stored_state: None,
        state_dim: 0,
    };
    for (i, r) in rewards.iter().enumerate() {
        for j in 0..scan {
            b.mask[i * t + j] = 1.0;
        }
        for (j, &x) in r.iter().enumerate() {
            b.rewards[i * t + scan + j] = x;
            b.mask[i * t + scan + j] = 1.0;
        }
    }
    b
}

fn hand_agent(gamma: f64, l: usize, u: usize, lambda: f64, scan: usize) -> RdpgAgent {
    let cfg = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![3] },
        gamma,
        opt_len: l,
        update_len: u,
        lambda,
        scan_len: scan,
        ..tiny()
    };
    RdpgAgent::new_with_kind(cfg, 2, 1, 0, Kind::Double).unwrap()
}

fn targets_for(agent: &RdpgAgent, b: &SequenceBatch, boot: &[f64]) -> Vec<f64> {
    agent.check_batch(b).unwrap();
    let p = agent.prepare(b);
    let q_tail = Tensor::from_slice(boot).to_kind(Kind::Double);
    to_vec64(&td_targets(&p, &q_tail))
}

/// Puts large finite garbage into every padding position of a batch.
fn poison_padding(b: &mut SequenceBatch) {
    let t = b.scan + b.opt;
    for i in 0..b.n {
        for j in 0..=t {
            let real_obs = j >= b.scan - b.scan_len[i] && j <= b.scan + b.opt_len[i];
            if !real_obs {
                for k in 0..b.obs_dim {
                    b.obs[(i * (t + 1) + j) * b.obs_dim + k] = 7.0 + (j * 13 + k) as f32;
                }
            }
            if j < t && b.mask[i * t + j] == 0.0 {
                for k in 0..b.act_dim {
                    b.actions[(i * t + j) * b.act_dim + k] = -3.0;
                }
                b.rewards[i * t + j] = 0.0;
            }
        }
    }
}

/// Real scan steps of window `i` as `[1, k, D]` and `[1, k, A]`.
fn real_scan(b: &SequenceBatch, i: usize) -> (Tensor, Tensor) {
    let t = b.scan + b.opt;
    let k = b.scan_len[i];
    let first = b.scan - k;
    let o: Vec<f32> = (first..b.scan)
        .flat_map(|j| {
            b.obs[(i * (t + 1) + j) * b.obs_dim..(i * (t + 1) + j + 1) * b.obs_dim].to_vec()
        })
        .collect();
    let a: Vec<f32> = (first..b.scan)
        .flat_map(|j| b.actions[(i * t + j) * b.act_dim..(i * t + j + 1) * b.act_dim].to_vec())
        .collect();
    (
        Tensor::from_slice(&o).view([1, k as i64, b.obs_dim as i64]),
        Tensor::from_slice(&a).view([1, k as i64, b.act_dim as i64]),
    )
}

/// Recomputes masks (and zeroes data outside the real range) after lengths were edited.
fn regenerate_masks(mut b: SequenceBatch) -> SequenceBatch {
    let t = b.scan + b.opt;
    for i in 0..b.n {
        for j in 0..t {
            let real = if j < b.scan {
                j >= b.scan - b.scan_len[i]
            } else {
                j - b.scan < b.opt_len[i]
            };
            b.mask[i * t + j] = f32::from(u8::from(real));
        }
    }
    poison_padding(&mut b);
    b
}

/// Central finite differences of `loss` w.r.t. a few entries of every variable of `vs`,
/// compared to the autograd gradient (already in the variables' `.grad`).
fn check_grads(vs: &VarStore, loss: &dyn Fn() -> f64, what: &str) {
    if let Some(m) = grad_mismatch(vs, loss) {
        panic!("{what}: {m}");
    }
}

/// The first entry (of a few per variable of `vs`) whose autograd gradient (already in the
/// variables' `.grad`) differs from the central finite difference of `loss`, described; `None`
/// when all agree.
fn grad_mismatch(vs: &VarStore, loss: &dyn Fn() -> f64) -> Option<String> {
    let eps = 1e-6;
    let mut checked = 0;
    for (name, var) in sorted_vars(vs) {
        let n = var.numel() as i64;
        let g = var.grad();
        if !g.defined() {
            return Some(format!("no gradient for {name}"));
        }
        let g = to_vec64(&g);
        for idx in [0, n / 2, n - 1] {
            let bump = |delta: f64| {
                tch::no_grad(|| {
                    let _ = var.view([-1]).narrow(0, idx, 1).g_add_scalar_(delta);
                })
            };
            bump(eps);
            let lp = loss();
            bump(-2.0 * eps);
            let lm = loss();
            bump(eps);
            let fd = (lp - lm) / (2.0 * eps);
            let ad = g[idx as usize];
            if (fd - ad).abs() > 1e-6 * (1.0 + ad.abs()) {
                return Some(format!(
                    "d/d {name}[{idx}]: autograd {ad} vs finite difference {fd}"
                ));
            }
            checked += 1;
        }
    }
    assert!(checked > 10);
    None
}

fn full_cfg() -> RdpgConfig {
    RdpgConfig {
        tau: 0.05,
        twin_critic: true,
        grad_clip: Some(1.0),
        target_noise: Some(super::config::TargetNoise {
            std: 0.2,
            clip: 0.5,
        }),
        ..tiny()
    }
}

/// A feed-forward TD3 with FORK (windows of 3 steps, so that padding is exercised); the
/// threshold keeps the forward-looking term on from the first update.
fn fork_cfg() -> RdpgConfig {
    RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![8] },
        recurrent: false,
        critic_action_fc: 0,
        actor_hidden: 8,
        critic_hidden: 8,
        scan_len: 0,
        policy_delay: 2,
        fork: Some(ForkConfig {
            weight: 0.5,
            threshold: 1e3,
            model_hidden: vec![6, 5],
            reward_hidden: vec![4, 3],
            lr: 1e-3,
        }),
        ..full_cfg()
    }
}

fn tmp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("rdpg-agents-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A window-of-k config on the tiny networks: `k - 1` scan steps, 3-step returns trained on
/// the first step, target networks.
fn window_cfg(k: usize) -> RdpgConfig {
    RdpgConfig {
        act_window: k,
        scan_len: k - 1,
        opt_len: 3,
        update_len: 1,
        tau: 0.01,
        ..tiny()
    }
}
