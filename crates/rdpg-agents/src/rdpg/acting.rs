//! The actor's state while acting ([`ActorState`]): per environment, the recurrent state
//! carried over the episode, or a window-of-k agent's last observations; what the replay
//! stores and a checkpoint restores.

use tch::Tensor;

use super::lstm::RecState;
use crate::common::tensor::tensor_to_vec;
use crate::error::{AgentError, Result};

/// The recurrent state of the actor for a batch of environments, carried between
/// [`RdpgAgent::act`](super::RdpgAgent::act) calls. Feed-forward agents carry an empty (zero-width) state.
#[derive(Debug)]
pub struct ActorState {
    pub(super) state: RecState,
    pub(super) n_envs: usize,
    pub(super) hidden: usize,
    /// Window-of-k agents (`act_window`): the observations the state is re-encoded from.
    pub(super) window: Option<Window>,
}

/// The acting history of a window-of-k agent (`act_window = k`): each environment's last
/// `k - 1` observations, oldest first and left-padded, and how many of them are real.
#[derive(Debug)]
pub(super) struct Window {
    pub(super) k: usize,
    pub(super) obs_dim: usize,
    /// `[n_envs, k - 1, obs_dim]` row-major.
    pub(super) hist: Vec<f32>,
    pub(super) len: Vec<usize>,
}

impl Window {
    fn row(&mut self, env: usize) -> &mut [f32] {
        let w = (self.k - 1) * self.obs_dim;
        &mut self.hist[env * w..(env + 1) * w]
    }

    /// Appends `obs` (`[n_envs, obs_dim]`) to every environment's history.
    pub(super) fn push(&mut self, obs: &[f32]) {
        let (d, k1) = (self.obs_dim, self.k - 1);
        if k1 == 0 {
            return; // a window of the current observation alone keeps no history
        }
        for (env, o) in obs.chunks_exact(d).enumerate() {
            let row = self.row(env);
            row.copy_within(d.., 0);
            row[(k1 - 1) * d..].copy_from_slice(o);
            self.len[env] = (self.len[env] + 1).min(k1);
        }
    }
}

impl ActorState {
    /// Number of environments.
    pub fn n_envs(&self) -> usize {
        self.n_envs
    }

    /// Size of one environment's state as stored in the replay (`2 * hidden`: `h` then `c`).
    pub fn state_dim(&self) -> usize {
        2 * self.hidden
    }

    /// Zeroes every environment's state.
    pub fn reset(&mut self) {
        tch::no_grad(|| {
            let _ = self.state.h.zero_();
            let _ = self.state.c.zero_();
        });
        for env in 0..self.n_envs {
            self.reset_window(env);
        }
    }

    fn reset_window(&mut self, env: usize) {
        if let Some(w) = &mut self.window {
            w.row(env).fill(0.0);
            w.len[env] = 0;
        }
    }

    /// Values per environment in [`ActorState::to_vec`]: `2 * hidden` (`h` then `c`), or for
    /// a window-of-k agent `1 + (k - 1) * obs_dim` (how many observations are real, then the
    /// observations).
    pub fn carried_len(&self) -> usize {
        match &self.window {
            Some(w) => 1 + (w.k - 1) * w.obs_dim,
            None => 2 * self.hidden,
        }
    }

    /// Overwrites environment `env`'s carried state with `v` ([`ActorState::carried_len`]
    /// values, as [`ActorState::to_vec`] gives them), e.g. when a checkpoint resumes.
    pub fn restore_env(&mut self, env: usize, v: &[f32]) -> Result<()> {
        if v.len() != self.carried_len() || env >= self.n_envs {
            return Err(AgentError::Shape(format!(
                "actor state of {} values for env {env}, expected {} ({} envs)",
                v.len(),
                self.carried_len(),
                self.n_envs
            )));
        }
        match &mut self.window {
            Some(w) => {
                let len = v[0];
                if !(len >= 0.0 && len <= (w.k - 1) as f32 && len.fract() == 0.0) {
                    return Err(AgentError::Shape(format!(
                        "window length {len} is not 0 to {}",
                        w.k - 1
                    )));
                }
                w.len[env] = len as usize;
                w.row(env).copy_from_slice(&v[1..]);
            }
            None => self.set_env_state(env, v),
        }
        Ok(())
    }

    /// Zeroes environment `env`'s state (call when its episode ends).
    pub fn reset_env(&mut self, env: usize) {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        tch::no_grad(|| {
            let _ = self.state.h.select(1, env as i64).zero_();
            let _ = self.state.c.select(1, env as i64).zero_();
        });
        self.reset_window(env);
    }

    /// Environment `env`'s state, `[h (hidden), c (hidden)]`: what the replay stores as the
    /// acting-time state of a step (take it *before* acting on that step).
    pub fn env_state(&self, env: usize) -> Vec<f32> {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        let hc = Tensor::cat(
            &[
                self.state.h.select(1, env as i64),
                self.state.c.select(1, env as i64),
            ],
            1,
        );
        tensor_to_vec(&hc)
    }

    /// All states, `[n_envs, carried_len]` row-major: `h` then `c` per environment, or a
    /// window-of-k agent's history ([`ActorState::carried_len`]).
    pub fn to_vec(&self) -> Vec<f32> {
        if let Some(w) = &self.window {
            let row = (w.k - 1) * w.obs_dim;
            return (0..self.n_envs)
                .flat_map(|e| {
                    std::iter::once(w.len[e] as f32)
                        .chain(w.hist[e * row..(e + 1) * row].iter().copied())
                })
                .collect();
        }
        tensor_to_vec(&Tensor::cat(
            &[self.state.h.squeeze_dim(0), self.state.c.squeeze_dim(0)],
            1,
        ))
    }

    /// Overwrites environment `env`'s state with `[h, c]` (`2 * hidden` values), e.g. the
    /// random Gaussian start the authors' code used when acting.
    pub fn set_env_state(&mut self, env: usize, hc: &[f32]) {
        assert!(
            env < self.n_envs,
            "env {env} out of range ({} envs)",
            self.n_envs
        );
        assert_eq!(hc.len(), 2 * self.hidden, "state size");
        let h = self.hidden as i64;
        let t = Tensor::from_slice(hc)
            .to_kind(self.state.h.kind())
            .to_device(self.state.h.device());
        tch::no_grad(|| {
            self.state
                .h
                .select(1, env as i64)
                .squeeze_dim(0)
                .copy_(&t.narrow(0, 0, h));
            self.state
                .c
                .select(1, env as i64)
                .squeeze_dim(0)
                .copy_(&t.narrow(0, h, h));
        });
    }
}
