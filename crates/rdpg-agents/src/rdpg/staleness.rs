//! Recurrent-state staleness (Kapturowski et al. 2019, "Recurrent Experience Replay in
//! Distributed Reinforcement Learning", Sec. 3): how far the states an update starts its
//! replayed windows from are from the states the current networks reach when they run along
//! the whole episode from its start, the state they would have carried had they acted.
//!
//! For positions `t` drawn uniformly over a replay's transitions, the state before step `t` is
//! computed from the episode start (the reference: a zero state at step 0, the current network
//! along steps `0..t`) and from a start an update can afford: the **stored** acting-time state
//! of step `t - k` followed by `k` steps of the current network (the update's start with
//! `burn_in_from_stored_state`, `k = scan_len`; `k = 0`: the stored state itself), or a **zero**
//! state at `t - k` followed by `k` steps (the paper's `h_init`; `k = 0`: no memory at all, the
//! scale of the gaps). Where `t < k` a burn-in starts at the episode start, as the update's
//! scan does, and is exact.
//!
//! Gaps, at step `t`: the actor's action, the RMS over action dimensions of
//! `mu(o_t | h) - mu(o_t | h_ref)` (actions lie in `[-1, 1]`); critic 0 at the replayed action
//! (its windows start from zero: no stored state), R2D2's `ΔQ = |Q(h) - Q(h_ref)|` over the
//! spread (max − min) of the reference `Q` over the drawn positions.

use std::collections::BTreeMap;

use rdpg_core::replay::{Episode, EpisodicReplay};
use rdpg_core::rng::NpRng;
use serde::Serialize;
use tch::Tensor;

use super::config::ScanMethod;
use super::lstm::{scan_state, RecState};
use super::RdpgAgent;
use crate::common::tensor::tensor_to_vec64;
use crate::error::{AgentError, Result};

/// The gap of one start, over one pool of positions.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct StartGap {
    /// Where the drawn positions come from: `agent` (the agent's own episodes), `agent, oldest
    /// quarter` … `agent, newest quarter` (by insertion), or `injected`.
    pub pool: String,
    /// `stored` or `zero`: the state at `t - burn_in`.
    pub start: String,
    /// Steps of the current network from the start to `t`.
    pub burn_in: usize,
    /// `actor` (action RMS gap) or `critic 0` (R2D2's ΔQ).
    pub net: String,
    /// Positions measured.
    pub positions: usize,
    /// Mean gap.
    pub mean: f64,
    /// 90th percentile of the gap.
    pub p90: f64,
    /// Largest gap.
    pub max: f64,
}

/// What [`state_staleness`] measured.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Staleness {
    /// Burn-in lengths measured.
    pub burn_ins: Vec<usize>,
    /// The agent's own `scan_len` (the burn-in its updates use).
    pub scan_len: usize,
    /// Whether its updates start from stored states (`burn_in_from_stored_state`).
    pub from_stored_state: bool,
    /// Spread (max − min) of critic 0's reference `Q` over the agent's drawn positions: the
    /// denominator of every ΔQ.
    pub q_spread: f64,
    /// One line per pool, start, burn-in and network.
    pub gaps: Vec<StartGap>,
}

/// The most positions one measurement draws (per pool).
pub const MAX_POSITIONS: usize = 1_000_000;

/// A drawn position: episode index (in [`EpisodicReplay::episodes`] order) and step.
type Position = (usize, usize);

/// Draws `n` positions uniformly over the transitions of `episodes` (indices into `all`).
fn draw(rng: &mut NpRng, all: &[&Episode], episodes: &[usize], n: usize) -> Vec<Position> {
    let mut ends = Vec::with_capacity(episodes.len());
    let mut total = 0u64;
    for &e in episodes {
        total += all[e].len() as u64;
        ends.push(total);
    }
    if total == 0 {
        return Vec::new();
    }
    let mut out: Vec<Position> = (0..n)
        .map(|_| {
            let u = rng.integers(0, total as i64) as u64;
            let i = ends.partition_point(|&end| end <= u);
            let start = if i == 0 { 0 } else { ends[i - 1] };
            (episodes[i], (u - start) as usize)
        })
        .collect();
    out.sort_unstable();
    out
}

