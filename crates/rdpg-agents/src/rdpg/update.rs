//! The update of Algorithm 1 (`Update`), top to bottom.
//!
//! # The update, top to bottom
//!
//! A [`SequenceBatch`] holds `N` windows; window `n` has `scan_len[n] <= s` real scan steps
//! (left-padded), `len_n = opt_len[n] <= l` real optimisation steps (right-padded) and the
//! bootstrap ("tail") observation `o_tail` right after its last real step.
//!
//! 1. **Scan** (paper Eq. (scan)): `h_{-1} = f((o_t, a_t)_{t = -scan_len..-1} | h_init)` for the
//!    actor (observations) and the critic (observation-action pairs), without gradient, from
//!    `h_init = 0` (or the acting-time state stored in the replay, actor only). Padding never
//!    touches the state ([`scan_state`]).
//! 2. **Critic** (paper Eq. (unsyncedinterpolatedTD), Algorithm 1 line "Get TD gradient"): the
//!    tail-step bootstrap
//!    `y_i = sum_{k=i}^{len-1} gamma^{k-i} r_k + gamma^{len-i} Q'(o_tail, mu'(o_tail)) (1 - term)`,
//!    i.e. every step bootstraps from the single Q at the window's tail (`^{(l-i)}TD_i`);
//!    `Q'`, `mu'` are the target networks when `tau > 0`, else the behaviour networks without
//!    gradient; both run along the window from their scanned states. Loss:
//!    `1/N sum_n sum_{i < min(u, len_n)} w_i (y_i - Q(o_i, a_i | h_{i-1}))^2` with
//!    `w_i = lambda^i / sum_{j<u} lambda^j` (uniform for `lambda = 1`; the same for every
//!    window, not renormalised for short windows: `rdpg_core::targets`); the critic is
//!    back-propagated through time over the window (the "optimisation length"). Adam with L2.
//! 3. **Actor** (paper Eq. (DPG), Algorithm 1 line "Get Actor gradient"):
//!    `J = -1/N sum_n 1/len_n sum_{i < len_n} Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})`. Without
//!    BPTT (paper Section III-A.3, the default) the actor state `h^A_{i-1}` fed to step `i` is a
//!    constant: the actor is run along the window without gradient to get the states, then every
//!    step is recomputed from its detached previous state in one batched call over `N * l`.
//!    The critic states `h^C_{i-1}` come from the critic's scan and its run along the replayed
//!    actions (after the critic's Adam step by default, as Algorithm 1 orders it).
//! 4. **Targets**: `theta' <- theta' + tau (theta - theta')` when `tau > 0`.
//!
//! With `fork` (feed-forward agents) FORK's dynamics and reward models take one step each
//! after the critic's, and on the actor's turn the actor loss of step 3 gains FORK's
//! forward-looking term while the dynamics model is accurate enough (`fork.rs`).
//!
//! `critic_target = "per_step_td0"` replaces step 2's targets with the classic RDPG's (Heess
//! et al. 2015, the paper's Table I baseline): per-step TD(0),
//! `y_i = r_i + gamma Q'(o_{i+1}, mu'(o_{i+1}) | h'_i) (1 - term_i)`, each step bootstrapping
//! from the next one along the window (`RdpgAgent::per_step_targets`).
//!
//! With `policy_delay = d > 1` (TD3) steps 3 and 4 run on every `d`-th update only; the
//! critic steps every time.
//!
//! With `parallel_twins` steps 1 and 2 run the second critic's share (its scan and its
//! target's, the target actor's scan, the behaviour actor's states, target critic 1's value,
//! critic 1's forward and backward pass) on a second thread, with the same arithmetic
//! (`twin_critic_gradients`), and critic 1's Adam step and its target's soft update run there
//! while this thread takes critic 0's step and the actor's: the result is bit-identical.

use std::time::Instant;

use rdpg_core::targets::interpolated_td_weights_padded;
use rdpg_core::SequenceBatch;
use serde::{Deserialize, Serialize};
use tch::Tensor;

use super::agent::RdpgAgent;
use super::config::{CriticTarget, ScanMethod};
use super::lstm::{scan_state, RecState};
use super::nets::{Actor, Critic};
use crate::common::side_thread::SideThread;
use crate::common::UpdateStats;

/// Wall-clock seconds spent in each phase of the updates since profiling was switched on
/// (meaningful on the CPU, where libtorch runs synchronously).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PhaseTimes {
    /// Updates measured.
    pub updates: u64,
    /// Batch upload and index tensors.
    pub prepare: f64,
    /// The no-gradient scans of step 1 (all networks, target networks included).
    pub scan: f64,
    /// No-gradient runs along the window: tail action, actor states, target critics.
    pub window_nograd: f64,
    /// Critic forward with gradient, backward, clipping and Adam step.
    pub critic_step: f64,
    /// FORK's model steps (0 without FORK).
    #[serde(default)]
    pub models: f64,
    /// The critic rescan and state run after its step (`actor_uses_updated_critic`).
    pub critic_rescan: f64,
    /// Actor forward, backward and Adam step.
    pub actor_step: f64,
    /// Soft target update and statistics.
    pub other: f64,
}

