//! The paper's critic targets and loss, as plain math on slices.
//!
//! This is the *reference* the tensor learner must reproduce; it is written for clarity, not
//! speed, and is tested against hand-computed numbers.
//!
//! # Tail-step bootstrap (Song et al. 2018, Sec. III-A-1; the authors' code)
//!
//! A sampled window has `l` optimisation steps `t .. t + l`. The critic target of **every**
//! step `i` of the window bootstraps from the single Q-value at the window's tail,
//! `Q(o_{t+len}, π(o_{t+len}))`, where `len` is the number of real optimisation steps
//! (`len < l` only when the episode ends inside the window):
//!
//! ```text
//! y_i = Σ_{k=i}^{len-1} γ^{k-i} r_k  +  γ^{len-i} · Q_tail · (1 - terminated)
//! ```
//!
//! Step `i` thus measures the `(len - i)`-step TD, `^{(l-i)}TD_{t+i}` in the paper's notation:
//! "TD(λ = 1) with the single bootstrap at the window's tail".
//!
//! # Interpolation weights (eq. `unsyncedinterpolatedTD`, Algorithm 1)
//!
//! Only the first `u ≤ l` steps of the window contribute to the critic loss, step `i` with
//! weight `λ^i`, normalised so the weights sum to one; see [`interpolated_td_weights`].

use crate::batch::SequenceBatch;

/// Critic targets of one window with a single bootstrap at its tail.
///
/// `rewards` holds the window's `l` optimisation-step rewards (padding after `len` is
/// ignored); `len` (the window's `opt_len`, `len <= rewards.len()`) is its number of real
/// steps; `tail_q` is the critic's value at the bootstrap observation that follows the last
/// real step; `tail_terminated` is true when that last step ended the episode by termination
/// (a time-limit truncation still bootstraps).
///
/// Returns `rewards.len()` values: for `i < len`,
/// `y_i = Σ_{k=i}^{len-1} γ^{k-i} r_k + γ^{len-i} · tail_q · (1 - tail_terminated)`;
/// entries `i >= len` (padding) are `0.0`.
///
/// ```
/// use rdpg_core::targets::tail_bootstrap_targets;
/// let y = tail_bootstrap_targets(&[1.0, 2.0, 4.0], 3, 0.5, 8.0, false);
/// assert_eq!(y, vec![4.0, 6.0, 8.0]);
/// ```
///
/// # Panics
///
/// If `len > rewards.len()`.
pub fn tail_bootstrap_targets(
    rewards: &[f32],
    len: usize,
    gamma: f64,
    tail_q: f64,
    tail_terminated: bool,
) -> Vec<f64> {
    assert!(
        len <= rewards.len(),
        "tail_bootstrap_targets: len {len} exceeds the window's {} rewards",
        rewards.len()
    );
    let mut y = vec![0.0; rewards.len()];
    // Backward recursion: y_{len-1} = r_{len-1} + γ·bootstrap, y_i = r_i + γ·y_{i+1}.
    let mut acc = if tail_terminated { 0.0 } else { tail_q };
    for i in (0..len).rev() {
        acc = f64::from(rewards[i]) + gamma * acc;
        y[i] = acc;
    }
    y
}

/// Tail-bootstrap targets of every window of a batch: `[n, opt]`, row-major.
///
/// `tail_q[w]` is the critic's value at window `w`'s bootstrap observation (slot
/// `scan + opt_len[w]` of `batch.obs`). Rewards are read from the optimisation part of the
/// batch; `batch.tail_terminated` decides whether the tail bootstraps. Padding entries are 0.
///
/// # Panics
///
/// If `tail_q.len() != batch.n` or the batch's arrays are inconsistent with its sizes.
pub fn batch_tail_bootstrap_targets(batch: &SequenceBatch, gamma: f64, tail_q: &[f64]) -> Vec<f64> {
    assert_eq!(
        tail_q.len(),
        batch.n,
        "batch_tail_bootstrap_targets: one tail value per window"
    );
    let steps = batch.steps();
    let mut out = Vec::with_capacity(batch.n * batch.opt);
    for (w, &q_tail) in tail_q.iter().enumerate() {
        let start = w * steps + batch.scan;
        let rewards = &batch.rewards[start..start + batch.opt];
        out.extend(tail_bootstrap_targets(
            rewards,
            batch.opt_len[w],
            gamma,
            q_tail,
            batch.tail_terminated[w] != 0.0,
        ));
    }
    out
}

