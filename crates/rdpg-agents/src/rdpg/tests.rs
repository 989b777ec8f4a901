//! Tests of the update's pieces (targets, weights, scan, tail bootstrap, gradients) and of
//! the agent (determinism, checkpoints, acting).

use rdpg_core::rng::NpRng;
use rdpg_core::SequenceBatch;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

use super::agent::RdpgAgent;
use super::bench::synthetic_batch;
use super::config::{ForkConfig, RdpgConfig, ScanMethod, Trunk};
use super::lstm::RecState;
use super::update::{
    actor_loss, critic_loss_from, scan_critic, tail_action, target_q, td_targets, ActorInput,
};
use crate::common::tensor::{sorted_vars, tensor_to_vec64 as to_vec64, DeviceSpec};
use crate::common::UpdateStats;

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

#[test]
fn td_targets_hand_computed() {
    // gamma 0.5, l = 3: full window, the same terminated, a short truncated window (its tail
    // bootstraps), a one-step terminated window.
    let agent = hand_agent(0.5, 3, 3, 1.0, 2);
    let b = hand_batch(
        2,
        3,
        &[&[1.0, 2.0, 3.0], &[1.0, 2.0, 3.0], &[1.0, 2.0], &[5.0]],
        &[0.0, 1.0, 0.0, 1.0],
    );
    let y = targets_for(&agent, &b, &[8.0, 8.0, 4.0, 2.0]);
    #[rustfmt::skip]
    let want = [
        3.75, 5.5, 7.0,  // 1 + .5*2 + .25*3 + .125*8 ; 2 + .5*3 + .25*8 ; 3 + .5*8
        2.75, 3.5, 3.0,  // terminated: no bootstrap
        3.0, 4.0, 0.0,   // 1 + .5*2 + .25*4 ; 2 + .5*4 ; padding
        5.0, 0.0, 0.0,   // terminated after one step
    ];
    assert_close(&y, &want, 1e-12, "y");

    // Baseline RDPG: l = u = 1, s = 0 is TD(0): y = r + gamma Q(o', mu(o')).
    let agent = hand_agent(0.99, 1, 1, 1.0, 0);
    let b = hand_batch(0, 1, &[&[1.0], &[1.0]], &[0.0, 1.0]);
    let y = targets_for(&agent, &b, &[10.0, 10.0]);
    assert_close(&y, &[1.0 + 0.99 * 10.0, 1.0], 1e-12, "td0");
}

#[test]
fn td_targets_match_reference_loop() {
    let mut rng = NpRng::from_seed(5);
    for &(gamma, l) in &[(0.9, 8usize), (0.99, 5), (1.0, 4)] {
        let agent = hand_agent(gamma, l, l, 1.0, 3);
        let lens: Vec<usize> = (0..6).map(|i| 1 + (i * 7) % l).collect();
        let rs: Vec<Vec<f32>> = lens
            .iter()
            .map(|&k| (0..k).map(|_| rng.normal(0.0, 1.0) as f32).collect())
            .collect();
        let refs: Vec<&[f32]> = rs.iter().map(Vec::as_slice).collect();
        let term: Vec<f32> = (0..6).map(|i| (i % 3 == 0) as u8 as f32).collect();
        let boot: Vec<f64> = (0..6).map(|_| rng.normal(0.0, 5.0)).collect();
        let b = hand_batch(3, l, &refs, &term);
        let y = targets_for(&agent, &b, &boot);
        let mut want = vec![0.0; 6 * l];
        for n in 0..6 {
            let len = lens[n];
            for i in 0..len {
                let mut acc: f64 = rs[n][i..len]
                    .iter()
                    .enumerate()
                    .map(|(j, &r)| gamma.powi(j as i32) * f64::from(r))
                    .sum();
                acc += gamma.powi((len - i) as i32) * boot[n] * (1.0 - f64::from(term[n]));
                want[n * l + i] = acc;
            }
        }
        assert_close(&y, &want, 1e-5, "y");
    }
}

#[test]
fn critic_weights_and_loss_hand_computed() {
    // l = 3, u = 2, lambda = 0.5: weights 1/1.5 and 0.5/1.5 on the first two steps of every
    // window; a one-step window keeps only its first weight (no renormalisation).
    let agent = hand_agent(0.5, 3, 2, 0.5, 0);
    let b = hand_batch(0, 3, &[&[1.0, 2.0, 3.0], &[5.0]], &[0.0, 1.0]);
    let p = agent.prepare(&b);
    let w = to_vec64(&p.critic_w);
    assert_close(
        &w,
        &[2.0 / 3.0, 1.0 / 3.0, 0.0, 2.0 / 3.0, 0.0, 0.0],
        1e-12,
        "w",
    );
    assert_close(
        &to_vec64(&p.actor_w),
        &[1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0, 1.0, 0.0, 0.0],
        1e-12,
        "v",
    );
    let y = Tensor::from_slice(&[1.0f64, 2.0, 3.0, 4.0, 5.0, 6.0]).view([2, 3]);
    let q = Tensor::from_slice(&[0.0f64, 0.0, 100.0, 2.0, 100.0, 100.0]).view([2, 3]);
    let loss = critic_loss_from(&p, &q, &y).double_value(&[]);
    // window 0: 2/3 * 1 + 1/3 * 4 = 2; window 1: 2/3 * 4 = 8/3; mean over N = 2 windows.
    assert!((loss - 7.0 / 3.0).abs() < 1e-12, "{loss}");
    // lambda = 1, u = l: uniform 1/u on real steps.
    let agent = hand_agent(0.5, 3, 3, 1.0, 0);
    let b = hand_batch(0, 3, &[&[1.0, 2.0]], &[0.0]);
    assert_close(
        &to_vec64(&agent.prepare(&b).critic_w),
        &[1.0 / 3.0, 1.0 / 3.0, 0.0],
        1e-12,
        "w1",
    );
    // lambda = 0 keeps only step 0.
    let agent = hand_agent(0.5, 3, 3, 0.0, 0);
    assert_close(
        &to_vec64(&agent.prepare(&b).critic_w),
        &[1.0, 0.0, 0.0],
        1e-12,
        "w0",
    );
}

#[test]
fn targets_and_loss_equal_the_rdpg_core_reference() {
    use rdpg_core::targets::{
        batch_tail_bootstrap_targets, critic_loss_reference, interpolated_td_weights_padded,
    };
    let mut rng = NpRng::from_seed(31);
    for &(gamma, l, u, lambda) in &[
        (0.99, 8usize, 8usize, 1.0),
        (0.9, 6, 3, 0.7),
        (0.5, 1, 1, 1.0),
    ] {
        let cfg = RdpgConfig {
            gamma,
            opt_len: l,
            update_len: u,
            lambda,
            ..tiny()
        };
        let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 0, Kind::Double).unwrap();
        let b = batch(&cfg, 9, 0.6, 40 + l as u64);
        let p = agent.prepare(&b);
        let tail: Vec<f64> = (0..b.n).map(|_| rng.normal(0.0, 3.0)).collect();
        let y = td_targets(&p, &Tensor::from_slice(&tail));
        let want = batch_tail_bootstrap_targets(&b, gamma, &tail);
        assert_close(&to_vec64(&y), &want, 1e-5, "targets");
        let q: Vec<f64> = (0..b.n * l).map(|_| rng.normal(0.0, 1.0)).collect();
        let loss = critic_loss_from(&p, &Tensor::from_slice(&q).view([b.n as i64, l as i64]), &y)
            .double_value(&[]);
        let mask: Vec<f32> = (0..b.n)
            .flat_map(|i| b.mask[i * b.steps() + b.scan..i * b.steps() + b.scan + l].to_vec())
            .collect();
        let weights = interpolated_td_weights_padded(l, u, lambda);
        let reference = critic_loss_reference(&q, &want, &weights, &mask);
        assert!(
            (loss - reference).abs() <= 1e-6 * (1.0 + reference.abs()),
            "{loss} vs {reference}"
        );
    }
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

#[test]
fn scan_with_padding_equals_running_the_window_alone() {
    for kind in [Kind::Double, Kind::Float] {
        for method in [ScanMethod::Grouped, ScanMethod::MaskedLoop] {
            let cfg = RdpgConfig {
                scan_len: 6,
                scan_method: method,
                ..tiny()
            };
            let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 3, kind).unwrap();
            let mut b = batch(&cfg, 12, 0.6, 11);
            b.scan_len[0] = 0;
            b.scan_len[1] = 1;
            b = regenerate_masks(b);
            poison_padding(&mut b);
            assert!(b.scan_len.contains(&6) && b.scan_len.iter().any(|&k| 0 < k && k < 6));
            let p = agent.prepare(&b);
            let sc = tch::no_grad(|| agent.scan_all(&p));
            let tol = if kind == Kind::Double { 1e-12 } else { 1e-5 };
            for i in 0..b.n {
                let (o, a) = real_scan(&b, i);
                let (o, a) = (o.to_kind(kind), a.to_kind(kind));
                let (ha, hc) = tch::no_grad(|| {
                    let z = agent.actor.core.zero_state(1, kind, Device::Cpu);
                    let ha = if b.scan_len[i] == 0 {
                        z
                    } else {
                        agent.actor.core.seq(&agent.actor.input_seq(&o), &z).1
                    };
                    let c = &agent.critics[0];
                    let z = c.core.zero_state(1, kind, Device::Cpu);
                    let hc = if b.scan_len[i] == 0 {
                        z
                    } else {
                        c.core.seq(&c.input_seq(&o, &a), &z).1
                    };
                    (ha, hc)
                });
                let idx = i as i64;
                let what = format!(
                    "{method:?} {kind:?} window {i} (scan_len {})",
                    b.scan_len[i]
                );
                assert_close(
                    &to_vec64(&sc.actor().h.select(1, idx)),
                    &to_vec64(&ha.h),
                    tol,
                    &what,
                );
                assert_close(
                    &to_vec64(&sc.actor().c.select(1, idx)),
                    &to_vec64(&ha.c),
                    tol,
                    &what,
                );
                assert_close(
                    &to_vec64(&sc.critics[0].h.select(1, idx)),
                    &to_vec64(&hc.h),
                    tol,
                    &what,
                );
                assert_close(
                    &to_vec64(&sc.critics[0].c.select(1, idx)),
                    &to_vec64(&hc.c),
                    tol,
                    &what,
                );
            }
        }
    }
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