impl PhaseTimes {
    /// Adds `o`'s updates and phase times to these.
    pub fn add(&mut self, o: &PhaseTimes) {
        self.updates += o.updates;
        self.prepare += o.prepare;
        self.scan += o.scan;
        self.window_nograd += o.window_nograd;
        self.critic_step += o.critic_step;
        self.models += o.models;
        self.critic_rescan += o.critic_rescan;
        self.actor_step += o.actor_step;
        self.other += o.other;
    }

    /// Seconds in all phases together.
    pub fn total(&self) -> f64 {
        self.prepare
            + self.scan
            + self.window_nograd
            + self.critic_step
            + self.models
            + self.critic_rescan
            + self.actor_step
            + self.other
    }
}

impl RdpgAgent {
    /// Switches per-phase timing on (resetting it) or off.
    pub fn set_profiling(&mut self, on: bool) {
        self.profile = on.then(PhaseTimes::default);
    }

    /// The per-phase timings accumulated since profiling was switched on.
    pub fn profile(&self) -> Option<PhaseTimes> {
        self.profile
    }

    /// One RDPG update (Algorithm 1, `Update`) on `batch`. See the module docs for the steps.
    ///
    /// # Panics
    /// If the batch does not fit the agent ([`RdpgAgent::check_batch`] fails).
    pub fn update(&mut self, batch: &SequenceBatch) -> UpdateStats {
        if let Err(e) = self.check_batch(batch) {
            panic!("RdpgAgent::update: {e}");
        }
        if self.cfg.flush_denormal {
            crate::common::tensor::set_flush_denormal(true);
        }
        let started = std::time::Instant::now();
        let mut clock = Clock::new(self.profile.is_some());
        let p = self.prepare(batch);
        // The second thread of `parallel_twins`, kept for the agent's life.
        let mut side = self
            .cfg
            .parallel_twins
            .then(|| self.side.take().unwrap_or_default());
        // FORK with `parallel_twins`: its models take their step on the second thread while
        // this one runs both critics (the one-thread path of step 2, bit-identical to the
        // split); without the second thread they step here after the critics.
        let models_on_side = match (&mut side, self.fork.take()) {
            (Some(side), Some(mut f)) => {
                let p1 = p.shallow_clone();
                side.start(self.cfg.flush_denormal, move || {
                    let step = f.train(&p1);
                    (f, step)
                });
                true
            }
            (_, f) => {
                self.fork = f;
                false
            }
        };
        clock.lap(|t| &mut t.prepare);

        // ---- 1. Scan: h_{-1} for every network, no gradient (paper Eq. (scan)). -------------
        let sc = match &mut side {
            Some(side) if !models_on_side => self.scan_all_parallel(&p, side),
            _ => self.scan_all(&p),
        };
        clock.lap(|t| &mut t.scan);

        // ---- 2. Critic: q along the window (with gradient) and its targets (without). -------
        let twin_side = side.as_mut().filter(|_| !models_on_side);
        let (q0, critic_loss, actor_states) = if let Some(side) = twin_side {
            self.twin_critic_gradients(&p, &sc, side, &mut clock)
        } else {
            let (q_sa, y, actor_states) = self.critic_objective(&p, &sc, &mut clock);
            let critic_loss = q_sa
                .iter()
                .map(|q| critic_loss_from(&p, q, &y))
                .reduce(|a, b| a + b)
                .expect("at least one critic");
            self.critic_opt.zero_grad();
            critic_loss.backward();
            (q_sa[0].detach(), critic_loss, actor_states)
        };
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.critic_opt.clip_grad_norm(c);
        }
        // TD3's delayed policy update: the actor and the target networks move on every
        // `policy_delay`-th update only (every update for the paper's RDPG, delay 1).
        self.updates += 1;
        let actor_turn = self.updates.is_multiple_of(self.cfg.policy_delay as u64);
        let updated_critic = self.cfg.actor_uses_updated_critic || !actor_turn;
        // Critic states h^C_{i-1} along the window for the actor loss: from the pre-update
        // critic, or (Algorithm 1 order) rescanned after its Adam step.
        let critic_states_old =
            (!updated_critic).then(|| tch::no_grad(|| self.critic_states(&p, &sc.critics[0])));
        let side_model_step = models_on_side.then(|| {
            let side = side.as_mut().expect("started with the models' step");
            let (f, step) = side.finish::<(super::fork::ForkModels, super::fork::ModelStep)>();
            self.fork = Some(f);
            step
        });
        // Adam for the critics: one step, taken now or after the actor's backward pass. With
        // `parallel_twins` critic 1's share (and on the actor's turn its target's soft update)
        // runs on the second thread until the end of the update: nothing below reads critic 1.
        let critic_step = self.critic_opt.begin_step();
        let n_critic = self.critic_opt.params().len();
        let (own, side_targets) = match &mut side {
            Some(side) => {
                let split = self.critic0_params;
                let mut part = self.critic_opt.part(split..n_critic);
                let t = self.targets.as_ref().expect("validated: target networks");
                let k = t.pairs.len() - (n_critic - split); // critic 1's target pairs are last
                let mut pairs: Vec<(Tensor, Tensor)> = t.pairs[k..]
                    .iter()
                    .map(|(a, b)| (a.shallow_clone(), b.shallow_clone()))
                    .collect();
                let tau = self.cfg.tau;
                side.start(self.cfg.flush_denormal, move || {
                    part.apply(&critic_step);
                    if actor_turn {
                        soft_update(&mut pairs, tau);
                    }
                });
                (0..split, k)
            }
            None => (
                0..n_critic,
                self.targets.as_ref().map_or(0, |t| t.pairs.len()),
            ),
        };
        if updated_critic {
            self.critic_opt.apply(&critic_step, own.clone());
        }
        clock.lap(|t| &mut t.critic_step);