/// The paper's interpolation weights for the first `u` steps of a window:
/// `w_i = λ^i / Σ_{j=0}^{u-1} λ^j`, `i = 0 .. u-1`, summing to one.
///
/// Step `i` of a window measures the `(l - i)`-step TD, so `w_i` weights the longest backups
/// most (eq. `unsyncedinterpolatedTD`). Special cases: `λ = 1` gives uniform weights `1 / u`
/// (truncated multi-step TD); `λ = 0` keeps only step 0 (`0^0 = 1`). With `u = l = 1` and no
/// scan this is the baseline RDPG's TD(0) on one step.
///
/// **Normalisation.** The paper writes the normaliser as `λ (1 - λ^u) / (1 - λ) = Σ_{i=1}^{u} λ^i`
/// while summing `λ^i` for `i = 0 .. u-1`, so its literal weights sum to `1/λ` (and blow up at
/// `λ = 0`). The text says the weights are normalised (`Z^{-1} Σ w(i) = 1`), so this function
/// normalises exactly; the two differ only by the constant factor `λ`, i.e. a rescaled
/// critic learning rate.
///
/// Returns `u` weights (empty for `u = 0`); weights for steps `u .. l` are zero, see
/// [`interpolated_td_weights_padded`].
///
/// # Panics
///
/// If `lambda` is negative or not finite.
pub fn interpolated_td_weights(u: usize, lambda: f64) -> Vec<f64> {
    assert!(
        lambda.is_finite() && lambda >= 0.0,
        "interpolated_td_weights: lambda must be finite and >= 0 (got {lambda})"
    );
    let mut w = Vec::with_capacity(u);
    let mut p = 1.0;
    for _ in 0..u {
        w.push(p);
        p *= lambda;
    }
    let z: f64 = w.iter().sum();
    for x in &mut w {
        *x /= z;
    }
    w
}

/// [`interpolated_td_weights`] padded with zeros to the window's `l` optimisation steps.
///
/// # Panics
///
/// If `u > l`, or `lambda` is negative or not finite.
pub fn interpolated_td_weights_padded(l: usize, u: usize, lambda: f64) -> Vec<f64> {
    assert!(u <= l, "interpolated_td_weights_padded: u = {u} > l = {l}");
    let mut w = interpolated_td_weights(u, lambda);
    w.resize(l, 0.0);
    w
}

