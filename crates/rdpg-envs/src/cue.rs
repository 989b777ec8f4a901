//! `CueMemory-v0`: the smallest task that needs memory, for fast learning tests.
//!
//! The first observation shows a cue, `+1` or `-1` (drawn from the reset seed), then `delay`
//! blank observations follow, then a query. The action on the query step earns `cue * a` and
//! ends the episode (`terminated`); every other step earns 0. Observation `[cue channel, query
//! flag]`, action one value in `[-1, 1]`.
//!
//! A policy without memory sees the same query observation whatever the cue, so its expected
//! return is 0; remembering the cue earns 1. Episodes are `delay + 2` steps long.
//!
//! `DelayedCue-v0` is the same task with the episode going on after the query: cue at step 0,
//! query at step 5, blank steps up to 12 steps, then `terminated`. It tests the paper's central
//! claim, scanning: a learner whose windows are shorter than the cue-query distance
//! (`l < 5`) and whose episodes are longer than its windows and scans (`s + l < 12`) sees the
//! query only in windows that start after the cue, and only a scan of `s >= 5` steps before
//! the window brings the cue back into the recurrent state.

use crate::Renderable;
use rdpg_core::env::validate_action;
use rdpg_core::rng::NpRng;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, Step};
use rdpg_render::{Scene, Shape};

/// Blank steps between the cue and the query in `CueMemory-v0`.
pub const DEFAULT_DELAY: usize = 4;

/// Blank steps between the cue and the query in `DelayedCue-v0`.
pub const DELAYED_DELAY: usize = 4;

/// Episode length of `DelayedCue-v0`.
pub const DELAYED_LEN: usize = 12;

/// The cue-recall task.
pub struct CueMemory {
    id: &'static str,
    delay: usize,
    /// Episode length (the query is at step `delay + 1`).
    len: usize,
    rng: Option<NpRng>,
    cue: f32,
    /// Steps taken in the episode; `None` before the first reset.
    t: Option<usize>,
    last_action: f32,
    /// The query was answered with the cue's sign.
    correct: bool,
    obs_space: BoxSpace,
    act_space: BoxSpace,
}

impl CueMemory {
    /// `CueMemory-v0`'s task with `delay` blank steps between cue and query; the episode ends
    /// on the query.
    pub fn new(delay: usize) -> Self {
        Self::build("CueMemory-v0", delay, delay + 2)
    }

    /// `DelayedCue-v0`: cue at step 0, query at step 5, episodes of 12 steps.
    pub fn delayed() -> Self {
        Self::build("DelayedCue-v0", DELAYED_DELAY, DELAYED_LEN)
    }

    fn build(id: &'static str, delay: usize, len: usize) -> Self {
        assert!(len >= delay + 2, "the episode must reach the query");
        Self {
            id,
            delay,
            len,
            rng: None,
            cue: 0.0,
            t: None,
            last_action: 0.0,
            correct: false,
            obs_space: BoxSpace::uniform(2, -1.0, 1.0),
            act_space: BoxSpace::uniform(1, -1.0, 1.0),
        }
    }

    /// The cue of the current episode (`±1`, 0 before the first reset).
    pub fn cue(&self) -> f32 {
        self.cue
    }

    fn obs(&self, t: usize) -> Vec<f32> {
        if t == 0 {
            vec![self.cue, 0.0]
        } else if t == self.delay + 1 {
            vec![0.0, 1.0]
        } else {
            vec![0.0, 0.0]
        }
    }
}

impl Env for CueMemory {
    fn id(&self) -> &str {
        self.id
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        if rng.is_some() {
            self.rng = rng;
        }
        let rng = self.rng.get_or_insert_with(NpRng::from_entropy);
        self.cue = if rng.random() < 0.5 { -1.0 } else { 1.0 };
        self.t = Some(0);
        self.last_action = 0.0;
        self.correct = false;
        Ok((self.obs(0), EnvInfo::default()))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        validate_action(&self.act_space, action)?;
        let t = self
            .t
            .ok_or(EnvError::NeedsReset("reset before stepping"))?;
        if t >= self.len {
            return Err(EnvError::NeedsReset("the episode has ended"));
        }
        let a = action[0].clamp(-1.0, 1.0);
        self.last_action = a;
        self.t = Some(t + 1);
        let query = t == self.delay + 1;
        let reward = if query { f64::from(self.cue * a) } else { 0.0 };
        self.correct |= query && reward > 0.0;
        let terminated = t + 1 == self.len;
        Ok(Step {
            obs: self.obs(t + 1),
            reward,
            terminated,
            truncated: false,
            info: EnvInfo {
                // Reported on the last step, where an episode's success is read.
                success: terminated && self.correct,
                stock_reward: None,
                course: None,
            },
        })
    }
    fn max_episode_steps(&self) -> Option<usize> {
        Some(self.len)
    }
}

