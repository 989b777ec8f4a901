//! What a run directory's files hold: metric rows, update statistics, the summary, teachers
//! and tests.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Result;
use rdpg_agents::common::ObstacleRecord;
use rdpg_agents::rdpg::inject::{TeacherFile, TeacherInfo};
use rdpg_agents::{EvalRecord, UpdateStats};
use serde::{Deserialize, Serialize};

/// One line of `metrics.jsonl`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Metric {
    /// A finished training episode (with exploration noise).
    Episode {
        /// Environment steps of the run when it ended.
        step: u64,
        /// Return on the training reward.
        #[serde(rename = "return")]
        ret: f64,
        /// Return on the stock reward.
        stock_return: f64,
        /// Length in steps.
        len: usize,
        /// Reached the end of the course.
        success: bool,
        /// Moving average of the last 100 training returns (`None` before 100 episodes).
        r100: Option<f64>,
        /// Wall-clock seconds since the run started (resumes included).
        wall: f64,
        /// The updates made since the previous episode row.
        #[serde(default)]
        learner: UpdateMeans,
    },
    /// A deterministic evaluation on held-out seeds, on the stock reward.
    Eval {
        /// Environment steps of the run.
        step: u64,
        /// Mean stock return.
        mean_return: f64,
        /// Standard deviation of the stock return.
        std_return: f64,
        /// Share of episodes that reached the end of the course.
        success_rate: f64,
        /// Wall-clock seconds since the run started.
        wall: f64,
    },
}

impl Metric {
    /// Environment steps of the row.
    pub fn step(&self) -> u64 {
        match self {
            Metric::Episode { step, .. } | Metric::Eval { step, .. } => *step,
        }
    }

    /// Wall-clock seconds of the run at the row.
    pub fn wall(&self) -> f64 {
        match self {
            Metric::Episode { wall, .. } | Metric::Eval { wall, .. } => *wall,
        }
    }
}

/// The learner's updates between two metric rows: how many, and their mean statistics
/// (`None` when there were none).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateMeans {
    /// Updates made.
    pub updates: u64,
    /// Mean critic (value) loss.
    pub critic_loss: Option<f64>,
    /// Mean actor (policy) loss over the updates that trained the actor.
    pub actor_loss: Option<f64>,
    /// Mean value estimate.
    pub q_mean: Option<f64>,
    /// Mean share of each batch drawn from injected (teacher) episodes.
    pub injected_share: Option<f64>,
    /// Mean wall-clock milliseconds per update (speed; differs between identical runs).
    #[serde(default)]
    pub update_ms: Option<f64>,
    /// The mean of each learner-specific statistic ([`UpdateStats::extra`]) over the updates
    /// that reported it, by name, beside the fields above (FORK: `model_loss`, `fork_share`).
    #[serde(flatten)]
    pub extra: BTreeMap<String, f64>,
}

/// Sums of update statistics, turned into [`UpdateMeans`] at each metric row. The sums
/// pending at a checkpoint are saved with it, so that a resumed run logs the same rows.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(from = "UpdateSumsFile")]
pub struct UpdateSums {
    n: u64,
    n_actor: u64,
    critic: f64,
    actor: f64,
    q: f64,
    injected: f64,
    seconds: f64,
    /// Per learner-specific statistic: the updates that reported it and their sum.
    extra: BTreeMap<String, (u64, f64)>,
}

/// [`UpdateSums`] as a checkpoint's `pending_updates.json` holds it, including the FORK
/// fields of files written before `extra` (read into it).
#[derive(Deserialize)]
struct UpdateSumsFile {
    n: u64,
    n_actor: u64,
    critic: f64,
    actor: f64,
    q: f64,
    injected: f64,
    #[serde(default)]
    seconds: f64,
    #[serde(default)]
    extra: BTreeMap<String, (u64, f64)>,
    #[serde(default)]
    n_model: u64,
    #[serde(default)]
    model: f64,
    #[serde(default)]
    n_fork_turn: u64,
    #[serde(default)]
    fork_used: u64,
}

impl From<UpdateSumsFile> for UpdateSums {
    fn from(f: UpdateSumsFile) -> Self {
        let mut extra = f.extra;
        if f.n_model > 0 {
            extra.insert("model_loss".into(), (f.n_model, f.model));
        }
        if f.n_fork_turn > 0 {
            extra.insert("fork_share".into(), (f.n_fork_turn, f.fork_used as f64));
        }
        Self {
            n: f.n,
            n_actor: f.n_actor,
            critic: f.critic,
            actor: f.actor,
            q: f.q,
            injected: f.injected,
            seconds: f.seconds,
            extra,
        }
    }
}

impl UpdateSums {
    /// Adds one update.
    pub fn add(&mut self, s: &UpdateStats) {
        self.n += 1;
        self.critic += s.critic_loss;
        self.q += s.q_mean;
        self.injected += s.injected_share;
        self.seconds += s.seconds;
        if let Some(a) = s.actor_loss {
            self.n_actor += 1;
            self.actor += a;
        }
        for (name, &x) in &s.extra {
            let (n, sum) = self.extra.entry(name.clone()).or_default();
            *n += 1;
            *sum += x;
        }
    }

    /// The means so far, and a fresh start.
    pub fn take(&mut self) -> UpdateMeans {
        let s = std::mem::take(self);
        let mean = |x: f64, n: u64| (n > 0).then(|| x / n as f64);
        UpdateMeans {
            updates: s.n,
            critic_loss: mean(s.critic, s.n),
            actor_loss: mean(s.actor, s.n_actor),
            q_mean: mean(s.q, s.n),
            injected_share: mean(s.injected, s.n),
            update_ms: mean(1000.0 * s.seconds, s.n),
            extra: s
                .extra
                .iter()
                .filter_map(|(name, &(n, sum))| Some((name.clone(), mean(sum, n)?)))
                .collect(),
        }
    }
}

