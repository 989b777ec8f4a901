//! Soft actor-critic: one update against the same update written in PyTorch
//! (`scripts/reference/sac_update.py`), the squashed Gaussian's log-probability, the soft
//! tail-step target against `rdpg_core::targets`, the temperature, acting, checkpoints and the
//! options SAC refuses.

use std::collections::HashMap;

use serde_json::Value;

use super::*;
use crate::rdpg::config::{SacConfig, TqcConfig};
use crate::rdpg::sac::{soft_actor_loss, squashed_sample};
use crate::rdpg::update::{critic_states, target_atoms};

const FIXTURE: &str = include_str!("../../../../../tests/fixtures/sac_update.json");

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// Every variable of the agent (targets prefixed `target.`), by name, to write into.
fn vars_by_name(agent: &RdpgAgent) -> HashMap<String, Tensor> {
    let mut out = HashMap::new();
    let mut add = |vs: &VarStore, prefix: &str| {
        for (n, t) in sorted_vars(vs) {
            out.insert(format!("{prefix}{n}"), t);
        }
    };
    add(&agent.actor_vs, "");
    for vs in &agent.critic_vs {
        add(vs, "");
    }
    for vs in &agent.targets.as_ref().unwrap().critic_vs {
        add(vs, "target.");
    }
    add(&agent.sac.as_ref().unwrap().vs, "");
    out
}

/// The PyTorch reference's update, reproduced: every weight after it (the actor, both critics,
/// their targets, `log_alpha`), the losses, the temperature and the entropy, for a
/// feed-forward agent, an LSTM agent (scan part, short windows, a terminated tail) and an
/// LSTM agent with BPTT in the actor loss.
#[test]
fn one_update_matches_pytorch() {
    let fixture: Value = serde_json::from_str(FIXTURE).unwrap();
    for case in fixture["cases"].as_array().unwrap() {
        let name = case["name"].as_str().unwrap();
        let cfg: RdpgConfig = serde_json::from_value(case["config"].clone()).unwrap();
        let (obs, act) = (
            case["obs_dim"].as_u64().unwrap() as usize,
            case["act_dim"].as_u64().unwrap() as usize,
        );
        let mut agent = RdpgAgent::new_with_kind(cfg, obs, act, 0, Kind::Double).unwrap();
        let vars = vars_by_name(&agent);
        let before = case["before"].as_object().unwrap();
        assert_eq!(vars.len(), before.len(), "{name}: variables");
        for (n, mut var) in vars {
            let v = Tensor::from_slice(&f64s(&before[&n])).view(var.size().as_slice());
            tch::no_grad(|| var.copy_(&v));
        }
        agent.rng = NpRng::from_seed(case["noise_seed"].as_u64().unwrap());
        let batch: SequenceBatch = serde_json::from_value(case["batch"].clone()).unwrap();
        let stats = agent.update(&batch).unwrap();

        let after = case["after"].as_object().unwrap();
        let weights: HashMap<String, Vec<f64>> = agent.weights().into_iter().collect();
        assert_eq!(weights.len(), after.len(), "{name}: variables after");
        for (n, want) in after {
            assert_close(&weights[n], &f64s(want), 1e-10, &format!("{name}: {n}"));
        }
        for (key, got) in [
            ("critic_loss", stats.critic_loss),
            ("actor_loss", stats.actor_loss.unwrap()),
            ("alpha", stats.extra["alpha"]),
            ("entropy", stats.extra["entropy"]),
        ] {
            let want = case[key].as_f64().unwrap();
            assert_close(&[got], &[want], 1e-10, &format!("{name}: {key}"));
        }
    }
}

