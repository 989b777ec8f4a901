//! The run directory: the one place that knows its layout, its metric rows, its summary and
//! the moving average of training returns.
//!
//! A run directory holds:
//! - `config.toml`: the resolved experiment (every default written out);
//! - `metrics.jsonl`: one object per finished training episode (`"kind":"episode"`) and per
//!   evaluation (`"kind":"eval"`), with the same rows in `episodes.csv` and `evals.csv`;
//! - `checkpoints/latest/`: the full training state (networks, optimiser, replay, RNGs,
//!   environments), which `--resume` continues from; `checkpoints/best/`: the agent of the best
//!   evaluation (`agent/`) and that evaluation (`eval.json`);
//! - `summary.json`: the run's headline numbers, each named by its reward and metric;
//! - `tb/`: the same metrics as TensorBoard scalars (`tensorboard --logdir runs/`).
//!
//! A zoo entry (`rdpg zoo`, see [`crate::zoo`]) is read through the same type: it holds
//! `config.toml` and one agent, `agent/`, which stands for the run's `best` agent.

use std::collections::VecDeque;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rdpg_agents::rdpg::inject::{TeacherFile, TeacherInfo};
use rdpg_agents::{DeterministicPolicy, EvalRecord, UpdateStats};
use serde::{Deserialize, Serialize};
use syntaxdot_summary::SummaryWriter;

use crate::experiment::Experiment;

/// The git commit this binary was built from (`+dirty` when tracked files differed from it,
/// `unknown` when built outside a git checkout).
pub const GIT_COMMIT: &str = env!("RDPG_GIT_COMMIT");

/// Which agent of a run: `best`, `latest`, `selected` or the step of a kept agent (on the
/// command line `--checkpoint best|latest|selected|STEP`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Which {
    /// `checkpoints/best`: the agent of the best periodic evaluation.
    Best,
    /// `checkpoints/latest`: the agent of the last checkpoint.
    Latest,
    /// `checkpoints/selected`: the agent `rdpg select` chose among the kept ones on more
    /// validation episodes.
    Selected,
    /// `checkpoints/agents/<step>`: an agent kept by `run.keep_agents_every`.
    Kept(u64),
}

impl std::fmt::Display for Which {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Which::Best => f.write_str("best"),
            Which::Latest => f.write_str("latest"),
            Which::Selected => f.write_str("selected"),
            Which::Kept(step) => write!(f, "{step}"),
        }
    }
}

impl std::str::FromStr for Which {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "best" => Ok(Which::Best),
            "latest" => Ok(Which::Latest),
            "selected" => Ok(Which::Selected),
            _ => s.parse().map(Which::Kept).map_err(|_| {
                format!(
                    "`{s}` is not an agent of a run: best, latest, selected or the step of a \
                     kept agent (run.keep_agents_every)"
                )
            }),
        }
    }
}

