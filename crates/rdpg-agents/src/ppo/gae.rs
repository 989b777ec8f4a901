//! The arithmetic of PPO outside the networks, as pure functions: generalised advantage
//! estimation ([`gae`], and `rollout_advantages` over a vector env's rollout) and the
//! adaptive KL coefficient ([`adapt_kl_coef`]).

use serde::{Deserialize, Serialize};

/// The steps collected since the last update phase, `len` vector steps of `n` environments,
/// step-major (`[len, n, ...]`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(super) struct Rollout {
    /// Vector steps collected.
    pub(super) len: usize,
    /// Observations acted on, `[len, n, D]`.
    pub(super) obs: Vec<f32>,
    /// Sampled (unclipped) actions, `[len, n, A]`.
    pub(super) actions: Vec<f32>,
    /// Training rewards, `[len, n]`.
    pub(super) rewards: Vec<f64>,
    /// The step reached a terminal state, `[len, n]`.
    pub(super) terminated: Vec<bool>,
    /// An episode ended on the step (terminated or truncated), `[len, n]`.
    pub(super) ended: Vec<bool>,
    /// `(t * n + i, last observation)` of every episode cut by the time limit (not terminal):
    /// the state its last step bootstraps from.
    pub(super) truncated_obs: Vec<(usize, Vec<f32>)>,
}

/// Generalised advantage estimates (Schulman et al. 2016, Eqs. 10 and 16) of one environment's
/// sequence of `T` consecutive steps, which may span several episodes.
///
/// For step `t`: `rewards[t]` is `r_t`, `values[t]` is `V(s_t)`, `next_values[t]` is `V` of the
/// true next state `s_{t+1}` (for a step that ended an episode by the time limit, the episode's
/// last observation; for the last step of the sequence, the observation after it; ignored when
/// `terminated[t]`), `terminated[t]` says `s_{t+1}` is terminal (no bootstrap) and `ended[t]`
/// that an episode ended on step `t` (terminated or truncated: the advantage does not flow back
/// across it). Returns `A_t` for every step, from
///
/// `delta_t = r_t + gamma (1 - terminated_t) V(s_{t+1}) - V(s_t)`,
/// `A_t = delta_t + gamma lambda (1 - ended_t) A_{t+1}`, `A_T = 0`.
///
/// The value targets are `R_t = A_t + V(s_t)`.
///
/// # Panics
/// If the slices have different lengths.
pub fn gae(
    rewards: &[f64],
    values: &[f64],
    next_values: &[f64],
    terminated: &[bool],
    ended: &[bool],
    gamma: f64,
    lambda: f64,
) -> Vec<f64> {
    let t = rewards.len();
    assert!(
        values.len() == t && next_values.len() == t && terminated.len() == t && ended.len() == t,
        "gae: slices of different lengths"
    );
    let mut adv = vec![0.0; t];
    let mut next_adv = 0.0;
    for k in (0..t).rev() {
        let boot = if terminated[k] { 0.0 } else { next_values[k] };
        let delta = rewards[k] + gamma * boot - values[k];
        let carry = if ended[k] { 0.0 } else { next_adv };
        adv[k] = delta + gamma * lambda * carry;
        next_adv = adv[k];
    }
    adv
}

/// The adaptive KL penalty rule of Schulman et al. 2017, section 4: given the mean KL `kl`
/// measured after an update phase, returns the next `beta`: `beta / factor` if
/// `kl < target / 1.5`, `beta * factor` if `kl > 1.5 target`, else `beta`.
pub fn adapt_kl_coef(beta: f64, kl: f64, target: f64, factor: f64) -> f64 {
    if kl < target / 1.5 {
        beta / factor
    } else if kl > target * 1.5 {
        beta * factor
    } else {
        beta
    }
}