#[test]
fn tail_bootstrap_uses_the_state_after_the_last_real_step() {
    let cfg = tiny();
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 9, Kind::Double).unwrap();
    let mut b = batch(&cfg, 10, 0.7, 4);
    poison_padding(&mut b);
    assert!(b.opt_len.iter().any(|&k| k < cfg.opt_len));
    let p = agent.prepare(&b);
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let (_, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
    let (q_sa, q_tail) = tch::no_grad(|| agent.critic_forward(&p, &sc, &a_tail, None));
    let t = b.scan + b.opt;
    for i in 0..b.n {
        // The real sequence of window i alone: scan steps, window steps, tail observation.
        let first = b.scan - b.scan_len[i];
        let last = b.scan + b.opt_len[i];
        let rows = (last - first + 1) as i64;
        let o: Vec<f32> = (first..=last)
            .flat_map(|j| b.obs[(i * (t + 1) + j) * OBS..(i * (t + 1) + j + 1) * OBS].to_vec())
            .collect();
        let o = Tensor::from_slice(&o)
            .view([1, rows, OBS as i64])
            .to_kind(Kind::Double);
        let (mu, _) = tch::no_grad(|| {
            agent.actor.forward_seq(
                &o,
                &agent.actor.core.zero_state(1, Kind::Double, Device::Cpu),
            )
        });
        let a_ref = mu.select(1, rows - 1); // mu(o_tail)
        assert_close(
            &to_vec64(&a_tail.select(0, i as i64)),
            &to_vec64(&a_ref),
            1e-12,
            "a_tail",
        );
        let mut a: Vec<f32> = (first..last)
            .flat_map(|j| b.actions[(i * t + j) * ACT..(i * t + j + 1) * ACT].to_vec())
            .collect();
        a.extend(to_vec64(&a_ref).iter().map(|&x| x as f32));
        let a = Tensor::from_slice(&a)
            .view([1, rows, ACT as i64])
            .to_kind(Kind::Double);
        // Replace the f32-rounded tail action by the exact one.
        let a = Tensor::cat(&[a.narrow(1, 0, rows - 1), a_ref.unsqueeze(1)], 1);
        let c = &agent.critics[0];
        let (q, _) = tch::no_grad(|| {
            c.forward_seq(&o, &a, &c.core.zero_state(1, Kind::Double, Device::Cpu))
        });
        let q = to_vec64(&q);
        let k = b.scan_len[i];
        let len = b.opt_len[i];
        assert_close(
            &to_vec64(&q_sa[0].select(0, i as i64).narrow(0, 0, len as i64)),
            &q[k..k + len],
            1e-10,
            "q_sa",
        );
        assert_close(&[to_vec64(&q_tail)[i]], &[q[k + len]], 1e-10, "q_tail");
    }
}

/// Central finite differences of `loss` w.r.t. a few entries of every variable of `vs`,
/// compared to the autograd gradient (already in the variables' `.grad`).
fn check_grads(vs: &VarStore, loss: &dyn Fn() -> f64, what: &str) {
    let eps = 1e-6;
    let mut checked = 0;
    for (name, var) in sorted_vars(vs) {
        let n = var.numel() as i64;
        let g = var.grad();
        assert!(g.defined(), "{what}: no gradient for {name}");
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
            assert!(
                (fd - ad).abs() <= 1e-6 * (1.0 + ad.abs()),
                "{what}: d/d {name}[{idx}]: autograd {ad} vs finite difference {fd}"
            );
            checked += 1;
        }
    }
    assert!(checked > 10);
}

#[test]
fn critic_loss_gradient_matches_finite_differences() {
    for recurrent in [true, false] {
        let cfg = RdpgConfig {
            recurrent,
            lambda: 0.7,
            update_len: 2,
            ..tiny()
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 21, Kind::Double).unwrap();
        let b = batch(&cfg, 5, 0.5, 8);
        let p = agent.prepare(&b);
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (_, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
        let (_, q_tail) = agent.critic_forward(&p, &sc, &a_tail, None);
        // The estimator treats the target and the scanned state as constants.
        let y = tch::no_grad(|| td_targets(&p, &q_tail.detach()));
        let loss = |agent: &RdpgAgent| {
            let (q, _) = agent.critic_forward(&p, &sc, &a_tail, None);
            critic_loss_from(&p, &q[0], &y)
        };
        agent.critic_opt.zero_grad();
        loss(&agent).backward();
        let f = || tch::no_grad(|| loss(&agent).double_value(&[]));
        check_grads(
            &agent.critic_vs[0],
            &f,
            &format!("critic (recurrent {recurrent})"),
        );
    }
}

#[test]
fn actor_loss_gradient_matches_finite_differences() {
    for bptt in [false, true] {
        let cfg = RdpgConfig {
            actor_bptt: bptt,
            ..tiny()
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 22, Kind::Double).unwrap();
        let b = batch(&cfg, 5, 0.5, 9);
        let p = agent.prepare(&b);
        let sc = tch::no_grad(|| agent.scan_all(&p));
        // Per-step gradient: the carried actor states are constants computed once.
        let (states, _) = tch::no_grad(|| agent.actor_window(&p, &sc));
        assert_eq!(states.is_some(), !bptt);
        let cs = tch::no_grad(|| agent.critic_states(&p, &sc.critics[0]));
        let loss = |agent: &RdpgAgent| {
            let input = match &states {
                Some((h, c)) => ActorInput::Detached { h, c },
                None => ActorInput::Bptt { h0: sc.actor() },
            };
            actor_loss(&agent.actor, &agent.critics[0], &p, input, &cs).0
        };
        agent.actor_opt.zero_grad();
        loss(&agent).backward();
        let f = || tch::no_grad(|| loss(&agent).double_value(&[]));
        check_grads(&agent.actor_vs, &f, &format!("actor (bptt {bptt})"));
    }
}

#[test]
fn bptt_and_per_step_gradients_differ_but_agree_on_the_first_step() {
    // The actor's gradient with and without BPTT, for windows of l steps.
    let grads = |bptt: bool, l: usize| -> Vec<f64> {
        let cfg = RdpgConfig {
            actor_bptt: bptt,
            opt_len: l,
            update_len: l,
            ..tiny()
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 23, Kind::Double).unwrap();
        let b = batch(&cfg, 4, 0.0, 10);
        let p = agent.prepare(&b);
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (states, _) = tch::no_grad(|| agent.actor_window(&p, &sc));
        let cs = tch::no_grad(|| agent.critic_states(&p, &sc.critics[0]));
        let input = match &states {
            Some((h, c)) => ActorInput::Detached { h, c },
            None => ActorInput::Bptt { h0: sc.actor() },
        };
        agent.actor_opt.zero_grad();
        actor_loss(&agent.actor, &agent.critics[0], &p, input, &cs)
            .0
            .backward();
        sorted_vars(&agent.actor_vs)
            .iter()
            .flat_map(|(_, v)| to_vec64(&v.grad()))
            .collect()
    };
    // With l = 1 there is no time to back-propagate through: both must agree exactly.
    assert_close(&grads(false, 1), &grads(true, 1), 1e-12, "l = 1");
    // With l = 3 the BPTT gradient also flows through the actor's state into earlier steps,
    // so the two differ.
    let (per_step, bptt) = (grads(false, 3), grads(true, 3));
    let diff: f64 = per_step.iter().zip(&bptt).map(|(a, b)| (a - b).abs()).sum();
    let size: f64 = per_step.iter().map(|a| a.abs()).sum();
    assert!(
        diff > 1e-6 * size,
        "l = 3: BPTT and per-step gradients agree ({diff} vs {size})"
    );
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

#[test]
fn same_seed_same_weights_after_updates() {
    for cfg in [
        tiny(),
        full_cfg(),
        fork_cfg(),
        RdpgConfig {
            actor_uses_updated_critic: false,
            actor_bptt: true,
            ..tiny()
        },
    ] {
        let run = || {
            let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 42).unwrap();
            let mut stats = Vec::new();
            for k in 0..4 {
                stats.push(UpdateStats {
                    seconds: 0.0, // wall time: the one field that may differ
                    ..agent.update(&batch(&cfg, 6, 0.4, 100 + k)).unwrap()
                });
            }
            (agent.weights(), stats)
        };
        let (w1, s1) = run();
        let (w2, s2) = run();
        assert_eq!(s1, s2);
        assert_eq!(w1, w2);
        // A different seed gives different weights.
        let other = RdpgAgent::new(cfg.clone(), OBS, ACT, 43).unwrap();
        assert_ne!(
            other.weights(),
            RdpgAgent::new(cfg.clone(), OBS, ACT, 42).unwrap().weights()
        );
    }
}

#[test]
fn updates_change_weights_and_stats_are_finite() {
    for cfg in [
        tiny(),
        full_cfg(),
        tiny().ddpg(),
        mlp(8),
        RdpgConfig {
            scan_method: ScanMethod::MaskedLoop,
            ..tiny()
        },
    ] {
        // Widths large enough that no ReLU layer is dead for the whole batch at init.
        let cfg = RdpgConfig {
            critic_action_fc: 16,
            actor_hidden: 16,
            critic_hidden: 16,
            ..cfg
        };
        let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 1).unwrap();
        let w0 = agent.weights();
        let s = agent.update(&batch(&cfg, 6, 0.5, 3)).unwrap();
        assert!(
            s.critic_loss.is_finite()
                && s.actor_loss.is_some_and(f64::is_finite)
                && s.q_mean.is_finite(),
            "{s:?}"
        );
        let w1 = agent.weights();
        for ((n, a), (_, b)) in w0.iter().zip(&w1) {
            if n.starts_with("actor.") || n.starts_with("critic") {
                assert_ne!(a, b, "{n} did not move");
            }
        }
        assert_eq!(agent.updates(), 1);
    }
}