/// The paths of a run directory.
#[derive(Debug, Clone)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// The run directory at `root` (nothing is read or created).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The directory itself.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `config.toml`: the resolved experiment.
    pub fn config(&self) -> PathBuf {
        self.root.join("config.toml")
    }

    /// `summary.json`.
    pub fn summary(&self) -> PathBuf {
        self.root.join("summary.json")
    }

    /// `teachers.json`: the teachers of a run with experience injection
    /// ([`TeacherSummary`]), written when it starts.
    pub fn teachers(&self) -> PathBuf {
        self.root.join("teachers.json")
    }

    /// The run's teachers (none without `teachers.json`).
    pub fn read_teachers(&self) -> Result<Vec<TeacherSummary>> {
        let path = self.teachers();
        if !path.exists() {
            return Ok(Vec::new());
        }
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: bad teacher list", path.display()))
    }

    /// `versions.jsonl`: one line per start and resume of the run (see
    /// [`RunDir::note_version`]).
    pub fn versions(&self) -> PathBuf {
        self.root.join("versions.jsonl")
    }

    /// Appends to `versions.jsonl` which binary `event` (`start` or `resume`) ran at `step`:
    /// its version, the git commit it was built from ([`GIT_COMMIT`]) and the time (Unix
    /// seconds).
    pub fn note_version(&self, event: &str, step: u64) -> Result<()> {
        let line = serde_json::json!({
            "event": event,
            "step": step,
            "version": env!("CARGO_PKG_VERSION"),
            "commit": GIT_COMMIT,
            "unix_time": std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
        });
        let path = self.versions();
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        writeln!(f, "{line}")
            .and_then(|_| f.sync_all())
            .with_context(|| format!("writing {}", path.display()))
    }

    /// `metrics.jsonl`.
    pub fn metrics(&self) -> PathBuf {
        self.root.join("metrics.jsonl")
    }

    /// `checkpoints/<which>` (a kept agent: `checkpoints/agents/<step>`).
    pub fn checkpoint(&self, which: Which) -> PathBuf {
        match which {
            Which::Kept(step) => self.kept_agents().join(step.to_string()),
            w => self.root.join("checkpoints").join(w.to_string()),
        }
    }

    /// `checkpoints/agents`: the agents kept every `run.keep_agents_every` steps.
    pub fn kept_agents(&self) -> PathBuf {
        self.root.join("checkpoints").join("agents")
    }

    /// The steps of the kept agents, in order (an unfinished `<step>.partial` is not one).
    pub fn kept_steps(&self) -> Result<Vec<u64>> {
        let dir = self.kept_agents();
        let mut steps = Vec::new();
        if !dir.exists() {
            return Ok(steps);
        }
        for e in std::fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))? {
            let e = e.with_context(|| format!("reading {}", dir.display()))?;
            if let Some(step) = e.file_name().to_str().and_then(|n| n.parse().ok()) {
                steps.push(step);
            }
        }
        steps.sort_unstable();
        Ok(steps)
    }

    /// The update statistics not yet logged when `checkpoints/latest` was saved.
    pub fn pending_updates(&self) -> PathBuf {
        self.checkpoint(Which::Latest).join("pending_updates.json")
    }

    /// Takes the run directory's lock (`.lock`, an advisory `flock`), held until the returned
    /// file is dropped: a second `rdpg train` on the same directory is refused.
    pub fn lock(&self) -> Result<File> {
        let path = self.root.join(".lock");
        let f = File::options()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        match f.try_lock() {
            Ok(()) => Ok(f),
            Err(std::fs::TryLockError::WouldBlock) => anyhow::bail!(
                "{} is in use by another `rdpg train` (it holds {}); wait for it or stop it",
                self.root.display(),
                path.display()
            ),
            Err(std::fs::TryLockError::Error(e)) => {
                Err(e).with_context(|| format!("locking {}", path.display()))
            }
        }
    }

    /// A new, empty `<dst>.partial` directory to write a checkpoint into before
    /// [`RunDir::commit`] moves it to `dst` (a stale one, left by a crash, is removed).
    pub fn fresh_partial(&self, dst: &Path) -> Result<PathBuf> {
        let tmp = dst.with_extension("partial");
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
        }
        std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
        Ok(tmp)
    }

    /// Moves the sealed checkpoint `tmp` to `dst`: the one it replaces becomes
    /// `<dst>.previous` until the new one is in place, so that a crash between the two renames
    /// leaves a complete checkpoint that [`RunDir::recover`] puts back.
    pub fn commit(&self, tmp: &Path, dst: &Path) -> Result<()> {
        let prev = dst.with_extension("previous");
        let ctx = |what: &str, p: &Path| format!("{what} {}", p.display());
        if prev.exists() {
            std::fs::remove_dir_all(&prev).with_context(|| ctx("removing", &prev))?;
        }
        if dst.exists() {
            std::fs::rename(dst, &prev).with_context(|| ctx("moving aside", dst))?;
        }
        std::fs::rename(tmp, dst).with_context(|| ctx("moving into place", tmp))?;
        if let Some(parent) = dst.parent() {
            File::open(parent)
                .and_then(|f| f.sync_all())
                .with_context(|| ctx("syncing", parent))?;
        }
        if prev.exists() {
            std::fs::remove_dir_all(&prev).with_context(|| ctx("removing", &prev))?;
        }
        Ok(())
    }

    /// Puts the checkpoints back in order after a crash inside [`RunDir::commit`]: a
    /// `<which>.previous` with no `<which>` becomes `<which>` again; unfinished `.partial`
    /// directories are removed (kept agents' too).
    pub fn recover(&self) -> Result<()> {
        let mut dsts: Vec<PathBuf> = [Which::Latest, Which::Best, Which::Selected]
            .into_iter()
            .map(|w| self.checkpoint(w))
            .collect();
        dsts.extend(
            self.kept_steps()?
                .into_iter()
                .map(|s| self.checkpoint(Which::Kept(s))),
        );
        if let Ok(entries) = std::fs::read_dir(self.kept_agents()) {
            for e in entries.flatten() {
                let p = e.path();
                let ext = p.extension().and_then(|x| x.to_str());
                if ext == Some("partial") || ext == Some("previous") {
                    dsts.push(p.with_extension(""));
                }
            }
        }
        for dst in dsts {
            self.recover_one(&dst)?;
        }
        Ok(())
    }

    /// [`RunDir::recover`] for one checkpoint directory `dst`.
    pub fn recover_one(&self, dst: &Path) -> Result<()> {
        let prev = dst.with_extension("previous");
        if !dst.exists() && prev.exists() {
            std::fs::rename(&prev, dst).with_context(|| format!("restoring {}", prev.display()))?;
        }
        let tmp = dst.with_extension("partial");
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
        }
        Ok(())
    }

    /// Removes `checkpoints/best` when it was chosen by an evaluation after step `upto` (a
    /// crash between saving it and the next `latest`), the agents kept after `upto` and a
    /// `selected` agent from after `upto`: the resumed run's metrics end at `upto`, so those
    /// agents have no record behind them. The resumed run saves `best` and the kept ones again.
    pub fn drop_agents_after(&self, upto: u64) -> Result<()> {
        let step = |which: Which| {
            std::fs::read_to_string(self.checkpoint(which).join("eval.json"))
                .ok()
                .and_then(|t| serde_json::from_str::<EvalRecord>(&t).ok())
                .map(|e| e.step)
        };
        let mut drop: Vec<PathBuf> = self
            .kept_steps()?
            .into_iter()
            .filter(|&s| s > upto)
            .map(|s| self.checkpoint(Which::Kept(s)))
            .collect();
        for which in [Which::Best, Which::Selected] {
            if step(which).is_some_and(|s| s > upto) {
                drop.push(self.checkpoint(which));
            }
        }
        for dir in drop {
            std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
        }
        Ok(())
    }

    /// Copies the agent of checkpoint `which` (`best` or `selected`) to `to` and returns the
    /// evaluation that chose it (`None` when there is none yet). A running `rdpg train` (or
    /// `rdpg select`) may replace the checkpoint during the copy; the evaluation read before
    /// and after the copy tells whether the copy is one agent, and it is taken again if not.
    pub fn snapshot_agent(&self, which: Which, to: &Path) -> Result<Option<EvalRecord>> {
        let eval = self.checkpoint(which).join("eval.json");
        let read = || -> Option<EvalRecord> {
            std::fs::read_to_string(&eval)
                .ok()
                .and_then(|t| serde_json::from_str(&t).ok())
        };
        for _ in 0..5 {
            let Some(before) = read() else {
                return Ok(None);
            };
            if to.exists() {
                std::fs::remove_dir_all(to)
                    .with_context(|| format!("removing {}", to.display()))?;
            }
            let copied = copy_agent(&self.agent(which), to);
            if copied.is_ok() && read().as_ref() == Some(&before) {
                return Ok(Some(before));
            }
        }
        anyhow::bail!(
            "{} kept changing while it was copied (a run is saving new agents): try again",
            self.checkpoint(which).display()
        )
    }

    /// The agent of a checkpoint: `checkpoints/<which>/agent` (a zoo entry's `agent/`).
    pub fn agent(&self, which: Which) -> PathBuf {
        if self.is_zoo_entry() {
            return self.root.join("agent");
        }
        self.checkpoint(which).join("agent")
    }

    /// Whether this is a zoo entry (one shipped agent, no checkpoints) rather than a run.
    pub fn is_zoo_entry(&self) -> bool {
        self.root.join("agent").join("agent.json").exists()
            && !self.root.join("checkpoints").exists()
    }

    /// Whether a run was started here (its `config.toml` exists).
    pub fn exists(&self) -> bool {
        self.config().exists()
    }

    /// The run's resolved experiment.
    pub fn experiment(&self) -> Result<Experiment> {
        Experiment::load(&self.config(), &[])
            .with_context(|| format!("{} is not a run directory", self.root.display()))
    }

    /// The run's experiment and its agent `which` as a deterministic policy.
    pub fn policy(&self, which: Which) -> Result<(Experiment, Box<dyn DeterministicPolicy>)> {
        let exp = self.experiment()?;
        if which != Which::Best && self.is_zoo_entry() {
            anyhow::bail!(
                "{} is a zoo entry: it ships one agent (the run's best or selected one), so \
                 drop --checkpoint {which}",
                self.root.display()
            );
        }
        let dir = self.agent(which);
        if !dir.exists() {
            let hint = match which {
                Which::Best => " (no evaluation has finished yet: try --checkpoint latest)",
                Which::Latest => "",
                Which::Selected => " (run `rdpg select` on the run first)",
                Which::Kept(_) => " (no agent was kept at that step: see checkpoints/agents)",
            };
            anyhow::bail!("{} holds no agent{hint}", dir.display());
        }
        let policy = rdpg_agents::load_policy(exp.algo, &dir)
            .with_context(|| format!("loading {}", dir.display()))?;
        Ok((exp, policy))
    }

    /// Every metric row of `metrics.jsonl`, in order. A torn last row (a crash while it was
    /// written: no final newline, not parseable) is left out; any other bad row is an error.
    pub fn read_metrics(&self) -> Result<Vec<Metric>> {
        Ok(self.read_metrics_upto(u64::MAX)?.0)
    }

    /// The rows of `metrics.jsonl` up to `upto` steps, and the length in bytes of the file's
    /// prefix that holds exactly them (a torn last row excluded, see [`RunDir::read_metrics`]).
    pub fn read_metrics_upto(&self, upto: u64) -> Result<(Vec<Metric>, u64)> {
        let path = self.metrics();
        let mut out = Vec::new();
        if !path.exists() {
            return Ok((out, 0));
        }
        let text = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let mut kept = 0u64;
        let mut start = 0usize;
        let mut line_no = 0;
        while start < text.len() {
            line_no += 1;
            let (end, complete) = match text[start..].iter().position(|&b| b == b'\n') {
                Some(k) => (start + k, true),
                None => (text.len(), false),
            };
            let parsed = std::str::from_utf8(&text[start..end])
                .ok()
                .and_then(|l| serde_json::from_str::<Metric>(l).ok());
            let m = match (parsed, complete) {
                (Some(m), true) => m,
                // The last row lost its end in a crash: it was never part of the run's record.
                (_, false) => break,
                (None, true) => anyhow::bail!(
                    "{}:{line_no}: bad metrics line (the file is corrupt; rows after a crash \
                     are only ever torn at the end)",
                    path.display()
                ),
            };
            if m.step() > upto {
                break;
            }
            out.push(m);
            start = end + 1;
            kept = start as u64;
        }
        Ok((out, kept))
    }

    /// The evaluations of `evals.csv` as [`Metric::Eval`] rows (a zoo entry's copy of its
    /// run's; a run's own are read from `metrics.jsonl`).
    pub fn read_evals_csv(&self) -> Result<Vec<Metric>> {
        let path = self.root.join("evals.csv");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let mut lines = text.lines();
        if lines.next() != Some(EVALS_HEADER.trim_end()) {
            anyhow::bail!(
                "{}: not an evals.csv (its header must be `{}`)",
                path.display(),
                EVALS_HEADER.trim_end()
            );
        }
        let mut out = Vec::new();
        for (k, line) in lines.enumerate() {
            let bad = || format!("{}:{}: bad evaluation row `{line}`", path.display(), k + 2);
            let f: Vec<&str> = line.split(',').collect();
            if f.len() != 5 {
                anyhow::bail!(bad());
            }
            let num = |i: usize| f[i].parse::<f64>().with_context(bad);
            out.push(Metric::Eval {
                step: f[0].parse().with_context(bad)?,
                mean_return: num(1)?,
                std_return: num(2)?,
                success_rate: num(3)?,
                wall: num(4)?,
            });
        }
        Ok(out)
    }

    /// The run's `summary.json`.
    pub fn read_summary(&self) -> Result<Summary> {
        let path = self.summary();
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("{} is not a finished run directory", self.root.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: bad summary", path.display()))
    }
}

