//! Wrappers: the time limit (the only source of `truncated`), observation masks, the two
//! training-time changes public Hardcore solutions rely on (a changed fall penalty and action
//! repeat), the previous action in the observation (an input recurrent agents commonly read)
//! and a stack of the last observations (the feed-forward agent's memory).

use crate::Renderable;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, NpRng, Step};

/// `Env` methods a wrapper passes to its `inner` env unchanged, by name.
macro_rules! delegate {
    ($($method:ident),+) => { $(delegate!(@one $method);)+ };
    (@one id) => { fn id(&self) -> &str { self.inner.id() } };
    (@one observation_space) => {
        fn observation_space(&self) -> &BoxSpace { self.inner.observation_space() }
    };
    (@one action_space) => { fn action_space(&self) -> &BoxSpace { self.inner.action_space() } };
    (@one reset) => {
        fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
            self.inner.reset_with(rng)
        }
    };
    (@one max_episode_steps) => {
        fn max_episode_steps(&self) -> Option<usize> { self.inner.max_episode_steps() }
    };
}

/// Wrappers draw what their inner env draws.
macro_rules! renderable_via_inner {
    ($($wrapper:ident),+) => {$(
        impl<E: Renderable> Renderable for $wrapper<E> {
            fn scene(&self) -> rdpg_render::Scene {
                self.inner.scene()
            }
        }
    )+};
}
renderable_via_inner!(
    TimeLimit,
    ObsMask,
    FallPenalty,
    ActionRepeat,
    PrevAction,
    FrameStack
);

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
    delegate!(id, observation_space, action_space);
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        self.elapsed = 0;
        let out = self.inner.reset_with(rng)?;
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
    delegate!(id, action_space, max_episode_steps);
    fn observation_space(&self) -> &BoxSpace {
        &self.space
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        let (obs, info) = self.inner.reset_with(rng)?;
        Ok((self.mask(obs), info))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        s.obs = self.mask(std::mem::take(&mut s.obs));
        Ok(s)
    }
}

/// Pays `penalty` instead of the inner env's reward on a step that ends the episode without
/// success (a walker's fall: the hull touches the ground or leaves the course, where the
/// stock reward is −100 and the paper's −20). Every step reports the stock reward in
/// `info.stock_reward`, so returns on the stock reward stay measurable.
pub struct FallPenalty<E> {
    inner: E,
    penalty: f64,
}

impl<E: Env> FallPenalty<E> {
    /// Wraps `inner`; `penalty` must be finite.
    pub fn new(inner: E, penalty: f64) -> Result<Self, EnvError> {
        if !penalty.is_finite() {
            return Err(EnvError::Config(format!(
                "fall penalty must be finite, got {penalty}"
            )));
        }
        Ok(Self { inner, penalty })
    }
}

impl<E: Env> Env for FallPenalty<E> {
    delegate!(
        id,
        observation_space,
        action_space,
        reset,
        max_episode_steps
    );
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        s.info.stock_reward = Some(s.info.stock_reward.unwrap_or(s.reward));
        if s.terminated && !s.info.success {
            s.reward = self.penalty;
        }
        Ok(s)
    }
}

/// Holds each action for `repeat` steps of the inner env (frame skip), returning the last
/// observation and the sum of the rewards (and of the stock rewards); it stops early when the
/// episode ends. Outside the time limit, so the limit still counts the inner env's frames and
/// an episode lasts `ceil(limit / repeat)` agent steps at most.
pub struct ActionRepeat<E> {
    inner: E,
    repeat: usize,
}

impl<E: Env> ActionRepeat<E> {
    /// Wraps `inner`; `repeat` must be at least 1 (1 changes nothing).
    pub fn new(inner: E, repeat: usize) -> Result<Self, EnvError> {
        if repeat == 0 {
            return Err(EnvError::Config("action repeat must be at least 1".into()));
        }
        Ok(Self { inner, repeat })
    }
}

impl<E: Env> Env for ActionRepeat<E> {
    delegate!(id, observation_space, action_space, reset);
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        let (mut reward, mut stock) = (s.reward, s.info.stock_reward);
        for _ in 1..self.repeat {
            if s.done() {
                break;
            }
            s = self.inner.step(action)?;
            reward += s.reward;
            stock = stock.zip(s.info.stock_reward).map(|(a, b)| a + b);
        }
        s.reward = reward;
        s.info.stock_reward = stock;
        Ok(s)
    }
    fn max_episode_steps(&self) -> Option<usize> {
        self.inner
            .max_episode_steps()
            .map(|n| n.div_ceil(self.repeat))
    }
}

