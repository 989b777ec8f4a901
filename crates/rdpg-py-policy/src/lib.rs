//! `rdpg._policy`: trained agents for the `rdpg` Python package.
//!
//! Its own extension module because it links libtorch: `import rdpg` and the environments
//! (`rdpg._rdpg`) load none; `rdpg.Policy` imports this module (after torch, which loads the
//! libtorch it links) the first time a policy is loaded. One class, [`Policy`], wrapped by
//! `python/rdpg/policy.py`. Arrays cross the boundary as `bytes` of little-endian `f32`.

// Python gets an exception with the Rust message, never a PanicException.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

#[path = "../../rdpg-py/src/bytes.rs"]
mod bytes;

use std::path::{Path, PathBuf};

use bytes::{f32_bytes, f32s, value_err};
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use rdpg_agents::common::to_env_action;
use rdpg_agents::{Algo, DeterministicPolicy, TrainConfig};
use rdpg_envs::EnvOptions;

/// One acting copy of the agent: its recurrent state inside, its previous action (zeros at an
/// episode's start), put in front of the observation when the run trained with
/// `prev_action_obs`, and its last `frame_stack - 1` views (zeros before the episode's first),
/// put before the current one when the run trained with a frame stack.
struct Actor {
    policy: Box<dyn DeterministicPolicy>,
    prev: Vec<f32>,
    /// The earlier views of the frame stack, oldest first (empty without one).
    history: Vec<f32>,
}

impl Actor {
    /// A fresh copy of the agent in `dir`, for actions of `act_dim` values with `history`
    /// values of earlier views, remembering at most `memory` observations when given.
    fn load(
        algo: Algo,
        dir: &Path,
        act_dim: usize,
        history: usize,
        memory: Option<usize>,
    ) -> PyResult<Self> {
        let mut policy = rdpg_agents::load_policy(algo, dir).map_err(value_err)?;
        limit(policy.as_mut(), memory)?;
        Ok(Self::new(policy, act_dim, history))
    }

    fn new(policy: Box<dyn DeterministicPolicy>, act_dim: usize, history: usize) -> Self {
        Self {
            policy,
            prev: vec![0.0; act_dim],
            history: vec![0.0; history],
        }
    }

    fn begin_episode(&mut self) {
        self.policy.begin_episode();
        self.prev.fill(0.0);
        self.history.fill(0.0);
    }

    /// The state `act_states` passes around besides the agent's own: the previous action
    /// (with `prev_action_obs`), then the earlier views.
    fn view_state(&self, train: &TrainConfig) -> Vec<f32> {
        let mut out = if train.prev_action_obs {
            self.prev.clone()
        } else {
            Vec::new()
        };
        out.extend_from_slice(&self.history);
        out
    }
}

/// Limits `policy` to its last `memory` observations from its next episode on
/// ([`DeterministicPolicy::limit_memory`]), then starts one.
fn limit(policy: &mut dyn DeterministicPolicy, memory: Option<usize>) -> PyResult<()> {
    if let Some(k) = memory {
        policy
            .limit_memory(k)
            .map_err(|e| value_err(format!("memory={k}: {e}")))?;
        policy.begin_episode();
    }
    Ok(())
}

/// A trained agent of a run or zoo directory, acting deterministically on full observations
/// of its environment (a run trained with hidden observation components drops them itself):
/// `Policy(path, checkpoint="best", memory=None)`; `memory = k`: a recurrent agent
/// remembering at most its last `k` observations (`rdpg eval --memory`).
///
/// Three kinds of acting, each with its own states: `act` (one environment), `act_batch`
/// (environment `i` of a vector env on copy `i`), and `act_states` (the state passed in and
/// returned, for `predict`).
#[pyclass(module = "rdpg._policy", unsendable)]
pub struct Policy {
    /// A private copy of the agent's directory, which every copy loads: all are the same agent
    /// even while a running `rdpg train` replaces the run's own.
    agent: AgentSnapshot,
    algo: Algo,
    train: TrainConfig,
    /// `act`'s copy.
    single: Actor,
    /// `act_batch`'s copies, one per environment.
    batch: Vec<Actor>,
    /// `act_states`'s copy: set to each row's state, acted with, read back.
    scratch: Actor,
    /// The observations every copy remembers at most (`None`: the whole episode).
    memory: Option<usize>,
    /// Values of the agent's own state (0: a stateless agent).
    carried: usize,
    obs_dim: usize,
    act_low: Vec<f32>,
    act_high: Vec<f32>,
}