/// The moving average of the last (up to) [`MovingAverage::WINDOW`] training returns: the one
/// definition behind the metric rows' `r100`, the summary's R_100MA and the plotted curves.
/// The paper's R_100MA is the best mean over *full* windows; before 100 episodes the mean is
/// over the episodes so far ([`MovingAverage::mean`]) and is not an R_100MA
/// ([`MovingAverage::r100`] is `None`).
#[derive(Debug, Clone, Default)]
pub struct MovingAverage {
    window: VecDeque<f64>,
    sum: f64,
}

impl MovingAverage {
    /// Episodes per window.
    pub const WINDOW: usize = 100;

    /// Adds a return.
    pub fn push(&mut self, r: f64) {
        self.window.push_back(r);
        self.sum += r;
        if self.window.len() > Self::WINDOW {
            self.sum -= self.window.pop_front().unwrap_or(0.0);
        }
    }

    /// The mean over the window so far (fewer than 100 returns early on); `None` before any.
    pub fn mean(&self) -> Option<f64> {
        (!self.window.is_empty()).then(|| self.sum / self.window.len() as f64)
    }

    /// The mean over a full window of 100 returns; `None` before 100 episodes.
    pub fn r100(&self) -> Option<f64> {
        (self.window.len() == Self::WINDOW).then(|| self.sum / Self::WINDOW as f64)
    }

