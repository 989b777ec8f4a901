//! `rdpg zoo`: ships a run's best (or `rdpg select`ed) agent as a zoo entry, small enough for
//! git.
//!
//! A zoo entry `zoo/<name>/` holds:
//! - `agent/`: the agent's `agent.json` and `weights.safetensors` (no optimiser state, no
//!   replay), sealed by `manifest.json` (sizes and CRC-32s, checked on every load);
//! - `config.toml`: the run's resolved experiment;
//! - `summary.json` ([`ZooSummary`]): the test evaluation (stock reward, test seeds, which model
//!   selection never saw), when the agent was taken (steps, updates, wall time), the whole run,
//!   the machine and the command that reproduces it;
//! - `evals.csv` and `curves.png`: the run's evaluations and learning curves;
//! - `episode.gif`: the agent on the first test seed;
//! - `README.md`: its model card, generated from the summary ([`model_card`]).
//!
//! `rdpg zoo --retest ENTRY --episodes N` tests an entry again (more test episodes, in order
//! on one env) and rewrites its summary's test and its card; `rdpg zoo --table DIR` prints the
//! table of a zoo's entries (the README's).
//!
//! `rdpg eval --run zoo/<name>` and `rdpg render --run zoo/<name>` read it as a run directory
//! whose `best` agent is `agent/`; `rdpg plot` and `rdpg compare` through
//! [`crate::rundir::read_as_run`].

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use rdpg_agents::common::evaluate_policy;

use crate::render::{render_run, RenderTarget};
use crate::rundir::{
    copy_file, machine_description, read_json, write_json, Metric, RunDir, Which, ZooAgent,
    ZooSummary, ZooTest, ZooTraining,
};

/// Arguments of `rdpg zoo`.
#[derive(Debug, Args)]
pub struct ZooArgs {
    /// Run directory written by `rdpg train`; its agent `--checkpoint` (chosen on the
    /// validation seeds) is shipped.
    #[arg(long, required_unless_present_any = ["table", "retest", "card"])]
    run: Option<PathBuf>,
    /// The agent to ship: `best` (the best periodic evaluation) or `selected` (chosen by
    /// `rdpg select` on more validation episodes).
    #[arg(long, default_value = "best")]
    checkpoint: Which,
    /// The zoo entry to create, e.g. `zoo/walker-td3`. Must not exist.
    #[arg(long, required_unless_present_any = ["table", "retest", "card"])]
    out: Option<PathBuf>,
    /// Test episodes (default: the run's `train.test_episodes`), from the run's test seeds.
    #[arg(long)]
    episodes: Option<usize>,
    /// The command that reproduces the run, shown in the summary and the README's zoo table
    /// (default: `rdpg train --config configs/<name>.toml`).
    #[arg(long)]
    command: Option<String>,
    /// Steps of the GIF (it shows the first test episode up to here).
    #[arg(long, default_value_t = 1000)]
    gif_steps: usize,
    /// Instead of shipping an agent: print the Markdown table of every entry of this zoo
    /// directory, read from the entries' `summary.json` (the README's zoo table).
    #[arg(long, value_name = "ZOO_DIR", conflicts_with_all = ["run", "out", "episodes", "command", "retest", "card"])]
    table: Option<PathBuf>,
    /// Instead of shipping an agent: test this zoo entry again on `--episodes` test episodes
    /// (default: as many as its summary has), in order on one env from its test seeds, and
    /// rewrite its `summary.json` test and its model card (`README.md`).
    #[arg(long, value_name = "ZOO_ENTRY", conflicts_with_all = ["run", "out", "command", "card"])]
    retest: Option<PathBuf>,
    /// Instead of shipping an agent: rewrite this zoo entry's model card (`README.md`) from
    /// its `summary.json` and `config.toml`, testing nothing (after its folder was renamed:
    /// the card's commands name the folder).
    #[arg(long, value_name = "ZOO_ENTRY", conflicts_with_all = ["run", "out", "command", "episodes"])]
    card: Option<PathBuf>,
}

