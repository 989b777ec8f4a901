//! The agent as a whole: determinism, checkpoints, acting, batch checks, parameter noise, sizes and bad input.

use super::*;

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
        with_heads(tiny(), true),
        RdpgConfig {
            critic_action_fc: 0,
            tau: 0.01,
            ..with_heads(mlp(5), true)
        },
        with_heads(ff.clone(), true),
        with_action_after_core(tiny(), true),
        with_action_after_core(with_heads(ff.clone(), true), true),
        RdpgConfig {
            tau: 0.01,
            ..with_action_after_core(with_heads(mlp(5), true), true)
        },
        ff,
    ] {
        let agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 0).unwrap();
        let mut vs = vec![&agent.actor_vs];
        vs.extend(&agent.critic_vs);
        if let Some(t) = &agent.targets {
            vs.extend(t.actor.iter().map(|(vs, _)| vs));
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