        // ---- FORK's models: one step each on this batch (`fork.rs`). -------------------------
        let model_step = match side_model_step {
            Some(step) => Some(step),
            None => self.fork.as_mut().map(|f| f.train(&p)),
        };
        clock.lap(|t| &mut t.models);

        // ---- 3. Actor: deterministic policy gradient (Eq. (DPG)), no BPTT by default. ------
        let mut actor_loss_value = None;
        if actor_turn {
            let critic_states = match critic_states_old {
                Some(s) => s,
                None => tch::no_grad(|| {
                    let h = scan_critic(&self.critics[0], &p, self.cfg.scan_method);
                    self.critic_states(&p, &h)
                }),
            };
            clock.lap(|t| &mut t.critic_rescan);
            let actor_in = match &actor_states {
                Some((hb, cb)) => ActorInput::Detached { h: hb, c: cb },
                None => ActorInput::Bptt { h0: &sc.actor },
            };
            // Critic 0 is a constant here: no gradients are computed or accumulated for it
            // (the only critic the actor loss reads).
            self.critic_vs[0].freeze();
            let (mut loss, a0) =
                actor_loss(&self.actor, &self.critics[0], &p, actor_in, &critic_states);
            // FORK: + w J_fork while the dynamics model is accurate enough (from the same
            // actions mu(o_i), [N*l, A]).
            if let (Some(f), Some(m)) = (&mut self.fork, &model_step) {
                if m.use_term {
                    let w = f.cfg.weight;
                    let j = f.actor_term(&self.actor, &self.critics[0], &p, &a0, self.cfg.gamma);
                    loss += j * w;
                }
            }
            self.actor_opt.zero_grad();
            loss.backward();
            self.critic_vs[0].unfreeze();
            if let Some(c) = self.cfg.grad_clip {
                let _ = self.actor_opt.clip_grad_norm(c);
            }
            if !updated_critic {
                self.critic_opt.apply(&critic_step, own);
            }
            self.actor_opt.step();
            actor_loss_value = Some(loss.double_value(&[]));
            clock.lap(|t| &mut t.actor_step);

            // ---- 4. Soft target update theta' <- theta' + tau (theta - theta'). -----------
            // (Critic 1's target on the second thread with `parallel_twins`.)
            if let Some(t) = &mut self.targets {
                soft_update(&mut t.pairs[..side_targets], self.cfg.tau);
            }
        }
        if let Some(mut side) = side {
            side.finish::<()>();
            self.side = Some(side);
        }
        let q_mean = tch::no_grad(|| (&q0 * &p.mask).sum(self.kind) / p.mask.sum(self.kind));
        let stats = UpdateStats {
            critic_loss: critic_loss.double_value(&[]),
            actor_loss: actor_loss_value,
            q_mean: q_mean.double_value(&[]),
            injected_share: batch.injected.iter().map(|&x| f64::from(x)).sum::<f64>()
                / batch.n as f64,
            seconds: started.elapsed().as_secs_f64(),
            model_loss: model_step.as_ref().map(|m| m.dynamics_loss),
            fork_term: model_step.filter(|_| actor_turn).map(|m| m.use_term),
        };
        clock.lap(|t| &mut t.other);
        if let Some(pt) = &mut self.profile {
            clock.add_into(pt);
            pt.updates += 1;
        }
        stats
    }

    /// Step 2 of the update: `Q(o_i, a_i | h_{i-1})` of every critic along the window, with
    /// gradient (`[N, l]` each), and their targets `y` (`[N, l]`) and the actor's states along
    /// the window (per-step actor gradient), both without gradient:
    ///
    /// 2a. the behaviour actor along the window from its scanned state gives its states and the
    ///     bootstrap action `mu'(o_tail)` (+ TD3 smoothing noise); with target networks also
    ///     `Q'(o_tail, mu'(o_tail))`;
    /// 2b. the tail-step bootstrap of the interpolated TD (Eq. (unsyncedinterpolatedTD)), or
    ///     the classic RDPG's per-step TD(0) (Heess et al. 2015).
    pub(super) fn critic_objective(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        clock: &mut Clock,
    ) -> (Vec<Tensor>, Tensor, Option<(Tensor, Tensor)>) {
        let (actor_states, mut a_tail) = tch::no_grad(|| self.actor_window(p, sc));
        if let Some(noise) = self.cfg.target_noise {
            a_tail = self.smooth_target_action(&a_tail, noise.std, noise.clip);
        }
        let target_q_tail = tch::no_grad(|| self.target_tail_q(p, sc, &a_tail));
        clock.lap(|t| &mut t.window_nograd);
        let (q_sa, y) = match self.cfg.critic_target {
            CriticTarget::TailBootstrap => {
                let (q_sa, q_tail) = self.critic_forward(p, sc, &a_tail, target_q_tail);
                (q_sa, tch::no_grad(|| td_targets(p, &q_tail))) // [N, l]
            }
            CriticTarget::PerStepTd0 => {
                let y = tch::no_grad(|| self.per_step_targets(p, sc)); // [N, l]
                let q_sa = self
                    .critics
                    .iter()
                    .zip(&sc.critics)
                    .map(|(c, h)| critic_window(c, p, h, None))
                    .collect();
                (q_sa, y)
            }
        };
        (q_sa, y, actor_states)
    }

    /// Step 2a (call without gradient): runs the behaviour actor along the window (`l + 1`
    /// slots) from its scanned state. Returns its states before each optimisation step
    /// (`[N, l, H]` each; only when the actor gradient is per step, i.e. no BPTT) and the
    /// bootstrap action `mu'(o_tail)`, `[N, A]` (from the target actor when there is one).
    pub(super) fn actor_window(
        &self,
        p: &Prepared,
        sc: &Scanned,
    ) -> (Option<(Tensor, Tensor)>, Tensor) {
        let need_states = self.actor.core.is_recurrent() && !self.cfg.actor_bptt;
        if let (false, Some(t), Some(h)) = (
            self.actor.core.is_recurrent(),
            &self.targets,
            &sc.target_actor,
        ) {
            // Feed-forward with a target actor: the behaviour actor's run along the window
            // would serve nothing (no states to keep, the bootstrap comes from mu').
            return (None, tail_action(&t.actor, p, h));
        }
        let xa = self.actor.input_seq(&p.obs_win); // [N, l+1, E]
        let (ya, states) = if need_states {
            let (ya, hb, cb, _) = self.actor.core.stepwise(&xa, &sc.actor);
            (ya, Some((hb.narrow(1, 0, p.l), cb.narrow(1, 0, p.l))))
        } else {
            (self.actor.core.seq(&xa, &sc.actor).0, None)
        };
        let a_tail = match (&self.targets, &sc.target_actor) {
            (Some(t), Some(h)) => tail_action(&t.actor, p, h),
            // The output at the tail slot `len_n` is mu(o_tail | h_{len-1}).
            _ => (self.actor.head(&ya) * p.tail_onehot.unsqueeze(-1))
                .sum_dim_intlist(1, false, self.kind),
        };
        (states, a_tail)
    }

    /// With target networks (`tau > 0`): `Q'(o_tail, a_tail)` from the target critics' own
    /// scans and window runs, the minimum over twin critics, `[N]`; `None` without targets.
    pub(super) fn target_tail_q(
        &self,
        p: &Prepared,
        sc: &Scanned,
        a_tail: &Tensor,
    ) -> Option<Tensor> {
        self.targets.as_ref().map(|t| {
            let qs: Vec<Tensor> = t
                .critics
                .iter()
                .zip(&sc.target_critics)
                .map(|(c, h)| target_q(c, p, h, a_tail))
                .collect();
            min_all(&qs)
        })
    }

    /// Step 2b's forward pass (with gradient): `Q(o_i, a_i | h_{i-1})` of every critic along
    /// the window, `[N, l]` each, and the bootstrap value `[N]`. Without target networks each
    /// critic's run continues one step into the tail slot with `a_tail`; that output,
    /// detached (minimum over twins), is the bootstrap.
    pub(super) fn critic_forward(
        &self,
        p: &Prepared,
        sc: &Scanned,
        a_tail: &Tensor,
        target_q_tail: Option<Tensor>,
    ) -> (Vec<Tensor>, Tensor) {
        let with_tail = target_q_tail.is_none();
        let qs: Vec<Tensor> = self
            .critics
            .iter()
            .zip(&sc.critics)
            .map(|(c, h)| critic_window(c, p, h, with_tail.then_some(a_tail)))
            .collect(); // each [N, l (+1)]
        let q_tail = match target_q_tail {
            Some(q) => q,
            None => min_all(&qs.iter().map(|q| tail_q(p, q).detach()).collect::<Vec<_>>()),
        };
        (qs.iter().map(|q| q.narrow(1, 0, p.l)).collect(), q_tail)
    }

    /// Step 2 with `parallel_twins` (tail-step bootstrap, target networks), with the same
    /// arithmetic as [`RdpgAgent::critic_objective`] followed by one backward pass of the
    /// summed loss, in three two-thread phases: the target actor's bootstrap action here and
    /// the behaviour actor's states along the window there; `Q'(o_tail, a_tail)` of target
    /// critic 0 here and 1 there; critic 0's TD loss and backward pass here and critic 1's
    /// there (the gradient of the summed loss is the pair of their gradients: the critics share
    /// no parameter). Zeroes the critics' gradients and back-propagates; returns critic 0's
    /// `Q(o_i, a_i | h_{i-1})` (`[N, l]`, detached), the summed TD loss and the actor's states.
    fn twin_critic_gradients(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        side: &mut SideThread,
        clock: &mut Clock,
    ) -> (Tensor, Tensor, Option<(Tensor, Tensor)>) {
        let ftz = self.cfg.flush_denormal;
        let need_states = self.actor.core.is_recurrent() && !self.cfg.actor_bptt;
        let (mut a_tail, actor_states) = {
            let t = self.targets.as_ref().expect("validated: target networks");
            let h = sc.target_actor.as_ref().expect("scanned with the targets");
            let main = || tch::no_grad(|| tail_action(&t.actor, p, h));
            if need_states {
                let (actor, p1, h1) = (
                    self.actor.shallow_clone(),
                    p.shallow_clone(),
                    sc.actor.shallow_clone(),
                );
                let states = move || tch::no_grad(|| actor_states(&actor, &p1, &h1));
                let (a_tail, states) = side.run(ftz, main, states);
                (a_tail, Some(states))
            } else {
                (main(), None)
            }
        };
        if let Some(noise) = self.cfg.target_noise {
            a_tail = self.smooth_target_action(&a_tail, noise.std, noise.clip);
        }
        let t = self.targets.as_ref().expect("validated: target networks");
        let (t1, p1, h1, a1) = (
            t.critics[1].shallow_clone(),
            p.shallow_clone(),
            sc.target_critics[1].shallow_clone(),
            a_tail.shallow_clone(),
        );
        let (q0_tail, q1_tail) = side.run(
            ftz,
            || tch::no_grad(|| target_q(&t.critics[0], p, &sc.target_critics[0], &a_tail)),
            move || tch::no_grad(|| target_q(&t1, &p1, &h1, &a1)),
        );
        let y = tch::no_grad(|| td_targets(p, &q0_tail.minimum(&q1_tail))); // [N, l]
        clock.lap(|t| &mut t.window_nograd);

        self.critic_opt.zero_grad();
        let (c1, p1, h1, y1) = (
            self.critics[1].shallow_clone(),
            p.shallow_clone(),
            sc.critics[1].shallow_clone(),
            y.shallow_clone(),
        );
        let ((q0, loss0), (_, loss1)) = side.run(
            ftz,
            || td_backward(&self.critics[0], p, &sc.critics[0], &y),
            move || td_backward(&c1, &p1, &h1, &y1),
        );
        (q0, loss0 + loss1, actor_states)
    }

    /// The classic RDPG's targets (Heess et al. 2015), per step (call without gradient):
    /// `y_i = r_i + gamma Q'(o_{i+1}, mu'(o_{i+1}) | h'_i) (1 - term_i)`, `[N, l]`, 0 on
    /// padding. `mu'` runs along the window from its scanned state (`l + 1` slots, the tail
    /// included); each target critic runs along the replayed actions, and from its state
    /// after step `i` takes one cell step on `(o_{i+1}, mu'(o_{i+1}))`; the minimum over twin
    /// critics. Only the last real step of a terminated episode has `term_i = 1`. `Q'`, `mu'`
    /// are the target networks when `tau > 0`, else the behaviour networks.
    pub(super) fn per_step_targets(&mut self, p: &Prepared, sc: &Scanned) -> Tensor {
        let (n, l) = (p.n, p.l);
        let (actor, actor_h) = match (&self.targets, &sc.target_actor) {
            (Some(t), Some(h)) => (&t.actor, h),
            _ => (&self.actor, &sc.actor),
        };
        let (mu, _) = actor.forward_seq(&p.obs_win, actor_h); // [N, l+1, A]
        let mut next_a = mu.narrow(1, 1, l); // mu'(o_{i+1}), [N, l, A]
        if let Some(noise) = self.cfg.target_noise {
            next_a = self.smooth_target_action(&next_a, noise.std, noise.clip);
        }
        let next_obs = p.obs_win.narrow(1, 1, l); // [N, l, D]
        let d = next_obs.size()[2];
        let a_dim = next_a.size()[2];
        let (critics, critic_h): (Vec<&Critic>, &[RecState]) = match &self.targets {
            Some(t) => (t.critics.iter().collect(), &sc.target_critics),
            None => (self.critics.iter().collect(), &sc.critics),
        };
        let qs: Vec<Tensor> = critics
            .iter()
            .zip(critic_h)
            .map(|(c, h)| {
                // States after each replayed step i = before slot i + 1: [N, l, H].
                let x = c.input_seq(&p.obs_win.narrow(1, 0, l), &p.act_win);
                let (_, hb, cb, fin) = c.core.stepwise(&x, h);
                let after = |before: &Tensor, last: &Tensor| {
                    Tensor::cat(&[before.narrow(1, 1, l - 1), last.transpose(0, 1)], 1)
                };
                let hc = hb.size()[2];
                let st = RecState {
                    h: after(&hb, &fin.h).reshape([1, n * l, hc]),
                    c: after(&cb, &fin.c).reshape([1, n * l, hc]),
                };
                let (q, _) = c.step(
                    &next_obs.reshape([n * l, d]),
                    &next_a.reshape([n * l, a_dim]),
                    &st,
                );
                q.reshape([n, l])
            })
            .collect();
        let q_next = min_all(&qs); // [N, l]
        (&p.rew + &q_next * &p.step_not_done * self.cfg.gamma) * &p.mask
    }

    /// Clipped Gaussian noise on the bootstrap action (target policy smoothing), drawn from the
    /// agent's own generator so that checkpoints resume identically.
    pub(super) fn smooth_target_action(&mut self, a: &Tensor, std: f64, clip: f64) -> Tensor {
        let n = a.numel();
        let noise: Vec<f32> = (0..n)
            .map(|_| (self.rng.normal(0.0, std)).clamp(-clip, clip) as f32)
            .collect();
        let noise = Tensor::from_slice(&noise)
            .view(a.size().as_slice())
            .to_kind(self.kind)
            .to_device(self.device);
        (a + noise).clamp(-1.0, 1.0)
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
                actor_w[i * ll + j] = 1.0 / len as f64;
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
                let h = self.actor.core.state_width();
                let t = up(st, &[n, 2 * h]);
                Some(RecState {
                    h: t.narrow(1, 0, h).unsqueeze(0).contiguous(),
                    c: t.narrow(1, h, h).unsqueeze(0).contiguous(),
                })
            }
            _ => None,
        };
        Prepared {
            n,
            s,
            l,
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

    /// Step 1 for every network, without gradient.
    pub(super) fn scan_all(&self, p: &Prepared) -> Scanned {
        let method = self.cfg.scan_method;
        let actor_init = self.actor_init(p);
        tch::no_grad(|| Scanned {
            actor: scan_actor(&self.actor, p, &actor_init, method),
            critics: self
                .critics
                .iter()
                .map(|c| scan_critic(c, p, method))
                .collect(),
            target_actor: self
                .targets
                .as_ref()
                .map(|t| scan_actor(&t.actor, p, &actor_init, method)),
            target_critics: self.targets.as_ref().map_or_else(Vec::new, |t| {
                t.critics
                    .iter()
                    .map(|c| scan_critic(c, p, method))
                    .collect()
            }),
        })
    }

    /// Step 1 with `parallel_twins`: actor, critic 0 and target critic 0 here; critic 1, its
    /// target and the target actor on a second thread (when there is a scan to run).
    fn scan_all_parallel(&self, p: &Prepared, side: &mut SideThread) -> Scanned {
        if p.s == 0 || !self.actor.core.is_recurrent() {
            return self.scan_all(p);
        }
        let method = self.cfg.scan_method;
        let t = self.targets.as_ref().expect("validated: target networks");
        let actor_init = self.actor_init(p);
        let (c1, t1, ta, p1, init1) = (
            self.critics[1].shallow_clone(),
            t.critics[1].shallow_clone(),
            t.actor.shallow_clone(),
            p.shallow_clone(),
            actor_init.shallow_clone(),
        );
        let ((actor, h0, th0), (h1, th1, h_ta)) = side.run(
            self.cfg.flush_denormal,
            || {
                tch::no_grad(|| {
                    (
                        scan_actor(&self.actor, p, &actor_init, method),
                        scan_critic(&self.critics[0], p, method),
                        scan_critic(&t.critics[0], p, method),
                    )
                })
            },
            move || {
                tch::no_grad(|| {
                    (
                        scan_critic(&c1, &p1, method),
                        scan_critic(&t1, &p1, method),
                        scan_actor(&ta, &p1, &init1, method),
                    )
                })
            },
        );
        Scanned {
            actor,
            critics: vec![h0, h1],
            target_actor: Some(h_ta),
            target_critics: vec![th0, th1],
        }
    }

    /// The actor scans' initial state: the stored acting-time state, or zeros.
    fn actor_init(&self, p: &Prepared) -> RecState {
        match &p.stored {
            Some(st) => st.shallow_clone(),
            None => self.actor.core.zero_state(p.n, self.kind, self.device),
        }
    }

    /// The critic's states before each optimisation step along the replayed actions
    /// (`h_{i-1}`, `c_{i-1}`, each `[N, l, H]`), from its scanned state (call without
    /// gradient).
    pub(super) fn critic_states(&self, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
        let critic = &self.critics[0];
        if !critic.core.is_recurrent() {
            // Zero-width states, `[N, l, 0]`: nothing to run.
            let z = h.h.new_zeros([p.n, p.l, 0], (self.kind, self.device));
            return (z.shallow_clone(), z);
        }
        let x = critic.input_seq(&p.obs_win.narrow(1, 0, p.l), &p.act_win);
        let (_, hb, cb, _) = critic.core.stepwise(&x, h);
        (hb, cb)
    }
}