#[test]
fn scan_methods_give_the_same_update() {
    let run = |method| {
        let cfg = RdpgConfig {
            scan_method: method,
            ..tiny()
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 5, Kind::Double).unwrap();
        let s = agent.update(&batch(&cfg, 8, 0.6, 77)).unwrap();
        (agent.weights(), s)
    };
    let (wa, sa) = run(ScanMethod::Grouped);
    let (wb, sb) = run(ScanMethod::MaskedLoop);
    assert!((sa.critic_loss - sb.critic_loss).abs() < 1e-10);
    for ((n, a), (_, b)) in wa.iter().zip(&wb) {
        assert_close(a, b, 1e-10, n);
    }
}

fn tmp_dir(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("rdpg-agents-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn save_load_gives_identical_outputs_and_next_update() {
    for (tag, cfg) in [
        ("plain", tiny()),
        ("full", full_cfg()),
        ("fork", fork_cfg()),
    ] {
        let mut a = RdpgAgent::new(cfg.clone(), OBS, ACT, 7).unwrap();
        for k in 0..3 {
            a.update(&batch(&cfg, 6, 0.3, k)).unwrap();
        }
        let dir = tmp_dir(tag);
        a.save(&dir).unwrap();
        let mut b = RdpgAgent::load(&dir).unwrap();
        assert_eq!(b.updates(), 3);
        assert_eq!(a.weights(), b.weights());
        let bounds = |x: &RdpgAgent| x.fork.as_ref().map(|f| f.bounds);
        assert_eq!(bounds(&a), bounds(&b));
        assert_eq!(bounds(&a).is_some(), tag == "fork");
        if let Some(f) = &a.fork {
            assert!(f.bounds.0 < 0.0 && f.bounds.1 > 0.0, "{:?}", f.bounds);
        }
        // An agent without FORK writes the same agent.json as before FORK existed.
        let meta = std::fs::read_to_string(dir.join("agent.json")).unwrap();
        assert_eq!(meta.contains("fork"), tag == "fork", "{meta}");
        // Same actions from the same states.
        let obs: Vec<f32> = (0..2 * OBS).map(|i| (i as f32 * 0.37).sin()).collect();
        let (mut sa, mut sb) = (a.initial_state(2), b.initial_state(2));
        for _ in 0..3 {
            assert_eq!(a.act(&obs, &mut sa).unwrap(), b.act(&obs, &mut sb).unwrap());
        }
        // The next update is bit-identical (Adam moments, step count and noise generator
        // restored).
        let nb = batch(&cfg, 6, 0.3, 99);
        let untimed = |s: UpdateStats| UpdateStats { seconds: 0.0, ..s };
        assert_eq!(
            untimed(a.update(&nb).unwrap()),
            untimed(b.update(&nb).unwrap())
        );
        assert_eq!(a.weights(), b.weights());
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn load_rejects_missing_files() {
    let dir = tmp_dir("missing");
    assert!(RdpgAgent::load(&dir).is_err());
}

#[test]
fn acting_matches_the_sequence_forward_and_resets() {
    let cfg = tiny();
    let agent = RdpgAgent::new(cfg, OBS, ACT, 2).unwrap();
    let n_envs = 3;
    let steps = 5;
    let obs: Vec<Vec<f32>> = (0..steps)
        .map(|t| {
            (0..n_envs * OBS)
                .map(|i| ((i + 7 * t) as f32 * 0.13).cos())
                .collect()
        })
        .collect();
    let mut st = agent.initial_state(n_envs);
    assert_eq!(st.state_dim(), 8);
    assert_eq!(agent.state_dim(), 8);
    let acts: Vec<Vec<f32>> = obs.iter().map(|o| agent.act(o, &mut st).unwrap()).collect();
    // The same observations as one [n_envs, T, D] sequence.
    let mut seq = vec![0.0f32; n_envs * steps * OBS];
    for (t, o) in obs.iter().enumerate() {
        for e in 0..n_envs {
            seq[(e * steps + t) * OBS..(e * steps + t + 1) * OBS]
                .copy_from_slice(&o[e * OBS..(e + 1) * OBS]);
        }
    }
    let seq = Tensor::from_slice(&seq).view([n_envs as i64, steps as i64, OBS as i64]);
    let (mu, _) = tch::no_grad(|| {
        agent.actor.forward_seq(
            &seq,
            &agent.actor.core.zero_state(3, Kind::Float, Device::Cpu),
        )
    });
    for (t, a) in acts.iter().enumerate() {
        for e in 0..n_envs {
            let want = to_vec64(&mu.select(0, e as i64).select(0, t as i64));
            let got: Vec<f64> = a[e * ACT..(e + 1) * ACT]
                .iter()
                .map(|&x| f64::from(x))
                .collect();
            assert_close(&got, &want, 1e-5, "act");
        }
    }
    assert!(st.env_state(1).iter().any(|&x| x != 0.0));
    agent.reset_state(&mut st, Some(1));
    assert!(st.env_state(1).iter().all(|&x| x == 0.0));
    assert!(st.env_state(0).iter().any(|&x| x != 0.0));
    let s0 = st.env_state(0);
    st.set_env_state(2, &s0);
    assert_eq!(st.env_state(2), s0);
    assert_eq!(st.to_vec().len(), 3 * 8);
    agent.reset_state(&mut st, None);
    assert!(st.to_vec().iter().all(|&x| x == 0.0));
}

#[test]
fn burn_in_starts_the_actor_scan_from_the_stored_state() {
    let cfg = RdpgConfig {
        burn_in_from_stored_state: true,
        ..tiny()
    };
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 4, Kind::Double).unwrap();
    let mut b = batch(&cfg, 5, 0.5, 12);
    assert!(agent.check_batch(&b).is_err(), "stored states are required");
    let mut rng = NpRng::from_seed(1);
    b.state_dim = 8;
    b.stored_state = Some((0..5 * 8).map(|_| rng.normal(0.0, 0.5) as f32).collect());
    agent.check_batch(&b).unwrap();
    let p = agent.prepare(&b);
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let st = b.stored_state.as_ref().unwrap();
    for i in 0..b.n {
        let (o, _) = real_scan(&b, i);
        let init = Tensor::from_slice(&st[i * 8..(i + 1) * 8]).to_kind(Kind::Double);
        let init = RecState {
            h: init.narrow(0, 0, 4).view([1, 1, 4]),
            c: init.narrow(0, 4, 4).view([1, 1, 4]),
        };
        let want = if b.scan_len[i] == 0 {
            init
        } else {
            tch::no_grad(|| {
                agent
                    .actor
                    .core
                    .seq(&agent.actor.input_seq(&o.to_kind(Kind::Double)), &init)
                    .1
            })
        };
        assert_close(
            &to_vec64(&sc.actor().h.select(1, i as i64)),
            &to_vec64(&want.h),
            1e-12,
            "h",
        );
        assert_close(
            &to_vec64(&sc.actor().c.select(1, i as i64)),
            &to_vec64(&want.c),
            1e-12,
            "c",
        );
    }
}

#[test]
fn critic_regresses_rewards_when_gamma_is_zero() {
    for cfg in [tiny(), tiny().ddpg()] {
        let cfg = RdpgConfig {
            gamma: 0.0,
            lr_critic: 3e-3,
            ..cfg
        };
        let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 6).unwrap();
        let b = batch(&cfg, 8, 0.3, 5);
        let first = agent.update(&b).unwrap().critic_loss;
        let mut last = first;
        for _ in 0..150 {
            last = agent.update(&b).unwrap().critic_loss;
        }
        assert!(last < 0.3 * first, "critic loss {first} -> {last}");
    }
}

#[test]
fn check_batch_rejects_inconsistent_batches() {
    let cfg = tiny();
    let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 0).unwrap();
    let good = batch(&cfg, 4, 0.5, 1);
    agent.check_batch(&good).unwrap();
    let mut b = good.clone();
    b.obs_dim = 12;
    assert!(agent.check_batch(&b).is_err());
    let mut b = good.clone();
    b.opt_len[0] = 0;
    assert!(agent.check_batch(&b).is_err());
    let mut b = good;
    let t = b.scan + b.opt;
    b.mask[t - 1] = 1.0 - b.mask[t - 1];
    assert!(agent.check_batch(&b).is_err());
    // `update` refuses it the same way, and changes nothing.
    let before = agent.actor_params();
    let e = agent.update(&b).unwrap_err().to_string();
    assert!(e.contains("mask"), "{e}");
    assert_eq!((agent.updates(), agent.actor_params()), (0, before));
}

