//! Experience injection (paper Sec. III-D): teacher trajectories recorded to a file, rebuilt
//! in the student's own view of the environment, loaded into the replay as injected episodes,
//! and sampled with a share of each batch that is annealed to zero.
//!
//! A teacher episode is given by its environment, seed, action repeat and actions: the
//! walkers are deterministic and every episode is recorded and replayed in a fresh Box2D world
//! ([`EnvOptions::fresh_world`]), so a student replays the actions through its *own* env
//! options and gets its own observations (mask, previous-action input), its own training
//! reward (paper, stock, a fall penalty) and its own steps. Any teacher can therefore teach
//! any student of the same environment and action repeat: another algorithm, other networks,
//! another reward. Each replayed episode must reach its recorded stock return and length, or
//! the file is refused naming the episode and both values.
//!
//! Teacher episodes carry no recurrent state of the student's actor. A student that starts
//! its windows from stored acting-time states (`burn_in_from_stored_state`) gets them
//! recomputed at load by its own (initial) actor, run over each episode from a zero state at
//! its start: the same staleness as its own first episodes, which the burn-in scan refreshes.
//!
//! The file: an 8-byte magic, the format (u32), the payload's length (u64) and CRC-32 (u32),
//! all little-endian, then the payload (bincode). A truncated or altered file is refused
//! before anything is decoded; a file of format 1 (observations and rewards on the teacher's
//! own reward, no seeds) is refused naming its format.

use std::path::{Path, PathBuf};

use bincode::Options;
use rdpg_core::replay::Episode;
use rdpg_envs::EnvOptions;
use serde::{Deserialize, Serialize};

use crate::common::policy::{episode_seeds, PREALLOCATED_EPISODES};
use crate::common::{to_env_action, DeterministicPolicy, TrainConfig};
use crate::error::{AgentError, Result};

/// The first bytes of a teacher file.
const MAGIC: &[u8; 8] = b"rdpgTCH\n";
/// The teacher file format this build writes and reads.
pub const TEACHER_FORMAT: u32 = 2;
/// Bytes before the payload: magic, format, length, CRC-32.
const HEADER_LEN: usize = 8 + 4 + 8 + 4;
/// Largest teacher file read (2 GiB): far above any real one (a thousand Hardcore episodes
/// are ~10 MB), so that a damaged length cannot exhaust memory.
const MAX_FILE_BYTES: u64 = 2 << 30;

/// Injection settings of a training run (`off_policy.injection`).
///
/// A share `initial_share` of the windows of every batch is drawn from the teacher episodes
/// at the start; the share falls linearly to zero at `anneal_steps` agent steps (the unit of
/// `train.total_steps`: with an action repeat, each is several env frames). The
/// teacher episodes sit in their own pool of at most `max_fraction` of the replay's capacity
/// (oldest injected episodes are dropped beyond it) that the agent's own episodes never evict;
/// once the share reaches 0 no batch draws from it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InjectionConfig {
    /// Teacher files written by `rdpg record`.
    pub teachers: Vec<PathBuf>,
    /// Share of each batch's windows drawn from teacher episodes at step 0, in `[0, 1]`.
    pub initial_share: f64,
    /// Agent step at which the share reaches 0 (linear annealing).
    pub anneal_steps: u64,
    /// Largest fraction of the replay capacity teacher episodes may occupy, in `(0, 1]`.
    #[serde(default = "default_max_fraction")]
    pub max_fraction: f64,
}

fn default_max_fraction() -> f64 {
    rdpg_core::replay::DEFAULT_MAX_INJECTED_FRACTION
}

impl InjectionConfig {
    /// Share of teacher windows at agent step `step`:
    /// `initial_share * max(0, 1 - step / anneal_steps)`.
    pub fn share(&self, step: u64) -> f64 {
        if self.anneal_steps == 0 || step >= self.anneal_steps {
            return 0.0;
        }
        self.initial_share * (1.0 - step as f64 / self.anneal_steps as f64)
    }

    /// Checks the fields; errors name `off_policy.injection`.
    pub fn validate(&self) -> Result<()> {
        let bad = |reason: String| {
            Err(AgentError::Config {
                field: "off_policy.injection",
                reason,
            })
        };
        if self.teachers.is_empty() {
            return bad("lists no teacher file".into());
        }
        if !(0.0..=1.0).contains(&self.initial_share) {
            return bad(format!(
                "initial_share {} is not in [0, 1]",
                self.initial_share
            ));
        }
        if !(self.max_fraction > 0.0 && self.max_fraction <= 1.0) {
            return bad(format!(
                "max_fraction {} is not in (0, 1]",
                self.max_fraction
            ));
        }
        Ok(())
    }
}

