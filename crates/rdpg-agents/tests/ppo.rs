//! End-to-end tests of the PPO trainer: determinism, resume identity (mid-rollout and
//! mid-episode), observer semantics, validation, corrupt checkpoints and a learning check on
//! Pendulum-v1.

use std::path::{Path, PathBuf};

use rdpg_agents::ppo::{PpoConfig, PpoTrainer};
use rdpg_agents::{
    AgentError, EpisodeRecord, EvalRecord, Quiet, TrainConfig, TrainObserver, Trainer, UpdateStats,
};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rdpg-ppo-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Pendulum-v1 (or `env`), 2 envs, rollouts of 64 steps per env (updates every 128 steps),
/// evaluation every 250 steps on one episode, a small network.
fn small(env: &str) -> (TrainConfig, PpoConfig) {
    let train = TrainConfig {
        env: env.into(),
        total_steps: 600,
        num_envs: 2,
        workers: 2,
        eval_every: 250,
        eval_episodes: 1,
        seed: 7,
        ..TrainConfig::default()
    };
    let ppo = PpoConfig {
        hidden: vec![16, 16],
        rollout_steps: 64,
        epochs: 3,
        minibatch_size: 32,
        num_threads: Some(1),
        ..PpoConfig::default()
    };
    (train, ppo)
}

/// Records every callback (as text, for exact comparison) and optionally stops at a step.
#[derive(Default)]
struct Recorder {
    events: Vec<String>,
    episodes: Vec<EpisodeRecord>,
    evals: Vec<u64>,
    updates: Vec<(u64, UpdateStats)>,
    stop_at: Option<u64>,
}

impl TrainObserver for Recorder {
    fn on_episode(&mut self, rec: &EpisodeRecord) {
        self.events.push(format!("{rec:?}"));
        self.episodes.push(rec.clone());
    }
    fn on_eval(&mut self, rec: &EvalRecord) {
        self.events.push(format!("{rec:?}"));
        self.evals.push(rec.step);
    }
    fn on_update(&mut self, step: u64, stats: &UpdateStats) {
        // Wall time is the one field that differs between identical runs.
        let stats = UpdateStats {
            seconds: 0.0,
            ..stats.clone()
        };
        self.events.push(format!("{step} {stats:?}"));
        self.updates.push((step, stats));
    }
    fn should_stop(&mut self, step: u64) -> bool {
        self.stop_at.is_some_and(|s| step >= s)
    }
}

/// The files of a trainer checkpoint, as bytes.
fn checkpoint_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    [
        "agent/weights.safetensors",
        "agent/optim.safetensors",
        "agent/agent.json",
        "loop.bin",
        "collector.bin",
        "checkpoint.json",
        "train.json",
    ]
    .iter()
    .map(|f| (f.to_string(), std::fs::read(dir.join(f)).unwrap()))
    .collect()
}

