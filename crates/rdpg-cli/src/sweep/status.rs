//! `rdpg sweep FILE --status`: where a sweep that runs for days stands — whether its driver runs,
//! each trial's state, progress, validation and speed, when the running ones will end, and the
//! core-hours left, all from the files the sweep writes (nothing is started or changed).

use super::{results::TrialResult, Sweep, Trial};
use crate::rundir::{read_json, Metric, RunDir};
use anyhow::Result;
use std::collections::BTreeMap;
use std::path::Path;

/// A trial's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum State {
    /// Its result file exists.
    Finished,
    /// Its `rdpg train` process is alive (the driver's `running/<trial>.json` names it).
    Running,
    /// It has a run directory but no live process and no result: the next `rdpg sweep`
    /// resumes it from its last checkpoint.
    Stopped,
    /// No run directory yet.
    NotStarted,
}

impl State {
    fn word(self) -> &'static str {
        match self {
            State::Finished => "finished",
            State::Running => "running",
            State::Stopped => "stopped",
            State::NotStarted => "not started",
        }
    }
}

/// What `--status` shows of one trial.
#[derive(Debug, Clone)]
pub(super) struct TrialStatus {
    /// `<row>-s<seed>`.
    pub id: String,
    /// Row name.
    pub row: String,
    /// Its state.
    pub state: State,
    /// Agent steps done (the latest metrics row; a stopped trial resumes from its last
    /// checkpoint, at most `checkpoint_every` before).
    pub steps: u64,
    /// Budget (agent steps).
    pub budget: u64,
    /// Wall-clock seconds so far (resumes included).
    pub wall: f64,
    /// Latest validation: (agent step, mean stock return).
    pub last_eval: Option<(u64, f64)>,
    /// Best validation (the agent the run's test will use).
    pub best_eval: Option<(u64, f64)>,
    /// Mean stock return of its test, once finished.
    pub test: Option<f64>,
    /// Recent speed: agent steps per wall-clock second over the last tenth of its budget.
    pub rate: Option<f64>,
}

/// Agent steps per second over the metrics rows of the last `span` steps, none of them before
/// `learning_from` (the warm-up steps, which run without updates and many times faster); at
/// least two rows and a positive wall-clock interval needed.
pub(super) fn recent_rate(rows: &[(u64, f64)], span: u64, learning_from: u64) -> Option<f64> {
    let &(step, wall) = rows.last()?;
    let from = rows
        .iter()
        .find(|&&(s, _)| s + span >= step && s >= learning_from)
        .filter(|&&(s, _)| s < step)?;
    let dt = wall - from.1;
    (dt > 0.0).then(|| (step - from.0) as f64 / dt)
}

fn process_alive(sweep: &Sweep, t: &Trial) -> bool {
    let record = sweep.root.join("running").join(format!("{}.json", t.id));
    let Ok(v) = read_json::<serde_json::Value>(&record) else {
        return false;
    };
    match v["pid"].as_u64() {
        // A record left by a machine that went away names a process that is not there.
        Some(pid) if cfg!(target_os = "linux") => Path::new("/proc").join(pid.to_string()).exists(),
        Some(_) => true,
        None => false,
    }
}

fn trial_status(sweep: &Sweep, t: &Trial) -> Result<TrialStatus> {
    let mut s = TrialStatus {
        id: t.id.clone(),
        row: t.row.clone(),
        state: State::NotStarted,
        steps: 0,
        budget: t.steps,
        wall: 0.0,
        last_eval: None,
        best_eval: None,
        test: None,
        rate: None,
    };
    let result = sweep.results.join(format!("{}.json", t.id));
    if result.exists() {
        let r: TrialResult = read_json(&result)?;
        s.state = State::Finished;
        s.steps = r.steps;
        s.wall = r.summary.wall_seconds;
        s.last_eval = r.curve.last().copied();
        s.best_eval = r
            .summary
            .best_eval
            .as_ref()
            .map(|e| (e.step, e.mean_stock_return));
        s.test = r.test().map(|t| t.mean_stock_return);
        return Ok(s);
    }
    let run = RunDir::new(&t.run_dir);
    if !run.root().exists() {
        return Ok(s);
    }
    s.state = if process_alive(sweep, t) {
        State::Running
    } else {
        State::Stopped
    };
    let metrics = run.read_metrics()?;
    let rows: Vec<(u64, f64)> = metrics.iter().map(|m| (m.step(), m.wall())).collect();
    if let Some(&(step, wall)) = rows.last() {
        (s.steps, s.wall) = (step, wall);
    }
    let warmup = run
        .experiment()
        .ok()
        .and_then(|e| e.off_policy)
        .map_or(0, |o| o.warmup_steps);
    s.rate = recent_rate(&rows, (t.steps / 10).max(1), warmup);
    for m in &metrics {
        if let Metric::Eval {
            step, mean_return, ..
        } = *m
        {
            s.last_eval = Some((step, mean_return));
            if s.best_eval.is_none_or(|(_, b)| mean_return > b) {
                s.best_eval = Some((step, mean_return));
            }
        }
    }
    Ok(s)
}

