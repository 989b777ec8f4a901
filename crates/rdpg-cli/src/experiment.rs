//! Experiment files: one TOML file per experiment, `--set key=value` overrides, validation.
//!
//! ```toml
//! name = "hardcore-rdpg"          # free text, used in reports
//! algo = "rdpg"                   # rdpg | ddpg | sac | ppo
//! [train]                         # rdpg_agents::TrainConfig: env, reward, budget, envs,
//! env = "BipedalWalkerHardcore-v3"  # evaluation, seeds (every algorithm)
//! total_steps = 1_000_000
//! [off_policy]                    # rdpg_agents::OffPolicyConfig (rdpg, ddpg, sac): warm-up,
//! warmup_steps = 10_000           # replay, exploration, injection
//! [agent]                         # rdpg_agents::RdpgConfig (rdpg, ddpg, sac)
//! scan_len = 120
//! [agent.sac]                     # rdpg_agents::rdpg::SacConfig (sac only; its exploration
//! init_alpha = 1.0                #   defaults to kind = "none"; `tqc = { quantiles = 25,
//!                                 #   drop_per_critic = 2 }` for TQC's critics)
//! [ppo]                           # rdpg_agents::PpoConfig (ppo)
//! [run]                           # RunConfig: checkpoints, kept agents
//! checkpoint_every = 50_000
//! keep_agents_every = 0
//! ```
//!
//! Every section has defaults, unknown keys are rejected with their name, a section that does
//! not apply to the algorithm is refused, and the resolved experiment (defaults filled in, only
//! the algorithm's own sections) is what a run directory stores as `config.toml`.

use std::path::Path;

use anyhow::{bail, Context, Result};
use rdpg_agents::rdpg::SacConfig;
use rdpg_agents::{Algo, Learner, OffPolicyConfig, PpoConfig, RdpgConfig, TrainConfig};
use serde::{Deserialize, Serialize};

/// Keys that were in `[train]` before the off-policy settings got their own section.
const MOVED_TO_OFF_POLICY: [&str; 6] = [
    "warmup_steps",
    "updates_per_step",
    "replay_capacity",
    "exploration",
    "param_noise",
    "injection",
];

/// Run-directory settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RunConfig {
    /// Save the full training state to `checkpoints/latest` every this many env steps (0: only
    /// at the end and on Ctrl-C).
    pub checkpoint_every: u64,
    /// Also keep the agent alone (its weights: no optimiser state, no replay; 0.8-1.7 MB for
    /// the zoo's agents) every this many env steps, in `checkpoints/agents/<step>/`, for `rdpg select`
    /// to choose among on more validation episodes than the periodic evaluations use
    /// (0: keep none).
    pub keep_agents_every: u64,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            checkpoint_every: 50_000,
            keep_agents_every: 0,
        }
    }
}

/// One experiment: what `rdpg train --config` reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// Name used in reports (defaults to the config file's stem).
    #[serde(default)]
    pub name: String,
    /// Learning algorithm.
    pub algo: Algo,
    /// The run: environment, reward, budget, environments, evaluation, seed.
    #[serde(default)]
    pub train: TrainConfig,
    /// The off-policy loop (`rdpg`, `ddpg`, `sac`): warm-up, replay, exploration, injection.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub off_policy: Option<OffPolicyConfig>,
    /// The off-policy learner's hyper-parameters (`rdpg`, `ddpg`, `sac`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub agent: Option<RdpgConfig>,
    /// PPO's hyper-parameters (`ppo`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ppo: Option<PpoConfig>,
    /// Checkpointing.
    #[serde(default)]
    pub run: RunConfig,
}

impl Experiment {
    /// Reads `path`, applies `overrides` (`key.path=value`, the value in TOML syntax or a bare
    /// string) and validates the result.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut value: toml::Table = toml::from_str(&text)
            .with_context(|| format!("{} is not valid TOML", path.display()))?;
        for o in overrides {
            set_key(&mut value, o)?;
        }
        if let Some(toml::Value::Table(train)) = value.get("train") {
            if let Some(key) = MOVED_TO_OFF_POLICY.iter().find(|k| train.contains_key(**k)) {
                bail!(
                    "{}: train.{key} is now off_policy.{key}: the off-policy settings (warm-up, \
                     update rate, replay, exploration, injection) have their own [off_policy] \
                     section since rdpg 0.2",
                    path.display()
                );
            }
        }
        if value.get("algo").and_then(toml::Value::as_str) == Some(Algo::Sac.as_str()) {
            // SAC explores by sampling its policy: no action noise unless the file asks.
            let off = value
                .entry("off_policy")
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let toml::Value::Table(off) = off {
                off.entry("exploration").or_insert_with(|| {
                    toml::Value::Table(toml::Table::from_iter([(
                        "kind".to_string(),
                        toml::Value::String("none".into()),
                    )]))
                });
            }
        }
        let mut exp: Experiment = value
            .try_into()
            .with_context(|| format!("invalid experiment {}", path.display()))?;
        if exp.name.is_empty() {
            exp.name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        exp.resolve()?;
        exp.validate()?;
        Ok(exp)
    }

