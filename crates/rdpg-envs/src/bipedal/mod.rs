//! BipedalWalker-v3 and BipedalWalkerHardcore-v3, identical to Gymnasium 1.4's
//! `envs/box2d/bipedal_walker.py`.
//!
//! Identity is bit for bit: the physics is pybox2d's own Box2D 2.3.0 (crate `rdpg-box2d`), the
//! random stream is numpy's `Generator(PCG64(SeedSequence(seed)))` ([`NpRng`]), bodies are
//! created and destroyed in Gymnasium's order on one world reused across resets, and every
//! quantity Python computes in double precision is computed here in `f64` before being rounded
//! to `f32` exactly where Python rounds it. The parity tests in `tests/gymnasium_parity.rs`
//! compare whole episodes against traces recorded from Gymnasium with `==`.
//!
//! Actions are four `f32` torques in `[-1, 1]`. As in Gymnasium, components outside the range
//! act as if clipped (the motor speed uses the sign, the torque the clipped magnitude);
//! non-finite components and wrong lengths are rejected with an [`EnvError`].

mod terrain;

use rdpg_box2d::{BodyId, BodyKind, FixtureDef, JointId, RayHit, RevoluteDef, World};
use rdpg_core::env::validate_action;
use rdpg_core::rng::NpRng;
use rdpg_core::{BoxSpace, Env, EnvError, EnvInfo, Step};

use terrain::Terrain;
pub use terrain::TerrainKind;

/// Simulation frequency (Hz).
pub const FPS: f64 = 50.0;
/// Pixels per metre of the reference renderer; also scales the geometry.
pub const SCALE: f64 = 30.0;
const MOTORS_TORQUE: f64 = 80.0;
const SPEED_HIP: f32 = 4.0;
const SPEED_KNEE: f32 = 6.0;
const LIDAR_RANGE: f64 = 160.0 / SCALE;
const INITIAL_RANDOM: f64 = 5.0;
const HULL_POLY: [[f64; 2]; 5] = [
    [-30.0, 9.0],
    [6.0, 9.0],
    [34.0, 1.0],
    [34.0, -8.0],
    [-30.0, -8.0],
];
const LEG_DOWN: f64 = -8.0 / SCALE;
const LEG_W: f64 = 8.0 / SCALE;
const LEG_H: f64 = 34.0 / SCALE;
/// Width of the reference viewport in pixels.
pub const VIEWPORT_W: f64 = 600.0;
/// Height of the reference viewport in pixels.
pub const VIEWPORT_H: f64 = 400.0;
/// Horizontal distance between terrain points (metres).
pub const TERRAIN_STEP: f64 = 14.0 / SCALE;
/// Number of terrain points.
pub const TERRAIN_LENGTH: usize = 200;
/// Mean ground height (metres).
pub const TERRAIN_HEIGHT: f64 = VIEWPORT_H / SCALE / 4.0;
const TERRAIN_GRASS: usize = 10;
const TERRAIN_STARTPAD: usize = 20;
/// Time limit of BipedalWalker-v3 (steps).
pub const MAX_STEPS_NORMAL: usize = 1600;
/// Time limit of BipedalWalkerHardcore-v3 (steps).
pub const MAX_STEPS_HARDCORE: usize = 2000;
/// Observation size: hull (4), two legs (2 x 5), lidar (10).
pub const OBS_DIM: usize = 24;
/// Action size: hip and knee torques of both legs.
pub const ACT_DIM: usize = 4;

// Contact-event tags of the bodies.
const TAG_TERRAIN: u64 = 0;
const TAG_HULL: u64 = 1;
const TAG_LEG0: u64 = 2; // legs[i] gets TAG_LEG0 + i

/// Which reward the walker pays. Every reported number must name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WalkerReward {
    /// Gymnasium's reward: progress shaping minus 5·|hull angle|, minus a torque cost, −100 on a
    /// fall.
    #[default]
    Stock,
    /// The reward of the paper's released code (patched v2): progress shaping only (no
    /// hull-angle term, no torque cost), −20 on a fall.
    Paper,
}

impl WalkerReward {
    /// The name used in configs, summaries and tables (`stock`, `paper`).
    pub fn as_str(self) -> &'static str {
        match self {
            WalkerReward::Stock => "stock",
            WalkerReward::Paper => "paper",
        }
    }
}

