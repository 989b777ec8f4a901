//! `rdpg train` and `rdpg eval`: run directories, metrics, checkpoints and progress.
//!
//! A run directory holds:
//! - `config.toml`: the resolved experiment (every default written out);
//! - `metrics.jsonl`: one object per finished training episode (`"kind":"episode"`) and per
//!   evaluation (`"kind":"eval"`), with the same rows in `episodes.csv` and `evals.csv`;
//! - `checkpoints/latest/`: the full training state (networks, optimiser, replay, RNGs), which
//!   `--resume` continues from; `checkpoints/best/`: the agent of the best evaluation;
//! - `summary.json`: the run's headline numbers, each named by its reward and metric;
//! - `tb/`: the same metrics as TensorBoard scalars (`tensorboard --logdir runs/`).

use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rdpg_agents::ppo::{PpoAgent, PpoTrainer};
use rdpg_agents::train::{
    evaluate_policy, DeterministicPolicy, EpisodeRecord, EvalRecord, RdpgPolicy, TrainObserver,
    Trainer,
};
use rdpg_agents::{RdpgAgent, UpdateStats};
use serde::{Deserialize, Serialize};
use syntaxdot_summary::SummaryWriter;

use crate::experiment::{Algo, Experiment};

/// Arguments of `rdpg train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Experiment file (TOML), e.g. `configs/memory-rdpg.toml`.
    #[arg(long, required_unless_present = "resume")]
    config: Option<PathBuf>,
    /// Override a key of the experiment, e.g. `--set agent.scan_len=24` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Budget in environment steps (overrides `train.total_steps`; with `--resume`, the new
    /// total).
    #[arg(long)]
    steps: Option<u64>,
    /// Run directory (default: `runs/<name>`). Must not hold a run already.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Continue the run in this directory from `checkpoints/latest`.
    #[arg(long, conflicts_with_all = ["config", "set", "out"])]
    resume: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
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
    fn step(&self) -> u64 {
        match self {
            Metric::Episode { step, .. } | Metric::Eval { step, .. } => *step,
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
    /// The reward the agent learned from (`stock` or `paper`).
    pub train_reward: String,
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
    /// Best deterministic evaluation (stock reward); its agent is `checkpoints/best`.
    pub best_eval: Option<EvalSummary>,
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
struct RunLog {
    dir: PathBuf,
    jsonl: BufWriter<File>,
    episodes_csv: BufWriter<File>,
    evals_csv: BufWriter<File>,
    window: VecDeque<(f64, f64)>,
    episodes: u64,
    best_r100: Option<f64>,
    best_r100_stock: Option<f64>,
    last_eval: Option<EvalRecord>,
    best_eval: Option<EvalRecord>,
    new_best: bool,
    started: Instant,
    wall_offset: f64,
    bar: ProgressBar,
    stop: Arc<AtomicBool>,
    /// TensorBoard scalars (`tb/`), written as metrics arrive.
    tb: SummaryWriter<BufWriter<File>>,
}

const EPISODES_HEADER: &str = "step,return,stock_return,len,success,r100,wall\n";
const EVALS_HEADER: &str = "step,mean_return,std_return,success_rate,wall\n";

impl RunLog {
    /// Opens the metric files of `dir`, keeping the records up to `upto` steps (a resumed
    /// run drops what was logged after its checkpoint) and rebuilding the running statistics.
    fn open(dir: &Path, upto: u64, total: u64, quiet: bool, stop: Arc<AtomicBool>) -> Result<Self> {
        let path = dir.join("metrics.jsonl");
        let mut old = Vec::new();
        if path.exists() {
            for (i, line) in BufReader::new(File::open(&path)?).lines().enumerate() {
                let line = line?;
                let m: Metric = serde_json::from_str(&line)
                    .with_context(|| format!("{}:{}: bad metrics line", path.display(), i + 1))?;
                if m.step() <= upto {
                    old.push(m);
                }
            }
        }
        let create = |name: &str, header: &str| -> Result<BufWriter<File>> {
            let mut w = BufWriter::new(File::create(dir.join(name))?);
            w.write_all(header.as_bytes())?;
            Ok(w)
        };
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
            dir: dir.to_path_buf(),
            jsonl: BufWriter::new(File::create(&path)?),
            episodes_csv: create("episodes.csv", EPISODES_HEADER)?,
            evals_csv: create("evals.csv", EVALS_HEADER)?,
            window: VecDeque::with_capacity(101),
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
            tb: SummaryWriter::from_prefix(dir.join("tb").join("rdpg"))
                .with_context(|| format!("creating {}", dir.join("tb").display()))?,
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
                    returns: Vec::new(),
                }),
            }
            let (Metric::Episode { wall, .. } | Metric::Eval { wall, .. }) = &m;
            log.wall_offset = *wall;
            log.write(&m)?;
        }
        log.new_best = false;
        log.flush()?;
        Ok(log)
    }

    fn wall(&self) -> f64 {
        self.wall_offset + self.started.elapsed().as_secs_f64()
    }

    /// Adds a training return to the 100-episode window; returns the moving average once 100
    /// episodes are in.
    fn push_return(&mut self, ret: f64, stock: f64) -> Option<f64> {
        self.episodes += 1;
        self.window.push_back((ret, stock));
        if self.window.len() > 100 {
            self.window.pop_front();
        }
        if self.window.len() < 100 {
            return None;
        }
        let r = self.window.iter().map(|w| w.0).sum::<f64>() / 100.0;
        let s = self.window.iter().map(|w| w.1).sum::<f64>() / 100.0;
        self.best_r100 = Some(self.best_r100.map_or(r, |b| b.max(r)));
        self.best_r100_stock = Some(self.best_r100_stock.map_or(s, |b| b.max(s)));
        Some(r)
    }

    fn note_eval(&mut self, r: &EvalRecord) {
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

    fn write(&mut self, m: &Metric) -> Result<()> {
        serde_json::to_writer(&mut self.jsonl, m)?;
        self.jsonl.write_all(b"\n")?;
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
            } => writeln!(
                self.episodes_csv,
                "{step},{ret},{stock_return},{len},{},{},{wall:.3}",
                *success as u8,
                r100.map_or(String::new(), |r| r.to_string())
            )?,
            Metric::Eval {
                step,
                mean_return,
                std_return,
                success_rate,
                wall,
            } => writeln!(
                self.evals_csv,
                "{step},{mean_return},{std_return},{success_rate},{wall:.3}"
            )?,
        }
        Ok(())
    }

    fn write_tensorboard(&mut self, m: &Metric) -> Result<()> {
        let scalars: Vec<(&str, f64)> = match m {
            Metric::Episode {
                ret,
                stock_return,
                r100,
                ..
            } => {
                let mut v = vec![
                    ("train/return", *ret),
                    ("train/stock_return", *stock_return),
                ];
                v.extend(r100.map(|r| ("train/return_100ma", r)));
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

    fn flush(&mut self) -> Result<()> {
        self.jsonl.flush()?;
        self.episodes_csv.flush()?;
        self.evals_csv.flush()?;
        Ok(())
    }

    fn summary(&self, exp: &Experiment, steps: u64) -> Summary {
        Summary {
            name: exp.name.clone(),
            algo: format!("{:?}", exp.algo).to_lowercase(),
            env: exp.train.env.clone(),
            train_reward: format!("{:?}", exp.train.reward).to_lowercase(),
            steps,
            episodes: self.episodes,
            wall_seconds: self.wall(),
            best_r100_train_reward: self.best_r100,
            best_r100_stock_reward: self.best_r100_stock,
            last_eval: self.last_eval.as_ref().map(EvalSummary::from),
            best_eval: self.best_eval.as_ref().map(EvalSummary::from),
        }
    }

    fn write_summary(&self, exp: &Experiment, steps: u64) -> Result<()> {
        let s = serde_json::to_string_pretty(&self.summary(exp, steps))?;
        std::fs::write(self.dir.join("summary.json"), s)?;
        Ok(())
    }

    fn message(&self) -> String {
        let mut m = format!("| {} episodes", self.episodes);
        if let Some(&(r, _)) = self.window.back() {
            m += &format!(", last return {r:.1}");
        }
        if let Some(e) = &self.last_eval {
            m += &format!(", eval {:.1}", e.mean_return);
        }
        m
    }
}

/// Errors from inside observer callbacks are kept here and raised after `run` returns.
struct Observer<'a> {
    log: &'a mut RunLog,
    error: Option<anyhow::Error>,
}

impl TrainObserver for Observer<'_> {
    fn on_episode(&mut self, r: &EpisodeRecord) {
        let r100 = self.log.push_return(r.ret, r.stock_return);
        let m = Metric::Episode {
            step: r.step,
            ret: r.ret,
            stock_return: r.stock_return,
            len: r.len,
            success: r.success,
            r100,
            wall: self.log.wall(),
        };
        if let Err(e) = self.log.write(&m) {
            self.error.get_or_insert(e);
        }
        self.log.bar.set_message(self.log.message());
    }
    fn on_eval(&mut self, r: &EvalRecord) {
        self.log.note_eval(r);
        let m = Metric::Eval {
            step: r.step,
            mean_return: r.mean_return,
            std_return: r.std_return,
            success_rate: r.success_rate,
            wall: self.log.wall(),
        };
        if let Err(e) = self.log.write(&m).and_then(|_| self.log.flush()) {
            self.error.get_or_insert(e);
        }
        self.log.bar.set_message(self.log.message());
    }
    fn on_update(&mut self, _step: u64, s: &UpdateStats) {
        if !(s.critic_loss.is_finite() && s.actor_loss.is_finite()) && self.error.is_none() {
            self.error = Some(anyhow::anyhow!(
                "the losses diverged (critic {}, actor {}); lower the learning rates",
                s.critic_loss,
                s.actor_loss
            ));
        }
    }
    fn should_stop(&mut self, step: u64) -> bool {
        self.log.bar.set_position(step);
        self.error.is_some() || self.log.stop.load(Ordering::Relaxed)
    }
}

