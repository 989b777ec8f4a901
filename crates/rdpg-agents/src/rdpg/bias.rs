//! The critics' estimation bias (Fujimoto et al. 2018, "Addressing Function Approximation
//! Error in Actor-Critic Methods", Sec. 4.1, Fig. 1): what the critics predict for the
//! deterministic policy's own episodes against the discounted return those episodes bring.
//!
//! The agent acts deterministically (as in evaluation) on episodes of its **training**
//! environment (its training reward, fall penalty, action repeat and observation view), one
//! after the other in one environment from `seed` on. Along each episode every critic runs
//! as the update trains it to predict: `Q_i(o_t, a_t | h^C_{t-1})`, its state carried from a
//! zero state at the episode start (a window-of-k agent: re-encoded from zero over the
//! `k - 1` steps before `t`, as its windows start). The reference is the discounted return
//! `G_t = sum_{j >= t} gamma^{j-t} r_j` of the rest of the episode, exact where it ended in a
//! termination. A time-limit truncation cuts the sum short by `gamma^{T-t} V(o_T)`: the last
//! `ceil(ln 0.01 / ln gamma)` steps of a truncated episode, whose cut tail weighs more than
//! 1 % of `V`, are left out (all of a truncated episode shorter than that).
//!
//! Bias at a step: `Q_t - G_t`; reported per critic (and the twins' minimum, which the
//! target takes) as means over the measured steps, relative to the mean `|G_t|`, with the
//! spread over episodes of each episode's mean bias. A soft actor-critic's critics estimate
//! the entropy-regularised value of its stochastic policy, not the deterministic return:
//! refused.

use rdpg_core::stats::mean_std;
use serde::Serialize;
use tch::{Kind, Tensor};

use super::config::ScanMethod;
use super::lstm::{scan_state, RecState};
use super::nets::Critic;
use super::staleness::scan_inputs;
use super::RdpgAgent;
use crate::common::config::TrainConfig;
use crate::common::policy::{episode_seeds, to_env_action, DeterministicPolicy};
use crate::common::tensor::tensor_to_vec64;
use crate::error::{AgentError, Result};
use crate::rdpg::trainer::RdpgPolicy;

/// The most episodes one measurement runs.
pub const MAX_EPISODES: usize = 100_000;

/// The share of `V(o_T)` a left-out truncated step's missing tail may weigh at most.
const TAIL_WEIGHT: f64 = 0.01;

/// One measured episode.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EpisodeBias {
    /// Reset seed.
    pub seed: u64,
    /// Agent steps.
    pub steps: usize,
    /// Whether it ended in a termination (else a time-limit truncation).
    pub terminated: bool,
    /// Undiscounted return on the training reward.
    pub train_return: f64,
    /// Steps measured (all of a terminated episode; a truncated one's less its tail).
    pub measured: usize,
}

/// One critic's bias over the measured steps.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CriticBias {
    /// `critic 0`, `critic 1`, or `min` (the twins' minimum).
    pub critic: String,
    /// Mean prediction `Q_t`.
    pub mean_q: f64,
    /// Mean discounted return `G_t`.
    pub mean_return: f64,
    /// Mean `Q_t - G_t`.
    pub mean_bias: f64,
    /// `mean_bias` over the mean `|G_t|`.
    pub relative_bias: f64,
    /// Root mean square of `Q_t - G_t`.
    pub rmse: f64,
    /// Sample standard deviation over episodes of each episode's mean bias (0 with one
    /// measured episode).
    pub episode_std: f64,
}

/// What [`estimation_bias`] measured.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct EstimationBias {
    /// The agent's discount.
    pub gamma: f64,
    /// Steps left out at the end of a truncated episode.
    pub truncated_tail: usize,
    /// Every episode run, in order.
    pub episodes: Vec<EpisodeBias>,
    /// Steps measured over all episodes.
    pub steps_measured: usize,
    /// One line per critic (and `min` for twins).
    pub critics: Vec<CriticBias>,
}

/// Running sums of one critic line over measured steps.
#[derive(Debug, Clone, Default)]
struct Sums {
    q: f64,
    g: f64,
    abs_g: f64,
    bias: f64,
    sq: f64,
}

impl Sums {
    fn add(&mut self, q: f64, g: f64) {
        self.q += q;
        self.g += g;
        self.abs_g += g.abs();
        self.bias += q - g;
        self.sq += (q - g).powi(2);
    }
}

