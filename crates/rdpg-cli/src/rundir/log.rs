//! The metric writer of a running run and the moving average behind `r100`.

use std::collections::VecDeque;
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rdpg_agents::EvalRecord;
use syntaxdot_summary::SummaryWriter;

use super::{
    machine_description, EvalSummary, Metric, RunDir, Summary, TeacherSummary, TestSummary,
    UpdateSums, EPISODES_HEADER, EVALS_HEADER,
};
use crate::experiment::Experiment;

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
        let scalars: Vec<(String, f64)> = match m {
            Metric::Episode {
                ret,
                stock_return,
                r100,
                learner: u,
                ..
            } => {
                let mut v = vec![
                    ("train/return", Some(*ret)),
                    ("train/stock_return", Some(*stock_return)),
                    ("train/return_100ma", *r100),
                    ("learner/critic_loss", u.critic_loss),
                    ("learner/actor_loss", u.actor_loss),
                    ("learner/q_mean", u.q_mean),
                    ("learner/injected_share", u.injected_share),
                    ("learner/update_ms", u.update_ms),
                ]
                .into_iter()
                .filter_map(|(k, x)| Some((k.to_string(), x?)))
                .collect::<Vec<_>>();
                v.extend(u.extra.iter().map(|(k, &x)| (format!("learner/{k}"), x)));
                v
            }
            Metric::Eval {
                mean_return,
                std_return,
                success_rate,
                ..
            } => vec![
                ("eval/mean_stock_return".into(), *mean_return),
                ("eval/std_stock_return".into(), *std_return),
                ("eval/success_rate".into(), *success_rate),
            ],
        };
        for (tag, v) in scalars {
            self.tb
                .write_scalar(&tag, m.step() as i64, v as f32)
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
