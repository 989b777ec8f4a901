//! Which actions an agent's critics prefer along its own episodes: its actor's, or another
//! policy's. Separates an actor that does not find what its critic values (the critic rates
//! the other policy's actions higher) from a critic that does not value what the other
//! policy does (it rates them lower).
//!
//! The agent acts deterministically on episodes of its **training** environment, as in
//! [`super::bias`]; the other policy is shown the same observations (its own state carried
//! along them from each episode start) and its action is recorded, never taken. At each step
//! every critic values both actions from the same state: `Q_i(o_t, a_t | h^C_{t-1})` and
//! `Q_i(o_t, b_t | h^C_{t-1})`, with `h^C` carried along the actions the agent took (a
//! window-of-k agent: re-encoded from zero over the `k - 1` steps before `t`). Reported per
//! critic and for the twins' minimum, over all steps and separately over the steps of
//! episodes that ended at the time limit (on the walkers: an agent standing in front of an
//! obstacle) and of those that ended in a termination.

use serde::Serialize;
use tch::{Kind, Tensor};

use super::RdpgAgent;
use crate::common::config::TrainConfig;
use crate::common::policy::{to_env_action, DeterministicPolicy};
use crate::common::tensor::tensor_to_vec64;
use crate::error::{AgentError, Result};
use crate::rdpg::bias::{critic_states_before, measured_env, steps_tensor};
use crate::rdpg::trainer::RdpgPolicy;

/// One critic's preference over a set of steps.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct PreferenceLine {
    /// `critic 0`, `critic 1`, or `min` (the twins' minimum).
    pub critic: String,
    /// `all`, `time limit` (steps of truncated episodes) or `terminated`.
    pub steps_of: String,
    /// Steps in the set.
    pub steps: usize,
    /// Mean `Q(o_t, a_t)` of the agent's own actions.
    pub mean_own: f64,
    /// Mean `Q(o_t, b_t)` of the other policy's actions.
    pub mean_other: f64,
    /// Share of the steps where the other policy's action is valued higher.
    pub other_preferred: f64,
}

/// What [`critic_preference`] measured.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CriticPreference {
    /// Episodes run.
    pub episodes: usize,
    /// Of those, episodes that ended at the time limit.
    pub truncated: usize,
    /// Mean undiscounted return of the agent's episodes on the training reward.
    pub mean_return: f64,
    /// Root mean square distance between the two policies' actions, over all steps.
    pub action_rms: f64,
    /// Per critic (and `min`), for all steps, then time-limit and terminated episodes' steps
    /// (a set without steps is left out).
    pub lines: Vec<PreferenceLine>,
}

/// Each critic's values of the own actions `act [T, A]` and the other actions `alt [T, A]`
/// along one episode (see the [module docs](self)): per critic, `(own, other)`.
fn both_values(
    agent: &RdpgAgent,
    obs: &[f32],
    act: &[f32],
    alt: &[f32],
    steps: usize,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let obs = steps_tensor(agent, obs, steps, agent.obs_dim()); // [T, D]
    let (act, alt) = (
        steps_tensor(agent, act, steps, agent.act_dim()), // [T, A]
        steps_tensor(agent, alt, steps, agent.act_dim()), // [T, A]
    );
    let values = |q: Tensor| tensor_to_vec64(&q.to_kind(Kind::Double));
    tch::no_grad(|| {
        agent
            .critics()
            .iter()
            .map(|critic| {
                let before = critic_states_before(agent, critic, &obs, &act); // [1, T, H] each
                (
                    values(critic.step(&obs, &act, &before).0), // [T]
                    values(critic.step(&obs, &alt, &before).0), // [T]
                )
            })
            .collect()
    })
}