/// `log pi(a)` of the squashed Gaussian against the density of `tanh(u)` by the change of
/// variables written out, in the saturated region too (`|u|` up to 30, where
/// `log(1 - tanh(u)^2)` computed naively is `-inf`).
#[test]
fn the_log_probability_is_the_squashed_gaussians() {
    let m = Tensor::from_slice(&[0.3, -1.2, 4.0, -2.0, 25.0, 0.0]).view([3, 2]);
    let log_s = Tensor::from_slice(&[-0.5, 0.2, 1.0, -3.0, 0.0, -20.0]).view([3, 2]);
    let eps = Tensor::from_slice(&[1.1, -0.4, 2.0, 0.7, 5.0, 0.3]).view([3, 2]);
    let (a, logp) = squashed_sample(&m, &log_s, &eps);
    let (m, log_s, eps) = (to_vec64(&m), to_vec64(&log_s), to_vec64(&eps));
    let mut want = [0.0f64; 3];
    for k in 0..6 {
        let u = m[k] + log_s[k].exp() * eps[k];
        let gauss = -0.5 * eps[k] * eps[k] - log_s[k] - 0.5 * (2.0 * std::f64::consts::PI).ln();
        // d tanh(u) / du = 1 / cosh(u)^2: log = -2 log cosh(u), with log cosh(u) =
        // |u| + log((1 + exp(-2|u|)) / 2).
        let log_cosh = u.abs() + ((1.0 + (-2.0 * u.abs()).exp()) / 2.0).ln();
        want[k / 2] += gauss + 2.0 * log_cosh;
        assert!((to_vec64(&a)[k] - u.tanh()).abs() < 1e-15);
    }
    assert_close(&to_vec64(&logp), &want, 1e-12, "log pi");
}

fn sac_cfg(recurrent: bool) -> RdpgConfig {
    let base = mlp(6);
    let base = if recurrent { base } else { base.ddpg() };
    RdpgConfig {
        tau: 0.01,
        twin_critic: true,
        sac: Some(SacConfig::default()),
        ..base
    }
}

