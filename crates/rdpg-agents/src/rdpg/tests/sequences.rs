//! The sequence machinery: scans over padded windows, the tail bootstrap's state, scan methods, burn-in from stored states, window-of-k agents.

use super::*;

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

/// A teacher episode's stored states (`episode_states`, computed when a teacher file loads) are
/// the states the student's actor carries before each step when it acts along the episode from
/// its start: what its own episodes store.
#[test]
fn teacher_episode_states_are_the_acting_states() {
    let agent = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 7, Kind::Double).unwrap();
    let (steps, n) = (9, 7);
    let mut rng = NpRng::from_seed(3);
    let obs: Vec<f32> = (0..steps * OBS)
        .map(|_| rng.normal(0.0, 1.0) as f32)
        .collect();
    let mut state = agent.initial_state(1);
    let mut acting = Vec::new();
    for t in 0..n {
        acting.extend(state.env_state(0));
        agent.act(&obs[t * OBS..(t + 1) * OBS], &mut state).unwrap();
    }
    let stored = agent.episode_states(&obs, n).unwrap();
    assert_eq!(
        stored.len(),
        n * 2 * 4,
        "[n, h and c of the actor's 4 units]"
    );
    let f64s = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
    assert_close(&f64s(&stored), &f64s(&acting), 1e-6, "states");
    assert!(stored.iter().skip(2 * 4).any(|&x| x != 0.0), "past step 0");
    assert!(
        agent.episode_states(&obs, steps + 1).is_err(),
        "more steps than observations"
    );
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

/// The memory probe: a stored-state agent limited to its last `k` observations acts as a
/// window-of-k agent would (re-encoded from zero, the current observation last); with `k`
/// past the episode's length it acts exactly as with its carried state, with `k = 1` from a
/// zero state at every step. A feed-forward agent and `k = 0` are refused, and a policy
/// limited by `limit_memory` acts so from its next episode.
#[test]
fn memory_limit_reencodes_the_last_k_observations() {
    use crate::common::policy::DeterministicPolicy;
    use crate::rdpg::trainer::RdpgPolicy;
    let agent = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 2, Kind::Double).unwrap();
    let mut rng = NpRng::from_seed(9);
    let obs: Vec<f32> = (0..6 * OBS).map(|_| rng.standard_normal() as f32).collect();
    let row = |t: usize| &obs[t * OBS..(t + 1) * OBS];
    let run = |st: &mut crate::rdpg::ActorState| -> Vec<Vec<f32>> {
        (0..6).map(|t| agent.act(row(t), st).unwrap()).collect()
    };
    let carried = run(&mut agent.initial_state(1));
    let long = run(&mut agent.initial_state_with_memory(1, 10).unwrap());
    let widen = |a: &[f32]| a.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
    for (a, b) in carried.iter().zip(&long) {
        assert_close(&widen(a), &widen(b), 1e-6, "k past the episode's length");
    }
    let k3 = run(&mut agent.initial_state_with_memory(1, 3).unwrap());
    let none = run(&mut agent.initial_state_with_memory(1, 1).unwrap());
    for t in 0..6_usize {
        let mut st = agent.initial_state(1);
        for u in t.saturating_sub(2)..t {
            agent.act(row(u), &mut st).unwrap();
        }
        let a = agent.act(row(t), &mut st).unwrap();
        assert_close(&widen(&a), &widen(&k3[t]), 1e-6, "k = 3");
        assert_eq!(
            agent.act(row(t), &mut agent.initial_state(1)).unwrap(),
            none[t],
            "k = 1 at step {t}"
        );
    }
    assert_ne!(
        carried[5], k3[5],
        "the probe changes what the agent remembers"
    );
    let mut policy = RdpgPolicy::new(&agent);
    policy.limit_memory(1).unwrap();
    policy.begin_episode();
    let probed: Vec<Vec<f32>> = (0..6).map(|t| policy.act(row(t)).unwrap()).collect();
    assert_eq!(probed, none);
    let e = agent
        .initial_state_with_memory(1, 0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("memory") && e.contains("k >= 1"), "{e}");
    let ff = RdpgAgent::new(
        RdpgConfig {
            recurrent: false,
            ..tiny()
        },
        OBS,
        ACT,
        2,
    )
    .unwrap();
    let e = RdpgPolicy::new(&ff)
        .limit_memory(4)
        .unwrap_err()
        .to_string();
    assert!(e.contains("feed-forward"), "{e}");
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
    let ta = agent.target_actor().unwrap();
    let unused = ta.core.zero_state(b.n as i64, Kind::Double, Device::Cpu);
    let a_tail = tch::no_grad(|| tail_action(ta, &p, &unused));
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
        let (mu, _) =
            tch::no_grad(|| ta.forward_seq(&o, &ta.core.zero_state(1, Kind::Double, Device::Cpu)));
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
    let no_window = RdpgConfig {
        window_grad: true,
        ..tiny()
    };
    let e = no_window.validate().unwrap_err().to_string();
    assert!(e.contains("window_grad") && e.contains("act_window"), "{e}");
}