#[test]
fn exploring_params_swap_in_a_perturbed_actor() {
    let mut agent = RdpgAgent::new(tiny(), OBS, ACT, 8).unwrap();
    let obs: Vec<f32> = (0..2 * OBS).map(|i| (i as f32 * 0.21).sin()).collect();
    let mut params = agent.actor_params();
    assert_eq!(params.len(), agent.actor_param_count());
    let reference = agent.act(&obs, &mut agent.initial_state(2)).unwrap();
    // The same parameters act identically.
    agent.set_exploring_params(Some(&params)).unwrap();
    assert_eq!(
        agent
            .act_exploring(&obs, &mut agent.initial_state(2))
            .unwrap(),
        reference
    );
    // Perturbed parameters act differently; the trained actor is untouched.
    for p in params.iter_mut() {
        *p += 0.05;
    }
    agent.set_exploring_params(Some(&params)).unwrap();
    assert_ne!(
        agent
            .act_exploring(&obs, &mut agent.initial_state(2))
            .unwrap(),
        reference
    );
    assert_eq!(
        agent.act(&obs, &mut agent.initial_state(2)).unwrap(),
        reference
    );
    agent.set_exploring_params(None).unwrap();
    assert_eq!(
        agent
            .act_exploring(&obs, &mut agent.initial_state(2))
            .unwrap(),
        reference
    );
    assert!(agent.set_exploring_params(Some(&params[1..])).is_err());
}

/// TD3's delayed policy updates: with `policy_delay = 2` the critics move on every update,
/// the actor and every target network only on updates 2, 4, ...; the statistics say which.
#[test]
fn policy_delay_moves_actor_and_targets_every_second_update() {
    let cfg = RdpgConfig {
        policy_delay: 2,
        critic_action_fc: 16,
        actor_hidden: 16,
        critic_hidden: 16,
        ..full_cfg()
    };
    let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 4).unwrap();
    let group = |w: &[(String, Vec<f64>)], prefix: &str| -> Vec<Vec<f64>> {
        w.iter()
            .filter(|(n, _)| n.starts_with(prefix))
            .map(|(_, v)| v.clone())
            .collect()
    };
    let mut prev = agent.weights();
    for k in 1..=4u64 {
        let s = agent.update(&batch(&cfg, 6, 0.5, 10 + k)).unwrap();
        let w = agent.weights();
        let actor_turn = k % 2 == 0;
        assert_eq!(s.actor_loss.is_some(), actor_turn, "update {k}: {s:?}");
        assert_ne!(
            group(&w, "critic"),
            group(&prev, "critic"),
            "critic, update {k}"
        );
        for prefix in ["actor.", "target.actor.", "target.critic"] {
            let moved = group(&w, prefix) != group(&prev, prefix);
            assert_eq!(moved, actor_turn, "{prefix} moved = {moved} on update {k}");
        }
        prev = w;
    }
    assert_eq!(agent.updates(), 4);
}

/// R2D2's "stored state, no burn-in": with `scan_len = 0` and stored states the actor's run
/// along the window starts from the stored state (not from zeros), so the bootstrap action
/// is the actor's output after the window from that state.
#[test]
fn stored_state_without_burn_in_starts_the_window_from_it() {
    let cfg = RdpgConfig {
        scan_len: 0,
        burn_in_from_stored_state: true,
        ..tiny()
    };
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 6, Kind::Double).unwrap();
    let mut b = batch(&cfg, 3, 0.0, 8);
    let sd = agent.state_dim();
    b.state_dim = sd;
    let states: Vec<f32> = (0..3 * sd).map(|i| (i as f32 * 0.37).sin() * 0.5).collect();
    b.stored_state = Some(states.clone());
    agent.check_batch(&b).unwrap();
    let p = agent.prepare(&b);
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let (_, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
    let h = sd / 2;
    for w in 0..3 {
        let st = &states[w * sd..(w + 1) * sd];
        let init = RecState {
            h: Tensor::from_slice(&st[..h])
                .to_kind(Kind::Double)
                .view([1, 1, h as i64]),
            c: Tensor::from_slice(&st[h..])
                .to_kind(Kind::Double)
                .view([1, 1, h as i64]),
        };
        let len = b.opt_len[w];
        let t = b.scan + b.opt;
        let o = Tensor::from_slice(&b.obs[w * (t + 1) * OBS..(w * (t + 1) + len + 1) * OBS])
            .to_kind(Kind::Double)
            .view([1, len as i64 + 1, OBS as i64]);
        let want = tch::no_grad(|| agent.actor.forward_seq(&o, &init).0.select(1, len as i64));
        assert_close(
            &to_vec64(&a_tail.select(0, w as i64)),
            &to_vec64(&want.squeeze_dim(0)),
            1e-10,
            "tail action from the stored state",
        );
    }
    // Without stored states the batch is refused (no silent zero start).
    b.stored_state = None;
    assert!(agent.check_batch(&b).is_err());
}

/// `lstm_forget_bias` adds its value to exactly the forget-gate quarter of each LSTM's input
/// bias (gate order i, f, g, o), in actor and critics, and changes nothing else.
#[test]
fn forget_bias_shifts_only_the_forget_gate() {
    let base = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 3, Kind::Double).unwrap();
    let cfg = RdpgConfig {
        lstm_forget_bias: 1.0,
        ..tiny()
    };
    let shifted = RdpgAgent::new_with_kind(cfg, OBS, ACT, 3, Kind::Double).unwrap();
    let mut lstms = 0;
    for ((n, a), (m, b)) in base.weights().iter().zip(&shifted.weights()) {
        assert_eq!(n, m);
        if n.ends_with("lstm.bias_ih_l0") {
            lstms += 1;
            let h = a.len() / 4;
            for (k, (x, y)) in a.iter().zip(b).enumerate() {
                let want = if (h..2 * h).contains(&k) { x + 1.0 } else { *x };
                assert!((y - want).abs() < 1e-12, "{n}[{k}]: {x} -> {y}");
            }
        } else {
            assert_eq!(a, b, "{n}");
        }
    }
    assert_eq!(lstms, 2, "actor and critic LSTMs");
    let ff = RdpgConfig {
        lstm_forget_bias: 1.0,
        ..tiny().ddpg()
    };
    assert!(ff.validate().is_err());
}

/// Rewards on padded steps (which the replay leaves at 0, but a buggy producer might not)
/// change neither the TD targets on real steps nor the critic loss.
#[test]
fn padded_rewards_do_not_reach_targets_or_loss() {
    let cfg = tiny();
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 2, Kind::Double).unwrap();
    let clean = batch(&cfg, 8, 0.7, 31);
    let mut dirty = clean.clone();
    for (r, m) in dirty.rewards.iter_mut().zip(&clean.mask) {
        if *m == 0.0 {
            *r = 5.0;
        }
    }
    assert_ne!(dirty.rewards, clean.rewards, "the batch has padding");
    let boot: Vec<f64> = (0..8).map(|i| 0.3 * i as f64 - 1.0).collect();
    let (y0, y1) = (
        targets_for(&agent, &clean, &boot),
        targets_for(&agent, &dirty, &boot),
    );
    let mask: Vec<f64> = clean
        .mask
        .chunks(clean.scan + clean.opt)
        .flat_map(|m| m[clean.scan..].iter().map(|&x| f64::from(x)))
        .collect();
    for ((a, b), m) in y0.iter().zip(&y1).zip(&mask) {
        if *m == 1.0 {
            assert_eq!(a, b);
        }
    }
    let loss = |b: &SequenceBatch| {
        let p = agent.prepare(b);
        let q = Tensor::zeros([8, cfg.opt_len as i64], (Kind::Double, Device::Cpu));
        let y = td_targets(&p, &Tensor::from_slice(&boot));
        critic_loss_from(&p, &q, &y).double_value(&[])
    };
    assert_eq!(loss(&clean), loss(&dirty));
}

/// Twin critics: the bootstrap is the minimum of the two target critics' values, value for
/// value; raising one critic's output above the other changes nothing, lowering it moves the
/// bootstrap exactly by the shift.
#[test]
fn twin_bootstrap_is_the_elementwise_minimum() {
    let cfg = RdpgConfig {
        tau: 0.1,
        twin_critic: true,
        ..tiny()
    };
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 12, Kind::Double).unwrap();
    let b = batch(&cfg, 6, 0.5, 4);
    let p = agent.prepare(&b);
    let boot = |agent: &RdpgAgent| {
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (_, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
        let q = tch::no_grad(|| agent.target_tail_q(&p, &sc, &a_tail)).unwrap();
        to_vec64(&q)
    };
    let base = boot(&agent);
    let shift = |delta: f64| {
        let t = agent.targets.as_ref().unwrap();
        let head = sorted_vars(&t.critic_vs[1])
            .into_iter()
            .find(|(n, _)| n.ends_with("head.bias"))
            .unwrap()
            .1;
        tch::no_grad(|| {
            let mut h = head.shallow_clone();
            let _ = h.g_add_scalar_(delta);
        });
    };
    // Each critic alone, to know which is smaller.
    let single = |i: usize| {
        let t = agent.targets.as_ref().unwrap();
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (_, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
        to_vec64(&tch::no_grad(|| {
            super::update::tail_q(
                &p,
                &super::update::critic_window(
                    &t.critics[i],
                    &p,
                    &sc.target_critics[i],
                    Some(&a_tail),
                ),
            )
        }))
    };
    let (q1, q2) = (single(0), single(1));
    for i in 0..6 {
        assert_eq!(base[i], q1[i].min(q2[i]));
    }
    shift(100.0);
    assert_close(
        &boot(&agent),
        &q1,
        1e-12,
        "critic 2 raised: critic 1 is the minimum",
    );
    shift(-200.0);
    let want: Vec<f64> = q2.iter().map(|q| q - 100.0).collect();
    assert_close(&boot(&agent), &want, 1e-9, "critic 2 lowered by 100");
}

/// Target policy smoothing: the noise is clipped at `clip` before it is added, and the
/// smoothed action stays in `[-1, 1]`.
#[test]
fn target_noise_is_clipped_then_the_action_clamped() {
    let mut agent = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 1, Kind::Double).unwrap();
    let a = Tensor::from_slice(&[0.0f64, 0.9, -0.95, 0.3]).view([2, 2]);
    let mut clipped = 0;
    for _ in 0..200 {
        let s = to_vec64(&agent.smooth_target_action(&a, 10.0, 0.5));
        for (x, y) in to_vec64(&a).iter().zip(&s) {
            assert!((-1.0..=1.0).contains(y), "{y}");
            let d = y - x;
            assert!(d.abs() <= 0.5 + 1e-12, "noise {d}");
            if (y.abs() - 1.0).abs() > 1e-12 && (d.abs() - 0.5).abs() < 1e-12 {
                clipped += 1;
            }
        }
    }
    // With σ = 10 almost every draw is clipped to ±0.5 (unless clamped at ±1).
    assert!(clipped > 300, "{clipped}");
}