impl Renderable for CueMemory {
    /// The cue as a green (+1) or red (-1) square while it is shown, a grey one otherwise, and
    /// the last action as a bar.
    fn scene(&self) -> Scene {
        let square = |fill: [u8; 3]| Shape::Polygon {
            points: vec![[50.0, 50.0], [150.0, 50.0], [150.0, 150.0], [50.0, 150.0]],
            fill,
            outline: None,
        };
        let fill = match (self.t, self.cue > 0.0) {
            (Some(0), true) => [60, 170, 60],
            (Some(0), false) => [200, 60, 60],
            _ => [180, 180, 180],
        };
        Scene {
            width: 200,
            height: 200,
            background: [255, 255, 255],
            shapes: vec![
                square(fill),
                Shape::Line {
                    from: [100.0, 180.0],
                    to: [100.0 + 80.0 * self.last_action, 180.0],
                    color: [0, 0, 0],
                    width: 6.0,
                },
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(env: &mut CueMemory, seed: u64, answer: impl Fn(&[f32]) -> f32) -> (f64, usize) {
        let (mut obs, _) = env.reset(Some(seed)).unwrap();
        let first = obs.clone();
        let (mut ret, mut len) = (0.0, 0);
        loop {
            let a = if obs[1] == 1.0 { answer(&first) } else { 0.0 };
            let s = env.step(&[a]).unwrap();
            ret += s.reward;
            len += 1;
            if s.terminated {
                assert!(!s.truncated);
                return (ret, len);
            }
            obs = s.obs;
        }
    }

    #[test]
    fn remembering_the_cue_earns_one_and_a_fixed_answer_earns_nothing_on_average() {
        let mut env = CueMemory::new(DEFAULT_DELAY);
        let mut fixed = 0.0;
        for seed in 0..200 {
            let (r, len) = run(&mut env, seed, |first| first[0]);
            assert_eq!((r, len), (1.0, DEFAULT_DELAY + 2));
            fixed += run(&mut env, seed, |_| 1.0).0;
        }
        // Both cues occur about equally often.
        assert!((fixed / 200.0).abs() < 0.2, "{fixed}");
    }

    #[test]
    fn delayed_cue_queries_at_step_5_and_runs_to_12() {
        let mut env = CueMemory::delayed();
        assert_eq!(env.id(), "DelayedCue-v0");
        for seed in 0..50 {
            let (r, len) = run(&mut env, seed, |first| first[0]);
            assert_eq!((r, len), (1.0, DELAYED_LEN));
        }
        let (obs, _) = env.reset(Some(3)).unwrap();
        assert_ne!(obs[0], 0.0);
        let mut flags = Vec::new();
        for _ in 0..DELAYED_LEN {
            let s = env.step(&[0.5]).unwrap();
            flags.push(s.obs[1]);
            assert_eq!(s.terminated, flags.len() == DELAYED_LEN);
        }
        // The observation after step 4 is the query (flag 1), acted on at step 5.
        assert_eq!(flags.iter().position(|&f| f == 1.0), Some(DELAYED_DELAY));
        assert_eq!(flags.iter().filter(|&&f| f == 1.0).count(), 1);
    }

    #[test]
    fn same_seed_same_cue_and_stepping_after_the_end_is_an_error() {
        let mut a = CueMemory::new(2);
        let mut b = CueMemory::new(2);
        for seed in 0..20 {
            assert_eq!(
                a.reset(Some(seed)).unwrap().0,
                b.reset(Some(seed)).unwrap().0
            );
        }
        let mut env = CueMemory::new(0);
        assert!(env.step(&[0.0]).is_err());
        env.reset(Some(1)).unwrap();
        env.step(&[0.0]).unwrap();
        assert!(env.step(&[1.0]).unwrap().terminated);
        assert!(env.step(&[1.0]).is_err());
    }
}
