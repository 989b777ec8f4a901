//! The batch as the update reads it ([`Prepared`]): the replay's windows uploaded to the
//! device, split into the scan part and the optimisation window, with the small index and
//! weight tensors of the targets and losses built once per update.

use rdpg_core::targets::interpolated_td_weights_padded;
use rdpg_core::SequenceBatch;
use tch::{Device, Kind, Tensor};

use super::config::{ActorWeights, RdpgConfig};
use super::lstm::RecState;
use crate::{AgentError, Result};

/// The batch on the device, split into the scan part and the optimisation window.
pub(super) struct Prepared {
    pub(super) n: i64,
    pub(super) s: i64,
    pub(super) l: i64,
    /// Steps the critic trains on in each window: `min(u, l)`, the first ones.
    pub(super) u: i64,
    /// `[N, s, D]`, `[N, s, A]`: the scan part.
    pub(super) obs_scan: Tensor,
    pub(super) act_scan: Tensor,
    /// `[N, l + 1, D]`: the window's observations plus the slot that holds `o_tail` for
    /// full windows (shorter windows have it at `len`, inside the window).
    pub(super) obs_win: Tensor,
    /// `[N, l, A]`, `[N, l]`: replayed actions and rewards of the window.
    pub(super) act_win: Tensor,
    pub(super) rew: Tensor,
    /// `[N, l]`: 1 on real steps.
    pub(super) mask: Tensor,
    /// `[N, l + 1]`: 1 at the tail position `len_n`.
    pub(super) tail_onehot: Tensor,
    /// `[N]`: `1 - tail_terminated`.
    pub(super) not_term: Tensor,
    /// `[N, l]`: 0 on the last real step of a window whose tail is terminal, else 1 (the
    /// per-step TD(0) targets' `1 - term_i`).
    pub(super) step_not_done: Tensor,
    /// `[N, l]`: `gamma^(len - i)` on real steps.
    pub(super) boot_coef: Tensor,
    /// `[l, l]`: `gamma^(k - i)` for `k >= i`.
    pub(super) disc: Tensor,
    /// `[N, l]`: `lambda^i / sum_{j<u} lambda^j` on real steps among the first `u`.
    pub(super) critic_w: Tensor,
    /// `[N, l]`: the actor loss's weights on real steps: `1 / len` (`actor_weights =
    /// "per_window"`) or `1 / l` (`per_step`); a window-of-k agent's: 1 on the first step.
    pub(super) actor_w: Tensor,
    pub(super) scan_len: Vec<usize>,
    /// Stored acting-time actor states `[1, N, H]` (when burning in from them).
    pub(super) stored: Option<RecState>,
    /// Window-of-k agents (`act_window`): the `k - 1` steps before each window's tail.
    pub(super) window_tail: Option<WindowTail>,
}

/// The `k - 1` observation-action pairs right before each window's tail (`act_window = k`),
/// left-padded: what the target networks re-encode from a zero state for the bootstrap, as
/// the actor does when it acts at the tail observation.
pub(super) struct WindowTail {
    /// `[N, k - 1, D]`, `[N, k - 1, A]`.
    pub(super) obs: Tensor,
    pub(super) act: Tensor,
    /// Real steps among them (the last ones), per window.
    pub(super) len: Vec<usize>,
}

impl WindowTail {
    fn shallow_clone(&self) -> Self {
        Self {
            obs: self.obs.shallow_clone(),
            act: self.act.shallow_clone(),
            len: self.len.clone(),
        }
    }
}

impl Prepared {
    /// Second handles to the same tensors, for the second thread of `parallel_twins`.
    pub(super) fn shallow_clone(&self) -> Self {
        Self {
            n: self.n,
            s: self.s,
            l: self.l,
            u: self.u,
            obs_scan: self.obs_scan.shallow_clone(),
            act_scan: self.act_scan.shallow_clone(),
            obs_win: self.obs_win.shallow_clone(),
            act_win: self.act_win.shallow_clone(),
            rew: self.rew.shallow_clone(),
            mask: self.mask.shallow_clone(),
            tail_onehot: self.tail_onehot.shallow_clone(),
            not_term: self.not_term.shallow_clone(),
            step_not_done: self.step_not_done.shallow_clone(),
            boot_coef: self.boot_coef.shallow_clone(),
            disc: self.disc.shallow_clone(),
            critic_w: self.critic_w.shallow_clone(),
            actor_w: self.actor_w.shallow_clone(),
            scan_len: self.scan_len.clone(),
            stored: self.stored.as_ref().map(RecState::shallow_clone),
            window_tail: self.window_tail.as_ref().map(WindowTail::shallow_clone),
        }
    }
}