/// The soft update: after an update, every target variable is exactly
/// `target + τ (online - target)` of the values before the step.
#[test]
fn soft_update_moves_targets_by_tau() {
    let cfg = RdpgConfig {
        tau: 0.25,
        critic_action_fc: 16,
        actor_hidden: 16,
        critic_hidden: 16,
        ..tiny()
    };
    let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 5, Kind::Double).unwrap();
    // One update so that online and target differ, then check the next one.
    agent.update(&batch(&cfg, 6, 0.5, 1)).unwrap();
    let before = agent.weights();
    agent.update(&batch(&cfg, 6, 0.5, 2)).unwrap();
    let after = agent.weights();
    let get = |w: &[(String, Vec<f64>)], n: &str| w.iter().find(|(m, _)| m == n).unwrap().1.clone();
    let mut checked = 0;
    for (name, old_target) in before.iter().filter(|(n, _)| n.starts_with("target.")) {
        let online = get(&after, &name["target.".len()..]);
        let new_target = get(&after, name);
        for ((t0, o), t1) in old_target.iter().zip(&online).zip(&new_target) {
            let want = t0 + 0.25 * (o - t0);
            assert!((t1 - want).abs() < 1e-12, "{name}: {t1} vs {want}");
        }
        assert_ne!(old_target, &new_target, "{name} did not move");
        checked += 1;
    }
    assert!(checked >= 10, "{checked} target variables");
}

/// The classic RDPG's per-step TD(0) targets against a direct computation: for every real
/// step `i` of every window, the target actor and critic run from the start of the window over
/// the replayed prefix `o_0..o_{i+1}`, `a_0..a_i` and the target action at `o_{i+1}`:
/// `y_i = r_i + gamma Q'(o_{i+1}, mu'(o_{i+1}) | h'_i)`, without the bootstrap after a
/// terminal step.
#[test]
fn per_step_td0_targets_match_a_direct_computation() {
    let cfg = RdpgConfig {
        critic_target: super::config::CriticTarget::PerStepTd0,
        scan_len: 0,
        opt_len: 4,
        update_len: 4,
        tau: 0.1,
        twin_critic: false,
        ..tiny()
    };
    let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 17, Kind::Double).unwrap();
    let b = batch(&cfg, 10, 0.7, 21);
    let p = agent.prepare(&b);
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let y = to_vec64(&tch::no_grad(|| agent.per_step_targets(&p, &sc)));
    let t = agent.targets.as_ref().unwrap();
    let (l, steps) = (b.opt, b.scan + b.opt);
    let mut checked = 0;
    for w in 0..b.n {
        let len = b.opt_len[w];
        for i in 0..len {
            let obs =
                Tensor::from_slice(&b.obs[w * (steps + 1) * OBS..(w * (steps + 1) + i + 2) * OBS])
                    .to_kind(Kind::Double)
                    .view([1, i as i64 + 2, OBS as i64]);
            let z = |h: i64| RecState::zeros(1, h, Kind::Double, Device::Cpu);
            let (mu, _) = tch::no_grad(|| t.actor.forward_seq(&obs, &z(4)));
            let next_a = mu.select(1, i as i64 + 1).view([1, 1, ACT as i64]);
            let acts = Tensor::from_slice(&b.actions[w * steps * ACT..(w * steps + i + 1) * ACT])
                .to_kind(Kind::Double)
                .view([1, i as i64 + 1, ACT as i64]);
            let acts = Tensor::cat(&[acts, next_a], 1);
            let (q, _) = tch::no_grad(|| t.critics[0].forward_seq(&obs, &acts, &z(5)));
            let q_next = q.double_value(&[0, i as i64 + 1]);
            let terminal = b.tail_terminated[w] == 1.0 && i + 1 == len;
            let r = f64::from(b.rewards[w * steps + i]);
            let want = r + if terminal { 0.0 } else { cfg.gamma * q_next };
            assert!(
                (y[w * l + i] - want).abs() < 1e-10,
                "window {w}, step {i}: {} vs {want}",
                y[w * l + i]
            );
            checked += 1;
        }
        for i in len..l {
            assert_eq!(y[w * l + i], 0.0, "padding");
        }
    }
    assert!(checked > 20, "{checked}");
    assert!(
        b.tail_terminated.contains(&1.0),
        "the batch has a terminal window"
    );
}

/// Gradient checks through the update's own code path: the autograd gradients of the critic
/// loss as `critic_objective` builds it (scan, window runs, bootstrap, targets) and of the
/// actor loss on the states it returns must equal finite differences of the same losses with
/// the targets, the scanned states and the carried actor states held fixed, as the estimator
/// (semi-gradient TD, actor without BPTT) defines them. A missing `no_grad`/`detach` on the
/// targets, the bootstrap, the scan or the actor's states makes autograd differentiate through
/// them and fails this test; so does gradient reaching the critic from the actor loss.
#[test]
fn update_path_gradients_hold_targets_scans_and_states_constant() {
    use super::config::CriticTarget;
    use super::profile::Clock;
    let cases = [
        (0.0, CriticTarget::TailBootstrap, true),
        (0.1, CriticTarget::TailBootstrap, true),
        (0.0, CriticTarget::PerStepTd0, true),
        (0.1, CriticTarget::PerStepTd0, true),
        (0.0, CriticTarget::TailBootstrap, false),
    ];
    for (tau, critic_target, recurrent) in cases {
        let what = format!("tau {tau}, {critic_target:?}, recurrent {recurrent}");
        let cfg = RdpgConfig {
            tau,
            critic_target,
            recurrent,
            lambda: 0.7,
            update_len: 2,
            ..tiny()
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 41, Kind::Double).unwrap();
        let b = batch(&cfg, 5, 0.5, 12);
        let p = agent.prepare(&b);
        let sc = agent.scan_all(&p);
        let (q_sa, y, states) = agent.critic_objective(&p, &sc, &mut Clock::new(false));
        agent.critic_opt.zero_grad();
        critic_loss_from(&p, &q_sa[0], &y).backward();
        let critic_fd = |agent: &RdpgAgent| {
            tch::no_grad(|| {
                let q = super::update::critic_window(&agent.critics[0], &p, &sc.critics[0], None);
                critic_loss_from(&p, &q, &y).double_value(&[])
            })
        };
        check_grads(
            &agent.critic_vs[0],
            &|| critic_fd(&agent),
            &format!("critic, {what}"),
        );

        if recurrent {
            let (h, c) = states.expect("per-step actor states");
            let cs = tch::no_grad(|| agent.critic_states(&p, &sc.critics[0]));
            let loss = |agent: &RdpgAgent| {
                actor_loss(
                    &agent.actor,
                    &agent.critics[0],
                    &p,
                    ActorInput::Detached { h: &h, c: &c },
                    &cs,
                )
                .0
            };
            agent.actor_opt.zero_grad();
            agent.critic_opt.zero_grad();
            for vs in &mut agent.critic_vs {
                vs.freeze();
            }
            loss(&agent).backward();
            for vs in &mut agent.critic_vs {
                vs.unfreeze();
            }
            let f = || tch::no_grad(|| loss(&agent).double_value(&[]));
            check_grads(&agent.actor_vs, &f, &format!("actor, {what}"));
            for (name, v) in sorted_vars(&agent.critic_vs[0]) {
                let g = v.grad();
                assert!(
                    !g.defined() || to_vec64(&g).iter().all(|&x| x == 0.0),
                    "{what}: the actor loss reached critic weight {name}"
                );
            }
        }
    }
}

