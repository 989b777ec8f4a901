//! Trajectory parity with Gymnasium: replays the traces in `tests/fixtures/traces` (recorded
//! from gymnasium 1.4.0 by `scripts/reference/gymnasium_traces.py`) and compares every observation,
//! reward, `terminated` and `truncated`.
//!
//! With pybox2d's Box2D 2.3.0 (the default build) the comparison is exact (`==`) over whole
//! episodes. With another Box2D build (e.g. stock 2.3.1) the test says so and compares with a
//! tolerance over the first 50 steps of each episode, where the chaotic dynamics have not yet
//! amplified the rounding differences.

use std::path::PathBuf;

use rdpg_core::Env;
use rdpg_envs::bipedal::{BipedalWalker, WalkerConfig, MAX_STEPS_HARDCORE, MAX_STEPS_NORMAL};
use rdpg_envs::TimeLimit;
use serde_json::Value;

fn fixtures() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/traces");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 6,
        "expected at least 6 trace files in {}",
        dir.display()
    );
    files
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn f32s(v: &Value) -> Vec<f32> {
    f64s(v).into_iter().map(|x| x as f32).collect()
}

struct Mismatch(String);

fn check_file(path: &PathBuf, exact: bool) -> Result<usize, Mismatch> {
    let text = std::fs::read_to_string(path).unwrap();
    let trace: Value = serde_json::from_str(&text).unwrap();
    let id = trace["env_id"].as_str().unwrap();
    let hardcore = id == "BipedalWalkerHardcore-v3";
    let limit = if hardcore {
        MAX_STEPS_HARDCORE
    } else {
        MAX_STEPS_NORMAL
    };
    let walker = BipedalWalker::new(WalkerConfig {
        hardcore,
        ..Default::default()
    })
    .unwrap();
    let mut env = TimeLimit::new(walker, limit).unwrap();
    assert_eq!(env.id(), id);
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    let mut steps_checked = 0;
    for (e, ep) in trace["episodes"].as_array().unwrap().iter().enumerate() {
        let at = |what: &str| format!("{name} episode {e} {what}");
        let seed = ep["seed"].as_u64();
        let (obs0, _) = env.reset(seed).unwrap();
        let (tx, ty) = env.inner().terrain_points();
        let (ex, ey) = (f64s(&ep["terrain_x"]), f64s(&ep["terrain_y"]));
        // Terrain and push come from the RNG and double arithmetic: exact in every build.
        if tx != ex.as_slice() || ty != ey.as_slice() {
            return Err(Mismatch(at("terrain differs")));
        }
        if env.inner().initial_push() != ep["init_push"].as_f64().unwrap() {
            return Err(Mismatch(at("initial push differs")));
        }
        if env.inner().terrain_body_count() != ep["terrain_len"].as_u64().unwrap() as usize {
            return Err(Mismatch(at("terrain body count differs")));
        }
        let obs: Vec<Vec<f32>> = ep["obs"].as_array().unwrap().iter().map(f32s).collect();
        let actions: Vec<Vec<f32>> = ep["actions"].as_array().unwrap().iter().map(f32s).collect();
        let rewards = f64s(&ep["rewards"]);
        let term: Vec<bool> = ep["terminated"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_bool().unwrap())
            .collect();
        let trunc: Vec<bool> = ep["truncated"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_bool().unwrap())
            .collect();
        let horizon = if exact {
            actions.len()
        } else {
            actions.len().min(50)
        };
        let close = |a: &[f32], b: &[f32]| {
            exact && a == b || !exact && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-3)
        };
        if !close(&obs0, &obs[0]) {
            return Err(Mismatch(at(&format!(
                "reset obs: {obs0:?} vs {:?}",
                obs[0]
            ))));
        }
        for k in 0..horizon {
            let s = env.step(&actions[k]).unwrap();
            steps_checked += 1;
            if !close(&s.obs, &obs[k + 1]) {
                return Err(Mismatch(at(&format!(
                    "step {k}: obs {:?} vs {:?}",
                    s.obs,
                    obs[k + 1]
                ))));
            }
            let reward_ok = if exact {
                s.reward == rewards[k]
            } else {
                (s.reward - rewards[k]).abs() <= 1e-2
            };
            if !reward_ok {
                return Err(Mismatch(at(&format!(
                    "step {k}: reward {} vs {}",
                    s.reward, rewards[k]
                ))));
            }
            if (s.terminated, s.truncated) != (term[k], trunc[k]) {
                return Err(Mismatch(at(&format!(
                    "step {k}: (terminated, truncated) = {:?} vs {:?}",
                    (s.terminated, s.truncated),
                    (term[k], trunc[k])
                ))));
            }
        }
        if horizon == actions.len() {
            assert!(
                term[horizon - 1] || trunc[horizon - 1],
                "{}",
                at("trace does not end its episode")
            );
        }
    }
    Ok(steps_checked)
}

#[test]
fn whole_episodes_match_gymnasium() {
    let exact = rdpg_box2d::is_pybox2d_core();
    if !exact {
        eprintln!(
            "NOTE: built with Box2D flavour {:?}, not pybox2d's 2.3.0: trajectories cannot be \
             bit-identical; comparing the first 50 steps of each episode with a tolerance",
            rdpg_box2d::FLAVOR
        );
    }
    let mut failures = Vec::new();
    let mut total = 0;
    for f in fixtures() {
        match check_file(&f, exact) {
            Ok(n) => total += n,
            Err(Mismatch(m)) => failures.push(m),
        }
    }
    assert!(
        failures.is_empty(),
        "{} trace file(s) differ:\n{}",
        failures.len(),
        failures.join("\n")
    );
    eprintln!("checked {total} steps against Gymnasium");
}

/// Learners flush subnormals to zero on their threads, and with one worker the vector env
/// steps on the learner's thread: the physics must stay Gymnasium's anyway. Every trace is
/// replayed again on a thread that flushes subnormals (FTZ/DAZ), and must still match.
#[test]
fn episodes_match_gymnasium_on_a_thread_that_flushes_denormals() {
    let exact = rdpg_box2d::is_pybox2d_core();
    rdpg_core::fpmode::set_flush_denormal(true);
    let flushing = rdpg_core::fpmode::flushes_denormals();
    for f in fixtures() {
        if let Err(Mismatch(m)) = check_file(&f, exact) {
            panic!("with FTZ/DAZ on the thread: {m}");
        }
    }
    assert!(
        rdpg_core::fpmode::flushes_denormals() == flushing,
        "stepping restores the thread's mode"
    );
    rdpg_core::fpmode::set_flush_denormal(false);
}
