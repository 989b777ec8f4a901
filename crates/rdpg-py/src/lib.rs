//! `rdpg._rdpg`: the Rust side of the `rdpg` Python package.
//!
//! Two classes, wrapped by `python/rdpg/__init__.py` into Gymnasium's API:
//! - [`Env`]: one registered environment (`rdpg_envs::make_with`), stepped with the GIL
//!   released;
//! - [`VecEnv`]: `n` environments stepped in parallel on persistent Rust worker threads (GIL
//!   released), with Gymnasium's *next-step* (default) or *same-step* autoreset.
//!
//! No libtorch: trained policies are the `rdpg._policy` module (crate `rdpg-py-policy`), so
//! that `import rdpg` and the environments load none.
//!
//! Arrays cross the boundary as `bytes` of little-endian `f32` (observations, actions) or
//! `f64` (rewards); the Python side views them with `numpy.frombuffer`, without copies of
//! Python objects per element. Every error is a Python exception carrying the Rust message.

// Python gets an exception with the Rust message, never a PanicException.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

mod bytes;

use std::sync::Mutex;

use bytes::{f32_bytes, f32s, value_err};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use rdpg_envs::registry::AnyEnv;
use rdpg_envs::{EnvOptions, Renderable, WalkerReward};

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
        frame_stack: 1,
    })
}

fn make(id: &str, opts: &EnvOptions) -> PyResult<Box<dyn AnyEnv>> {
    rdpg_envs::make_with(id, opts).map_err(|e| value_err(format!("{id}: {e}")))
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

/// A step's info as Python takes it: `(success, stock_reward, course)`; `course` (walkers):
/// `(obstacle at hand or None, stumps, staircases, pits passed)`.
type PyInfo = (
    bool,
    Option<f64>,
    Option<(Option<&'static str>, u32, u32, u32)>,
);

fn py_info(info: &rdpg_core::EnvInfo) -> PyInfo {
    (
        info.success,
        info.stock_reward,
        info.course.map(|c| {
            let [stump, stairs, pit] = c.passed;
            (c.at.map(|o| o.as_str()), stump, stairs, pit)
        }),
    )
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
    /// info)`, `info` as `(success, stock_reward, course)`; `course` (walkers): `(obstacle at
    /// hand or None, stumps, staircases, pits passed)`.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        action: &[u8],
    ) -> PyResult<(Bound<'py, PyBytes>, f64, bool, bool, PyInfo)> {
        let env = self.env();
        let a = f32s(action, env.action_space().dim(), "action")?;
        check_action(&a, "action")?;
        let s = py.detach(|| env.step(&a)).map_err(runtime_err)?;
        Ok((
            f32_bytes(py, &s.obs),
            s.reward,
            s.terminated,
            s.truncated,
            py_info(&s.info),
        ))
    }

    /// The current frame: `(rgb bytes, height, width)`.
    fn render<'py>(&mut self, py: Python<'py>) -> (Bound<'py, PyBytes>, u32, u32) {
        let scene = self.env().scene();
        let frame = py.detach(|| rdpg_render::rasterize(&scene));
        (PyBytes::new(py, &frame.rgb), frame.height, frame.width)
    }
}

/// `n` environments stepped in parallel on Rust threads, with autoreset: `VecEnv(id,
/// num_envs, reward="stock", hide_obs=[], threads=None, fall_penalty=None, action_repeat=1,
/// same_step=False)`.
///
/// The environments live on `threads` persistent workers (`rdpg_envs::VecEnv`, at most one per
/// env; default: one per core). Autoreset follows Gymnasium's `AutoresetMode.NEXT_STEP` (the
/// default): the step that ends an episode returns its last observation; the next step of that
/// env ignores its action and returns the first observation of a new episode (the reset,
/// without a seed, continues the env's random stream) with reward 0 and both flags false. With
/// `same_step` (`AutoresetMode.SAME_STEP`) the step that ends an episode returns the new
/// episode's first observation, the last one among its final observations. `reset(seed)`
/// seeds env `i` with `seed + i`.
#[pyclass(module = "rdpg._rdpg")]
pub struct VecEnv {
    /// Behind a mutex only to make the class `Sync`; methods take `&mut self`.
    inner: Mutex<rdpg_envs::VecEnv>,
    /// The first observation of the next episode of each env whose episode ended on the
    /// previous step (handed out, instead of stepping it, on the next step).
    pending_reset: Vec<Option<Vec<f32>>>,
    /// Same-step autoreset (else next-step).
    same_step: bool,
    obs_dim: usize,
    act_dim: usize,
}

#[pymethods]
impl VecEnv {
    #[new]
    #[pyo3(signature = (
        id, num_envs, reward = "stock", hide_obs = Vec::new(), threads = None,
        fall_penalty = None, action_repeat = 1, same_step = false
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        id: &str,
        num_envs: usize,
        reward: &str,
        hide_obs: Vec<usize>,
        threads: Option<usize>,
        fall_penalty: Option<f64>,
        action_repeat: usize,
        same_step: bool,
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
            same_step,
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
    /// all as bytes, then each env's step info (`(success, stock_reward, course)`, as `Env`
    /// gives it; None for an env that only reset) and, with same-step autoreset, the final
    /// observation (float32 bytes) of each env whose episode ended, else None.
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
        Vec<Option<PyInfo>>,
        Vec<Option<Bound<'py, PyBytes>>>,
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
        let (mut infos, mut finals) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for (s, pending) in steps.into_iter().zip(&mut self.pending_reset) {
            if let Some(first) = pending.take() {
                // The step after an episode's end: the new episode's first observation.
                obs.extend(first);
                rewards.extend(0f64.to_le_bytes());
                term.push(0);
                trunc.push(0);
                infos.push(None);
                finals.push(None);
                continue;
            }
            match s.final_obs {
                Some(last) if self.same_step => {
                    obs.extend(s.obs);
                    finals.push(Some(f32_bytes(py, &last)));
                }
                Some(last) => {
                    obs.extend(last);
                    *pending = Some(s.obs);
                    finals.push(None);
                }
                None => {
                    obs.extend(s.obs);
                    finals.push(None);
                }
            }
            rewards.extend(s.reward.to_le_bytes());
            term.push(s.terminated as u8);
            trunc.push(s.truncated as u8);
            infos.push(Some(py_info(&s.info)));
        }
        Ok((
            f32_bytes(py, &obs),
            PyBytes::new(py, &rewards),
            PyBytes::new(py, &term),
            PyBytes::new(py, &trunc),
            infos,
            finals,
        ))
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
    m.add_function(wrap_pyfunction!(env_ids, m)?)?;
    Ok(())
}
