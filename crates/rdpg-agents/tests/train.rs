//! End-to-end tests of the training loop: resume identity, validation, corrupt checkpoints.

use std::path::{Path, PathBuf};

use rdpg_agents::train::{ExplorationConfig, ParamNoiseSpec, Quiet, TrainConfig, Trainer};
use rdpg_agents::{memory_task_config, AgentError, RdpgConfig};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rdpg-train-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn small() -> (TrainConfig, RdpgConfig) {
    let train = TrainConfig {
        env: "PendulumNoVel-v1".into(),
        total_steps: 700,
        warmup_steps: 250,
        updates_per_step: 0.25,
        num_envs: 2,
        workers: 2,
        replay_capacity: 5_000,
        exploration: ExplorationConfig::Ou {
            theta: 0.15,
            sigma: 0.3,
        },
        eval_every: 0,
        eval_episodes: 1,
        seed: 11,
        ..TrainConfig::default()
    };
    let mut agent = memory_task_config(false);
    agent.actor_hidden = 16;
    agent.critic_hidden = 16;
    agent.trunk = rdpg_agents::Trunk::Mlp { hidden: vec![16] };
    agent.batch_size = 8;
    agent.num_threads = Some(1);
    (train, agent)
}

fn bytes(dir: &Path, file: &str) -> Vec<u8> {
    std::fs::read(dir.join("agent").join(file)).unwrap()
}

#[test]
fn half_save_load_half_equals_one_go() {
    let (train, agent) = small();
    resume_is_identical(train, agent, "plain");
}

#[test]
fn half_save_load_half_equals_one_go_with_parameter_noise() {
    let (mut train, agent) = small();
    train.param_noise = Some(ParamNoiseSpec {
        every_steps: 60,
        ..ParamNoiseSpec::default()
    });
    let sigma = resume_is_identical(train, agent, "param");
    assert!(sigma.is_some_and(|s| s != ParamNoiseSpec::default().initial_stddev));
}

/// Runs 700 steps in one go and 333 + save + load + the rest; asserts identical weights,
/// optimiser and replay, and returns the parameter-noise σ reached.
fn resume_is_identical(train: TrainConfig, agent: RdpgConfig, tag: &str) -> Option<f64> {
    let tmp = |name: &str| tmp(&format!("{tag}-{name}"));
    let mut one = Trainer::new(train.clone(), agent.clone()).unwrap();
    one.run(700, &mut Quiet).unwrap();
    let d1 = tmp("one");
    one.save(&d1).unwrap();

    let mut first = Trainer::new(train, agent).unwrap();
    // 333 is not a multiple of anything: episodes are in progress in both envs.
    first.run(333, &mut Quiet).unwrap();
    let mid = tmp("mid");
    first.save(&mid).unwrap();
    drop(first);
    let mut second = Trainer::load(&mid).unwrap();
    assert_eq!(second.steps(), 334);
    second.run(700, &mut Quiet).unwrap();
    let d2 = tmp("two");
    second.save(&d2).unwrap();

    assert!(
        one.agent().updates() > 50,
        "the run must actually learn: {} updates",
        one.agent().updates()
    );
    assert_eq!(one.agent().updates(), second.agent().updates());
    assert_eq!(
        bytes(&d1, "weights.safetensors"),
        bytes(&d2, "weights.safetensors"),
        "weights differ"
    );
    assert_eq!(
        bytes(&d1, "optim.safetensors"),
        bytes(&d2, "optim.safetensors"),
        "optimiser differs"
    );
    assert_eq!(
        std::fs::read(d1.join("replay.bin")).unwrap(),
        std::fs::read(d2.join("replay.bin")).unwrap()
    );
    assert_eq!(one.param_noise_stddev(), second.param_noise_stddev());
    one.param_noise_stddev()
}

