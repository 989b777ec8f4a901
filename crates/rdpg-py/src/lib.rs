//! `rdpg._rdpg`: the Rust side of the `rdpg` Python package.
//!
//! Three classes, wrapped by `python/rdpg/__init__.py` into Gymnasium's API:
//! - [`Env`]: one registered environment (`rdpg_envs::make_with`), stepped with the GIL
//!   released;
//! - [`VecEnv`]: `n` environments stepped in parallel on persistent Rust worker threads (GIL
//!   released), with Gymnasium's default *next-step* autoreset;
//! - [`Policy`]: a trained agent of a run or zoo directory, acting deterministically.
//!
//! Arrays cross the boundary as `bytes` of little-endian `f32` (observations, actions) or
//! `f64` (rewards); the Python side views them with `numpy.frombuffer`, without copies of
//! Python objects per element. Every error is a Python exception carrying the Rust message.

// Python gets an exception with the Rust message, never a PanicException.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use rdpg_agents::common::to_env_action;
use rdpg_agents::{Algo, DeterministicPolicy, TrainConfig};
use rdpg_envs::registry::AnyEnv;
use rdpg_envs::{EnvOptions, Renderable, WalkerReward};

fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

fn runtime_err(e: impl std::fmt::Display) -> PyErr {
    PyRuntimeError::new_err(e.to_string())
}

/// The environment options of the Python constructors. With `action_repeat > 1` the env keeps
/// its own time limit whatever `time_limit` says: the limit counts frames (as in `rdpg train`),
/// so Gymnasium's TimeLimit, which counts agent steps, never fires first.
fn options(
    reward: &str,
    hide_obs: Vec<usize>,
    time_limit: bool,
    fall_penalty: Option<f64>,
    action_repeat: usize,
) -> PyResult<EnvOptions> {
    let reward = match reward {
        "stock" => WalkerReward::Stock,
        "paper" => WalkerReward::Paper,
        other => {
            return Err(value_err(format!(
                "reward {other:?}: expected \"stock\" or \"paper\""
            )))
        }
    };
    // Gymnasium's behaviour: the walker keeps its Box2D world across resets.
    Ok(EnvOptions {
        reward,
        hide_obs,
        // Without its own limit the env is Gymnasium's raw class: `gymnasium.make` adds the
        // TimeLimit wrapper (and honours `max_episode_steps=`).
        max_episode_steps: (!time_limit && action_repeat == 1).then_some(usize::MAX),
        fresh_world: false,
        fall_penalty,
        action_repeat,
        prev_action: false,
    })
}

fn make(id: &str, opts: &EnvOptions) -> PyResult<Box<dyn AnyEnv>> {
    rdpg_envs::make_with(id, opts).map_err(|e| value_err(format!("{id}: {e}")))
}

/// `f32`s from little-endian bytes, exactly `n` of them.
fn f32s(bytes: &[u8], n: usize, what: &str) -> PyResult<Vec<f32>> {
    if n.checked_mul(4) != Some(bytes.len()) {
        return Err(value_err(format!(
            "{what}: {} bytes, expected {n} float32 values",
            bytes.len(),
        )));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

fn f32_bytes<'py>(py: Python<'py>, v: &[f32]) -> Bound<'py, PyBytes> {
    let raw: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    PyBytes::new(py, &raw)
}

fn check_action(a: &[f32], what: &str) -> PyResult<()> {
    match a.iter().position(|x| !x.is_finite()) {
        Some(k) => Err(value_err(format!(
            "{what}: component {k} is {} (actions must be finite)",
            a[k]
        ))),
        None => Ok(()),
    }
}

/// One environment: `Env(id, reward="stock", hide_obs=[], time_limit=True, fall_penalty=None,
/// action_repeat=1)`; with `time_limit=False` it never truncates (Gymnasium's `TimeLimit`
/// wrapper does), unless `action_repeat > 1` (then the env's own limit counts frames).
/// `fall_penalty`: the reward of a fall (the stock reward stays in `step`'s last value).
#[pyclass(module = "rdpg._rdpg")]
pub struct Env {
    /// Behind a mutex only to make the class `Sync`; methods take `&mut self`.
    env: Mutex<Box<dyn AnyEnv>>,
}

impl Env {
    fn env(&mut self) -> &mut Box<dyn AnyEnv> {
        self.env.get_mut().unwrap_or_else(|p| p.into_inner())
    }
}