/// `rdpg zoo`.
pub fn run(a: &ZooArgs) -> Result<()> {
    if a.episodes == Some(0) {
        bail!("--episodes must be at least 1");
    }
    let (a_run, a_out) = match (&a.table, &a.retest, &a.card, &a.run, &a.out) {
        (Some(dir), ..) => {
            print!("{}", zoo_table(dir)?);
            return Ok(());
        }
        (None, Some(entry), ..) => return retest(entry, a.episodes),
        (None, None, Some(entry), ..) => return rewrite_card(entry),
        (None, None, None, Some(run), Some(out)) => (run, out),
        // clap requires both without --table.
        _ => bail!("--run and --out are required"),
    };
    let run = RunDir::new(a_run);
    if run.is_zoo_entry() {
        bail!("{} is already a zoo entry", a_run.display());
    }
    if a_out.exists() {
        bail!(
            "{} exists: remove it first (a zoo entry is written whole)",
            a_out.display()
        );
    }
    if !matches!(a.checkpoint, Which::Best | Which::Selected) {
        bail!(
            "--checkpoint {}: a zoo entry ships an agent chosen on the validation seeds, \
             `best` or `selected` (`rdpg select` chooses among kept agents)",
            a.checkpoint
        );
    }
    let exp = run.experiment()?;
    // Before anything is written: a run that declared no test needs --episodes.
    let episodes = crate::eval::test_episodes(a.episodes, &exp.train)?;
    let summary = run.read_summary()?;
    // Write into a temporary sibling, then rename: no half-written entry is left behind.
    let mut tmp_name = a_out.file_name().unwrap_or_default().to_os_string();
    tmp_name.push(".partial");
    let tmp = a_out.with_file_name(tmp_name);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    // Copy first, then test the copy: what ships is what was tested, even if the run is
    // still training and commits a new best meanwhile.
    let agent_dir = run.agent(a.checkpoint);
    let Some(chosen) = run.snapshot_agent(a.checkpoint, &tmp.join("agent"))? else {
        // The message of a missing agent, with its hint.
        run.policy(a.checkpoint)?;
        bail!(
            "{} has no eval.json: not an agent chosen on the validation seeds",
            run.checkpoint(a.checkpoint).display()
        );
    };
    copy_file(&run.config(), &tmp.join("config.toml"))?;
    copy_file(&a_run.join("evals.csv"), &tmp.join("evals.csv"))?;
    let agent_meta: serde_json::Value = read_json(&tmp.join("agent").join("agent.json"))?;
    let updates = agent_meta["updates"].as_u64().with_context(|| {
        format!(
            "{}: no `updates` count",
            agent_dir.join("agent.json").display()
        )
    })?;
    // The run's clock when the agent was saved: its evaluation's row, or (a kept agent
    // between evaluations) the last row before it.
    let metrics = run.read_metrics()?;
    let wall_at_best = metrics
        .iter()
        .find(|m| matches!(m, Metric::Eval { step, .. } if *step == chosen.step))
        .or_else(|| metrics.iter().rev().find(|m| m.step() <= chosen.step))
        .map(Metric::wall);
    let entry = RunDir::new(&tmp);
    let (_, mut policy) = entry.policy(Which::Best)?;
    let t = &exp.train;
    let test = evaluate_policy(policy.as_mut(), t, episodes, t.test_seed)?;
    crate::report::plot_runs(std::slice::from_ref(a_run), &tmp.join("curves.png"))?;
    let target = RenderTarget {
        gif: tmp.join("episode.gif"),
        png_dir: None,
        every: 4,
        scale_down: 2,
        max_steps: Some(a.gif_steps),
    };
    render_run(&entry, Which::Best, t.test_seed, &target)?;

    let mut files = Vec::new();
    for f in [
        "agent/agent.json",
        "agent/weights.safetensors",
        "agent/manifest.json",
        "config.toml",
        "evals.csv",
        "curves.png",
        "episode.gif",
    ] {
        let p = tmp.join(f);
        let len = std::fs::metadata(&p)
            .with_context(|| format!("{}", p.display()))?
            .len();
        files.push((f.to_string(), len));
    }
    let name = if exp.name.is_empty() {
        a_out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    } else {
        exp.name.clone()
    };
    let zs = ZooSummary {
        reproduce: a
            .command
            .clone()
            .unwrap_or_else(|| format!("rdpg train --config configs/{name}.toml")),
        name,
        algo: exp.algo.as_str().into(),
        env: t.env.clone(),
        training_reward: summary.train_reward.clone(),
        evaluation_reward: summary.eval_reward.clone(),
        test: ZooTest::from_eval(&test, episodes, t.test_seed),
        agent: ZooAgent {
            steps: chosen.step,
            updates,
            wall_seconds: wall_at_best,
            validation_mean_return: chosen.mean_return,
            validation_std_return: Some(chosen.std_return),
            validation_success_rate: Some(chosen.success_rate),
            validation_episodes: chosen.returns.len(),
        },
        training: ZooTraining {
            steps: summary.steps,
            episodes: summary.episodes,
            wall_seconds: summary.wall_seconds,
            seed: t.seed,
            best_r100_train_reward: summary.best_r100_train_reward,
        },
        machine: summary.machine.clone().unwrap_or_else(|| {
            format!(
                "{} (the machine that ran `rdpg zoo`; the run did not record its own)",
                machine_description()
            )
        }),
        files,
        teachers: summary.teachers.clone(),
    };
    write_json(&tmp.join("summary.json"), &zs)?;
    std::fs::write(
        tmp.join("README.md"),
        model_card(&entry_name(a_out), &zs, &exp),
    )
    .with_context(|| format!("writing {}", tmp.join("README.md").display()))?;
    std::fs::rename(&tmp, a_out)
        .with_context(|| format!("renaming {} to {}", tmp.display(), a_out.display()))?;
    println!("{}", serde_json::to_string(&zs)?);
    Ok(())
}

