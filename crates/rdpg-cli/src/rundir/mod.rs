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
//!
//! The module's rooms: this file is the layout and its transactions ([`RunDir`]);
//! [`schema`] the files' contents (metric rows, summary, teachers, tests); [`log`] the metric
//! writer of a running run ([`RunLog`]); [`machine`] the host's facts; [`zoo_entry`] a zoo
//! entry's summary, and the entry read as a run.

mod log;
pub mod machine;
mod schema;
mod zoo_entry;

pub use log::{MovingAverage, RunLog};
pub use machine::machine_description;
pub use schema::{
    EvalSummary, Metric, Summary, TeacherSummary, TestSummary, UpdateSums, EPISODES_HEADER,
    EVALS_HEADER,
};
pub use zoo_entry::{read_as_run, ZooAgent, ZooSummary, ZooTest, ZooTraining};

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rdpg_agents::{DeterministicPolicy, EvalRecord};

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
        let dir = self.existing_agent(which)?;
        let policy = rdpg_agents::load_policy(exp.algo, &dir)
            .with_context(|| format!("loading {}", dir.display()))?;
        Ok((exp, policy))
    }

    /// The folder of agent `which` ([`RunDir::agent`]), refused with a hint when it does not
    /// exist, or when `which` names a checkpoint of a zoo entry (it ships one agent).
    pub fn existing_agent(&self, which: Which) -> Result<PathBuf> {
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
        Ok(dir)
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
mod tests;