/// Configuration of a walker.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WalkerConfig {
    /// Stumps, stairs and pits (BipedalWalkerHardcore-v3).
    pub hardcore: bool,
    /// Reward paid by `step` (the stock reward is always in `info.stock_reward` otherwise).
    pub reward: WalkerReward,
    /// Build a new Box2D world at every reset. Gymnasium's walker keeps one world for its
    /// whole life, and Box2D's internal state (proxy ids, allocator free lists) carries over
    /// the resets, so the contacts of an episode, and from the first one on its trajectory,
    /// can depend on the episodes before it (the same in Gymnasium and here, bit for bit).
    /// With a fresh world each episode is a function of its seed and actions alone, equal to
    /// the first episode of a new Gymnasium env: what training needs to rebuild an episode
    /// in progress from a checkpoint. Default: off (Gymnasium's behaviour).
    pub fresh_world: bool,
}

/// A drawable terrain piece kept for rendering.
#[derive(Debug, Clone)]
pub(crate) struct TerrainBody {
    pub id: BodyId,
    pub fill: [u8; 3],
    pub outline: [u8; 3],
}

/// The walker environment (without time limit: wrap it in
/// [`TimeLimit`](crate::wrappers::TimeLimit) or use [`crate::make`]).
pub struct BipedalWalker {
    config: WalkerConfig,
    id: &'static str,
    world: World,
    rng: Option<NpRng>,
    obs_space: BoxSpace,
    act_space: BoxSpace,
    terrain: Terrain,
    /// Terrain bodies in Gymnasium's `self.terrain` order (reversed creation order).
    terrain_bodies: Vec<TerrainBody>,
    hull: Option<BodyId>,
    legs: Vec<BodyId>,
    joints: Vec<JointId>,
    ground_contact: [bool; 4],
    game_over: bool,
    prev_shaping: Option<f64>,
    prev_shaping_paper: Option<f64>,
    initial_push: f64,
    lidar: [RayHit; 10],
    lidar_origin: [f32; 2],
    scroll: f64,
    elapsed: usize,
    episode_over: bool,
}

impl BipedalWalker {
    /// A walker with the given configuration; call [`Env::reset`] before stepping.
    pub fn new(config: WalkerConfig) -> Result<Self, EnvError> {
        let world = World::new([0.0, -10.0], true).map_err(phys)?;
        let pi = std::f32::consts::PI;
        let mut low = vec![
            -pi, -5.0, -5.0, -5.0, -pi, -5.0, -pi, -5.0, -0.0, -pi, -5.0, -pi, -5.0, -0.0,
        ];
        let mut high = vec![
            pi, 5.0, 5.0, 5.0, pi, 5.0, pi, 5.0, 5.0, pi, 5.0, pi, 5.0, 5.0,
        ];
        low.extend([-1.0; 10]);
        high.extend([1.0; 10]);
        Ok(Self {
            config,
            id: if config.hardcore {
                "BipedalWalkerHardcore-v3"
            } else {
                "BipedalWalker-v3"
            },
            world,
            rng: None,
            obs_space: BoxSpace::new(low, high),
            act_space: BoxSpace::uniform(ACT_DIM, -1.0, 1.0),
            terrain: Terrain::default(),
            terrain_bodies: Vec::new(),
            hull: None,
            legs: Vec::new(),
            joints: Vec::new(),
            ground_contact: [false; 4],
            game_over: false,
            prev_shaping: None,
            prev_shaping_paper: None,
            initial_push: 0.0,
            lidar: [RayHit {
                fraction: 1.0,
                point: [0.0; 2],
            }; 10],
            lidar_origin: [0.0; 2],
            scroll: 0.0,
            elapsed: 0,
            episode_over: true,
        })
    }

    /// The configuration this walker was built with.
    pub fn config(&self) -> WalkerConfig {
        self.config
    }

    /// Terrain heights of the current episode: `(x, y)` of the 200 terrain points.
    pub fn terrain_points(&self) -> (&[f64], &[f64]) {
        (&self.terrain.x, &self.terrain.y)
    }

    /// Number of static terrain bodies (obstacle polygons plus the 199 edges).
    pub fn terrain_body_count(&self) -> usize {
        self.terrain_bodies.len()
    }

    /// The x force pushed on the hull at the start of the episode (drawn after the clouds).
    pub fn initial_push(&self) -> f64 {
        self.initial_push
    }