/// The trainer of an experiment: off-policy (RDPG, DDPG) or on-policy (PPO).
enum AnyTrainer {
    OffPolicy(Box<Trainer>),
    Ppo(Box<PpoTrainer>),
}

impl AnyTrainer {
    fn new(exp: &Experiment) -> Result<Self> {
        Ok(match exp.algo {
            Algo::Ppo => Self::Ppo(Box::new(PpoTrainer::new(
                exp.train.clone(),
                exp.ppo.clone(),
            )?)),
            Algo::Rdpg | Algo::Ddpg => Self::OffPolicy(Box::new(Trainer::new(
                exp.train.clone(),
                exp.agent.clone(),
            )?)),
        })
    }
    fn load(exp: &Experiment, dir: &Path) -> Result<Self> {
        Ok(match exp.algo {
            Algo::Ppo => Self::Ppo(Box::new(PpoTrainer::load(dir)?)),
            Algo::Rdpg | Algo::Ddpg => Self::OffPolicy(Box::new(Trainer::load(dir)?)),
        })
    }
    fn steps(&self) -> u64 {
        match self {
            Self::OffPolicy(t) => t.steps(),
            Self::Ppo(t) => t.steps(),
        }
    }
    fn set_total_steps(&mut self, n: u64) {
        match self {
            Self::OffPolicy(t) => t.set_total_steps(n),
            Self::Ppo(t) => t.set_total_steps(n),
        }
    }
    fn run(&mut self, until: u64, obs: &mut dyn TrainObserver) -> Result<u64> {
        Ok(match self {
            Self::OffPolicy(t) => t.run(until, obs)?,
            Self::Ppo(t) => t.run(until, obs)?,
        })
    }
    fn evaluate(&mut self) -> Result<EvalRecord> {
        Ok(match self {
            Self::OffPolicy(t) => t.evaluate()?,
            Self::Ppo(t) => t.evaluate()?,
        })
    }
    fn save(&mut self, dir: &Path) -> Result<()> {
        match self {
            Self::OffPolicy(t) => t.save(dir)?,
            Self::Ppo(t) => t.save(dir)?,
        }
        Ok(())
    }
    /// Saves the agent alone (the `best` checkpoint), with the evaluation that chose it.
    fn save_best(&self, dir: &Path, eval: Option<&EvalRecord>) -> Result<()> {
        match self {
            Self::OffPolicy(t) => t.agent().save(dir.join("agent"))?,
            Self::Ppo(t) => t.agent().save(dir.join("agent"))?,
        }
        if let Some(e) = eval {
            std::fs::write(dir.join("eval.json"), serde_json::to_string_pretty(e)?)?;
        }
        Ok(())
    }
}