/// The batch on the device, split into the scan part and the optimisation window.
pub(super) struct Prepared {
    pub(super) n: i64,
    pub(super) s: i64,
    pub(super) l: i64,
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
    /// `[N, l]`: `1 / len` on real steps.
    pub(super) actor_w: Tensor,
    pub(super) scan_len: Vec<usize>,
    /// Stored acting-time actor states `[1, N, H]` (when burning in from them).
    pub(super) stored: Option<RecState>,
}

impl Prepared {
    /// Second handles to the same tensors, for the second thread of `parallel_twins`.
    fn shallow_clone(&self) -> Self {
        Self {
            n: self.n,
            s: self.s,
            l: self.l,
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
        }
    }
}

/// `theta' <- theta' + tau (theta - theta')` for each (target, online) pair.
fn soft_update(pairs: &mut [(Tensor, Tensor)], tau: f64) {
    tch::no_grad(|| {
        for (tv, sv) in pairs {
            let _ = tv.lerp_(sv, tau);
        }
    });
}

/// `h_{-1}` of `actor` from `init` (call without gradient): its scan over the replayed
/// observations, or `init` when there is nothing to scan.
pub(super) fn scan_actor(
    actor: &Actor,
    p: &Prepared,
    init: &RecState,
    method: ScanMethod,
) -> RecState {
    if p.s == 0 || !actor.core.is_recurrent() {
        return init.shallow_clone();
    }
    let x = actor.input_seq(&p.obs_scan);
    scan_state(&actor.core, &x, &p.scan_len, init, method)
}