/// What a batch is checked against and uploaded for: the agent's settings, sizes and tensors.
pub(super) struct BatchSpec<'a> {
    pub(super) cfg: &'a RdpgConfig,
    pub(super) obs_dim: usize,
    pub(super) act_dim: usize,
    /// The actor's recurrent width `H` (a stored state is `[h, c]`, `2H` values).
    pub(super) state_width: i64,
    pub(super) kind: Kind,
    pub(super) device: Device,
}

impl BatchSpec<'_> {
    fn state_dim(&self) -> usize {
        2 * self.state_width as usize
    }

    /// Checks a batch against the agent (sizes, lengths, mask, stored state).
    pub(super) fn check_batch(&self, b: &SequenceBatch) -> Result<()> {
        let err = |m: String| Err(AgentError::Shape(m));
        let t = b.scan.saturating_add(b.opt);
        // Saturating: a batch with absurd sizes does not match, rather than overflow.
        let times = |a: usize, c: usize, d: usize| a.saturating_mul(c).saturating_mul(d);
        if b.obs_dim != self.obs_dim || b.act_dim != self.act_dim {
            return err(format!(
                "batch obs/act dims {}/{} but agent {}/{}",
                b.obs_dim, b.act_dim, self.obs_dim, self.act_dim
            ));
        }
        if b.n == 0 || b.opt == 0 {
            return err("batch needs n >= 1 and opt >= 1".into());
        }
        if b.obs.len() != times(b.n, t.saturating_add(1), b.obs_dim)
            || b.actions.len() != times(b.n, t, b.act_dim)
            || b.rewards.len() != times(b.n, t, 1)
            || b.mask.len() != times(b.n, t, 1)
            || b.scan_len.len() != b.n
            || b.opt_len.len() != b.n
            || b.tail_terminated.len() != b.n
        {
            return err("batch array lengths do not match n, scan, opt, dims".into());
        }
        for i in 0..b.n {
            let (k, len) = (b.scan_len[i], b.opt_len[i]);
            if k > b.scan || len == 0 || len > b.opt {
                return err(format!(
                    "window {i}: scan_len {k} / opt_len {len} out of range"
                ));
            }
            for j in 0..t {
                let real = if j < b.scan {
                    j >= b.scan - k
                } else {
                    j - b.scan < len
                };
                if (b.mask[i * t + j] != 0.0) != real {
                    return err(format!(
                        "window {i}: mask at step {j} disagrees with lengths"
                    ));
                }
            }
        }
        if self.cfg.burn_in_from_stored_state {
            match &b.stored_state {
                Some(s)
                    if b.state_dim == self.state_dim() && s.len() == times(b.n, b.state_dim, 1) => {
                }
                _ => {
                    return err(format!(
                        "burn_in_from_stored_state needs stored states of size {}",
                        self.state_dim()
                    ))
                }
            }
        }
        Ok(())
    }

    /// Uploads the batch and builds the small index/weight tensors of the update.
    pub(super) fn prepare(&self, b: &SequenceBatch) -> Prepared {
        let (n, s, l) = (b.n as i64, b.scan as i64, b.opt as i64);
        let (d, a) = (b.obs_dim as i64, b.act_dim as i64);
        let up = |v: &[f32], shape: &[i64]| -> Tensor {
            Tensor::from_slice(v)
                .view(shape)
                .to_kind(self.kind)
                .to_device(self.device)
        };
        let up64 = |v: Vec<f64>, shape: &[i64]| -> Tensor {
            Tensor::from_slice(&v)
                .view(shape)
                .to_kind(self.kind)
                .to_device(self.device)
        };
        let obs = up(&b.obs, &[n, s + l + 1, d]);
        let actions = up(&b.actions, &[n, s + l, a]);
        let rewards = up(&b.rewards, &[n, s + l]);
        let gamma = self.cfg.gamma;
        let u = self.cfg.update_len.min(b.opt);
        let (nn, ll) = (b.n, b.opt);
        // lambda^i / sum_{j<u} lambda^j on the first u steps, shared by all windows (padded
        // steps drop out, short windows are not renormalised): rdpg-core's reference.
        let td_w = interpolated_td_weights_padded(ll, u, self.cfg.lambda);
        let mut onehot = vec![0.0; nn * (ll + 1)];
        let mut mask = vec![0.0; nn * ll];
        let mut boot_coef = vec![0.0; nn * ll];
        let mut critic_w = vec![0.0; nn * ll];
        let mut actor_w = vec![0.0; nn * ll];
        let mut not_term = vec![0.0; nn];
        let mut step_not_done = vec![1.0; nn * ll];
        for i in 0..nn {
            let len = b.opt_len[i];
            onehot[i * (ll + 1) + len] = 1.0;
            not_term[i] = 1.0 - f64::from(b.tail_terminated[i]);
            step_not_done[i * ll + len - 1] = not_term[i];
            for j in 0..len {
                mask[i * ll + j] = 1.0;
                boot_coef[i * ll + j] = gamma.powi((len - j) as i32);
                // Window-of-k: the actor trains where its state matches acting, step 0.
                actor_w[i * ll + j] = match (self.cfg.act_window, self.cfg.actor_weights) {
                    (0, ActorWeights::PerWindow) => 1.0 / len as f64,
                    (0, ActorWeights::PerStep) => 1.0 / ll as f64,
                    _ => f64::from(u8::from(j == 0)),
                };
                critic_w[i * ll + j] = td_w[j];
            }
        }
        // disc[k, i] = gamma^(k - i) for k >= i: (r * mask) @ disc = discounted reward sums.
        let mut disc = vec![0.0; ll * ll];
        for k in 0..ll {
            for i in 0..=k {
                disc[k * ll + i] = gamma.powi((k - i) as i32);
            }
        }
        // The stored acting-time state of each window's first step (its first scan step, or
        // with `s = 0` its first optimisation step: R2D2's "stored state, no burn-in").
        let stored = match (&b.stored_state, self.cfg.burn_in_from_stored_state) {
            (Some(st), true) => {
                let h = self.state_width;
                let t = up(st, &[n, 2 * h]);
                Some(RecState {
                    h: t.narrow(1, 0, h).unsqueeze(0).contiguous(),
                    c: t.narrow(1, h, h).unsqueeze(0).contiguous(),
                })
            }
            _ => None,
        };
        // Window-of-k: the k - 1 = s steps before the tail at `s + len_n` in the scan +
        // window sequence, i.e. columns len_n .. len_n + s - 1; the real ones are the last
        // min(s, scan_len + len_n).
        let window_tail = (self.cfg.act_window > 0).then(|| {
            let idx: Vec<i64> = (0..nn)
                .flat_map(|i| (0..s).map(move |j| b.opt_len[i] as i64 + j))
                .collect();
            let idx = Tensor::from_slice(&idx)
                .view([n, s, 1])
                .to_device(self.device);
            let take = |x: &Tensor, w: i64| {
                x.narrow(1, 0, s + l)
                    .gather(1, &idx.expand([n, s, w], false), false)
            };
            WindowTail {
                obs: take(&obs, d),
                act: take(&actions, a),
                len: (0..nn)
                    .map(|i| (b.scan_len[i] + b.opt_len[i]).min(s as usize))
                    .collect(),
            }
        });
        Prepared {
            window_tail,
            n,
            s,
            l,
            u: u as i64,
            obs_scan: obs.narrow(1, 0, s),
            act_scan: actions.narrow(1, 0, s),
            obs_win: obs.narrow(1, s, l + 1),
            act_win: actions.narrow(1, s, l),
            rew: rewards.narrow(1, s, l),
            mask: up64(mask, &[n, l]),
            tail_onehot: up64(onehot, &[n, l + 1]),
            not_term: up64(not_term, &[n]),
            step_not_done: up64(step_not_done, &[n, l]),
            boot_coef: up64(boot_coef, &[n, l]),
            disc: up64(disc, &[l, l]),
            critic_w: up64(critic_w, &[n, l]),
            actor_w: up64(actor_w, &[n, l]),
            scan_len: b.scan_len.clone(),
            stored,
        }
    }
}
