//! `rdpg`: the command-line front end of the rdpg framework.
//!
//! Subcommands: `train` (an experiment file to a run directory), `eval` (a trained agent on
//! held-out seeds), `record` (a teacher's episodes for experience injection), `plot` and
//! `compare` (learning curves, a Table-I-shaped comparison), `rollout` (replay a fixed action
//! sequence and print the trajectory as JSON lines), `render` (an episode to PNG frames and an
//! animated GIF), `select` (choose among kept agents on more validation episodes), `zoo` (ship
//! an agent), `sweep` (rows × seeds on Ray Tune), `table` (seed-aggregated tables and curves),
//! `claims` (the paper's claims checked on the sweeps' results), `staleness` (how stale the
//! recurrent states of a run's replayed windows are), `bias` (its critics against the returns
//! they predict), `preference` (which actions its critics prefer, its actor's or another
//! run's), `bench` (throughput).

mod bench;
mod bias;
mod claims;
mod eval;
mod experiment;
mod preference;
mod render;
mod report;
mod rollout;
mod rundir;
mod select;
mod staleness;
mod stop;
mod sweep;
mod table;
mod train;
mod zoo;

mod fuzz;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Recurrent deterministic policy gradients for legged robots on rough terrain.
#[derive(Debug, Parser)]
#[command(name = "rdpg", version = concat!(env!("CARGO_PKG_VERSION"), " (commit ", env!("RDPG_GIT_COMMIT"), ")"), about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Train an agent from an experiment file (TOML) into a run directory.
    Train(train::TrainArgs),
    /// Evaluate a run's agent deterministically on held-out seeds (stock reward): one JSON
    /// line with the mean, std, success and time-limit shares, every return and length.
    Eval(eval::EvalArgs),
    /// Record a trained agent's episodes as a teacher file for experience injection.
    Record(eval::RecordArgs),
    /// Learning curves of runs as a PNG (training return and evaluations).
    Plot(report::PlotArgs),
    /// Compare runs: a Markdown table in the shape of the paper's Table I and an overlay plot.
    Compare(report::CompareArgs),
    /// Replay a fixed action sequence and print one JSON object per step.
    Rollout(rollout::RolloutArgs),
    /// Render an episode to an animated GIF (and optionally PNG frames).
    Render(render::RenderArgs),
    /// Choose among a run's kept agents (`run.keep_agents_every`) on more validation episodes.
    Select(select::SelectArgs),
    /// Ship a run's best (or selected) agent as a zoo entry (weights, config, test evaluation, curves, GIF).
    Zoo(zoo::ZooArgs),
    /// Many runs from one sweep file (rows × seeds, each an `rdpg train` process) on Ray Tune:
    /// on this machine or a Ray cluster; rerun to resume.
    Sweep(sweep::SweepArgs),
    /// Seed-aggregated tables (Markdown, CSV) and curves of a sweep's result files or runs.
    Table(table::TableArgs),
    /// The paper's claims, each checked as orderings of a sweep's rows (a Markdown table with
    /// the IQM differences, their 95 % CIs and a verdict).
    Claims(claims::ClaimsArgs),
    /// How far the recurrent states a run's updates start their windows from lie from those
    /// its networks reach along the whole episode (R2D2's staleness), from its replay buffer.
    Staleness(staleness::StalenessArgs),
    /// A run's critics against the discounted returns of its deterministic policy's episodes
    /// on the training reward (TD3's estimation bias).
    Bias(bias::BiasArgs),
    /// Which actions a run's critics prefer along its own episodes: its actor's or another
    /// run's policy's (shown the same observations).
    Preference(preference::PreferenceArgs),
    /// Measure throughput.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

fn main() -> Result<()> {
    rdpg_core::malloc::keep_freed_memory();
    let cli = Cli::parse();
    match cli.command {
        Command::Train(a) => train::run(&a),
        Command::Eval(a) => eval::eval(&a),
        Command::Record(a) => eval::record(&a),
        Command::Plot(a) => report::plot(&a),
        Command::Compare(a) => report::compare(&a),
        Command::Rollout(a) => rollout::run(&a),
        Command::Render(a) => render::run(&a),
        Command::Select(a) => select::run(&a),
        Command::Zoo(a) => zoo::run(&a),
        Command::Sweep(a) => sweep::run(&a),
        Command::Table(a) => table::run(&a),
        Command::Claims(a) => claims::run(&a),
        Command::Staleness(a) => staleness::run(&a),
        Command::Bias(a) => bias::run(&a),
        Command::Preference(a) => preference::run(&a),
        Command::Bench(b) => bench::run(&b),
    }
}