/// The recurrent actor's states before each optimisation step (`[N, l, H]` each), from its
/// scanned state `h` along the window (call without gradient).
fn actor_states(actor: &Actor, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
    let (_, hb, cb, _) = actor.core.stepwise(&actor.input_seq(&p.obs_win), h);
    (hb.narrow(1, 0, p.l), cb.narrow(1, 0, p.l))
}

/// `h_{-1}` of `critic` from zeros (call without gradient): its scan over the replayed
/// observation-action pairs, or the zero state when there is nothing to scan.
pub(super) fn scan_critic(critic: &Critic, p: &Prepared, method: ScanMethod) -> RecState {
    let init = critic
        .core
        .zero_state(p.n, p.obs_win.kind(), p.obs_win.device());
    if p.s == 0 || !critic.core.is_recurrent() {
        return init;
    }
    let x = critic.input_seq(&p.obs_scan, &p.act_scan);
    scan_state(&critic.core, &x, &p.scan_len, &init, method)
}

/// `Q'(o_tail, a_tail)` of target critic `c` from its scanned state `h`, `[N]` (call without
/// gradient): its run along the window with `a_tail` at the tail position, or for a
/// feed-forward critic one forward pass on the tail observation.
pub(super) fn target_q(c: &Critic, p: &Prepared, h: &RecState, a_tail: &Tensor) -> Tensor {
    if c.core.is_recurrent() {
        tail_q(p, &critic_window(c, p, h, Some(a_tail)))
    } else {
        c.step(&tail_obs(p), a_tail, h).0
    }
}

