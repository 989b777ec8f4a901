//! TD targets, critic weights and losses, bootstraps (twin, smoothed, feed-forward) and the soft update, against hand computations and `rdpg_core::targets`.

use super::*;

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
    // per_step: 1/l on every real step, the short window's step no heavier than the others.
    let per_step = RdpgAgent::new_with_kind(
        RdpgConfig {
            actor_weights: ActorWeights::PerStep,
            ..agent.config().clone()
        },
        2,
        1,
        0,
        Kind::Double,
    )
    .unwrap();
    assert_close(
        &to_vec64(&per_step.prepare(&b).actor_w),
        &[1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0, 0.0, 0.0],
        1e-12,
        "v per step",
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
            crate::rdpg::update::tail_q(
                &p,
                &crate::rdpg::update::critic_window(
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
        critic_target: crate::rdpg::config::CriticTarget::PerStepTd0,
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
            let (mu, _) = tch::no_grad(|| agent.target_actor().unwrap().forward_seq(&obs, &z(4)));
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
        let ta = agent.target_actor().unwrap();
        let none = ta.core.zero_state(1, Kind::Double, Device::Cpu);
        let a_ref = tch::no_grad(|| ta.step(&o, &none).0);
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

/// The critic runs only over the steps its loss trains (the first `u` of each window), in
/// f32, for the feed-forward critic with n-step returns (`l = 3, u = 1`, the Hardcore TD3
/// recipes) and a recurrent one with `u < l`: its values and TD loss equal those of the whole
/// window's run (`l` steps, zero weight past `u`) bit for bit, and every critic's gradient to
/// f32 rounding. (Not bit for bit: a weight's gradient sums over the rows, `N u` here against
/// `N l` with zero rows there, which the matrix product blocks differently.)
#[test]
fn critic_on_trained_steps_equals_the_whole_window() {
    use crate::rdpg::profile::Clock;
    use crate::rdpg::update::critic_window;
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
