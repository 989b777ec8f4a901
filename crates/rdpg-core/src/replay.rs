//! Episodic experience replay (Song et al. 2018, Sec. II-C and III-D).
//!
//! The buffer keeps whole episodes, FIFO by episode, and samples fixed-shape windows
//! ([`SequenceBatch`]) that never cross an episode boundary: `scan` burn-in steps before a
//! start `t` (clipped at the episode start, left-padded) and `opt` optimisation steps from `t`
//! (clipped at the episode end, right-padded), plus the bootstrap observation after the last
//! real step.
//!
//! # Storage
//!
//! Each episode of `n` transitions is stored compactly as flat `f32` vectors: `n + 1`
//! observations (the final `next_obs` included), `n` actions, `n` rewards, optionally `n`
//! acting-time recurrent states (the state *before* step `t`), the `terminated` / `truncated`
//! flags of its last transition and whether it was injected (teacher experience).
//!
//! Episodes enter whole, when they end ([`EpisodicReplay::add_episode`]; the trainer keeps each
//! episode in progress beside the buffer). Agent and injected episodes are kept in two FIFO
//! queues with separate budgets: the agent's own episodes share `capacity`, evicted oldest
//! first; injected (teacher)
//! episodes have their own cap, `floor(max_injected_fraction * capacity)` transitions, and are
//! evicted only by newer injected episodes. So teacher experience loaded at the start of a run
//! stays for as long as the run samples from it, however much the agent collects. A global
//! insertion sequence number keeps the order of episodes across both queues.
//!
//! # Sampling
//!
//! A *position* is a pair (episode, start `t`), and every transition is a start: an episode of
//! `n_e` transitions has the starts `0 .. n_e`, and a window starting at `t > n_e - opt` runs
//! past the episode's end with right padding (`opt_len = n_e - t`). Windows are drawn uniformly
//! over all positions, i.e. uniformly over transitions, so the last `opt - 1` steps of an
//! episode (the fall included) start windows exactly as often as any other step. Per pool, a prefix-sum index over the
//! episodes' start counts (keyed by `opt`) is kept in an internal cache, extended and trimmed
//! incrementally as episodes come and go and rebuilt only when `opt` changes; each draw is
//! one `integers` draw plus a binary search.

use std::collections::VecDeque;
use std::sync::{Mutex, MutexGuard};

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use thiserror::Error;

use crate::batch::SequenceBatch;
use crate::rng::NpRng;

/// Default cap on the share of the capacity that injected episodes may occupy.
pub const DEFAULT_MAX_INJECTED_FRACTION: f64 = 0.5;

fn default_max_injected_fraction() -> f64 {
    DEFAULT_MAX_INJECTED_FRACTION
}

/// Sizes and limits of an [`EpisodicReplay`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReplayConfig {
    /// Capacity in transitions of the agent's own episodes.
    pub capacity: usize,
    /// Observation size.
    pub obs_dim: usize,
    /// Action size.
    pub act_dim: usize,
    /// Size of the stored acting-time recurrent state; 0 stores none.
    #[serde(default)]
    pub state_dim: usize,
    /// Injected (teacher) transitions have their own budget of `floor(fraction * capacity)`
    /// transitions, on top of `capacity` (default [`DEFAULT_MAX_INJECTED_FRACTION`]); in
    /// `[0, 1]`.
    #[serde(default = "default_max_injected_fraction")]
    pub max_injected_fraction: f64,
}

impl ReplayConfig {
    /// A configuration without stored states and the default injected fraction.
    pub fn new(capacity: usize, obs_dim: usize, act_dim: usize) -> Self {
        Self {
            capacity,
            obs_dim,
            act_dim,
            state_dim: 0,
            max_injected_fraction: DEFAULT_MAX_INJECTED_FRACTION,
        }
    }

    /// The same configuration storing recurrent states of `state_dim` values.
    pub fn with_state_dim(mut self, state_dim: usize) -> Self {
        self.state_dim = state_dim;
        self
    }

    /// The same configuration with another cap on injected transitions.
    pub fn with_max_injected_fraction(mut self, fraction: f64) -> Self {
        self.max_injected_fraction = fraction;
        self
    }

    /// Largest number of injected transitions allowed: `floor(fraction * capacity)`.
    pub fn max_injected_transitions(&self) -> usize {
        (self.max_injected_fraction * self.capacity as f64).floor() as usize
    }

    /// Checks that capacity and sizes are positive and the fraction lies in `[0, 1]`.
    pub fn validate(&self) -> Result<(), ReplayError> {
        if self.capacity == 0 {
            return Err(ReplayError::Config("capacity must be positive".into()));
        }
        if self.obs_dim == 0 || self.act_dim == 0 {
            return Err(ReplayError::Config(
                "obs_dim and act_dim must be positive".into(),
            ));
        }
        if !(0.0..=1.0).contains(&self.max_injected_fraction) {
            return Err(ReplayError::Config(format!(
                "max_injected_fraction must be in [0, 1] (got {})",
                self.max_injected_fraction
            )));
        }
        Ok(())
    }
}

/// What the replay buffer rejects.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ReplayError {
    /// Invalid configuration.
    #[error("invalid replay configuration: {0}")]
    Config(String),
    /// An array does not have the size the configuration implies.
    #[error("{what} has {got} values, expected {expected}")]
    Dimension {
        /// Which array.
        what: &'static str,
        /// Values expected.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// An episode without any transition.
    #[error("an episode needs at least one transition")]
    EmptyEpisode,
    /// An injected episode longer than the injected quota of the buffer.
    #[error("injected episode of {len} transitions exceeds the injected quota of {limit}")]
    InjectedTooLong {
        /// Transitions in the episode.
        len: usize,
        /// `floor(max_injected_fraction * capacity)`.
        limit: usize,
    },
    /// A deserialised buffer is inconsistent.
    #[error("corrupt replay buffer: {0}")]
    Corrupt(String),
}