/// The gaps at one position, one value per burn-in length.
struct At {
    /// The actor from the stored start (`None`: the episode stores no states).
    actor_stored: Vec<Option<f64>>,
    /// The actor from the zero start.
    actor_zero: Vec<f64>,
    /// Critic 0's `|Q - Q_ref|` from the zero start.
    q_zero: Vec<f64>,
    /// Critic 0's reference `Q`.
    q_ref: f64,
}

/// `x [1, T, E]` -> the `k` steps before each of `ts`, `[m, k, E]`, left-padded with step 0
/// (never read: the scan runs only each window's real steps), and their real lengths.
pub(super) fn scan_inputs(x: &Tensor, ts: &[usize], k: usize) -> (Tensor, Vec<usize>) {
    let idx: Vec<i64> = ts
        .iter()
        .flat_map(|&t| (0..k).map(move |j| (t + j).saturating_sub(k) as i64))
        .collect();
    let e = x.size()[2];
    let it = Tensor::from_slice(&idx).to_device(x.device());
    let xs = x
        .select(0, 0)
        .index_select(0, &it)
        .view([ts.len() as i64, k as i64, e]);
    (xs, ts.iter().map(|&t| t.min(k)).collect())
}

/// The rows `ts` of `[1, T, H]` states as a `[1, m, H]` state.
fn rows(h: &Tensor, c: &Tensor, ts: &Tensor) -> RecState {
    RecState {
        h: h.select(0, 0).index_select(0, ts).unsqueeze(0),
        c: c.select(0, 0).index_select(0, ts).unsqueeze(0),
    }
}

/// The gaps at steps `ts` of `ep`, one [`At`] per step.
fn episode_gaps(agent: &RdpgAgent, ep: &Episode, ts: &[usize], burn_ins: &[usize]) -> Vec<At> {
    let (kind, device) = (agent.kind, agent.device());
    let (d, a, n) = (
        agent.obs_dim() as i64,
        agent.act_dim() as i64,
        ep.len() as i64,
    );
    let actor = agent.actor();
    let critic = &agent.critics()[0];
    let m = ts.len() as i64;
    let obs = Tensor::from_slice(&ep.obs)
        .view([1, n + 1, d])
        .to_kind(kind)
        .to_device(device)
        .narrow(1, 0, n); // [1, n, D]: o_0 .. o_{n-1}
    let acts = Tensor::from_slice(&ep.actions)
        .view([1, n, a])
        .to_kind(kind)
        .to_device(device); // [1, n, A]
    let it =
        Tensor::from_slice(&ts.iter().map(|&t| t as i64).collect::<Vec<_>>()).to_device(device);
    let o_t = obs.select(0, 0).index_select(0, &it); // [m, D]
    let a_t = acts.select(0, 0).index_select(0, &it); // [m, A]

    // The actor: reference states before every step from the episode start, [1, n, H] each.
    let xa = actor.input_seq(&obs); // [1, n, E]
    let zero_a = actor.core.zero_state(1, kind, device);
    let (ha, ca) = actor.core.states_before(&xa, &zero_a);
    let act_ref = actor.step(&o_t, &rows(&ha, &ca, &it)).0; // [m, A]
    let action_gap = |s: &RecState| -> Vec<f64> {
        let diff = actor.step(&o_t, s).0 - &act_ref; // [m, A]
        tensor_to_vec64(&diff.square().mean_dim(1, false, kind).sqrt())
    };
    let stored = (!ep.states.is_empty()).then(|| {
        let w = ep.states.len() as i64 / n;
        let st = Tensor::from_slice(&ep.states)
            .view([n, w])
            .to_kind(kind)
            .to_device(device); // [n, 2H]: h then c
        (st.narrow(1, 0, w / 2), st.narrow(1, w / 2, w / 2))
    });

    // Critic 0 along the replayed actions.
    let xc = critic.input_seq(&obs, &acts); // [1, n, Ec]
    let zero_c = critic.core.zero_state(1, kind, device);
    let (hc, cc) = critic.core.states_before(&xc, &zero_c);
    let q_ref = critic.step(&o_t, &a_t, &rows(&hc, &cc, &it)).0; // [m]

    let mut out: Vec<At> = tensor_to_vec64(&q_ref)
        .into_iter()
        .map(|q_ref| At {
            actor_stored: Vec::new(),
            actor_zero: Vec::new(),
            q_zero: Vec::new(),
            q_ref,
        })
        .collect();
    for &k in burn_ins {
        let (xs, real) = scan_inputs(&xa, ts, k);
        let za = actor.core.zero_state(m, kind, device);
        let zero = action_gap(&scan_state(
            &actor.core,
            &xs,
            &real,
            &za,
            ScanMethod::Grouped,
        ));
        let from_stored = stored.as_ref().map(|(h, c)| {
            // The stored state before the first real burn-in step, t - min(k, t).
            let first: Vec<i64> = ts.iter().map(|&t| (t - t.min(k)) as i64).collect();
            let fi = Tensor::from_slice(&first).to_device(device);
            let init = RecState {
                h: h.index_select(0, &fi).unsqueeze(0),
                c: c.index_select(0, &fi).unsqueeze(0),
            };
            action_gap(&scan_state(
                &actor.core,
                &xs,
                &real,
                &init,
                ScanMethod::Grouped,
            ))
        });
        let (xs, real) = scan_inputs(&xc, ts, k);
        let zc = critic.core.zero_state(m, kind, device);
        let s = scan_state(&critic.core, &xs, &real, &zc, ScanMethod::Grouped);
        let q = tensor_to_vec64(&(critic.step(&o_t, &a_t, &s).0 - &q_ref).abs());
        for (i, at) in out.iter_mut().enumerate() {
            at.actor_zero.push(zero[i]);
            at.actor_stored.push(from_stored.as_ref().map(|v| v[i]));
            at.q_zero.push(q[i]);
        }
    }
    out
}