#[pymethods]
impl Env {
    #[new]
    #[pyo3(signature = (
        id, reward = "stock", hide_obs = Vec::new(), time_limit = true, fall_penalty = None,
        action_repeat = 1
    ))]
    fn new(
        id: &str,
        reward: &str,
        hide_obs: Vec<usize>,
        time_limit: bool,
        fall_penalty: Option<f64>,
        action_repeat: usize,
    ) -> PyResult<Self> {
        let opts = options(reward, hide_obs, time_limit, fall_penalty, action_repeat)?;
        Ok(Self {
            env: Mutex::new(make(id, &opts)?),
        })
    }

    /// `(low, high)` of the observation space, as lists.
    fn observation_bounds(&mut self) -> (Vec<f32>, Vec<f32>) {
        let s = self.env().observation_space();
        (s.low.clone(), s.high.clone())
    }

    /// `(low, high)` of the action space, as lists.
    fn action_bounds(&mut self) -> (Vec<f32>, Vec<f32>) {
        let s = self.env().action_space();
        (s.low.clone(), s.high.clone())
    }

    /// Resets (with the seed given as its little-endian 32-bit words, any size, or continuing
    /// the env's random stream): the observation bytes.
    #[pyo3(signature = (seed = None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<Vec<u32>>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let env = self.env();
        let rng = seed.map(|w| rdpg_core::NpRng::from_seed_words(&w));
        let (obs, _) = py.detach(|| env.reset_with(rng)).map_err(runtime_err)?;
        Ok(f32_bytes(py, &obs))
    }

    /// Steps with an action (float32 bytes): `(obs bytes, reward, terminated, truncated,
    /// success, stock_reward, course)`; `course` (walkers): `(obstacle at hand or None,
    /// stumps, staircases, pits passed)`.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: &[u8],
    ) -> PyResult<(
        Bound<'py, PyBytes>,
        f64,
        bool,
        bool,
        bool,
        Option<f64>,
        Option<(Option<&'static str>, u32, u32, u32)>,
    )> {
        let env = self.env();
        let a = f32s(action, env.action_space().dim(), "action")?;
        check_action(&a, "action")?;
        let s = py.detach(|| env.step(&a)).map_err(runtime_err)?;
        Ok((
            f32_bytes(py, &s.obs),
            s.reward,
            s.terminated,
            s.truncated,
            s.info.success,
            s.info.stock_reward,
            s.info.course.map(|c| {
                let [stump, stairs, pit] = c.passed;
                (c.at.map(|o| o.as_str()), stump, stairs, pit)
            }),
        ))
    }

    /// The current frame: `(rgb bytes, height, width)`.
    fn render<'py>(&mut self, py: Python<'py>) -> (Bound<'py, PyBytes>, u32, u32) {
        let scene = self.env().scene();
        let frame = py.detach(|| rdpg_render::rasterize(&scene));
        (PyBytes::new(py, &frame.rgb), frame.height, frame.width)
    }
}

/// `n` environments stepped in parallel on Rust threads, with next-step autoreset:
/// `VecEnv(id, num_envs, reward="stock", hide_obs=[], threads=None, fall_penalty=None,
/// action_repeat=1)`.
///
/// The environments live on `threads` persistent workers (`rdpg_envs::VecEnv`, at most one per
/// env; default: one per core). Autoreset follows Gymnasium's default
/// (`AutoresetMode.NEXT_STEP`): the step that ends an episode returns its last observation; the
/// next step of that env ignores its action and returns the first observation of a new episode
/// (the reset, without a seed, continues the env's random stream) with reward 0 and both flags
/// false. `reset(seed)` seeds env `i` with `seed + i`.
#[pyclass(module = "rdpg._rdpg")]
pub struct VecEnv {
    /// Behind a mutex only to make the class `Sync`; methods take `&mut self`.
    inner: Mutex<rdpg_envs::VecEnv>,
    /// The first observation of the next episode of each env whose episode ended on the
    /// previous step (handed out, instead of stepping it, on the next step).
    pending_reset: Vec<Option<Vec<f32>>>,
    obs_dim: usize,
    act_dim: usize,
}

