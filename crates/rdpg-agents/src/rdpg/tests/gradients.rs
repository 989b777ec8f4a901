//! Gradients (finite differences, BPTT or not, what the update holds constant), the order of Algorithm 1, TD3's policy delay and the parallel twins.

use super::*;

#[test]
fn critic_loss_gradient_matches_finite_differences() {
    for (recurrent, heads, after) in [
        (true, false, false),
        (false, false, false),
        (true, true, false),
        (false, true, false),
        (true, false, true),
        (false, true, true),
    ] {
        let cfg = RdpgConfig {
            recurrent,
            lambda: 0.7,
            update_len: 2,
            ..with_action_after_core(with_heads(tiny(), heads), after)
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
            &format!("critic (recurrent {recurrent}, heads {heads}, action after core {after})"),
        );
    }
}

#[test]
fn actor_loss_gradient_matches_finite_differences() {
    for (bptt, heads, after) in [
        (false, false, false),
        (true, false, false),
        (false, true, false),
        (true, true, false),
        (false, false, true),
        (true, true, true),
    ] {
        let cfg = RdpgConfig {
            actor_bptt: bptt,
            ..with_action_after_core(with_heads(tiny(), heads), after)
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
        check_grads(
            &agent.actor_vs,
            &f,
            &format!("actor (bptt {bptt}, heads {heads}, action after core {after})"),
        );
    }
}

/// `window_grad`: the critic and actor losses of a window-of-k agent back-propagate through
/// the window's `k - 1` history steps. The critic's gradient is the finite difference of its
/// loss with the history encoded inside it, and both losses have a gradient w.r.t. the history
/// observations; without `window_grad` the history is a constant: the finite differences
/// disagree and the history observations get no gradient.
#[test]
fn window_grad_back_propagates_through_the_history() {
    for window_grad in [true, false] {
        let cfg = RdpgConfig {
            window_grad,
            ..window_cfg(4)
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 23, Kind::Double).unwrap();
        let b = batch(&cfg, 5, 0.5, 10);
        let mut p = agent.prepare(&b);
        let y = tch::no_grad(|| {
            let sc = agent.scan_all(&p);
            let (_, a_tail) = agent.actor_window(&p, &sc);
            let q_tail = agent.target_tail_q(&p, &sc, &a_tail).unwrap();
            td_targets(&p, &q_tail)
        });
        let critic_loss_of = |agent: &RdpgAgent, p: &Prepared| {
            let sc = agent.scan_for(p, false);
            critic_loss_from(p, &trained_q(&agent.critics[0], p, &sc.critics[0]), &y)
        };
        agent.critic_opt.zero_grad();
        critic_loss_of(&agent, &p).backward();
        let f = || tch::no_grad(|| critic_loss_of(&agent, &p).double_value(&[]));
        let mismatch = grad_mismatch(&agent.critic_vs[0], &f);
        assert_eq!(mismatch.is_none(), window_grad, "{mismatch:?}");

        // The history observations as leaves: does each loss reach them?
        let critic_states = tch::no_grad(|| agent.updated_critic_states(&p));
        let history_grad = |p: &mut Prepared, loss: &dyn Fn(&Prepared) -> Tensor| {
            p.obs_scan = p.obs_scan.detach().set_requires_grad(true);
            loss(p).backward();
            let g = p.obs_scan.grad();
            g.defined() && g.abs().sum(Kind::Double).double_value(&[]) > 0.0
        };
        let actor_loss_of = |p: &Prepared| {
            let sc = agent.scan_for(p, true);
            let detached = agent
                .actor_states_detached()
                .then(|| tch::no_grad(|| actor_states(&agent.actor, p, sc.actor())));
            let input = match &detached {
                Some((h, c)) => ActorInput::Detached { h, c },
                None => ActorInput::Bptt { h0: sc.actor() },
            };
            actor_loss(&agent.actor, &agent.critics[0], p, input, &critic_states).0
        };
        assert_eq!(history_grad(&mut p, &actor_loss_of), window_grad, "actor");
        let critic = |p: &Prepared| critic_loss_of(&agent, p);
        assert_eq!(history_grad(&mut p, &critic), window_grad, "critic");
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

/// Gradient checks through the update's own code path: the autograd gradients of the critic
/// loss as `critic_objective` builds it (scan, window runs, bootstrap, targets) and of the
/// actor loss on the states it returns must equal finite differences of the same losses with
/// the targets, the scanned states and the carried actor states held fixed, as the estimator
/// (semi-gradient TD, actor without BPTT) defines them. A missing `no_grad`/`detach` on the
/// targets, the bootstrap, the scan or the actor's states makes autograd differentiate through
/// them and fails this test; so does gradient reaching the critic from the actor loss.
#[test]
fn update_path_gradients_hold_targets_scans_and_states_constant() {
    use crate::rdpg::config::CriticTarget;
    use crate::rdpg::profile::Clock;
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
                let q =
                    crate::rdpg::update::critic_window(&agent.critics[0], &p, &sc.critics[0], None);
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
    use crate::rdpg::profile::Clock;
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
        target_noise: Some(crate::rdpg::config::TargetNoise {
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
    // The history scans with gradient: critic 1's graph built on the second thread.
    let window_grad = RdpgConfig {
        window_grad: true,
        ..window.clone()
    };
    for cfg in [
        recurrent,
        feed_forward,
        deferred,
        fork_cfg(),
        window,
        window_grad,
    ] {
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
                        .flat_map(|t| t.actor.iter().map(|(vs, _)| vs).chain(&t.critic_vs)),
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