/// 600 steps in one go, versus `split` steps (mid-rollout, mid-episode) + save + load + the
/// rest, versus one trainer stopped by its observer at 150 and run again: identical checkpoints
/// (weights, optimiser moments, beta, generator, rollout, episodes) and identical callbacks.
fn resume_is_identical(env: &str, split: u64) -> Recorder {
    let (train, ppo) = small(env);
    let mut one = PpoTrainer::new(train.clone(), ppo.clone()).unwrap();
    let mut rec_one = Recorder::default();
    assert_eq!(one.run(600, &mut rec_one).unwrap(), 600);
    let d1 = tmp(&format!("{env}-one"));
    one.save(&d1).unwrap();

    let mut first = PpoTrainer::new(train.clone(), ppo.clone()).unwrap();
    let mut rec_two = Recorder::default();
    let reached = first.run(split, &mut rec_two).unwrap();
    assert_eq!(reached, split + 1);
    let mid = tmp(&format!("{env}-mid"));
    first.save(&mid).unwrap();
    drop(first);
    let mut second = PpoTrainer::load(&mid).unwrap();
    assert_eq!(second.steps(), reached);
    second.run(600, &mut rec_two).unwrap();
    let d2 = tmp(&format!("{env}-two"));
    second.save(&d2).unwrap();

    let mut stopped = PpoTrainer::new(train, ppo).unwrap();
    let mut rec_three = Recorder {
        stop_at: Some(150),
        ..Recorder::default()
    };
    assert_eq!(stopped.run(600, &mut rec_three).unwrap(), 150);
    rec_three.stop_at = None;
    stopped.run(600, &mut rec_three).unwrap();
    let d3 = tmp(&format!("{env}-three"));
    stopped.save(&d3).unwrap();

    let (b1, b2, b3) = (
        checkpoint_bytes(&d1),
        checkpoint_bytes(&d2),
        checkpoint_bytes(&d3),
    );
    for ((f, x), ((_, y), (_, z))) in b1.iter().zip(b2.iter().zip(&b3)) {
        assert!(x == y, "{env}: {f} differs after save + load");
        assert!(x == z, "{env}: {f} differs after a stop");
    }
    assert_eq!(rec_one.events, rec_two.events);
    assert_eq!(rec_one.events, rec_three.events);
    // Updates at 128, 256, 384 and 512 steps; weights really changed.
    assert_eq!(one.agent().updates(), 4);
    let steps: Vec<u64> = rec_one.updates.iter().map(|u| u.0).collect();
    assert_eq!(steps, vec![128, 256, 384, 512]);
    let fresh = PpoTrainer::new(small(env).0, small(env).1).unwrap();
    assert_ne!(fresh.agent().weights(), one.agent().weights());
    for d in [d1, mid, d2, d3] {
        let _ = std::fs::remove_dir_all(d);
    }
    rec_one
}

#[test]
fn resume_is_bit_identical_pendulum() {
    // Pendulum episodes are truncated at 200 steps per env: both end at step 400, and the
    // update at 512 bootstraps from their last observations. Splitting at 450 (25 steps into
    // the second episodes, 33 steps into the rollout 384..512) puts those truncations in the
    // saved partial rollout.
    let rec = resume_is_identical("Pendulum-v1", 449);
    assert_eq!(rec.episodes.len(), 2);
    for (i, e) in rec.episodes.iter().enumerate() {
        assert_eq!((e.step, e.env, e.len), (400, i, 200));
        assert_eq!(e.ret, e.stock_return);
        assert!(e.ret < 0.0);
    }
    assert_eq!(rec.evals, vec![250, 500]);
    for (_, s) in &rec.updates {
        assert!(
            s.critic_loss.is_finite()
                && s.actor_loss.is_some_and(f64::is_finite)
                && s.q_mean.is_finite()
        );
    }
}

#[test]
fn resume_is_bit_identical_with_terminations() {
    // CueMemory-v0 episodes terminate after 6 steps: many episode boundaries per rollout.
    // Split at 290: 145 steps per env, one step into an episode, mid-rollout.
    let rec = resume_is_identical("CueMemory-v0", 289);
    assert_eq!(rec.episodes.len(), 600 / 6);
    assert!(rec.episodes.iter().all(|e| e.len == 6));
}

#[test]
fn same_seed_same_weights() {
    let run = |seed: u64| {
        let (mut train, ppo) = small("Pendulum-v1");
        train.seed = seed;
        let mut t = PpoTrainer::new(train, ppo).unwrap();
        t.run(300, &mut Quiet).unwrap();
        assert_eq!(t.agent().updates(), 2);
        (t.agent().weights(), t.agent().kl_coef())
    };
    let a = run(3);
    assert_eq!(a, run(3));
    assert_ne!(a.0, run(4).0);
}

#[test]
fn budget_caps_the_run_and_can_be_raised() {
    let (mut train, ppo) = small("Pendulum-v1");
    train.total_steps = 100;
    let mut t = PpoTrainer::new(train, ppo).unwrap();
    assert_eq!(t.run(u64::MAX, &mut Quiet).unwrap(), 100);
    assert_eq!(t.run(u64::MAX, &mut Quiet).unwrap(), 100);
    t.set_total_steps(200);
    assert_eq!(t.run(u64::MAX, &mut Quiet).unwrap(), 200);
    assert_eq!(t.config().total_steps, 200);
    assert_eq!(t.agent().updates(), 1);
}

