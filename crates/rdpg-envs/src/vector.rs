//! A vector of environments stepped in parallel on worker threads, with automatic reset.
//!
//! Environment `i` is reset with seed `seed + i` (as Gymnasium's vector envs do) and, when its
//! episode ends, reset again without a seed (continuing its own random stream), in the same
//! step (Gymnasium's "same-step" autoreset): the returned observation is the first of the new
//! episode and the last observation of the finished one is in [`VecStep::final_obs`]. Each
//! environment lives on one worker for its whole life, so results do not depend on the number
//! of workers and equal those of N sequential environments with the same seeds.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use rdpg_core::{EnvError, EnvInfo};

use crate::registry::AnyEnv;

/// One environment's result of [`VecEnv::step`].
#[derive(Debug, Clone, PartialEq)]
pub struct VecStep {
    /// Observation to act on next (the reset observation if the episode ended).
    pub obs: Vec<f32>,
    /// Reward of the transition.
    pub reward: f64,
    /// The episode reached a terminal state.
    pub terminated: bool,
    /// The episode was cut by the time limit.
    pub truncated: bool,
    /// Last observation of the finished episode, when it ended on this step.
    pub final_obs: Option<Vec<f32>>,
    /// Info of the transition.
    pub info: EnvInfo,
}

enum Cmd {
    Reset(Option<u64>),
    Step(Vec<Vec<f32>>),
}

type Reply = Result<Vec<VecStep>, EnvError>;

struct Worker {
    tx: Option<Sender<Cmd>>,
    rx: Receiver<Reply>,
    handle: Option<JoinHandle<()>>,
    count: usize,
}

/// N environments on W worker threads.
pub struct VecEnv {
    workers: Vec<Worker>,
    num_envs: usize,
    obs_dim: usize,
    act_dim: usize,
}

impl VecEnv {
    /// Distributes `envs` over `workers` threads (at most one per env, at least one).
    pub fn new(envs: Vec<Box<dyn AnyEnv>>, workers: usize) -> Result<Self, EnvError> {
        if envs.is_empty() {
            return Err(EnvError::Config(
                "a vector env needs at least one env".into(),
            ));
        }
        let num_envs = envs.len();
        let obs_dim = envs[0].observation_space().dim();
        let act_dim = envs[0].action_space().dim();
        if envs
            .iter()
            .any(|e| e.observation_space().dim() != obs_dim || e.action_space().dim() != act_dim)
        {
            return Err(EnvError::Config(
                "all envs of a vector env need the same spaces".into(),
            ));
        }
        let w = workers.clamp(1, num_envs);
        let mut chunks: Vec<Vec<Box<dyn AnyEnv>>> = (0..w).map(|_| Vec::new()).collect();
        for (i, env) in envs.into_iter().enumerate() {
            chunks[i * w / num_envs].push(env);
        }
        let mut offset = 0u64;
        let workers = chunks
            .into_iter()
            .map(|chunk| {
                let (tx, crx) = channel::<Cmd>();
                let (ctx, rx) = channel::<Reply>();
                let count = chunk.len();
                let first = offset;
                offset += count as u64;
                let handle = std::thread::Builder::new()
                    .name("rdpg-vecenv".into())
                    .spawn(move || worker_loop(chunk, first, crx, ctx))
                    .map_err(|e| EnvError::Config(format!("cannot spawn worker thread: {e}")))?;
                Ok(Worker {
                    tx: Some(tx),
                    rx,
                    handle: Some(handle),
                    count,
                })
            })
            .collect::<Result<Vec<_>, EnvError>>()?;
        Ok(Self {
            workers,
            num_envs,
            obs_dim,
            act_dim,
        })
    }

    /// `n` copies of the registered environment `id` (see [`crate::make_with`]).
    pub fn make(
        id: &str,
        opts: &crate::EnvOptions,
        n: usize,
        workers: usize,
    ) -> Result<Self, EnvError> {
        let envs = (0..n)
            .map(|_| crate::make_with(id, opts))
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(envs, workers)
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.num_envs
    }

    /// Observation size.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Action size.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }

    /// Resets every environment, env `i` with seed `seed + i` (or unseeded); returns the
    /// observations.
    pub fn reset(&mut self, seed: Option<u64>) -> Result<Vec<Vec<f32>>, EnvError> {
        for w in &self.workers {
            send(w, Cmd::Reset(seed))?;
        }
        Ok(self.collect()?.into_iter().map(|s| s.obs).collect())
    }

    /// Steps every environment with its action (`actions.len() == num_envs`).
    pub fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<VecStep>, EnvError> {
        if actions.len() != self.num_envs {
            return Err(EnvError::Config(format!(
                "{} actions for {} envs",
                actions.len(),
                self.num_envs
            )));
        }
        let mut start = 0;
        for w in &self.workers {
            send(w, Cmd::Step(actions[start..start + w.count].to_vec()))?;
            start += w.count;
        }
        self.collect()
    }

