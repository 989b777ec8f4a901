//! A vector of environments stepped in parallel on worker threads, with automatic reset.
//!
//! Environment `i` is reset with seed `seed + i` (as Gymnasium's vector envs do) and, when its
//! episode ends, reset again without a seed (continuing its own random stream), in the same
//! step (Gymnasium's "same-step" autoreset): the returned observation is the first of the new
//! episode and the last observation of the finished one is in [`VecStep::final_obs`]. Each
//! environment lives on one worker for its whole life, so results do not depend on the number
//! of workers and equal those of N sequential environments with the same seeds.
//!
//! With a *seed schedule* ([`VecEnv::reset_scheduled`]) every episode instead gets its own seed,
//! [`episode_seed`]`(base, i, k)` for the `k`-th episode of env `i`, so that any episode can be
//! rebuilt from `(base, i, k)` and its actions alone ([`VecEnv::restore`]): this is how training
//! checkpoints resume mid-episode with bit-identical environments.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;

use rdpg_core::rng::{seed_words, seed_words_plus};
use rdpg_core::spin::recv_spin;
use rdpg_core::{EnvError, EnvInfo, NpRng};

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
    /// Reset with `seed + i` (the seed as its 32-bit words), only the envs whose flag is set
    /// (all when `None`).
    Reset(Option<Vec<u32>>, Option<Vec<bool>>),
    ResetScheduled(u64, Vec<u64>),
    /// One action per env; `None` leaves that env untouched.
    Step(Vec<Option<Vec<f32>>>),
    Restore(usize, u64, Vec<Vec<f32>>),
}