#[pymethods]
impl VecEnv {
    #[new]
    #[pyo3(signature = (
        id, num_envs, reward = "stock", hide_obs = Vec::new(), threads = None,
        fall_penalty = None, action_repeat = 1
    ))]
    fn new(
        id: &str,
        num_envs: usize,
        reward: &str,
        hide_obs: Vec<usize>,
        threads: Option<usize>,
        fall_penalty: Option<f64>,
        action_repeat: usize,
    ) -> PyResult<Self> {
        if num_envs == 0 {
            return Err(value_err("num_envs must be at least 1"));
        }
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let workers = threads.unwrap_or(cores).clamp(1, num_envs);
        let opts = options(reward, hide_obs, true, fall_penalty, action_repeat)?;
        let inner = rdpg_envs::VecEnv::make(id, &opts, num_envs, workers)
            .map_err(|e| value_err(format!("{id}: {e}")))?;
        Ok(Self {
            obs_dim: inner.obs_dim(),
            act_dim: inner.act_dim(),
            pending_reset: vec![None; num_envs],
            inner: Mutex::new(inner),
        })
    }

    /// `(obs_dim, act_dim)`.
    fn dims(&self) -> (usize, usize) {
        (self.obs_dim, self.act_dim)
    }

    /// Resets every env (env `i` with `seed + i` when a seed is given, as its little-endian
    /// 32-bit words, any size): `[n, obs_dim]` bytes.
    #[pyo3(signature = (seed = None))]
    fn reset<'py>(
        &mut self,
        py: Python<'py>,
        seed: Option<Vec<u32>>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let inner = self.inner.get_mut().unwrap_or_else(|p| p.into_inner());
        // Without a seed, an env whose episode just ended has already been reset (unseeded)
        // inside the vector env: its pending first observation is its reset, as one reset in
        // Gymnasium. With a seed every env is reset.
        let which: Option<Vec<bool>> = seed
            .is_none()
            .then(|| self.pending_reset.iter().map(Option::is_none).collect());
        let obs = py
            .detach(|| inner.reset_some_words(seed.as_deref(), which.as_deref()))
            .map_err(runtime_err)?;
        let obs: Vec<f32> = obs
            .into_iter()
            .zip(&mut self.pending_reset)
            .flat_map(|(o, pending)| pending.take().filter(|_| o.is_empty()).unwrap_or(o))
            .collect();
        Ok(f32_bytes(py, &obs))
    }

    /// Steps every env with its row of `actions` (`[n, act_dim]` float32 bytes): `(obs
    /// [n, obs_dim] float32, rewards [n] float64, terminated [n] bool, truncated [n] bool)`,
    /// all as bytes.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: &[u8],
    ) -> PyResult<(
        Bound<'py, PyBytes>,
        Bound<'py, PyBytes>,
        Bound<'py, PyBytes>,
        Bound<'py, PyBytes>,
    )> {
        let n = self.pending_reset.len();
        let a = f32s(actions, n * self.act_dim, "actions")?;
        check_action(&a, "actions")?;
        let some: Vec<Option<Vec<f32>>> = a
            .chunks_exact(self.act_dim)
            .zip(&self.pending_reset)
            .map(|(row, pending)| pending.is_none().then(|| row.to_vec()))
            .collect();
        let inner = self.inner.get_mut().unwrap_or_else(|p| p.into_inner());
        let steps = py.detach(|| inner.step_some(&some)).map_err(runtime_err)?;
        let mut obs = Vec::with_capacity(n * self.obs_dim);
        let (mut rewards, mut term, mut trunc) = (Vec::new(), Vec::new(), Vec::new());
        for (s, pending) in steps.into_iter().zip(&mut self.pending_reset) {
            if let Some(first) = pending.take() {
                // The step after an episode's end: the new episode's first observation.
                obs.extend(first);
                rewards.extend(0f64.to_le_bytes());
                term.push(0);
                trunc.push(0);
                continue;
            }
            match s.final_obs {
                Some(last) => {
                    obs.extend(last);
                    *pending = Some(s.obs);
                }
                None => obs.extend(s.obs),
            }
            rewards.extend(s.reward.to_le_bytes());
            term.push(s.terminated as u8);
            trunc.push(s.truncated as u8);
        }
        Ok((
            f32_bytes(py, &obs),
            PyBytes::new(py, &rewards),
            PyBytes::new(py, &term),
            PyBytes::new(py, &trunc),
        ))
    }
}

/// A trained agent of a run or zoo directory, acting deterministically on full observations
/// of its environment (a run trained with hidden observation components drops them itself):
/// `Policy(path, checkpoint="best")`.
#[pyclass(module = "rdpg._rdpg", unsendable)]
pub struct Policy {
    /// A private copy of the agent's directory, which every copy of the batched form loads:
    /// all are the same agent even while a running `rdpg train` replaces the run's own.
    agent: AgentSnapshot,
    algo: Algo,
    train: TrainConfig,
    /// One copy per environment of the batched form (each keeps its own recurrent state).
    copies: Vec<Box<dyn DeterministicPolicy>>,
    /// Each copy's previous action (zeros at an episode's start), put in front of its
    /// observation when the run trained with `prev_action_obs`.
    prev: Vec<Vec<f32>>,
    obs_dim: usize,
    act_low: Vec<f32>,
    act_high: Vec<f32>,
}

