//! The update of `update.rs` on two threads (`parallel_twins`: twin critics, target
//! networks, tail-step bootstrap), bit-identical to the one-thread form.
//!
//! The schedule: the second thread (kept for the agent's life, `SideThread`) runs critic 1's
//! scan and its target's and, on the actor's turn, the target actor's scan (step 1; on the
//! other updates the behaviour actor is not scanned and the target actor is scanned here),
//! the behaviour actor's states (on the actor's turn),
//! target critic 1's tail value and critic 1's forward and backward pass (step 2), then
//! critic 1's Adam step and, on the actor's turn, its target's soft update, until the end of
//! the update (nothing after step 2 reads critic 1). This thread does the rest in the order of
//! `update.rs`. With FORK, its models take their step on the second thread instead, while this
//! one runs both critics. The gradients of the summed twin loss are the pair of the critics'
//! own gradients (they share no parameter), and Adam steps parameters independently, so the
//! split changes no number.

use std::time::Instant;

use rdpg_core::SequenceBatch;
use tch::Tensor;

use super::agent::RdpgAgent;
use super::fork::{ForkModels, ModelStep};
use super::lstm::RecState;
use super::nets::Critic;
use super::prepared::Prepared;
use super::profile::Clock;
use super::update::{
    actor_states, critic_loss_from, grad_if, scan_actor, scan_critic, scan_target_actor,
    scan_target_critic, soft_update, tail_action, target_q, td_targets, trained_q, Scanned,
};
use crate::common::side_thread::SideThread;
use crate::common::UpdateStats;

