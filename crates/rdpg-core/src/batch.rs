//! The minibatch of sub-trajectories the recurrent learners train on.
//!
//! Every array is flat, batch-major (`[n, time, features]`, row-major). Window `i` covers the
//! *scan* steps `t_i - s .. t_i` (used only to initialise the recurrent state, no gradient)
//! followed by the *optimisation* steps `t_i .. t_i + l`, plus one bootstrap observation after
//! the last optimisation step. Steps that do not exist (before the episode start in the scan
//! part, after the episode end in the optimisation part) are padding: zero data, `mask = 0`.
//!
//! Scan padding is on the LEFT (the scan ends right before `t_i`, the first `s - scan_len[i]`
//! scan steps are padding); optimisation padding is on the RIGHT.

use serde::{Deserialize, Serialize};

/// `n` windows of `scan + opt` steps.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SequenceBatch {
    /// Number of windows.
    pub n: usize,
    /// Scan length `s` (time steps before the optimisation part).
    pub scan: usize,
    /// Optimisation length `l`.
    pub opt: usize,
    /// Observation size.
    pub obs_dim: usize,
    /// Action size.
    pub act_dim: usize,
    /// `[n, scan + opt + 1, obs_dim]`: observations; index `scan + opt` is the bootstrap
    /// observation following the last optimisation step (`o_{t+l}`), or, for a window whose
    /// episode ends earlier, the observation following its last valid step, placed at
    /// `scan + opt_len[i]`.
    pub obs: Vec<f32>,
    /// `[n, scan + opt, act_dim]`: actions taken.
    pub actions: Vec<f32>,
    /// `[n, scan + opt]`: rewards received.
    pub rewards: Vec<f32>,
    /// `[n, scan + opt]`: 1 for real steps, 0 for padding.
    pub mask: Vec<f32>,
    /// `[n]`: number of real scan steps (`<= scan`).
    pub scan_len: Vec<usize>,
    /// `[n]`: number of real optimisation steps (`1..=opt`).
    pub opt_len: Vec<usize>,
    /// `[n]`: 1 if the window's last real step ended its episode by *termination* (no
    /// bootstrap from the tail); 0 otherwise (including time-limit truncation, which
    /// bootstraps).
    pub tail_terminated: Vec<f32>,
    /// `[n]`: 1 if the window was drawn from injected (teacher) experience.
    pub injected: Vec<f32>,
    /// Acting-time recurrent state stored at the first real step of each window's scan
    /// (`[n, state_dim]`), when the replay stores states (R2D2-style start); `None` otherwise.
    pub stored_state: Option<Vec<f32>>,
    /// Size of one stored state, 0 when none.
    pub state_dim: usize,
}

impl SequenceBatch {
    /// Total steps per window (`scan + opt`).
    pub fn steps(&self) -> usize {
        self.scan + self.opt
    }
}
