//! `state_staleness`: exact starts measure no gap, a burn-in as long as the episode is exact,
//! a zero stored state is the zero start, and what it cannot measure is refused.

use rdpg_core::replay::{Episode, EpisodicReplay, ReplayConfig};

use super::*;
use crate::rdpg::staleness::{state_staleness, StartGap};

/// One episode of `n` steps of random observations and actions, storing no states.
fn episode(rng: &mut NpRng, n: usize, injected: bool) -> Episode {
    let obs = (0..(n + 1) * OBS)
        .map(|_| rng.normal(0.0, 1.0) as f32)
        .collect();
    let actions = (0..n * ACT)
        .map(|_| rng.uniform(-1.0, 1.0) as f32)
        .collect();
    Episode {
        obs,
        actions,
        rewards: vec![0.0; n],
        states: Vec::new(),
        terminated: true,
        truncated: false,
        injected,
    }
}

fn gap<'a>(gaps: &'a [StartGap], pool: &str, net: &str, start: &str, k: usize) -> &'a StartGap {
    gaps.iter()
        .find(|g| g.pool == pool && g.net == net && g.start == start && g.burn_in == k)
        .unwrap_or_else(|| panic!("no line {pool} / {net} / {start} + {k}: {gaps:#?}"))
}

/// Episodes whose stored states are the current actor's own acting states measure no gap
/// from the stored start; zeros stored are the zero start; a burn-in as long as the episodes
/// is exact from either start, for the actor and the critic; without memory the gap is large.
#[test]
fn exact_starts_measure_no_gap_and_no_memory_does() {
    let agent = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 5, Kind::Double).unwrap();
    let sd = agent.state_dim();
    let mut rng = NpRng::from_seed(11);
    let mut exact =
        EpisodicReplay::new(ReplayConfig::new(1000, OBS, ACT).with_state_dim(sd)).unwrap();
    let mut zeros =
        EpisodicReplay::new(ReplayConfig::new(1000, OBS, ACT).with_state_dim(sd)).unwrap();
    let n = 12;
    for e in 0..6 {
        let mut ep = episode(&mut rng, n, e == 5);
        ep.states = agent.episode_states(&ep.obs, n).unwrap();
        exact.add_episode(ep.clone()).unwrap();
        ep.states = vec![0.0; n * sd];
        zeros.add_episode(ep).unwrap();
    }
    let ks = [0, 2, n - 2, n - 1];
    let s = state_staleness(&agent, &exact, 300, &ks, 1).unwrap();
    assert_eq!(s.burn_ins, ks);
    assert!(s.q_spread > 0.0);
    for pool in ["agent", "injected"] {
        for k in ks {
            let g = gap(&s.gaps, pool, "actor", "stored", k);
            assert!(g.max < 1e-6, "{g:?}"); // states stored as f32
        }
        for net in ["actor", "critic 0"] {
            // A burn-in of n - 1 steps reaches back to step 0 from every step: exact. One of
            // n - 2 steps misses step 0 at the last step only: a gap there.
            let g = gap(&s.gaps, pool, net, "zero", n - 1);
            assert!(g.max < 1e-12, "{g:?}");
            let g = gap(&s.gaps, pool, net, "zero", n - 2);
            assert!(g.max > 1e-9, "{g:?}");
            let none = gap(&s.gaps, pool, net, "zero", 0);
            let short = gap(&s.gaps, pool, net, "zero", 2);
            assert!(none.mean > 1e-5, "no memory, no gap: {none:?}");
            assert!(short.mean < none.mean, "{short:?} {none:?}");
        }
    }
    assert_eq!(gap(&s.gaps, "agent", "actor", "zero", 0).positions, 300);
    assert_eq!(gap(&s.gaps, "injected", "actor", "zero", 0).positions, 300);
    // Five own episodes by age: ranks 0 and 1 make the oldest quarter, 2, 3 and 4 one each.
    let quarters: Vec<usize> = ["oldest", "second", "third", "newest"]
        .iter()
        .map(|q| gap(&s.gaps, &format!("agent, {q} quarter"), "actor", "zero", 0).positions)
        .collect();
    assert_eq!(quarters.iter().sum::<usize>(), 300, "{quarters:?}");
    assert!(
        quarters[1..]
            .iter()
            .all(|&q| 2 * q < quarters[0] + 30 && 2 * q + 30 > quarters[0]),
        "{quarters:?}"
    );

    let z = state_staleness(&agent, &zeros, 300, &ks, 1).unwrap();
    for k in ks {
        let (stored, zero) = (
            gap(&z.gaps, "agent", "actor", "stored", k),
            gap(&z.gaps, "agent", "actor", "zero", k),
        );
        assert_eq!((stored.mean, stored.max), (zero.mean, zero.max));
    }
    // Measured the same way twice from the same seed.
    assert_eq!(s, state_staleness(&agent, &exact, 300, &ks, 1).unwrap());
}

/// Feed-forward and window-of-k agents, a replay of other sizes, one without the agent's own
/// episodes and a burn-in longer than every episode are refused, each with its reason.
#[test]
fn staleness_refuses_what_it_cannot_measure() {
    let mut rng = NpRng::from_seed(2);
    let agent = RdpgAgent::new_with_kind(tiny(), OBS, ACT, 5, Kind::Double).unwrap();
    let mut replay = EpisodicReplay::new(ReplayConfig::new(100, OBS, ACT)).unwrap();
    replay.add_episode(episode(&mut rng, 5, true)).unwrap();
    let err = |a: &RdpgAgent, r: &EpisodicReplay| {
        state_staleness(a, r, 10, &[0, 2], 0)
            .unwrap_err()
            .to_string()
    };
    assert!(err(&agent, &replay).contains("no episode of the agent's own"));
    replay.add_episode(episode(&mut rng, 5, false)).unwrap();
    assert!(state_staleness(&agent, &replay, 10, &[0, 2], 0).is_ok());
    let err_n = |n: usize| {
        state_staleness(&agent, &replay, n, &[0], 0)
            .unwrap_err()
            .to_string()
    };
    for n in [0, 1_000_001] {
        assert!(err_n(n).contains("measure 1 to 1000000 positions"));
    }
    assert!(state_staleness(&agent, &replay, 10, &[5], 0).is_ok());
    assert!(state_staleness(&agent, &replay, 10, &[6], 0)
        .unwrap_err()
        .to_string()
        .contains("longer than the replay's longest episode (5 steps)"));

    let ff = RdpgConfig {
        recurrent: false,
        ..tiny()
    };
    let ff = RdpgAgent::new_with_kind(ff, OBS, ACT, 5, Kind::Double).unwrap();
    assert!(err(&ff, &replay).contains("feed-forward"));
    let window = RdpgAgent::new_with_kind(window_cfg(3), OBS, ACT, 5, Kind::Double).unwrap();
    assert!(err(&window, &replay).contains("window of its last 3"));

    let other = EpisodicReplay::new(ReplayConfig::new(100, OBS + 1, ACT)).unwrap();
    assert!(err(&agent, &other).contains("sizes"));
}