/// Who the teacher was, as `rdpg record` found it: shown in a student's summary and tables.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TeacherInfo {
    /// The teacher's run directory or zoo entry, as given to `rdpg record`.
    pub run: String,
    /// Its experiment name (e.g. `hardcore-td3-paper`).
    pub name: String,
    /// Its algorithm.
    pub algo: String,
    /// Which of its agents: `best`, `latest`, `selected` or a step.
    pub checkpoint: String,
    /// The reward it trained on, in words (`paper, action repeat 3`).
    pub train_reward: String,
    /// Its own test on the stock reward, when the recorded agent has one.
    pub test: Option<TeacherTest>,
}

/// A teacher's own test (stock reward, its test seeds).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TeacherTest {
    /// Environment steps of the tested agent.
    pub step: u64,
    /// Test episodes.
    pub episodes: usize,
    /// Mean stock return.
    pub mean_stock_return: f64,
    /// Its standard deviation over episodes.
    pub std_stock_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
}

/// One recorded teacher episode: what it takes to replay it, and what the replay must give.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherEpisode {
    /// The seed of the episode's reset (in a fresh world).
    pub seed: u64,
    /// `[n, act_dim]` actions in `[-1, 1]`, each held for the file's action repeat.
    pub actions: Vec<f32>,
    /// Its return on the stock reward.
    pub stock_return: f64,
    /// The episode ended by termination.
    pub terminated: bool,
    /// The episode ended by the time limit (and not by termination).
    pub truncated: bool,
}

/// Recorded teacher trajectories (format [`TEACHER_FORMAT`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherFile {
    /// Environment id.
    pub env: String,
    /// Frames each action was held for.
    pub action_repeat: usize,
    /// Action size.
    pub act_dim: usize,
    /// Gaussian action noise added while recording (0: the deterministic policy).
    pub noise_sigma: f64,
    /// Who the teacher was.
    pub teacher: TeacherInfo,
    /// The episodes.
    pub episodes: Vec<TeacherEpisode>,
}