    /// Fills in the algorithm's own sections with their defaults; a section of another
    /// algorithm is an error naming it.
    fn resolve(&mut self) -> Result<()> {
        let algo = self.algo.as_str();
        if self.algo == Algo::Ppo {
            for (given, key) in [
                (self.agent.is_some(), "agent"),
                (self.off_policy.is_some(), "off_policy"),
            ] {
                if given {
                    bail!("[{key}] does not apply to algo = \"{algo}\" (on-policy: use [ppo])");
                }
            }
            self.ppo.get_or_insert_with(PpoConfig::default);
        } else {
            if self.ppo.is_some() {
                bail!("[ppo] does not apply to algo = \"{algo}\" (use [agent] and [off_policy])");
            }
            let agent = self.agent.get_or_insert_with(RdpgConfig::default);
            match (self.algo, agent.sac.is_some()) {
                (Algo::Sac, false) => agent.sac = Some(SacConfig::default()),
                (Algo::Rdpg | Algo::Ddpg, true) => {
                    bail!("[agent.sac] applies to algo = \"sac\" only (this is \"{algo}\")")
                }
                _ => {}
            }
            self.off_policy.get_or_insert_with(OffPolicyConfig::default);
        }
        Ok(())
    }

    /// Checks the sections and their consistency; errors name the key.
    pub fn validate(&self) -> Result<()> {
        self.train.validate()?;
        if let Some(ppo) = &self.ppo {
            ppo.validate()?;
        }
        if let Some(off) = &self.off_policy {
            off.validate()?;
        }
        if let Some(agent) = &self.agent {
            match (self.algo, agent.recurrent) {
                (Algo::Ddpg, true) => bail!("algo = \"ddpg\" needs agent.recurrent = false"),
                (Algo::Rdpg, false) => bail!("algo = \"rdpg\" needs agent.recurrent = true"),
                (Algo::Sac, _) if agent.sac.is_none() => {
                    bail!("algo = \"sac\" needs its [agent.sac] section")
                }
                _ => agent.validate()?,
            }
        }
        Ok(())
    }

    /// The learner of this (resolved) experiment, for `rdpg_agents::new_trainer`.
    pub fn learner(&self) -> Learner {
        match self.algo {
            Algo::Ppo => Learner::Ppo(self.ppo.clone().unwrap_or_default()),
            Algo::Rdpg | Algo::Ddpg | Algo::Sac => Learner::OffPolicy {
                agent: self.agent.clone().unwrap_or_default(),
                off_policy: self.off_policy.clone().unwrap_or_default(),
            },
        }
    }

    /// The resolved experiment as TOML (every default written out).
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }
}

/// Applies one `a.b.c=value` override to a TOML table, creating intermediate tables.
fn set_key(root: &mut toml::Table, assignment: &str) -> Result<()> {
    let Some((key, raw)) = assignment.split_once('=') else {
        bail!("--set {assignment:?}: expected key=value");
    };
    let key = key.trim();
    let path: Vec<&str> = key.split('.').collect();
    if path.iter().any(|p| p.is_empty()) {
        bail!("--set {assignment:?}: empty key component");
    }
    // Parse the value as TOML (numbers, booleans, arrays, inline tables, quoted strings);
    // anything else is taken as a bare string.
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.trim().to_string()));
    let mut table = root;
    for part in &path[..path.len() - 1] {
        let entry = table
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        table = match entry {
            toml::Value::Table(t) => t,
            _ => bail!("--set {key}: {part} is not a table"),
        };
    }
    table.insert(path[path.len() - 1].to_string(), value);
    Ok(())
}