/// One critic's part of step 2b: `Q(o_i, a_i | h_{i-1})` along the window (`[N, l]`), its TD
/// loss against `y` and the loss's backward pass. Returns both detached.
fn td_backward(c: &Critic, p: &Prepared, h: &RecState, y: &Tensor) -> (Tensor, Tensor) {
    let q = critic_window(c, p, h, None);
    let loss = critic_loss_from(p, &q, y);
    loss.backward();
    (q.detach(), loss.detach())
}

/// `h_{-1}` of every network.
pub(super) struct Scanned {
    pub(super) actor: RecState,
    pub(super) critics: Vec<RecState>,
    pub(super) target_actor: Option<RecState>,
    pub(super) target_critics: Vec<RecState>,
}

/// The critic along the window from its scanned state: `Q(o_i, a_i | h_{i-1})` for the
/// replayed actions, `[N, l]`; with `a_tail`, one more slot where the tail position `len_n`
/// holds `Q(o_tail, a_tail | h_{len-1})`, `[N, l + 1]`.
pub(super) fn critic_window(
    critic: &Critic,
    p: &Prepared,
    h: &RecState,
    a_tail: Option<&Tensor>,
) -> Tensor {
    let (obs, act) = match a_tail {
        Some(at) => {
            let n = p.n;
            let a_dim = p.act_win.size()[2];
            let pad = Tensor::zeros([n, 1, a_dim], (p.act_win.kind(), p.act_win.device()));
            let ext = Tensor::cat(&[&p.act_win, &pad], 1); // [N, l+1, A], zero past len
            let oh = p.tail_onehot.unsqueeze(-1); // [N, l+1, 1]
            (
                p.obs_win.shallow_clone(),
                &ext * (1.0 - &oh) + at.unsqueeze(1) * oh,
            )
        }
        None => (p.obs_win.narrow(1, 0, p.l), p.act_win.shallow_clone()),
    };
    critic.forward_seq(&obs, &act, h).0
}