    /// The most recent return.
    pub fn last(&self) -> Option<f64> {
        self.window.back().copied()
    }
}

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
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
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
    /// Mean FORK dynamics-model loss (runs with `agent.fork`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_loss: Option<f64>,
    /// Share of the actor updates whose loss had FORK's forward-looking term.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fork_share: Option<f64>,
}

/// Sums of update statistics, turned into [`UpdateMeans`] at each metric row. The sums
/// pending at a checkpoint are saved with it, so that a resumed run logs the same rows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateSums {
    n: u64,
    n_actor: u64,
    critic: f64,
    actor: f64,
    q: f64,
    injected: f64,
    #[serde(default)]
    seconds: f64,
    #[serde(default)]
    n_model: u64,
    #[serde(default)]
    model: f64,
    #[serde(default)]
    n_fork_turn: u64,
    #[serde(default)]
    fork_used: u64,
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
        if let Some(m) = s.model_loss {
            self.n_model += 1;
            self.model += m;
        }
        if let Some(used) = s.fork_term {
            self.n_fork_turn += 1;
            self.fork_used += u64::from(used);
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
            model_loss: mean(s.model, s.n_model),
            fork_share: mean(s.fork_used as f64, s.n_fork_turn),
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
    /// [`machine_description`].
    #[serde(default)]
    pub machine: Option<String>,
}

