//! `rdpg eval` and `rdpg record`: a run directory's agents ([`crate::rundir`]) on the test seeds
//! or any others, and as a teacher's trajectories for experience injection.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::{evaluate_policy, evaluate_policy_traced, EpisodeTrace, TrainConfig};
use rdpg_agents::rdpg::inject::{TeacherInfo, TeacherTest};
use serde::Serialize;

use crate::rundir::{eval_metric, RunDir, Which};

/// Arguments of `rdpg eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run directory written by `rdpg train`.
    #[arg(long)]
    run: PathBuf,
    /// Evaluation episodes (default: the run's `train.test_episodes`).
    #[arg(long)]
    episodes: Option<usize>,
    /// Which agent of the run: best, latest, selected (by `rdpg select`) or the step of a kept
    /// agent.
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    /// First seed (default: the run's test seeds, `train.test_seed`, which model selection
    /// never saw).
    #[arg(long)]
    seed: Option<u64>,
    /// Also write every episode's actions to FILE, one JSON line per episode:
    /// `{"seed": N, "return": R, "actions": [[a0, a1, ...], ...]}`. Replaying the lines in
    /// order in one Gymnasium env (`reset(seed=N)`, the actions as float32) gives the same
    /// episodes and returns (scripts/reference/replay_actions.py).
    #[arg(long, value_name = "FILE")]
    actions_out: Option<PathBuf>,
    /// A memory probe for recurrent agents: act remembering at most the last K observations,
    /// the current one included (the recurrent state re-encoded from zero over them at every
    /// step, as a window-of-K agent acts; 1: no memory). The returns show how far back the
    /// agent's memory matters; they are not its test score.
    #[arg(long, value_name = "K")]
    memory: Option<usize>,
}

/// Arguments of `rdpg record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// The teacher: a run directory written by `rdpg train`.
    #[arg(long)]
    run: PathBuf,
    /// Which agent of the run: best, latest, selected (by `rdpg select`) or the step of a kept
    /// agent.
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    /// Episodes to record.
    #[arg(long, default_value_t = 20)]
    episodes: usize,
    /// Output file (bincode), listed in a student's `off_policy.injection.teachers`.
    #[arg(long)]
    out: PathBuf,
    /// First seed of the recorded episodes.
    #[arg(long, default_value_t = 2_000_000)]
    seed: u64,
    /// Gaussian action noise while recording (0: the deterministic policy).
    #[arg(long, default_value_t = 0.0)]
    noise: f64,
}

/// `rdpg record`: a teacher's trajectories for experience injection.
pub fn record(a: &RecordArgs) -> Result<()> {
    if a.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    if !(a.noise.is_finite() && a.noise >= 0.0) {
        bail!("--noise must be a non-negative number");
    }
    let run = RunDir::new(&a.run);
    let (exp, mut policy) = run.policy(a.checkpoint)?;
    // The teacher's own test: its summary's, which tests the best (a zoo entry's: the one it
    // ships); other agents of a run have none.
    let test = match a.checkpoint {
        Which::Best if run.is_zoo_entry() => crate::rundir::read_as_run(&run)?.0.test_eval,
        Which::Best => run.read_summary().ok().and_then(|s| s.test_eval),
        _ => None,
    }
    .map(|t| TeacherTest {
        step: t.step,
        episodes: t.episodes,
        mean_stock_return: t.mean_stock_return,
        std_stock_return: t.std_stock_return,
        success_rate: t.success_rate,
    });
    let info = TeacherInfo {
        run: a.run.display().to_string(),
        name: exp.name.clone(),
        algo: exp.algo.as_str().into(),
        checkpoint: a.checkpoint.to_string(),
        train_reward: String::new(), // `record` names the run's own
        test,
    };
    let t = rdpg_agents::rdpg::inject::record(
        policy.as_mut(),
        &exp.train,
        a.episodes,
        a.seed,
        a.noise,
        info,
    )?;
    t.save(&a.out)?;
    let steps: usize = t.episodes.iter().map(|e| e.steps(t.act_dim)).sum();
    let mean: f64 =
        t.episodes.iter().map(|e| e.stock_return).sum::<f64>() / t.episodes.len() as f64;
    println!(
        "{}",
        serde_json::json!({
            "out": a.out.display().to_string(),
            "env": t.env,
            "action_repeat": t.action_repeat,
            "teacher_train_reward": t.teacher.train_reward,
            "episodes": t.episodes.len(),
            "steps": steps,
            "mean_stock_return": mean,
        })
    );
    Ok(())
}

/// The `--actions-out` file of `rdpg eval`: one JSON line per episode, written to
/// `FILE.partial` and renamed to `FILE` once the evaluation has finished (a failed one leaves
/// any earlier `FILE` as it was). A run with an action repeat `k > 1` lists the agent's actions and says
/// `"action_repeat": k` (each held for `k` frames, the last one until the episode ends).
struct ActionsWriter {
    path: PathBuf,
    partial: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    action_repeat: usize,
}