/// Algorithm 1's order: with `actor_uses_updated_critic` the actor loss is computed with the
/// critic *after* its Adam step, on critic states rescanned with the new weights; without it,
/// with the critic before the step. Each update's reported actor loss equals the loss rebuilt
/// by hand in that order, and the two orders differ.
#[test]
fn actor_sees_the_critic_in_algorithm_1_order() {
    use super::profile::Clock;
    let mut losses = Vec::new();
    for updated in [true, false] {
        let cfg = RdpgConfig {
            actor_uses_updated_critic: updated,
            critic_action_fc: 16,
            actor_hidden: 16,
            critic_hidden: 16,
            ..tiny()
        };
        let b = batch(&cfg, 6, 0.5, 77);
        let mut a = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 9, Kind::Double).unwrap();
        let mut m = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 9, Kind::Double).unwrap();
        let reported = a.update(&b).unwrap().actor_loss.unwrap();
        // By hand on the twin agent.
        let p = m.prepare(&b);
        let sc = m.scan_all(&p);
        let (q_sa, y, states) = m.critic_objective(&p, &sc, &mut Clock::new(false));
        let (h, c) = states.unwrap();
        let loss_now = |m: &RdpgAgent, cs: &(Tensor, Tensor)| {
            tch::no_grad(|| {
                actor_loss(
                    &m.actor,
                    &m.critics[0],
                    &p,
                    ActorInput::Detached { h: &h, c: &c },
                    cs,
                )
                .0
            })
            .double_value(&[])
        };
        // The critic before its step: its weights and its states along the window.
        let before = loss_now(&m, &tch::no_grad(|| m.critic_states(&p, &sc.critics[0])));
        m.critic_opt.zero_grad();
        critic_loss_from(&p, &q_sa[0], &y).backward();
        m.critic_opt.step();
        let h_new = tch::no_grad(|| scan_critic(&m.critics[0], &p, m.cfg.scan_method));
        let after = loss_now(&m, &tch::no_grad(|| m.critic_states(&p, &h_new)));
        let by_hand = if updated { after } else { before };
        assert!(
            (reported - by_hand).abs() < 1e-12,
            "updated critic {updated}: reported {reported} vs by hand {by_hand}"
        );
        losses.push(reported);
    }
    assert_ne!(losses[0], losses[1], "the two orders must differ");
}

/// Bad observations are errors with a message, never a panic, and leave the state alone.
#[test]
fn acting_on_bad_observations_is_an_error() {
    let agent = RdpgAgent::new(tiny(), OBS, ACT, 2).unwrap();
    let mut st = agent.initial_state(2);
    let before = st.to_vec();
    let short = vec![0.1f32; 2 * OBS - 1];
    let e = agent.act(&short, &mut st).unwrap_err().to_string();
    assert!(e.contains("obs_dim 13"), "{e}");
    let mut nan = vec![0.1f32; 2 * OBS];
    nan[OBS + 4] = f32::NAN;
    let e = agent.act_exploring(&nan, &mut st).unwrap_err().to_string();
    assert!(e.contains("component 4 of environment 1"), "{e}");
    assert_eq!(st.to_vec(), before);
}

/// The feed-forward update's short cuts (TD3's critic, target networks): the bootstrap action
/// is `mu'(o_tail)` and the bootstrap value `min_k Q'_k(o_tail, a_tail)`, computed for each
/// window on its own tail observation alone, whatever the padding holds; and the actor's
/// critic states are zero-width.
#[test]
fn feed_forward_bootstrap_reads_the_tail_observation_alone() {
    let cfg = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![6] },
        recurrent: false,
        critic_action_fc: 0,
        twin_critic: true,
        tau: 0.01,
        scan_len: 0,
        ..tiny()
    };
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 5, Kind::Double).unwrap();
    let mut b = batch(&cfg, 10, 0.7, 8);
    poison_padding(&mut b);
    assert!(b.opt_len.iter().any(|&k| k < cfg.opt_len));
    let p = agent.prepare(&b);
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let (states, a_tail) = tch::no_grad(|| agent.actor_window(&p, &sc));
    assert!(states.is_none());
    let q_tail = tch::no_grad(|| agent.target_tail_q(&p, &sc, &a_tail)).unwrap();
    let t = agent.targets.as_ref().unwrap();
    let tt = b.scan + b.opt;
    for i in 0..b.n {
        let j = b.scan + b.opt_len[i]; // the tail observation's slot
        let o: Vec<f32> = b.obs[(i * (tt + 1) + j) * OBS..(i * (tt + 1) + j + 1) * OBS].to_vec();
        let o = Tensor::from_slice(&o)
            .view([1, OBS as i64])
            .to_kind(Kind::Double);
        let none = t.actor.core.zero_state(1, Kind::Double, Device::Cpu);
        let a_ref = tch::no_grad(|| t.actor.step(&o, &none).0);
        let a_i = a_tail.select(0, i as i64).unsqueeze(0);
        assert_close(&to_vec64(&a_i), &to_vec64(&a_ref), 1e-12, "a_tail");
        let q_ref: Vec<f64> = t
            .critics
            .iter()
            .map(|c| to_vec64(&tch::no_grad(|| c.step(&o, &a_i, &none).0))[0])
            .collect();
        let q_min = q_ref.iter().copied().fold(f64::INFINITY, f64::min);
        assert_close(
            &to_vec64(&q_tail.select(0, i as i64).unsqueeze(0)),
            &[q_min],
            1e-12,
            "q_tail",
        );
    }
    let (h, c) = tch::no_grad(|| agent.critic_states(&p, &sc.critics[0]));
    assert_eq!(h.size(), [b.n as i64, cfg.opt_len as i64, 0]);
    assert_eq!(c.size(), h.size());
}

/// `parallel_twins` runs the second critic (scan, target value, gradient) on a second thread:
/// the updates are the same as on one thread, bit for bit (f32, the trained kind) — every
/// weight, target weight and optimiser moment, and the reported statistics — for a recurrent
/// agent with a scan and stored-state burn-in and for a feed-forward one, over updates with and
/// without the actor's turn (policy delay 2).
#[test]
fn parallel_twins_update_bit_for_bit_like_one_thread() {
    let twin_td3 = |cfg: RdpgConfig| RdpgConfig {
        twin_critic: true,
        tau: 0.05,
        policy_delay: 2,
        target_noise: Some(super::config::TargetNoise {
            std: 0.2,
            clip: 0.5,
        }),
        ..cfg
    };
    let recurrent = twin_td3(RdpgConfig {
        burn_in_from_stored_state: true,
        ..tiny()
    });
    let feed_forward = twin_td3(RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![6] },
        recurrent: false,
        critic_action_fc: 0,
        opt_len: 3, // n-step returns for the first step: the critic runs on it alone
        update_len: 1,
        scan_len: 0,
        ..tiny()
    });
    // The critic's Adam step after the actor's backward pass, and clipped gradients.
    let deferred = RdpgConfig {
        actor_uses_updated_critic: false,
        grad_clip: Some(0.5),
        ..recurrent.clone()
    };
    let window = twin_td3(window_cfg(4));
    for cfg in [recurrent, feed_forward, deferred, fork_cfg(), window] {
        let parallel = RdpgConfig {
            parallel_twins: true,
            ..cfg.clone()
        };
        let mut one = RdpgAgent::new(cfg.clone(), OBS, ACT, 21).unwrap();
        let mut two = RdpgAgent::new(parallel, OBS, ACT, 21).unwrap();
        for k in 0..5 {
            let mut b = batch(&cfg, 6, 0.5, 100 + k);
            if cfg.burn_in_from_stored_state {
                let width = 2 * cfg.actor_hidden;
                b.state_dim = width;
                b.stored_state = Some(
                    (0..b.n * width)
                        .map(|i| (i as f32 * 0.37).sin() * 0.3)
                        .collect(),
                );
            }
            let (s1, s2) = (one.update(&b).unwrap(), two.update(&b).unwrap());
            assert_eq!(s1.critic_loss, s2.critic_loss, "update {k}: critic loss");
            assert_eq!(s1.actor_loss, s2.actor_loss, "update {k}: actor loss");
            assert_eq!(s1.q_mean, s2.q_mean, "update {k}: q mean");
        }
        let state = |a: &RdpgAgent| -> Vec<(String, Vec<f64>)> {
            let mut out: Vec<_> = std::iter::once(&a.actor_vs)
                .chain(&a.critic_vs)
                .chain(
                    a.targets
                        .iter()
                        .flat_map(|t| std::iter::once(&t.actor_vs).chain(&t.critic_vs)),
                )
                .flat_map(sorted_vars)
                .map(|(n, t)| (n, to_vec64(&t)))
                .collect();
            for (n, t) in a
                .critic_opt
                .state("critic_opt.")
                .into_iter()
                .chain(a.actor_opt.state("actor_opt."))
            {
                out.push((n, to_vec64(&t.to_kind(Kind::Double))));
            }
            out
        };
        let (s1, s2) = (state(&one), state(&two));
        assert_eq!(s1.len(), s2.len());
        for ((n1, v1), (n2, v2)) in s1.iter().zip(&s2) {
            assert_eq!(n1, n2);
            assert_eq!(v1, v2, "{n1} differs (recurrent: {})", cfg.recurrent);
        }
    }
}