/// Steps left out at the end of a truncated episode: the fewest `h` with `gamma^h <= 1 %`.
pub fn truncated_tail(gamma: f64) -> usize {
    if gamma <= TAIL_WEIGHT {
        return 1;
    }
    (TAIL_WEIGHT.ln() / gamma.ln()).ceil() as usize
}

/// `G_t = r_t + gamma G_{t+1}` backwards from `G_T = 0`.
fn discounted_returns(rewards: &[f64], gamma: f64) -> Vec<f64> {
    let mut g = vec![0.0; rewards.len()];
    let mut acc = 0.0;
    for t in (0..rewards.len()).rev() {
        acc = rewards[t] + gamma * acc;
        g[t] = acc;
    }
    g
}

/// Each critic's `Q(o_t, a_t | h^C_{t-1})` along one episode, `obs [T, D]`, `act [T, A]`
/// (see the [module docs](self)): one `Vec` of `T` values per critic.
fn critic_values(agent: &RdpgAgent, obs: &[f32], act: &[f32], steps: usize) -> Vec<Vec<f64>> {
    let obs = steps_tensor(agent, obs, steps, agent.obs_dim()); // [T, D]
    let act = steps_tensor(agent, act, steps, agent.act_dim()); // [T, A]
    tch::no_grad(|| {
        agent
            .critics()
            .iter()
            .map(|critic| {
                let before = critic_states_before(agent, critic, &obs, &act);
                tensor_to_vec64(&critic.step(&obs, &act, &before).0.to_kind(Kind::Double))
                // [T]
            })
            .collect()
    })
}

/// One episode's per-step values (`T * width` of them) as an agent's tensor `[T, width]`.
pub(super) fn steps_tensor(agent: &RdpgAgent, v: &[f32], steps: usize, width: usize) -> Tensor {
    Tensor::from_slice(v)
        .view([steps as i64, width as i64])
        .to_kind(agent.kind)
        .to_device(agent.device())
}

/// `critic`'s state before each step `t` of one episode (`obs [T, D]`, `act [T, A]`), batched
/// over the steps as a `[1, T, H]` state: carried from a zero state along the episode's
/// actions, or, for a window-of-k agent, its `k - 1` steps before `t` re-encoded from zero (as
/// it acts and trains). No gradient.
pub(super) fn critic_states_before(
    agent: &RdpgAgent,
    critic: &Critic,
    obs: &Tensor,
    act: &Tensor,
) -> RecState {
    let (kind, device) = (agent.kind, agent.device());
    let x = critic.input_seq(&obs.unsqueeze(0), &act.unsqueeze(0)); // [1, T, E]
    match agent.config().act_window {
        0 => {
            let (h, c) = critic
                .core
                .states_before(&x, &critic.core.zero_state(1, kind, device));
            RecState { h, c } // [1, T, H] each
        }
        window => {
            let steps = obs.size()[0];
            let ts: Vec<usize> = (0..steps as usize).collect();
            let (xs, real) = scan_inputs(&x, &ts, window - 1);
            let zero = critic.core.zero_state(steps, kind, device);
            scan_state(&critic.core, &xs, &real, &zero, ScanMethod::Grouped)
        }
    }
}