/// The soft bootstrap: with `alpha` fixed, the critic loss of an update equals the one built
/// from `rdpg_core::targets` on the window's rewards with `min Q'(o_tail, a_tail) - alpha log
/// pi(a_tail)` at the tail (SAC), or with each of TQC's kept atoms there and the quantile
/// Huber loss written out, all computed from the agent before the update with the same noise.
#[test]
fn the_soft_tail_target_is_the_interpolated_td_with_the_entropy_at_the_bootstrap() {
    let tqc = TqcConfig {
        quantiles: 3,
        drop_per_critic: 1,
    };
    for (recurrent, tqc) in [(true, None), (false, None), (true, Some(tqc))] {
        let cfg = RdpgConfig {
            sac: Some(SacConfig {
                init_alpha: 0.7,
                learn_alpha: false,
                tqc: tqc.clone(),
                ..Default::default()
            }),
            ..sac_cfg(recurrent)
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 4, Kind::Double).unwrap();
        let b = batch(&cfg, 5, 0.5, 9);
        let p = agent.prepare(&b);
        agent.rng = NpRng::from_seed(21);
        // The tail sample, from the same draws the update makes first.
        let mut rng = NpRng::from_seed(21);
        let eps: Vec<f64> = (0..p.n as usize * ACT)
            .map(|_| rng.standard_normal())
            .collect();
        let eps = Tensor::from_slice(&eps).view([p.n, ACT as i64]);
        let sc = agent.scan_all(&p);
        let (x, y) = tch::no_grad(|| {
            let (_, x, y) = agent.actor_along_window(&p, &sc);
            (x, y)
        });
        let (m, log_s) = agent.actor.gaussian(&x, &y);
        let (a_tail, logp) = squashed_sample(&m, &log_s, &eps);
        let logp = to_vec64(&logp);
        let t = agent.targets.as_ref().unwrap();
        // Each target critic's atoms at the tail, per window: [critic][n][M].
        let atoms: Vec<Vec<Vec<f64>>> = t
            .critics
            .iter()
            .zip(&sc.target_critics)
            .map(|(c, h)| {
                let z = target_atoms(c, &p, h, &a_tail);
                let m = z.size()[1] as usize;
                to_vec64(&z).chunks(m).map(<[f64]>::to_vec).collect()
            })
            .collect();
        // The bootstrap values per window: SAC's one (min of the two means), TQC's K kept
        // atoms (pooled, sorted, the largest d per critic dropped); minus alpha log pi.
        let tails: Vec<Vec<f64>> = (0..b.n)
            .map(|k| {
                let mean = |z: &[f64]| z.iter().sum::<f64>() / z.len() as f64;
                let kept = match &tqc {
                    None => vec![mean(&atoms[0][k]).min(mean(&atoms[1][k]))],
                    Some(t) => {
                        let mut pooled: Vec<f64> =
                            atoms.iter().flat_map(|a| a[k].clone()).collect();
                        pooled.sort_by(f64::total_cmp);
                        pooled.truncate(pooled.len() - 2 * t.drop_per_critic);
                        pooled
                    }
                };
                kept.iter().map(|z| z - 0.7 * logp[k]).collect()
            })
            .collect();
        // The reference: per window and kept atom, rdpg_core::targets on its rewards and that
        // tail value; the squared error (SAC) or the quantile Huber loss (TQC).
        let (l, u) = (cfg.opt_len, cfg.update_len);
        let ys: Vec<Vec<f64>> = (0..tails[0].len())
            .map(|j| {
                let v: Vec<f64> = tails.iter().map(|t| t[j]).collect();
                rdpg_core::targets::batch_tail_bootstrap_targets(&b, cfg.gamma, &v)
                // [n, l]
            })
            .collect();
        let critic_z: Vec<Vec<f64>> = agent
            .critics
            .iter()
            .zip(&sc.critics)
            .map(|(c, h)| to_vec64(&crate::rdpg::tqc::trained_atoms(c, &p, h)))
            .collect();
        let m = cfg.critic_outputs();
        let w = rdpg_core::targets::interpolated_td_weights(u, cfg.lambda);
        let mut want = 0.0;
        for k in 0..b.n {
            for z in &critic_z {
                for i in 0..b.opt_len[k].min(u) {
                    let at = |q: usize| z[(k * u + i) * m + q];
                    let per_step = match &tqc {
                        None => (ys[0][k * l + i] - at(0)).powi(2),
                        Some(_) => {
                            let mut sum = 0.0;
                            for q in 0..m {
                                let tau = (2 * q + 1) as f64 / (2 * m) as f64;
                                for y in &ys {
                                    let d = y[k * l + i] - at(q);
                                    let huber = if d.abs() <= 1.0 {
                                        0.5 * d * d
                                    } else {
                                        d.abs() - 0.5
                                    };
                                    sum += (tau - f64::from(u8::from(d < 0.0))).abs() * huber;
                                }
                            }
                            sum / (m * ys.len()) as f64
                        }
                    };
                    want += w[i] * per_step / b.n as f64;
                }
            }
        }
        let stats = agent.update(&b).unwrap();
        assert_close(
            &[stats.critic_loss],
            &[want],
            1e-9,
            &format!("soft critic loss (tqc {})", tqc.is_some()),
        );
        assert_eq!(stats.extra["alpha"], 0.7);
    }
}

/// The temperature falls while the policy's entropy is above the target and rises while it
/// is below; with `learn_alpha = false` it stays.
#[test]
fn the_temperature_follows_the_entropy_target() {
    for (target, falls) in [(-10.0, true), (10.0, false)] {
        let cfg = RdpgConfig {
            sac: Some(SacConfig {
                target_entropy: Some(target),
                lr_alpha: 0.05,
                ..Default::default()
            }),
            ..sac_cfg(false)
        };
        let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 1).unwrap();
        let b = batch(&cfg, 8, 0.0, 2);
        for _ in 0..5 {
            agent.update(&b).unwrap();
        }
        let alpha = agent.sac.as_ref().unwrap().alpha();
        assert_eq!(alpha < 1.0, falls, "target {target}: alpha {alpha}");
    }
    let cfg = RdpgConfig {
        sac: Some(SacConfig {
            learn_alpha: false,
            init_alpha: 0.3,
            ..Default::default()
        }),
        ..sac_cfg(true)
    };
    let mut agent = RdpgAgent::new(cfg.clone(), OBS, ACT, 1).unwrap();
    agent.update(&batch(&cfg, 4, 0.3, 2)).unwrap();
    assert!((agent.sac.as_ref().unwrap().alpha() - 0.3).abs() < 1e-7);
}