impl ActionsWriter {
    fn create(path: &Path, action_repeat: usize) -> Result<Self> {
        let mut partial = path.as_os_str().to_owned();
        partial.push(".partial");
        let partial = PathBuf::from(partial);
        let f = std::fs::File::create(&partial)
            .with_context(|| format!("cannot create --actions-out file {}", partial.display()))?;
        Ok(Self {
            path: path.to_owned(),
            partial,
            out: std::io::BufWriter::new(f),
            action_repeat,
        })
    }

    fn episode(&mut self, e: &EpisodeTrace<'_>) -> rdpg_agents::Result<()> {
        #[derive(Serialize)]
        struct Episode<'a> {
            seed: u64,
            #[serde(rename = "return")]
            ret: f64,
            actions: &'a [Vec<f32>],
            #[serde(skip_serializing_if = "Option::is_none")]
            action_repeat: Option<usize>,
        }
        let line = Episode {
            seed: e.seed,
            ret: e.ret,
            actions: e.actions,
            action_repeat: (self.action_repeat > 1).then_some(self.action_repeat),
        };
        serde_json::to_writer(&mut self.out, &line)?;
        self.out.write_all(b"\n")?;
        Ok(())
    }

    fn finish(self) -> Result<()> {
        let f = self
            .out
            .into_inner()
            .map_err(|e| e.into_error())
            .and_then(|f| f.sync_all().map(|_| f));
        f.with_context(|| format!("cannot write --actions-out file {}", self.partial.display()))?;
        std::fs::rename(&self.partial, &self.path).with_context(|| {
            format!(
                "cannot rename {} to {}",
                self.partial.display(),
                self.path.display()
            )
        })
    }
}

/// `--episodes`, or else the run's `train.test_episodes`; a run that declared no test (0)
/// needs `--episodes`.
pub(crate) fn test_episodes(episodes: Option<usize>, t: &TrainConfig) -> Result<usize> {
    match episodes.unwrap_or(t.test_episodes) {
        0 => bail!(
            "the run has no test episodes (train.test_episodes = 0: a tuning run whose test \
             seeds stay unopened); give --episodes"
        ),
        n => Ok(n),
    }
}

/// `rdpg eval`.
pub fn eval(a: &EvalArgs) -> Result<()> {
    if a.episodes == Some(0) {
        bail!("--episodes must be at least 1");
    }
    let (exp, mut policy) = RunDir::new(&a.run).policy(a.checkpoint)?;
    if let Some(k) = a.memory {
        policy
            .limit_memory(k)
            .with_context(|| format!("--memory {k} on {}", a.run.display()))?;
    }
    let seed = a.seed.unwrap_or(exp.train.test_seed);
    let episodes = test_episodes(a.episodes, &exp.train)?;
    let r = match &a.actions_out {
        None => evaluate_policy(policy.as_mut(), &exp.train, episodes, seed)?,
        Some(path) => {
            let mut out = ActionsWriter::create(path, exp.train.action_repeat)?;
            let r = evaluate_policy_traced(policy.as_mut(), &exp.train, episodes, seed, &mut |e| {
                out.episode(e)
            });
            let r = match r {
                Ok(r) => r,
                Err(e) => {
                    let _ = std::fs::remove_file(&out.partial);
                    return Err(e).with_context(|| {
                        format!("evaluating with --actions-out {}", path.display())
                    });
                }
            };
            out.finish()?;
            r
        }
    };
    #[derive(Serialize)]
    struct Line<'a> {
        run: String,
        checkpoint: String,
        /// `--memory`: the observations the agent remembered at most.
        #[serde(skip_serializing_if = "Option::is_none")]
        memory: Option<usize>,
        env: &'a str,
        episodes: usize,
        first_seed: u64,
        metric: String,
        mean_stock_return: f64,
        std_stock_return: f64,
        success_rate: f64,
        time_limit_rate: f64,
        returns: &'a [f64],
        lengths: &'a [usize],
        /// Walkers: per obstacle kind, obstacles passed and episodes that fell or got stuck
        /// at one (`none`: away from any obstacle).
        #[serde(skip_serializing_if = "BTreeMap::is_empty")]
        obstacles: &'a BTreeMap<String, rdpg_agents::common::ObstacleRecord>,
    }
    let line = Line {
        run: a.run.display().to_string(),
        checkpoint: a.checkpoint.to_string(),
        memory: a.memory,
        env: &exp.train.env,
        episodes,
        first_seed: seed,
        metric: eval_metric(&exp.train),
        mean_stock_return: r.mean_return,
        std_stock_return: r.std_return,
        success_rate: r.success_rate,
        time_limit_rate: r.time_limit_rate,
        returns: &r.returns,
        lengths: &r.lengths,
        obstacles: &r.obstacles,
    };
    println!("{}", serde_json::to_string(&line)?);
    Ok(())
}