impl Policy {
    /// Copy `i`'s action for a full observation of the env: the run's observation mask and
    /// previous-action input applied as in training; remembers the action.
    fn act_one(&mut self, i: usize, obs: &[f32]) -> PyResult<Vec<f32>> {
        let mut view = if self.train.prev_action_obs {
            self.prev[i].clone()
        } else {
            Vec::new()
        };
        view.extend(
            obs.iter()
                .enumerate()
                .filter(|(k, _)| !self.train.hide_obs.contains(k))
                .map(|(_, &x)| x),
        );
        let a = self.copies[i].act(&view).map_err(value_err)?;
        let a = to_env_action(&a, &self.act_low, &self.act_high);
        self.prev[i].clone_from(&a);
        Ok(a)
    }

    fn ensure_copies(&mut self, n: usize) -> PyResult<()> {
        while self.copies.len() < n {
            let p = rdpg_agents::load_policy(self.algo, &self.agent.0).map_err(value_err)?;
            self.copies.push(p);
            self.prev.push(vec![0.0; self.act_low.len()]);
        }
        Ok(())
    }
}

/// A private copy of an agent directory in the temporary directory, removed on drop.
struct AgentSnapshot(PathBuf);

impl Drop for AgentSnapshot {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl AgentSnapshot {
    /// Copies the agent directory `src` (its files and their manifest) and loads the copy; a
    /// copy torn by a run saving a new agent meanwhile fails its checksums and is taken again.
    fn take(algo: Algo, src: &Path) -> PyResult<(AgentSnapshot, Box<dyn DeterministicPolicy>)> {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        for _ in 0..5 {
            let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let snap = AgentSnapshot(
                std::env::temp_dir().join(format!("rdpg-policy-{}-{n}", std::process::id())),
            );
            let copied = std::fs::create_dir_all(&snap.0).and_then(|()| {
                for f in std::fs::read_dir(src)? {
                    let f = f?;
                    if f.file_type()?.is_file() {
                        std::fs::copy(f.path(), snap.0.join(f.file_name()))?;
                    }
                }
                Ok(())
            });
            if copied.is_ok() {
                if let Ok(p) = rdpg_agents::load_policy(algo, &snap.0) {
                    return Ok((snap, p));
                }
            }
        }
        // Not a race: the agent itself does not load, and its own error names its files.
        match rdpg_agents::load_policy(algo, src) {
            Err(e) => Err(value_err(e)),
            Ok(_) => Err(value_err(format!(
                "{} kept changing while it was copied (a run is saving new agents): try again",
                src.display()
            ))),
        }
    }
}

/// The agent directory of a zoo entry (`agent/`, its one agent: `best`) or of a run's agent
/// `checkpoint`, as `rdpg eval --checkpoint` names it: `best`, `latest`, `selected`
/// (`checkpoints/<name>/agent`) or the step of a kept agent (`checkpoints/agents/<step>/agent`).
fn agent_dir(dir: &Path, checkpoint: &str) -> PyResult<PathBuf> {
    let zoo = dir.join("agent");
    if zoo.join("agent.json").exists() && !dir.join("checkpoints").exists() {
        if checkpoint != "best" {
            return Err(value_err(format!(
                "{} is a zoo entry: it ships one agent, so drop checkpoint={checkpoint:?}",
                dir.display()
            )));
        }
        return Ok(zoo);
    }
    let ckpts = dir.join("checkpoints");
    let (which, hint) = match checkpoint {
        "best" => (ckpts.join("best"), " (no evaluation has finished yet)"),
        "latest" => (ckpts.join("latest"), ""),
        "selected" => (
            ckpts.join("selected"),
            " (run `rdpg select` on the run first)",
        ),
        step if step.parse::<u64>().is_ok() => (
            ckpts
                .join("agents")
                .join(step.parse::<u64>().unwrap_or(0).to_string()),
            " (no agent was kept at that step: see checkpoints/agents)",
        ),
        other => {
            return Err(value_err(format!(
                "checkpoint={other:?} is not an agent of a run: \"best\", \"latest\", \
                 \"selected\" or the step of a kept agent"
            )))
        }
    };
    let agent = which.join("agent");
    if !agent.exists() {
        return Err(value_err(format!(
            "{} holds no agent {checkpoint:?}{hint}: {} does not exist",
            dir.display(),
            agent.display()
        )));
    }
    Ok(agent)
}

#[pymethods]
impl Policy {
    #[new]
    #[pyo3(signature = (path, checkpoint = "best"))]
    fn new(path: PathBuf, checkpoint: &str) -> PyResult<Self> {
        let config = path.join("config.toml");
        let text = std::fs::read_to_string(&config).map_err(|e| {
            value_err(format!(
                "{}: not a run or zoo directory ({}: {e})",
                path.display(),
                config.display()
            ))
        })?;
        let bad = |e: &dyn std::fmt::Display| value_err(format!("{}: {e}", config.display()));
        let table: toml::Table = toml::from_str(&text).map_err(|e| bad(&e))?;
        let algo: Algo = table
            .get("algo")
            .cloned()
            .ok_or_else(|| bad(&"no `algo`"))?
            .try_into()
            .map_err(|e| bad(&e))?;
        let train: TrainConfig = table
            .get("train")
            .cloned()
            .ok_or_else(|| bad(&"no [train] section"))?
            .try_into()
            .map_err(|e| bad(&e))?;
        train.validate().map_err(|e| bad(&e))?;
        let env = make(&train.env, &EnvOptions::default())?;
        let (agent, mut first) = AgentSnapshot::take(algo, &agent_dir(&path, checkpoint)?)?;
        let (obs_dim, act_dim) = (env.observation_space().dim(), env.action_space().dim());
        // The agent must fit what the config says it saw: one probe action on zeros.
        let seen = (0..obs_dim).filter(|k| !train.hide_obs.contains(k)).count()
            + if train.prev_action_obs { act_dim } else { 0 };
        let probe = first.act(&vec![0.0; seen]).map_err(|e| {
            bad(&format!(
                "the agent does not fit {} as configured ({seen} inputs): {e}",
                train.env
            ))
        })?;
        if probe.len() != act_dim {
            return Err(bad(&format!(
                "the agent gives {} action values, {} takes {act_dim}",
                probe.len(),
                train.env
            )));
        }
        first.begin_episode();
        Ok(Self {
            obs_dim,
            act_low: env.action_space().low.clone(),
            act_high: env.action_space().high.clone(),
            agent,
            algo,
            train,
            copies: vec![first],
            prev: vec![vec![0.0; act_dim]],
        })
    }