    /// Hull position `(x, y)` in metres, if an episode is running.
    pub fn hull_position(&self) -> Option<[f32; 2]> {
        let s = self.world.body_state(self.hull?).ok()?;
        Some([s.x, s.y])
    }

    /// x beyond which the course is finished (the episode terminates with success).
    pub fn finish_x() -> f64 {
        (TERRAIN_LENGTH - TERRAIN_GRASS) as f64 * TERRAIN_STEP
    }

    /// The random generator, created from OS entropy on first use (as Gymnasium does).
    fn rng(&mut self) -> &mut NpRng {
        self.rng.get_or_insert_with(NpRng::from_entropy)
    }

    /// Gymnasium's `_destroy`: terrain in list order, hull, then legs.
    fn destroy(&mut self) -> Result<(), EnvError> {
        if self.terrain_bodies.is_empty() {
            return Ok(());
        }
        self.world.set_contact_recording(false);
        for t in std::mem::take(&mut self.terrain_bodies) {
            self.world.destroy_body(t.id).map_err(phys)?;
        }
        if let Some(h) = self.hull.take() {
            self.world.destroy_body(h).map_err(phys)?;
        }
        for leg in std::mem::take(&mut self.legs) {
            self.world.destroy_body(leg).map_err(phys)?;
        }
        self.joints.clear();
        Ok(())
    }

    fn create_body_and_legs(&mut self) -> Result<(), EnvError> {
        let init_x = TERRAIN_STEP * TERRAIN_STARTPAD as f64 / 2.0;
        let init_y = TERRAIN_HEIGHT + 2.0 * LEG_H;
        let w = &mut self.world;
        let hull = w.create_body(
            BodyKind::Dynamic,
            [init_x as f32, init_y as f32],
            0.0,
            TAG_HULL,
        );
        let hull_poly: Vec<[f32; 2]> = HULL_POLY
            .iter()
            .map(|[x, y]| [(x / SCALE) as f32, (y / SCALE) as f32])
            .collect();
        let hull_fd = FixtureDef {
            density: 5.0,
            friction: 0.1,
            restitution: 0.0,
            category_bits: 0x0020,
            mask_bits: 0x0001,
            ..FixtureDef::default()
        };
        w.add_polygon(hull, &hull_poly, &hull_fd).map_err(phys)?;
        self.hull = Some(hull);
        let push = self.rng().uniform(-INITIAL_RANDOM, INITIAL_RANDOM);
        self.initial_push = push;
        let w = &mut self.world;
        w.apply_force_to_center(hull, [push as f32, 0.0], true)
            .map_err(phys)?;

        let leg_fd = FixtureDef {
            density: 1.0,
            restitution: 0.0,
            category_bits: 0x0020,
            mask_bits: 0x0001,
            ..FixtureDef::default()
        };
        let hull_angle = w.body_state(hull).map_err(phys)?.angle;
        for (k, i) in [-1.0f64, 1.0].into_iter().enumerate() {
            let angle = (i * 0.05) as f32;
            let upper = w.create_body(
                BodyKind::Dynamic,
                [init_x as f32, (init_y - LEG_H / 2.0 - LEG_DOWN) as f32],
                angle,
                TAG_LEG0 + 2 * k as u64,
            );
            w.add_box(upper, (LEG_W / 2.0) as f32, (LEG_H / 2.0) as f32, &leg_fd)
                .map_err(phys)?;
            let hip = w
                .create_revolute(&RevoluteDef {
                    body_a: hull,
                    body_b: upper,
                    local_anchor_a: [0.0, LEG_DOWN as f32],
                    local_anchor_b: [0.0, (LEG_H / 2.0) as f32],
                    // pybox2d sets referenceAngle = bodyB.angle - bodyA.angle (in Python floats).
                    reference_angle: (angle as f64 - hull_angle as f64) as f32,
                    enable_limit: true,
                    lower_angle: -0.8,
                    upper_angle: 1.1,
                    enable_motor: true,
                    motor_speed: i as f32,
                    max_motor_torque: MOTORS_TORQUE as f32,
                    collide_connected: false,
                })
                .map_err(phys)?;
            let lower = w.create_body(
                BodyKind::Dynamic,
                [
                    init_x as f32,
                    (init_y - LEG_H * 3.0 / 2.0 - LEG_DOWN) as f32,
                ],
                angle,
                TAG_LEG0 + 2 * k as u64 + 1,
            );
            w.add_box(
                lower,
                (0.8 * LEG_W / 2.0) as f32,
                (LEG_H / 2.0) as f32,
                &leg_fd,
            )
            .map_err(phys)?;
            let knee = w
                .create_revolute(&RevoluteDef {
                    body_a: upper,
                    body_b: lower,
                    local_anchor_a: [0.0, (-LEG_H / 2.0) as f32],
                    local_anchor_b: [0.0, (LEG_H / 2.0) as f32],
                    // bodyB.angle - bodyA.angle: both legs share `angle`.
                    reference_angle: 0.0,
                    enable_limit: true,
                    lower_angle: -1.6,
                    upper_angle: -0.1,
                    enable_motor: true,
                    motor_speed: 1.0,
                    max_motor_torque: MOTORS_TORQUE as f32,
                    collide_connected: false,
                })
                .map_err(phys)?;
            self.legs.extend([upper, lower]);
            self.joints.extend([hip, knee]);
        }
        Ok(())
    }