/// The actor's gradient of FORK's term as computed (predicted observations held constant, the
/// reward model frozen) equals the gradient of the term written as TD3-FORK's code writes it
/// (`detach` exactly where its authors put it, models trainable), and reaches neither model.
/// (The update freezes the critic around the actor's loss; see the test below.)
#[test]
fn fork_term_equals_the_reference_formulation() {
    let cfg = fork_cfg();
    let gamma = cfg.gamma;
    let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 31, Kind::Double).unwrap();
    let b = batch(&cfg, 5, 0.5, 12);
    let p = agent.prepare(&b);
    let mut f = agent.fork.take().unwrap();
    for _ in 0..3 {
        f.train(&p); // bounds set, models away from their initialisation
    }
    let actor_grads = |agent: &RdpgAgent| -> Vec<Vec<f64>> {
        sorted_vars(&agent.actor_vs)
            .iter()
            .map(|(_, v)| to_vec64(&v.grad()))
            .collect()
    };

    // mu(o_i) as the update hands it over: the actions the actor loss differentiated through.
    let sc = tch::no_grad(|| agent.scan_all(&p));
    let cs = tch::no_grad(|| agent.critic_states(&p, &sc.critics[0]));
    let input = ActorInput::Bptt { h0: sc.actor() }; // feed-forward: no per-step states
    let (_, a0) = actor_loss(&agent.actor, &agent.critics[0], &p, input, &cs);
    agent.actor_opt.zero_grad();
    f.dynamics_opt.zero_grad();
    f.reward_opt.zero_grad();
    let ours = f.actor_term(&agent.actor, &agent.critics[0], &p, &a0, gamma);
    ours.backward();
    let g_ours = actor_grads(&agent);
    for (name, v) in f.vars() {
        let g = v.grad();
        assert!(
            !g.defined() || to_vec64(&g).iter().all(|&x| x == 0.0),
            "{name} received a gradient from the actor's term"
        );
    }

    // TD3-FORK's formulation, literally.
    agent.actor_opt.zero_grad();
    let (n, l) = (p.n, p.l);
    let d = OBS as i64;
    let state = p.obs_win.narrow(1, 0, l).reshape([n * l, d]);
    let zero = agent
        .actor
        .core
        .zero_state(n * l, Kind::Double, Device::Cpu);
    let actor = |o: &Tensor| agent.actor.step(o, &zero).0;
    let p_next_state = f.predict(&state, &actor(&state));
    let p_next_r = f.reward(&state, &p_next_state.detach(), &actor(&state));
    let p_next_state2 = f.predict(&p_next_state, &actor(&p_next_state.detach()));
    let p_next_r2 = f.reward(
        &p_next_state.detach(),
        &p_next_state2.detach(),
        &actor(&p_next_state.detach()),
    );
    let actions3 = actor(&p_next_state2.detach());
    let zc = agent.critics[0]
        .core
        .zero_state(n * l, Kind::Double, Device::Cpu);
    let (q, _) = agent.critics[0].step(&p_next_state2.detach(), &actions3, &zc);
    let v = p_next_r + p_next_r2 * gamma + q * (gamma * gamma);
    let reference = -(v.reshape([n, l]) * &p.actor_w).sum(Kind::Double) / n as f64;
    reference.backward();
    let g_ref = actor_grads(&agent);

    assert_close(
        &[ours.double_value(&[])],
        &[reference.double_value(&[])],
        1e-12,
        "J_fork",
    );
    for (k, (a, r)) in g_ours.iter().zip(&g_ref).enumerate() {
        assert!(
            a.iter().any(|&x| x != 0.0),
            "actor variable {k}: no gradient"
        );
        assert_close(a, r, 1e-10, &format!("actor variable {k}"));
    }
}

/// The term enters the actor's update exactly when it should: an agent with weight 0, or
/// with a threshold the model never meets, trains exactly like one without FORK's term (same
/// critics, models and actor), and weight 0.5 moves only the actor (and its target).
#[test]
fn fork_term_moves_the_actor_only_when_gated_in() {
    let with = |weight: f64, threshold: f64| RdpgConfig {
        fork: Some(ForkConfig {
            weight,
            threshold,
            ..fork_cfg().fork.unwrap()
        }),
        ..fork_cfg()
    };
    let train = |cfg: RdpgConfig| {
        let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 9).unwrap();
        // Two updates: the actor's first turn is the second (later critic updates would
        // see the moved target actor).
        let stats: Vec<UpdateStats> = (0..2)
            .map(|k| agent.update(&batch(&cfg, 6, 0.5, 40 + k)).unwrap())
            .collect();
        (agent.weights(), stats)
    };
    let (w_on, s_on) = train(with(0.5, 1e3));
    let (w_zero, _) = train(with(0.0, 1e3));
    let (w_gated, s_gated) = train(with(0.5, 1e-12));
    assert_eq!(w_zero, w_gated, "weight 0 and a closed gate must agree");
    assert!(s_on.iter().all(|s| s.model_loss.is_some()));
    assert_eq!(s_on[1].fork_term, Some(true));
    assert_eq!(s_gated[1].fork_term, Some(false));
    for ((name, a), (_, b)) in w_on.iter().zip(&w_zero) {
        let actor = name.starts_with("actor.") || name.starts_with("target.actor.");
        assert_eq!(actor, a != b, "{name}: moved {}", a != b);
    }
}

/// FORK's models fit a fixed batch: the dynamics loss falls below TD3-FORK's threshold
/// (switching the term on), the reward loss falls, padding is ignored, the bounds are the
/// batch's extreme observation values; an update reports the loss, and whether the term was
/// used only on the actor's turn.
#[test]
fn fork_models_fit_a_batch_and_switch_the_term_on() {
    let cfg = RdpgConfig {
        fork: Some(ForkConfig {
            threshold: 0.02,
            model_hidden: vec![64, 64],
            reward_hidden: vec![32, 32],
            lr: 3e-3,
            ..ForkConfig::default()
        }),
        ..fork_cfg()
    };
    let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 5).unwrap();
    let mut b = batch(&cfg, 8, 0.5, 4);
    poison_padding(&mut b);
    let p = agent.prepare(&b);
    let f = agent.fork.as_mut().unwrap();
    let first = f.train(&p);
    assert!(!first.use_term, "loss {} at init", first.dynamics_loss);
    // The bounds: extreme values over the real steps' observations and their successors.
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    let t = b.scan + b.opt;
    for i in 0..b.n {
        for j in 0..=b.opt_len[i] {
            for k in 0..OBS {
                let x = f64::from(b.obs[(i * (t + 1) + b.scan + j) * OBS + k]);
                lo = lo.min(x);
                hi = hi.max(x);
            }
        }
    }
    assert_eq!(f.bounds, (lo, hi));
    let reward_loss = |f: &super::fork::ForkModels| {
        let (n, l) = (p.n, p.l);
        let obs = p.obs_win.narrow(1, 0, l).reshape([n * l, OBS as i64]);
        let next = p.obs_win.narrow(1, 1, l).reshape([n * l, OBS as i64]);
        let act = p.act_win.reshape([n * l, ACT as i64]);
        let e = (f.reward(&obs, &next, &act) - p.rew.reshape([n * l])) * p.mask.reshape([n * l]);
        tch::no_grad(|| (&e * &e).sum(Kind::Float).double_value(&[]))
    };
    let r0 = reward_loss(f);
    let steps = (0..3000).position(|_| f.train(&p).use_term);
    assert!(steps.is_some(), "the dynamics loss never fell below 0.02");
    assert!(reward_loss(f) < 0.1 * r0, "{} vs {r0}", reward_loss(f));

    let s1 = agent.update(&b).unwrap();
    let s2 = agent.update(&b).unwrap();
    assert!(s1.model_loss.is_some_and(|x| x < 0.02), "{s1:?}");
    assert_eq!((s1.fork_term, s2.fork_term), (None, Some(true)));
    let plain = RdpgAgent::new(tiny(), OBS, ACT, 5)
        .unwrap()
        .update(&batch(&tiny(), 4, 0.5, 1))
        .unwrap();
    assert_eq!((plain.model_loss, plain.fork_term), (None, None));
}

/// The critic runs only over the steps its loss trains (the first `u` of each window), in
/// f32, for the feed-forward critic with n-step returns (`l = 3, u = 1`, the Hardcore TD3
/// recipes) and a recurrent one with `u < l`: its values and TD loss equal those of the whole
/// window's run (`l` steps, zero weight past `u`) bit for bit, and every critic's gradient to
/// f32 rounding. (Not bit for bit: a weight's gradient sums over the rows, `N u` here against
/// `N l` with zero rows there, which the matrix product blocks differently.)
#[test]
fn critic_on_trained_steps_equals_the_whole_window() {
    use super::profile::Clock;
    use super::update::critic_window;
    let ff = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![16] },
        recurrent: false,
        critic_action_fc: 0,
        actor_hidden: 16,
        critic_hidden: 16,
        opt_len: 3,
        update_len: 1,
        scan_len: 0,
        twin_critic: true,
        tau: 0.05,
        batch_size: 64,
        ..tiny()
    };
    let rec = RdpgConfig {
        opt_len: 4,
        update_len: 2,
        twin_critic: true,
        tau: 0.05,
        ..tiny()
    };
    for cfg in [ff, rec] {
        let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 17).unwrap();
        let b = batch(&cfg, cfg.batch_size, 0.5, 33);
        let p = agent.prepare(&b);
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (q_sa, y, _) = agent.critic_objective(&p, &sc, &mut Clock::new(false));
        assert_eq!(q_sa[0].size(), [b.n as i64, cfg.update_len as i64]);
        let grads = |agent: &RdpgAgent| -> Vec<Vec<f64>> {
            agent
                .critic_vs
                .iter()
                .flat_map(sorted_vars)
                .map(|(_, v)| to_vec64(&v.grad()))
                .collect()
        };
        let sum = |qs: &[Tensor]| {
            qs.iter()
                .map(|q| critic_loss_from(&p, q, &y))
                .reduce(|a, b| a + b)
                .unwrap()
        };
        agent.critic_opt.zero_grad();
        let loss = sum(&q_sa);
        loss.backward();
        let (loss, g) = (loss.double_value(&[]), grads(&agent));
        let whole: Vec<Tensor> = agent
            .critics
            .iter()
            .zip(&sc.critics)
            .map(|(c, h)| critic_window(c, &p, h, None)) // [N, l]
            .collect();
        agent.critic_opt.zero_grad();
        let loss_ref = sum(&whole);
        loss_ref.backward();
        let u = cfg.update_len as i64;
        assert!(whole[0].narrow(1, 0, u).equal(&q_sa[0]));
        assert_eq!(
            loss,
            loss_ref.double_value(&[]),
            "recurrent {}",
            cfg.recurrent
        );
        for (k, (a, b)) in g.iter().zip(grads(&agent)).enumerate() {
            let scale = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let worst = a
                .iter()
                .zip(&b)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
            assert!(
                worst <= 1e-6 * scale,
                "recurrent {}: parameter {k}: {worst:e} off at scale {scale:e}",
                cfg.recurrent
            );
        }
    }
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

