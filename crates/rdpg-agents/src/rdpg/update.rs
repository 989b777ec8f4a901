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
//!    `J = -1/N sum_n sum_{i < len_n} v_{n,i} Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})`, with
//!    `v_{n,i} = 1/len_n` (`actor_weights = "per_window"`, the default) or `1/l` (`per_step`,
//!    every replayed step alike); a window-of-k agent: 1 on the first step alone. Without
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
//! With `act_window = k` (window-of-k agents) every state the update reads is that of the
//! acting actor's `k`-observation window: the scan (`s = k - 1`) starts from zero, the critic
//! and the actor train on the window's first step only, and step 2a's bootstrap re-encodes the
//! `k - 1` steps before `o_tail` from zero (`Prepared::window_tail`) instead of continuing the
//! target networks' run along the window. With `window_grad` the behaviour networks' scans
//! keep their graph: the critic loss back-propagates through the critic's encoding of the
//! `k - 1` replayed history steps, and the actor loss (BPTT) through the actor's, as LSTM-TD3
//! trains its history.
//!
//! With `policy_delay = d > 1` (TD3) steps 3 and 4 run on every `d`-th update only; the
//! critic steps every time.
//!
//! With target networks the behaviour actor's scan and its states along the window serve step
//! 3 alone: they run on the actor's turns only.
//!
//! With `parallel_twins` the same update runs on two threads (`twins.rs`): the second critic's
//! share of steps 1 and 2 (its scan and its target's, the target actor's scan, the behaviour
//! actor's states, target critic 1's value, critic 1's forward and backward pass), critic 1's
//! Adam step and its target's soft update run on a second thread, with the same arithmetic:
//! the result is bit-identical. The batch as the update reads it is built in `prepared.rs`,
//! the per-phase stopwatch in `profile.rs`.

use std::collections::BTreeMap;
use std::time::Instant;

use rdpg_core::SequenceBatch;
use tch::Tensor;

use super::agent::RdpgAgent;
use super::config::{CriticTarget, ScanMethod};
use super::fork::ModelStep;
use super::lstm::{scan_state, RecState};
use super::nets::{Actor, Critic};
use super::prepared::Prepared;
use super::profile::Clock;
use crate::common::UpdateStats;
use crate::Result;

impl Scanned {
    /// The behaviour actor's scanned state.
    ///
    /// # Panics
    /// If the update did not scan it (see [`Scanned::actor`]).
    #[allow(
        clippy::expect_used,
        reason = "the update scans the behaviour actor wherever it reads it (scans_actor)"
    )]
    pub(super) fn actor(&self) -> &RecState {
        self.actor
            .as_ref()
            .expect("the behaviour actor is scanned where the update reads it")
    }
}

