//! Learning checks that CI runs (a few minutes at most). The full memory-task protocol
//! (PendulumNoVel-v1, 3 seeds) is in RESULTS.md ("PendulumNoVel-v1: `memory-rdpg`").
//!
//! `CueMemory-v0` shows a cue (±1) on the first step and asks for it four blank steps later:
//! a feed-forward policy cannot beat 0 in expectation, a recurrent one can reach 1. RDPG must
//! learn it; DDPG with the same budget must not.
//!
//! TD3 with FORK's forward-looking actor must learn `Pendulum-v1`'s swing-up with its term in
//! the actor's loss (a wrong sign or a broken model would stop it).
//!
//! SAC must learn the same swing-up with its temperature tracking the entropy target.

use rdpg_agents::rdpg::{
    ExplorationConfig, ForkConfig, OffPolicyConfig, OffPolicyTrainer, SacConfig, TargetNoise,
    TqcConfig, Trunk,
};
use rdpg_agents::{Quiet, RdpgConfig, TrainConfig, TrainObserver, Trainer, UpdateStats};

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

/// Pendulum-v1, 8000 env steps, 1000 random warm-up steps, one update per step, and a
/// feed-forward agent with 64-unit layers, the action at the critic's input, twin critics:
/// the setting of the swing-up checks (each sets its own algorithm's options on top).
fn pendulum_setting(exploration: ExplorationConfig) -> (TrainConfig, OffPolicyConfig, RdpgConfig) {
    let train = TrainConfig {
        env: "Pendulum-v1".into(),
        total_steps: 8_000,
        eval_every: 0,
        eval_episodes: 10,
        seed: 0,
        ..TrainConfig::default()
    };
    let off = OffPolicyConfig {
        warmup_steps: 1_000,
        updates_per_step: 1.0,
        replay_capacity: 10_000,
        exploration,
        ..OffPolicyConfig::default()
    };
    let agent = RdpgConfig {
        trunk: Trunk::Mlp { hidden: vec![64] },
        recurrent: false,
        actor_hidden: 64,
        critic_hidden: 64,
        critic_action_fc: 0,
        opt_len: 1,
        update_len: 1,
        scan_len: 0,
        lr_actor: 1e-3,
        lr_critic: 1e-3,
        critic_l2: 0.0,
        twin_critic: true,
        batch_size: 64,
        device: rdpg_agents::DeviceSpec::Cpu,
        num_threads: Some(1),
        ..RdpgConfig::default()
    };
    (train, off, agent)
}

/// Counts the actor updates and those whose loss had FORK's term.
#[derive(Default)]
struct ForkUse {
    actor_updates: u64,
    with_term: u64,
    model_loss: Vec<f64>,
}

impl TrainObserver for ForkUse {
    fn on_update(&mut self, _step: u64, s: &UpdateStats) {
        if let Some(&used) = s.extra.get("fork_share") {
            self.actor_updates += 1;
            self.with_term += used as u64;
        }
        self.model_loss.extend(s.extra.get("model_loss"));
    }
}

#[test]
fn td3_with_fork_learns_the_pendulum_swing_up() {
    let (train, off, base) = pendulum_setting(ExplorationConfig::Gaussian { sigma: 0.1 });
    let td3 = RdpgConfig {
        tau: 0.005,
        target_noise: Some(TargetNoise {
            std: 0.2,
            clip: 0.5,
        }),
        policy_delay: 2,
        fork: Some(ForkConfig {
            // Pendulum's angular velocity reaches 8: a looser threshold than TD3-FORK's 0.02
            // on walker observations, so that the term is in play.
            threshold: 0.2,
            model_hidden: vec![64, 64],
            reward_hidden: vec![64, 64],
            lr: 1e-3,
            // The term outweighs -Q(o, mu(o)) (weight 1): a wrong term would stop the
            // learning that the usual 0.5 leaves to the critic's term.
            weight: 3.0,
        }),
        ..base
    };
    let mut t = OffPolicyTrainer::new(train, off, td3).unwrap();
    let before = t.evaluate().unwrap().mean_return;
    let mut seen = ForkUse::default();
    t.run(u64::MAX, &mut seen).unwrap();
    let after = t.evaluate().unwrap().mean_return;
    let first = seen.model_loss[..100].iter().sum::<f64>() / 100.0;
    let last = seen.model_loss[seen.model_loss.len() - 100..]
        .iter()
        .sum::<f64>()
        / 100.0;
    eprintln!(
        "td3+fork: eval {before:.1} -> {after:.1}; term in {} of {} actor updates; model loss \
         {first:.4} -> {last:.4}",
        seen.with_term, seen.actor_updates
    );
    assert_eq!(seen.actor_updates, 3_500);
    assert!(
        seen.with_term > seen.actor_updates / 2,
        "the forward-looking term was rarely used: {} of {}",
        seen.with_term,
        seen.actor_updates
    );
    assert!(
        last < 0.5 * first,
        "the dynamics model did not learn: {first} -> {last}"
    );
    // A random or untrained policy scores about -1200 to -1600; a swing-up about -150.
    assert!(
        after > -500.0,
        "TD3+FORK did not learn the swing-up: {before:.1} -> {after:.1}"
    );
}

/// The temperature and the entropy SAC reports on its updates.
#[derive(Default)]
struct SacTrace {
    alpha: Vec<f64>,
    entropy: Vec<f64>,
}

impl TrainObserver for SacTrace {
    fn on_update(&mut self, _step: u64, s: &UpdateStats) {
        self.alpha.extend(s.extra.get("alpha"));
        self.entropy.extend(s.extra.get("entropy"));
    }
}

/// SAC (feed-forward) learns `Pendulum-v1`'s swing-up, its temperature falling from 1 as the
/// policy's entropy approaches the target (-1).
#[test]
fn sac_learns_the_pendulum_swing_up() {
    soft_swing_up(None);
}

/// The same with TQC's critics (5 atoms each, 1 dropped per critic).
#[test]
fn tqc_learns_the_pendulum_swing_up() {
    soft_swing_up(Some(TqcConfig {
        quantiles: 5,
        drop_per_critic: 1,
    }));
}

fn soft_swing_up(tqc: Option<TqcConfig>) {
    let (train, off, base) = pendulum_setting(ExplorationConfig::None);
    let name = if tqc.is_some() { "tqc" } else { "sac" };
    let sac = RdpgConfig {
        tau: 0.01,
        sac: Some(SacConfig {
            lr_alpha: 1e-3,
            tqc,
            ..SacConfig::default()
        }),
        ..base
    };
    let mut t = OffPolicyTrainer::new(train, off, sac).unwrap();
    let before = t.evaluate().unwrap().mean_return;
    let mut seen = SacTrace::default();
    t.run(u64::MAX, &mut seen).unwrap();
    let after = t.evaluate().unwrap().mean_return;
    let (a0, a1) = (seen.alpha[0], *seen.alpha.last().unwrap());
    let h1 = seen.entropy[seen.entropy.len() - 100..].iter().sum::<f64>() / 100.0;
    eprintln!("{name}: eval {before:.1} -> {after:.1}; alpha {a0:.3} -> {a1:.3}; entropy {h1:.2}");
    assert_eq!(seen.alpha.len(), 7_000);
    assert!(a1 < 0.5 * a0, "the temperature did not fall: {a0} -> {a1}");
    assert!(h1 < 2.0, "the policy's entropy stayed at {h1}");
    assert!(
        after > -500.0,
        "{name} did not learn the swing-up: {before:.1} -> {after:.1}"
    );
}
