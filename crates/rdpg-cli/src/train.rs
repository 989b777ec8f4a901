//! `rdpg train`: any algorithm through `rdpg_agents::{new_trainer, load_trainer}`, into run
//! directories ([`crate::rundir`]); `rdpg eval` and `rdpg record` read them (`crate::eval`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::checkpoint::seal;
use rdpg_agents::common::{evaluate_policy_traced, EpisodeTrace};
use rdpg_agents::{AgentError, EpisodeRecord, EvalRecord, TrainObserver, Trainer, UpdateStats};

use crate::experiment::{check_memory, Experiment};
use crate::rundir::{
    copy_agent, write_json, Metric, RunDir, RunLog, TeacherSummary, TestSummary, Which,
};

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

/// Errors from inside observer callbacks are kept here and raised after `run` returns.
struct Observer<'a> {
    log: &'a mut RunLog,
    error: Option<anyhow::Error>,
}

impl<'a> Observer<'a> {
    fn new(log: &'a mut RunLog) -> Self {
        Self { log, error: None }
    }
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
            learner: self.log.updates.take(),
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
        if let Err(e) = self.log.write(&m) {
            self.error.get_or_insert(e);
        }
        self.log.bar.set_message(self.log.message());
    }
    fn on_update(&mut self, _step: u64, s: &UpdateStats) {
        self.log.updates.add(s);
        let actor_ok = s.actor_loss.is_none_or(f64::is_finite);
        if !(s.critic_loss.is_finite() && actor_ok) && self.error.is_none() {
            self.error = Some(anyhow::anyhow!(
                "the losses diverged (critic {}, actor {:?}); lower the learning rates",
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

/// Saves the whole training state to `checkpoints/latest`, with the update statistics the
/// metric files have not logged yet. Written whole into a new directory, sealed (fsync and
/// checksums) and only then moved into place: a crash or a full disk at any moment leaves the
/// previous checkpoint intact.
fn save_latest(
    trainer: &mut dyn Trainer,
    run: &RunDir,
    exp: &Experiment,
    log: &RunLog,
) -> Result<()> {
    let dst = run.checkpoint(Which::Latest);
    let tmp = run.fresh_partial(&dst)?;
    trainer.save(&tmp)?;
    let snapshot = tmp.join("config.toml");
    std::fs::write(&snapshot, exp.to_toml()?)
        .with_context(|| format!("writing {}", snapshot.display()))?;
    let pending = tmp.join("pending_updates.json");
    std::fs::write(&pending, serde_json::to_string(&log.updates)?)
        .with_context(|| format!("writing {}", pending.display()))?;
    // Sealed again with the files added here.
    seal(&tmp)?;
    run.commit(&tmp, &dst)
}

/// What a resume may change in a run's `config.toml`: the budget, the final test's size
/// (`train.test_episodes`: it runs after training), the checkpoint and kept-agent cadences and
/// `agent.parallel_twins` (a speed setting that changes no number; the trainer takes it).
/// Any other edit since the checkpoint (`then`) would be ignored by the restored trainer while
/// reports showed it as in effect, so it is refused, naming the keys.
fn check_resume_edits(then: &Experiment, now: &Experiment, path: &Path) -> Result<()> {
    let table = |e: &Experiment| -> Result<toml::Table> {
        let mut t: toml::Table = toml::from_str(&e.to_toml()?)?;
        if let Some(toml::Value::Table(train)) = t.get_mut("train") {
            train.remove("total_steps");
            train.remove("test_episodes");
        }
        if let Some(toml::Value::Table(run)) = t.get_mut("run") {
            run.remove("checkpoint_every");
            run.remove("keep_agents_every");
        }
        if let Some(toml::Value::Table(agent)) = t.get_mut("agent") {
            agent.remove("parallel_twins");
        }
        Ok(t)
    };
    let mut changed = Vec::new();
    diff_keys("", &table(then)?, &table(now)?, &mut changed);
    if !changed.is_empty() {
        bail!(
            "{} was edited since the last checkpoint ({}): a resumed run keeps the settings it \
             was started with, except train.total_steps (or --steps), train.test_episodes, \
             run.checkpoint_every, run.keep_agents_every and agent.parallel_twins. \
             Undo the edit, or start a new run from the edited file with --config",
            path.display(),
            changed.join(", ")
        );
    }
    Ok(())
}

/// The dotted keys whose values differ between `a` and `b`.
fn diff_keys(prefix: &str, a: &toml::Table, b: &toml::Table, out: &mut Vec<String>) {
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    for k in keys {
        let name = format!("{prefix}{k}");
        match (a.get(k), b.get(k)) {
            (Some(toml::Value::Table(x)), Some(toml::Value::Table(y))) => {
                diff_keys(&format!("{name}."), x, y, out)
            }
            (x, y) if x != y => out.push(name),
            _ => {}
        }
    }
}

/// Saves the agent alone as checkpoint `which` (`best` with its optimiser state; a kept agent
/// without, half the size), with the evaluation at its step if there is one; written and moved
/// into place like [`save_latest`].
fn save_agent(
    trainer: &dyn Trainer,
    run: &RunDir,
    which: Which,
    eval: Option<&EvalRecord>,
) -> Result<()> {
    let dst = run.checkpoint(which);
    let tmp = run.fresh_partial(&dst)?;
    if let Which::Kept(_) = which {
        let full = tmp.join("full");
        trainer.save_agent(&full)?;
        copy_agent(&full, &tmp.join("agent"))?;
        std::fs::remove_dir_all(&full).with_context(|| format!("removing {}", full.display()))?;
    } else {
        trainer.save_agent(&tmp.join("agent"))?;
    }
    if let Some(e) = eval {
        write_json(&tmp.join("eval.json"), e)?;
    }
    // Sealed again with the files added here.
    seal(&tmp)?;
    run.commit(&tmp, &dst)
}

/// Keeps the agent of the current step (`run.keep_agents_every`), with the evaluation at this
/// step if there was one.
fn keep_agent(trainer: &dyn Trainer, run: &RunDir, log: &RunLog) -> Result<()> {
    let step = trainer.steps();
    let eval = log.last_eval.as_ref().filter(|e| e.step == step);
    save_agent(trainer, run, Which::Kept(step), eval)
}

/// `rdpg train`.
pub fn run(a: &TrainArgs) -> Result<()> {
    // Ctrl-C, SIGTERM and SIGHUP: finish the current step, save, exit 130 (a second Ctrl-C
    // exits at once). First, before any thread exists (see `stop`).
    let stop = Arc::new(AtomicBool::new(false));
    crate::stop::install(stop.clone())?;
    let (run, exp, mut trainer, _lock) = if let Some(dir) = &a.resume {
        let run = RunDir::new(dir);
        if !run.exists() {
            bail!("{} holds no run (no config.toml) to resume", dir.display());
        }
        let lock = run.lock()?;
        run.recover()?;
        let mut exp = run.experiment()?;
        let latest = run.checkpoint(Which::Latest);
        let mut trainer = rdpg_agents::load_trainer(&latest)
            .with_context(|| format!("resuming {}", dir.display()))?;
        // The checkpoint's own copy of the experiment: what the trainer was built from.
        let snapshot = latest.join("config.toml");
        if snapshot.exists() {
            let then = Experiment::load(&snapshot, &[])
                .with_context(|| format!("reading {}", snapshot.display()))?;
            check_resume_edits(&then, &exp, &run.config())?;
        }
        if let Some(n) = a.steps {
            if n < trainer.steps() {
                bail!(
                    "--steps {n} is below the {} steps {} has already done: a run cannot be \
                     shortened (its agents chosen on validation are kept; `rdpg select --from` \
                     and `--checkpoint STEP` reach earlier ones)",
                    trainer.steps(),
                    dir.display()
                );
            }
            exp.train.total_steps = n;
            exp.validate()?;
            std::fs::write(run.config(), exp.to_toml()?)
                .with_context(|| format!("writing {}", run.config().display()))?;
        }
        // config.toml holds the budget (set by --steps or edited): the trainer follows it,
        // and the speed setting parallel_twins.
        trainer.set_total_steps(exp.train.total_steps);
        if let (Some(agent), Some(off)) = (
            &exp.agent,
            trainer
                .as_any_mut()
                .downcast_mut::<rdpg_agents::OffPolicyTrainer>(),
        ) {
            off.set_parallel_twins(agent.parallel_twins)?;
        }
        // Only once the resume is accepted: a refused one leaves the run as it was.
        run.drop_agents_after(trainer.steps())?;
        run.note_version("resume", trainer.steps())?;
        (run, exp, trainer, lock)
    } else {
        let path = a.config.as_ref().expect("clap requires --config");
        let mut sets = a.set.clone();
        if let Some(n) = a.steps {
            sets.push(format!("train.total_steps={n}"));
        }
        let exp = Experiment::load(path, &sets)?;
        let run = RunDir::new(
            a.out
                .clone()
                .unwrap_or_else(|| Path::new("runs").join(&exp.name)),
        );
        if run.exists() {
            bail!(
                "{} already holds a run: continue it with --resume {0}, or choose another --out",
                run.root().display()
            );
        }
        // The trainer first: a start that fails (e.g. no CUDA device) leaves no directory.
        check_memory(&exp)?;
        let trainer = rdpg_agents::new_trainer(exp.train.clone(), exp.learner())?;
        std::fs::create_dir_all(run.root())
            .with_context(|| format!("creating run directory {}", run.root().display()))?;
        let lock = run.lock()?;
        if run.exists() {
            bail!(
                "{} was just started by another `rdpg train`",
                run.root().display()
            );
        }
        std::fs::write(run.config(), exp.to_toml()?)
            .with_context(|| format!("writing {}", run.config().display()))?;
        let teachers = exp
            .off_policy
            .iter()
            .flat_map(|o| o.injection.iter().flat_map(|i| &i.teachers))
            .map(|p| TeacherSummary::read(p))
            .collect::<Result<Vec<_>>>()?;
        if !teachers.is_empty() {
            write_json(&run.teachers(), &teachers)?;
        }
        run.note_version("start", 0)?;
        (run, exp, trainer, lock)
    };
    let total = exp.train.total_steps;
    let mut log = RunLog::open(&run, trainer.steps(), total, a.quiet, stop.clone())?;
    // The next multiple of `k` after `step` (never when `k` is 0).
    let every = |k: u64, step: u64| step.checked_div(k).map_or(u64::MAX, |q| (q + 1) * k);
    if !a.quiet {
        eprintln!(
            "training {} ({} on {}, reward: {}) for {total} steps -> {}",
            exp.name,
            exp.algo.as_str(),
            exp.train.env,
            exp.train.reward_label(),
            run.root().display()
        );
    }
    let mut next_ckpt = every(exp.run.checkpoint_every, trainer.steps());
    let mut next_keep = every(exp.run.keep_agents_every, trainer.steps());
    while trainer.steps() < total {
        // Stop at each evaluation (to keep the best agent), checkpoint and kept agent.
        let target = total
            .min(next_ckpt)
            .min(next_keep)
            .min(every(exp.train.eval_every, trainer.steps()));
        let mut obs = Observer::new(&mut log);
        trainer.run(target, &mut obs)?;
        if let Some(e) = obs.error {
            let _ = log.sync();
            return Err(e);
        }
        if std::mem::take(&mut log.new_best) {
            save_agent(trainer.as_ref(), &run, Which::Best, log.best_eval.as_ref())?;
        }
        // (The agent kept at the end waits for the final evaluation, to carry it.)
        if trainer.steps() >= next_keep && trainer.steps() < total {
            keep_agent(trainer.as_ref(), &run, &log)?;
            next_keep = every(exp.run.keep_agents_every, trainer.steps());
        }
        log.write_summary(&exp, trainer.steps())?;
        if stop.load(Ordering::Relaxed) {
            // The metric record first: a checkpoint must never be ahead of it.
            log.sync()?;
            save_latest(trainer.as_mut(), &run, &exp, &log)?;
            log.write_summary(&exp, trainer.steps())?;
            stopped(&mut log, &run, trainer.steps());
        }
        if trainer.steps() >= next_ckpt {
            log.sync()?;
            save_latest(trainer.as_mut(), &run, &exp, &log)?;
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
        let mut obs = Observer::new(&mut log);
        obs.on_eval(&r);
        if let Some(e) = obs.error {
            return Err(e);
        }
        if std::mem::take(&mut log.new_best) {
            save_agent(trainer.as_ref(), &run, Which::Best, log.best_eval.as_ref())?;
        }
    }
    if trainer.steps() >= next_keep {
        keep_agent(trainer.as_ref(), &run, &log)?;
    }
    log.sync()?;
    save_latest(trainer.as_mut(), &run, &exp, &log)?;
    if exp.train.test_episodes > 0 {
        // Stopped before or during the test: the run is saved at its budget, and a resume
        // runs only the test.
        match test_best(&run, &exp, log.best_eval.as_ref(), &stop)? {
            Some(t) => log.test_eval = Some(t),
            None => {
                log.write_summary(&exp, trainer.steps())?;
                stopped(&mut log, &run, trainer.steps())
            }
        }
    }
    log.write_summary(&exp, trainer.steps())?;
    log.bar.finish();
    let s = log.summary(&exp, trainer.steps());
    println!("{}", serde_json::to_string(&s)?);
    Ok(())
}

/// Ends a run stopped by Ctrl-C, SIGTERM or SIGHUP, once it is saved at `step`: exits 130.
fn stopped(log: &mut RunLog, run: &RunDir, step: u64) -> ! {
    log.bar.abandon();
    eprintln!(
        "interrupted at step {step}: saved {}; continue with `rdpg train --resume {}`",
        run.checkpoint(Which::Latest).display(),
        run.root().display()
    );
    // Not a success: `rdpg train ... && next-step` must not carry on.
    std::process::exit(130);
}

/// The final test: the agent chosen on the validation seeds (`checkpoints/best`) on the test
/// seeds, which nothing else looks at; `None` when `stop` is raised before its last episode.
fn test_best(
    run: &RunDir,
    exp: &Experiment,
    best: Option<&EvalRecord>,
    stop: &AtomicBool,
) -> Result<Option<TestSummary>> {
    if stop.load(Ordering::Relaxed) {
        return Ok(None);
    }
    let (_, mut policy) = run.policy(Which::Best)?;
    let t = &exp.train;
    let mut each = |_: &EpisodeTrace<'_>| match stop.load(Ordering::Relaxed) {
        true => Err(AgentError::Stopped),
        false => Ok(()),
    };
    let r =
        match evaluate_policy_traced(policy.as_mut(), t, t.test_episodes, t.test_seed, &mut each) {
            Err(AgentError::Stopped) => return Ok(None),
            r => r?,
        };
    Ok(Some(TestSummary {
        step: best.map_or(0, |b| b.step),
        episodes: t.test_episodes,
        first_seed: t.test_seed,
        mean_stock_return: r.mean_return,
        std_stock_return: r.std_return,
        success_rate: r.success_rate,
        returns: r.returns,
        successes: r.successes,
        time_limit_rate: Some(r.time_limit_rate),
        obstacles: r.obstacles,
    }))
}