/// `rdpg train`.
pub fn run(a: &TrainArgs) -> Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("installing the Ctrl-C handler")?;
    }
    let (dir, exp, mut trainer) = if let Some(dir) = &a.resume {
        let mut exp = Experiment::load(&dir.join("config.toml"), &[])
            .with_context(|| format!("{} is not a run directory", dir.display()))?;
        let mut trainer = AnyTrainer::load(&exp, &dir.join("checkpoints").join("latest"))
            .with_context(|| format!("resuming {}", dir.display()))?;
        if let Some(n) = a.steps {
            exp.train.total_steps = n;
            exp.validate()?;
            trainer.set_total_steps(n);
            std::fs::write(dir.join("config.toml"), exp.to_toml()?)?;
        }
        (dir.clone(), exp, trainer)
    } else {
        let path = a.config.as_ref().expect("clap requires --config");
        let mut sets = a.set.clone();
        if let Some(n) = a.steps {
            sets.push(format!("train.total_steps={n}"));
        }
        let exp = Experiment::load(path, &sets)?;
        let dir = a
            .out
            .clone()
            .unwrap_or_else(|| Path::new("runs").join(&exp.name));
        if dir.join("config.toml").exists() {
            bail!(
                "{} already holds a run: continue it with --resume {0}, or choose another --out",
                dir.display()
            );
        }
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("creating run directory {}", dir.display()))?;
        std::fs::write(dir.join("config.toml"), exp.to_toml()?)?;
        let trainer = AnyTrainer::new(&exp)?;
        (dir, exp, trainer)
    };
    let total = exp.train.total_steps;
    let mut log = RunLog::open(&dir, trainer.steps(), total, a.quiet, stop.clone())?;
    let latest = dir.join("checkpoints").join("latest");
    let best = dir.join("checkpoints").join("best");
    // The next multiple of `k` after `step` (never when `k` is 0).
    let every = |k: u64, step: u64| step.checked_div(k).map_or(u64::MAX, |q| (q + 1) * k);
    if !a.quiet {
        eprintln!(
            "training {} ({} on {}, {} reward) for {total} steps -> {}",
            exp.name,
            format!("{:?}", exp.algo).to_lowercase(),
            exp.train.env,
            format!("{:?}", exp.train.reward).to_lowercase(),
            dir.display()
        );
    }
    let mut next_ckpt = every(exp.run.checkpoint_every, trainer.steps());
    while trainer.steps() < total {
        // Stop at each evaluation (to keep the best agent) and checkpoint.
        let target = total
            .min(next_ckpt)
            .min(every(exp.train.eval_every, trainer.steps()));
        let mut obs = Observer {
            log: &mut log,
            error: None,
        };
        trainer.run(target, &mut obs)?;
        if let Some(e) = obs.error {
            log.flush()?;
            return Err(e);
        }
        if std::mem::take(&mut log.new_best) {
            trainer.save_best(&best, log.best_eval.as_ref())?;
        }
        log.write_summary(&exp, trainer.steps())?;
        if stop.load(Ordering::Relaxed) {
            trainer.save(&latest)?;
            log.flush()?;
            log.write_summary(&exp, trainer.steps())?;
            log.bar.abandon();
            eprintln!(
                "interrupted at step {}: saved {}; continue with `rdpg train --resume {}`",
                trainer.steps(),
                latest.display(),
                dir.display()
            );
            return Ok(());
        }
        if trainer.steps() >= next_ckpt {
            trainer.save(&latest)?;
            next_ckpt = every(exp.run.checkpoint_every, trainer.steps());
        }
    }
    // A final evaluation unless the last one was at this step.
    if log
        .last_eval
        .as_ref()
        .is_none_or(|e| e.step != trainer.steps())
    {
        let r = trainer.evaluate()?;
        Observer {
            log: &mut log,
            error: None,
        }
        .on_eval(&r);
        if std::mem::take(&mut log.new_best) {
            trainer.save_best(&best, log.best_eval.as_ref())?;
        }
    }
    trainer.save(&latest)?;
    log.flush()?;
    log.write_summary(&exp, trainer.steps())?;
    log.bar.finish();
    let s = log.summary(&exp, trainer.steps());
    println!("{}", serde_json::to_string(&s)?);
    Ok(())
}