/// The headline numbers of a run (`summary.json`), each named by reward and metric.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Summary {
    /// Experiment name.
    pub name: String,
    /// Algorithm.
    pub algo: String,
    /// Environment id.
    pub env: String,
    /// The reward the agent learned from, with every change that shows in a return
    /// (`stock`, `paper`, `stock, fall -10, action repeat 3`).
    pub train_reward: String,
    /// The reward of the evaluations: `stock`, with the run's action repeat if any.
    #[serde(default = "stock")]
    pub eval_reward: String,
    /// Environment steps done.
    pub steps: u64,
    /// Training episodes finished.
    pub episodes: u64,
    /// Wall-clock seconds of training.
    pub wall_seconds: f64,
    /// The paper's R_100MA: best 100-episode moving average of training returns on the
    /// training reward (with exploration noise); `None` before 100 episodes.
    pub best_r100_train_reward: Option<f64>,
    /// The same on the stock reward.
    pub best_r100_stock_reward: Option<f64>,
    /// Last deterministic evaluation (stock reward).
    pub last_eval: Option<EvalSummary>,
    /// Best deterministic evaluation on the validation seeds (stock reward); its agent is
    /// `checkpoints/best`.
    pub best_eval: Option<EvalSummary>,
    /// The final test of `checkpoints/best` on the test seeds (disjoint from the validation
    /// seeds that chose it), written when the run reaches its budget.
    #[serde(default)]
    pub test_eval: Option<TestSummary>,
    /// The teachers of experience injection (none without injection).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub teachers: Vec<TeacherSummary>,
    /// The machine that wrote this summary (the last session of the run), see
    /// [`machine_description`](super::machine_description).
    #[serde(default)]
    pub machine: Option<String>,
}

/// The default of [`Summary::eval_reward`] (summaries written before it existed).
fn stock() -> String {
    "stock".into()
}

/// A teacher of a run with experience injection, as its [`Summary`] and every table that
/// shows it name it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TeacherSummary {
    /// The teacher file, as the run's config lists it.
    pub file: String,
    /// Who recorded it: run, experiment, algorithm, agent, training reward, its own test.
    #[serde(flatten)]
    pub teacher: TeacherInfo,
    /// Episodes in the file.
    pub episodes: usize,
    /// Their mean stock return.
    pub mean_stock_return: f64,
    /// Gaussian action noise while recording.
    pub noise_sigma: f64,
}

impl TeacherSummary {
    /// Reads the teacher file `path` (checked as a student's load checks it).
    pub fn read(path: &Path) -> Result<Self> {
        let t = TeacherFile::load(path)?;
        Ok(Self {
            file: path.display().to_string(),
            episodes: t.episodes.len(),
            mean_stock_return: t.episodes.iter().map(|e| e.stock_return).sum::<f64>()
                / t.episodes.len() as f64,
            noise_sigma: t.noise_sigma,
            teacher: t.teacher,
        })
    }

    /// In words: `hardcore-td3-paper (ddpg, best at 1975000 steps; test 245.5 ± 52.3 stock, 100
    /// ep.)`.
    pub fn label(&self) -> String {
        let t = &self.teacher;
        // The teacher's budget (the steps of its tested agent) and its own test.
        let (at, test) = t.test.map_or((String::new(), "no test".into()), |x| {
            (
                format!(" at {} steps", x.step),
                format!(
                    "test {:.1} ± {:.1} stock, {} ep.",
                    x.mean_stock_return, x.std_stock_return, x.episodes
                ),
            )
        });
        format!("{} ({}, {}{at}; {test})", t.name, t.algo, t.checkpoint)
    }
}

/// The test evaluation in [`Summary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TestSummary {
    /// Environment steps of the tested agent (the best validation evaluation's).
    pub step: u64,
    /// Test episodes.
    pub episodes: usize,
    /// First test seed (episode k uses `first_seed + k`).
    pub first_seed: u64,
    /// Mean stock return.
    pub mean_stock_return: f64,
    /// Its standard deviation over episodes.
    pub std_stock_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
    /// Every episode's stock return, in seed order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub returns: Vec<f64>,
    /// Whether each episode reached the end of the course, in seed order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub successes: Vec<bool>,
    /// Share of episodes cut by the time limit (neither finished nor fell); absent in tests
    /// recorded before it was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit_rate: Option<f64>,
    /// Walkers: how the test episodes fared at each kind of obstacle (and `none`: episodes
    /// that ended away from any; as `rdpg eval` counts them); absent in tests recorded before
    /// it was.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub obstacles: BTreeMap<String, ObstacleRecord>,
}

/// An evaluation in [`Summary`].
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct EvalSummary {
    /// Environment steps at the evaluation.
    pub step: u64,
    /// Mean stock return.
    pub mean_stock_return: f64,
    /// Its standard deviation over episodes.
    pub std_stock_return: f64,
    /// Share of episodes that reached the end of the course.
    pub success_rate: f64,
}

impl From<&EvalRecord> for EvalSummary {
    fn from(r: &EvalRecord) -> Self {
        Self {
            step: r.step,
            mean_stock_return: r.mean_return,
            std_stock_return: r.std_return,
            success_rate: r.success_rate,
        }
    }
}

/// The header of `episodes.csv` (a view of the episode rows of `metrics.jsonl`).
pub const EPISODES_HEADER: &str = "step,return,stock_return,len,success,r100,updates,critic_loss,\
                               actor_loss,q_mean,injected_share,update_ms,wall\n";
/// The header of `evals.csv` (a view of the evaluation rows).
pub const EVALS_HEADER: &str = "step,mean_return,std_return,success_rate,wall\n";