/// Puts the previous action in front of the observation, `[a_{t-1}, o_t]` (zeros after a
/// reset), clipped to the action space as the env applies it: the input recurrent off-policy
/// agents commonly read next to the observation (R2D2; Ni et al. 2022). In front, so that a
/// lidar trunk still finds the lidar values at the end of the observation.
pub struct PrevAction<E> {
    inner: E,
    space: BoxSpace,
}

impl<E: Env> PrevAction<E> {
    /// Wraps `inner`.
    pub fn new(inner: E) -> Self {
        let (a, o) = (inner.action_space(), inner.observation_space());
        let space = BoxSpace::new(
            a.low.iter().chain(&o.low).copied().collect(),
            a.high.iter().chain(&o.high).copied().collect(),
        );
        Self { inner, space }
    }
}

impl<E: Env> Env for PrevAction<E> {
    delegate!(id, action_space, max_episode_steps);
    fn observation_space(&self) -> &BoxSpace {
        &self.space
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        let (obs, info) = self.inner.reset_with(rng)?;
        let mut out = vec![0.0; self.inner.action_space().dim()];
        out.extend(obs);
        Ok((out, info))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        let space = self.inner.action_space();
        let mut out: Vec<f32> = action
            .iter()
            .zip(space.low.iter().zip(&space.high))
            .map(|(&x, (&lo, &hi))| x.clamp(lo, hi))
            .collect();
        out.extend(s.obs);
        s.obs = out;
        Ok(s)
    }
}

/// The last `k` observations of the inner env side by side, `[o_{t-k+1}, …, o_t]`, oldest
/// first, zeros before the episode's first (Stable-Baselines3's `VecFrameStack`, DQN's frame
/// stack): what a feed-forward agent remembers, where a recurrent one carries a state. The
/// newest observation last, so that a lidar trunk still finds the lidar values at the end.
pub struct FrameStack<E> {
    inner: E,
    k: usize,
    space: BoxSpace,
    /// The observation last returned (`k` inner observations).
    stack: Vec<f32>,
}

impl<E: Env> FrameStack<E> {
    /// Wraps `inner`; `k` must be at least 1 (1 changes nothing). The space's bounds are the
    /// inner ones repeated `k` times.
    pub fn new(inner: E, k: usize) -> Result<Self, EnvError> {
        if k == 0 {
            return Err(EnvError::Config("frame stack must be at least 1".into()));
        }
        let o = inner.observation_space();
        let space = BoxSpace::new(o.low.repeat(k), o.high.repeat(k));
        Ok(Self {
            inner,
            k,
            space,
            stack: Vec::new(),
        })
    }

    /// Shifts `obs` in as the newest observation; `fresh`: the episode starts (zeros before).
    fn push(&mut self, obs: &[f32], fresh: bool) -> Vec<f32> {
        let d = obs.len();
        if fresh || self.stack.len() != self.k * d {
            self.stack = vec![0.0; self.k * d];
        }
        push_view(&mut self.stack, obs);
        self.stack.clone()
    }
}

/// Shifts `view` into `stack` (views of `view.len()` values side by side, oldest first) as the
/// newest, dropping the oldest: [`FrameStack`]'s step, for code that stacks views itself (the
/// Python `Policy`).
pub fn push_view(stack: &mut [f32], view: &[f32]) {
    let (n, d) = (stack.len(), view.len());
    stack.copy_within(d.., 0);
    stack[n - d..].copy_from_slice(view);
}

