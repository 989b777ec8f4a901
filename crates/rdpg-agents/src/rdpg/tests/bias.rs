//! `estimation_bias`: each critic's values and the returns against a step-by-step reference,
//! a truncated episode's tail left out, a terminated one measured whole, and what it cannot
//! measure refused.

use super::*;
use crate::common::config::TrainConfig;
use crate::common::policy::{to_env_action, DeterministicPolicy};
use crate::rdpg::bias::{estimation_bias, truncated_tail, CriticBias};
use crate::rdpg::config::SacConfig;
use crate::rdpg::trainer::RdpgPolicy;

/// A tiny MLP-trunk agent for `obs`/`act` sizes, twin critics, discount 0.9, in f64.
pub(super) fn agent(obs: usize, act: usize, window: usize) -> RdpgAgent {
    let base = match window {
        0 => mlp(4),
        k => RdpgConfig {
            trunk: mlp(4).trunk,
            ..window_cfg(k)
        },
    };
    let cfg = RdpgConfig {
        gamma: 0.9,
        twin_critic: true,
        ..base
    };
    RdpgAgent::new_with_kind(cfg, obs, act, 3, Kind::Double).unwrap()
}

pub(super) fn train_cfg(env: &str) -> TrainConfig {
    TrainConfig {
        env: env.into(),
        ..Default::default()
    }
}

/// The reference, written independently of the measurement: the episodes rolled out again,
/// each critic stepped one step at a time with its carried state (a window agent: run from
/// zero over the window ending at `t`), the returns summed forwards; per critic (and `min`),
/// the mean `Q`, mean `G` and mean bias over the measured steps.
fn reference(agent: &RdpgAgent, env_id: &str, episodes: u64, seed: u64) -> Vec<(f64, f64)> {
    let gamma = agent.config().gamma;
    let window = agent.config().act_window;
    let mut env = rdpg_envs::make(env_id).unwrap();
    let space = env.action_space().clone();
    let lines = agent.critics().len() + 1;
    let mut sums = vec![(0.0, 0.0, 0usize); lines];
    let mut policy = RdpgPolicy::new(agent);
    for ep in 0..episodes {
        let (mut o, _) = env.reset(Some(seed + ep)).unwrap();
        policy.begin_episode();
        let mut steps: Vec<(Vec<f32>, Vec<f32>, f64)> = Vec::new();
        let terminated = loop {
            let a = policy.act(&o).unwrap();
            let s = env
                .step(&to_env_action(&a, &space.low, &space.high))
                .unwrap();
            steps.push((o.clone(), a, s.reward));
            if s.done() {
                break s.terminated;
            }
            o = s.obs;
        };
        let n = steps.len();
        let measured = if terminated {
            n
        } else {
            n.saturating_sub(truncated_tail(gamma))
        };
        let row = |v: &[f32]| Tensor::from_slice(v).to_kind(Kind::Double).view([1, -1]);
        let mut q = vec![vec![0.0; n]; agent.critics().len()];
        for (i, critic) in agent.critics().iter().enumerate() {
            let mut s = critic.core.zero_state(1, Kind::Double, Device::Cpu);
            for t in 0..n {
                if window == 0 {
                    let (v, next) = critic.step(&row(&steps[t].0), &row(&steps[t].1), &s);
                    q[i][t] = v.double_value(&[0]);
                    s = next;
                } else {
                    let from = (t + 1).saturating_sub(window);
                    let mut w = critic.core.zero_state(1, Kind::Double, Device::Cpu);
                    let mut v = Tensor::zeros([1], (Kind::Double, Device::Cpu));
                    for (o, a, _) in &steps[from..=t] {
                        (v, w) = critic.step(&row(o), &row(a), &w);
                    }
                    q[i][t] = v.double_value(&[0]);
                }
            }
        }
        for t in 0..measured {
            let g: f64 = (t..n)
                .map(|j| gamma.powi((j - t) as i32) * steps[j].2)
                .sum();
            let min = q.iter().map(|q| q[t]).fold(f64::INFINITY, f64::min);
            for (line, v) in q.iter().map(|q| q[t]).chain([min]).enumerate() {
                sums[line].0 += v;
                sums[line].1 += g;
                sums[line].2 += 1;
            }
        }
    }
    sums.into_iter()
        .map(|(q, g, m)| (q / m as f64, g / m as f64))
        .collect()
}