/// Seconds of wall clock each unfinished trial still needs: its own recent speed where it has
/// one, otherwise its row's measured seconds per agent step (finished trials first, else the
/// row's started ones); `None` where the row has no measurement yet.
pub(super) fn seconds_left(trials: &[TrialStatus]) -> Vec<Option<f64>> {
    let mut per_step: BTreeMap<&str, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
    for t in trials {
        let e = per_step.entry(&t.row).or_default();
        if t.steps > 0 && t.wall > 0.0 {
            let v = t.wall / t.steps as f64;
            if t.state == State::Finished {
                e.0.push(v);
            } else {
                e.1.push(v);
            }
        }
    }
    let median = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| v[v.len() / 2])
    };
    trials
        .iter()
        .map(|t| {
            if t.state == State::Finished {
                return Some(0.0);
            }
            let left = t.budget.saturating_sub(t.steps) as f64;
            if let Some(r) = t.rate {
                return Some(left / r);
            }
            let (done, started) = &per_step[t.row.as_str()];
            median(done).or_else(|| median(started)).map(|s| left * s)
        })
        .collect()
}

fn hours(secs: f64) -> String {
    if secs < 3600.0 {
        format!("{:.0} min", (secs / 60.0).ceil())
    } else {
        format!("{:.1} h", secs / 3600.0)
    }
}

fn eval(e: Option<(u64, f64)>) -> String {
    e.map_or("–".into(), |(step, r)| {
        format!("{r:.1} at {}k", step / 1000)
    })
}

/// The "Left:" line: the core-hours the measured trials still need, and how many trials belong
/// to rows with no measurement yet.
fn left_line(left: &[Option<f64>], threads: usize) -> String {
    // `Sum` of no floats is −0.0: start from +0.0 so a sweep with nothing measured prints 0.0.
    let known = left.iter().flatten().fold(0.0, |a, s| a + s);
    let unknown = left.iter().filter(|l| l.is_none()).count();
    let measured = format!(
        "{:.1} core-hours ({threads} thread(s) per trial) at the speeds measured in this sweep's \
         own trials on this machine",
        known * threads as f64 / 3600.0
    );
    let left = match (unknown, left.len() - unknown) {
        (0, _) => measured,
        (n, 0) => format!("{n} trial(s), of rows not measured yet (`--plan` estimates them)"),
        (n, _) => format!(
            "{measured}, plus {n} trial(s) of rows not measured yet (`--plan` estimates them)"
        ),
    };
    format!(
        "\nLeft: {left}. Wall and speeds are as the trials ran: on a machine shared with other \
         work they include its share.\n"
    )
}