/// Seed of episode `k` of env `i` under the seed schedule `base` (a SplitMix64 mix, masked to
/// 63 bits so that it is also a valid seed for Python tools).
pub fn episode_seed(base: u64, env: usize, k: u64) -> u64 {
    let mut z = base
        ^ (env as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ k.wrapping_mul(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) >> 1
}

type Reply = Result<Vec<VecStep>, EnvError>;

enum Link {
    /// A shard on its own thread.
    Remote {
        tx: Option<Sender<Cmd>>,
        rx: Receiver<Reply>,
        handle: Option<JoinHandle<()>>,
    },
    /// The last shard, run on the calling thread after the remote ones were sent their work.
    Local {
        shard: Shard,
        pending: Option<Reply>,
    },
}

struct Worker {
    link: Link,
    count: usize,
}

/// N environments on W threads (W - 1 workers plus the calling thread).
pub struct VecEnv {
    workers: Vec<Worker>,
    schedule: Option<u64>,
    episode_index: Vec<u64>,
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
        let last = chunks.len() - 1;
        let workers = chunks
            .into_iter()
            .enumerate()
            .map(|(k, envs)| {
                let count = envs.len();
                let shard = Shard {
                    envs,
                    first: offset,
                    schedule: None,
                };
                offset += count as u64;
                if k == last {
                    return Ok(Worker {
                        link: Link::Local {
                            shard,
                            pending: None,
                        },
                        count,
                    });
                }
                let (tx, crx) = channel::<Cmd>();
                let (ctx, rx) = channel::<Reply>();
                let handle = std::thread::Builder::new()
                    .name("rdpg-vecenv".into())
                    .spawn(move || worker_loop(shard, crx, ctx))
                    .map_err(|e| EnvError::Config(format!("cannot spawn worker thread: {e}")))?;
                Ok(Worker {
                    link: Link::Remote {
                        tx: Some(tx),
                        rx,
                        handle: Some(handle),
                    },
                    count,
                })
            })
            .collect::<Result<Vec<_>, EnvError>>()?;
        Ok(Self {
            workers,
            schedule: None,
            episode_index: vec![0; num_envs],
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
        self.reset_some(seed, None)
    }

    /// [`VecEnv::reset`] of the environments flagged in `which` only (all when `None`); the
    /// others are left untouched and their observation is empty.
    pub fn reset_some(
        &mut self,
        seed: Option<u64>,
        which: Option<&[bool]>,
    ) -> Result<Vec<Vec<f32>>, EnvError> {
        self.reset_some_words(seed.map(seed_words).as_deref(), which)
    }

    /// [`VecEnv::reset_some`] for a seed of any size, given as its little-endian 32-bit words
    /// (Gymnasium accepts any non-negative integer; env `i` gets `seed + i`).
    pub fn reset_some_words(
        &mut self,
        seed: Option<&[u32]>,
        which: Option<&[bool]>,
    ) -> Result<Vec<Vec<f32>>, EnvError> {
        if which.is_some_and(|w| w.len() != self.num_envs) {
            return Err(EnvError::Config(format!(
                "reset flags for {} envs",
                self.num_envs
            )));
        }
        self.schedule = None;
        let mut start = 0;
        for w in &mut self.workers {
            let flags = which.map(|f| f[start..start + w.count].to_vec());
            send(w, Cmd::Reset(seed.map(<[u32]>::to_vec), flags))?;
            start += w.count;
        }
        Ok(self.collect()?.into_iter().map(|s| s.obs).collect())
    }

    /// Resets every environment under the seed schedule `base`, env `i` starting at its episode
    /// `episodes[i]` (all zeros for a fresh start); later auto-resets continue the schedule.
    pub fn reset_scheduled(
        &mut self,
        base: u64,
        episodes: &[u64],
    ) -> Result<Vec<Vec<f32>>, EnvError> {
        if episodes.len() != self.num_envs {
            return Err(EnvError::Config(format!(
                "{} episode indices for {} envs",
                episodes.len(),
                self.num_envs
            )));
        }
        let mut start = 0;
        for w in &mut self.workers {
            send(
                w,
                Cmd::ResetScheduled(base, episodes[start..start + w.count].to_vec()),
            )?;
            start += w.count;
        }
        self.schedule = Some(base);
        self.episode_index = episodes.to_vec();
        Ok(self.collect()?.into_iter().map(|s| s.obs).collect())
    }

    /// Episode index of every env under the seed schedule (0 before any scheduled reset).
    pub fn episode_indices(&mut self) -> Vec<u64> {
        self.episode_index.clone()
    }

    /// Rebuilds env `env`'s current episode: resets it with the schedule's seed for its current
    /// episode index and replays `actions`; returns the observation after them.
    #[allow(
        clippy::expect_used,
        reason = "a worker answers a one-env command with one step"
    )]
    pub fn restore(&mut self, env: usize, actions: Vec<Vec<f32>>) -> Result<Vec<f32>, EnvError> {
        let base = self
            .schedule
            .ok_or_else(|| EnvError::Config("restore needs a seed schedule".into()))?;
        let mut start = 0;
        for w in &mut self.workers {
            if env < start + w.count {
                send(w, Cmd::Restore(env - start, base, actions))?;
                return receive(w).map(|mut v| v.pop().expect("one step").obs);
            }
            start += w.count;
        }
        Err(EnvError::Config(format!(
            "env {env} out of range ({} envs)",
            self.num_envs
        )))
    }

    /// Steps every environment with its action (`actions.len() == num_envs`).
    pub fn step(&mut self, actions: &[Vec<f32>]) -> Result<Vec<VecStep>, EnvError> {
        let some: Vec<Option<Vec<f32>>> = actions.iter().cloned().map(Some).collect();
        self.step_some(&some)
    }

    /// Steps the environments whose action is given and leaves the others untouched: their
    /// result is an empty placeholder (no observation, reward 0, both flags false). This is
    /// what Gymnasium's next-step autoreset needs (the step after an episode's end is not
    /// taken in that environment).
    pub fn step_some(&mut self, actions: &[Option<Vec<f32>>]) -> Result<Vec<VecStep>, EnvError> {
        if actions.len() != self.num_envs {
            return Err(EnvError::Config(format!(
                "{} actions for {} envs",
                actions.len(),
                self.num_envs
            )));
        }
        let mut start = 0;
        for w in &mut self.workers {
            send(w, Cmd::Step(actions[start..start + w.count].to_vec()))?;
            start += w.count;
        }
        let steps = self.collect()?;
        if self.schedule.is_some() {
            for (k, s) in self.episode_index.iter_mut().zip(&steps) {
                *k += s.final_obs.is_some() as u64;
            }
        }
        Ok(steps)
    }

    fn collect(&mut self) -> Result<Vec<VecStep>, EnvError> {
        let mut out = Vec::with_capacity(self.num_envs);
        let mut first_err = None;
        for w in &mut self.workers {
            match receive(w) {
                Ok(steps) => out.extend(steps),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        match first_err {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }
}

#[allow(clippy::expect_used, reason = "the sender is dropped only in Drop")]
fn send(w: &mut Worker, cmd: Cmd) -> Result<(), EnvError> {
    match &mut w.link {
        Link::Remote { tx, .. } => tx
            .as_ref()
            .expect("sender lives until drop")
            .send(cmd)
            .map_err(|_| EnvError::Physics("vector env worker died".into())),
        Link::Local { shard, pending } => {
            *pending = Some(shard.handle(cmd));
            Ok(())
        }
    }
}

#[allow(clippy::expect_used, reason = "receive follows send on the same link")]
fn receive(w: &mut Worker) -> Reply {
    match &mut w.link {
        Link::Remote { rx, .. } => recv_spin(rx)
            .unwrap_or_else(|_| Err(EnvError::Physics("vector env worker died".into()))),
        Link::Local { pending, .. } => pending.take().expect("a command was sent"),
    }
}

/// A slice of the environments with their seed-schedule state; lives on a worker thread, or on
/// the calling thread for the last slice (one fewer thread hand-off per step).
struct Shard {
    envs: Vec<Box<dyn AnyEnv>>,
    first: u64,
    /// Seed schedule (base, episode index per env) when active.
    schedule: Option<(u64, Vec<u64>)>,
}

fn fresh(obs: Vec<f32>, info: EnvInfo) -> VecStep {
    VecStep {
        obs,
        reward: 0.0,
        terminated: false,
        truncated: false,
        final_obs: None,
        info,
    }
}

impl Shard {
    fn handle(&mut self, cmd: Cmd) -> Reply {
        let first = self.first;
        let envs = &mut self.envs;
        let schedule = &mut self.schedule;
        match cmd {
            Cmd::ResetScheduled(base, episodes) => {
                let r = envs
                    .iter_mut()
                    .zip(&episodes)
                    .enumerate()
                    .map(|(i, (env, &k))| {
                        let (obs, info) =
                            env.reset(Some(episode_seed(base, first as usize + i, k)))?;
                        Ok(fresh(obs, info))
                    })
                    .collect();
                *schedule = Some((base, episodes));
                r
            }
            Cmd::Restore(i, base, actions) => (|| {
                let k = schedule.as_ref().map_or(0, |s| s.1[i]);
                let env = &mut envs[i];
                let (mut obs, mut info) =
                    env.reset(Some(episode_seed(base, first as usize + i, k)))?;
                for a in &actions {
                    let s = env.step(a)?;
                    if s.done() {
                        return Err(EnvError::Config(
                            "restored episode ended before its last action".into(),
                        ));
                    }
                    (obs, info) = (s.obs, s.info);
                }
                Ok(vec![fresh(obs, info)])
            })(),
            Cmd::Reset(seed, flags) => {
                *schedule = None;
                envs.iter_mut()
                    .enumerate()
                    .map(|(i, env)| {
                        if flags.as_ref().is_some_and(|f| !f[i]) {
                            return Ok(fresh(Vec::new(), EnvInfo::default()));
                        }
                        let rng = seed
                            .as_ref()
                            .map(|s| NpRng::from_seed_words(&seed_words_plus(s, first + i as u64)));
                        let (obs, info) = env.reset_with(rng)?;
                        Ok(fresh(obs, info))
                    })
                    .collect()
            }
            Cmd::Step(actions) => envs
                .iter_mut()
                .zip(actions)
                .enumerate()
                .map(|(i, (env, a))| {
                    let Some(a) = a else {
                        return Ok(fresh(Vec::new(), EnvInfo::default()));
                    };
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
                        let seed = schedule.as_mut().map(|(base, ks)| {
                            ks[i] += 1;
                            episode_seed(*base, first as usize + i, ks[i])
                        });
                        let (obs, _) = env.reset(seed)?;
                        out.final_obs = Some(std::mem::replace(&mut out.obs, obs));
                    }
                    Ok(out)
                })
                .collect(),
        }
    }
}

fn worker_loop(mut shard: Shard, rx: Receiver<Cmd>, tx: Sender<Reply>) {
    while let Ok(cmd) = recv_spin(&rx) {
        if tx.send(shard.handle(cmd)).is_err() {
            return;
        }
    }
}

impl Drop for VecEnv {
    fn drop(&mut self) {
        for w in &mut self.workers {
            if let Link::Remote { tx, handle, .. } = &mut w.link {
                drop(tx.take());
                if let Some(h) = handle.take() {
                    let _ = h.join();
                }
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
    fn seed_schedule_restores_episodes_mid_way() {
        let opts = EnvOptions {
            max_episode_steps: Some(40),
            fresh_world: true,
            ..Default::default()
        };
        let mut a = VecEnv::make("BipedalWalkerHardcore-v3", &opts, 2, 2).unwrap();
        a.reset_scheduled(77, &[0, 0]).unwrap();
        let mut taken: Vec<Vec<Vec<f32>>> = vec![Vec::new(); 2];
        let mut last = Vec::new();
        for t in 0..70 {
            let acts = actions(t, 2);
            let steps = a.step(&acts).unwrap();
            for (i, s) in steps.iter().enumerate() {
                if s.final_obs.is_some() {
                    taken[i].clear();
                } else {
                    taken[i].push(acts[i].clone());
                }
            }
            last = steps.into_iter().map(|s| s.obs).collect();
        }
        assert_eq!(a.episode_indices(), vec![1, 1], "one time-limit reset each");
        // A second vector env rebuilt from (schedule, episode indices, actions) is identical.
        let mut b = VecEnv::make("BipedalWalkerHardcore-v3", &opts, 2, 1).unwrap();
        b.reset_scheduled(77, &a.episode_indices()).unwrap();
        for (i, acts) in taken.iter().enumerate() {
            assert_eq!(b.restore(i, acts.clone()).unwrap(), last[i]);
        }
        let acts = actions(99, 2);
        let (sa, sb) = (a.step(&acts).unwrap(), b.step(&acts).unwrap());
        assert_eq!(sa, sb);
        assert_ne!(episode_seed(77, 0, 0), episode_seed(77, 1, 0));
        assert_ne!(episode_seed(77, 0, 0), episode_seed(77, 0, 1));
    }

    #[test]
    fn wrong_action_count_is_an_error() {
        let mut vec = VecEnv::new(vec![make("Pendulum-v1").unwrap()], 4).unwrap();
        vec.reset(Some(0)).unwrap();
        assert!(vec.step(&[]).is_err());
        assert!(vec.step(&[vec![f32::NAN]]).is_err());
    }
}
