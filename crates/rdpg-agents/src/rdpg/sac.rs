//! Soft actor-critic's update (`algo = "sac"`; Haarnoja et al. 2018, "Soft Actor-Critic
//! Algorithms and Applications", Algorithm 1), on RDPG's sequence machinery, top to bottom.
//!
//! # The policy
//!
//! A squashed Gaussian (the paper's Appendix C): the actor's output layer gives the mean `m`
//! and the log standard deviation `log s` (clamped to `LOG_STD_RANGE`) from the core's output;
//! a sample is `u = m + s * eps`, `eps ~ N(0, I)` (the reparameterisation, Eq. (8)),
//! `a = tanh(u)`, with
//! `log pi(a | o) = sum_j [log N(u_j; m_j, s_j^2) - log(1 - tanh(u_j)^2)]` (Appendix C, Eq. (21)); the
//! second term is computed as `2 (log 2 - u - softplus(-2u))`, exact and stable for large `|u|`.
//! Acting samples; evaluation and a shipped policy act with `tanh(m)`.
//!
//! # The update, top to bottom
//!
//! The batch holds `N` windows as for RDPG (`update.rs`): `len_n <= l` real optimisation steps,
//! the tail observation `o_tail`, a scan part before the window. `alpha = exp(log alpha)` is
//! read once, at the start: the targets and the actor loss use the same value.
//!
//! 1. **Scan**: `h_{-1}` of the actor (from zeros or the stored acting-time state), of each
//!    critic and of each target critic, no gradient (paper Eq. (scan)). There is no target
//!    actor.
//! 2. **Critic** (soft Bellman residual, Eq. (5), with RDPG's tail-step bootstrap): the actor
//!    runs along the window from its scanned state (no gradient) and samples
//!    `a_tail ~ pi(. | o_tail, h_{len-1})`; then
//!    `y_i = sum_{k=i}^{len-1} gamma^{k-i} r_k
//!           + gamma^{len-i} (min_j Q'_j(o_tail, a_tail) - alpha log pi(a_tail | o_tail)) (1 - term)`:
//!    the entropy term enters **at the bootstrap only**, as the soft value
//!    `V(o_tail) = E[Q(o_tail, a) - alpha log pi(a | o_tail)]` (Eq. (3)) of one sample; the
//!    rewards along the window are the replayed ones, whose actions the behaviour policy chose
//!    (with `l = 1` this is the paper's target exactly). Loss and weights as RDPG's:
//!    `sum_j 1/N sum_n sum_{i < min(u, len_n)} w_i (y_i - Q_j(o_i, a_i | h_{i-1}))^2`, the
//!    critics back-propagated through the window; Adam (with L2), then the actor reads them.
//!    With `sac.tqc` the critics output atoms and the target is TQC's truncated mixture, the
//!    loss the quantile Huber loss (`tqc.rs`).
//! 3. **Actor** (Eqs. (7) and (9)):
//!    `J_pi = 1/N sum_n sum_{i < len_n} v_{n,i} [alpha log pi(a~_i | o_i) - min_j Q_j(o_i, a~_i | h^C_{i-1})]`,
//!    `v` RDPG's actor weights (`actor_weights`: `1/len_n` by default, or `1/l`),
//!    `a~_i` a fresh reparameterised sample at every step; without BPTT (the default) the
//!    actor's state before each step is a constant, as for RDPG. Adam. With `sac.tqc` the
//!    mean over critics (of their atoms' means) replaces the min.
//! 4. **Temperature** (Eq. (18), in `log alpha` as the authors' softlearning code steps it):
//!    `J(log alpha) = -log alpha * 1/N sum_n sum_i v_{n,i} (log pi(a~_i | o_i) + H_target)`, the
//!    log-probabilities of step 3 held constant; Adam. Skipped when `learn_alpha = false`.
//! 5. **Targets**: `theta'_j <- theta'_j + tau (theta_j - theta'_j)` for the critics.
//!
//! Noise: `eps` for `a_tail` (`[N, A]`) then for the actor's samples (`[N * l, A]`), drawn in
//! that order from the agent's own generator (`NpRng::standard_normal`), so checkpoints resume
//! identically and a reference can replay the update (the golden test against PyTorch).
//! Window-of-k agents (`act_window`) sample `a_tail` from the tail's own re-encoded window, as
//! they act.

use std::collections::BTreeMap;
use std::time::Instant;

use rdpg_core::SequenceBatch;
use tch::Tensor;

