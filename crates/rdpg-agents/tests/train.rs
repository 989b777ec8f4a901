//! End-to-end tests of the training loop: resume identity, validation, corrupt checkpoints.

use std::path::{Path, PathBuf};

use rdpg_agents::rdpg::{
    memory_task_config, ExplorationConfig, OffPolicyConfig, OffPolicyTrainer, ParamNoiseSpec,
    PerturbSchedule,
};
use rdpg_agents::{AgentError, Quiet, RdpgConfig, TrainConfig, Trainer};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rdpg-train-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn small() -> (TrainConfig, OffPolicyConfig, RdpgConfig) {
    let train = TrainConfig {
        env: "PendulumNoVel-v1".into(),
        total_steps: 700,
        num_envs: 2,
        workers: 2,
        eval_every: 0,
        eval_episodes: 1,
        seed: 11,
        ..TrainConfig::default()
    };
    let off = OffPolicyConfig {
        warmup_steps: 250,
        updates_per_step: 0.25,
        replay_capacity: 5_000,
        exploration: ExplorationConfig::Ou {
            theta: 0.15,
            sigma: 0.3,
        },
        ..OffPolicyConfig::default()
    };
    let mut agent = memory_task_config(false);
    agent.actor_hidden = 16;
    agent.critic_hidden = 16;
    agent.trunk = rdpg_agents::rdpg::Trunk::Mlp { hidden: vec![16] };
    agent.batch_size = 8;
    agent.num_threads = Some(1);
    (train, off, agent)
}

fn bytes(dir: &Path, file: &str) -> Vec<u8> {
    std::fs::read(dir.join("agent").join(file)).unwrap()
}

#[test]
fn half_save_load_half_equals_one_go() {
    let (train, off, agent) = small();
    resume_is_identical(train, off, agent, "plain");
}

#[test]
fn half_save_load_half_equals_one_go_with_parameter_noise() {
    let (train, mut off, agent) = small();
    off.param_noise = Some(ParamNoiseSpec {
        adapt_every_updates: 5,
        perturb: PerturbSchedule::Steps(60),
        ..ParamNoiseSpec::default()
    });
    let sigma = resume_is_identical(train, off, agent, "param");
    assert!(sigma.is_some_and(|s| s != ParamNoiseSpec::default().initial_stddev));
}

/// Window-of-k agents carry each environment's last observations across a checkpoint.
#[test]
fn half_save_load_half_equals_one_go_with_a_window_of_k() {
    let (train, off, mut agent) = small();
    agent.act_window = 4;
    agent.scan_len = 3;
    agent.update_len = 1;
    agent.tau = 0.01;
    resume_is_identical(train, off, agent, "window");
}

/// Runs 700 steps in one go and 333 + save + load + the rest; asserts identical weights,
/// optimiser and replay, and returns the parameter-noise σ reached.
fn resume_is_identical(
    train: TrainConfig,
    off: OffPolicyConfig,
    agent: RdpgConfig,
    tag: &str,
) -> Option<f64> {
    let tmp = |name: &str| tmp(&format!("{tag}-{name}"));
    let mut one = OffPolicyTrainer::new(train.clone(), off.clone(), agent.clone()).unwrap();
    one.run(700, &mut Quiet).unwrap();
    let d1 = tmp("one");
    one.save(&d1).unwrap();

    let mut first = OffPolicyTrainer::new(train, off, agent).unwrap();
    // 333 is not a multiple of anything: episodes are in progress in both envs.
    first.run(333, &mut Quiet).unwrap();
    let mid = tmp("mid");
    first.save(&mid).unwrap();
    drop(first);
    let mut second = OffPolicyTrainer::load(&mid).unwrap();
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
    let (mut train, off, agent) = small();
    train.total_steps = 300;
    let mut t = OffPolicyTrainer::new(train, off, agent).unwrap();
    t.run(300, &mut Quiet).unwrap();
    let d = tmp("corrupt");
    t.save(&d).unwrap();
    let replay = d.join("replay.bin");
    let full = std::fs::read(&replay).unwrap();
    std::fs::write(&replay, &full[..full.len() / 2]).unwrap();
    let err = OffPolicyTrainer::load(&d)
        .err()
        .expect("a truncated replay must not load")
        .to_string();
    assert!(
        err.contains("replay.bin") && err.contains("truncated or corrupt"),
        "{err}"
    );
    std::fs::remove_file(d.join("loop.bin")).unwrap();
    std::fs::write(&replay, &full).unwrap();
    let err = OffPolicyTrainer::load(&d).err().unwrap().to_string();
    assert!(err.contains("loop.bin"), "{err}");
    assert!(OffPolicyTrainer::load(&tmp("missing")).is_err());
}