/// Acting: the deterministic action is `tanh(m)`, a sample `tanh(m + s eps)` (so zero noise
/// gives the deterministic action), and both carry the recurrent state alike.
#[test]
fn acting_samples_and_evaluating_takes_the_mean() {
    let agent = RdpgAgent::new(sac_cfg(true), OBS, ACT, 3).unwrap();
    let obs: Vec<f32> = (0..2 * OBS).map(|i| (i as f32 * 0.37).sin()).collect();
    let (mut s1, mut s2, mut s3) = (
        agent.initial_state(2),
        agent.initial_state(2),
        agent.initial_state(2),
    );
    for _ in 0..3 {
        let det = agent.act(&obs, &mut s1).unwrap();
        let zero = agent.act_sampled(&obs, &mut s2, &[0.0; 2 * ACT]).unwrap();
        let noisy = agent.act_sampled(&obs, &mut s3, &[1.5; 2 * ACT]).unwrap();
        assert_eq!(det, zero);
        assert_ne!(det, noisy);
        assert!(noisy.iter().all(|a| a.abs() <= 1.0));
    }
    assert_eq!(s1.to_vec(), s3.to_vec());
    let err = agent
        .act_sampled(&obs, &mut s1, &[0.0; 3])
        .unwrap_err()
        .to_string();
    assert!(err.contains("noise values"), "{err}");
    let td3 = RdpgAgent::new(mlp(6), OBS, ACT, 3).unwrap();
    let err = td3
        .act_sampled(&obs, &mut td3.initial_state(2), &[0.0; 2 * ACT])
        .unwrap_err()
        .to_string();
    assert!(err.contains("sac"), "{err}");
}

/// A checkpoint holds `log_alpha` and its Adam moments (and no target actor): a loaded agent
/// continues bit-identically, and its parameter count is the config's; for an LSTM agent, a
/// window-of-k one (`act_window`, with and without `window_grad`) and one with TQC's critics.
#[test]
fn a_checkpoint_continues_identically() {
    let window = RdpgConfig {
        act_window: 3,
        scan_len: 2,
        update_len: 1,
        ..sac_cfg(true)
    };
    let window_grad = RdpgConfig {
        window_grad: true,
        ..window.clone()
    };
    let base = sac_cfg(true);
    let tqc = RdpgConfig {
        sac: Some(SacConfig {
            tqc: Some(TqcConfig {
                quantiles: 5,
                drop_per_critic: 2,
            }),
            ..base.sac.clone().unwrap()
        }),
        ..base
    };
    for cfg in [sac_cfg(true), window, window_grad, tqc] {
        checkpoint_round_trip(cfg);
    }
}

fn checkpoint_round_trip(cfg: RdpgConfig) {
    let b = batch(&cfg, 4, 0.3, 5);
    let mut a = RdpgAgent::new(cfg.clone(), OBS, ACT, 8).unwrap();
    a.update(&b).unwrap();
    let dir = std::env::temp_dir().join(format!("rdpg-agents-sac-{}", std::process::id()));
    a.save(&dir).unwrap();
    let mut c = RdpgAgent::load(&dir).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let names: Vec<String> = a.weights().into_iter().map(|(n, _)| n).collect();
    assert!(names.contains(&"log_alpha".to_string()));
    assert!(!names.iter().any(|n| n.starts_with("target.actor")));
    let count: usize = a.weights().iter().map(|(_, v)| v.len()).sum();
    assert_eq!(count as f64, cfg.param_count(OBS, ACT));
    for _ in 0..2 {
        a.update(&b).unwrap();
        c.update(&b).unwrap();
    }
    assert_eq!(a.weights(), c.weights());
}