impl RdpgAgent {
    /// One RDPG update (Algorithm 1, `Update`) on `batch`. See the module docs for the steps.
    ///
    /// # Errors
    /// If the batch does not fit the agent ([`RdpgAgent::check_batch`]); nothing has changed.
    pub fn update(&mut self, batch: &SequenceBatch) -> Result<UpdateStats> {
        self.check_batch(batch)?;
        if self.cfg.flush_denormal {
            crate::common::tensor::set_flush_denormal(true);
        }
        if self.sac.is_some() {
            return Ok(self.update_sac(batch)); // soft actor-critic's update (sac.rs)
        }
        if self.cfg.parallel_twins {
            return Ok(self.update_parallel(batch)); // the same update on two threads (twins.rs)
        }
        let started = Instant::now();
        let mut clock = Clock::new(self.profile.is_some());
        let p = self.prepare(batch);
        clock.lap(|t| &mut t.prepare);

        // ---- 1. Scan: h_{-1} for every network, no gradient (paper Eq. (scan)). -------------
        let sc = self.scan_for(&p, self.scans_actor());
        clock.lap(|t| &mut t.scan);

        // ---- 2. Critic: TD gradient (Eq. (unsyncedinterpolatedTD)) and its Adam step. --------
        let (q0, critic_loss, actor_states) = self.critic_gradients(&p, &sc, &mut clock);
        let (actor_turn, critic_states_before) = self.clip_and_count(&p, &sc);
        // Algorithm 1 order: the actor reads the critic after its step. Otherwise (on the
        // actor's turn) the actor reads the critic as it was and the critic steps after the
        // actor's backward pass.
        let deferred = critic_states_before.is_some();
        if !deferred {
            self.critic_opt.step();
        }
        clock.lap(|t| &mut t.critic_step);

        // ---- FORK's models: one step each on this batch (`fork.rs`). -------------------------
        let model_step = self.fork.as_mut().map(|f| f.train(&p));
        clock.lap(|t| &mut t.models);

        // ---- 3. Actor: deterministic policy gradient (Eq. (DPG)), no BPTT by default. ------
        // TD3's delayed policy update: the actor and the target networks move on every
        // `policy_delay`-th update only (every update for the paper's RDPG, delay 1).
        let mut actor_loss = None;
        if actor_turn {
            let critic_states =
                critic_states_before.unwrap_or_else(|| self.updated_critic_states(&p));
            clock.lap(|t| &mut t.critic_rescan);
            let loss = self.actor_gradient(&p, &sc, &actor_states, &critic_states, &model_step);
            if deferred {
                self.critic_opt.step();
            }
            self.actor_opt.step();
            actor_loss = Some(loss);
            clock.lap(|t| &mut t.actor_step);

            // ---- 4. Soft target update theta' <- theta' + tau (theta - theta'). -----------
            if let Some(t) = &mut self.targets {
                soft_update(&mut t.pairs, self.cfg.tau);
            }
        }
        let mut stats = self.update_stats(batch, &p, &q0, &critic_loss, actor_loss, model_step);
        stats.seconds = started.elapsed().as_secs_f64();
        clock.lap(|t| &mut t.other);
        clock.finish(&mut self.profile);
        Ok(stats)
    }

    /// Step 2's gradient: the critics' TD loss (summed over twins) back-propagated into
    /// zeroed gradients. Returns critic 0's `Q(o_i, a_i | h_{i-1})` on the trained steps
    /// (detached), the loss and the actor's states along the window (per-step actor gradient).
    #[allow(clippy::expect_used, reason = "an agent has one or two critics")]
    pub(super) fn critic_gradients(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        clock: &mut Clock,
    ) -> (Tensor, Tensor, Option<(Tensor, Tensor)>) {
        let (q_sa, y, actor_states) = self.critic_objective(p, sc, clock);
        let critic_loss = q_sa
            .iter()
            .map(|q| critic_loss_from(p, q, &y))
            .reduce(|a, b| a + b)
            .expect("at least one critic");
        self.critic_opt.zero_grad();
        critic_loss.backward();
        (q_sa[0].detach(), critic_loss, actor_states)
    }

