//! `CueMemory-v0`: the smallest task that needs memory, for fast learning tests.
//!
//! The first observation shows a cue, `+1` or `-1` (drawn from the reset seed), then `delay`
//! blank observations follow, then a query. The action on the query step earns `cue * a` and
//! ends the episode (`terminated`); every other step earns 0. Observation `[cue channel, query
//! flag]`, action one value in `[-1, 1]`.
//!
//! A policy without memory sees the same query observation whatever the cue, so its expected
//! return is 0; remembering the cue earns 1. Episodes are `delay + 2` steps long.

use crate::Renderable;
use rdpg_core::env::validate_action;
use rdpg_core::rng::NpRng;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, Step};
use rdpg_render::{Scene, Shape};

/// Blank steps between the cue and the query in `CueMemory-v0`.
pub const DEFAULT_DELAY: usize = 4;

/// The cue-recall task.
pub struct CueMemory {
    delay: usize,
    rng: Option<NpRng>,
    cue: f32,
    /// Steps taken in the episode; `None` before the first reset.
    t: Option<usize>,
    last_action: f32,
    obs_space: BoxSpace,
    act_space: BoxSpace,
}

impl CueMemory {
    /// A task with `delay` blank steps between cue and query.
    pub fn new(delay: usize) -> Self {
        Self {
            delay,
            rng: None,
            cue: 0.0,
            t: None,
            last_action: 0.0,
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
        "CueMemory-v0"
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn reset(&mut self, seed: Option<u64>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        if let Some(s) = seed {
            self.rng = Some(NpRng::from_seed(s));
        }
        let rng = self.rng.get_or_insert_with(NpRng::from_entropy);
        self.cue = if rng.random() < 0.5 { -1.0 } else { 1.0 };
        self.t = Some(0);
        self.last_action = 0.0;
        Ok((self.obs(0), EnvInfo::default()))
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        validate_action(&self.act_space, action)?;
        let t = self
            .t
            .ok_or(EnvError::NeedsReset("reset before stepping"))?;
        if t > self.delay + 1 {
            return Err(EnvError::NeedsReset("the episode has ended"));
        }
        let a = action[0].clamp(-1.0, 1.0);
        self.last_action = a;
        self.t = Some(t + 1);
        let query = t == self.delay + 1;
        let reward = if query { f64::from(self.cue * a) } else { 0.0 };
        Ok(Step {
            obs: if query {
                vec![0.0, 0.0]
            } else {
                self.obs(t + 1)
            },
            reward,
            terminated: query,
            truncated: false,
            info: EnvInfo {
                success: query && reward > 0.0,
                stock_reward: None,
            },
        })
    }
    fn max_episode_steps(&self) -> Option<usize> {
        Some(self.delay + 2)
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
            assert_eq!(s.reward, 0.0);
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