/// The status report (what `--status` prints).
pub(super) fn report(sweep: &Sweep) -> Result<String> {
    let trials = sweep
        .trials
        .iter()
        .map(|t| trial_status(sweep, t))
        .collect::<Result<Vec<_>>>()?;
    let left = seconds_left(&trials);
    let count = |s: State| trials.iter().filter(|t| t.state == s).count();
    let driver = match super::stop::running_driver(sweep)? {
        Some(pid) => format!("Its driver runs (process {pid}; `--stop` stops it)."),
        None => "No driver runs.".into(),
    };
    let mut out = format!(
        "Sweep `{}`: {} trials, {} finished, {} running, {} stopped, {} not started. {driver}\n\n\
         | trial | status | agent steps | wall | validation: last | best | test | steps/h now | left |\n\
         |---|---|---:|---:|---|---|---:|---:|---:|\n",
        sweep.file.name,
        trials.len(),
        count(State::Finished),
        count(State::Running),
        count(State::Stopped),
        count(State::NotStarted),
    );
    for (t, left) in trials.iter().zip(&left) {
        let done = if t.budget > 0 {
            format!(
                "{} / {} ({:.0} %)",
                t.steps,
                t.budget,
                100.0 * t.steps as f64 / t.budget as f64
            )
        } else {
            t.steps.to_string()
        };
        out += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            t.id,
            t.state.word(),
            done,
            if t.wall > 0.0 {
                hours(t.wall)
            } else {
                "–".into()
            },
            eval(t.last_eval),
            eval(t.best_eval),
            t.test.map_or("–".into(), |v| format!("{v:.1}")),
            t.rate.map_or("–".into(), |r| format!("{:.0}k", r * 3.6)),
            match (t.state, left) {
                (State::Finished, _) => "–".into(),
                (_, Some(s)) => hours(*s),
                (_, None) => "?".into(),
            },
        );
    }
    out += &left_line(&left, sweep.file.threads);
    if let Some(eta) = trials
        .iter()
        .zip(&left)
        .filter(|(t, _)| t.state == State::Running)
        .filter_map(|(t, l)| l.map(|l| (t.id.as_str(), l)))
        .map(|(id, l)| format!("{id} in {}", hours(l)))
        .reduce(|a, b| a + ", " + &b)
    {
        out += &format!("Running trials end (at their current speed): {eta}.\n");
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(row: &str, state: State, steps: u64, wall: f64, rate: Option<f64>) -> TrialStatus {
        TrialStatus {
            id: format!("{row}-{steps}"),
            row: row.into(),
            state,
            steps,
            budget: 1000,
            wall,
            last_eval: None,
            best_eval: None,
            test: None,
            rate,
        }
    }

    #[test]
    fn the_recent_rate_spans_the_last_rows() {
        let rows = [(0, 0.0), (100, 10.0), (200, 30.0), (300, 50.0)];
        // Over the last 200 steps: from (100, 10) to (300, 50).
        assert_eq!(recent_rate(&rows, 200, 0), Some(5.0));
        // Over the last 100: (200, 30) to (300, 50).
        assert_eq!(recent_rate(&rows, 100, 0), Some(5.0));
        assert_eq!(recent_rate(&rows, 1000, 0), Some(6.0));
        // Warm-up to step 150: the span starts at (200, 30); to 300, no speed yet.
        assert_eq!(recent_rate(&rows, 1000, 150), Some(5.0));
        assert_eq!(recent_rate(&rows, 1000, 300), None);
        assert_eq!(
            recent_rate(&rows[..1], 100, 0),
            None,
            "one row has no speed"
        );
        assert_eq!(recent_rate(&[(5, 1.0), (5, 1.0)], 10, 0), None);
    }

    #[test]
    fn time_left_uses_the_trial_then_its_row_finished_then_started() {
        let trials = [
            trial("a", State::Finished, 1000, 400.0, None),
            trial("a", State::Finished, 1000, 600.0, None),
            trial("a", State::Running, 500, 100.0, Some(2.0)),
            trial("a", State::NotStarted, 0, 0.0, None),
            trial("b", State::Stopped, 250, 500.0, None),
            trial("b", State::NotStarted, 0, 0.0, None),
            trial("c", State::NotStarted, 0, 0.0, None),
        ];
        let left = seconds_left(&trials);
        assert_eq!(left[0], Some(0.0));
        assert_eq!(
            left[2],
            Some(250.0),
            "its own speed: 500 steps at 2 per second"
        );
        // Row a's finished trials: 0.4 and 0.6 s per step, the median (upper) 0.6.
        assert_eq!(left[3], Some(600.0));
        // Row b has no finished trial: its started one's 2 s per step.
        assert_eq!(left[4], Some(1500.0));
        assert_eq!(left[5], Some(2000.0));
        assert_eq!(left[6], None, "row c has no measurement");
    }

    #[test]
    fn the_left_line_never_prints_a_negative_zero() {
        let none = left_line(&[None, None], 1);
        assert!(
            none.starts_with("\nLeft: 2 trial(s), of rows not measured yet"),
            "{none}"
        );
        let done = left_line(&[Some(0.0), Some(0.0)], 1);
        assert!(
            done.starts_with("\nLeft: 0.0 core-hours (1 thread"),
            "{done}"
        );
        let both = left_line(&[Some(0.0), Some(3600.0), None], 2);
        assert!(
            both.starts_with("\nLeft: 2.0 core-hours (2 thread"),
            "{both}"
        );
        assert!(
            both.contains(", plus 1 trial(s) of rows not measured yet"),
            "{both}"
        );
    }
}