#[test]
fn invalid_train_configs_name_the_field() {
    let (train, off, agent) = small();
    let cases: Vec<(TrainConfig, OffPolicyConfig, &str)> = vec![
        (
            TrainConfig {
                env: "Nope-v0".into(),
                ..train.clone()
            },
            off.clone(),
            "train.env",
        ),
        (
            TrainConfig {
                num_envs: 0,
                ..train.clone()
            },
            off.clone(),
            "train.num_envs",
        ),
        (
            train.clone(),
            OffPolicyConfig {
                updates_per_step: f64::NAN,
                ..off.clone()
            },
            "off_policy.updates_per_step",
        ),
        (
            train.clone(),
            OffPolicyConfig {
                exploration: ExplorationConfig::Gaussian { sigma: -1.0 },
                ..off.clone()
            },
            "off_policy.exploration",
        ),
        (
            train.clone(),
            OffPolicyConfig {
                param_noise: Some(ParamNoiseSpec {
                    adoption_coefficient: 0.9,
                    ..ParamNoiseSpec::default()
                }),
                ..off.clone()
            },
            "off_policy.param_noise",
        ),
    ];
    for (cfg, off, field) in cases {
        match OffPolicyTrainer::new(cfg, off, agent.clone()) {
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
    assert!(OffPolicyTrainer::new(train, off, bad_agent).is_err());
}

/// Teacher files: recorded, loaded into the replay under the injected cap, sampled, checked
/// against the run's environment, and rejected clearly when corrupt.
#[test]
fn experience_injection_loads_teachers_under_the_cap() {
    use rdpg_agents::rdpg::inject::{record, InjectionConfig, TeacherFile, TeacherInfo};
    let (train, mut off, agent) = small();
    let teacher_agent = rdpg_agents::RdpgAgent::new(agent.clone(), 2, 1, 5).unwrap();
    let mut policy = rdpg_agents::rdpg::RdpgPolicy::new(&teacher_agent);
    let t = record(&mut policy, &train, 12, 77, 0.3, TeacherInfo::default()).unwrap();
    assert_eq!(t.episodes.len(), 12);
    assert!(t
        .episodes
        .iter()
        .all(|e| e.steps(1) == 200 && e.truncated && !e.terminated));
    let path = tmp("teacher.bin");
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    t.save(&path).unwrap();
    assert_eq!(TeacherFile::load(&path).unwrap(), t);

    // Capacity 5000 with a 0.3 cap: at most 1500 injected transitions, i.e. 7 episodes of 200.
    off.injection = Some(InjectionConfig {
        teachers: vec![path.clone()],
        initial_share: 0.5,
        anneal_steps: 500,
        max_fraction: 0.3,
    });
    let mut tr = OffPolicyTrainer::new(train.clone(), off.clone(), agent.clone()).unwrap();
    assert_eq!(tr.replay().num_injected_episodes(), 7);
    assert_eq!(tr.replay().injected_transitions(), 1400);
    tr.run(700, &mut Quiet).unwrap();
    assert!(tr.agent().updates() > 50);
    assert!(tr.replay().injected_transitions() <= 1500);

    // A teacher of another environment or reward is refused, naming the key.
    let mut other = train.clone();
    other.env = "Pendulum-v1".into();
    match OffPolicyTrainer::new(other, off.clone(), agent.clone()) {
        Err(AgentError::Config { field, reason }) => {
            assert_eq!(field, "off_policy.injection");
            assert!(reason.contains("PendulumNoVel-v1"), "{reason}");
        }
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("a teacher of another env was accepted"),
    }
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    match OffPolicyTrainer::new(train, off, agent) {
        Err(AgentError::Checkpoint(m)) => assert!(m.contains("truncated"), "{m}"),
        Err(e) => panic!("unexpected error {e}"),
        Ok(_) => panic!("a truncated teacher file was accepted"),
    }
}

/// A trainer checkpoint of the layout before the re-cut (format 1: `train.json` and
/// `loop.bin`, no `checkpoint.json`) is refused with a message naming both formats, by the
/// algorithm-agnostic loader and by each trainer; a header of another trainer is refused too.
#[test]
fn checkpoints_of_another_format_or_trainer_are_refused_naming_them() {
    let d = tmp("format1");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("train.json"), "{}").unwrap();
    std::fs::write(d.join("loop.bin"), [0u8; 8]).unwrap();
    for err in [
        rdpg_agents::load_trainer(&d).err().unwrap().to_string(),
        OffPolicyTrainer::load(&d).err().unwrap().to_string(),
        rdpg_agents::PpoTrainer::load(&d).err().unwrap().to_string(),
    ] {
        assert!(
            err.contains("format 1") && err.contains("formats 3 to 4"),
            "{err}"
        );
    }
    std::fs::write(
        d.join("checkpoint.json"),
        r#"{"format": 3, "trainer": "ppo"}"#,
    )
    .unwrap();
    let err = OffPolicyTrainer::load(&d).err().unwrap().to_string();
    assert!(err.contains("Ppo") && err.contains("OffPolicy"), "{err}");
    std::fs::write(
        d.join("checkpoint.json"),
        r#"{"format": 2, "trainer": "off_policy"}"#,
    )
    .unwrap();
    let err = rdpg_agents::load_trainer(&d).err().unwrap().to_string();
    assert!(
        err.contains("format 2") && err.contains("formats 3 to 4"),
        "{err}"
    );
}

/// A checkpoint of trainer format 3 (its `replay.bin` ending in an episode in progress that
/// the trainer never used, `None`) resumes like the same checkpoint in format 4; one whose
/// replay holds such an episode is refused, naming the file.
#[test]
fn a_format_3_checkpoint_resumes_and_one_with_an_episode_in_progress_is_refused() {
    let (train, off, agent) = small();
    let mut t = OffPolicyTrainer::new(train, off, agent).unwrap();
    t.run(333, &mut Quiet).unwrap();
    let new = tmp("format4");
    t.save(&new).unwrap();
    let as_format_3 = |tag: &str, open: Option<rdpg_core::Episode>| -> PathBuf {
        let d = tmp(tag);
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        copy_dir(&new, &d);
        std::fs::write(
            d.join("checkpoint.json"),
            r#"{"format": 3, "trainer": "off_policy"}"#,
        )
        .unwrap();
        let mut replay = std::fs::read(d.join("replay.bin")).unwrap();
        replay.extend(bincode::serialize(&open).unwrap());
        std::fs::write(d.join("replay.bin"), replay).unwrap();
        std::fs::remove_file(d.join("manifest.json")).unwrap();
        rdpg_agents::common::checkpoint::seal(&d).unwrap();
        d
    };
    let old = as_format_3("format3", None);
    let mut a = OffPolicyTrainer::load(&new).unwrap();
    let mut b = OffPolicyTrainer::load(&old).unwrap();
    a.run(500, &mut Quiet).unwrap();
    b.run(500, &mut Quiet).unwrap();
    assert!(a.agent().updates() > 0);
    assert_eq!(a.agent().weights(), b.agent().weights());
    let episode = a.replay().episodes()[0].clone();
    let bad = as_format_3("format3-open", Some(episode));
    let err = OffPolicyTrainer::load(&bad).err().unwrap().to_string();
    assert!(
        err.contains("replay.bin") && err.contains("in progress"),
        "{err}"
    );
}

/// Copies the files of checkpoint `from` (nested directories included) into `to`.
fn copy_dir(from: &Path, to: &Path) {
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            std::fs::create_dir_all(&dest).unwrap();
            copy_dir(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}

/// The algorithm-agnostic surface: `new_trainer` and `load_trainer` give a `Box<dyn Trainer>`
/// that resumes exactly, and `load_policy` evaluates the saved agent like the trainer does.
#[test]
fn any_algorithm_through_the_trainer_trait() {
    let (train, off, agent) = small();
    let learner = rdpg_agents::Learner::OffPolicy {
        agent,
        off_policy: off,
    };
    let mut t = rdpg_agents::new_trainer(train.clone(), learner).unwrap();
    t.run(300, &mut Quiet).unwrap();
    let d = tmp("dyn");
    t.save(&d).unwrap();
    let mut back = rdpg_agents::load_trainer(&d).unwrap();
    assert_eq!(back.steps(), t.steps());
    assert_eq!(back.updates(), t.updates());
    let (e1, e2) = (t.evaluate().unwrap(), back.evaluate().unwrap());
    assert_eq!(e1, e2);
    t.save_agent(&d.join("best")).unwrap();
    let mut policy = rdpg_agents::load_policy(rdpg_agents::Algo::Rdpg, &d.join("best")).unwrap();
    let e3 = rdpg_agents::common::evaluate_policy(
        policy.as_mut(),
        &train,
        train.eval_episodes,
        train.eval_seed,
    )
    .unwrap();
    assert_eq!(e3.returns, e1.returns);
}

/// Injected (teacher) episodes stay in their own pool for the whole anneal: with a replay of
/// 2000 transitions, an anneal over 10k steps and 8k steps of the agent's own experience (4x
/// the capacity), the batches near 8k still hold the annealed share, `round(n * share)` of
/// `n` windows, as logged in each update's statistics.
#[test]
fn injected_experience_outlives_the_agents_fifo() {
    use rdpg_agents::rdpg::inject::{record, InjectionConfig, TeacherInfo};
    use rdpg_agents::rdpg::RdpgPolicy;
    use rdpg_agents::{TrainObserver, UpdateStats};

    let train = TrainConfig {
        env: "CueMemory-v0".into(),
        total_steps: 8_200,
        eval_every: 0,
        eval_episodes: 1,
        seed: 3,
        ..TrainConfig::default()
    };
    let mut agent = memory_task_config(false);
    agent.actor_hidden = 8;
    agent.critic_hidden = 8;
    agent.trunk = rdpg_agents::rdpg::Trunk::Mlp { hidden: vec![8] };
    agent.batch_size = 32;
    agent.scan_len = 2;
    agent.opt_len = 4;
    agent.update_len = 4;
    agent.num_threads = Some(1);
    let teacher_agent = rdpg_agents::RdpgAgent::new(agent.clone(), 2, 1, 5).unwrap();
    let teacher = record(
        &mut RdpgPolicy::new(&teacher_agent),
        &train,
        50,
        9,
        0.2,
        TeacherInfo::default(),
    )
    .unwrap();
    let path = tmp("cue-teacher.bin");
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    teacher.save(&path).unwrap();
    let inj = InjectionConfig {
        teachers: vec![path],
        initial_share: 0.5,
        anneal_steps: 10_000,
        max_fraction: 0.3,
    };
    let off = OffPolicyConfig {
        warmup_steps: 500,
        updates_per_step: 0.1,
        replay_capacity: 2_000,
        injection: Some(inj.clone()),
        ..OffPolicyConfig::default()
    };
    struct Shares(Vec<(u64, f64)>);
    impl TrainObserver for Shares {
        fn on_update(&mut self, step: u64, s: &UpdateStats) {
            self.0.push((step, s.injected_share));
        }
    }
    let mut t = OffPolicyTrainer::new(train, off, agent).unwrap();
    let mut shares = Shares(Vec::new());
    t.run(u64::MAX, &mut shares).unwrap();
    assert_eq!(t.replay().num_injected_episodes(), 50);
    assert!(t.replay().agent_len_transitions() <= 2_000);
    let late: Vec<&(u64, f64)> = shares.0.iter().filter(|(s, _)| *s >= 7_900).collect();
    assert!(late.len() >= 20, "{} late updates", late.len());
    for &&(step, share) in &late {
        let want = (32.0 * inj.share(step)).round() / 32.0;
        assert_eq!(share, want, "step {step}");
        assert!(share > 0.0, "step {step}: no teacher windows left");
    }
}

/// With parameter noise the environments act with a perturbed copy of the actor, but the
/// replay stores the trained actor's states (what burn-in starts from): every stored state
/// equals the trained actor's state along the episode's observations.
#[test]
fn stored_states_come_from_the_trained_actor_under_parameter_noise() {
    let (mut train, mut off, mut agent) = small();
    train.num_envs = 1;
    train.workers = 1;
    train.total_steps = 900;
    off.updates_per_step = 0.0; // a fixed actor, so that the episode can be replayed
    off.warmup_steps = 250;
    off.param_noise = Some(ParamNoiseSpec {
        perturb: PerturbSchedule::Steps(100),
        ..ParamNoiseSpec::default()
    });
    agent.burn_in_from_stored_state = true;
    let mut t = OffPolicyTrainer::new(train, off, agent).unwrap();
    t.run(u64::MAX, &mut Quiet).unwrap();
    // Episodes are 200 steps: the third (steps 400..600) was acted by perturbed copies.
    let ep = t.replay().episodes()[2].clone();
    let a = t.agent();
    let sd = a.state_dim();
    let (mut clean, mut exploring) = (a.initial_state(1), a.initial_state(1));
    let mut differs = false;
    for k in 0..ep.len() {
        let stored = &ep.states[k * sd..(k + 1) * sd];
        assert_eq!(stored, &clean.to_vec()[..], "state before step {k}");
        differs |= stored != &exploring.to_vec()[..];
        let o = &ep.obs[k * 2..(k + 1) * 2];
        a.act(o, &mut clean).unwrap();
        a.act_exploring(o, &mut exploring).unwrap();
    }
    assert!(differs, "the exploring copy was never perturbed");
}

/// Parameter-noise adaptation (Plappert et al.) on a fixed actor: the distance made by one
/// fresh perturbation is noisy, so σ settles where the *median* distance equals the target
/// (the rule multiplies and divides by the same factor). From σ ten times too large and ten
/// times too small, with a coefficient of 1.05 (`ln 10 / ln 1.05` ≈ 47 steps to cross), after
/// 60 adaptations the median distance of the next 60 is within a factor of 1.5 of the target
/// and both runs agree on σ within a factor of 2.
#[test]
fn parameter_noise_reaches_the_target_distance_on_a_fixed_actor() {
    use rdpg_agents::rdpg::trainer::adapt_param_noise;
    use rdpg_core::noise::{AdaptiveParamNoise, ParamNoiseConfig};
    use rdpg_core::rng::NpRng;
    let (_, _, mut cfg) = small();
    cfg.actor_hidden = 32;
    cfg.trunk = rdpg_agents::rdpg::Trunk::Mlp { hidden: vec![32] };
    let mut agent = rdpg_agents::RdpgAgent::new(cfg, 2, 1, 7).unwrap();
    let mut rng = NpRng::from_seed(1);
    let obs: Vec<f32> = (0..128).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let target = 0.1;
    let mut sigmas = Vec::new();
    for initial in [1.0, 0.01] {
        let mut noise = AdaptiveParamNoise::new(ParamNoiseConfig {
            initial_stddev: initial,
            desired_action_stddev: target,
            adoption_coefficient: 1.05,
        });
        let mut distances = Vec::new();
        for _ in 0..120 {
            distances.push(adapt_param_noise(&mut agent, &mut noise, &obs, &mut rng).unwrap());
        }
        let first = distances[0];
        assert!(
            if initial > 0.1 {
                first > 2.0 * target
            } else {
                first < 0.5 * target
            },
            "σ = {initial} starts at distance {first}"
        );
        let mut tail = distances[60..].to_vec();
        tail.sort_by(f64::total_cmp);
        let median = tail[tail.len() / 2];
        assert!(
            median > target / 1.5 && median < target * 1.5,
            "from σ = {initial}: median distance {median} after 60 adaptations"
        );
        sigmas.push(noise.sigma);
    }
    let ratio = sigmas[0] / sigmas[1];
    assert!(
        (0.5..2.0).contains(&ratio),
        "σ from above {} and from below {}",
        sigmas[0],
        sigmas[1]
    );
}

/// `truncated` episodes reach the replay with the true last observation (the `final_obs` of
/// the vector env, not the next episode's reset observation) and the flags kept apart: each
/// stored episode, replayed in a fresh env from its scheduled seed with its stored actions,
/// ends on its stored last observation with `truncated` and not `terminated`.
#[test]
fn final_observations_and_truncation_reach_the_replay() {
    use rdpg_agents::common::to_env_action;
    use rdpg_envs::vector::episode_seed;
    let (mut train, off, agent) = small();
    train.total_steps = 1_200; // 3 episodes of 200 steps in each of the 2 envs
    let mut t = OffPolicyTrainer::new(train.clone(), off, agent).unwrap();
    t.run(u64::MAX, &mut Quiet).unwrap();
    let episodes = t.replay().episodes();
    assert_eq!(episodes.len(), 6);
    let mut env = rdpg_envs::make_with(&train.env, &train.env_options()).unwrap();
    let space = env.action_space().clone();
    let mut seen = Vec::new();
    for ep in episodes {
        assert!(ep.truncated && !ep.terminated);
        let found = (0..2)
            .flat_map(|i| (0..3).map(move |k| (i, k)))
            .find(|&(i, k)| {
                let (o, _) = env.reset(Some(episode_seed(train.seed, i, k))).unwrap();
                o[..] == ep.obs[..2]
            })
            .expect("the episode's first observation comes from its scheduled seed");
        seen.push(found);
        let (o, _) = env
            .reset(Some(episode_seed(train.seed, found.0, found.1)))
            .unwrap();
        assert_eq!(o[..], ep.obs[..2]);
        let n = ep.len();
        let mut last = None;
        for k in 0..n {
            let a = to_env_action(&ep.actions[k..k + 1], &space.low, &space.high);
            let s = env.step(&a).unwrap();
            assert_eq!(s.obs[..], ep.obs[(k + 1) * 2..(k + 2) * 2], "step {k}");
            last = Some(s);
        }
        let last = last.unwrap();
        assert!(last.truncated && !last.terminated);
    }
    seen.sort();
    seen.dedup();
    assert_eq!(seen.len(), 6);
}

/// Teacher files hold seeds and actions: a student replays them through its own env options
/// (another reward, a fall penalty, the previous action in front of its observation, a frame
/// stack) and gets its own view of the same episodes, checked against the recorded stock
/// return; what cannot be rebuilt, and a changed, damaged or old file, is refused saying why.
#[test]
fn teacher_episodes_replay_in_the_students_own_view() {
    use rdpg_agents::common::to_env_action;
    use rdpg_agents::rdpg::inject::{record, TeacherFile, TeacherInfo};
    use rdpg_agents::rdpg::RdpgPolicy;
    let teacher_cfg = TrainConfig {
        env: "BipedalWalker-v3".into(),
        ..TrainConfig::default()
    };
    let (_, _, agent) = small();
    let teacher_agent = rdpg_agents::RdpgAgent::new(agent, 24, 4, 3).unwrap();
    let path = tmp("walker-teacher.bin");
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    record(
        &mut RdpgPolicy::new(&teacher_agent),
        &teacher_cfg,
        3,
        40,
        0.5,
        TeacherInfo::default(),
    )
    .unwrap()
    .save(&path)
    .unwrap();
    let t = TeacherFile::load(&path).unwrap();
    assert_eq!(
        (t.env.as_str(), t.action_repeat, t.act_dim),
        ("BipedalWalker-v3", 1, 4)
    );
    assert_eq!(t.teacher.train_reward, "stock");

    // The teacher's own view: its stock rewards add up to the recorded returns.
    let own = t.episodes_for(&teacher_cfg, &path).unwrap();
    for (e, te) in own.iter().zip(&t.episodes) {
        assert!(e.injected && e.states.is_empty());
        assert_eq!((e.len(), &e.actions), (te.steps(4), &te.actions));
        let ret: f64 = e.rewards.iter().map(|&r| f64::from(r)).sum();
        assert!(
            (ret - te.stock_return).abs() < 1e-3,
            "{ret} {}",
            te.stock_return
        );
    }
    // A student on the paper's reward, with a fall penalty of -10 and the previous action in
    // front of its observation: the same episodes, seen its way.
    let student = TrainConfig {
        reward: rdpg_envs::WalkerReward::Paper,
        fall_penalty: Some(-10.0),
        prev_action_obs: true,
        ..teacher_cfg.clone()
    };
    let theirs = t.episodes_for(&student, &path).unwrap();
    let mut falls = 0;
    for (s, o) in theirs.iter().zip(&own) {
        assert_eq!(
            (s.len(), s.terminated, s.truncated),
            (o.len(), o.terminated, o.truncated)
        );
        for k in 0..=s.len() {
            let row = &s.obs[k * 28..(k + 1) * 28];
            assert_eq!(&row[4..], &o.obs[k * 24..(k + 1) * 24], "step {k}");
            // The previous action as the env applied it (mapped onto its action space).
            let prev = if k == 0 {
                vec![0.0; 4]
            } else {
                to_env_action(&o.actions[(k - 1) * 4..k * 4], &[-1.0; 4], &[1.0; 4])
            };
            assert_eq!(&row[..4], &prev[..], "step {k}");
        }
        assert_ne!(s.rewards, o.rewards);
        if o.terminated {
            falls += 1;
            assert_eq!(
                (*s.rewards.last().unwrap(), *o.rewards.last().unwrap()),
                (-10.0, -100.0)
            );
        }
    }
    assert!(
        falls > 0,
        "no teacher episode fell: the fall penalty went unchecked"
    );
    // A student that sees its last 2 observations: each step's view is the one before and
    // its own, zeros before the episode's first.
    let stacked = TrainConfig {
        frame_stack: 2,
        ..teacher_cfg.clone()
    };
    for (s, o) in t.episodes_for(&stacked, &path).unwrap().iter().zip(&own) {
        assert_eq!((s.len(), &s.rewards), (o.len(), &o.rewards));
        for k in 0..=s.len() {
            let before = if k == 0 {
                vec![0.0; 24]
            } else {
                o.obs[(k - 1) * 24..k * 24].to_vec()
            };
            assert_eq!(s.obs[k * 48..k * 48 + 24], before[..], "step {k}");
            assert_eq!(
                s.obs[k * 48 + 24..(k + 1) * 48],
                o.obs[k * 24..(k + 1) * 24]
            );
        }
    }

    // Another action repeat or env cannot be rebuilt: refused, naming both sides.
    let repeat3 = TrainConfig {
        action_repeat: 3,
        ..teacher_cfg.clone()
    };
    let err = t.episodes_for(&repeat3, &path).unwrap_err().to_string();
    assert!(
        err.contains("action repeat 1") && err.contains("uses 3"),
        "{err}"
    );
    let hardcore = TrainConfig {
        env: "BipedalWalkerHardcore-v3".into(),
        ..teacher_cfg.clone()
    };
    let err = t.episodes_for(&hardcore, &path).unwrap_err().to_string();
    assert!(
        err.contains("recorded on BipedalWalker-v3") && err.contains("BipedalWalkerHardcore-v3"),
        "{err}"
    );
    // An episode that no longer replays to its record is refused, naming it and both values.
    let mut changed = t.clone();
    changed.episodes[1].stock_return += 1.0;
    let err = changed
        .episodes_for(&teacher_cfg, &path)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("episode 1 (seed 41)")
            && err.contains(&format!("{:.6}", t.episodes[1].stock_return))
            && err.contains(&format!("{:.6}", changed.episodes[1].stock_return)),
        "{err}"
    );
    // A flipped byte, a cut file, a format-1 file and another kind of file are refused.
    let bytes = std::fs::read(&path).unwrap();
    let bad = tmp("bad-teacher.bin");
    std::fs::create_dir_all(bad.parent().unwrap()).unwrap();
    let mut flipped = bytes.clone();
    *flipped.last_mut().unwrap() ^= 1;
    let mut v1 = 15u64.to_le_bytes().to_vec();
    v1.extend_from_slice(b"rdpg-teacher-v1");
    v1.extend_from_slice(&[0; 64]);
    for (content, needle) in [
        (flipped, "CRC-32"),
        (bytes[..bytes.len() - 10].to_vec(), "truncated"),
        (bytes[..10].to_vec(), "truncated"),
        (v1, "format 1"),
        (b"{\"name\": 1}".to_vec(), "not a teacher file"),
    ] {
        std::fs::write(&bad, content).unwrap();
        let err = TeacherFile::load(&bad).unwrap_err().to_string();
        assert!(err.contains(needle), "{needle}: {err}");
    }
}

/// A student that starts windows from stored states gets, for each teacher episode, its own
/// actor's states from a zero state at the episode's start: what acting along it gives.
#[test]
fn stored_state_students_get_their_own_states_for_teacher_episodes() {
    use rdpg_agents::rdpg::inject::{record, InjectionConfig, TeacherInfo};
    use rdpg_agents::rdpg::RdpgPolicy;
    let (train, mut off, mut agent) = small();
    let teacher_agent = rdpg_agents::RdpgAgent::new(agent.clone(), 2, 1, 5).unwrap();
    let path = tmp("stored-state-teacher.bin");
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    record(
        &mut RdpgPolicy::new(&teacher_agent),
        &train,
        2,
        7,
        0.3,
        TeacherInfo::default(),
    )
    .unwrap()
    .save(&path)
    .unwrap();
    off.injection = Some(InjectionConfig {
        teachers: vec![path],
        initial_share: 0.5,
        anneal_steps: 500,
        max_fraction: 0.3,
    });
    agent.burn_in_from_stored_state = true;
    let tr = OffPolicyTrainer::new(train, off, agent).unwrap();
    let a = tr.agent();
    let (od, sd) = (a.obs_dim(), a.state_dim());
    let injected: Vec<_> = tr
        .replay()
        .episodes()
        .into_iter()
        .filter(|e| e.injected)
        .collect();
    assert_eq!(injected.len(), 2);
    for ep in injected {
        assert_eq!(ep.states.len(), ep.len() * sd);
        let mut st = a.initial_state(1);
        for k in 0..ep.len() {
            let want = st.env_state(0);
            let got = &ep.states[k * sd..(k + 1) * sd];
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() <= 1e-5, "step {k}: {g} vs {w}");
            }
            a.act(&ep.obs[k * od..(k + 1) * od], &mut st).unwrap();
        }
        assert!(ep.states[sd..].iter().any(|&x| x != 0.0));
    }
}