/// Arguments of `rdpg eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run directory written by `rdpg train`.
    #[arg(long)]
    run: PathBuf,
    /// Evaluation episodes.
    #[arg(long, default_value_t = 10)]
    episodes: usize,
    /// Which agent: `best` (best evaluation so far) or `latest`.
    #[arg(long, default_value = "best")]
    checkpoint: String,
    /// First seed (default: the run's held-out `train.eval_seed`).
    #[arg(long)]
    seed: Option<u64>,
}

/// Arguments of `rdpg record`.
#[derive(Debug, Args)]
pub struct RecordArgs {
    /// The teacher: a run directory written by `rdpg train` (or its `checkpoints/best` or
    /// `checkpoints/latest`).
    #[arg(long)]
    checkpoint: PathBuf,
    /// Episodes to record.
    #[arg(long, default_value_t = 20)]
    episodes: usize,
    /// Output file (bincode), listed in a student's `train.injection.teachers`.
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
    // A run directory, or one of its checkpoints.
    let (run, which) = match a.checkpoint.file_name().and_then(|n| n.to_str()) {
        Some(w @ ("best" | "latest")) if !a.checkpoint.join("config.toml").exists() => {
            let run = a
                .checkpoint
                .parent()
                .and_then(Path::parent)
                .context("--checkpoint: expected a run directory")?;
            (run.to_path_buf(), w)
        }
        _ => (a.checkpoint.clone(), "best"),
    };
    let (exp, mut policy) = load_run_policy(&run, which)?;
    let t = rdpg_agents::inject::record(
        policy.as_mut(),
        &exp.train,
        a.episodes,
        a.seed,
        a.noise,
        &run.display().to_string(),
    )?;
    t.save(&a.out)?;
    let steps: usize = t.episodes.iter().map(|e| e.len()).sum();
    let mean: f64 = t
        .episodes
        .iter()
        .map(|e| e.rewards.iter().map(|&r| f64::from(r)).sum::<f64>())
        .sum::<f64>()
        / t.episodes.len() as f64;
    println!(
        "{}",
        serde_json::json!({
            "out": a.out.display().to_string(),
            "env": t.env,
            "reward": format!("{:?}", t.reward).to_lowercase(),
            "episodes": t.episodes.len(),
            "steps": steps,
            "mean_return": mean,
        })
    );
    Ok(())
}

