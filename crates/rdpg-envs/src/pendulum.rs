//! Gymnasium's Pendulum-v1, and the partially observable variant with the angular velocity
//! hidden (`PendulumNoVel-v1`, observation `[cos θ, sin θ]`): a memory task that a
//! feed-forward agent cannot solve, since the velocity must be inferred from the history.
//!
//! Dynamics, reward and reset distribution follow Gymnasium 1.4's `pendulum.py`, including its
//! numeric types (the float32 torque enters the double-precision update as float32 products).

use crate::Renderable;
use rdpg_core::env::validate_action;
use rdpg_core::rng::NpRng;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, Step};
use rdpg_render::{Scene, Shape};

const MAX_SPEED: f64 = 8.0;
const MAX_TORQUE: f32 = 2.0;
const DT: f64 = 0.05;
const G: f64 = 10.0;
/// Time limit of Pendulum-v1 (steps).
pub const MAX_STEPS: usize = 200;

/// The pendulum swing-up task.
pub struct Pendulum {
    hide_velocity: bool,
    rng: Option<NpRng>,
    state: Option<[f64; 2]>,
    last_u: f32,
    obs_space: BoxSpace,
    act_space: BoxSpace,
}

impl Pendulum {
    /// Pendulum-v1, or with `hide_velocity` its velocity-hidden variant.
    pub fn new(hide_velocity: bool) -> Self {
        let obs_space = if hide_velocity {
            BoxSpace::uniform(2, -1.0, 1.0)
        } else {
            BoxSpace::new(vec![-1.0, -1.0, -8.0], vec![1.0, 1.0, 8.0])
        };
        Self {
            hide_velocity,
            rng: None,
            state: None,
            last_u: 0.0,
            obs_space,
            act_space: BoxSpace::uniform(1, -MAX_TORQUE, MAX_TORQUE),
        }
    }

    /// `(θ, θ̇)` of the current episode.
    pub fn state(&self) -> Option<[f64; 2]> {
        self.state
    }

    fn obs(&self, [th, thdot]: [f64; 2]) -> Vec<f32> {
        let mut o = vec![th.cos() as f32, th.sin() as f32];
        if !self.hide_velocity {
            o.push(thdot as f32);
        }
        o
    }
}

/// `((x + π) mod 2π) − π` with Python's modulo.
fn angle_normalize(x: f64) -> f64 {
    (x + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
}

impl Env for Pendulum {
    fn id(&self) -> &str {
        if self.hide_velocity {
            "PendulumNoVel-v1"
        } else {
            "Pendulum-v1"
        }
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn reset_with(&mut self, rng: Option<NpRng>) -> Result<(Vec<f32>, EnvInfo), EnvError> {
        // Physics in IEEE mode whatever the thread (learners flush subnormals).
        rdpg_core::fpmode::with_ieee_denormals(|| {
            if rng.is_some() {
                self.rng = rng;
            }
            let rng = self.rng.get_or_insert_with(NpRng::from_entropy);
            let th = rng.uniform(-std::f64::consts::PI, std::f64::consts::PI);
            let thdot = rng.uniform(-1.0, 1.0);
            self.state = Some([th, thdot]);
            self.last_u = 0.0;
            Ok((self.obs([th, thdot]), EnvInfo::default()))
        })
    }
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        // Physics in IEEE mode whatever the thread (learners flush subnormals).
        rdpg_core::fpmode::with_ieee_denormals(|| {
            validate_action(&self.act_space, action)?;
            let [th, thdot] = self
                .state
                .ok_or(EnvError::NeedsReset("reset before stepping"))?;
            let u = action[0].clamp(-MAX_TORQUE, MAX_TORQUE);
            self.last_u = u;
            let costs =
                angle_normalize(th).powi(2) + 0.1 * thdot.powi(2) + (0.001f32 * (u * u)) as f64;
            let newthdot = thdot + (3.0 * G / 2.0 * th.sin() + (3.0f32 * u) as f64) * DT;
            let newthdot = newthdot.clamp(-MAX_SPEED, MAX_SPEED);
            let newth = th + newthdot * DT;
            self.state = Some([newth, newthdot]);
            Ok(Step {
                obs: self.obs([newth, newthdot]),
                reward: -costs,
                terminated: false,
                truncated: false,
                info: EnvInfo::default(),
            })
        })
    }
    fn max_episode_steps(&self) -> Option<usize> {
        Some(MAX_STEPS)
    }
}

impl Renderable for Pendulum {
    fn scene(&self) -> Scene {
        let (w, h) = (500u32, 500u32);
        let c = [250.0f32, 250.0];
        let th = self.state.map_or(0.0, |s| s[0]) as f32;
        // θ = 0 is upright; image y points down.
        let tip = [c[0] + 200.0 * th.sin(), c[1] - 200.0 * th.cos()];
        let mut shapes = vec![Shape::Line {
            from: c,
            to: tip,
            color: [204, 77, 77],
            width: 40.0,
        }];
        let disc = |r: f32, p: [f32; 2]| -> Vec<[f32; 2]> {
            (0..24)
                .map(|k| {
                    let a = k as f32 * std::f32::consts::TAU / 24.0;
                    [p[0] + r * a.cos(), p[1] + r * a.sin()]
                })
                .collect()
        };
        shapes.push(Shape::Polygon {
            points: disc(20.0, c),
            fill: [204, 77, 77],
            outline: None,
        });
        shapes.push(Shape::Polygon {
            points: disc(5.0, c),
            fill: [0, 0, 0],
            outline: None,
        });
        // Torque indicator: a bar whose length is the last torque.
        let len = 50.0 * self.last_u;
        shapes.push(Shape::Line {
            from: [c[0], 470.0],
            to: [c[0] + len, 470.0],
            color: [0, 0, 0],
            width: 6.0,
        });
        Scene {
            width: w,
            height: h,
            background: [255, 255, 255],
            shapes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_velocity_variant_shares_dynamics() {
        let mut full = Pendulum::new(false);
        let mut pomdp = Pendulum::new(true);
        let (a, _) = full.reset(Some(5)).unwrap();
        let (b, _) = pomdp.reset(Some(5)).unwrap();
        assert_eq!(&a[..2], &b[..]);
        for t in 0..50 {
            let u = [((t % 5) as f32 - 2.0) * 0.7];
            let sa = full.step(&u).unwrap();
            let sb = pomdp.step(&u).unwrap();
            assert_eq!(&sa.obs[..2], &sb.obs[..]);
            assert_eq!(sa.reward, sb.reward);
            assert!(sa.reward <= 0.0 && sa.reward >= -16.3);
        }
    }

    #[test]
    fn angle_normalize_matches_python_modulo() {
        use std::f64::consts::PI;
        assert!((angle_normalize(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        assert!((angle_normalize(-3.0 * PI / 2.0) - PI / 2.0).abs() < 1e-12);
        assert_eq!(angle_normalize(0.0), 0.0);
    }
}