/// The Markdown table of every entry of the zoo directory `dir` (by name), each row read from
/// the entry's `summary.json`: agent, environment, training reward, the test (stock reward, on
/// the test seeds), success (walkers), when the agent was taken, its run's seed and command.
pub fn zoo_table(dir: &Path) -> Result<String> {
    let mut entries = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = e?.path();
        if path.join("summary.json").is_file() {
            entries.push(path);
        }
    }
    if entries.is_empty() {
        bail!(
            "{}: no zoo entry (a folder with summary.json)",
            dir.display()
        );
    }
    entries.sort();
    let mut md = String::from(
        "| agent | env | training reward | test: mean ± std (stock reward) | success | agent \
         steps (updates) | wall | seed | reproduce |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for path in entries {
        let z: ZooSummary = read_json(&path.join("summary.json"))?;
        let dirname = path.file_name().unwrap_or_default().to_string_lossy();
        let walker = z.env.starts_with("BipedalWalker");
        let wall = z.agent.wall_seconds.map_or("—".to_string(), wall);
        let _ = writeln!(
            md,
            "| [{dirname}]({}/{dirname}) | {} | {} | **{:.1} ± {:.1}** ({} ep.) | {} | {} ({}) | \
             {wall} | {} | `{}` |",
            dir.display(),
            z.env,
            z.training_reward,
            z.test.mean_return,
            z.test.std_return,
            z.test.episodes,
            if walker {
                format!("{:.0} %", 100.0 * z.test.success_rate)
            } else {
                "—".into()
            },
            steps_k(z.agent.steps),
            steps_k(z.agent.updates),
            z.training.seed,
            z.reproduce,
        );
    }
    Ok(md)
}

/// `62 min`, `3.1 h`: a wall-clock time as the tables write it.
pub(crate) fn wall(seconds: f64) -> String {
    if seconds < 5400.0 {
        format!("{:.0} min", seconds / 60.0)
    } else {
        format!("{:.1} h", seconds / 3600.0)
    }
}

/// `375k`, `1.975M`: a step count as the tables write it.
pub(crate) fn steps_k(n: u64) -> String {
    if n >= 1_000_000 {
        format!("{}M", n as f64 / 1e6)
    } else if n >= 1000 {
        format!("{}k", n as f64 / 1e3)
    } else {
        n.to_string()
    }
}

