//! A zoo entry's own summary (`rdpg zoo` writes it) and the entry read in a run's terms, so
//! that plots, comparisons and records read a zoo entry as they read a run.

use std::collections::BTreeMap;

use anyhow::{bail, Result};
use rdpg_agents::common::ObstacleRecord;
use rdpg_agents::EvalRecord;
use serde::{Deserialize, Serialize};

use super::{read_json, EvalSummary, Metric, RunDir, Summary, TeacherSummary, TestSummary};

/// `summary.json` of a zoo entry.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooSummary {
    /// The experiment's name.
    pub name: String,
    /// Algorithm.
    pub algo: String,
    /// Environment id.
    pub env: String,
    /// The reward the agent was trained on, with every option that changes the reward or the
    /// time scale.
    pub training_reward: String,
    /// The reward of every evaluation here: always `stock`.
    pub evaluation_reward: String,
    /// Deterministic test evaluation of the shipped agent.
    pub test: ZooTest,
    /// When the shipped agent was taken.
    pub agent: ZooAgent,
    /// The whole training run.
    pub training: ZooTraining,
    /// The machine of the training run's last session.
    pub machine: String,
    /// The command that reproduces the run.
    pub reproduce: String,
    /// Sizes in bytes of the entry's files.
    pub files: Vec<(String, u64)>,
    /// The teachers of experience injection (none without injection).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub teachers: Vec<TeacherSummary>,
}

/// The test evaluation in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooTest {
    /// Episodes.
    pub episodes: usize,
    /// First seed (episode k uses `first_seed + k`); the run's test seeds.
    pub first_seed: u64,
    /// Mean stock return.
    pub mean_return: f64,
    /// Standard deviation over episodes.
    pub std_return: f64,
    /// Share of episodes that reached the end of the course without falling.
    pub success_rate: f64,
    /// Every episode's stock return.
    pub returns: Vec<f64>,
    /// Share of episodes cut by the time limit (neither finished nor fell); absent in entries
    /// tested before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_limit_rate: Option<f64>,
    /// Walkers: how the test episodes fared at each kind of obstacle (and `none`: episodes
    /// that ended away from any); absent in entries tested before it was recorded.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub obstacles: BTreeMap<String, ObstacleRecord>,
}

impl ZooTest {
    /// The test of `episodes` episodes from `first_seed`, as `evaluate_policy` gave it.
    pub fn from_eval(test: &EvalRecord, episodes: usize, first_seed: u64) -> Self {
        Self {
            episodes,
            first_seed,
            mean_return: test.mean_return,
            std_return: test.std_return,
            success_rate: test.success_rate,
            returns: test.returns.clone(),
            time_limit_rate: Some(test.time_limit_rate),
            obstacles: test.obstacles.clone(),
        }
    }
}

/// The shipped agent in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooAgent {
    /// Environment steps of training when it was evaluated and kept.
    pub steps: u64,
    /// Learner updates it had received.
    pub updates: u64,
    /// Wall-clock seconds of training until then.
    pub wall_seconds: Option<f64>,
    /// Its validation evaluation (the one that chose it): mean stock return.
    pub validation_mean_return: f64,
    /// Its standard deviation over the validation episodes (entries before 2026-12-03: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_std_return: Option<f64>,
    /// Its success share on the validation episodes (entries before 2026-12-03: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_success_rate: Option<f64>,
    /// Validation episodes: the periodic evaluation's (`best`), or `rdpg select`'s
    /// (`selected`).
    pub validation_episodes: usize,
}

/// The training run in [`ZooSummary`].
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZooTraining {
    /// Environment steps of the whole run.
    pub steps: u64,
    /// Training episodes.
    pub episodes: u64,
    /// Wall-clock seconds.
    pub wall_seconds: f64,
    /// The run's seed.
    pub seed: u64,
    /// The paper's R_100MA on the training reward (with exploration noise).
    pub best_r100_train_reward: Option<f64>,
}

/// A zoo entry in a run's terms, for `rdpg plot` and `rdpg compare`: its summary as a run's
/// [`Summary`] (the validation evaluation that chose the agent as `best_eval`, its test as
/// `test_eval`) and its evaluations. An entry ships no training episodes, so it has no
/// training-return curve.
pub fn read_as_run(entry: &RunDir) -> Result<(Summary, Vec<Metric>)> {
    let path = entry.summary();
    let zs: ZooSummary = read_json(&path)?;
    let evals = entry.read_evals_csv()?;
    let eval_summary = |m: &Metric| match *m {
        Metric::Eval {
            step,
            mean_return,
            std_return,
            success_rate,
            ..
        } => Some(EvalSummary {
            step,
            mean_stock_return: mean_return,
            std_stock_return: std_return,
            success_rate,
        }),
        Metric::Episode { .. } => None,
    };
    // The evaluation that chose the agent: `rdpg select`'s when the entry records it,
    // otherwise the periodic one at its step.
    let selected = match (
        zs.agent.validation_std_return,
        zs.agent.validation_success_rate,
    ) {
        (Some(std), Some(success)) => Some(EvalSummary {
            step: zs.agent.steps,
            mean_stock_return: zs.agent.validation_mean_return,
            std_stock_return: std,
            success_rate: success,
        }),
        _ => None,
    };
    let best_eval = selected.or_else(|| {
        evals
            .iter()
            .filter(|m| m.step() == zs.agent.steps)
            .find_map(eval_summary)
    });
    if best_eval.is_none() {
        bail!(
            "{}: no evaluation at the shipped agent's step {} in evals.csv",
            entry.root().display(),
            zs.agent.steps
        );
    }
    let summary = Summary {
        name: zs.name,
        algo: zs.algo,
        env: zs.env,
        train_reward: zs.training_reward,
        eval_reward: zs.evaluation_reward,
        steps: zs.training.steps,
        episodes: zs.training.episodes,
        wall_seconds: zs.training.wall_seconds,
        best_r100_train_reward: zs.training.best_r100_train_reward,
        best_r100_stock_reward: None,
        last_eval: evals.last().and_then(eval_summary),
        best_eval,
        test_eval: Some(TestSummary {
            step: zs.agent.steps,
            episodes: zs.test.episodes,
            first_seed: zs.test.first_seed,
            mean_stock_return: zs.test.mean_return,
            std_stock_return: zs.test.std_return,
            success_rate: zs.test.success_rate,
            returns: zs.test.returns,
            successes: Vec::new(),
            time_limit_rate: zs.test.time_limit_rate,
            obstacles: zs.test.obstacles,
        }),
        teachers: zs.teachers,
        machine: Some(zs.machine),
    };
    Ok((summary, evals))
}