    /// One physics step with `action`; returns (obs, stock reward, paper reward, terminated,
    /// success).
    fn advance(
        &mut self,
        action: [f32; 4],
    ) -> Result<([f32; OBS_DIM], f64, f64, bool, bool), EnvError> {
        let hull = self
            .hull
            .ok_or(EnvError::NeedsReset("no episode running"))?;
        for (j, a) in action.iter().enumerate() {
            let speed = if j % 2 == 0 { SPEED_HIP } else { SPEED_KNEE };
            // float(SPEED * np.sign(a)) and float(80 * np.clip(np.abs(a), 0, 1)), in float32.
            let torque = MOTORS_TORQUE as f32 * a.abs().clamp(0.0, 1.0);
            self.world
                .set_motor(self.joints[j], speed * np_sign(*a), torque)
                .map_err(phys)?;
        }
        self.world.clear_contact_events();
        self.world.step((1.0 / FPS) as f32, 6 * 30, 2 * 30);
        for e in self.world.contact_events() {
            let tags = [e.tag_a, e.tag_b];
            if e.begin && tags.contains(&TAG_HULL) {
                self.game_over = true;
            }
            for leg in [1usize, 3] {
                if tags.contains(&(TAG_LEG0 + leg as u64)) {
                    self.ground_contact[leg] = e.begin;
                }
            }
        }

        let h = self.world.body_state(hull).map_err(phys)?;
        self.lidar_origin = [h.x, h.y];
        for (i, hit) in self.lidar.iter_mut().enumerate() {
            let a = 1.5 * i as f64 / 10.0;
            let p2 = [
                (h.x as f64 + a.sin() * LIDAR_RANGE) as f32,
                (h.y as f64 - a.cos() * LIDAR_RANGE) as f32,
            ];
            *hit = self.world.raycast_closest([h.x, h.y], p2, 0x0001);
        }
        let j = |k: usize| -> Result<(f64, f64), EnvError> {
            Ok((
                self.world.joint_angle(self.joints[k]).map_err(phys)? as f64,
                self.world.joint_speed(self.joints[k]).map_err(phys)? as f64,
            ))
        };
        let (a0, s0) = j(0)?;
        let (a1, s1) = j(1)?;
        let (a2, s2) = j(2)?;
        let (a3, s3) = j(3)?;
        let contact = |k: usize| if self.ground_contact[k] { 1.0 } else { 0.0 };
        let mut obs = [0f32; OBS_DIM];
        let head: [f64; 14] = [
            h.angle as f64,
            2.0 * h.angular_velocity as f64 / FPS,
            0.3 * h.vx as f64 * (VIEWPORT_W / SCALE) / FPS,
            0.3 * h.vy as f64 * (VIEWPORT_H / SCALE) / FPS,
            a0,
            s0 / SPEED_HIP as f64,
            a1 + 1.0,
            s1 / SPEED_KNEE as f64,
            contact(1),
            a2,
            s2 / SPEED_HIP as f64,
            a3 + 1.0,
            s3 / SPEED_KNEE as f64,
            contact(3),
        ];
        for (o, v) in obs.iter_mut().zip(head) {
            *o = v as f32;
        }
        for (o, hit) in obs[14..].iter_mut().zip(&self.lidar) {
            *o = hit.fraction;
        }
        self.scroll = h.x as f64 - VIEWPORT_W / SCALE / 5.0;

        // Stock reward, with Python's types: doubles for the shaping, then float32 as soon as
        // the float32 torque cost is subtracted (NumPy 2 promotion rules).
        let progress = 130.0 * h.x as f64 / SCALE;
        let shaping = progress - 5.0 * (h.angle as f64).abs();
        let mut reward = self.prev_shaping.map_or(0.0, |p| shaping - p);
        self.prev_shaping = Some(shaping);
        let cost_scale = (0.00035 * MOTORS_TORQUE) as f32;
        let mut reward32 = reward as f32;
        for a in action {
            reward32 -= cost_scale * a.abs().clamp(0.0, 1.0);
        }
        reward = reward32 as f64;
        // The paper's reward: progress only, no torque cost.
        let mut paper = self.prev_shaping_paper.map_or(0.0, |p| progress - p);
        self.prev_shaping_paper = Some(progress);

        let mut terminated = false;
        let mut success = false;
        if self.game_over || h.x < 0.0 {
            reward = -100.0;
            paper = -20.0;
            terminated = true;
        }
        if h.x as f64 > Self::finish_x() {
            success = !terminated;
            terminated = true;
        }
        self.elapsed += 1;
        Ok((obs, reward, paper, terminated, success))
    }