/// The weighted squared TD error the learner's critic loss must equal.
///
/// `q`, `targets` and `mask` are `[n, l]` (row-major, the optimisation part of each window);
/// `weights` is `[l]` and is shared by all windows. The reduction is
///
/// ```text
/// L = (1/n) Σ_{w=0}^{n-1} Σ_{i=0}^{l-1} weights_i · mask_{w,i} · (targets_{w,i} - q_{w,i})²
/// ```
///
/// i.e. a weighted sum over the steps of a window, averaged over windows. Padded steps
/// (`mask = 0`) contribute nothing and the weights are **not** renormalised for windows
/// shorter than `u`. Returns 0 for `n = 0`.
///
/// # Panics
///
/// If `weights` is empty while `q` is not, if `q.len()` is not a multiple of
/// `weights.len()`, or if `targets` / `mask` differ in length from `q`.
pub fn critic_loss_reference(q: &[f64], targets: &[f64], weights: &[f64], mask: &[f32]) -> f64 {
    assert_eq!(
        q.len(),
        targets.len(),
        "critic_loss_reference: q vs targets"
    );
    assert_eq!(q.len(), mask.len(), "critic_loss_reference: q vs mask");
    if q.is_empty() {
        return 0.0;
    }
    let l = weights.len();
    assert!(
        l > 0 && q.len().is_multiple_of(l),
        "critic_loss_reference: q has {} entries, not a multiple of l = {l}",
        q.len()
    );
    let n = q.len() / l;
    let mut total = 0.0;
    for (idx, ((&qi, &yi), &mi)) in q.iter().zip(targets).zip(mask).enumerate() {
        let d = yi - qi;
        total += weights[idx % l] * f64::from(mi) * d * d;
    }
    total / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &[f64], b: &[f64]) {
        assert_eq!(a.len(), b.len(), "{a:?} vs {b:?}");
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn targets_full_window_bootstraps_from_tail() {
        // l = 3, γ = 0.5, r = [1, 2, 4], Q_tail = 8.
        // y0 = 1 + 0.5*2 + 0.25*4 + 0.125*8 = 4
        // y1 = 2 + 0.5*4 + 0.25*8 = 6
        // y2 = 4 + 0.5*8 = 8
        let y = tail_bootstrap_targets(&[1.0, 2.0, 4.0], 3, 0.5, 8.0, false);
        close(&y, &[4.0, 6.0, 8.0]);
    }

    #[test]
    fn targets_terminated_drop_bootstrap() {
        // Same window, episode terminated at its last step: y = [1+1+1, 2+2, 4].
        let y = tail_bootstrap_targets(&[1.0, 2.0, 4.0], 3, 0.5, 8.0, true);
        close(&y, &[3.0, 4.0, 4.0]);
    }

    #[test]
    fn targets_short_window_truncated_bootstraps_early() {
        // l = 4 but the episode was truncated after 2 steps of the window: rewards [3, -2]
        // then padding. γ = 0.9, Q_tail = 10 (taken at the obs after step 1).
        // y0 = 3 + 0.9*(-2) + 0.81*10 = 3 - 1.8 + 8.1 = 9.3
        // y1 = -2 + 0.9*10 = 7
        let y = tail_bootstrap_targets(&[3.0, -2.0, 0.0, 0.0], 2, 0.9, 10.0, false);
        close(&y, &[9.3, 7.0, 0.0, 0.0]);
    }

    #[test]
    fn targets_short_window_terminated() {
        // Same short window, terminated: y0 = 3 - 1.8 = 1.2, y1 = -2.
        let y = tail_bootstrap_targets(&[3.0, -2.0, 0.0, 0.0], 2, 0.9, 10.0, true);
        close(&y, &[1.2, -2.0, 0.0, 0.0]);
    }

    #[test]
    fn targets_one_step_is_td0() {
        // l = 1: the baseline TD(0) target r + γ Q(o').
        close(
            &tail_bootstrap_targets(&[0.5], 1, 0.99, 2.0, false),
            &[0.5 + 0.99 * 2.0],
        );
        close(&tail_bootstrap_targets(&[0.5], 1, 0.99, 2.0, true), &[0.5]);
    }

    #[test]
    fn targets_gamma_one_is_monte_carlo_plus_tail() {
        let y = tail_bootstrap_targets(&[1.0, 1.0, 1.0, 1.0], 4, 1.0, 100.0, false);
        close(&y, &[104.0, 103.0, 102.0, 101.0]);
    }

    #[test]
    #[should_panic(expected = "exceeds")]
    fn targets_len_too_long_panics() {
        let _ = tail_bootstrap_targets(&[1.0], 2, 0.9, 0.0, false);
    }

    #[test]
    fn batch_targets_read_opt_part() {
        // Two windows, scan 1, opt 2. Window 0 full and truncated-free; window 1 is one real
        // step ending in termination.
        let batch = SequenceBatch {
            n: 2,
            scan: 1,
            opt: 2,
            obs_dim: 1,
            act_dim: 1,
            obs: vec![0.0; 2 * 4],
            actions: vec![0.0; 2 * 3],
            rewards: vec![9.0, 1.0, 2.0, 0.0, 5.0, 0.0],
            mask: vec![1.0, 1.0, 1.0, 0.0, 1.0, 0.0],
            scan_len: vec![1, 0],
            opt_len: vec![2, 1],
            tail_terminated: vec![0.0, 1.0],
            injected: vec![0.0, 0.0],
            stored_state: None,
            state_dim: 0,
        };
        // Window 0: y = [1 + 0.5*2 + 0.25*4, 2 + 0.5*4] = [3, 4]; window 1: [5, 0].
        let y = batch_tail_bootstrap_targets(&batch, 0.5, &[4.0, 7.0]);
        close(&y, &[3.0, 4.0, 5.0, 0.0]);
    }

    #[test]
    fn weights_lambda_half() {
        // u = 3, λ = 0.5: λ^i = [1, 0.5, 0.25], sum 1.75.
        let w = interpolated_td_weights(3, 0.5);
        close(&w, &[1.0 / 1.75, 0.5 / 1.75, 0.25 / 1.75]);
        // The paper's closed form (1 - λ^u)/(1 - λ) is the same sum.
        assert!(((1.0 - 0.5f64.powi(3)) / 0.5 - 1.75).abs() < 1e-15);
    }

    #[test]
    fn weights_lambda_one_uniform() {
        close(&interpolated_td_weights(4, 1.0), &[0.25; 4]);
    }

    #[test]
    fn weights_lambda_zero_first_only() {
        close(&interpolated_td_weights(3, 0.0), &[1.0, 0.0, 0.0]);
    }

    #[test]
    fn weights_u_one_is_td0_and_padding_is_zero() {
        close(&interpolated_td_weights(1, 0.7), &[1.0]);
        close(
            &interpolated_td_weights_padded(4, 1, 0.7),
            &[1.0, 0.0, 0.0, 0.0],
        );
        // l = 5, u = 2, λ = 0.8: [1, 0.8] / 1.8 then zeros.
        close(
            &interpolated_td_weights_padded(5, 2, 0.8),
            &[1.0 / 1.8, 0.8 / 1.8, 0.0, 0.0, 0.0],
        );
        assert!(interpolated_td_weights(0, 0.5).is_empty());
    }

    #[test]
    fn weights_sum_to_one() {
        for &lambda in &[0.0, 0.1, 0.5, 0.9, 0.99, 1.0] {
            for u in 1..12 {
                let s: f64 = interpolated_td_weights(u, lambda).iter().sum();
                assert!((s - 1.0).abs() < 1e-12, "u {u} λ {lambda}: {s}");
            }
        }
    }

    #[test]
    #[should_panic(expected = "u = 3 > l = 2")]
    fn weights_u_above_l_panics() {
        let _ = interpolated_td_weights_padded(2, 3, 0.5);
    }

    #[test]
    fn loss_hand_computed() {
        // n = 2, l = 3, u = 2, λ = 1 -> weights [0.5, 0.5, 0].
        let w = interpolated_td_weights_padded(3, 2, 1.0);
        let q = [1.0, 2.0, 3.0, 0.0, 0.0, 0.0];
        let y = [2.0, 4.0, 100.0, 1.0, 3.0, 5.0];
        // Window 1's second step is padding.
        let mask = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0];
        // Window 0: 0.5*1 + 0.5*4 + 0*9409 = 2.5; window 1: 0.5*1 = 0.5. Mean = 1.5.
        let loss = critic_loss_reference(&q, &y, &w, &mask);
        assert!((loss - 1.5).abs() < 1e-12, "{loss}");
    }

    #[test]
    fn loss_end_to_end_with_targets() {
        // l = u = 3, λ = 0.5, γ = 0.5, r = [1, 2, 4], Q_tail = 8 -> y = [4, 6, 8].
        // q = [4, 5, 10]: errors [0, 1, -2], squared [0, 1, 4];
        // weights [4/7, 2/7, 1/7] -> loss = 2/7 + 4/7 = 6/7.
        let y = tail_bootstrap_targets(&[1.0, 2.0, 4.0], 3, 0.5, 8.0, false);
        let w = interpolated_td_weights(3, 0.5);
        let loss = critic_loss_reference(&[4.0, 5.0, 10.0], &y, &w, &[1.0; 3]);
        assert!((loss - 6.0 / 7.0).abs() < 1e-12, "{loss}");
    }

    #[test]
    fn loss_empty_is_zero() {
        assert_eq!(critic_loss_reference(&[], &[], &[1.0], &[]), 0.0);
    }
}