/// A rough upper estimate of the memory a run of `exp` needs, in bytes: the replay (or PPO's
/// rollout), the environments, the networks with their optimiser state, and the activations
/// of one update. In floating point, so that absurd sizes give an absurd estimate rather than
/// an overflow.
fn memory_estimate(exp: &Experiment) -> Result<f64> {
    let env = rdpg_envs::make_with(&exp.train.env, &exp.train.env_options())?;
    let (obs, act) = (
        env.observation_space().dim() as f64,
        env.action_space().dim() as f64,
    );
    let envs = exp.train.num_envs as f64;
    // A walker with its Box2D world, terrain and lidar, with room to spare.
    let per_env = 512.0 * 1024.0;
    let bytes = match exp.learner() {
        rdpg_agents::Learner::OffPolicy { agent, off_policy } => {
            let critics = if agent.twin_critic { 2.0 } else { 1.0 };
            let state = if agent.burn_in_from_stored_state {
                2.0 * (agent.actor_hidden as f64 + critics * agent.critic_hidden as f64)
            } else {
                0.0
            };
            let injected = off_policy
                .injection
                .as_ref()
                .map_or(0.0, |i| i.max_fraction);
            let per_step = 4.0 * (obs + act + 2.0 + state);
            let replay = off_policy.replay_capacity as f64 * (1.0 + injected) * per_step;
            let heads: usize = agent.actor_head.iter().chain(&agent.critic_head).sum();
            let width =
                (agent.embed_dim() + agent.actor_hidden + agent.critic_hidden + heads) as f64;
            let steps = agent.scan_len as f64 + agent.opt_len as f64 + 1.0;
            // Inputs, gates and saved activations of the online and target networks.
            let batch = agent.batch_size as f64 * steps * 4.0 * (obs + act + 16.0 * width) * 4.0;
            // Networks, targets, gradients and Adam's two moments.
            let params = 5.0 * 4.0 * agent.param_count(obs as usize, act as usize);
            replay + batch + params
        }
        rdpg_agents::Learner::Ppo(p) => {
            let rollout = p.rollout_steps as f64 * envs * 4.0 * (obs + act + 8.0);
            let width: f64 = p.hidden.iter().map(|&h| h as f64).sum();
            // Policy and value networks (square layers at most), gradients, Adam's moments.
            let params =
                2.0 * 4.0 * 4.0 * p.hidden.iter().map(|&h| (h as f64).powi(2)).sum::<f64>();
            rollout + p.minibatch_size as f64 * 4.0 * (obs + act + 8.0 * width) * 4.0 + params
        }
    };
    Ok(bytes + envs * per_env)
}

/// Refuses a run whose [`memory_estimate`] exceeds the memory this machine has available.
pub fn check_memory(exp: &Experiment) -> Result<()> {
    let need = memory_estimate(exp)?;
    let available = crate::rundir::machine::meminfo_bytes("MemAvailable");
    let gib = |b: f64| b / (1u64 << 30) as f64;
    if let Some(avail) = available.filter(|&a| need > a as f64) {
        bail!(
            "this run needs about {:.1} GiB (replay or rollout, {} environments, one update's \
             activations) but the machine has {:.1} GiB available: lower \
             off_policy.replay_capacity, agent.batch_size or train.num_envs",
            gib(need),
            exp.train.num_envs,
            gib(avail as f64)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str, sets: &[&str]) -> Result<Experiment> {
        let dir = std::env::temp_dir().join(format!("rdpg-exp-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(format!("e{}.toml", text.len() + sets.len()));
        std::fs::write(&p, text).unwrap();
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        Experiment::load(&p, &sets)
    }

    #[test]
    fn defaults_overrides_and_round_trip() {
        let e = parse(
            "algo = \"rdpg\"\n[train]\nenv = \"CueMemory-v0\"\n",
            &[
                "agent.scan_len=7",
                "train.seed=3",
                "name=x",
                "off_policy.exploration={kind=\"none\"}",
            ],
        )
        .unwrap();
        assert_eq!(e.agent.as_ref().unwrap().scan_len, 7);
        assert_eq!(e.train.seed, 3);
        assert_eq!(e.name, "x");
        let back: Experiment = toml::from_str(&e.to_toml().unwrap()).unwrap();
        assert_eq!(back, e);
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let err = |text: &str, sets: &[&str]| format!("{:#}", parse(text, sets).unwrap_err());
        let base = "algo = \"rdpg\"\n";
        assert!(err(base, &["agent.scan_lenn=3"]).contains("scan_lenn"));
        assert!(err(base, &["train.bogus=1"]).contains("bogus"));
        assert!(err(base, &["agent.gamma=1.5"]).contains("gamma"));
        assert!(err(base, &["train.env=Nope-v0"]).contains("train.env"));
        assert!(err(base, &["agent.batch_size=-1"]).contains("batch_size"));
        assert!(err(base, &["agent.recurrent=false"]).contains("recurrent"));
        assert!(err("algo = \"sac\"\n", &[]).contains("sac"));
        assert!(err(base, &["novalue"]).contains("key=value"));
        // Sections of another algorithm are refused, and so are keys from before the split.
        let ppo = "algo = \"ppo\"\n";
        assert!(err(ppo, &["off_policy.warmup_steps=3"]).contains("[off_policy]"));
        assert!(err(ppo, &["agent.scan_len=3"]).contains("[agent]"));
        assert!(err(base, &["ppo.epochs=3"]).contains("[ppo]"));
        assert!(err(base, &["train.warmup_steps=3"]).contains("off_policy.warmup_steps"));
        assert!(err(base, &["off_policy.replay_capacity=0"]).contains("replay_capacity"));
    }

    #[test]
    fn resolved_experiments_hold_only_their_algorithms_sections() {
        let ppo = parse("algo = \"ppo\"\n", &[]).unwrap();
        let text = ppo.to_toml().unwrap();
        assert!(
            text.contains("[ppo]") && !text.contains("[agent]") && !text.contains("[off_policy]")
        );
        let rdpg = parse("algo = \"rdpg\"\n", &[]).unwrap();
        let text = rdpg.to_toml().unwrap();
        assert!(
            text.contains("[agent]") && text.contains("[off_policy]") && !text.contains("[ppo]")
        );
    }
}