/// GAE over a rollout of `n` environments: `values` is `V` of the rollout's observations
/// (`[len, n]`), `last_values` of the observations after the rollout (`[n]`), and
/// `trunc_values` of `ro.truncated_obs` (same order). Returns the advantages, `[len, n]`.
pub(super) fn rollout_advantages(
    ro: &Rollout,
    n: usize,
    values: &[f64],
    last_values: &[f64],
    trunc_values: &[f64],
    gamma: f64,
    lambda: f64,
) -> Vec<f64> {
    let t_len = ro.len;
    // V(s_{t+1}) of every step: the next observation of the same env, the one after the
    // rollout for the last step, the episode's last observation after a truncation (after a
    // termination it is unused).
    let mut next = vec![0.0; t_len * n];
    for t in 0..t_len {
        for i in 0..n {
            next[t * n + i] = if t + 1 < t_len {
                values[(t + 1) * n + i]
            } else {
                last_values[i]
            };
        }
    }
    for ((k, _), &v) in ro.truncated_obs.iter().zip(trunc_values) {
        next[*k] = v;
    }
    let mut adv = vec![0.0; t_len * n];
    for i in 0..n {
        let col = |x: &[f64]| -> Vec<f64> { (0..t_len).map(|t| x[t * n + i]).collect() };
        let colb = |x: &[bool]| -> Vec<bool> { (0..t_len).map(|t| x[t * n + i]).collect() };
        let a = gae(
            &col(&ro.rewards),
            &col(values),
            &col(&next),
            &colb(&ro.terminated),
            &colb(&ro.ended),
            gamma,
            lambda,
        );
        for (t, x) in a.into_iter().enumerate() {
            adv[t * n + i] = x;
        }
    }
    adv
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GAE on a 5-step sequence with a termination (t = 1) and a truncation (t = 3), against
    /// values computed by hand with gamma = lambda = 0.5 (gamma lambda = 0.25):
    /// `delta = [1 + .5 - .5, 2 - 1, 3 + 1 - 1.5, 4 + 1.5 - 2, 5 + 2 - 2.5]`
    /// `= [1, 1, 2.5, 3.5, 4.5]`;
    /// `A_4 = 4.5`, `A_3 = 3.5` (episode end), `A_2 = 2.5 + .25 * 3.5 = 3.375`, `A_1 = 1`
    /// (termination: no bootstrap, no carry), `A_0 = 1 + .25 * 1 = 1.25`.
    #[test]
    fn gae_matches_hand_computation() {
        let rewards = [1.0, 2.0, 3.0, 4.0, 5.0];
        let values = [0.5, 1.0, 1.5, 2.0, 2.5];
        // V(s_{t+1}): V(s_1); unused (terminal, 99 must not leak in); V(s_3); V(final obs of
        // the truncated episode) = 3; V(obs after the sequence) = 4.
        let next = [1.0, 99.0, 2.0, 3.0, 4.0];
        let terminated = [false, true, false, false, false];
        let ended = [false, true, false, true, false];
        let adv = gae(&rewards, &values, &next, &terminated, &ended, 0.5, 0.5);
        assert_eq!(adv, vec![1.25, 1.0, 3.375, 3.5, 4.5]);
        // lambda = 0: the one-step TD errors.
        let td = gae(&rewards, &values, &next, &terminated, &ended, 0.5, 0.0);
        assert_eq!(td, vec![1.0, 1.0, 2.5, 3.5, 4.5]);
    }

    /// The rollout layout (`[len, n]`, step-major) feeds each env's own column to [`gae`], the
    /// next step's value of the same env, the post-rollout value at the end and the truncated
    /// episode's last-observation value after a truncation.
    #[test]
    fn rollout_advantages_bootstrap_per_env() {
        // 2 envs x 3 steps. Env 0: truncated at t = 1. Env 1: terminated at t = 0.
        let ro = Rollout {
            len: 3,
            rewards: vec![1.0, 10.0, 2.0, 20.0, 3.0, 30.0],
            terminated: vec![false, true, false, false, false, false],
            ended: vec![false, true, true, false, false, false],
            truncated_obs: vec![(2, vec![0.0])],
            ..Rollout::default()
        };
        let values = [0.1, 1.0, 0.2, 2.0, 0.3, 3.0];
        let (last, trunc) = ([0.4, 4.0], [7.0]);
        let (g, l) = (0.9, 0.8);
        let got = rollout_advantages(&ro, 2, &values, &last, &trunc, g, l);
        let env0 = gae(
            &[1.0, 2.0, 3.0],
            &[0.1, 0.2, 0.3],
            &[0.2, 7.0, 0.4],
            &[false, false, false],
            &[false, true, false],
            g,
            l,
        );
        let env1 = gae(
            &[10.0, 20.0, 30.0],
            &[1.0, 2.0, 3.0],
            &[2.0, 3.0, 4.0],
            &[true, false, false],
            &[true, false, false],
            g,
            l,
        );
        let want: Vec<f64> = (0..3).flat_map(|t| [env0[t], env1[t]]).collect();
        assert_eq!(got, want);
        // Env 0, t = 1 bootstraps from the truncated episode's last observation (7), not from
        // the next episode's first one (0.3).
        assert!((got[2] - (2.0 + 0.9 * 7.0 - 0.2)).abs() < 1e-12);
    }

    /// The beta rule of Schulman et al. 2017 section 4, strict thresholds at 1.5x.
    #[test]
    fn kl_coefficient_adaptation() {
        let (t, f) = (0.01, 2.0);
        assert_eq!(adapt_kl_coef(1.0, 0.02, t, f), 2.0); // > 1.5 target: double
        assert_eq!(adapt_kl_coef(1.0, 0.005, t, f), 0.5); // < target / 1.5: halve
        assert_eq!(adapt_kl_coef(1.0, 0.01, t, f), 1.0); // in between: keep
        assert_eq!(adapt_kl_coef(1.0, 0.015, t, f), 1.0); // exactly at the bounds: keep
        assert_eq!(adapt_kl_coef(1.0, 0.01 / 1.5, t, f), 1.0);
        assert_eq!(adapt_kl_coef(0.5, 1.0, t, 3.0), 1.5);
        assert_eq!(adapt_kl_coef(0.5, 0.0, t, 3.0), 0.5 / 3.0);
    }
}
