//! `critic_preference`: the critics' values of the agent's own actions and of another
//! policy's against a step-by-step reference, a policy against itself, and refusals.

use super::bias::{agent, train_cfg};
use super::*;
use crate::common::policy::{to_env_action, DeterministicPolicy};
use crate::rdpg::preference::{critic_preference, PreferenceLine};
use crate::rdpg::trainer::RdpgPolicy;

/// The reference, written independently of the measurement: the episodes rolled out again
/// with both policies, each critic stepped one step at a time along the agent's actions with
/// its carried state, the other action valued from the same state (a window agent: run from
/// zero over the window ending at `t`, its last step with either action); per critic (and
/// `min`): steps, mean own value, mean other value, steps where the other is valued higher.
fn reference(
    agent: &RdpgAgent,
    other: &RdpgAgent,
    env_id: &str,
    episodes: u64,
    seed: u64,
) -> Vec<(usize, f64, f64, usize)> {
    let window = agent.config().act_window;
    let mut env = rdpg_envs::make(env_id).unwrap();
    let space = env.action_space().clone();
    let critics = agent.critics();
    let mut sums = vec![(0usize, 0.0, 0.0, 0usize); critics.len() + 1];
    let (mut policy, mut alt) = (RdpgPolicy::new(agent), RdpgPolicy::new(other));
    let row = |v: &[f32]| Tensor::from_slice(v).to_kind(Kind::Double).view([1, -1]);
    for ep in 0..episodes {
        let (mut o, _) = env.reset(Some(seed + ep)).unwrap();
        policy.begin_episode();
        alt.begin_episode();
        let mut steps: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = Vec::new();
        loop {
            let (a, b) = (policy.act(&o).unwrap(), alt.act(&o).unwrap());
            let s = env
                .step(&to_env_action(&a, &space.low, &space.high))
                .unwrap();
            steps.push((o.clone(), a, b));
            if s.done() {
                break;
            }
            o = s.obs;
        }
        let mut q = vec![vec![(0.0, 0.0); steps.len()]; critics.len()];
        for (i, critic) in critics.iter().enumerate() {
            let mut s = critic.core.zero_state(1, Kind::Double, Device::Cpu);
            for (t, (o, a, b)) in steps.iter().enumerate() {
                let from = if window == 0 {
                    t
                } else {
                    s = critic.core.zero_state(1, Kind::Double, Device::Cpu);
                    (t + 1).saturating_sub(window)
                };
                for (o, a, _) in &steps[from..t] {
                    s = critic.step(&row(o), &row(a), &s).1;
                }
                let (own, next) = critic.step(&row(o), &row(a), &s);
                let other = critic.step(&row(o), &row(b), &s).0;
                q[i][t] = (own.double_value(&[0]), other.double_value(&[0]));
                s = next;
            }
        }
        for t in 0..steps.len() {
            let min = |f: fn(&(f64, f64)) -> f64| {
                q.iter().map(|q| f(&q[t])).fold(f64::INFINITY, f64::min)
            };
            let mins = (min(|v| v.0), min(|v| v.1));
            for (line, (own, oth)) in q.iter().map(|q| q[t]).chain([mins]).enumerate() {
                let s = &mut sums[line];
                *s = (s.0 + 1, s.1 + own, s.2 + oth, s.3 + usize::from(oth > own));
            }
        }
    }
    sums
}

fn all_steps(lines: &[PreferenceLine]) -> Vec<&PreferenceLine> {
    lines.iter().filter(|l| l.steps_of == "all").collect()
}

