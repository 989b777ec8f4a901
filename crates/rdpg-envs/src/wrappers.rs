//! Wrappers: the time limit (the only source of `truncated`) and observation masks.

use crate::Renderable;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, Step};

/// Ends episodes after `max_steps` steps with `truncated = true` (Gymnasium's `TimeLimit`).
/// `terminated` from the inner env passes through unchanged, so a step that both terminates
/// and hits the limit reports both.
pub struct TimeLimit<E> {
    inner: E,
    max_steps: usize,
    elapsed: usize,
    needs_reset: bool,
}

impl<E: Env> TimeLimit<E> {
    /// Wraps `inner` with a limit of `max_steps` steps (must be positive).
    pub fn new(inner: E, max_steps: usize) -> Result<Self, EnvError> {
        if max_steps == 0 {
            return Err(EnvError::Config(
                "time limit must be at least 1 step".into(),
            ));
        }
        Ok(Self {
            inner,
            max_steps,
            elapsed: 0,
            needs_reset: true,
        })
    }

    /// The wrapped environment.
    pub fn inner(&self) -> &E {
        &self.inner
    }

    /// Steps taken in the current episode.
    pub fn elapsed(&self) -> usize {
        self.elapsed
    }
}

impl<E: Env> Env for TimeLimit<E> {
    fn id(&self) -> &str {
        self.inner.id()
    }
    fn observation_space(&self) -> &BoxSpace {
        self.inner.observation_space()
    }
    fn action_space(&self) -> &BoxSpace {
        self.inner.action_space()
    }
    fn reset(&mut self, seed: Option<u64>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        self.elapsed = 0;
        let out = self.inner.reset(seed)?;
        self.needs_reset = false;
        Ok(out)
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        if self.needs_reset {
            return Err(EnvError::NeedsReset("the episode is over or never started"));
        }
        let mut s = self.inner.step(action)?;
        self.elapsed += 1;
        if self.elapsed >= self.max_steps {
            s.truncated = true;
        }
        self.needs_reset = s.done();
        Ok(s)
    }
    fn max_episode_steps(&self) -> Option<usize> {
        Some(self.max_steps)
    }
}

impl<E: Renderable> Renderable for TimeLimit<E> {
    fn scene(&self) -> rdpg_render::Scene {
        self.inner.scene()
    }
}

/// Keeps only the observation components listed in `keep` (in that order): e.g. hide the
/// walker's velocities, or Pendulum's angular velocity, to make a task partially observable.
pub struct ObsMask<E> {
    inner: E,
    keep: Vec<usize>,
    space: BoxSpace,
}

impl<E: Env> ObsMask<E> {
    /// Wraps `inner`, keeping the components `keep` (each must be a valid index, no repeats).
    pub fn new(inner: E, keep: Vec<usize>) -> Result<Self, EnvError> {
        let full = inner.observation_space();
        let mut seen = vec![false; full.dim()];
        for &k in &keep {
            if k >= full.dim() {
                return Err(EnvError::Config(format!(
                    "observation mask index {k} out of range (observation has {} components)",
                    full.dim()
                )));
            }
            if std::mem::replace(&mut seen[k], true) {
                return Err(EnvError::Config(format!(
                    "observation mask repeats index {k}"
                )));
            }
        }
        if keep.is_empty() {
            return Err(EnvError::Config("observation mask keeps nothing".into()));
        }
        let space = BoxSpace::new(
            keep.iter().map(|&k| full.low[k]).collect(),
            keep.iter().map(|&k| full.high[k]).collect(),
        );
        Ok(Self { inner, keep, space })
    }

    /// Wraps `inner`, hiding the components `hide` and keeping the others in order.
    pub fn hiding(inner: E, hide: &[usize]) -> Result<Self, EnvError> {
        let n = inner.observation_space().dim();
        if let Some(&bad) = hide.iter().find(|&&h| h >= n) {
            return Err(EnvError::Config(format!(
                "observation mask index {bad} out of range (observation has {n} components)"
            )));
        }
        Self::new(inner, (0..n).filter(|i| !hide.contains(i)).collect())
    }

    /// The wrapped environment.
    pub fn inner(&self) -> &E {
        &self.inner
    }

    fn mask(&self, obs: Vec<f32>) -> Vec<f32> {
        self.keep.iter().map(|&k| obs[k]).collect()
    }
}

impl<E: Env> Env for ObsMask<E> {
    fn id(&self) -> &str {
        self.inner.id()
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.space
    }
    fn action_space(&self) -> &BoxSpace {
        self.inner.action_space()
    }
    fn reset(&mut self, seed: Option<u64>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        let (obs, info) = self.inner.reset(seed)?;
        Ok((self.mask(obs), info))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        s.obs = self.mask(std::mem::take(&mut s.obs));
        Ok(s)
    }
    fn max_episode_steps(&self) -> Option<usize> {
        self.inner.max_episode_steps()
    }
}

impl<E: Renderable> Renderable for ObsMask<E> {
    fn scene(&self) -> rdpg_render::Scene {
        self.inner.scene()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Pendulum;

    #[test]
    fn time_limit_truncates_and_demands_reset() {
        let mut env = TimeLimit::new(Pendulum::new(false), 3).unwrap();
        assert!(env.step(&[0.0]).is_err());
        env.reset(Some(0)).unwrap();
        assert!(!env.step(&[0.0]).unwrap().truncated);
        assert!(!env.step(&[0.0]).unwrap().truncated);
        let last = env.step(&[0.0]).unwrap();
        assert!(last.truncated && !last.terminated);
        assert!(matches!(env.step(&[0.0]), Err(EnvError::NeedsReset(_))));
        env.reset(None).unwrap();
        assert_eq!(env.elapsed(), 0);
    }

    #[test]
    fn mask_keeps_components_in_order() {
        let mut full = Pendulum::new(false);
        let (obs, _) = full.reset(Some(3)).unwrap();
        let mut masked = ObsMask::hiding(Pendulum::new(false), &[2]).unwrap();
        let (m, _) = masked.reset(Some(3)).unwrap();
        assert_eq!(m, obs[..2].to_vec());
        assert_eq!(masked.observation_space().dim(), 2);
        assert!(ObsMask::new(Pendulum::new(false), vec![3]).is_err());
        assert!(ObsMask::new(Pendulum::new(false), vec![0, 0]).is_err());
        assert!(ObsMask::hiding(Pendulum::new(false), &[9]).is_err());
    }
}