use super::agent::RdpgAgent;
use super::config::ScanMethod;
use super::lstm::{scan_state, RecState};
use super::nets::{Actor, Critic};
use super::prepared::Prepared;
use super::profile::Clock;
use super::tqc::{combine_critics, quantile_huber_loss, trained_atoms, truncated_targets};
use super::update::{
    critic_loss_from, critic_states, min_all, scan_actor, scan_critic, soft_update, target_atoms,
    td_targets, trained_q, ActorInput, Scanned,
};
use crate::common::UpdateStats;

impl RdpgAgent {
    /// One SAC update on `batch` (the batch already checked). See the module docs.
    pub(super) fn update_sac(&mut self, batch: &SequenceBatch) -> UpdateStats {
        let started = Instant::now();
        let mut clock = Clock::new(self.profile.is_some());
        let p = self.prepare(batch);
        let alpha = self.temperature().alpha();
        clock.lap(|t| &mut t.prepare);

        // ---- 1. Scan: h_{-1} of the actor, the critics and the target critics. ------------
        let method = self.cfg.scan_method;
        let actor_init = self.actor_init(&p);
        let sc = Scanned {
            actor: Some(self.history_grad(|| scan_actor(&self.actor, &p, &actor_init, method))),
            critics: self
                .critics
                .iter()
                .map(|c| self.history_grad(|| scan_critic(c, &p, method)))
                .collect(),
            target_actor: None,
            target_critics: tch::no_grad(|| {
                self.targets.as_ref().map_or_else(Vec::new, |t| {
                    t.critics
                        .iter()
                        .map(|c| super::update::scan_target_critic(c, &p, method))
                        .collect()
                })
            }),
        };
        clock.lap(|t| &mut t.scan);

        // ---- 2. Critics: the soft tail-step bootstrap (Eq. (5), (3)) and their Adam step. ----
        let need_states = self.actor_states_detached();
        let (actor_states, x_tail, y_tail) = tch::no_grad(|| self.actor_along_window(&p, &sc));
        let eps_tail = self.standard_normal(&[p.n, self.act_dim as i64]); // [N, A]
        let (a_tail, logp_tail) = tch::no_grad(|| {
            let (m, log_s) = self.actor.gaussian(&x_tail, &y_tail);
            squashed_sample(&m, &log_s, &eps_tail) // [N, A], [N]
        });
        let tqc = self.cfg.sac.as_ref().and_then(|s| s.tqc.clone());
        // Each target critic's output at (o_tail, a_tail): [N, M] (M = 1 without TQC).
        let tail_atoms: Vec<Tensor> = tch::no_grad(|| {
            let t = self.targets.as_ref();
            t.map(|t| &t.critics)
                .into_iter()
                .flatten()
                .zip(&sc.target_critics)
                .map(|(c, h)| target_atoms(c, &p, h, &a_tail))
                .collect()
        });
        let (critic_loss, q_sa) = match &tqc {
            None => {
                let qs: Vec<Tensor> = tail_atoms.iter().map(Critic::value).collect(); // [N]
                let v_tail = min_all(&qs) - &logp_tail * alpha; // [N]
                let y = tch::no_grad(|| td_targets(&p, &v_tail)); // [N, l]
                clock.lap(|t| &mut t.window_nograd);
                let q_sa: Vec<Tensor> = self
                    .critics
                    .iter()
                    .zip(&sc.critics)
                    .map(|(c, h)| trained_q(c, &p, h)) // [N, u] each
                    .collect();
                let loss: Tensor = q_sa.iter().map(|q| critic_loss_from(&p, q, &y)).sum();
                (loss, q_sa)
            }
            Some(t) => {
                // TQC (tqc.rs): the pooled atoms truncated, the quantile Huber loss.
                let y = tch::no_grad(|| {
                    truncated_targets(&p, &tail_atoms, &logp_tail, alpha, t.drop_per_critic)
                }); // [N, l, K]
                clock.lap(|t| &mut t.window_nograd);
                let z_sa: Vec<Tensor> = self
                    .critics
                    .iter()
                    .zip(&sc.critics)
                    .map(|(c, h)| trained_atoms(c, &p, h)) // [N, u, M] each
                    .collect();
                let loss: Tensor = z_sa.iter().map(|z| quantile_huber_loss(&p, z, &y)).sum();
                (loss, z_sa.iter().map(Critic::value).collect())
            }
        };
        self.critic_opt.zero_grad();
        critic_loss.backward();
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.critic_opt.clip_grad_norm(c);
        }
        self.critic_opt.step();
        self.updates += 1;
        clock.lap(|t| &mut t.critic_step);

