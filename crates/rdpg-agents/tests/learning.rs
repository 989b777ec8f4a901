//! Learning checks that CI runs (a few minutes at most). The full memory-task protocol
//! (PendulumNoVel-v1, 3 seeds, 50k steps) is in BENCHMARKS.md.
//!
//! `CueMemory-v0` shows a cue (±1) on the first step and asks for it four blank steps later:
//! a feed-forward policy cannot beat 0 in expectation, a recurrent one can reach 1. RDPG must
//! learn it; DDPG with the same budget must not.

use rdpg_agents::rdpg::{ExplorationConfig, OffPolicyConfig, OffPolicyTrainer, Trunk};
use rdpg_agents::{Quiet, RdpgConfig, TrainConfig, Trainer};

fn cue_run(ddpg: bool, seed: u64) -> (f64, f64) {
    let train = TrainConfig {
        env: "CueMemory-v0".into(),
        total_steps: 6_000,
        eval_every: 0,
        eval_episodes: 100,
        seed,
        ..TrainConfig::default()
    };
    let off = OffPolicyConfig {
        warmup_steps: 600,
        updates_per_step: 0.5,
        replay_capacity: 20_000,
        exploration: ExplorationConfig::Gaussian { sigma: 0.3 },
        ..OffPolicyConfig::default()
    };
    let rdpg = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![32] },
        actor_hidden: 32,
        critic_hidden: 32,
        critic_action_fc: 16,
        batch_size: 32,
        opt_len: 8,
        update_len: 8,
        scan_len: 4,
        gamma: 0.95,
        tau: 0.01,
        actor_uses_updated_critic: false,
        device: rdpg_agents::DeviceSpec::Cpu,
        num_threads: Some(1),
        ..RdpgConfig::default()
    };
    let agent = if ddpg { rdpg.ddpg() } else { rdpg };
    let mut t = OffPolicyTrainer::new(train, off, agent).unwrap();
    let before = t.evaluate().unwrap().mean_return;
    t.run(u64::MAX, &mut Quiet).unwrap();
    let after = t.evaluate().unwrap();
    eprintln!(
        "{} seed {seed}: eval {before:.3} -> {:.3} (success {:.2}), {} updates",
        if ddpg { "ddpg" } else { "rdpg" },
        after.mean_return,
        after.success_rate,
        t.agent().updates()
    );
    (before, after.mean_return)
}

#[test]
fn rdpg_remembers_the_cue_and_ddpg_cannot() {
    let (_, rdpg) = cue_run(false, 0);
    let (_, ddpg) = cue_run(true, 0);
    // Perfect recall earns 1 per episode; any feed-forward policy earns 0 in expectation (on 100
    // held-out episodes, |mean| < 0.3 with overwhelming probability).
    assert!(
        rdpg > 0.8,
        "RDPG did not learn to remember the cue: {rdpg:.3}"
    );
    assert!(ddpg < 0.3, "DDPG cannot remember, yet scored {ddpg:.3}");
}