impl<E: Env> Env for FrameStack<E> {
    delegate!(id, action_space, max_episode_steps);
    fn observation_space(&self) -> &BoxSpace {
        &self.space
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        let (obs, info) = self.inner.reset_with(rng)?;
        Ok((self.push(&obs, true), info))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        let mut s = self.inner.step(action)?;
        s.obs = self.push(&s.obs, false);
        Ok(s)
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

    #[test]
    fn action_repeat_sums_rewards_and_keeps_the_frame_limit() {
        let mut one = TimeLimit::new(Pendulum::new(false), 10).unwrap();
        let mut three =
            ActionRepeat::new(TimeLimit::new(Pendulum::new(false), 10).unwrap(), 3).unwrap();
        assert_eq!(three.max_episode_steps(), Some(4));
        assert!(ActionRepeat::new(Pendulum::new(false), 0).is_err());
        one.reset(Some(5)).unwrap();
        three.reset(Some(5)).unwrap();
        let mut agent_steps = 0;
        loop {
            let a = [0.3 * agent_steps as f32 - 1.0];
            let s3 = three.step(&a).unwrap();
            agent_steps += 1;
            // The same frames one by one: 3, 3, 3, then the 1 frame the limit leaves.
            let frames = if agent_steps < 4 { 3 } else { 1 };
            let mut r = 0.0;
            let mut last = None;
            for _ in 0..frames {
                let s = one.step(&a).unwrap();
                r += s.reward;
                last = Some(s);
            }
            let last = last.unwrap();
            assert_eq!(s3.obs, last.obs);
            assert_eq!(s3.reward, r);
            assert_eq!(
                (s3.terminated, s3.truncated),
                (last.terminated, last.truncated)
            );
            if s3.done() {
                break;
            }
        }
        assert_eq!(agent_steps, 4);
    }

    #[test]
    fn fall_penalty_replaces_only_the_reward_of_a_fall() {
        use crate::{BipedalWalker, WalkerConfig};
        let walker = || BipedalWalker::new(WalkerConfig::default()).unwrap();
        let mut stock = walker();
        let mut changed = FallPenalty::new(walker(), -5.0).unwrap();
        assert!(FallPenalty::new(walker(), f64::NAN).is_err());
        stock.reset(Some(1)).unwrap();
        changed.reset(Some(1)).unwrap();
        // Kick backwards until the hull touches the ground.
        for _ in 0..1600 {
            let (a, b) = (
                stock.step(&[1.0; 4]).unwrap(),
                changed.step(&[1.0; 4]).unwrap(),
            );
            assert_eq!(b.info.stock_reward, Some(a.reward));
            assert_eq!(a.obs, b.obs);
            if a.terminated {
                assert_eq!((a.reward, b.reward), (-100.0, -5.0));
                return;
            }
            assert_eq!(a.reward, b.reward);
        }
        panic!("the walker never fell");
    }

    #[test]
    fn prev_action_prepends_the_clipped_previous_action() {
        let mut plain = Pendulum::new(false);
        let mut env = PrevAction::new(Pendulum::new(false));
        assert_eq!(env.observation_space().dim(), 4);
        assert_eq!(env.observation_space().low[0], -2.0);
        let (o, _) = env.reset(Some(3)).unwrap();
        let (p, _) = plain.reset(Some(3)).unwrap();
        assert_eq!(o, [vec![0.0], p].concat());
        for a in [0.5f32, -7.0, 1.25] {
            let s = env.step(&[a]).unwrap();
            let t = plain.step(&[a]).unwrap();
            assert_eq!(s.obs, [vec![a.clamp(-2.0, 2.0)], t.obs].concat());
            assert_eq!(s.reward, t.reward);
        }
        let (o, _) = env.reset(Some(4)).unwrap();
        assert_eq!(o[0], 0.0, "a reset clears the previous action");
    }

    #[test]
    fn frame_stack_keeps_the_last_k_observations_oldest_first() {
        let mut plain = Pendulum::new(false);
        let mut env = FrameStack::new(Pendulum::new(false), 3).unwrap();
        assert!(FrameStack::new(Pendulum::new(false), 0).is_err());
        assert_eq!(env.observation_space().dim(), 9);
        assert_eq!(
            env.observation_space().high[3..6],
            plain.observation_space().high[..]
        );
        let (o, _) = env.reset(Some(3)).unwrap();
        let (p0, _) = plain.reset(Some(3)).unwrap();
        assert_eq!(o, [vec![0.0; 6], p0.clone()].concat());
        let p1 = plain.step(&[0.5]).unwrap().obs;
        assert_eq!(
            env.step(&[0.5]).unwrap().obs,
            [vec![0.0; 3], p0.clone(), p1.clone()].concat()
        );
        let p2 = plain.step(&[-1.0]).unwrap().obs;
        assert_eq!(
            env.step(&[-1.0]).unwrap().obs,
            [p0, p1.clone(), p2.clone()].concat()
        );
        let p3 = plain.step(&[2.0]).unwrap();
        let s3 = env.step(&[2.0]).unwrap();
        assert_eq!(s3.obs, [p1, p2, p3.obs].concat());
        assert_eq!(s3.reward, p3.reward);
        let (o, _) = env.reset(Some(4)).unwrap();
        let (p, _) = plain.reset(Some(4)).unwrap();
        assert_eq!(o, [vec![0.0; 6], p].concat(), "a reset clears the stack");
        let mut one = FrameStack::new(Pendulum::new(false), 1).unwrap();
        assert_eq!(
            one.reset(Some(4)).unwrap().0,
            plain.reset(Some(4)).unwrap().0
        );
    }
}