impl TeacherFile {
    /// Writes the file (header, then the bincode payload).
    pub fn save(&self, path: &Path) -> Result<()> {
        let err =
            |e: &dyn std::fmt::Display| AgentError::Checkpoint(format!("{}: {e}", path.display()));
        let payload = bincode::serialize(self).map_err(|e| err(&e))?;
        let mut bytes = Vec::with_capacity(HEADER_LEN + payload.len());
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&TEACHER_FORMAT.to_le_bytes());
        bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        bytes.extend_from_slice(&payload);
        std::fs::write(path, bytes).map_err(|e| err(&e))
    }

    /// Reads a file written by [`TeacherFile::save`]; a file that is truncated, altered, of
    /// another format or not a teacher file is refused, saying which.
    pub fn load(path: &Path) -> Result<Self> {
        let err =
            |m: String| AgentError::Checkpoint(format!("teacher file {}: {m}", path.display()));
        let len = std::fs::metadata(path)
            .map_err(|e| err(e.to_string()))?
            .len();
        if len > MAX_FILE_BYTES {
            return Err(err(format!(
                "{len} bytes is more than a teacher file can hold ({MAX_FILE_BYTES})"
            )));
        }
        let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
        if bytes.len() >= 8 + 15
            && bytes[..8] == 15u64.to_le_bytes()
            && &bytes[8..23] == b"rdpg-teacher-v1"
        {
            return Err(err(format!(
                "format 1 (observations and rewards on the teacher's own reward, no seeds) \
                 cannot be replayed through a student's environment; this build reads format \
                 {TEACHER_FORMAT}: record the teacher again with `rdpg record`"
            )));
        }
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(err("is not a teacher file (no teacher header)".into()));
        }
        if bytes.len() < HEADER_LEN {
            return Err(err("is truncated (incomplete header)".into()));
        }
        let word = |at: usize, n: usize| -> u64 {
            bytes[at..at + n]
                .iter()
                .rev()
                .fold(0u64, |v, &b| (v << 8) | u64::from(b))
        };
        let format = word(8, 4);
        if format != u64::from(TEACHER_FORMAT) {
            return Err(err(format!(
                "is of format {format}, this build reads format {TEACHER_FORMAT}"
            )));
        }
        let (want_len, want_crc) = (word(12, 8), word(20, 4) as u32);
        let payload = &bytes[HEADER_LEN..];
        if payload.len() as u64 != want_len {
            return Err(err(format!(
                "is truncated or extended: its header says {want_len} bytes of episodes, it \
                 holds {}",
                payload.len()
            )));
        }
        if crc32fast::hash(payload) != want_crc {
            return Err(err(
                "is corrupt: its CRC-32 does not match the header (altered after recording)".into(),
            ));
        }
        let t: TeacherFile = bincode::DefaultOptions::new()
            .with_fixint_encoding()
            .with_limit(want_len)
            .deserialize(payload)
            .map_err(|e| err(format!("is corrupt: {e}")))?;
        t.check().map_err(err)?;
        Ok(t)
    }

    /// Sizes and values a replay relies on.
    fn check(&self) -> std::result::Result<(), String> {
        if self.act_dim == 0 || self.action_repeat == 0 || self.episodes.is_empty() {
            return Err(format!(
                "holds act_dim {}, action_repeat {} and {} episodes (none may be 0)",
                self.act_dim,
                self.action_repeat,
                self.episodes.len()
            ));
        }
        for (i, e) in self.episodes.iter().enumerate() {
            if e.actions.is_empty() || e.actions.len() % self.act_dim != 0 {
                return Err(format!(
                    "episode {i} holds {} action values, not a positive multiple of act_dim {}",
                    e.actions.len(),
                    self.act_dim
                ));
            }
            if let Some(x) = e.actions.iter().find(|x| !(-1.0..=1.0).contains(*x)) {
                return Err(format!(
                    "episode {i} holds the action value {x}, not in [-1, 1]"
                ));
            }
            if !e.stock_return.is_finite() || e.terminated && e.truncated {
                return Err(format!(
                    "episode {i} records return {} with terminated {} and truncated {}",
                    e.stock_return, e.terminated, e.truncated
                ));
            }
        }
        Ok(())
    }

    /// The file's episodes as the student of `cfg` sees them: each replayed in a fresh world
    /// through the student's own env options (observations, training reward, steps), checked
    /// against its recorded stock return and length. Refuses another environment or another
    /// action repeat, naming both sides.
    pub fn episodes_for(&self, cfg: &TrainConfig, path: &Path) -> Result<Vec<Episode>> {
        let refuse = |reason: String| AgentError::Config {
            field: "off_policy.injection",
            reason: format!("teacher {}: {reason}", path.display()),
        };
        if self.env != cfg.env {
            return Err(refuse(format!(
                "recorded on {}, the run trains on {}",
                self.env, cfg.env
            )));
        }
        if self.action_repeat != cfg.action_repeat {
            return Err(refuse(format!(
                "recorded with action repeat {}, the run uses {}: each action is held for its \
                 teacher's number of frames and cannot be replayed at another",
                self.action_repeat, cfg.action_repeat
            )));
        }
        let mut env = rdpg_envs::make_with(&cfg.env, &replay_options(cfg))?;
        let space = env.action_space().clone();
        if space.dim() != self.act_dim {
            return Err(refuse(format!(
                "records {} action values per step, the environment takes {}",
                self.act_dim,
                space.dim()
            )));
        }
        let mut out = Vec::with_capacity(self.episodes.len());
        for (i, te) in self.episodes.iter().enumerate() {
            let (obs, _) = env.reset(Some(te.seed))?;
            let mut ep = Episode {
                obs,
                actions: Vec::with_capacity(te.actions.len()),
                rewards: Vec::new(),
                states: Vec::new(),
                terminated: false,
                truncated: false,
                injected: true,
            };
            let mut stock = 0.0;
            for a in te.actions.chunks(self.act_dim) {
                let s = env.step(&to_env_action(a, &space.low, &space.high))?;
                stock += s.info.stock_reward.unwrap_or(s.reward);
                ep.actions.extend_from_slice(a);
                ep.rewards.push(s.reward as f32);
                ep.obs.extend_from_slice(&s.obs);
                if s.done() {
                    ep.terminated = s.terminated;
                    ep.truncated = s.truncated && !s.terminated;
                    break;
                }
            }
            let steps = te.actions.len() / self.act_dim;
            let same = ep.len() == steps
                && (ep.terminated, ep.truncated) == (te.terminated, te.truncated)
                && (stock - te.stock_return).abs() <= 1e-6 * te.stock_return.abs().max(1.0);
            if !same {
                let end = |t: bool, u: bool| match (t, u) {
                    (true, _) => "terminated",
                    (_, true) => "truncated",
                    _ => "not over",
                };
                return Err(refuse(format!(
                    "episode {i} (seed {}) replays to {} steps, stock return {stock:.6}, {}; \
                     the file records {steps} steps, {:.6}, {} (recorded by another version \
                     of the environment, or changed)",
                    te.seed,
                    ep.len(),
                    end(ep.terminated, ep.truncated),
                    te.stock_return,
                    end(te.terminated, te.truncated),
                )));
            }
            out.push(ep);
        }
        Ok(out)
    }
}