/// The default of [`Summary::eval_reward`] (summaries written before it existed).
fn stock() -> String {
    "stock".into()
}

/// This host in words: architecture, CPU model and count, memory, e.g. "x86_64, 2 CPUs (AMD
/// EPYC 7B13), 24 GiB RAM". Training devices other than the CPU are in each run's config.
pub fn machine_description() -> String {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, m)| m.trim().to_string());
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    let mem_gib = meminfo_bytes("MemTotal").map(|b| b as f64 / (1u64 << 30) as f64);
    let mut s = format!("{}, {cpus} CPUs", std::env::consts::ARCH);
    if let Some(m) = model {
        s += &format!(" ({m})");
    }
    if let Some(g) = mem_gib {
        s += &format!(", {g:.0} GiB RAM");
    }
    s
}

/// A `/proc/meminfo` entry (e.g. `MemTotal`, `MemAvailable`) in bytes; `None` where there
/// is no such file or entry.
pub fn meminfo_bytes(key: &str) -> Option<u64> {
    let m = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb = m
        .lines()
        .find_map(|l| l.strip_prefix(key)?.strip_prefix(':'))?;
    kb.trim()
        .trim_end_matches("kB")
        .trim()
        .parse::<u64>()
        .ok()
        .map(|kb| kb * 1024)
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

    /// In words: `hardcore-td3-paper (ddpg, best; test 245.5 ± 62.5 stock, 100 ep.)`.
    pub fn label(&self) -> String {
        let t = &self.teacher;
        let test = t.test.map_or("no test".into(), |x| {
            format!(
                "test {:.1} ± {:.1} stock, {} ep.",
                x.mean_stock_return, x.std_stock_return, x.episodes
            )
        });
        format!("{} ({}, {}; {test})", t.name, t.algo, t.checkpoint)
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

/// Collects metrics into the run directory and drives the progress bar.
pub struct RunLog {
    dir: RunDir,
    jsonl: File,
    episodes_csv: File,
    evals_csv: File,
    ma: MovingAverage,
    ma_stock: MovingAverage,
    episodes: u64,
    best_r100: Option<f64>,
    best_r100_stock: Option<f64>,
    /// The last evaluation.
    pub last_eval: Option<EvalRecord>,
    /// The best evaluation so far.
    pub best_eval: Option<EvalRecord>,
    /// Set when an evaluation beat the best so far (cleared by whoever saves it).
    pub new_best: bool,
    started: Instant,
    wall_offset: f64,
    /// The progress bar.
    pub bar: ProgressBar,
    /// Set by Ctrl-C.
    pub stop: Arc<AtomicBool>,
    /// The learner's updates since the last episode row.
    pub updates: UpdateSums,
    /// The final test evaluation, once made.
    pub test_eval: Option<TestSummary>,
    /// The run's teachers (`teachers.json`).
    teachers: Vec<TeacherSummary>,
    /// TensorBoard scalars (`tb/`), written as metrics arrive.
    tb: SummaryWriter<File>,
}

const EPISODES_HEADER: &str = "step,return,stock_return,len,success,r100,updates,critic_loss,\
                               actor_loss,q_mean,injected_share,update_ms,wall\n";
const EVALS_HEADER: &str = "step,mean_return,std_return,success_rate,wall\n";

impl RunLog {
    /// Opens the metric files of `dir`, keeping the records up to `upto` steps (a resumed
    /// run drops what was logged after its checkpoint) and rebuilding the running statistics.
    pub fn open(
        dir: &RunDir,
        upto: u64,
        total: u64,
        quiet: bool,
        stop: Arc<AtomicBool>,
    ) -> Result<Self> {
        let path = dir.metrics();
        // `metrics.jsonl` is the run's record: it is cut back to the checkpoint in place (a
        // resumed run continues from there bit-identically), never rewritten. The CSVs and
        // TensorBoard files are views of it, rebuilt below.
        let (old, kept_bytes) = dir.read_metrics_upto(upto)?;
        let jsonl = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        jsonl
            .set_len(kept_bytes)
            .and_then(|_| jsonl.sync_all())
            .with_context(|| format!("cutting {} back to step {upto}", path.display()))?;
        let pending = dir.pending_updates();
        let updates = if upto > 0 && pending.exists() {
            serde_json::from_str(&std::fs::read_to_string(&pending)?)
                .with_context(|| format!("{}: bad pending update statistics", pending.display()))?
        } else {
            UpdateSums::default()
        };
        let create = |name: &str, header: &str| -> Result<File> {
            let p = dir.root().join(name);
            let mut f = File::create(&p).with_context(|| format!("creating {}", p.display()))?;
            f.write_all(header.as_bytes())
                .with_context(|| format!("writing {}", p.display()))?;
            Ok(f)
        };
        let tb_dir = dir.root().join("tb");
        let old_tb: Vec<PathBuf> = std::fs::read_dir(&tb_dir)
            .map(|d| d.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        std::fs::create_dir_all(&tb_dir)
            .with_context(|| format!("creating {}", tb_dir.display()))?;
        let micros = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros());
        let tb_path = tb_dir.join(format!("rdpg.out.tfevents.{micros}.rdpg"));
        let tb = File::create(&tb_path)
            .and_then(SummaryWriter::new)
            .with_context(|| format!("creating {}", tb_path.display()))?;
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
            b.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:30}] {human_pos}/{human_len} steps, {per_sec}, ETA {eta} {msg}",
                )?
                .progress_chars("=> "),
            );
            b.set_position(upto);
            b.reset_eta();
            b
        };
        let mut log = Self {
            dir: dir.clone(),
            jsonl,
            episodes_csv: create("episodes.csv", EPISODES_HEADER)?,
            evals_csv: create("evals.csv", EVALS_HEADER)?,
            ma: MovingAverage::default(),
            ma_stock: MovingAverage::default(),
            episodes: 0,
            best_r100: None,
            best_r100_stock: None,
            last_eval: None,
            best_eval: None,
            new_best: false,
            started: Instant::now(),
            wall_offset: 0.0,
            bar,
            stop,
            updates,
            test_eval: None,
            teachers: dir.read_teachers()?,
            tb,
        };
        for m in old {
            match &m {
                Metric::Episode {
                    ret, stock_return, ..
                } => {
                    log.push_return(*ret, *stock_return);
                }
                Metric::Eval {
                    step,
                    mean_return,
                    std_return,
                    success_rate,
                    ..
                } => log.note_eval(&EvalRecord {
                    step: *step,
                    mean_return: *mean_return,
                    std_return: *std_return,
                    success_rate: *success_rate,
                    time_limit_rate: 0.0,
                    returns: Vec::new(),
                    lengths: Vec::new(),
                    successes: Vec::new(),
                    obstacles: Default::default(),
                }),
            }
            log.wall_offset = m.wall();
            log.write_views(&m)?;
        }
        log.new_best = false;
        // The rebuilt TensorBoard file holds every kept row: the older ones can go.
        for p in old_tb.iter().filter(|p| **p != tb_path) {
            let _ = std::fs::remove_file(p);
        }
        Ok(log)
    }

    /// Wall-clock seconds of the run (resumes included).
    pub fn wall(&self) -> f64 {
        self.wall_offset + self.started.elapsed().as_secs_f64()
    }

    /// Adds a training return to the 100-episode windows; returns the R_100MA once 100
    /// episodes are in.
    pub fn push_return(&mut self, ret: f64, stock: f64) -> Option<f64> {
        self.episodes += 1;
        self.ma.push(ret);
        self.ma_stock.push(stock);
        let (r, s) = (self.ma.r100()?, self.ma_stock.r100()?);
        self.best_r100 = Some(self.best_r100.map_or(r, |b| b.max(r)));
        self.best_r100_stock = Some(self.best_r100_stock.map_or(s, |b| b.max(s)));
        Some(r)
    }

    /// Records an evaluation (and whether it is the best so far).
    pub fn note_eval(&mut self, r: &EvalRecord) {
        if self
            .best_eval
            .as_ref()
            .is_none_or(|b| r.mean_return > b.mean_return)
        {
            self.best_eval = Some(r.clone());
            self.new_best = true;
        }
        self.last_eval = Some(r.clone());
    }

    /// Appends a metric row to `metrics.jsonl` (one `write` of the whole line, so a crash
    /// can only tear the last row), then to the CSVs and TensorBoard. Every file is written
    /// through unbuffered: a row is on disk (in the OS's cache) as soon as this returns.
    pub fn write(&mut self, m: &Metric) -> Result<()> {
        let mut line = serde_json::to_vec(m)?;
        line.push(b'\n');
        self.jsonl
            .write_all(&line)
            .with_context(|| format!("writing {}", self.dir.metrics().display()))?;
        self.write_views(m)
    }

    /// The CSV and TensorBoard rows of a metric.
    fn write_views(&mut self, m: &Metric) -> Result<()> {
        self.write_tensorboard(m)?;
        match m {
            Metric::Episode {
                step,
                ret,
                stock_return,
                len,
                success,
                r100,
                wall,
                learner: u,
            } => {
                let opt = |x: Option<f64>| x.map_or(String::new(), |r| r.to_string());
                let row = format!(
                    "{step},{ret},{stock_return},{len},{},{},{},{},{},{},{},{},{wall:.3}\n",
                    *success as u8,
                    opt(*r100),
                    u.updates,
                    opt(u.critic_loss),
                    opt(u.actor_loss),
                    opt(u.q_mean),
                    opt(u.injected_share),
                    opt(u.update_ms)
                );
                self.episodes_csv
                    .write_all(row.as_bytes())
                    .context("writing episodes.csv")?
            }
            Metric::Eval {
                step,
                mean_return,
                std_return,
                success_rate,
                wall,
            } => self
                .evals_csv
                .write_all(
                    format!("{step},{mean_return},{std_return},{success_rate},{wall:.3}\n")
                        .as_bytes(),
                )
                .context("writing evals.csv")?,
        }
        Ok(())
    }

    fn write_tensorboard(&mut self, m: &Metric) -> Result<()> {
        let scalars: Vec<(&str, f64)> = match m {
            Metric::Episode {
                ret,
                stock_return,
                r100,
                learner: u,
                ..
            } => {
                let mut v = vec![
                    ("train/return", *ret),
                    ("train/stock_return", *stock_return),
                ];
                v.extend(r100.map(|r| ("train/return_100ma", r)));
                v.extend(u.critic_loss.map(|x| ("learner/critic_loss", x)));
                v.extend(u.actor_loss.map(|x| ("learner/actor_loss", x)));
                v.extend(u.q_mean.map(|x| ("learner/q_mean", x)));
                v.extend(u.injected_share.map(|x| ("learner/injected_share", x)));
                v.extend(u.update_ms.map(|x| ("learner/update_ms", x)));
                v.extend(u.model_loss.map(|x| ("learner/model_loss", x)));
                v.extend(u.fork_share.map(|x| ("learner/fork_share", x)));
                v
            }
            Metric::Eval {
                mean_return,
                std_return,
                success_rate,
                ..
            } => vec![
                ("eval/mean_stock_return", *mean_return),
                ("eval/std_stock_return", *std_return),
                ("eval/success_rate", *success_rate),
            ],
        };
        for (tag, v) in scalars {
            self.tb
                .write_scalar(tag, m.step() as i64, v as f32)
                .context("writing TensorBoard events")?;
        }
        Ok(())
    }

    /// Forces the metric record to the disk (`fsync`), e.g. with each checkpoint.
    pub fn sync(&mut self) -> Result<()> {
        self.jsonl
            .sync_all()
            .with_context(|| format!("syncing {}", self.dir.metrics().display()))
    }

    /// The run's headline numbers at `steps`.
    pub fn summary(&self, exp: &Experiment, steps: u64) -> Summary {
        Summary {
            name: exp.name.clone(),
            algo: exp.algo.as_str().into(),
            env: exp.train.env.clone(),
            train_reward: exp.train.reward_label(),
            eval_reward: exp.train.eval_reward_label(),
            steps,
            episodes: self.episodes,
            wall_seconds: self.wall(),
            best_r100_train_reward: self.best_r100,
            best_r100_stock_reward: self.best_r100_stock,
            last_eval: self.last_eval.as_ref().map(EvalSummary::from),
            best_eval: self.best_eval.as_ref().map(EvalSummary::from),
            test_eval: self.test_eval.clone(),
            teachers: self.teachers.clone(),
            machine: Some(machine_description()),
        }
    }

    /// Writes `summary.json` (whole: a new file renamed over the old one).
    pub fn write_summary(&self, exp: &Experiment, steps: u64) -> Result<()> {
        let s = serde_json::to_string_pretty(&self.summary(exp, steps))?;
        let path = self.dir.summary();
        let tmp = path.with_extension("json.partial");
        std::fs::write(&tmp, s)
            .and_then(|_| std::fs::rename(&tmp, &path))
            .with_context(|| format!("writing {}", path.display()))
    }

    /// The progress bar's message.
    pub fn message(&self) -> String {
        let mut m = format!("| {} episodes", self.episodes);
        if let Some(r) = self.ma.last() {
            m += &format!(", last return {r:.1}");
        }
        if let Some(e) = &self.last_eval {
            m += &format!(", eval {:.1}", e.mean_return);
        }
        m
    }
}

