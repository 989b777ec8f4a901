//! Where an update's time goes: per-phase wall-clock seconds ([`PhaseTimes`]), accumulated by
//! the update's stopwatch (`Clock`) while profiling is on (`rdpg bench update`).

use std::time::Instant;

use serde::{Deserialize, Serialize};

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
        for (a, b) in self.phases_mut().into_iter().zip(o.phases()) {
            *a += b;
        }
    }

    /// Seconds in all phases together.
    pub fn total(&self) -> f64 {
        self.phases().iter().sum()
    }

    /// Every phase divided by the number of updates measured (seconds per update).
    pub fn per_update(mut self) -> PhaseTimes {
        let k = self.updates.max(1) as f64;
        for v in self.phases_mut() {
            *v /= k;
        }
        self
    }

    /// The phases in the order of the update.
    fn phases(&self) -> [f64; 8] {
        [
            self.prepare,
            self.scan,
            self.window_nograd,
            self.critic_step,
            self.models,
            self.critic_rescan,
            self.actor_step,
            self.other,
        ]
    }

    fn phases_mut(&mut self) -> [&mut f64; 8] {
        [
            &mut self.prepare,
            &mut self.scan,
            &mut self.window_nograd,
            &mut self.critic_step,
            &mut self.models,
            &mut self.critic_rescan,
            &mut self.actor_step,
            &mut self.other,
        ]
    }
}

/// Per-phase stopwatch of one update (a no-op when profiling is off).
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

    /// Charges the time since the last lap to the phase `field` picks.
    pub(super) fn lap(&mut self, field: impl FnOnce(&mut PhaseTimes) -> &mut f64) {
        if self.on {
            let now = Instant::now();
            *field(&mut self.acc) += (now - self.last).as_secs_f64();
            self.last = now;
        }
    }

    /// Adds this update's phases to the agent's profile, if it keeps one.
    pub(super) fn finish(self, profile: &mut Option<PhaseTimes>) {
        if let Some(pt) = profile {
            pt.add(&self.acc);
            pt.updates += 1;
        }
    }
}