/// The env options a teacher episode is recorded and replayed with: the run's own, in a fresh
/// world at every reset (an episode is then a function of its seed and actions alone).
fn replay_options(cfg: &TrainConfig) -> EnvOptions {
    EnvOptions {
        fresh_world: true,
        ..cfg.env_options()
    }
}

/// Runs `policy` (plus Gaussian action noise of `noise_sigma`, 0 for none) for `episodes`
/// episodes of `cfg`'s environment and options (the teacher's own view), seeds `seed, seed +
/// 1, ...`, each in a fresh world, and returns them as a teacher file.
pub fn record(
    policy: &mut dyn DeterministicPolicy,
    cfg: &TrainConfig,
    episodes: usize,
    seed: u64,
    noise_sigma: f64,
    teacher: TeacherInfo,
) -> Result<TeacherFile> {
    let mut env = rdpg_envs::make_with(&cfg.env, &replay_options(cfg))?;
    let space = env.action_space().clone();
    let mut rng = rdpg_core::rng::NpRng::from_seed(seed ^ 0x7EAC_4E25);
    let mut out = Vec::with_capacity(episodes.min(PREALLOCATED_EPISODES));
    for ep_seed in episode_seeds(seed, episodes)? {
        let (mut obs, _) = env.reset(Some(ep_seed))?;
        policy.begin_episode();
        let mut ep = TeacherEpisode {
            seed: ep_seed,
            actions: Vec::new(),
            stock_return: 0.0,
            terminated: false,
            truncated: false,
        };
        loop {
            let mut a = policy.act(&obs)?;
            if noise_sigma > 0.0 {
                for x in &mut a {
                    *x = (*x + (noise_sigma * rng.standard_normal()) as f32).clamp(-1.0, 1.0);
                }
            }
            let s = env.step(&to_env_action(&a, &space.low, &space.high))?;
            ep.actions.extend_from_slice(&a);
            ep.stock_return += s.info.stock_reward.unwrap_or(s.reward);
            if s.done() {
                ep.terminated = s.terminated;
                ep.truncated = s.truncated && !s.terminated;
                break;
            }
            obs = s.obs;
        }
        out.push(ep);
    }
    Ok(TeacherFile {
        env: cfg.env.clone(),
        action_repeat: cfg.action_repeat,
        act_dim: space.dim(),
        noise_sigma,
        teacher: TeacherInfo {
            train_reward: cfg.reward_label(),
            ..teacher
        },
        episodes: out,
    })
}

impl TeacherEpisode {
    /// Number of agent steps.
    pub fn steps(&self, act_dim: usize) -> usize {
        self.actions.len() / act_dim.max(1)
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn share_anneals_linearly_to_zero() {
        let c = InjectionConfig {
            teachers: vec!["t".into()],
            initial_share: 0.5,
            anneal_steps: 1000,
            max_fraction: 0.3,
        };
        assert_eq!(c.share(0), 0.5);
        assert_eq!(c.share(500), 0.25);
        assert!((c.share(900) - 0.05).abs() < 1e-12);
        assert_eq!(c.share(1000), 0.0);
        assert_eq!(c.share(5000), 0.0);
        assert!(c.validate().is_ok());
        for bad in [
            InjectionConfig {
                initial_share: 1.5,
                ..c.clone()
            },
            InjectionConfig {
                max_fraction: 0.0,
                ..c.clone()
            },
            InjectionConfig {
                teachers: vec![],
                ..c.clone()
            },
        ] {
            assert!(matches!(
                bad.validate(),
                Err(AgentError::Config {
                    field: "off_policy.injection",
                    ..
                })
            ));
        }
    }
}