/// RDPG's options that do not apply to SAC are refused by name, and TQC's impossible sizes.
#[test]
fn options_of_the_deterministic_learner_are_refused_by_name() {
    let sac = sac_cfg(false);
    for (cfg, field) in [
        (
            RdpgConfig {
                target_noise: Some(crate::rdpg::TargetNoise {
                    std: 0.2,
                    clip: 0.5,
                }),
                ..sac.clone()
            },
            "target_noise",
        ),
        (
            RdpgConfig {
                policy_delay: 2,
                ..sac.clone()
            },
            "policy_delay",
        ),
        (
            RdpgConfig {
                fork: Some(ForkConfig::default()),
                ..sac.clone()
            },
            "fork",
        ),
        (
            RdpgConfig {
                tau: 0.0,
                ..sac.clone()
            },
            "tau",
        ),
        (
            RdpgConfig {
                parallel_twins: true,
                ..sac.clone()
            },
            "parallel_twins",
        ),
        (
            RdpgConfig {
                sac: Some(SacConfig {
                    init_alpha: 0.0,
                    ..Default::default()
                }),
                ..sac.clone()
            },
            "sac.init_alpha",
        ),
        (
            RdpgConfig {
                sac: Some(SacConfig {
                    tqc: Some(TqcConfig {
                        quantiles: 3,
                        drop_per_critic: 3,
                    }),
                    ..Default::default()
                }),
                ..sac.clone()
            },
            "sac.tqc.drop_per_critic",
        ),
        (
            RdpgConfig {
                sac: Some(SacConfig {
                    tqc: Some(TqcConfig {
                        quantiles: 0,
                        drop_per_critic: 0,
                    }),
                    ..Default::default()
                }),
                ..sac.clone()
            },
            "sac.tqc.quantiles",
        ),
    ] {
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains(field), "{field}: {err}");
    }
}

/// The actor loss's gradient (through the reparameterised sample, the tanh correction and the
/// minimum over the twin critics, or TQC's mean over their atoms) against finite differences,
/// BPTT or not, the noise and the critics' states held fixed.
#[test]
fn the_actor_loss_gradient_matches_finite_differences() {
    for (bptt, tqc) in [(false, false), (true, false), (false, true)] {
        let base = sac_cfg(true);
        let cfg = RdpgConfig {
            actor_bptt: bptt,
            sac: Some(SacConfig {
                tqc: tqc.then_some(TqcConfig {
                    quantiles: 4,
                    drop_per_critic: 1,
                }),
                ..base.sac.clone().unwrap()
            }),
            ..base
        };
        let mut agent = RdpgAgent::new_with_kind(cfg.clone(), OBS, ACT, 31, Kind::Double).unwrap();
        let b = batch(&cfg, 4, 0.5, 12);
        let p = agent.prepare(&b);
        let sc = tch::no_grad(|| agent.scan_all(&p));
        let (states, _, _) = tch::no_grad(|| agent.actor_along_window(&p, &sc));
        let cs: Vec<(Tensor, Tensor)> = tch::no_grad(|| {
            agent
                .critics
                .iter()
                .zip(&sc.critics)
                .map(|(c, h)| critic_states(c, &p, h))
                .collect()
        });
        let mut rng = NpRng::from_seed(3);
        let eps: Vec<f64> = (0..(p.n * p.l) as usize * ACT)
            .map(|_| rng.standard_normal())
            .collect();
        let eps = Tensor::from_slice(&eps).view([p.n * p.l, ACT as i64]);
        let loss = |agent: &RdpgAgent| {
            let input = match &states {
                Some((h, c)) if !bptt => ActorInput::Detached { h, c },
                _ => ActorInput::Bptt { h0: sc.actor() },
            };
            soft_actor_loss(agent, &p, input, &cs, &eps, 0.4, tqc).0
        };
        agent.actor_opt.zero_grad();
        loss(&agent).backward();
        let f = || tch::no_grad(|| loss(&agent).double_value(&[]));
        check_grads(
            &agent.actor_vs,
            &f,
            &format!("SAC actor (bptt {bptt}, tqc {tqc})"),
        );
    }
}