    pub(crate) fn scene_parts(&self) -> render::SceneParts<'_> {
        render::SceneParts {
            world: &self.world,
            terrain: &self.terrain,
            terrain_bodies: &self.terrain_bodies,
            legs: &self.legs,
            hull: self.hull,
            lidar: &self.lidar,
            lidar_origin: self.lidar_origin,
            scroll: self.scroll,
            elapsed: self.elapsed,
        }
    }
}

pub(crate) mod render;

fn phys(e: rdpg_box2d::PhysicsError) -> EnvError {
    EnvError::Physics(e.to_string())
}

/// `np.sign` for float32: ±1, and ±0 passed through.
fn np_sign(a: f32) -> f32 {
    if a > 0.0 {
        1.0
    } else if a < 0.0 {
        -1.0
    } else {
        a
    }
}

impl Env for BipedalWalker {
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
        // Physics in IEEE mode whatever the thread (learners flush subnormals).
        rdpg_core::fpmode::with_ieee_denormals(|| {
            if rng.is_some() {
                self.rng = rng;
            }
            if self.config.fresh_world {
                // Dropping the old world frees every body, joint and contact it holds.
                self.world = World::new([0.0, -10.0], true).map_err(phys)?;
                self.terrain_bodies.clear();
                self.hull = None;
                self.legs.clear();
                self.joints.clear();
            } else {
                self.destroy()?;
            }
            self.world.set_contact_recording(true);
            self.game_over = false;
            self.prev_shaping = None;
            self.prev_shaping_paper = None;
            self.scroll = 0.0;
            self.ground_contact = [false; 4];
            self.elapsed = 0;
            let hardcore = self.config.hardcore;
            let rng = self.rng.get_or_insert_with(NpRng::from_entropy);
            self.terrain = Terrain::generate(rng, hardcore);
            self.terrain_bodies = self
                .terrain
                .build(&mut self.world, TAG_TERRAIN)
                .map_err(phys)?;
            terrain::draw_clouds(rng, &mut self.terrain);
            self.create_body_and_legs()?;
            self.episode_over = false;
            // Gymnasium returns the observation of one real step with a zero action; that step is
            // not counted by the time limit.
            let (obs, ..) = self.advance([0.0; 4])?;
            self.elapsed = 0;
            Ok((obs.to_vec(), EnvInfo::default()))
        })
    }

    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        // Physics in IEEE mode whatever the thread (learners flush subnormals).
        rdpg_core::fpmode::with_ieee_denormals(|| {
            validate_action(&self.act_space, action)?;
            if self.episode_over {
                return Err(EnvError::NeedsReset("the episode is over"));
            }
            let (obs, stock, paper, terminated, success) =
                self.advance([action[0], action[1], action[2], action[3]])?;
            self.episode_over = terminated;
            let (reward, stock_reward) = match self.config.reward {
                WalkerReward::Stock => (stock, None),
                WalkerReward::Paper => (paper, Some(stock)),
            };
            Ok(Step {
                obs: obs.to_vec(),
                reward,
                terminated,
                truncated: false,
                info: EnvInfo {
                    success,
                    stock_reward,
                    course: self
                        .hull_position()
                        .map(|h| self.terrain.course_at(f64::from(h[0]))),
                },
            })
        })
    }

    fn max_episode_steps(&self) -> Option<usize> {
        Some(if self.config.hardcore {
            MAX_STEPS_HARDCORE
        } else {
            MAX_STEPS_NORMAL
        })
    }
}