/// The episodes' seeds and the training environment a measurement of `agent` runs them on:
/// 1 to [`MAX_EPISODES`] episodes, an environment of the agent's sizes.
pub(super) fn measured_env(
    agent: &RdpgAgent,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<(
    impl Iterator<Item = u64>,
    Box<dyn rdpg_envs::registry::AnyEnv>,
)> {
    if episodes == 0 || episodes > MAX_EPISODES {
        return Err(AgentError::Input(format!(
            "measure 1 to {MAX_EPISODES} episodes (got {episodes})"
        )));
    }
    let seeds = episode_seeds(seed, episodes)?;
    let env = rdpg_envs::make_with(&cfg.env, &cfg.env_options())?;
    let (obs, act) = (env.observation_space().dim(), env.action_space().dim());
    if (obs, act) != (agent.obs_dim(), agent.act_dim()) {
        return Err(AgentError::Input(format!(
            "{} gives observations/actions of sizes {obs}/{act}, the agent's are {}/{}",
            cfg.env,
            agent.obs_dim(),
            agent.act_dim()
        )));
    }
    Ok((seeds, env))
}

/// Measures `agent`'s critics' estimation bias (see the [module docs](self)) on `episodes`
/// episodes of `cfg`'s training environment from seed `seed` on.
///
/// # Errors
///
/// A soft actor-critic agent, 0 or more than [`MAX_EPISODES`] episodes, seeds past the
/// largest, an environment that does not match the agent's sizes, no step measured (every
/// episode truncated within its left-out tail), or a non-finite action or value (the
/// networks diverged).
pub fn estimation_bias(
    agent: &RdpgAgent,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
) -> Result<EstimationBias> {
    let acfg = agent.config();
    if acfg.sac.is_some() {
        return Err(AgentError::Input(
            "a soft actor-critic's critics estimate the entropy-regularised value of its \
             stochastic policy, not the deterministic policy's return: no reference to measure \
             against"
                .into(),
        ));
    }
    let (seeds, mut env) = measured_env(agent, cfg, episodes, seed)?;
    let space = env.action_space().clone();
    let gamma = acfg.gamma;
    let tail = truncated_tail(gamma);
    let n_critics = agent.critics().len();
    let lines = if n_critics > 1 { n_critics + 1 } else { 1 };
    // Per line: running sums over the measured steps, and each episode's mean bias.
    let mut sums = vec![Sums::default(); lines];
    let mut per_episode: Vec<Vec<f64>> = vec![Vec::new(); lines];
    let mut steps_measured = 0;
    let mut out = Vec::with_capacity(episodes.min(4096));
    let mut policy = RdpgPolicy::new(agent);
    for ep_seed in seeds {
        let (mut o, _) = env.reset(Some(ep_seed))?;
        policy.begin_episode();
        let (mut obs, mut act, mut rew) = (Vec::new(), Vec::new(), Vec::new());
        let terminated = loop {
            let a = policy.act(&o)?;
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            obs.extend_from_slice(&o);
            act.extend_from_slice(&a);
            rew.push(s.reward);
            if s.done() {
                break s.terminated;
            }
            o = s.obs;
        };
        let steps = rew.len();
        let measured = if terminated {
            steps
        } else {
            steps.saturating_sub(tail)
        };
        out.push(EpisodeBias {
            seed: ep_seed,
            steps,
            terminated,
            train_return: rew.iter().sum(),
            measured,
        });
        if measured == 0 {
            continue;
        }
        let g = discounted_returns(&rew, gamma);
        let mut qs = critic_values(agent, &obs, &act, steps);
        if let Some((t, _)) = qs
            .iter()
            .flat_map(|q| q.iter().enumerate())
            .find(|(_, q)| !q.is_finite())
        {
            return Err(AgentError::Diverged(format!(
                "a critic's value at step {t} of the episode from seed {ep_seed} is not finite"
            )));
        }
        if n_critics > 1 {
            let min = (0..steps)
                .map(|t| qs.iter().map(|q| q[t]).fold(f64::INFINITY, f64::min))
                .collect();
            qs.push(min);
        }
        for (line, q) in qs.iter().enumerate() {
            let before = sums[line].bias;
            for t in 0..measured {
                sums[line].add(q[t], g[t]);
            }
            per_episode[line].push((sums[line].bias - before) / measured as f64);
        }
        steps_measured += measured;
    }
    if steps_measured == 0 {
        return Err(AgentError::Input(format!(
            "no step measured: every episode was truncated within its last {tail} steps, \
             whose returns the time limit cuts short (gamma {gamma})"
        )));
    }
    let m = steps_measured as f64;
    let critics = sums
        .iter()
        .zip(&per_episode)
        .enumerate()
        .map(|(line, (sum, eps))| {
            let (mean_q, mean_return) = (sum.q / m, sum.g / m);
            CriticBias {
                critic: if line < n_critics {
                    format!("critic {line}")
                } else {
                    "min".into()
                },
                mean_q,
                mean_return,
                mean_bias: mean_q - mean_return,
                relative_bias: (mean_q - mean_return) / (sum.abs_g / m),
                rmse: (sum.sq / m).sqrt(),
                episode_std: mean_std(eps).1,
            }
        })
        .collect();
    Ok(EstimationBias {
        gamma,
        truncated_tail: tail,
        episodes: out,
        steps_measured,
        critics,
    })
}