#[test]
fn corrupt_checkpoints_get_clear_errors() {
    let (mut train, agent) = small();
    train.total_steps = 300;
    let mut t = Trainer::new(train, agent).unwrap();
    t.run(300, &mut Quiet).unwrap();
    let d = tmp("corrupt");
    t.save(&d).unwrap();
    let replay = d.join("replay.bin");
    let full = std::fs::read(&replay).unwrap();
    std::fs::write(&replay, &full[..full.len() / 2]).unwrap();
    let err = Trainer::load(&d)
        .err()
        .expect("a truncated replay must not load")
        .to_string();
    assert!(
        err.contains("replay.bin") && err.contains("truncated or corrupt"),
        "{err}"
    );
    std::fs::remove_file(d.join("loop.bin")).unwrap();
    std::fs::write(&replay, &full).unwrap();
    let err = Trainer::load(&d).err().unwrap().to_string();
    assert!(err.contains("loop.bin"), "{err}");
    assert!(Trainer::load(&tmp("missing")).is_err());
}

#[test]
fn invalid_train_configs_name_the_field() {
    let (train, agent) = small();
    let cases: Vec<(TrainConfig, &str)> = vec![
        (
            TrainConfig {
                env: "Nope-v0".into(),
                ..train.clone()
            },
            "train.env",
        ),
        (
            TrainConfig {
                num_envs: 0,
                ..train.clone()
            },
            "train.num_envs",
        ),
        (
            TrainConfig {
                updates_per_step: f64::NAN,
                ..train.clone()
            },
            "train.updates_per_step",
        ),
        (
            TrainConfig {
                exploration: ExplorationConfig::Gaussian { sigma: -1.0 },
                ..train.clone()
            },
            "train.exploration",
        ),
        (
            TrainConfig {
                param_noise: Some(ParamNoiseSpec {
                    adoption_coefficient: 0.9,
                    ..ParamNoiseSpec::default()
                }),
                ..train.clone()
            },
            "train.param_noise",
        ),
    ];
    for (cfg, field) in cases {
        match Trainer::new(cfg, agent.clone()) {
            Err(AgentError::Config { field: f, .. }) => assert_eq!(f, field),
            Err(e) => panic!("{field}: unexpected error {e}"),
            Ok(_) => panic!("{field}: accepted"),
        }
    }
    // The agent's own validation runs too.
    let bad_agent = RdpgConfig {
        gamma: 1.5,
        ..agent
    };
    assert!(Trainer::new(train, bad_agent).is_err());
}

/// Teacher files: recorded, loaded into the replay under the injected cap, sampled, checked
/// against the run's environment, and rejected clearly when corrupt.
#[test]
fn experience_injection_loads_teachers_under_the_cap() {
    use rdpg_agents::inject::{record, InjectionConfig, TeacherFile};
    let (mut train, agent) = small();
    let mut teacher_agent = rdpg_agents::RdpgAgent::new(agent.clone(), 2, 1, 5).unwrap();
    let mut policy = rdpg_agents::train::RdpgPolicy::new(&mut teacher_agent);
    let t = record(&mut policy, &train, 12, 77, 0.3, "test").unwrap();
    assert_eq!(t.episodes.len(), 12);
    assert!(t
        .episodes
        .iter()
        .all(|e| e.len() == 200 && e.truncated && !e.terminated));
    let path = tmp("teacher.bin");
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    t.save(&path).unwrap();
    assert_eq!(TeacherFile::load(&path).unwrap(), t);

    // Capacity 5000 with a 0.3 cap: at most 1500 injected transitions, i.e. 7 episodes of 200.
    train.injection = Some(InjectionConfig {
        teachers: vec![path.clone()],
        initial_share: 0.5,
        anneal_steps: 500,
        max_fraction: 0.3,
    });
    let mut tr = Trainer::new(train.clone(), agent.clone()).unwrap();
    assert_eq!(tr.replay().num_injected_episodes(), 7);
    assert_eq!(tr.replay().injected_transitions(), 1400);
    tr.run(700, &mut Quiet).unwrap();
    assert!(tr.agent().updates() > 50);
    assert!(tr.replay().injected_transitions() <= 1500);

    // A teacher of another environment or reward is refused, naming the key.
    let mut other = train.clone();
    other.env = "Pendulum-v1".into();
    match Trainer::new(other, agent.clone()) {
        Err(AgentError::Config { field, reason }) => {
            assert_eq!(field, "train.injection");
            assert!(reason.contains("PendulumNoVel-v1"), "{reason}");
        }
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("a teacher of another env was accepted"),
    }
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    match Trainer::new(train, agent) {
        Err(AgentError::Checkpoint(m)) => assert!(m.contains("truncated"), "{m}"),
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("a truncated teacher file was accepted"),
    }
}