/// Measures how `agent`'s critics value `other`'s actions against the agent's own (see the
/// [module docs](self)) on `episodes` episodes of `cfg`'s training environment from `seed`.
///
/// # Errors
///
/// A soft actor-critic agent (its critics value its stochastic policy), 0 or more than
/// [`MAX_EPISODES`](super::bias::MAX_EPISODES) episodes, seeds past the largest, an
/// environment that does not match the agent's sizes, the other policy's error (e.g. an
/// observation size it does not take), or a non-finite action or value.
pub fn critic_preference(
    agent: &RdpgAgent,
    other: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<CriticPreference> {
    if agent.config().sac.is_some() {
        return Err(AgentError::Input(
            "a soft actor-critic's critics value its stochastic policy, not one action".into(),
        ));
    }
    let (seeds, mut env) = measured_env(agent, cfg, episodes, seed)?;
    let space = env.action_space().clone();
    let n_critics = agent.critics().len();
    let lines = if n_critics > 1 { n_critics + 1 } else { 1 };
    // Per line and set (all, time limit, terminated): (steps, sum own, sum other, preferred).
    let mut sums = vec![[(0usize, 0.0, 0.0, 0usize); 3]; lines];
    let (mut truncated, mut total_return, mut sq_dist, mut all_steps) = (0, 0.0, 0.0, 0usize);
    let mut policy = RdpgPolicy::new(agent);
    for ep_seed in seeds {
        let (mut o, _) = env.reset(Some(ep_seed))?;
        policy.begin_episode();
        other.begin_episode();
        let (mut obs, mut act, mut alt) = (Vec::new(), Vec::new(), Vec::new());
        let terminated = loop {
            let a = policy.act(&o)?;
            let b = other.act(&o)?;
            if b.len() != a.len() || b.iter().any(|v| !v.is_finite()) {
                return Err(AgentError::Input(format!(
                    "the other policy gave {} action values (finite: {}) where the agent \
                     gives {}",
                    b.len(),
                    b.iter().all(|v| v.is_finite()),
                    a.len()
                )));
            }
            sq_dist += a
                .iter()
                .zip(&b)
                .map(|(x, y)| f64::from(x - y).powi(2))
                .sum::<f64>();
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            total_return += s.reward;
            obs.extend_from_slice(&o);
            act.extend_from_slice(&a);
            alt.extend_from_slice(&b);
            if s.done() {
                break s.terminated;
            }
            o = s.obs;
        };
        let steps = obs.len() / agent.obs_dim();
        all_steps += steps;
        truncated += usize::from(!terminated);
        let mut qs = both_values(agent, &obs, &act, &alt, steps);
        if qs
            .iter()
            .any(|(q, r)| q.iter().chain(r).any(|v| !v.is_finite()))
        {
            return Err(AgentError::Diverged(format!(
                "a critic's value in the episode from seed {ep_seed} is not finite"
            )));
        }
        if n_critics > 1 {
            let min = |which: usize| -> Vec<f64> {
                (0..steps)
                    .map(|t| {
                        qs.iter()
                            .map(|q| if which == 0 { q.0[t] } else { q.1[t] })
                            .fold(f64::INFINITY, f64::min)
                    })
                    .collect()
            };
            let line = (min(0), min(1));
            qs.push(line);
        }
        let set = if terminated { 2 } else { 1 };
        for (line, (own, oth)) in qs.iter().enumerate() {
            for (q, r) in own.iter().zip(oth) {
                for k in [0, set] {
                    let s = &mut sums[line][k];
                    *s = (s.0 + 1, s.1 + q, s.2 + r, s.3 + usize::from(r > q));
                }
            }
        }
    }
    let names = ["all", "time limit", "terminated"];
    let lines = sums
        .iter()
        .enumerate()
        .flat_map(|(line, sets)| {
            let critic = if line < n_critics {
                format!("critic {line}")
            } else {
                "min".into()
            };
            sets.iter().zip(names).filter(|(s, _)| s.0 > 0).map(
                move |(&(n, own, oth, pref), steps_of)| PreferenceLine {
                    critic: critic.clone(),
                    steps_of: steps_of.into(),
                    steps: n,
                    mean_own: own / n as f64,
                    mean_other: oth / n as f64,
                    other_preferred: pref as f64 / n as f64,
                },
            )
        })
        .collect();
    Ok(CriticPreference {
        episodes,
        truncated,
        mean_return: total_return / episodes as f64,
        action_rms: (sq_dist / (all_steps * agent.act_dim()) as f64).sqrt(),
        lines,
    })
}