    /// After step 2's backward pass: clips the critics' gradients (`grad_clip`) and counts the
    /// update. Returns whether it is the actor's turn (TD3's `policy_delay`) and, when the
    /// actor reads critic 0 as it was before its step (`actor_uses_updated_critic = false`, on
    /// the actor's turn), critic 0's states along the window, taken now.
    pub(super) fn clip_and_count(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
    ) -> (bool, Option<(Tensor, Tensor)>) {
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.critic_opt.clip_grad_norm(c);
        }
        self.updates += 1;
        let actor_turn = self.updates.is_multiple_of(self.cfg.policy_delay as u64);
        let before = (actor_turn && !self.cfg.actor_uses_updated_critic)
            .then(|| tch::no_grad(|| self.critic_states(p, &sc.critics[0])));
        (actor_turn, before)
    }

    /// Critic 0's states `h^C_{i-1}` along the window after its Adam step: its scan and its
    /// run along the replayed actions again (no gradient).
    pub(super) fn updated_critic_states(&self, p: &Prepared) -> (Tensor, Tensor) {
        tch::no_grad(|| {
            let h = scan_critic(&self.critics[0], p, self.cfg.scan_method);
            self.critic_states(p, &h)
        })
    }

    /// Step 3's gradient: the actor loss (Eq. (DPG), plus FORK's weighted term while its
    /// dynamics model is accurate enough) back-propagated into the actor's zeroed gradients
    /// (clipped), critic 0 held constant. Returns the loss.
    pub(super) fn actor_gradient(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        actor_states: &Option<(Tensor, Tensor)>,
        critic_states: &(Tensor, Tensor),
        model_step: &Option<ModelStep>,
    ) -> f64 {
        let actor_in = match actor_states {
            Some((hb, cb)) => ActorInput::Detached { h: hb, c: cb },
            None => ActorInput::Bptt { h0: sc.actor() },
        };
        // Critic 0 is a constant here: no gradients are computed or accumulated for it
        // (the only critic the actor loss reads).
        self.critic_vs[0].freeze();
        let (mut loss, a0) = actor_loss(&self.actor, &self.critics[0], p, actor_in, critic_states);
        // FORK: + w J_fork while the dynamics model is accurate enough (from the same
        // actions mu(o_i), [N*l, A]).
        if let (Some(f), Some(m)) = (&mut self.fork, model_step) {
            if m.use_term {
                let w = f.cfg.weight;
                let j = f.actor_term(&self.actor, &self.critics[0], p, &a0, self.cfg.gamma);
                loss += j * w;
            }
        }
        self.actor_opt.zero_grad();
        loss.backward();
        self.critic_vs[0].unfreeze();
        if let Some(c) = self.cfg.grad_clip {
            let _ = self.actor_opt.clip_grad_norm(c);
        }
        loss.double_value(&[])
    }

    /// The update's statistics (`seconds` left at 0 for the caller to set).
    pub(super) fn update_stats(
        &self,
        batch: &SequenceBatch,
        p: &Prepared,
        q0: &Tensor,
        critic_loss: &Tensor,
        actor_loss: Option<f64>,
        model_step: Option<ModelStep>,
    ) -> UpdateStats {
        // Mean over the trained steps (the real ones among the first u).
        let mask = p.mask.narrow(1, 0, p.u);
        let q_mean = tch::no_grad(|| (q0 * &mask).sum(self.kind) / mask.sum(self.kind));
        let mut extra = BTreeMap::new();
        if let Some(m) = &model_step {
            extra.insert("model_loss".to_string(), m.dynamics_loss);
            // FORK's term is reported on the actor's turns only.
            if actor_loss.is_some() {
                extra.insert("fork_share".to_string(), f64::from(u8::from(m.use_term)));
            }
        }
        UpdateStats {
            critic_loss: critic_loss.double_value(&[]),
            q_mean: q_mean.double_value(&[]),
            injected_share: batch.injected.iter().map(|&x| f64::from(x)).sum::<f64>()
                / batch.n as f64,
            seconds: 0.0,
            actor_loss,
            extra,
        }
    }

    /// Step 2 of the update: `Q(o_i, a_i | h_{i-1})` of every critic on the trained steps, with
    /// gradient (`[N, u]` each), and their targets `y` (`[N, l]`) and the actor's states along
    /// the window (per-step actor gradient, on the actor's turns), both without gradient:
    ///
    /// 2a. the bootstrap action `mu'(o_tail)` (+ TD3 smoothing noise) from the target actor's
    ///     run along the window (the behaviour actor's without target networks), with target
    ///     networks `Q'(o_tail, mu'(o_tail))`, and the behaviour actor's states;
    /// 2b. the tail-step bootstrap of the interpolated TD (Eq. (unsyncedinterpolatedTD)); or,
    ///     instead of 2a and 2b, the classic RDPG's per-step TD(0) (Heess et al. 2015).
    pub(super) fn critic_objective(
        &mut self,
        p: &Prepared,
        sc: &Scanned,
        clock: &mut Clock,
    ) -> (Vec<Tensor>, Tensor, Option<(Tensor, Tensor)>) {
        match self.cfg.critic_target {
            CriticTarget::TailBootstrap => {
                let (actor_states, mut a_tail) = tch::no_grad(|| self.actor_window(p, sc));
                if let Some(noise) = self.cfg.target_noise {
                    a_tail = self.smooth_target_action(&a_tail, noise.std, noise.clip);
                }
                let target_q_tail = tch::no_grad(|| self.target_tail_q(p, sc, &a_tail));
                clock.lap(|t| &mut t.window_nograd);
                let (q_sa, q_tail) = self.critic_forward(p, sc, &a_tail, target_q_tail);
                let y = tch::no_grad(|| td_targets(p, &q_tail)); // [N, l]
                (q_sa, y, actor_states)
            }
            CriticTarget::PerStepTd0 => {
                let need_states = self.actor_states_detached();
                let actor_states = sc
                    .actor
                    .as_ref()
                    .filter(|_| need_states)
                    .map(|h| tch::no_grad(|| actor_states(&self.actor, p, h)));
                let y = tch::no_grad(|| self.per_step_targets(p, sc)); // [N, l]
                clock.lap(|t| &mut t.window_nograd);
                let q_sa = self
                    .critics
                    .iter()
                    .zip(&sc.critics)
                    .map(|(c, h)| trained_q(c, p, h))
                    .collect();
                (q_sa, y, actor_states)
            }
        }
    }

    /// Step 2a (call without gradient): the bootstrap action `mu'(o_tail)`, `[N, A]`, from the
    /// target actor's run along the window (`l + 1` slots), and the behaviour actor's states
    /// before each optimisation step (`[N, l, H]` each; only for the per-step actor gradient,
    /// i.e. no BPTT, on the actor's turn: [`actor_states`]). Without target networks the
    /// behaviour actor's own run along the window gives both.
    pub(super) fn actor_window(
        &self,
        p: &Prepared,
        sc: &Scanned,
    ) -> (Option<(Tensor, Tensor)>, Tensor) {
        let need_states = self.actor_states_detached();
        if let (Some(ta), Some(h)) = (self.target_actor(), &sc.target_actor) {
            // The bootstrap comes from mu': the behaviour actor runs for its states only, on
            // the actor's turn (when it was scanned).
            let states = sc
                .actor
                .as_ref()
                .filter(|_| need_states)
                .map(|h| actor_states(&self.actor, p, h));
            return (states, tail_action(ta, p, h));
        }
        // No target actor: the behaviour actor's run along the window (l + 1 slots) gives both;
        // its output at the tail slot `len_n` is mu(o_tail | h_{len-1}).
        let xa = self.actor.input_seq(&p.obs_win); // [N, l+1, E]
        let (ya, states) = if need_states {
            let (ya, hb, cb, _) = self.actor.core.stepwise(&xa, sc.actor());
            (ya, Some((hb.narrow(1, 0, p.l), cb.narrow(1, 0, p.l))))
        } else {
            (self.actor.core.seq(&xa, sc.actor()).0, None)
        };
        let a_tail = (self.actor.head(&xa, &ya) * p.tail_onehot.unsqueeze(-1))
            .sum_dim_intlist(1, false, self.kind);
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

    /// Step 2b's forward pass (with gradient): `Q(o_i, a_i | h_{i-1})` of every critic on the
    /// trained steps, `[N, u]` each, and the bootstrap value `[N]`. With target networks the
    /// critics run over the first `u` window steps only (the loss weighs no later step);
    /// without them each critic's run continues to the tail slot with `a_tail`, and that
    /// output, detached (minimum over twins), is the bootstrap.
    pub(super) fn critic_forward(
        &self,
        p: &Prepared,
        sc: &Scanned,
        a_tail: &Tensor,
        target_q_tail: Option<Tensor>,
    ) -> (Vec<Tensor>, Tensor) {
        let critics = self.critics.iter().zip(&sc.critics);
        match target_q_tail {
            Some(q_tail) => (critics.map(|(c, h)| trained_q(c, p, h)).collect(), q_tail),
            None => {
                let qs: Vec<Tensor> = critics
                    .map(|(c, h)| critic_window(c, p, h, Some(a_tail)))
                    .collect(); // each [N, l + 1]
                let q_tail = min_all(&qs.iter().map(|q| tail_q(p, q).detach()).collect::<Vec<_>>());
                (qs.iter().map(|q| q.narrow(1, 0, p.u)).collect(), q_tail)
            }
        }
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
        let (actor, actor_h) = match (self.target_actor(), &sc.target_actor) {
            (Some(ta), Some(h)) => (ta, h),
            _ => (&self.actor, sc.actor()),
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
                let (ha, ca) = c.core.states_after(&x, h);
                let hc = ha.size()[2];
                let st = RecState {
                    h: ha.reshape([1, n * l, hc]),
                    c: ca.reshape([1, n * l, hc]),
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

    /// Step 1 for every network, without gradient.
    #[cfg(test)]
    pub(super) fn scan_all(&self, p: &Prepared) -> Scanned {
        self.scan_for(p, true)
    }

    /// Step 1 for every network the update reads: the behaviour actor only with `actor` (its
    /// states serve the actor's turn alone when target networks give the bootstrap; see
    /// [`RdpgAgent::scans_actor`]). Without gradient, except the behaviour networks' scans of
    /// a `window_grad` agent ([`RdpgAgent::history_grad`]).
    pub(super) fn scan_for(&self, p: &Prepared, actor: bool) -> Scanned {
        let method = self.cfg.scan_method;
        let actor_init = self.actor_init(p);
        Scanned {
            actor: actor
                .then(|| self.history_grad(|| scan_actor(&self.actor, p, &actor_init, method))),
            critics: self
                .critics
                .iter()
                .map(|c| self.history_grad(|| scan_critic(c, p, method)))
                .collect(),
            target_actor: self
                .target_actor()
                .map(|ta| tch::no_grad(|| scan_target_actor(ta, p, &actor_init, method))),
            target_critics: self.targets.as_ref().map_or_else(Vec::new, |t| {
                t.critics
                    .iter()
                    .map(|c| tch::no_grad(|| scan_target_critic(c, p, method)))
                    .collect()
            }),
        }
    }

    /// Runs a behaviour network's scan `f`: recording its graph for a `window_grad` agent (the
    /// losses back-propagate through the window's history), without gradient otherwise.
    pub(super) fn history_grad<T>(&self, f: impl FnOnce() -> T) -> T {
        grad_if(self.cfg.window_grad, f)
    }

    /// Whether the actor loss feeds each window step a constant actor state (the paper's
    /// actor without BPTT): a recurrent actor, without `actor_bptt` or `window_grad`.
    pub(super) fn actor_states_detached(&self) -> bool {
        self.actor.core.is_recurrent() && !self.cfg.actor_bptt && !self.cfg.window_grad
    }

    /// The target actor, if there is one (`tau > 0`, not SAC).
    pub(super) fn target_actor(&self) -> Option<&Actor> {
        self.targets.as_ref()?.actor.as_ref().map(|(_, a)| a)
    }

    /// Whether this update reads the behaviour actor's scan: on the actor's turn, or always
    /// without target networks (the behaviour actor gives the bootstrap action).
    pub(super) fn scans_actor(&self) -> bool {
        self.targets.is_none() || (self.updates + 1).is_multiple_of(self.cfg.policy_delay as u64)
    }

    /// The actor scans' initial state: the stored acting-time state, or zeros.
    pub(super) fn actor_init(&self, p: &Prepared) -> RecState {
        match &p.stored {
            Some(st) => st.shallow_clone(),
            None => self.actor.core.zero_state(p.n, self.kind, self.device),
        }
    }

    /// The critic's states before each optimisation step along the replayed actions
    /// (`h_{i-1}`, `c_{i-1}`, each `[N, l, H]`), from its scanned state (call without
    /// gradient).
    pub(super) fn critic_states(&self, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
        critic_states(&self.critics[0], p, h)
    }
}

/// Runs `f` recording its autograd graph when `record`, without gradient otherwise.
pub(super) fn grad_if<T>(record: bool, f: impl FnOnce() -> T) -> T {
    if record {
        f()
    } else {
        tch::no_grad(f)
    }
}

/// `critic`'s states before each optimisation step along the replayed actions (`h_{i-1}`,
/// `c_{i-1}`, each `[N, l, H]`), from its scanned state `h` (call without gradient).
pub(super) fn critic_states(critic: &Critic, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
    if !critic.core.is_recurrent() {
        // Zero-width states, `[N, l, 0]`: nothing to run.
        let z = h.h.new_zeros([p.n, p.l, 0], (h.h.kind(), h.h.device()));
        return (z.shallow_clone(), z);
    }
    let x = critic.input_seq(&p.obs_win.narrow(1, 0, p.l), &p.act_win);
    critic.core.states_before(&x, h)
}

/// `theta' <- theta' + tau (theta - theta')` for each (target, online) pair.
pub(super) fn soft_update(pairs: &mut [(Tensor, Tensor)], tau: f64) {
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
pub(super) fn actor_states(actor: &Actor, p: &Prepared, h: &RecState) -> (Tensor, Tensor) {
    let x = actor.input_seq(&p.obs_win.narrow(1, 0, p.l)); // [N, l, E]
    actor.core.states_before(&x, h)
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

/// A target actor's `h_{-1}`: [`scan_actor`], except for window-of-k agents, whose bootstrap
/// re-encodes its own window (`Prepared::window_tail`) and never reads it (`init` then).
pub(super) fn scan_target_actor(
    actor: &Actor,
    p: &Prepared,
    init: &RecState,
    method: ScanMethod,
) -> RecState {
    match p.window_tail {
        Some(_) => init.shallow_clone(),
        None => scan_actor(actor, p, init, method),
    }
}

/// A target critic's `h_{-1}`: [`scan_critic`], except for window-of-k agents (zeros, unread:
/// see [`scan_target_actor`]).
pub(super) fn scan_target_critic(critic: &Critic, p: &Prepared, method: ScanMethod) -> RecState {
    match p.window_tail {
        Some(_) => critic
            .core
            .zero_state(p.n, p.obs_win.kind(), p.obs_win.device()),
        None => scan_critic(critic, p, method),
    }
}

/// `Q'(o_tail, a_tail)` of target critic `c` from its scanned state `h`, `[N]` (call without
/// gradient): its run along the window with `a_tail` at the tail position, or for a
/// feed-forward critic one forward pass on the tail observation.
pub(super) fn target_q(c: &Critic, p: &Prepared, h: &RecState, a_tail: &Tensor) -> Tensor {
    Critic::value(&target_atoms(c, p, h, a_tail))
}

/// [`target_q`] before the value is taken: the output layer's `M` values at
/// `(o_tail, a_tail)`, `[N, M]` (TQC's atoms; `M = 1` otherwise).
pub(super) fn target_atoms(c: &Critic, p: &Prepared, h: &RecState, a_tail: &Tensor) -> Tensor {
    if let Some(w) = &p.window_tail {
        // Window-of-k: the k - 1 pairs before the tail from a zero state, then the tail.
        let h0 = c.core.zero_state(p.n, p.obs_win.kind(), p.obs_win.device());
        let x = c.input_seq(&w.obs, &w.act); // [N, k-1, E]
        let h = scan_state(&c.core, &x, &w.len, &h0, ScanMethod::Grouped);
        return c.atoms_step(&tail_obs(p), a_tail, &h).0;
    }
    if c.core.is_recurrent() {
        let (obs, act) = window_pairs(p, Some(a_tail));
        let z = c.atoms_seq(&obs, &act, h).0; // [N, l+1, M]
        (z * p.tail_onehot.unsqueeze(-1)).sum_dim_intlist(1, false, p.obs_win.kind())
    } else {
        c.atoms_step(&tail_obs(p), a_tail, h).0
    }
}

/// `h_{-1}` of every network (the behaviour actor's only where the update reads it).
pub(super) struct Scanned {
    /// `None` where the update does not read it: on updates that do not train the actor
    /// when target networks give the bootstrap.
    pub(super) actor: Option<RecState>,
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
    let (obs, act) = window_pairs(p, a_tail);
    critic.forward_seq(&obs, &act, h).0
}

/// The critic's inputs along the window, `([N, l, D], [N, l, A])`; with `a_tail`, one more
/// position where the tail position `len_n` holds `(o_tail, a_tail)`,
/// `([N, l + 1, D], [N, l + 1, A])`.
pub(super) fn window_pairs(p: &Prepared, a_tail: Option<&Tensor>) -> (Tensor, Tensor) {
    match a_tail {
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
    }
}

/// `Q(o_i, a_i | h_{i-1})` of `critic` on the steps the loss trains, the first `u` of the
/// window (`[N, u]`), from its scanned state.
pub(super) fn trained_q(critic: &Critic, p: &Prepared, h: &RecState) -> Tensor {
    let (obs, act) = (p.obs_win.narrow(1, 0, p.u), p.act_win.narrow(1, 0, p.u));
    critic.forward_seq(&obs, &act, h).0
}

/// The value at each window's tail position: `q_ext [N, l + 1]` -> `[N]`.
pub(super) fn tail_q(p: &Prepared, q_ext: &Tensor) -> Tensor {
    (q_ext * &p.tail_onehot).sum_dim_intlist(1, false, q_ext.kind())
}

/// `mu'(o_tail)` of `actor` from its scanned state: `[N, A]`. A feed-forward actor acts on
/// the tail observation alone.
pub(super) fn tail_action(actor: &Actor, p: &Prepared, h: &RecState) -> Tensor {
    if let Some(w) = &p.window_tail {
        // Window-of-k: the k - 1 observations before the tail from a zero state, as acting.
        let h0 = actor
            .core
            .zero_state(p.n, p.obs_win.kind(), p.obs_win.device());
        let x = actor.input_seq(&w.obs); // [N, k-1, E]
        let h = scan_state(&actor.core, &x, &w.len, &h0, ScanMethod::Grouped);
        return actor.step(&tail_obs(p), &h).0;
    }
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

/// `1/N sum_n sum_i w_{n,i} (y_{n,i} - q_{n,i})^2` (paper Eq. (unsyncedinterpolatedTD)) for
/// `q_sa [N, w]` on the first `w <= l` window steps (`w = u`, the trained steps, in the
/// update), `y [N, l]`. The squared errors are summed in the window's `[N, l]` layout, zero
/// past `w` (where `w_{n,i} = 0` anyway for `i >= u`): the sum adds the same terms in the same
/// order as a run over the whole window, bit for bit.
pub(super) fn critic_loss_from(p: &Prepared, q_sa: &Tensor, y: &Tensor) -> Tensor {
    let w = q_sa.size()[1];
    weighted_window_sum(p, (y.narrow(1, 0, w) - q_sa).square())
}

/// `1/N sum_n sum_i w_{n,i} e_{n,i}` of per-step errors `e [N, w]` on the first `w <= l`
/// window steps, summed in the window's `[N, l]` layout (zero past `w`).
pub(super) fn weighted_window_sum(p: &Prepared, e: Tensor) -> Tensor {
    let w = e.size()[1];
    let mut e = e;
    if w < p.l {
        e = Tensor::cat(
            &[
                e.shallow_clone(),
                e.new_zeros([p.n, p.l - w], (e.kind(), e.device())),
            ],
            1,
        );
    }
    (&p.critic_w * &e).sum(e.kind()) / p.n as f64
}

/// Where the actor's recurrent input comes from in the actor loss.
pub(super) enum ActorInput<'a> {
    /// No BPTT: the states before each step (`[N, l, H]`), constants.
    Detached { h: &'a Tensor, c: &'a Tensor },
    /// BPTT: run the actor with gradient along the window from its scanned state.
    Bptt { h0: &'a RecState },
}

/// `-1/N sum_n sum_i v_{n,i} Q(o_i, mu(o_i | h^A_{i-1}) | h^C_{i-1})` (paper Eq. (DPG);
/// `v = actor_w`, see `actor_weights`),
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
            let x = actor.trunk.forward(&obs_flat); // [N*l, E]
            let (y, _) = actor.core.step(&x, &st);
            actor.head(&x, &y) // [N*l, A]
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