/// Mean, 90th percentile and maximum of `v` (NaN when empty).
fn summary(v: &mut [f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let i = ((v.len() as f64 * 0.9).ceil() as usize).clamp(1, v.len()) - 1;
    (mean, v[i], v[v.len() - 1])
}

/// Measures how stale the starts of `agent`'s replayed windows are (see the [module
/// docs](self)): `positions` positions drawn uniformly over the agent's own transitions in
/// `replay` (and as many over its injected ones, if it holds any), each burn-in length of
/// `burn_ins`, from `seed`. The networks are the agent's current ones, without gradient.
///
/// # Errors
///
/// A feed-forward agent or a window-of-k agent (`act_window`: it acts and trains from the same
/// zero-started window, so its starts are exact), a replay whose sizes do not match the agent,
/// one without a transition of the agent's own, or a burn-in longer than its longest episode.
pub fn state_staleness(
    agent: &RdpgAgent,
    replay: &EpisodicReplay,
    positions: usize,
    burn_ins: &[usize],
    seed: u64,
) -> Result<Staleness> {
    let cfg = agent.config();
    if !agent.actor().core.is_recurrent() {
        return Err(AgentError::Input(
            "a feed-forward agent carries no recurrent state: nothing to measure".into(),
        ));
    }
    if cfg.act_window > 0 {
        return Err(AgentError::Input(format!(
            "this agent acts and trains on a window of its last {} observations re-encoded \
             from zero: its windows start exactly where acting does, nothing to measure",
            cfg.act_window
        )));
    }
    let rc = replay.config();
    if (rc.obs_dim, rc.act_dim) != (agent.obs_dim(), agent.act_dim())
        || (rc.state_dim != 0 && rc.state_dim != agent.state_dim())
    {
        return Err(AgentError::Input(format!(
            "the replay holds observations/actions/states of sizes {}/{}/{}, the agent's are \
             {}/{}/{}",
            rc.obs_dim,
            rc.act_dim,
            rc.state_dim,
            agent.obs_dim(),
            agent.act_dim(),
            agent.state_dim()
        )));
    }
    if positions == 0 || positions > MAX_POSITIONS || burn_ins.is_empty() {
        return Err(AgentError::Input(format!(
            "measure 1 to {MAX_POSITIONS} positions (got {positions}) and at least one burn-in \
             length"
        )));
    }
    let all = replay.episodes();
    let own: Vec<usize> = (0..all.len()).filter(|&e| !all[e].injected).collect();
    let injected: Vec<usize> = (0..all.len()).filter(|&e| all[e].injected).collect();
    if own.is_empty() {
        return Err(AgentError::Input(
            "the replay holds no episode of the agent's own".into(),
        ));
    }
    let longest = all.iter().map(|e| e.len()).max().unwrap_or(0);
    if let Some(k) = burn_ins.iter().find(|&&k| k > longest) {
        return Err(AgentError::Input(format!(
            "a burn-in of {k} steps is longer than the replay's longest episode ({longest} \
             steps): from every position it would start at the episode's start"
        )));
    }
    let mut rng = NpRng::from_seed(seed);
    let drawn_own = draw(&mut rng, &all, &own, positions);
    let drawn_injected = draw(&mut rng, &all, &injected, positions);

    // Gaps per position, keyed by (episode, step), computed one episode at a time.
    let mut measured: BTreeMap<Position, At> = BTreeMap::new();
    let mut by_episode: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for &(e, t) in drawn_own.iter().chain(&drawn_injected) {
        by_episode.entry(e).or_default().push(t);
    }
    tch::no_grad(|| {
        for (&e, ts) in &mut by_episode {
            ts.dedup();
            for (&t, at) in ts.iter().zip(episode_gaps(agent, all[e], ts, burn_ins)) {
                measured.insert((e, t), at);
            }
        }
    });
    let q_refs: Vec<f64> = drawn_own.iter().map(|p| measured[p].q_ref).collect();
    let (lo, hi) = q_refs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &q| {
            (l.min(q), h.max(q))
        });
    // No spread (one position, or a constant critic): ΔQ is undefined.
    let q_spread = if hi > lo { hi - lo } else { f64::NAN };

    // Pools: all own episodes, each quarter by age, the injected ones.
    let rank: BTreeMap<usize, usize> = own.iter().enumerate().map(|(r, &e)| (e, r)).collect();
    let mut pools: Vec<(String, Vec<Position>)> = vec![("agent".into(), drawn_own.clone())];
    for (q, name) in ["oldest", "second", "third", "newest"].iter().enumerate() {
        let quarter: Vec<Position> = drawn_own
            .iter()
            .copied()
            .filter(|(e, _)| rank[e] * 4 / own.len() == q)
            .collect();
        pools.push((format!("agent, {name} quarter"), quarter));
    }
    if !drawn_injected.is_empty() {
        pools.push(("injected".into(), drawn_injected));
    }
    let mut gaps = Vec::new();
    for (pool, pos) in pools.iter().filter(|(_, pos)| !pos.is_empty()) {
        for (b, &k) in burn_ins.iter().enumerate() {
            let mut push = |start: &str, net: &str, mut v: Vec<f64>| {
                let (mean, p90, max) = summary(&mut v);
                gaps.push(StartGap {
                    pool: pool.clone(),
                    start: start.into(),
                    burn_in: k,
                    net: net.into(),
                    positions: v.len(),
                    mean,
                    p90,
                    max,
                });
            };
            let stored: Vec<f64> = pos
                .iter()
                .filter_map(|p| measured[p].actor_stored[b])
                .collect();
            if !stored.is_empty() {
                push("stored", "actor", stored);
            }
            push(
                "zero",
                "actor",
                pos.iter().map(|p| measured[p].actor_zero[b]).collect(),
            );
            push(
                "zero",
                "critic 0",
                pos.iter()
                    .map(|p| measured[p].q_zero[b] / q_spread)
                    .collect(),
            );
        }
    }
    Ok(Staleness {
        burn_ins: burn_ins.to_vec(),
        scan_len: cfg.scan_len,
        from_stored_state: cfg.burn_in_from_stored_state,
        q_spread,
        gaps,
    })
}