#[test]
fn bad_values_are_rejected() {
    let field = |r: Result<PpoTrainer, AgentError>| match r {
        Err(AgentError::Config { field, .. }) => field,
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("accepted"),
    };
    // The off-policy options (injection, parameter noise) are not part of the run config
    // PPO takes: an experiment giving them to PPO is refused by the CLI (`experiment.rs`).
    let (train, ppo) = small("Pendulum-v1");
    let env = TrainConfig {
        env: "Nope-v0".into(),
        ..train.clone()
    };
    assert_eq!(field(PpoTrainer::new(env, ppo.clone())), "train.env");
    let bad = PpoConfig {
        kl_target: 0.0,
        ..ppo
    };
    assert_eq!(field(PpoTrainer::new(train, bad)), "ppo.kl_target");
}

#[test]
fn corrupt_checkpoints_get_clear_errors() {
    let (train, ppo) = small("Pendulum-v1");
    let mut t = PpoTrainer::new(train, ppo).unwrap();
    t.run(150, &mut Quiet).unwrap();
    let d = tmp("corrupt");
    t.save(&d).unwrap();
    assert!(PpoTrainer::load(&d).is_ok());
    let lp = d.join("loop.bin");
    let full = std::fs::read(&lp).unwrap();
    std::fs::write(&lp, &full[..full.len() / 2]).unwrap();
    let err = PpoTrainer::load(&d)
        .err()
        .expect("truncated loop.bin")
        .to_string();
    assert!(
        err.contains("loop.bin") && err.contains("truncated or corrupt"),
        "{err}"
    );
    std::fs::write(&lp, &full).unwrap();
    std::fs::remove_file(d.join("agent/optim.safetensors")).unwrap();
    let err = PpoTrainer::load(&d)
        .err()
        .expect("no optimiser")
        .to_string();
    assert!(err.contains("optim.safetensors"), "{err}");
    // A checkpoint of another run size does not load.
    let text = std::fs::read_to_string(d.join("train.json")).unwrap();
    let mut cfg: TrainConfig = serde_json::from_str(&text).unwrap();
    cfg.num_envs = 3;
    std::fs::write(d.join("train.json"), serde_json::to_string(&cfg).unwrap()).unwrap();
    assert!(PpoTrainer::load(&d).is_err());
    let err = PpoTrainer::load(&tmp("missing")).err().unwrap().to_string();
    assert!(err.contains("train.json"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}

/// Learning check: PPO learns to swing up and hold Pendulum-v1 (full observation) in 30k
/// steps (about 10 s in release on one thread). The untrained policy scores about -1100 on the
/// held-out evaluation episodes (it lets the pendulum hang); a policy that swings up and
/// balances scores above -200 (seeds 0-4 reach -150 to -180 with these settings). A broken
/// gradient, ratio, advantage or KL term leaves it below -400. gamma 0.95 and the shorter
/// rollouts (512 x 4 envs) are the task's settings, not the defaults (which are for the
/// walker).
#[test]
fn learns_pendulum_swing_up() {
    let train = TrainConfig {
        env: "Pendulum-v1".into(),
        total_steps: 30_000,
        num_envs: 4,
        workers: 1,
        eval_every: 0,
        eval_episodes: 10,
        seed: 0,
        ..TrainConfig::default()
    };
    let ppo = PpoConfig {
        gamma: 0.95,
        rollout_steps: 512,
        lr_policy: 1e-3,
        lr_value: 3e-3,
        num_threads: Some(1),
        ..PpoConfig::default()
    };
    let mut t = PpoTrainer::new(train, ppo).unwrap();
    let before = t.evaluate().unwrap().mean_return;
    let started = std::time::Instant::now();
    t.run(u64::MAX, &mut Quiet).unwrap();
    let after = t.evaluate().unwrap();
    eprintln!(
        "PPO Pendulum-v1: eval {before:.1} -> {:.1} in {:.1} s, beta {}, log std {:?}",
        after.mean_return,
        started.elapsed().as_secs_f64(),
        t.agent().kl_coef(),
        t.agent().log_std()
    );
    assert!(before < -800.0, "untrained policy scored {before}");
    assert!(
        after.mean_return > -400.0,
        "trained policy scored {}",
        after.mean_return
    );
}