/// Copies an agent's files (`agent.json`, `weights.safetensors`; no optimiser, no replay) from
/// `from` into a new directory `to`, sealed by its own manifest.
pub fn copy_agent(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
    for f in ["agent.json", "weights.safetensors"] {
        copy_file(&from.join(f), &to.join(f))?;
    }
    rdpg_agents::common::checkpoint::seal(to)?;
    Ok(())
}

/// `std::fs::copy` with both paths in the error.
pub fn copy_file(from: &Path, to: &Path) -> Result<()> {
    std::fs::copy(from, to)
        .with_context(|| format!("copying {} to {}", from.display(), to.display()))?;
    Ok(())
}

/// Reads and parses a JSON file, naming it in the error.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))
}

/// Writes `v` as pretty JSON with a final newline (eval.json, selection.json, zoo summaries).
pub fn write_json<T: serde::Serialize>(path: &Path, v: &T) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(v)? + "\n")
        .with_context(|| format!("writing {}", path.display()))
}

/// What a deterministic evaluation's mean is, for JSON output: the stock reward, with the
/// run's action repeat when it has one.
pub fn eval_metric(t: &rdpg_agents::TrainConfig) -> String {
    match t.action_repeat {
        1 => "deterministic evaluation, stock reward".into(),
        k => format!("deterministic evaluation, stock reward, action repeat {k}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evals_csv_is_read_back_and_bad_rows_are_named() {
        let dir = std::env::temp_dir().join(format!("rdpg-evals-csv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run = RunDir::new(&dir);
        let path = dir.join("evals.csv");
        std::fs::write(
            &path,
            format!("{EVALS_HEADER}25000,-12.5,3.25,0.1,86.550\n"),
        )
        .unwrap();
        let rows = run.read_evals_csv().unwrap();
        assert_eq!(rows.len(), 1);
        assert!(matches!(
            rows[0],
            Metric::Eval { step: 25000, mean_return, std_return, success_rate, wall }
                if (mean_return, std_return, success_rate, wall) == (-12.5, 3.25, 0.1, 86.55)
        ));
        for (text, needle) in [
            ("step,return\n".to_string(), "not an evals.csv"),
            (
                format!("{EVALS_HEADER}25000,-12.5,3.25,0.1\n"),
                "evals.csv:2: bad",
            ),
            (
                format!("{EVALS_HEADER}1,2,3,4,5\nx,2,3,4,5\n"),
                "evals.csv:3: bad",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let err = format!("{:#}", run.read_evals_csv().unwrap_err());
            assert!(err.contains(needle), "{err}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