/// One whole episode, stored flat.
///
/// With `n = rewards.len()` transitions: `obs` holds `(n + 1) * obs_dim` values (the final
/// `next_obs` last), `actions` `n * act_dim`, `states` either `n * state_dim` values (the
/// acting-time recurrent state *before* each step) or nothing (read as zeros, the paper's
/// `h_init`). The flags describe the last transition only; an episode with neither flag set
/// is treated like a truncation (its tail bootstraps).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Episode {
    /// `[n + 1, obs_dim]` observations.
    pub obs: Vec<f32>,
    /// `[n, act_dim]` actions.
    pub actions: Vec<f32>,
    /// `[n]` rewards.
    pub rewards: Vec<f32>,
    /// `[n, state_dim]` acting-time recurrent states, or empty.
    pub states: Vec<f32>,
    /// The last transition ended the episode by termination.
    pub terminated: bool,
    /// The last transition ended the episode by truncation (time limit).
    pub truncated: bool,
    /// Injected (teacher) experience rather than the agent's own.
    pub injected: bool,
}

impl Episode {
    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    /// True when the episode has no transition.
    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }

    fn check(&self, config: &ReplayConfig) -> Result<(), ReplayError> {
        let n = self.len();
        if n == 0 {
            return Err(ReplayError::EmptyEpisode);
        }
        let dim = check_dim;
        // Saturating: sizes read from a file may be absurd, and then they do not match.
        let times = |a: usize, b: usize| a.saturating_mul(b);
        dim("episode obs", times(n + 1, config.obs_dim), self.obs.len())?;
        dim(
            "episode actions",
            times(n, config.act_dim),
            self.actions.len(),
        )?;
        if !self.states.is_empty() {
            dim(
                "episode states",
                times(n, config.state_dim),
                self.states.len(),
            )?;
        }
        Ok(())
    }
}

/// An episode with its insertion sequence number.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Stored {
    seq: u64,
    episode: Episode,
}

/// Everything that is checkpointed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Store {
    config: ReplayConfig,
    next_seq: u64,
    agent: VecDeque<Stored>,
    injected: VecDeque<Stored>,
}

/// A buffer as trainer checkpoint format 3 wrote it (`replay.bin`): the same, followed by an
/// episode in progress that the trainer never used (always `None` in the files it wrote).
/// Read with bincode and turned into a buffer with `EpisodicReplay::try_from`, which refuses
/// one that holds an episode in progress.
#[derive(Debug, Deserialize)]
pub struct ReplayFormat3 {
    config: ReplayConfig,
    next_seq: u64,
    agent: VecDeque<Stored>,
    injected: VecDeque<Stored>,
    open: Option<Episode>,
}

impl TryFrom<ReplayFormat3> for EpisodicReplay {
    type Error = ReplayError;

    fn try_from(f: ReplayFormat3) -> Result<Self, ReplayError> {
        if f.open.is_some() {
            return Err(ReplayError::Corrupt(
                "a format-3 buffer holding an episode in progress, which this build does not \
                 keep"
                    .into(),
            ));
        }
        Self::from_store(Store {
            config: f.config,
            next_seq: f.next_seq,
            agent: f.agent,
            injected: f.injected,
        })
    }
}

/// Number of window starts of an episode of `len` transitions: one per transition, whatever
/// `opt` (windows past the end are right-padded).
fn starts(len: usize, _opt: usize) -> u64 {
    len as u64
}

/// Prefix sums of the start counts of one pool, for one `opt`.
#[derive(Debug, Default)]
struct PoolIndex {
    opt: usize,
    /// `(seq, absolute cumulative starts through this episode, starts of this episode)`,
    /// aligned with the pool's episodes.
    entries: VecDeque<(u64, u64, u64)>,
}

impl PoolIndex {
    fn sync(&mut self, pool: &VecDeque<Stored>, opt: usize) {
        if self.opt != opt {
            self.entries.clear();
            self.opt = opt;
        }
        let front_seq = pool.front().map(|e| e.seq);
        while let Some(&(seq, _, _)) = self.entries.front() {
            if front_seq.is_none_or(|f| seq < f) {
                self.entries.pop_front();
            } else {
                break;
            }
        }
        if self.entries.len() > pool.len()
            || self
                .entries
                .back()
                .is_some_and(|e| e.0 != pool[self.entries.len() - 1].seq)
        {
            // Cannot happen with FIFO pools; rebuild rather than trust a stale index.
            self.entries.clear();
        }
        let mut cum = self.entries.back().map_or(0, |e| e.1);
        for ep in pool.iter().skip(self.entries.len()) {
            let c = starts(ep.episode.len(), opt);
            cum += c;
            self.entries.push_back((ep.seq, cum, c));
        }
    }

    fn total(&self) -> u64 {
        match (self.entries.front(), self.entries.back()) {
            (Some(f), Some(b)) => b.1 - (f.1 - f.2),
            _ => 0,
        }
    }

    /// The episode index and start of position `u` in `0 .. total()`.
    fn locate(&self, u: u64) -> (usize, usize) {
        let f = self.entries[0];
        let abs = f.1 - f.2 + u;
        let i = self.entries.partition_point(|e| e.1 <= abs);
        let e = self.entries[i];
        (i, (abs - (e.1 - e.2)) as usize)
    }
}

/// The sampling caches of both pools (agent, injected).
#[derive(Debug, Default)]
struct Index {
    agent: PoolIndex,
    injected: PoolIndex,
}

/// Episodic replay buffer with whole-episode FIFO eviction, uniform window sampling and
/// experience injection.
///
/// Serialises (serde) to its configuration and episodes; the sampling cache
/// is rebuilt on demand, so a restored buffer draws exactly the same windows from the same
/// generator state.
#[derive(Debug)]
pub struct EpisodicReplay {
    store: Store,
    agent_transitions: usize,
    injected_transitions: usize,
    index: Mutex<Index>,
}

impl Clone for EpisodicReplay {
    fn clone(&self) -> Self {
        Self {
            store: self.store.clone(),
            agent_transitions: self.agent_transitions,
            injected_transitions: self.injected_transitions,
            index: Mutex::default(),
        }
    }
}

