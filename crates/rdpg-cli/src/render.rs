//! `rdpg render`: an episode to an animated GIF (and optionally PNG frames).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use rdpg_agents::common::to_env_action;
use rdpg_core::rng::NpRng;
use rdpg_envs::Renderable;
use rdpg_render::{downscale, rasterize, save_png, GifWriter};

use crate::rundir::{RunDir, Which};

/// Which actions drive the rendered episode.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Policy {
    /// Uniform random actions.
    Random,
    /// All-zero actions.
    Zeros,
}

/// Arguments of `rdpg render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Environment id (default: BipedalWalker-v3, or the run's environment with `--run`).
    #[arg(long)]
    env: Option<String>,
    /// Drive the episode with the trained agent of this run directory (deterministic).
    #[arg(long, conflicts_with = "policy")]
    run: Option<PathBuf>,
    /// With `--run`: which agent of the run (best, latest, selected or the step of a kept
    /// agent).
    #[arg(long, default_value = "best", requires = "run")]
    checkpoint: Which,
    /// Seed of the episode.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Actions.
    #[arg(long, value_enum, default_value_t = Policy::Random)]
    policy: Policy,
    /// Stop after this many steps even if the episode goes on.
    #[arg(long)]
    max_steps: Option<usize>,
    /// Output GIF.
    #[arg(long)]
    gif: PathBuf,
    /// Also write every rendered frame as PNG into this directory.
    #[arg(long)]
    png_dir: Option<PathBuf>,
    /// Render every k-th step (GIF plays at 50/k fps, i.e. real time).
    #[arg(long, default_value_t = 2)]
    every: usize,
    /// Downscale frames by this factor (1 = full 600x400).
    #[arg(long, default_value_t = 1)]
    scale_down: u32,
}

/// Runs `rdpg render` with a fixed policy or a run's trained agent.
pub fn run(args: &RenderArgs) -> Result<()> {
    if args.every == 0 || args.scale_down == 0 {
        anyhow::bail!(
            "--every {} and --scale-down {} must both be at least 1",
            args.every,
            args.scale_down
        );
    }
    let target = RenderTarget {
        gif: args.gif.clone(),
        png_dir: args.png_dir.clone(),
        every: args.every,
        scale_down: args.scale_down,
        max_steps: args.max_steps,
    };
    let (env_id, summary) = if let Some(run) = &args.run {
        let run = RunDir::new(run);
        let env_id = run.experiment()?.train.env;
        if args.env.as_ref().is_some_and(|e| *e != env_id) {
            bail!(
                "--env {:?} differs from the run's environment {:?}",
                args.env.as_deref().unwrap_or_default(),
                env_id
            );
        }
        render_run(&run, args.checkpoint, args.seed, &target)?
    } else {
        let id = args
            .env
            .clone()
            .unwrap_or_else(|| "BipedalWalker-v3".into());
        let mut env = rdpg_envs::make(&id)?;
        let dim = env.action_space().dim();
        let (lo, hi) = (
            env.action_space().low.clone(),
            env.action_space().high.clone(),
        );
        let mut rng = NpRng::from_seed(args.seed.wrapping_add(1_000_003));
        let policy = args.policy;
        let summary = render_episode(
            &mut env,
            args.seed,
            |_obs| {
                Ok(match policy {
                    Policy::Random => (0..dim)
                        .map(|i| rng.uniform(lo[i] as f64, hi[i] as f64) as f32)
                        .collect(),
                    Policy::Zeros => vec![0.0; dim],
                })
            },
            &target,
        )?;
        (id, summary)
    };
    println!(
        "{} seed {}: return {:.3} over {} steps ({}), {} frames -> {}",
        env_id,
        args.seed,
        summary.ret,
        summary.steps,
        summary.ending,
        summary.frames,
        args.gif.display()
    );
    Ok(())
}

/// Renders one episode (reset seed `seed`) of a run's agent `which`, deterministic, on the
/// run's environment; returns the environment id and what happened.
pub fn render_run(
    run: &RunDir,
    which: Which,
    seed: u64,
    target: &RenderTarget,
) -> Result<(String, EpisodeSummary)> {
    let (exp, mut policy) = run.policy(which)?;
    // The agent sees the run's observation mask at its action rate; the reward shown is the
    // stock one.
    let mut env = rdpg_envs::make_with(&exp.train.env, &exp.train.eval_env_options())?;
    let (lo, hi) = (
        env.action_space().low.clone(),
        env.action_space().high.clone(),
    );
    policy.begin_episode();
    let summary = render_episode(
        &mut env,
        seed,
        |obs| Ok(to_env_action(&policy.act(obs)?, &lo, &hi)),
        target,
    )?;
    Ok((exp.train.env, summary))
}

/// Where and how to write frames.
pub struct RenderTarget {
    /// Output GIF.
    pub gif: PathBuf,
    /// Optional PNG directory.
    pub png_dir: Option<PathBuf>,
    /// Render every k-th step.
    pub every: usize,
    /// Downscale factor.
    pub scale_down: u32,
    /// Step cap.
    pub max_steps: Option<usize>,
}

/// What happened in a rendered episode.
pub struct EpisodeSummary {
    /// Sum of rewards.
    pub ret: f64,
    /// Steps taken.
    pub steps: usize,
    /// "terminated", "truncated" or "stopped".
    pub ending: &'static str,
    /// Frames written.
    pub frames: u64,
}

/// Plays one episode with `policy`, writing frames to `target`.
pub fn render_episode<E, P>(
    env: &mut E,
    seed: u64,
    mut policy: P,
    target: &RenderTarget,
) -> Result<EpisodeSummary>
where
    E: rdpg_core::Env + Renderable,
    P: FnMut(&[f32]) -> Result<Vec<f32>>,
{
    let (mut obs, _) = env.reset(Some(seed))?;
    let first = env.scene();
    let (w, h) = (
        first.width.div_ceil(target.scale_down),
        first.height.div_ceil(target.scale_down),
    );
    let fps = 50.0 / target.every as f32;
    if let Some(dir) = &target.png_dir {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if let Some(parent) = target.gif.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let mut gif = GifWriter::create(&target.gif, w, h, fps)?;
    let mut write = |scene: &rdpg_render::Scene, k: usize| -> Result<()> {
        let mut frame = rasterize(scene);
        if target.scale_down > 1 {
            frame = downscale(&frame, target.scale_down);
        }
        if let Some(dir) = &target.png_dir {
            save_png(&frame, &dir.join(format!("frame_{k:05}.png")))?;
        }
        gif.push(&frame)?;
        Ok(())
    };
    write(&first, 0)?;
    let (mut ret, mut steps, mut ending) = (0.0, 0, "stopped");
    loop {
        if target.max_steps.is_some_and(|m| steps >= m) {
            break;
        }
        let action = policy(&obs)?;
        let s = env.step(&action)?;
        steps += 1;
        ret += s.reward;
        let done = s.done();
        obs = s.obs;
        if steps % target.every == 0 || done {
            write(&env.scene(), steps)?;
        }
        if done {
            ending = if s.terminated {
                "terminated"
            } else {
                "truncated"
            };
            break;
        }
    }
    let frames = gif.frames();
    gif.finish()?;
    Ok(EpisodeSummary {
        ret,
        steps,
        ending,
        frames,
    })
}