/// The value at each window's tail position: `q_ext [N, l + 1]` -> `[N]`.
pub(super) fn tail_q(p: &Prepared, q_ext: &Tensor) -> Tensor {
    (q_ext * &p.tail_onehot).sum_dim_intlist(1, false, q_ext.kind())
}

/// `mu'(o_tail)` of `actor` from its scanned state: `[N, A]`. A feed-forward actor acts on
/// the tail observation alone.
pub(super) fn tail_action(actor: &Actor, p: &Prepared, h: &RecState) -> Tensor {
    if !actor.core.is_recurrent() {
        return actor.step(&tail_obs(p), h).0;
    }
    let (mu, _) = actor.forward_seq(&p.obs_win, h); // [N, l+1, A]
    (mu * p.tail_onehot.unsqueeze(-1)).sum_dim_intlist(1, false, p.obs_win.kind())
}

/// Each window's tail observation `o_tail` (at position `len_n`): `[N, D]`.
pub(super) fn tail_obs(p: &Prepared) -> Tensor {
    (&p.obs_win * p.tail_onehot.unsqueeze(-1)).sum_dim_intlist(1, false, p.obs_win.kind())
}

/// Element-wise minimum of one or two tensors.
pub(super) fn min_all(ts: &[Tensor]) -> Tensor {
    let mut m = ts[0].shallow_clone();
    for t in &ts[1..] {
        m = m.minimum(t);
    }
    m
}