    /// The environment id the agent was trained on.
    #[getter]
    fn env_id(&self) -> String {
        self.train.env.clone()
    }

    /// Frames each action was held for in training (`train.action_repeat`; 1: none): the
    /// policy expects to act at that rate.
    #[getter]
    fn action_repeat(&self) -> usize {
        self.train.action_repeat
    }

    /// The algorithm (`rdpg`, `ddpg`, `ppo`).
    #[getter]
    fn algo(&self) -> &'static str {
        self.algo.as_str()
    }

    /// Starts new episodes: zeroes every recurrent state.
    fn reset(&mut self) {
        for (c, prev) in self.copies.iter_mut().zip(&mut self.prev) {
            c.begin_episode();
            prev.fill(0.0);
        }
    }

    /// The action (float32 bytes, within the env's bounds) for one observation.
    fn act<'py>(&mut self, py: Python<'py>, obs: &[u8]) -> PyResult<Bound<'py, PyBytes>> {
        let a = self.act_one(0, &f32s(obs, self.obs_dim, "observation")?)?;
        Ok(f32_bytes(py, &a))
    }

    /// Actions for `n` environments (`[n, obs_dim]` float32 bytes), each with its own state.
    fn act_batch<'py>(
        &mut self,
        py: Python<'py>,
        obs: &[u8],
        n: usize,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let values = n
            .checked_mul(self.obs_dim)
            .ok_or_else(|| value_err(format!("act_batch: {n} environments is too many")))?;
        let all = f32s(obs, values, "observations")?;
        self.ensure_copies(n)?;
        let mut out = Vec::with_capacity(n * self.act_low.len());
        for (i, row) in all.chunks_exact(self.obs_dim).enumerate() {
            out.extend(self.act_one(i, row)?);
        }
        Ok(f32_bytes(py, &out))
    }

    /// Zeroes the recurrent state of environment `i` of the batched form (its episode ended);
    /// an environment the batched form has not acted for yet starts fresh anyway.
    fn reset_one(&mut self, i: usize) {
        if let (Some(c), Some(prev)) = (self.copies.get_mut(i), self.prev.get_mut(i)) {
            c.begin_episode();
            prev.fill(0.0);
        }
    }
}

/// The environment ids this build provides.
#[pyfunction]
fn env_ids() -> Vec<&'static str> {
    rdpg_envs::ENV_IDS.to_vec()
}

/// The Python module.
#[pymodule]
fn _rdpg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Env>()?;
    m.add_class::<VecEnv>()?;
    m.add_class::<Policy>()?;
    m.add_function(wrap_pyfunction!(env_ids, m)?)?;
    Ok(())
}