        // ---- 3. Actor: J_pi = E[alpha log pi(a~|o) - min_j Q_j(o, a~)] (Eq. (9)). ---------
        // The critics' states along the window after their step, each [N, l, Hc].
        let critic_states: Vec<(Tensor, Tensor)> = tch::no_grad(|| {
            self.critics
                .iter()
                .map(|c| critic_states(c, &p, &scan_critic(c, &p, method)))
                .collect()
        });
        clock.lap(|t| &mut t.critic_rescan);
        let input = match &actor_states {
            Some((h, c)) if need_states => ActorInput::Detached { h, c },
            _ => ActorInput::Bptt { h0: sc.actor() },
        };
        let eps = self.standard_normal(&[p.n * p.l, self.act_dim as i64]); // [N*l, A]
        for vs in &mut self.critic_vs {
            vs.freeze();
        }
        let (actor_loss, logp) =
            soft_actor_loss(self, &p, input, &critic_states, &eps, alpha, tqc.is_some());
        self.actor_opt.zero_grad();
        actor_loss.backward();
        for vs in &mut self.critic_vs {
            vs.unfreeze();
        }
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.actor_opt.clip_grad_norm(c);
        }
        self.actor_opt.step();
        clock.lap(|t| &mut t.actor_step);

        // ---- 4. Temperature: J(log alpha) = -log alpha E[log pi + H_target] (Eq. (18)). -----
        let logp = logp.detach().reshape([p.n, p.l]); // [N, l]
        let mean_logp = tch::no_grad(|| (&logp * &p.actor_w).sum(self.kind) / p.n as f64);
        let t = self.temperature_mut();
        if t.learn {
            let j = -(&t.log_alpha * (&mean_logp + t.target_entropy)).sum(logp.kind());
            t.opt.zero_grad();
            j.backward();
            t.opt.step();
        }

        // ---- 5. Soft target update of the critics. ----------------------------------------
        if let Some(t) = &mut self.targets {
            soft_update(&mut t.pairs, self.cfg.tau);
        }

        let mask = p.mask.narrow(1, 0, p.u);
        let q_mean = tch::no_grad(|| (&q_sa[0] * &mask).sum(self.kind) / mask.sum(self.kind));
        let extra = BTreeMap::from([
            ("alpha".to_string(), alpha),
            ("entropy".to_string(), -mean_logp.double_value(&[])),
        ]);
        let stats = UpdateStats {
            critic_loss: critic_loss.double_value(&[]),
            q_mean: q_mean.double_value(&[]),
            injected_share: batch.injected.iter().map(|&x| f64::from(x)).sum::<f64>()
                / batch.n as f64,
            seconds: started.elapsed().as_secs_f64(),
            actor_loss: Some(actor_loss.double_value(&[])),
            extra,
        };
        clock.lap(|t| &mut t.other);
        clock.finish(&mut self.profile);
        stats
    }

    /// Step 2's actor run along the window (call without gradient) from its scanned state:
    /// its states before each optimisation step (`[N, l, H]` each; for the per-step actor
    /// loss, i.e. a recurrent actor without BPTT) and the core's input and output at each
    /// window's tail, `[N, E]` and `[N, H]` (a window-of-k agent re-encodes the `k - 1` steps
    /// before the tail from zeros, as it acts).
    pub(super) fn actor_along_window(
        &self,
        p: &Prepared,
        sc: &Scanned,
    ) -> (Option<(Tensor, Tensor)>, Tensor, Tensor) {
        let actor = &self.actor;
        let need_states = self.actor_states_detached();
        let xa = actor.input_seq(&p.obs_win); // [N, l+1, E]
        let (ya, states) = if need_states {
            let (ya, hb, cb, _) = actor.core.stepwise(&xa, sc.actor());
            (ya, Some((hb.narrow(1, 0, p.l), cb.narrow(1, 0, p.l))))
        } else {
            (actor.core.seq(&xa, sc.actor()).0, None)
        };
        let (x_tail, y_tail) = match &p.window_tail {
            Some(w) => {
                let h0 = actor.core.zero_state(p.n, self.kind, self.device);
                let h = scan_state(
                    &actor.core,
                    &actor.input_seq(&w.obs),
                    &w.len,
                    &h0,
                    ScanMethod::Grouped,
                );
                let (x, y, _) = actor.features(&super::update::tail_obs(p), &h);
                (x, y)
            }
            None => {
                let at_tail = |t: &Tensor| {
                    (t * p.tail_onehot.unsqueeze(-1)).sum_dim_intlist(1, false, self.kind)
                };
                (at_tail(&xa), at_tail(&ya))
            }
        };
        (states, x_tail, y_tail)
    }

    /// Standard normal draws of the agent's generator in a tensor of this `shape`.
    fn standard_normal(&mut self, shape: &[i64]) -> Tensor {
        let n: i64 = shape.iter().product();
        let v: Vec<f64> = (0..n).map(|_| self.rng.standard_normal()).collect();
        Tensor::from_slice(&v)
            .view(shape)
            .to_kind(self.kind)
            .to_device(self.device)
    }

    #[allow(clippy::expect_used, reason = "update_sac runs for SAC agents only")]
    fn temperature(&self) -> &super::agent::Temperature {
        self.sac.as_ref().expect("a SAC agent")
    }

    #[allow(clippy::expect_used, reason = "update_sac runs for SAC agents only")]
    fn temperature_mut(&mut self) -> &mut super::agent::Temperature {
        self.sac.as_mut().expect("a SAC agent")
    }
}