/// Tail-step bootstrap targets, `[N, l]`:
/// `y_i = sum_{k=i}^{len-1} gamma^{k-i} r_k + gamma^{len-i} q_tail (1 - term)` on real steps,
/// 0 on padding.
pub(super) fn td_targets(p: &Prepared, q_tail: &Tensor) -> Tensor {
    let returns = (&p.rew * &p.mask).matmul(&p.disc); // [N, l]
    returns + &p.boot_coef * (q_tail * &p.not_term).unsqueeze(1)
}

/// `1/N sum_n sum_i w_{n,i} (y_{n,i} - q_{n,i})^2` (paper Eq. (unsyncedinterpolatedTD)).
pub(super) fn critic_loss_from(p: &Prepared, q_sa: &Tensor, y: &Tensor) -> Tensor {
    (&p.critic_w * (y - q_sa).square()).sum(q_sa.kind()) / p.n as f64
}

/// Where the actor's recurrent input comes from in the actor loss.
pub(super) enum ActorInput<'a> {
    /// No BPTT: the states before each step (`[N, l, H]`), constants.
    Detached { h: &'a Tensor, c: &'a Tensor },
    /// BPTT: run the actor with gradient along the window from its scanned state.
    Bptt { h0: &'a RecState },
}

/// `-1/N sum_n 1/len_n sum_i Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})` (paper Eq. (DPG)),
/// and the actions `mu(o_i | h^A_{i-1})` it differentiates through, `[N*l, A]` (FORK's term
/// reuses them). `critic_states` are the critic's `(h_{i-1}, c_{i-1})`, `[N, l, Hc]`.
pub(super) fn actor_loss(
    actor: &Actor,
    critic: &Critic,
    p: &Prepared,
    input: ActorInput<'_>,
    critic_states: &(Tensor, Tensor),
) -> (Tensor, Tensor) {
    let (n, l) = (p.n, p.l);
    let obs = p.obs_win.narrow(1, 0, l); // [N, l, D]
    let d = obs.size()[2];
    let obs_flat = obs.reshape([n * l, d]); // [N*l, D]
    let a = match input {
        ActorInput::Detached { h, c } => {
            // Every step from its own (constant) previous state: one batched LSTM cell over
            // N*l rows.
            let ha = h.size()[2];
            let st = RecState {
                h: h.reshape([1, n * l, ha]),
                c: c.reshape([1, n * l, ha]),
            };
            let (y, _) = actor.core.step(&actor.trunk.forward(&obs_flat), &st);
            actor.head(&y) // [N*l, A]
        }
        ActorInput::Bptt { h0 } => {
            let (a, _) = actor.forward_seq(&obs, h0); // [N, l, A]
            let a_dim = a.size()[2];
            a.reshape([n * l, a_dim])
        }
    };
    // Q(o_i, a_i | h^C_{i-1}): one critic cell step per (window, step) from its carried state.
    let hc = critic_states.0.size()[2];
    let stc = RecState {
        h: critic_states.0.reshape([1, n * l, hc]),
        c: critic_states.1.reshape([1, n * l, hc]),
    };
    let (q, _) = critic.step(&obs_flat, &a, &stc); // [N*l]
    let loss = -(q.reshape([n, l]) * &p.actor_w).sum(a.kind()) / n as f64;
    (loss, a)
}

/// Per-phase stopwatch (no-op when profiling is off).
pub(super) struct Clock {
    on: bool,
    last: Instant,
    acc: PhaseTimes,
}

impl Clock {
    pub(super) fn new(on: bool) -> Self {
        Self {
            on,
            last: Instant::now(),
            acc: PhaseTimes::default(),
        }
    }

    fn lap(&mut self, field: impl FnOnce(&mut PhaseTimes) -> &mut f64) {
        if self.on {
            let now = Instant::now();
            *field(&mut self.acc) += (now - self.last).as_secs_f64();
            self.last = now;
        }
    }

    fn add_into(&self, t: &mut PhaseTimes) {
        t.add(&self.acc);
    }
}