/// The folder name of a zoo entry (`zoo/walker-td3` → `walker-td3`), which its card's commands
/// name.
fn entry_name(entry: &Path) -> String {
    entry
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Writes `text` to `entry/name` whole (aside, then renamed).
fn write_whole(entry: &Path, name: &str, text: &str) -> Result<()> {
    let (path, part) = (entry.join(name), entry.join(format!("{name}.partial")));
    std::fs::write(&part, text).with_context(|| format!("writing {}", part.display()))?;
    std::fs::rename(&part, &path).with_context(|| format!("renaming to {}", path.display()))
}

/// `entry` as a run directory, refused unless it is a zoo entry.
fn zoo_entry(entry: &Path) -> Result<RunDir> {
    let run = RunDir::new(entry);
    if !run.is_zoo_entry() {
        bail!(
            "{}: not a zoo entry (`rdpg zoo --run` makes one)",
            entry.display()
        );
    }
    Ok(run)
}

/// `rdpg zoo --card ENTRY`: the entry's model card made again from its summary and config.
fn rewrite_card(entry: &Path) -> Result<()> {
    let run = zoo_entry(entry)?;
    let zs: ZooSummary = read_json(&run.summary())?;
    let exp = run.experiment()?;
    write_whole(
        entry,
        "README.md",
        &model_card(&entry_name(entry), &zs, &exp),
    )
}

/// `rdpg zoo --retest ENTRY`: the entry's agent tested again on `episodes` test episodes (in
/// order on one env, from its run's test seeds); its summary's test and its card rewritten,
/// each whole (written aside, then renamed).
fn retest(entry: &Path, episodes: Option<usize>) -> Result<()> {
    let run = zoo_entry(entry)?;
    let mut zs: ZooSummary = read_json(&run.summary())?;
    let (exp, mut policy) = run.policy(Which::Best)?;
    let t = &exp.train;
    let n = episodes.unwrap_or(zs.test.episodes);
    let test = evaluate_policy(policy.as_mut(), t, n, t.test_seed)?;
    zs.test = ZooTest::from_eval(&test, n, t.test_seed);
    write_whole(
        entry,
        "summary.json",
        &(serde_json::to_string_pretty(&zs)? + "\n"),
    )?;
    write_whole(
        entry,
        "README.md",
        &model_card(&entry_name(entry), &zs, &exp),
    )?;
    println!(
        "{}",
        serde_json::json!({
            "entry": entry.display().to_string(),
            "episodes": n,
            "first_seed": t.test_seed,
            "mean_return": zs.test.mean_return,
            "std_return": zs.test.std_return,
            "success_rate": zs.test.success_rate,
        })
    );
    Ok(())
}

/// A zoo entry's model card (`README.md`), made from its summary and config: what it is, its
/// rewards, budget, seed and how it was chosen, its test, how to load it, where it fails.
/// `entry` is the entry's folder name (`zoo/<entry>`), which its commands name; where it is
/// not the experiment's name (`hardcore-td3-paper-2m` of experiment `hardcore-td3-paper`),
/// the card says both.
pub fn model_card(entry: &str, zs: &ZooSummary, exp: &crate::experiment::Experiment) -> String {
    let t = &zs.test;
    let n = t.episodes as f64;
    let walker = zs.env.starts_with("BipedalWalker");
    let mut md = format!(
        "# {name}\n\n`{algo}` agent{experiment} for {env}, trained on the **{train}** reward and \
         tested on the **{eval}** reward{repeat}. Generated from `summary.json` by `rdpg zoo` \
         (`rdpg zoo --retest zoo/{name}` tests the agent again and rewrites both).\n\n",
        name = entry,
        experiment = if entry == zs.name {
            String::new()
        } else {
            format!(" (experiment `{}`)", zs.name)
        },
        algo = zs.algo,
        env = zs.env,
        train = zs.training_reward,
        eval = zs.evaluation_reward,
        repeat = match exp.train.action_repeat {
            1 => String::new(),
            k => format!(" (each action held for {k} frames, in training and in tests)"),
        },
    );
    let _ = writeln!(md, "| | |\n|---|---|");
    let _ = writeln!(
        md,
        "| test | **{:.1} ± {:.1}** (standard error {:.1}) over {} test episodes from seed {}, \
         in order on one env{} |",
        t.mean_return,
        t.std_return,
        t.std_return / n.sqrt(),
        t.episodes,
        t.first_seed,
        if walker {
            format!("; success {:.0} %", 100.0 * t.success_rate)
        } else {
            String::new()
        },
    );
    let _ = writeln!(
        md,
        "| the agent | taken at {} steps ({} updates) of a {}-step run, chosen on {} validation \
         episodes (mean {:.1}), which the test never saw |",
        steps_k(zs.agent.steps),
        steps_k(zs.agent.updates),
        steps_k(zs.training.steps),
        zs.agent.validation_episodes,
        zs.agent.validation_mean_return,
    );
    let _ = writeln!(
        md,
        "| the run | seed {}, {} of training on {} |",
        zs.training.seed,
        wall(zs.training.wall_seconds),
        zs.machine
    );
    let _ = writeln!(md, "| reproduce | `{}` |", zs.reproduce);
    for teacher in &zs.teachers {
        let _ = writeln!(
            md,
            "| injection | taught by `{}`: {} episodes (mean {:.1} stock) of {} |",
            teacher.file,
            teacher.episodes,
            teacher.mean_stock_return,
            teacher.label()
        );
    }
    let _ = writeln!(
        md,
        "\n```sh\nrdpg eval --run zoo/{0} --episodes {1}   # the test above\n\
         rdpg render --run zoo/{0} --gif {0}.gif\n```\n\n```python\nimport rdpg\n\
         policy = rdpg.Policy.load(rdpg.zoo(\"{0}\"))\nenv = policy.make_env()   # its action repeat, \
         stock reward\n```\n",
        entry, t.episodes
    );
    if walker && (!t.obstacles.is_empty() || t.time_limit_rate.is_some()) {
        md.push_str("## Where it fails\n\n");
        if let Some(r) = t.time_limit_rate {
            let _ = writeln!(
                md,
                "{:.0} % of the test episodes reach the time limit without finishing (too slow \
                 or stuck).\n",
                100.0 * r
            );
        }
        if !t.obstacles.is_empty() {
            md.push_str("| obstacle | passed | fell at it | stuck at it |\n|---|---|---|---|\n");
            for (kind, o) in &t.obstacles {
                let _ = writeln!(md, "| {kind} | {} | {} | {} |", o.passed, o.fell, o.stuck);
            }
        }
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every committed zoo entry's card is the one its summary, config and folder name make
    /// (`rdpg zoo --card` rewrites a stale one): its commands name the folder it is in.
    #[test]
    fn committed_cards_are_generated_from_their_entries() {
        let zoo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../zoo");
        let mut checked = 0;
        for e in std::fs::read_dir(&zoo).unwrap() {
            let entry = e.unwrap().path();
            if !RunDir::new(&entry).is_zoo_entry() {
                continue;
            }
            let zs: ZooSummary = read_json(&entry.join("summary.json")).unwrap();
            let exp = RunDir::new(&entry).experiment().unwrap();
            let want = model_card(&entry_name(&entry), &zs, &exp);
            let have = std::fs::read_to_string(entry.join("README.md")).unwrap();
            assert!(
                have == want,
                "{}: the card is stale: `rdpg zoo --card {}` rewrites it",
                entry.display(),
                entry.display()
            );
            checked += 1;
        }
        assert!(checked >= 8, "only {checked} zoo entries found");
    }

    /// A walker's card gives the test with its standard error and where the agent fails, from
    /// the summary alone.
    #[test]
    fn a_walkers_card_says_where_it_fails() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../zoo/hardcore-td3-paper");
        let mut zs: ZooSummary = read_json(&root.join("summary.json")).unwrap();
        let exp = crate::experiment::Experiment::load(&root.join("config.toml"), &[]).unwrap();
        zs.test.time_limit_rate = Some(0.03);
        zs.test.obstacles.insert(
            "stump".into(),
            rdpg_agents::common::ObstacleRecord {
                passed: 410,
                fell: 7,
                stuck: 2,
            },
        );
        // The test as the entry's summary records it (the card's numbers are its own).
        let t = zs.test.clone();
        zs.test = ZooTest {
            episodes: 4,
            returns: vec![300.0, 250.0, -100.0, 298.0],
            mean_return: 187.0,
            std_return: 167.0,
            success_rate: 0.5,
            ..t
        };
        let card = model_card("hardcore-td3-paper", &zs, &exp);
        for want in [
            "**187.0 ± 167.0** (standard error 83.5) over 4 test episodes from seed 3000000",
            "success 50 %",
            "each action held for 3 frames",
            "3 % of the test episodes reach the time limit",
            "| stump | 410 | 7 | 2 |",
            "rdpg eval --run zoo/hardcore-td3-paper --episodes 4",
        ] {
            assert!(card.contains(want), "{want}\n{card}");
        }
        assert!(!card.contains("(experiment `"), "{card}");
        // An entry in a folder of another name: its commands name the folder, the card the
        // experiment.
        let card = model_card("hardcore-td3-paper-2m", &zs, &exp);
        for want in [
            "# hardcore-td3-paper-2m\n",
            "`ddpg` agent (experiment `hardcore-td3-paper`) for BipedalWalkerHardcore-v3",
            "rdpg eval --run zoo/hardcore-td3-paper-2m --episodes 4",
            "rdpg.zoo(\"hardcore-td3-paper-2m\")",
        ] {
            assert!(card.contains(want), "{want}\n{card}");
        }
    }
}