impl Policy {
    /// `actor`'s action for a full observation of the env: the run's observation mask,
    /// previous-action input and frame stack applied as in training; remembers the action and
    /// the view.
    fn act_one(
        train: &TrainConfig,
        low: &[f32],
        high: &[f32],
        actor: &mut Actor,
        obs: &[f32],
    ) -> PyResult<Vec<f32>> {
        let mut view = if train.prev_action_obs {
            actor.prev.clone()
        } else {
            Vec::new()
        };
        view.extend(
            obs.iter()
                .enumerate()
                .filter(|(k, _)| !train.hide_obs.contains(k))
                .map(|(_, &x)| x),
        );
        let a = if actor.history.is_empty() {
            actor.policy.act(&view)
        } else {
            let stacked = [actor.history.as_slice(), &view].concat();
            rdpg_envs::wrappers::push_view(&mut actor.history, &view);
            actor.policy.act(&stacked)
        }
        .map_err(value_err)?;
        let a = to_env_action(&a, low, high);
        actor.prev.clone_from(&a);
        Ok(a)
    }

    /// Values of one environment's state in `act_states`: the previous action (with
    /// `prev_action_obs`), the earlier views of the frame stack, then the agent's own carried
    /// state.
    fn state_len(&self) -> usize {
        let prev = if self.train.prev_action_obs {
            self.act_low.len()
        } else {
            0
        };
        prev + self.single.history.len() + self.carried
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
    #[pyo3(signature = (path, checkpoint = "best", memory = None))]
    fn new(path: PathBuf, checkpoint: &str, memory: Option<usize>) -> PyResult<Self> {
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
        let env = rdpg_envs::make_with(&train.env, &EnvOptions::default())
            .map_err(|e| value_err(format!("{}: {e}", train.env)))?;
        let (agent, mut first) = AgentSnapshot::take(algo, &agent_dir(&path, checkpoint)?)?;
        limit(first.as_mut(), memory)?;
        let (obs_dim, act_dim) = (env.observation_space().dim(), env.action_space().dim());
        // The agent must fit what the config says it saw: one probe action on zeros.
        let view = (0..obs_dim).filter(|k| !train.hide_obs.contains(k)).count()
            + if train.prev_action_obs { act_dim } else { 0 };
        let seen = view * train.frame_stack;
        let history = seen - view;
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
        let carried = first.state().len();
        let scratch = Actor::load(algo, &agent.0, act_dim, history, memory)?;
        Ok(Self {
            obs_dim,
            act_low: env.action_space().low.clone(),
            act_high: env.action_space().high.clone(),
            agent,
            algo,
            train,
            carried,
            single: Actor::new(first, act_dim, history),
            batch: Vec::new(),
            scratch,
            memory,
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

    /// The private copy of the agent's directory this policy acts with (what `to_torch`
    /// reads: the same agent even while a run saves new ones).
    #[getter]
    fn agent_dir(&self) -> PathBuf {
        self.agent.0.clone()
    }

    /// Values of one environment's state in `act_states` (0: the policy carries nothing).
    #[getter(state_len)]
    fn py_state_len(&self) -> usize {
        self.state_len()
    }

    /// Starts a new episode for `act` and for every environment of `act_batch`.
    fn reset(&mut self) {
        self.single.begin_episode();
        for a in &mut self.batch {
            a.begin_episode();
        }
    }

    /// The action (float32 bytes, within the env's bounds) for one observation, continuing
    /// `act`'s own state.
    fn act<'py>(&mut self, py: Python<'py>, obs: &[u8]) -> PyResult<Bound<'py, PyBytes>> {
        let obs = f32s(obs, self.obs_dim, "observation")?;
        let a = Self::act_one(
            &self.train,
            &self.act_low,
            &self.act_high,
            &mut self.single,
            &obs,
        )?;
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
        while self.batch.len() < n {
            let a = Actor::load(
                self.algo,
                &self.agent.0,
                self.act_low.len(),
                self.single.history.len(),
                self.memory,
            )?;
            self.batch.push(a);
        }
        let mut out = Vec::with_capacity(n * self.act_low.len());
        for (row, actor) in all.chunks_exact(self.obs_dim).zip(&mut self.batch) {
            out.extend(Self::act_one(
                &self.train,
                &self.act_low,
                &self.act_high,
                actor,
                row,
            )?);
        }
        Ok(f32_bytes(py, &out))
    }

    /// Starts a new episode for environment `i` of `act_batch`; an environment it has not
    /// acted for yet starts fresh anyway.
    fn reset_one(&mut self, i: usize) {
        if let Some(a) = self.batch.get_mut(i) {
            a.begin_episode();
        }
    }

    /// Actions for `n` environments from explicit states: `obs` `[n, obs_dim]`, `states`
    /// `[n, state_len]` (float32 bytes, or None: every environment starts an episode),
    /// `starts[i]`: environment `i` starts an episode (its state is ignored). Returns
    /// `(actions [n, act_dim], states [n, state_len])` as bytes; no other state changes.
    #[pyo3(signature = (obs, n, states, starts))]
    fn act_states<'py>(
        &mut self,
        py: Python<'py>,
        obs: &[u8],
        n: usize,
        states: Option<&[u8]>,
        starts: Vec<bool>,
    ) -> PyResult<(Bound<'py, PyBytes>, Bound<'py, PyBytes>)> {
        let width = self.state_len();
        let too_many = || value_err(format!("act_states: {n} environments is too many"));
        let all = f32s(
            obs,
            n.checked_mul(self.obs_dim).ok_or_else(too_many)?,
            "observations",
        )?;
        let states = match states {
            Some(b) => Some(f32s(
                b,
                n.checked_mul(width).ok_or_else(too_many)?,
                "states",
            )?),
            None => None,
        };
        if starts.len() != n {
            return Err(value_err(format!(
                "episode_start: {} values for {n} environments",
                starts.len()
            )));
        }
        let prev = if self.train.prev_action_obs {
            self.act_low.len()
        } else {
            0
        };
        let views = width - self.carried;
        let (mut actions, mut out) = (Vec::with_capacity(n * self.act_low.len()), Vec::new());
        for (i, row) in all.chunks_exact(self.obs_dim).enumerate() {
            match &states {
                Some(s) if !starts[i] => {
                    let st = &s[i * width..(i + 1) * width];
                    if let Some(k) = st[..views].iter().position(|x| !x.is_finite()) {
                        return Err(value_err(format!(
                            "state of environment {i}: value {k} is {}",
                            st[k]
                        )));
                    }
                    if prev > 0 {
                        self.scratch.prev.copy_from_slice(&st[..prev]);
                    }
                    self.scratch.history.copy_from_slice(&st[prev..views]);
                    self.scratch
                        .policy
                        .set_state(&st[views..])
                        .map_err(|e| value_err(format!("state of environment {i}: {e}")))?;
                }
                _ => self.scratch.begin_episode(),
            }
            actions.extend(Self::act_one(
                &self.train,
                &self.act_low,
                &self.act_high,
                &mut self.scratch,
                row,
            )?);
            out.extend(self.scratch.view_state(&self.train));
            out.extend(self.scratch.policy.state());
        }
        Ok((f32_bytes(py, &actions), f32_bytes(py, &out)))
    }
}

/// The Python module.
#[pymodule]
fn _policy(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Policy>()?;
    Ok(())
}