impl PartialEq for EpisodicReplay {
    /// Same configuration and episodes (with their order).
    fn eq(&self, other: &Self) -> bool {
        self.store == other.store
    }
}

impl Serialize for EpisodicReplay {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.store.serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for EpisodicReplay {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let store = Store::deserialize(deserializer)?;
        Self::from_store(store).map_err(serde::de::Error::custom)
    }
}

impl EpisodicReplay {
    /// An empty buffer.
    pub fn new(config: ReplayConfig) -> Result<Self, ReplayError> {
        config.validate()?;
        Ok(Self {
            store: Store {
                config,
                next_seq: 0,
                agent: VecDeque::new(),
                injected: VecDeque::new(),
            },
            agent_transitions: 0,
            injected_transitions: 0,
            index: Mutex::default(),
        })
    }

    fn from_store(store: Store) -> Result<Self, ReplayError> {
        store.config.validate()?;
        let corrupt = |m: String| Err(ReplayError::Corrupt(m));
        let mut totals = [0usize; 2];
        for (p, (pool, injected)) in [(&store.agent, false), (&store.injected, true)]
            .into_iter()
            .enumerate()
        {
            let mut last: Option<u64> = None;
            for s in pool {
                s.episode.check(&store.config)?;
                if s.episode.injected != injected {
                    return corrupt(format!("episode {} is in the wrong pool", s.seq));
                }
                if last.is_some_and(|l| s.seq <= l) || s.seq >= store.next_seq {
                    return corrupt(format!("episode sequence number {} out of order", s.seq));
                }
                last = Some(s.seq);
                totals[p] += s.episode.len();
            }
        }
        Ok(Self {
            store,
            agent_transitions: totals[0],
            injected_transitions: totals[1],
            index: Mutex::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &ReplayConfig {
        &self.store.config
    }

    /// Transitions held, in the agent's and injected episodes.
    pub fn len_transitions(&self) -> usize {
        self.agent_transitions + self.injected_transitions
    }

    /// The agent's own transitions: what `capacity` bounds.
    pub fn agent_len_transitions(&self) -> usize {
        self.agent_transitions
    }

    /// True when the buffer holds no transition at all.
    pub fn is_empty(&self) -> bool {
        self.len_transitions() == 0
    }

    /// Transitions in injected episodes.
    pub fn injected_transitions(&self) -> usize {
        self.injected_transitions
    }

    /// Episodes held, agent and injected.
    pub fn num_episodes(&self) -> usize {
        self.store.agent.len() + self.store.injected.len()
    }

    /// Injected episodes held.
    pub fn num_injected_episodes(&self) -> usize {
        self.store.injected.len()
    }

    /// The episodes, oldest first (agent and injected interleaved by insertion).
    pub fn episodes(&self) -> Vec<&Episode> {
        let mut all: Vec<&Stored> = self
            .store
            .agent
            .iter()
            .chain(self.store.injected.iter())
            .collect();
        all.sort_by_key(|s| s.seq);
        all.into_iter().map(|s| &s.episode).collect()
    }

    /// Drops every episode.
    pub fn clear(&mut self) {
        self.store.agent.clear();
        self.store.injected.clear();
        self.agent_transitions = 0;
        self.injected_transitions = 0;
        *self.index_lock() = Index::default();
    }

    /// Number of window positions for `opt` optimisation steps (agent and injected).
    pub fn num_positions(&self, opt: usize) -> u64 {
        let mut index = self.index_lock();
        index.agent.sync(&self.store.agent, opt);
        index.injected.sync(&self.store.injected, opt);
        index.agent.total() + index.injected.total()
    }

    /// Adds a whole episode once it has ended: the agent's own, or a teacher's when
    /// `episode.injected`.
    ///
    /// When `state_dim > 0`, `states` may be empty (read as zeros, e.g. for a teacher with
    /// another network); when `state_dim == 0` any states are dropped. Adding an injected
    /// episode evicts the oldest injected episodes until the injected transitions fit in
    /// their own budget, `floor(max_injected_fraction * capacity)`; adding an agent episode
    /// evicts the oldest agent episodes while the agent's transitions exceed `capacity`.
    #[allow(
        clippy::expect_used,
        reason = "injected transitions are counted from the injected episodes held"
    )]
    pub fn add_episode(&mut self, mut episode: Episode) -> Result<(), ReplayError> {
        let cfg = self.store.config;
        if cfg.state_dim == 0 {
            episode.states = Vec::new();
        }
        episode.check(&cfg)?;
        if episode.injected {
            let limit = cfg.max_injected_transitions();
            let len = episode.len();
            if len > limit {
                return Err(ReplayError::InjectedTooLong { len, limit });
            }
            while self.injected_transitions + len > limit {
                let old = self
                    .store
                    .injected
                    .pop_front()
                    .expect("injected transitions counted without an injected episode");
                self.injected_transitions -= old.episode.len();
            }
        }
        self.insert(episode);
        Ok(())
    }

    fn insert(&mut self, episode: Episode) {
        let seq = self.store.next_seq;
        self.store.next_seq += 1;
        let len = episode.len();
        let stored = Stored { seq, episode };
        if stored.episode.injected {
            self.injected_transitions += len;
            self.store.injected.push_back(stored);
        } else {
            self.agent_transitions += len;
            self.store.agent.push_back(stored);
            self.evict_over_capacity();
        }
    }

    /// Evicts the agent's oldest episodes while its transitions exceed the capacity. Injected
    /// episodes are not touched. The newest agent episode is never evicted: capacity is
    /// exceeded only by a buffer holding one single agent episode longer than the capacity.
    #[allow(
        clippy::expect_used,
        reason = "agent transitions are counted from the agent episodes held"
    )]
    fn evict_over_capacity(&mut self) {
        while self.agent_len_transitions() > self.store.config.capacity {
            if self.store.agent.len() <= 1 {
                break;
            }
            let old = self.store.agent.pop_front().expect("agent episode");
            self.agent_transitions -= old.episode.len();
        }
    }

    fn index_lock(&self) -> MutexGuard<'_, Index> {
        // The index is a cache that `sync` repairs, so a poisoned lock is still usable.
        self.index.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Draws `n` windows uniformly over all positions of the episodes held (agent and
    /// injected alike; see the [module docs](self)). Returns `None` when there is none.
    ///
    /// # Panics
    ///
    /// If `opt == 0`.
    #[allow(
        clippy::expect_used,
        reason = "positions count steps held in memory, far below i64::MAX"
    )]
    pub fn sample(
        &self,
        rng: &mut NpRng,
        n: usize,
        scan: usize,
        opt: usize,
    ) -> Option<SequenceBatch> {
        assert!(opt > 0, "sample: opt must be at least 1");
        let mut index = self.index_lock();
        index.agent.sync(&self.store.agent, opt);
        index.injected.sync(&self.store.injected, opt);
        let (ta, ti) = (index.agent.total(), index.injected.total());
        let total = ta + ti;
        if total == 0 {
            return None;
        }
        let mut batch = self.empty_batch(n, scan, opt);
        let high = i64::try_from(total).expect("position count fits in i64");
        for w in 0..n {
            let u = rng.integers(0, high) as u64;
            let (pool, idx, u) = if u < ta {
                (&self.store.agent, &index.agent, u)
            } else {
                (&self.store.injected, &index.injected, u - ta)
            };
            let (e, t) = idx.locate(u);
            self.write_window(&mut batch, w, &pool[e].episode, t);
        }
        Some(batch)
    }

    /// Draws `round(n * injected_share)` windows uniformly over the positions of injected
    /// episodes (first in the batch) and the rest uniformly over the agent's own episodes.
    /// If one pool is empty every window comes from the other. Returns `None` when the buffer
    /// holds no episode. Annealing the share towards 0 over training is up to the caller.
    ///
    /// # Panics
    ///
    /// If `opt == 0` or `injected_share` is not in `[0, 1]`.
    #[allow(
        clippy::expect_used,
        reason = "positions count steps held in memory, far below i64::MAX"
    )]
    pub fn sample_mixed(
        &self,
        rng: &mut NpRng,
        n: usize,
        scan: usize,
        opt: usize,
        injected_share: f64,
    ) -> Option<SequenceBatch> {
        assert!(opt > 0, "sample_mixed: opt must be at least 1");
        assert!(
            (0.0..=1.0).contains(&injected_share),
            "sample_mixed: injected_share must be in [0, 1] (got {injected_share})"
        );
        let mut index = self.index_lock();
        index.agent.sync(&self.store.agent, opt);
        index.injected.sync(&self.store.injected, opt);
        let (ta, ti) = (index.agent.total(), index.injected.total());
        let n_injected = match (ta, ti) {
            (0, 0) => return None,
            (0, _) => n,
            (_, 0) => 0,
            _ => ((n as f64 * injected_share).round() as usize).min(n),
        };
        let mut batch = self.empty_batch(n, scan, opt);
        for w in 0..n {
            let (pool, idx, total) = if w < n_injected {
                (&self.store.injected, &index.injected, ti)
            } else {
                (&self.store.agent, &index.agent, ta)
            };
            let high = i64::try_from(total).expect("position count fits in i64");
            let u = rng.integers(0, high) as u64;
            let (e, t) = idx.locate(u);
            self.write_window(&mut batch, w, &pool[e].episode, t);
        }
        Some(batch)
    }

    fn empty_batch(&self, n: usize, scan: usize, opt: usize) -> SequenceBatch {
        let cfg = &self.store.config;
        let steps = scan + opt;
        SequenceBatch {
            n,
            scan,
            opt,
            obs_dim: cfg.obs_dim,
            act_dim: cfg.act_dim,
            obs: vec![0.0; n * (steps + 1) * cfg.obs_dim],
            actions: vec![0.0; n * steps * cfg.act_dim],
            rewards: vec![0.0; n * steps],
            mask: vec![0.0; n * steps],
            scan_len: vec![0; n],
            opt_len: vec![0; n],
            tail_terminated: vec![0.0; n],
            injected: vec![0.0; n],
            stored_state: (cfg.state_dim > 0).then(|| vec![0.0; n * cfg.state_dim]),
            state_dim: cfg.state_dim,
        }
    }

    /// Copies the window of `ep` starting at `t` into slot `w` of `b`. The real steps
    /// `t - scan_len .. t + opt_len` are contiguous both in the episode and in the window
    /// (from slot `scan - scan_len`), so each array is one copy.
    fn write_window(&self, b: &mut SequenceBatch, w: usize, ep: &Episode, t: usize) {
        let (od, ad, sd) = (b.obs_dim, b.act_dim, b.state_dim);
        let (scan, opt) = (b.scan, b.opt);
        let steps = scan + opt;
        let n_e = ep.len();
        let scan_len = scan.min(t);
        let opt_len = opt.min(n_e - t);
        let first = t - scan_len;
        let real = scan_len + opt_len;
        let slot0 = scan - scan_len;

        let o = (w * (steps + 1) + slot0) * od;
        b.obs[o..o + (real + 1) * od].copy_from_slice(&ep.obs[first * od..(first + real + 1) * od]);
        let a = (w * steps + slot0) * ad;
        b.actions[a..a + real * ad].copy_from_slice(&ep.actions[first * ad..(first + real) * ad]);
        let r = w * steps + slot0;
        b.rewards[r..r + real].copy_from_slice(&ep.rewards[first..first + real]);
        b.mask[r..r + real].fill(1.0);
        b.scan_len[w] = scan_len;
        b.opt_len[w] = opt_len;
        b.tail_terminated[w] = if ep.terminated && t + opt_len == n_e {
            1.0
        } else {
            0.0
        };
        b.injected[w] = if ep.injected { 1.0 } else { 0.0 };
        if let Some(states) = b.stored_state.as_mut() {
            if !ep.states.is_empty() {
                states[w * sd..(w + 1) * sd]
                    .copy_from_slice(&ep.states[first * sd..(first + 1) * sd]);
            }
        }
    }
}