/// A reparameterised squashed-Gaussian sample and its log-probability (Eq. (21)):
/// `m`, `log_s`, `eps` `[B, A]` -> (`a = tanh(m + s eps)` `[B, A]`, `log pi(a)` `[B]`).
pub(super) fn squashed_sample(m: &Tensor, log_s: &Tensor, eps: &Tensor) -> (Tensor, Tensor) {
    let u = m + log_s.exp() * eps;
    // log N(u; m, s^2) = -eps^2 / 2 - log s - log(2 pi) / 2, per component.
    let log_normal = eps.square() * -0.5 - log_s - 0.5 * (2.0 * std::f64::consts::PI).ln();
    // log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)).
    let log_det = ((-&u - (&u * -2.0).softplus()) + std::f64::consts::LN_2) * 2.0;
    let logp = (log_normal - log_det).sum_dim_intlist(-1, false, u.kind());
    (u.tanh(), logp)
}

/// Step 3's loss `1/N sum_n sum_i w_{n,i} [alpha log pi(a~_i) - min_j Q_j(o_i, a~_i |
/// h^C_{i-1})]` (`w = actor_w`: `1/len_n` or `1/l` on real steps, by `actor_weights`) with gradient into the actor, and the
/// log-probabilities `[N*l]`. `critic_states[j]` are critic `j`'s `(h_{i-1}, c_{i-1})`,
/// `[N, l, Hc]`; `eps` is `[N*l, A]`.
pub(super) fn soft_actor_loss(
    agent: &RdpgAgent,
    p: &Prepared,
    input: ActorInput<'_>,
    critic_states: &[(Tensor, Tensor)],
    eps: &Tensor,
    alpha: f64,
    tqc: bool,
) -> (Tensor, Tensor) {
    let (n, l) = (p.n, p.l);
    let actor: &Actor = &agent.actor;
    let obs = p.obs_win.narrow(1, 0, l); // [N, l, D]
    let d = obs.size()[2];
    let obs_flat = obs.reshape([n * l, d]); // [N*l, D]
    let (x, y) = match input {
        ActorInput::Detached { h, c } => {
            // Every step from its own (constant) previous state: one cell step over N*l rows.
            let ha = h.size()[2];
            let st = RecState {
                h: h.reshape([1, n * l, ha]),
                c: c.reshape([1, n * l, ha]),
            };
            let (x, y, _) = actor.features(&obs_flat, &st); // [N*l, E], [N*l, H]
            (x, y)
        }
        ActorInput::Bptt { h0 } => {
            let x = actor.input_seq(&obs); // [N, l, E]
            let (y, _) = actor.core.seq(&x, h0); // [N, l, H]
            let (e, h) = (x.size()[2], y.size()[2]);
            (x.reshape([n * l, e]), y.reshape([n * l, h]))
        }
    };
    let (m, log_s) = actor.gaussian(&x, &y); // [N*l, A] each
    let (a, logp) = squashed_sample(&m, &log_s, eps); // [N*l, A], [N*l]
    let qs: Vec<Tensor> = agent
        .critics
        .iter()
        .zip(critic_states)
        .map(|(critic, (hc, cc))| {
            let w = hc.size()[2];
            let st = RecState {
                h: hc.reshape([1, n * l, w]),
                c: cc.reshape([1, n * l, w]),
            };
            critic.step(&obs_flat, &a, &st).0 // [N*l]
        })
        .collect();
    let per_step = (&logp * alpha - combine_critics(&qs, tqc)).reshape([n, l]); // [N, l]
    let loss = (per_step * &p.actor_w).sum(a.kind()) / n as f64;
    (loss, logp)
}