/// On Pendulum (every episode ends at the time limit) the values of both policies' actions
/// match the step-by-step reference for a recurrent, a feed-forward and a window-of-3 agent
/// against another agent; the time-limit lines repeat the `all` ones.
#[test]
fn both_policies_actions_match_the_step_by_step_reference() {
    let feed_forward = RdpgConfig {
        gamma: 0.9,
        twin_critic: true,
        ..mlp(4).ddpg()
    };
    // The action at the critic's input (as the walker recipes): a tiny ReLU action branch
    // can be dead over both policies' actions and value them alike.
    for cfg in [
        agent(3, 1, 0).config().clone(),
        agent(3, 1, 3).config().clone(),
        feed_forward,
    ] {
        let cfg = RdpgConfig {
            critic_action_fc: 0,
            ..cfg
        };
        let a = RdpgAgent::new_with_kind(cfg.clone(), 3, 1, 3, Kind::Double).unwrap();
        let other = RdpgAgent::new_with_kind(cfg, 3, 1, 11, Kind::Double).unwrap();
        let mut alt = RdpgPolicy::new(&other);
        let p = critic_preference(&a, &mut alt, &train_cfg("Pendulum-v1"), 2, 40).unwrap();
        assert_eq!((p.episodes, p.truncated), (2, 2));
        assert!(p.action_rms > 0.0);
        let lines = all_steps(&p.lines);
        let names: Vec<_> = lines.iter().map(|l| l.critic.as_str()).collect();
        assert_eq!(names, ["critic 0", "critic 1", "min"]);
        let r = reference(&a, &other, "Pendulum-v1", 2, 40);
        for (l, &(n, own, oth, pref)) in lines.iter().zip(&r) {
            assert_eq!(l.steps, n);
            assert!((l.mean_own - own / n as f64).abs() < 1e-9, "{l:?}");
            assert!((l.mean_other - oth / n as f64).abs() < 1e-9, "{l:?}");
            assert_eq!(l.other_preferred, pref as f64 / n as f64, "{l:?}");
        }
        assert!(
            lines.iter().all(|l| l.mean_other != l.mean_own),
            "{lines:?}"
        );
        for l in p.lines.iter().filter(|l| l.steps_of == "time limit") {
            let all = lines.iter().find(|x| x.critic == l.critic).unwrap();
            assert_eq!((l.steps, l.mean_own), (all.steps, all.mean_own));
        }
        assert!(!p.lines.iter().any(|l| l.steps_of == "terminated"));
    }
}

/// Against itself the agent's critics value both actions alike: no step prefers the other.
#[test]
fn a_policy_against_itself_is_preferred_nowhere() {
    let a = agent(3, 1, 0);
    let mut same = RdpgPolicy::new(&a);
    let p = critic_preference(&a, &mut same, &train_cfg("Pendulum-v1"), 1, 0).unwrap();
    assert_eq!(p.action_rms, 0.0);
    for l in &p.lines {
        assert_eq!(
            (l.mean_own, l.other_preferred),
            (l.mean_other, 0.0),
            "{l:?}"
        );
    }
}

/// CueMemory's episodes terminate: their steps form the `terminated` set; zero episodes, a
/// soft actor-critic and an agent of other sizes are refused.
#[test]
fn terminated_episodes_and_refusals() {
    let a = agent(2, 1, 0);
    let other = RdpgAgent::new_with_kind(a.config().clone(), 2, 1, 5, Kind::Double).unwrap();
    let mut alt = RdpgPolicy::new(&other);
    let p = critic_preference(&a, &mut alt, &train_cfg("CueMemory-v0"), 3, 0).unwrap();
    assert_eq!(p.truncated, 0);
    assert!(p.lines.iter().any(|l| l.steps_of == "terminated"));
    assert!(!p.lines.iter().any(|l| l.steps_of == "time limit"));
    let err = |r: crate::error::Result<_>| r.map(|_| ()).unwrap_err().to_string();
    let cfg = train_cfg("Pendulum-v1");
    let b = agent(3, 1, 0);
    assert!(err(critic_preference(&b, &mut RdpgPolicy::new(&b), &cfg, 0, 0)).contains("1 to"));
    assert!(err(critic_preference(&a, &mut RdpgPolicy::new(&b), &cfg, 1, 0)).contains("sizes"));
    let sac = RdpgAgent::new_with_kind(
        RdpgConfig {
            sac: Some(crate::rdpg::config::SacConfig::default()),
            tau: 0.01,
            ..mlp(4)
        },
        3,
        1,
        3,
        Kind::Double,
    )
    .unwrap();
    assert!(err(critic_preference(
        &sac,
        &mut RdpgPolicy::new(&b),
        &cfg,
        1,
        0
    ))
    .contains("soft"));
}
