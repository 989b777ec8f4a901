//! The learner's option enums (`[agent]` keys with named values): how the scan handles short
//! windows, how the critic's targets are built, how the actor loss weighs a window's steps.
//! Re-exported by `config.rs` with the rest of [`RdpgConfig`](super::config::RdpgConfig).

use serde::{Deserialize, Serialize};

/// How the no-gradient scan (burn-in) handles windows whose scan is shorter than `s`
/// (left-padded windows near an episode start). Both give the state after exactly
/// `scan_len` real steps from the initial state; padding never touches it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScanMethod {
    /// Windows grouped by their scan length, each group one call of the fused LSTM kernel
    /// over its real steps (one call in all when every window has a full scan, the common
    /// case; a few more for the shorter scans of windows near an episode start). The default.
    Grouped,
    /// One LSTM cell step per scan step over the whole batch; the state of windows still in
    /// their padding is kept with a mask (`where`). Competitive when most windows are short
    /// (short episodes).
    MaskedLoop,
}

/// How the actor loss (Eq. (DPG)) weighs the steps of the replayed windows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ActorWeights {
    /// `1/len_n` on each real step of window `n`: every window weighs the same, so the steps
    /// of the short windows at an episode's end weigh more (with windows of `l = 8`, an
    /// episode's last step up to `1 + 1/2 + ... + 1/8 = 2.7` times a middle one). The default.
    PerWindow,
    /// `1/l` on every real step: every replayed step weighs the same wherever its window
    /// ends, as the expectation over visited states of Eq. (DPG) reads and as the critic's
    /// interpolated TD weights do (they are not renormalised for short windows either).
    PerStep,
}

/// How the critic's regression targets are built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CriticTarget {
    /// The paper's tail-step bootstrap of the interpolated TD(λ): every step of a window
    /// bootstraps from the single `Q'` at the window's tail (Eq. (unsyncedinterpolatedTD)).
    TailBootstrap,
    /// The classic RDPG of Heess et al. (2015): per-step TD(0), each step bootstrapping from
    /// `Q'` at the next step along the window (with `update_len = opt_len`, `lambda = 1`,
    /// `actor_bptt = true`, `scan_len = 0` and target networks, the paper's Table I baseline).
    PerStepTd0,
}