/// Loads the agent of a run directory (`best` or `latest`) as a deterministic policy, with
/// the run's experiment.
pub fn load_run_policy(
    run: &Path,
    which: &str,
) -> Result<(Experiment, Box<dyn DeterministicPolicy>)> {
    let exp = Experiment::load(&run.join("config.toml"), &[])
        .with_context(|| format!("{} is not a run directory", run.display()))?;
    let sub = match which {
        "best" | "latest" => which,
        other => bail!("--checkpoint {other:?}: expected best or latest"),
    };
    let dir = run.join("checkpoints").join(sub).join("agent");
    let policy: Box<dyn DeterministicPolicy> = match exp.algo {
        Algo::Ppo => {
            Box::new(PpoAgent::load(&dir).with_context(|| format!("loading {}", dir.display()))?)
        }
        Algo::Rdpg | Algo::Ddpg => Box::new(RdpgPolicy::new(
            RdpgAgent::load(&dir).with_context(|| format!("loading {}", dir.display()))?,
        )),
    };
    Ok((exp, policy))
}

/// `rdpg eval`.
pub fn eval(a: &EvalArgs) -> Result<()> {
    if a.episodes == 0 {
        bail!("--episodes must be at least 1");
    }
    let (exp, mut policy) = load_run_policy(&a.run, &a.checkpoint)?;
    let seed = a.seed.unwrap_or(exp.train.eval_seed);
    let r = evaluate_policy(policy.as_mut(), &exp.train, a.episodes, seed)?;
    #[derive(Serialize)]
    struct Line<'a> {
        run: String,
        checkpoint: &'a str,
        env: &'a str,
        episodes: usize,
        first_seed: u64,
        metric: &'static str,
        mean_stock_return: f64,
        std_stock_return: f64,
        success_rate: f64,
        returns: &'a [f64],
    }
    let line = Line {
        run: a.run.display().to_string(),
        checkpoint: &a.checkpoint,
        env: &exp.train.env,
        episodes: a.episodes,
        first_seed: seed,
        metric: "deterministic evaluation, stock reward",
        mean_stock_return: r.mean_return,
        std_stock_return: r.std_return,
        success_rate: r.success_rate,
        returns: &r.returns,
    };
    println!("{}", serde_json::to_string(&line)?);
    Ok(())
}