    fn collect(&self) -> Result<Vec<VecStep>, EnvError> {
        let mut out = Vec::with_capacity(self.num_envs);
        let mut first_err = None;
        for w in &self.workers {
            match w.rx.recv() {
                Ok(Ok(steps)) => out.extend(steps),
                Ok(Err(e)) => {
                    first_err.get_or_insert(e);
                }
                Err(_) => {
                    first_err.get_or_insert(EnvError::Physics("vector env worker died".into()));
                }
            }
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }
}

fn send(w: &Worker, cmd: Cmd) -> Result<(), EnvError> {
    w.tx.as_ref()
        .expect("sender lives until drop")
        .send(cmd)
        .map_err(|_| EnvError::Physics("vector env worker died".into()))
}

fn worker_loop(mut envs: Vec<Box<dyn AnyEnv>>, first: u64, rx: Receiver<Cmd>, tx: Sender<Reply>) {
    while let Ok(cmd) = rx.recv() {
        let reply = match cmd {
            Cmd::Reset(seed) => envs
                .iter_mut()
                .enumerate()
                .map(|(i, env)| {
                    let (obs, info) = env.reset(seed.map(|s| s.wrapping_add(first + i as u64)))?;
                    Ok(VecStep {
                        obs,
                        reward: 0.0,
                        terminated: false,
                        truncated: false,
                        final_obs: None,
                        info,
                    })
                })
                .collect(),
            Cmd::Step(actions) => envs
                .iter_mut()
                .zip(actions)
                .map(|(env, a)| {
                    let s = env.step(&a)?;
                    let done = s.done();
                    let mut out = VecStep {
                        obs: s.obs,
                        reward: s.reward,
                        terminated: s.terminated,
                        truncated: s.truncated,
                        final_obs: None,
                        info: s.info,
                    };
                    if done {
                        let (obs, _) = env.reset(None)?;
                        out.final_obs = Some(std::mem::replace(&mut out.obs, obs));
                    }
                    Ok(out)
                })
                .collect(),
        };
        if tx.send(reply).is_err() {
            return;
        }
    }
}

impl Drop for VecEnv {
    fn drop(&mut self) {
        for w in &mut self.workers {
            drop(w.tx.take());
            if let Some(h) = w.handle.take() {
                let _ = h.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{make, EnvOptions};
    use rdpg_core::Env;

    fn actions(t: usize, n: usize) -> Vec<Vec<f32>> {
        (0..n)
            .map(|i| {
                (0..4)
                    .map(|j| (((t * 7 + i * 3 + j * 5) % 11) as f32 / 5.0) - 1.0)
                    .collect()
            })
            .collect()
    }

    #[test]
    fn parallel_equals_sequential_with_autoreset() {
        let n = 3;
        let opts = EnvOptions {
            max_episode_steps: Some(60),
            ..Default::default()
        };
        let mut vec = VecEnv::make("BipedalWalker-v3", &opts, n, 2).unwrap();
        let mut seq: Vec<_> = (0..n)
            .map(|_| crate::make_with("BipedalWalker-v3", &opts).unwrap())
            .collect();
        let v0 = vec.reset(Some(10)).unwrap();
        for (i, env) in seq.iter_mut().enumerate() {
            assert_eq!(env.reset(Some(10 + i as u64)).unwrap().0, v0[i]);
        }
        let mut ended = 0;
        for t in 0..150 {
            let acts = actions(t, n);
            let vs = vec.step(&acts).unwrap();
            for (i, env) in seq.iter_mut().enumerate() {
                let s = env.step(&acts[i]).unwrap();
                assert_eq!(vs[i].reward, s.reward);
                assert_eq!(
                    (vs[i].terminated, vs[i].truncated),
                    (s.terminated, s.truncated)
                );
                if s.done() {
                    ended += 1;
                    assert_eq!(vs[i].final_obs.as_ref(), Some(&s.obs));
                    assert_eq!(vs[i].obs, env.reset(None).unwrap().0);
                } else {
                    assert_eq!(vs[i].obs, s.obs);
                }
            }
        }
        assert!(ended >= n, "episodes should have ended and auto-reset");
    }

    #[test]
    fn wrong_action_count_is_an_error() {
        let mut vec = VecEnv::new(vec![make("Pendulum-v1").unwrap()], 4).unwrap();
        vec.reset(Some(0)).unwrap();
        assert!(vec.step(&[]).is_err());
        assert!(vec.step(&[vec![f32::NAN]]).is_err());
    }
}