/// Window-of-k acting: each action is `mu(o_t)` after the previous `k - 1` observations from
/// a zero state, whatever came before; a reset empties the window, and the carried history
/// round-trips through `to_vec` / `restore_env`.
#[test]
fn window_agents_act_on_their_last_k_observations() {
    let k = 3;
    let agent = RdpgAgent::new_with_kind(window_cfg(k), OBS, ACT, 2, Kind::Double).unwrap();
    let mut rng = NpRng::from_seed(5);
    let obs: Vec<f32> = (0..8 * OBS).map(|_| rng.standard_normal() as f32).collect();
    let row = |t: usize| &obs[t * OBS..(t + 1) * OBS];
    let reference = |first: usize, t: usize| {
        let o = Tensor::from_slice(&obs[first * OBS..(t + 1) * OBS])
            .view([1, (t + 1 - first) as i64, OBS as i64])
            .to_kind(Kind::Double);
        let h0 = agent.actor.core.zero_state(1, Kind::Double, Device::Cpu);
        let (mu, _) = tch::no_grad(|| agent.actor.forward_seq(&o, &h0));
        to_vec64(&mu.select(1, (t - first) as i64))
    };
    let mut st = agent.initial_state(1);
    assert_eq!(st.carried_len(), 1 + (k - 1) * OBS);
    for t in 0..6 {
        let a: Vec<f64> = agent
            .act(row(t), &mut st)
            .unwrap()
            .iter()
            .map(|&x| f64::from(x))
            .collect();
        assert_close(
            &a,
            &reference(t.saturating_sub(k - 1), t),
            1e-6,
            "window action",
        );
    }
    let saved = st.to_vec();
    let mut back = agent.initial_state(1);
    back.restore_env(0, &saved).unwrap();
    assert_eq!(
        agent.act(row(6), &mut st).unwrap(),
        agent.act(row(6), &mut back).unwrap()
    );
    assert!(back.restore_env(0, &saved[1..]).is_err());
    let mut bad = saved.clone();
    bad[0] = k as f32; // more real steps than the window holds
    assert!(back.restore_env(0, &bad).is_err());
    st.reset_env(0);
    let a: Vec<f64> = agent
        .act(row(7), &mut st)
        .unwrap()
        .iter()
        .map(|&x| f64::from(x))
        .collect();
    assert_close(&a, &reference(7, 7), 1e-6, "after a reset");
}

/// Window-of-k bootstrap: the target actor and critic re-encode the `k - 1` steps before each
/// window's tail from a zero state (fewer near an episode start, the padding never entering),
/// whatever the window's length, as the actor does when it acts at the tail.
#[test]
fn window_tail_reencodes_the_steps_before_the_tail_from_zero() {
    let k = 4;
    let cfg = window_cfg(k);
    let agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 9, Kind::Double).unwrap();
    let mut b = batch(&cfg, 16, 0.7, 4);
    poison_padding(&mut b);
    assert!(b.opt_len.iter().any(|&x| x < cfg.opt_len));
    assert!(b.scan_len.iter().any(|&x| x < cfg.scan_len));
    let p = agent.prepare(&b);
    let t = agent.targets.as_ref().unwrap();
    let unused = t
        .actor
        .core
        .zero_state(b.n as i64, Kind::Double, Device::Cpu);
    let a_tail = tch::no_grad(|| tail_action(&t.actor, &p, &unused));
    let unused_c = t.critics[0]
        .core
        .zero_state(b.n as i64, Kind::Double, Device::Cpu);
    let q_tail = tch::no_grad(|| target_q(&t.critics[0], &p, &unused_c, &a_tail));
    let tt = b.scan + b.opt;
    for i in 0..b.n {
        let tail = b.scan + b.opt_len[i];
        let first = (b.scan - b.scan_len[i]).max(tail - (k - 1));
        let rows = (tail - first + 1) as i64;
        let o: Vec<f32> = (first..=tail)
            .flat_map(|j| b.obs[(i * (tt + 1) + j) * OBS..(i * (tt + 1) + j + 1) * OBS].to_vec())
            .collect();
        let o = Tensor::from_slice(&o)
            .view([1, rows, OBS as i64])
            .to_kind(Kind::Double);
        let (mu, _) = tch::no_grad(|| {
            t.actor
                .forward_seq(&o, &t.actor.core.zero_state(1, Kind::Double, Device::Cpu))
        });
        let a_ref = mu.select(1, rows - 1);
        assert_close(
            &to_vec64(&a_tail.select(0, i as i64)),
            &to_vec64(&a_ref),
            1e-12,
            "a_tail",
        );
        let a: Vec<f32> = (first..tail)
            .flat_map(|j| b.actions[(i * tt + j) * ACT..(i * tt + j + 1) * ACT].to_vec())
            .collect();
        let a = Tensor::from_slice(&a)
            .view([1, rows - 1, ACT as i64])
            .to_kind(Kind::Double);
        let a = Tensor::cat(&[a, a_ref.unsqueeze(1)], 1);
        let c = &t.critics[0];
        let (q, _) = tch::no_grad(|| {
            c.forward_seq(&o, &a, &c.core.zero_state(1, Kind::Double, Device::Cpu))
        });
        assert_close(
            &[to_vec64(&q_tail)[i]],
            &[to_vec64(&q)[rows as usize - 1]],
            1e-10,
            "q_tail",
        );
    }
    // The actor trains on the first step only, where its state is the acting one.
    let w = to_vec64(&p.actor_w);
    for i in 0..b.n {
        for j in 0..cfg.opt_len {
            assert_eq!(w[i * cfg.opt_len + j], f64::from(u8::from(j == 0)));
        }
    }
    // And the whole update runs, with finite statistics.
    let mut agent = agent;
    let stats = agent.update(&b).unwrap();
    assert!(stats.critic_loss.is_finite() && stats.q_mean.is_finite());
}

/// `act_window` refuses the settings under which training would not see what acting sees.
#[test]
fn window_configs_are_checked() {
    assert!(window_cfg(3).validate().is_ok());
    for bad in [
        RdpgConfig {
            scan_len: 3,
            ..window_cfg(3)
        },
        RdpgConfig {
            update_len: 2,
            ..window_cfg(3)
        },
        RdpgConfig {
            tau: 0.0,
            ..window_cfg(3)
        },
        RdpgConfig {
            burn_in_from_stored_state: true,
            ..window_cfg(3)
        },
        RdpgConfig {
            act_window: 1,
            scan_len: 0,
            ..window_cfg(3)
        },
    ] {
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("act_window"), "{e}");
    }
}

/// `param_count` is the exact number of values the networks hold (targets included), for
/// every trunk and core kind: what a loader compares with a weights file before building.
#[test]
fn param_count_is_exact() {
    let ff = RdpgConfig {
        recurrent: false,
        opt_len: 1,
        update_len: 1,
        scan_len: 0,
        ..mlp(7)
    };
    for cfg in [
        tiny(),
        mlp(7),
        RdpgConfig {
            twin_critic: true,
            tau: 0.01,
            ..tiny()
        },
        RdpgConfig {
            critic_action_fc: 0,
            tau: 0.01,
            ..mlp(5)
        },
        ff,
    ] {
        let agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 0).unwrap();
        let mut vs = vec![&agent.actor_vs];
        vs.extend(&agent.critic_vs);
        if let Some(t) = &agent.targets {
            vs.push(&t.actor_vs);
            vs.extend(&t.critic_vs);
        }
        let real: i64 = vs
            .iter()
            .flat_map(|v| sorted_vars(v))
            .map(|(_, t)| t.numel() as i64)
            .sum();
        assert_eq!(cfg.param_count(OBS, ACT), real as f64, "{cfg:?}");
    }
}

/// An observation far outside training's (1e38, finite) that overflows the LSTM state is an
/// input error, and the state stays as it was: the next action is the one it would have been.
#[test]
fn an_overflowing_observation_leaves_the_state_as_it_was() {
    let wide = |cfg: RdpgConfig| RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![64] },
        actor_hidden: 32,
        ..cfg
    };
    for cfg in [wide(tiny()), wide(window_cfg(3))] {
        let agent = RdpgAgent::new(cfg, OBS, ACT, 4).unwrap();
        let normal: Vec<f32> = (0..OBS).map(|i| 0.1 * i as f32).collect();
        let (mut a, mut b) = (agent.initial_state(1), agent.initial_state(1));
        agent.act(&normal, &mut a).unwrap();
        agent.act(&normal, &mut b).unwrap();
        // Finite, but the trunk's sums overflow: inf - inf downstream.
        let huge = vec![f32::MAX; OBS];
        match agent.act(&huge, &mut a) {
            Err(crate::AgentError::Input(m)) => assert!(m.contains("overflows"), "{m}"),
            other => panic!("expected an input error, got {other:?}"),
        }
        assert_eq!(
            agent.act(&normal, &mut a).unwrap(),
            agent.act(&normal, &mut b).unwrap()
        );
    }
}