/// `Ok` when a slice has the expected length, else a [`ReplayError::Dimension`] naming it.
fn check_dim(what: &'static str, expected: usize, got: usize) -> Result<(), ReplayError> {
    if expected == got {
        Ok(())
    } else {
        Err(ReplayError::Dimension {
            what,
            expected,
            got,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Value stored for episode `id`, step `k`: distinct, non-zero, exact in f32.
    fn code(id: usize, k: usize) -> f32 {
        (id * 1000 + k + 1) as f32
    }

    fn decode(v: f32) -> (usize, usize) {
        let x = v as usize - 1;
        (x / 1000, x % 1000)
    }

    const OD: usize = 2;
    const AD: usize = 1;
    const SD: usize = 3;

    /// An episode whose every value encodes (id, step): obs component `c` of step `k` is
    /// `code(id, k) + 0.25 c`, actions `-code`, rewards `code`, states `code + 0.5 c`.
    fn coded_episode(id: usize, len: usize, terminated: bool, injected: bool) -> Episode {
        let mut ep = Episode {
            terminated,
            truncated: !terminated,
            injected,
            ..Episode::default()
        };
        for k in 0..=len {
            for c in 0..OD {
                ep.obs.push(code(id, k) + 0.25 * c as f32);
            }
        }
        for k in 0..len {
            ep.actions.push(-code(id, k));
            ep.rewards.push(code(id, k));
            for c in 0..SD {
                ep.states.push(code(id, k) + 0.5 * c as f32);
            }
        }
        ep
    }

    /// Adds a coded agent episode of `len` steps.
    fn add_coded(buf: &mut EpisodicReplay, id: usize, len: usize, terminated: bool) {
        buf.add_episode(coded_episode(id, len, terminated, false))
            .unwrap();
    }

    fn config(capacity: usize) -> ReplayConfig {
        ReplayConfig::new(capacity, OD, AD).with_state_dim(SD)
    }

    /// What the buffer should hold: (id, len, terminated, injected) of the closed episodes.
    type Meta = (usize, usize, bool, bool);

    /// Checks every window of `b` against the episodes in `eps` (by id). Returns the
    /// (id, t) of each window.
    fn check_batch(b: &SequenceBatch, eps: &[Meta]) -> Vec<(usize, usize)> {
        let (s, l) = (b.scan, b.opt);
        let steps = s + l;
        assert_eq!(b.obs.len(), b.n * (steps + 1) * OD);
        assert_eq!(b.actions.len(), b.n * steps * AD);
        assert_eq!(b.rewards.len(), b.n * steps);
        assert_eq!(b.mask.len(), b.n * steps);
        assert_eq!(b.state_dim, SD);
        let states = b.stored_state.as_ref().expect("states stored");
        let mut out = Vec::new();
        for w in 0..b.n {
            let (sl, ol) = (b.scan_len[w], b.opt_len[w]);
            assert!(sl <= s && (1..=l).contains(&ol), "lengths {sl} {ol}");
            let first_slot = s - sl;
            let obs0 = b.obs[(w * (steps + 1) + first_slot) * OD];
            let (id, first_step) = decode(obs0);
            let &(_, len, terminated, injected) = eps
                .iter()
                .find(|m| m.0 == id)
                .unwrap_or_else(|| panic!("window from episode {id} not in the buffer"));
            let t = first_step + sl;
            // Scan clipped at the episode start, opt clipped at the episode end.
            assert_eq!(sl, s.min(t));
            assert!(t < len);
            assert_eq!(ol, l.min(len - t));
            for j in 0..=steps {
                let real_obs = j >= first_slot && j <= s + ol;
                for c in 0..OD {
                    let v = b.obs[(w * (steps + 1) + j) * OD + c];
                    if real_obs {
                        let k = t + j - s;
                        assert_eq!(v, code(id, k) + 0.25 * c as f32, "obs slot {j}");
                    } else {
                        assert_eq!(v, 0.0, "obs padding slot {j}");
                    }
                }
                if j == steps {
                    break;
                }
                let real = j >= first_slot && j < s + ol;
                let m = b.mask[w * steps + j];
                let r = b.rewards[w * steps + j];
                let a = b.actions[(w * steps + j) * AD];
                if real {
                    let k = t + j - s;
                    assert_eq!((m, r, a), (1.0, code(id, k), -code(id, k)), "slot {j}");
                } else {
                    assert_eq!((m, r, a), (0.0, 0.0, 0.0), "padding slot {j}");
                }
            }
            let tail_term = terminated && t + ol == len;
            assert_eq!(b.tail_terminated[w], if tail_term { 1.0 } else { 0.0 });
            assert_eq!(b.injected[w], if injected { 1.0 } else { 0.0 });
            for c in 0..SD {
                let expected = if injected {
                    0.0 // injected test episodes carry no states
                } else {
                    code(id, t - sl) + 0.5 * c as f32
                };
                assert_eq!(states[w * SD + c], expected);
            }
            out.push((id, t));
        }
        out
    }

    /// A naive model of the eviction rules, on a plain Vec.
    #[derive(Default)]
    struct Model {
        closed: Vec<Meta>,
    }

    impl Model {
        fn total(&self) -> usize {
            self.closed.iter().map(|m| m.1).sum::<usize>()
        }
        /// The agent's transitions: what the capacity bounds.
        fn agent_total(&self) -> usize {
            self.closed
                .iter()
                .filter(|m| !m.3)
                .map(|m| m.1)
                .sum::<usize>()
        }
        /// Evicts the oldest agent episodes while the agent is over capacity; injected
        /// episodes have their own budget.
        fn evict(&mut self, cap: usize) {
            loop {
                let agent = self.closed.iter().filter(|m| !m.3).count();
                if self.agent_total() <= cap || agent <= 1 {
                    break;
                }
                let pos = self.closed.iter().position(|m| !m.3).unwrap();
                self.closed.remove(pos);
            }
        }
    }

    #[derive(Debug, Clone)]
    enum Op {
        /// The agent's own episode: (len, terminated).
        Agent(usize, bool),
        /// Injected whole episode: (len, terminated).
        Inject(usize, bool),
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            3 => (1usize..15, any::<bool>()).prop_map(|(l, t)| Op::Agent(l, t)),
            1 => (1usize..10, any::<bool>()).prop_map(|(l, t)| Op::Inject(l, t)),
        ]
    }

    /// Builds a buffer and its model from ops.
    fn build(cap: usize, ops: &[Op]) -> (EpisodicReplay, Model) {
        let mut buf = EpisodicReplay::new(config(cap)).unwrap();
        let mut model = Model::default();
        let inj_limit = config(cap).max_injected_transitions();
        for (id, op) in ops.iter().enumerate() {
            match *op {
                Op::Agent(len, term) => {
                    add_coded(&mut buf, id, len, term);
                    model.closed.push((id, len, term, false));
                    model.evict(cap);
                }
                Op::Inject(len, term) => {
                    let mut ep = coded_episode(id, len, term, true);
                    ep.states.clear();
                    let res = buf.add_episode(ep);
                    if len > inj_limit {
                        assert!(matches!(res, Err(ReplayError::InjectedTooLong { .. })));
                        continue;
                    }
                    res.unwrap();
                    loop {
                        let inj: usize = model.closed.iter().filter(|m| m.3).map(|m| m.1).sum();
                        if inj + len <= inj_limit {
                            break;
                        }
                        let pos = model.closed.iter().position(|m| m.3).unwrap();
                        model.closed.remove(pos);
                    }
                    model.closed.push((id, len, term, true));
                    model.evict(cap);
                }
            }
        }
        (buf, model)
    }

    fn ids(buf: &EpisodicReplay) -> Vec<usize> {
        buf.episodes().iter().map(|e| decode(e.obs[0]).0).collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        #[test]
        fn prop_windows_and_eviction(
            cap in 5usize..80,
            ops in prop::collection::vec(op(), 0..25),
            n in 1usize..40,
            scan in 0usize..7,
            opt in 1usize..7,
            seed in any::<u64>(),
            share in 0.0f64..=1.0,
        ) {
            let (buf, model) = build(cap, &ops);
            // Eviction: exactly the model's episodes, oldest first, same counts.
            prop_assert_eq!(ids(&buf), model.closed.iter().map(|m| m.0).collect::<Vec<_>>());
            prop_assert_eq!(buf.len_transitions(), model.total());
            let inj: usize = model.closed.iter().filter(|m| m.3).map(|m| m.1).sum();
            prop_assert_eq!(buf.injected_transitions(), inj);
            prop_assert!(inj <= config(cap).max_injected_transitions());
            // Capacity bounds the agent's transitions unless one single agent episode is
            // longer than it; injected ones have their own budget.
            let agent_eps = buf.num_episodes() - buf.num_injected_episodes();
            prop_assert!(buf.agent_len_transitions() <= cap || agent_eps <= 1);
            prop_assert_eq!(buf.len_transitions(), buf.agent_len_transitions() + inj);

            let mut rng = NpRng::from_seed(seed);
            match buf.sample(&mut rng, n, scan, opt) {
                None => prop_assert_eq!(buf.num_episodes(), 0),
                Some(b) => {
                    prop_assert_eq!(b.n, n);
                    check_batch(&b, &model.closed);
                }
            }
            match buf.sample_mixed(&mut rng, n, scan, opt, share) {
                None => prop_assert_eq!(buf.num_episodes(), 0),
                Some(b) => {
                    check_batch(&b, &model.closed);
                    let n_inj = b.injected.iter().filter(|&&x| x == 1.0).count();
                    let has_inj = buf.num_injected_episodes() > 0;
                    let has_agent = buf.num_episodes() > buf.num_injected_episodes();
                    let expected = match (has_agent, has_inj) {
                        (true, true) => (n as f64 * share).round() as usize,
                        (false, true) => n,
                        _ => 0,
                    };
                    prop_assert_eq!(n_inj, expected);
                    // Injected windows come first.
                    prop_assert!(b.injected[..n_inj].iter().all(|&x| x == 1.0));
                }
            }
        }

        #[test]
        fn prop_serde_round_trip_same_samples(
            cap in 5usize..60,
            ops in prop::collection::vec(op(), 1..12),
            seed in any::<u64>(),
        ) {
            let (buf, _) = build(cap, &ops);
            let mut rng = NpRng::from_seed(seed);
            // Warm the original's cache with another opt first: it must not matter.
            let _ = buf.sample(&mut rng.clone(), 3, 1, 2);
            let json = serde_json::to_string(&buf).unwrap();
            let back: EpisodicReplay = serde_json::from_str(&json).unwrap();
            prop_assert!(back == buf);
            prop_assert_eq!(back.len_transitions(), buf.len_transitions());
            prop_assert_eq!(back.injected_transitions(), buf.injected_transitions());
            let mut rng2 = rng.clone();
            prop_assert_eq!(buf.sample(&mut rng, 16, 3, 4), back.sample(&mut rng2, 16, 3, 4));
            prop_assert_eq!(
                buf.sample_mixed(&mut rng, 16, 2, 3, 0.3),
                back.sample_mixed(&mut rng2, 16, 2, 3, 0.3)
            );
            prop_assert_eq!(rng, rng2);
        }
    }

    /// Every transition starts a window equally often (uniform over transitions, not over
    /// the start positions of full windows): the last `opt - 1` steps of each episode, its
    /// terminal step included, are as likely as any other, with right-padded windows.
    #[test]
    fn uniform_over_transitions() {
        // Lengths 3, 5, 1, 8, 2: 19 transitions, each a start, with opt = 3.
        let lens = [3usize, 5, 1, 8, 2];
        let mut buf = EpisodicReplay::new(config(100)).unwrap();
        for (id, &len) in lens.iter().enumerate() {
            add_coded(&mut buf, id, len, id % 2 == 0);
        }
        let metas: Vec<Meta> = lens
            .iter()
            .enumerate()
            .map(|(id, &len)| (id, len, id % 2 == 0, false))
            .collect();
        assert_eq!(buf.num_positions(3), 19);
        let mut counts = std::collections::HashMap::new();
        let mut rng = NpRng::from_seed(123);
        let draws = 190_000;
        for _ in 0..(draws / 500) {
            let b = buf.sample(&mut rng, 500, 2, 3).unwrap();
            for key in check_batch(&b, &metas) {
                *counts.entry(key).or_insert(0usize) += 1;
            }
        }
        // Every transition of every episode started windows, the last ones included.
        for (id, &len) in lens.iter().enumerate() {
            for t in 0..len {
                assert!(counts.contains_key(&(id, t)), "({id}, {t}) never sampled");
            }
        }
        assert_eq!(counts.len(), 19, "{counts:?}");
        let expected = draws as f64 / 19.0;
        let chi2: f64 = counts
            .values()
            .map(|&c| (c as f64 - expected).powi(2) / expected)
            .sum();
        // 18 degrees of freedom: P(chi2 > 42.3) = 0.001.
        assert!(chi2 < 42.3, "chi2 = {chi2}, counts {counts:?}");
    }

    #[test]
    fn uniform_across_pools() {
        // Agent: one episode with 5 starts (len 5); injected: one with 3 (len 3).
        let mut buf = EpisodicReplay::new(config(100)).unwrap();
        add_coded(&mut buf, 0, 5, true);
        let mut ep = coded_episode(1, 3, true, true);
        ep.states.clear();
        buf.add_episode(ep).unwrap();
        let mut rng = NpRng::from_seed(5);
        let b = buf.sample(&mut rng, 60_000, 0, 2).unwrap();
        let inj = b.injected.iter().sum::<f32>() as f64 / 60_000.0;
        assert!((inj - 3.0 / 8.0).abs() < 0.01, "{inj}");
    }

    #[test]
    fn hand_checked_window() {
        // One terminated episode of 4 steps, scan 2, opt 3, start forced by sampling enough.
        let mut buf = EpisodicReplay::new(config(100)).unwrap();
        add_coded(&mut buf, 7, 4, true);
        let mut rng = NpRng::from_seed(0);
        let b = buf.sample(&mut rng, 200, 2, 3).unwrap();
        let metas = [(7, 4, true, false)];
        let keys = check_batch(&b, &metas);
        // Starts 0 and 1 both occur.
        assert!(keys.contains(&(7, 0)) && keys.contains(&(7, 1)));
        let w = keys.iter().position(|k| *k == (7, 1)).unwrap();
        // Start 1: scan_len 1 (slot 0 padding), opt steps 1, 2, 3, bootstrap obs 4, which
        // ends the episode by termination.
        assert_eq!((b.scan_len[w], b.opt_len[w]), (1, 3));
        assert_eq!(&b.mask[w * 5..w * 5 + 5], &[0.0, 1.0, 1.0, 1.0, 1.0]);
        assert_eq!(
            &b.rewards[w * 5..w * 5 + 5],
            &[0.0, code(7, 0), code(7, 1), code(7, 2), code(7, 3)]
        );
        assert_eq!(b.obs[(w * 6 + 5) * OD], code(7, 4));
        assert_eq!(b.tail_terminated[w], 1.0);
        assert_eq!(
            &b.stored_state.as_ref().unwrap()[w * SD..w * SD + 1],
            &[code(7, 0)]
        );
        let w0 = keys.iter().position(|k| *k == (7, 0)).unwrap();
        assert_eq!(b.tail_terminated[w0], 0.0);
        assert_eq!(b.obs[(w0 * 6 + 5) * OD], code(7, 3));
    }

    #[test]
    fn short_episode_right_padded() {
        // Truncated episode of 2 steps with opt 4: one window, opt_len 2, bootstrap at
        // slot scan + 2, not terminated.
        let mut buf = EpisodicReplay::new(config(100)).unwrap();
        add_coded(&mut buf, 3, 2, false);
        let mut rng = NpRng::from_seed(1);
        let b = buf.sample(&mut rng, 1, 1, 4).unwrap();
        check_batch(&b, &[(3, 2, false, false)]);
        assert_eq!((b.scan_len[0], b.opt_len[0]), (0, 2));
        assert_eq!(b.mask, vec![0.0, 1.0, 1.0, 0.0, 0.0]);
        assert_eq!(b.obs[3 * OD], code(3, 2));
        assert_eq!(b.tail_terminated[0], 0.0);
    }

    #[test]
    fn eviction_oldest_first_and_a_long_episode_kept_alone() {
        let mut buf = EpisodicReplay::new(config(10)).unwrap();
        assert!(buf.sample(&mut NpRng::from_seed(0), 4, 0, 1).is_none());
        add_coded(&mut buf, 0, 4, true);
        add_coded(&mut buf, 1, 4, true);
        assert_eq!(ids(&buf), vec![0, 1]);
        add_coded(&mut buf, 2, 3, true); // 11 > 10: evict episode 0
        assert_eq!(ids(&buf), vec![1, 2]);
        assert_eq!(buf.len_transitions(), 7);
        // An episode longer than the capacity evicts every other one, never itself.
        add_coded(&mut buf, 3, 13, false);
        assert_eq!((buf.num_episodes(), buf.len_transitions()), (1, 13));
        add_coded(&mut buf, 4, 1, true);
        assert_eq!(ids(&buf), vec![4]);
    }

    #[test]
    fn injected_quota_evicts_injected_first() {
        // Capacity 20, quota 10 injected transitions.
        let mut buf = EpisodicReplay::new(config(20)).unwrap();
        let inject =
            |buf: &mut EpisodicReplay, id, len| buf.add_episode(coded_episode(id, len, true, true));
        inject(&mut buf, 0, 4).unwrap();
        add_coded(&mut buf, 1, 3, true);
        inject(&mut buf, 2, 4).unwrap();
        assert_eq!(ids(&buf), vec![0, 1, 2]);
        inject(&mut buf, 3, 4).unwrap(); // 12 > 10 injected: drop injected 0, not agent 1
        assert_eq!(ids(&buf), vec![1, 2, 3]);
        assert_eq!(buf.injected_transitions(), 8);
        assert_eq!(
            inject(&mut buf, 4, 11),
            Err(ReplayError::InjectedTooLong { len: 11, limit: 10 })
        );
        assert_eq!(ids(&buf), vec![1, 2, 3]);
        // The agent's own episodes, however many, never evict injected ones: those have
        // their own budget on top of the capacity.
        for id in 10..20 {
            add_coded(&mut buf, id, 5, true);
        }
        assert_eq!(buf.num_injected_episodes(), 2);
        assert_eq!(buf.injected_transitions(), 8);
        assert_eq!(buf.agent_len_transitions(), 20);
        assert_eq!(ids(&buf), vec![2, 3, 16, 17, 18, 19]);
        let none = EpisodicReplay::new(config(20).with_max_injected_fraction(0.0));
        assert!(none
            .unwrap()
            .add_episode(coded_episode(0, 1, true, true))
            .is_err());
    }

    #[test]
    fn rejects_bad_input() {
        assert!(EpisodicReplay::new(ReplayConfig::new(0, 1, 1)).is_err());
        assert!(EpisodicReplay::new(config(10).with_max_injected_fraction(1.5)).is_err());
        let mut buf = EpisodicReplay::new(config(10)).unwrap();
        let mut ep = coded_episode(0, 3, true, false);
        ep.states.pop();
        assert!(matches!(
            buf.add_episode(ep),
            Err(ReplayError::Dimension {
                what: "episode states",
                ..
            })
        ));
        assert!(buf.is_empty(), "a rejected episode stores nothing");
        assert_eq!(
            buf.add_episode(Episode::default()),
            Err(ReplayError::EmptyEpisode)
        );
        let mut ep = coded_episode(0, 3, true, false);
        ep.obs.pop();
        assert!(buf.add_episode(ep).is_err());
        // A corrupt checkpoint is refused.
        add_coded(&mut buf, 0, 3, true);
        let mut json: serde_json::Value = serde_json::to_value(&buf).unwrap();
        json["agent"][0]["episode"]["rewards"] = serde_json::json!([1.0]);
        assert!(serde_json::from_value::<EpisodicReplay>(json).is_err());
    }

    #[test]
    fn states_optional() {
        // state_dim = 0: no stored_state, states dropped.
        let mut buf = EpisodicReplay::new(ReplayConfig::new(10, OD, AD)).unwrap();
        buf.add_episode(coded_episode(0, 3, true, false)).unwrap();
        assert!(buf.episodes()[0].states.is_empty());
        let b = buf.sample(&mut NpRng::from_seed(0), 2, 1, 1).unwrap();
        assert_eq!((b.stored_state, b.state_dim), (None, 0));
        // state_dim > 0 and an episode without states: its windows start from zeros.
        let mut buf = EpisodicReplay::new(config(10)).unwrap();
        let mut ep = coded_episode(0, 3, true, false);
        ep.states.clear();
        buf.add_episode(ep).unwrap();
        let b = buf.sample(&mut NpRng::from_seed(0), 2, 1, 1).unwrap();
        assert_eq!(b.stored_state, Some(vec![0.0; 2 * SD]));
    }

    #[test]
    fn clear_and_reuse() {
        let mut buf = EpisodicReplay::new(config(50)).unwrap();
        add_coded(&mut buf, 0, 5, true);
        let mut rng = NpRng::from_seed(0);
        assert!(buf.sample(&mut rng, 2, 0, 2).is_some());
        buf.clear();
        assert_eq!((buf.len_transitions(), buf.num_episodes()), (0, 0));
        assert!(buf.sample(&mut rng, 2, 0, 2).is_none());
        add_coded(&mut buf, 2, 4, true);
        let b = buf.sample(&mut rng, 8, 0, 2).unwrap();
        check_batch(&b, &[(2, 4, true, false)]);
        assert_eq!(buf.num_positions(2), 4);
    }

    #[test]
    fn index_follows_evictions_incrementally() {
        // Interleave pushes, evictions and samples with a changing opt; every batch must be
        // consistent with the episodes present.
        let mut buf = EpisodicReplay::new(config(40)).unwrap();
        let mut rng = NpRng::from_seed(77);
        let mut present: Vec<Meta> = Vec::new();
        for id in 0..200 {
            let len = 1 + (id * 7) % 11;
            add_coded(&mut buf, id, len, id % 3 == 0);
            present.push((id, len, id % 3 == 0, false));
            let live = ids(&buf);
            present.retain(|m| live.contains(&m.0));
            let opt = 1 + id % 4;
            let b = buf.sample(&mut rng, 10, id % 3, opt).unwrap();
            check_batch(&b, &present);
            let expected: u64 = present.iter().map(|m| starts(m.1, opt)).sum();
            assert_eq!(buf.num_positions(opt), expected);
        }
    }

    #[test]
    fn a_large_buffer_samples() {
        // 1e5 transitions in 100 episodes; 64 windows of 120 + 8 steps.
        let cfg = ReplayConfig::new(100_000, 24, 4).with_state_dim(16);
        let mut buf = EpisodicReplay::new(cfg).unwrap();
        for e in 0..100 {
            let len = 1000;
            let ep = Episode {
                obs: vec![e as f32; (len + 1) * 24],
                actions: vec![0.0; len * 4],
                rewards: vec![1.0; len],
                states: vec![0.5; len * 16],
                terminated: e % 2 == 0,
                truncated: e % 2 == 1,
                injected: false,
            };
            buf.add_episode(ep).unwrap();
        }
        assert_eq!(buf.len_transitions(), 100_000);
        let mut rng = NpRng::from_seed(0);
        for _ in 0..20 {
            let b = buf.sample(&mut rng, 64, 120, 8).unwrap();
            assert!(b.opt_len.iter().all(|&l| (1..=8).contains(&l)));
            let real: usize = b.scan_len.iter().zip(&b.opt_len).map(|(s, l)| s + l).sum();
            assert_eq!(b.mask.iter().filter(|&&m| m == 1.0).count(), real);
        }
    }
}