impl RdpgAgent {
    /// [`RdpgAgent::update`] with `parallel_twins` (checked batch, denormal mode set).
    #[allow(
        clippy::expect_used,
        reason = "parallel twins are validated to need target networks, scanned with them"
    )]
    pub(super) fn update_parallel(&mut self, batch: &SequenceBatch) -> UpdateStats {
        let started = Instant::now();
        let mut clock = Clock::new(self.profile.is_some());
        let ftz = self.cfg.flush_denormal;
        let p = self.prepare(batch);
        let mut side = self.side.take().unwrap_or_default();
        // FORK: its models step on the second thread while this one runs both critics.
        let models_on_side = match self.fork.take() {
            Some(mut f) => {
                let p1 = p.shallow_clone();
                side.start(ftz, move || {
                    let step = f.train(&p1);
                    (f, step)
                });
                true
            }
            None => false,
        };
        clock.lap(|t| &mut t.prepare);

        // ---- 1. Scan. ------------------------------------------------------------------------
        let sc = if models_on_side {
            self.scan_for(&p, self.scans_actor())
        } else {
            self.scan_all_parallel(&p, &mut side)
        };
        clock.lap(|t| &mut t.scan);

        // ---- 2. Critic. ----------------------------------------------------------------------
        let (q0, critic_loss, actor_states) = if models_on_side {
            self.critic_gradients(&p, &sc, &mut clock)
        } else {
            self.twin_critic_gradients(&p, &sc, &mut side, &mut clock)
        };
        let (actor_turn, critic_states_before) = self.clip_and_count(&p, &sc);
        let deferred = critic_states_before.is_some();
        let model_step = models_on_side.then(|| {
            let (f, step) = side.finish::<(ForkModels, ModelStep)>();
            self.fork = Some(f);
            step
        });
        // Critic 1's share of the Adam step (and on the actor's turn its target's soft update)
        // on the second thread until the end of the update; critic 0's here.
        let critic_step = self.critic_opt.begin_step();
        let n_critic = self.critic_opt.params().len();
        let split = self.critic0_params;
        let mut part = self.critic_opt.part(split..n_critic);
        let t = self.targets.as_ref().expect("validated: target networks");
        let own_targets = t.pairs.len() - (n_critic - split); // critic 1's target pairs are last
        let mut pairs: Vec<(Tensor, Tensor)> = t.pairs[own_targets..]
            .iter()
            .map(|(a, b)| (a.shallow_clone(), b.shallow_clone()))
            .collect();
        let tau = self.cfg.tau;
        side.start(ftz, move || {
            part.apply(&critic_step);
            if actor_turn {
                soft_update(&mut pairs, tau);
            }
        });
        if !deferred {
            self.critic_opt.apply(&critic_step, 0..split);
        }
        clock.lap(|t| &mut t.critic_step);
        clock.lap(|t| &mut t.models); // (FORK's models stepped on the second thread)

        // ---- 3. Actor. -----------------------------------------------------------------------
        let mut actor_loss = None;
        if actor_turn {
            let critic_states =
                critic_states_before.unwrap_or_else(|| self.updated_critic_states(&p));
            clock.lap(|t| &mut t.critic_rescan);
            let loss = self.actor_gradient(&p, &sc, &actor_states, &critic_states, &model_step);
            if deferred {
                self.critic_opt.apply(&critic_step, 0..split);
            }
            self.actor_opt.step();
            actor_loss = Some(loss);
            clock.lap(|t| &mut t.actor_step);

            // ---- 4. Soft target update (critic 1's target on the second thread). ------------
            if let Some(t) = &mut self.targets {
                soft_update(&mut t.pairs[..own_targets], self.cfg.tau);
            }
        }
        side.finish::<()>();
        self.side = Some(side);
        let mut stats = self.update_stats(batch, &p, &q0, &critic_loss, actor_loss, model_step);
        stats.seconds = started.elapsed().as_secs_f64();
        clock.lap(|t| &mut t.other);
        clock.finish(&mut self.profile);
        stats
    }

    /// Step 1 with `parallel_twins`: critic 0, target critic 0 and (when the update reads it)
    /// the behaviour actor here, critic 1, its target and the target actor on a second thread;
    /// without the behaviour actor, the target actor here too (when there is a scan to run).
    #[allow(
        clippy::expect_used,
        reason = "parallel twins are validated to need target networks, scanned with them"
    )]
    fn scan_all_parallel(&self, p: &Prepared, side: &mut SideThread) -> Scanned {
        let with_actor = self.scans_actor();
        if p.s == 0 || !self.actor.core.is_recurrent() {
            return self.scan_for(p, with_actor);
        }
        let method = self.cfg.scan_method;
        let t = self.targets.as_ref().expect("validated: target networks");
        let t_actor = self
            .target_actor()
            .expect("validated: a deterministic actor (not SAC) has a target actor");
        let actor_init = self.actor_init(p);
        let (c1, t1, ta, p1, init1) = (
            self.critics[1].shallow_clone(),
            t.critics[1].shallow_clone(),
            t_actor.shallow_clone(),
            p.shallow_clone(),
            actor_init.shallow_clone(),
        );
        let window_grad = self.cfg.window_grad;
        // The actor (behaviour or target) scanned here.
        let here = if with_actor { &self.actor } else { t_actor };
        let ((h_a, h0, th0), (h1, th1, h_ta)) = side.run(
            self.cfg.flush_denormal,
            || {
                (
                    match with_actor {
                        true => self.history_grad(|| scan_actor(here, p, &actor_init, method)),
                        false => tch::no_grad(|| scan_target_actor(here, p, &actor_init, method)),
                    },
                    self.history_grad(|| scan_critic(&self.critics[0], p, method)),
                    tch::no_grad(|| scan_target_critic(&t.critics[0], p, method)),
                )
            },
            move || {
                // Critic 1's scan keeps its graph for a `window_grad` agent, as critic 0's.
                (
                    grad_if(window_grad, || scan_critic(&c1, &p1, method)),
                    tch::no_grad(|| scan_target_critic(&t1, &p1, method)),
                    with_actor
                        .then(|| tch::no_grad(|| scan_target_actor(&ta, &p1, &init1, method))),
                )
            },
        );
        let (actor, target_actor) = match h_ta {
            Some(h_ta) => (Some(h_a), h_ta),
            None => (None, h_a),
        };
        Scanned {
            actor,
            critics: vec![h0, h1],
            target_actor: Some(target_actor),
            target_critics: vec![th0, th1],
        }
    }

    /// Step 2 with `parallel_twins` (tail-step bootstrap, target networks), with the same
    /// arithmetic as [`RdpgAgent::critic_objective`] followed by one backward pass of the
    /// summed loss, in three two-thread phases: the target actor's bootstrap action here and
    /// the behaviour actor's states along the window there; `Q'(o_tail, a_tail)` of target
    /// critic 0 here and 1 there; critic 0's TD loss and backward pass here and critic 1's
    /// there (the gradient of the summed loss is the pair of their gradients: the critics share
    /// no parameter). Zeroes the critics' gradients and back-propagates; returns critic 0's
    /// `Q(o_i, a_i | h_{i-1})` on the trained steps (`[N, u]`, detached), the summed TD loss
    /// and the actor's states (on the actor's turn).
    #[allow(
        clippy::expect_used,
        reason = "parallel twins are validated to need target networks, scanned with them"
    )]
    fn twin_critic_gradients(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        side: &mut SideThread,
        clock: &mut Clock,
    ) -> (Tensor, Tensor, Option<(Tensor, Tensor)>) {
        let ftz = self.cfg.flush_denormal;
        let need_states = self.actor_states_detached();
        let (mut a_tail, actor_states) = {
            let t_actor = self.target_actor().expect("validated: target networks");
            let h = sc.target_actor.as_ref().expect("scanned with the targets");
            let main = || tch::no_grad(|| tail_action(t_actor, p, h));
            if let Some(h_actor) = sc.actor.as_ref().filter(|_| need_states) {
                let (actor, p1, h1) = (
                    self.actor.shallow_clone(),
                    p.shallow_clone(),
                    h_actor.shallow_clone(),
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
}

/// One critic's part of step 2b: `Q(o_i, a_i | h_{i-1})` on the trained steps (`[N, u]`), its TD
/// loss against `y` and the loss's backward pass. Returns both detached.
fn td_backward(c: &Critic, p: &Prepared, h: &RecState, y: &Tensor) -> (Tensor, Tensor) {
    let q = trained_q(c, p, h);
    let loss = critic_loss_from(p, &q, y);
    loss.backward();
    (q.detach(), loss.detach())
}