fn assert_matches(lines: &[CriticBias], reference: &[(f64, f64)]) {
    assert_eq!(
        lines.iter().map(|c| c.critic.as_str()).collect::<Vec<_>>(),
        ["critic 0", "critic 1", "min"]
    );
    for (c, &(q, g)) in lines.iter().zip(reference) {
        assert!((c.mean_q - q).abs() < 1e-9, "{c:?} against Q {q}");
        assert!((c.mean_return - g).abs() < 1e-9, "{c:?} against G {g}");
        assert!((c.mean_bias - (q - g)).abs() < 1e-9);
        assert!(c.rmse >= c.mean_bias.abs() && c.episode_std > 0.0);
    }
}

/// Pendulum's episodes end at the time limit (200 steps): with gamma 0.9 the last 44 of each
/// are left out; the critics' values (recurrent, feed-forward, window of 3) and the returns
/// match the step-by-step reference.
#[test]
fn truncated_episodes_match_the_step_by_step_reference() {
    assert_eq!(truncated_tail(0.9), 44); // 0.9^43 > 0.01 >= 0.9^44
    assert_eq!(truncated_tail(0.99), 459);
    for (name, agent) in [
        ("recurrent", agent(3, 1, 0)),
        ("window of 3", agent(3, 1, 3)),
        ("feed-forward", {
            let cfg = RdpgConfig {
                gamma: 0.9,
                twin_critic: true,
                ..mlp(4).ddpg()
            };
            RdpgAgent::new_with_kind(cfg, 3, 1, 3, Kind::Double).unwrap()
        }),
    ] {
        let b = estimation_bias(&agent, &train_cfg("Pendulum-v1"), 3, 50).unwrap();
        assert_eq!(b.truncated_tail, 44, "{name}");
        assert_eq!(b.episodes.len(), 3);
        for (k, e) in b.episodes.iter().enumerate() {
            assert_eq!((e.seed, e.steps, e.terminated), (50 + k as u64, 200, false));
            assert_eq!(e.measured, 156);
        }
        assert_eq!(b.steps_measured, 3 * 156);
        assert_matches(&b.critics, &reference(&agent, "Pendulum-v1", 3, 50));
    }
}

/// A terminated episode is measured to its last step (CueMemory: 6 steps, reward only at the
/// query); every episode truncated within its tail measures nothing and says so.
#[test]
fn terminated_episodes_are_measured_whole_and_nothing_measured_is_refused() {
    let a = agent(2, 1, 0);
    let b = estimation_bias(&a, &train_cfg("CueMemory-v0"), 4, 7).unwrap();
    assert!(b.episodes.iter().all(|e| e.terminated && e.measured == 6));
    assert_eq!(b.steps_measured, 24);
    assert_matches(&b.critics, &reference(&a, "CueMemory-v0", 4, 7));

    let long = RdpgAgent::new_with_kind(
        RdpgConfig {
            gamma: 0.999,
            ..mlp(4)
        },
        3,
        1,
        3,
        Kind::Double,
    )
    .unwrap();
    let err = estimation_bias(&long, &train_cfg("Pendulum-v1"), 2, 0)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no step measured"), "{err}");
}

/// Soft actor-critics, 0 episodes and an env of other sizes are refused with a reason.
#[test]
fn what_cannot_be_measured_is_refused() {
    let sac = RdpgAgent::new_with_kind(
        RdpgConfig {
            sac: Some(SacConfig::default()),
            tau: 0.01,
            ..mlp(4)
        },
        3,
        1,
        3,
        Kind::Double,
    )
    .unwrap();
    let cases = [
        (
            estimation_bias(&sac, &train_cfg("Pendulum-v1"), 1, 0),
            "entropy-regularised",
        ),
        (
            estimation_bias(&agent(3, 1, 0), &train_cfg("Pendulum-v1"), 0, 0),
            "1 to 100000 episodes",
        ),
        (
            estimation_bias(&agent(3, 1, 0), &train_cfg("CueMemory-v0"), 1, 0),
            "sizes 2/1, the agent's are 3/1",
        ),
    ];
    for (r, want) in cases {
        let err = r.unwrap_err().to_string();
        assert!(err.contains(want), "{err}");
    }
}