impl crate::Renderable for BipedalWalker {
    fn scene(&self) -> rdpg_render::Scene {
        self.scene_parts().scene()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_episode() {
        let run = || {
            let mut env = BipedalWalker::new(WalkerConfig {
                hardcore: true,
                ..Default::default()
            })
            .unwrap();
            let (mut obs, _) = env.reset(Some(7)).unwrap();
            let mut total = 0.0;
            for t in 0..200 {
                let a = [((t % 7) as f32 - 3.0) / 3.0, 0.5, -0.5, 1.0];
                let s = env.step(&a).unwrap();
                total += s.reward;
                obs = s.obs;
                if s.terminated {
                    break;
                }
            }
            (obs, total)
        };
        assert_eq!(run(), run());
    }

    #[test]
    fn bad_actions_are_errors_not_crashes() {
        let mut env = BipedalWalker::new(WalkerConfig::default()).unwrap();
        assert!(matches!(env.step(&[0.0; 4]), Err(EnvError::NeedsReset(_))));
        env.reset(Some(0)).unwrap();
        assert!(matches!(
            env.step(&[0.0; 3]),
            Err(EnvError::ActionLength { .. })
        ));
        assert!(matches!(
            env.step(&[0.0, f32::NAN, 0.0, 0.0]),
            Err(EnvError::NonFiniteAction { index: 1, .. })
        ));
        // Out of range acts as clipped, like Gymnasium.
        let big = env.step(&[5.0, -5.0, 5.0, -5.0]).unwrap();
        assert!(big.obs.iter().all(|v| v.is_finite()));
    }

    /// With `fresh_world` an episode is a function of its seed and actions alone: after other
    /// episodes in the same env it equals the same episode in a new env. Without it, as in
    /// Gymnasium (checked with gymnasium 1.4.0: the same history effect, step for step),
    /// Box2D's state carried over the resets changes the trajectory of 1 of these 5 episodes.
    #[test]
    fn fresh_world_episodes_depend_on_seed_and_actions_alone() {
        let cfg = WalkerConfig {
            fresh_world: true,
            ..Default::default()
        };
        let mut rng = NpRng::from_seed(0);
        let mut diverged_without = 0;
        for trial in 0..5u64 {
            let actions: Vec<[f32; 4]> = (0..400)
                .map(|_| std::array::from_fn(|_| rng.uniform(-1.0, 1.0) as f32))
                .collect();
            let run = |fresh: bool, history: bool| {
                let mut env = BipedalWalker::new(WalkerConfig {
                    fresh_world: fresh,
                    ..cfg
                })
                .unwrap();
                if history {
                    for e in 0..3 {
                        env.reset(Some(100 + e + 10 * trial)).unwrap();
                        for a in actions.iter().rev() {
                            if env.step(a).unwrap().done() {
                                break;
                            }
                        }
                    }
                }
                let mut obs = vec![env.reset(Some(5 + trial)).unwrap().0];
                for a in &actions {
                    let s = env.step(a).unwrap();
                    obs.push(s.obs.clone());
                    if s.done() {
                        break;
                    }
                }
                obs
            };
            assert_eq!(run(true, true), run(true, false), "trial {trial}");
            diverged_without += (run(false, true) != run(false, false)) as usize;
        }
        assert_eq!(
            diverged_without, 1,
            "the history effect this option removes"
        );
    }

    #[test]
    fn paper_reward_pays_minus_20_on_a_fall() {
        let mut env = BipedalWalker::new(WalkerConfig {
            hardcore: false,
            reward: WalkerReward::Paper,
            ..Default::default()
        })
        .unwrap();
        env.reset(Some(1)).unwrap();
        // Kick backwards until the hull touches the ground.
        for _ in 0..1600 {
            let s = env.step(&[1.0, 1.0, 1.0, 1.0]).unwrap();
            if s.terminated {
                assert_eq!(s.reward, -20.0);
                assert_eq!(s.info.stock_reward, Some(-100.0));
                return;
            }
            assert!(s.info.stock_reward.is_some());
        }
        panic!("the walker never fell");
    }
}
