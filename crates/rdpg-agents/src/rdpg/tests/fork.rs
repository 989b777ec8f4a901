//! FORK's forward-looking actor term and its models.

use super::*;

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
    assert!(s_on.iter().all(|s| s.extra.contains_key("model_loss")));
    assert_eq!(s_on[1].extra.get("fork_share"), Some(&1.0));
    assert_eq!(s_gated[1].extra.get("fork_share"), Some(&0.0));
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
    let reward_loss = |f: &crate::rdpg::fork::ForkModels| {
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
    assert!(s1.extra["model_loss"] < 0.02, "{s1:?}");
    assert_eq!(
        (s1.extra.get("fork_share"), s2.extra.get("fork_share")),
        (None, Some(&1.0))
    );
    let plain = RdpgAgent::new(tiny(), OBS, ACT, 5)
        .unwrap()
        .update(&batch(&tiny(), 4, 0.5, 1))
        .unwrap();
    assert!(plain.extra.is_empty(), "{plain:?}");
}
