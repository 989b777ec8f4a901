//! Terrain and cloud generation, a line-by-line port of Gymnasium's `_generate_terrain` and
//! `_generate_clouds` (same random draws in the same order, same double arithmetic).

use super::{
    TerrainBody, SCALE, TERRAIN_GRASS, TERRAIN_HEIGHT, TERRAIN_LENGTH, TERRAIN_STARTPAD,
    TERRAIN_STEP, VIEWPORT_H,
};
use rdpg_box2d::{BodyKind, FixtureDef, PhysicsError, World};
use rdpg_core::rng::NpRng;
use rdpg_core::{Course, Obstacle};

const FRICTION: f32 = 2.5;
/// Gymnasium draws clouds with `3.14`, not π: keep it for identical cloud shapes.
#[allow(clippy::approx_constant)]
const GYM_PI: f64 = 3.14;

/// Terrain states of the generator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TerrainKind {
    /// Rolling grass.
    Grass = 0,
    /// A square stump.
    Stump = 1,
    /// A staircase up or down.
    Stairs = 2,
    /// A pit between two walls.
    Pit = 3,
}

impl TerrainKind {
    /// The obstacle this state draws (none for grass).
    fn obstacle(self) -> Option<Obstacle> {
        match self {
            Self::Grass => None,
            Self::Stump => Some(Obstacle::Stump),
            Self::Stairs => Some(Obstacle::Stairs),
            Self::Pit => Some(Obstacle::Pit),
        }
    }

    fn from_index(i: i64) -> Self {
        match i {
            1 => Self::Stump,
            2 => Self::Stairs,
            3 => Self::Pit,
            _ => Self::Grass,
        }
    }
}

/// The generated course: terrain points, obstacle polygons, render polygons and clouds.
#[derive(Debug, Clone, Default)]
pub(crate) struct Terrain {
    /// x of the 200 terrain points.
    pub x: Vec<f64>,
    /// y of the 200 terrain points.
    pub y: Vec<f64>,
    /// Obstacle polygons (stumps, stair steps, pit walls), in creation order.
    pub obstacles: Vec<Vec<[f64; 2]>>,
    /// Clouds: polygon, min x, max x.
    pub clouds: Vec<(Vec<[f64; 2]>, f64, f64)>,
    /// Each obstacle's kind and x extent `[from, to)`: the terrain points the generator spent
    /// in its state, in course order.
    pub spans: Vec<(Obstacle, f64, f64)>,
}

/// How far in front of an obstacle a hull counts as being at it (metres): about the hull's
/// length, so that a walker that trips while stepping onto it is counted there.
const AT_OBSTACLE_AHEAD: f64 = 4.0 * TERRAIN_STEP;

impl Terrain {
    /// Runs the generator, drawing from `rng` exactly as Gymnasium does.
    pub fn generate(rng: &mut NpRng, hardcore: bool) -> Self {
        let mut t = Terrain::default();
        let mut state = TerrainKind::Grass;
        let mut velocity = 0.0f64;
        let mut y = TERRAIN_HEIGHT;
        let mut counter: i64 = TERRAIN_STARTPAD as i64;
        let mut oneshot = false;
        let (mut stair_steps, mut stair_width, mut stair_height) = (0i64, 0i64, 0i64);
        let mut original_y = 0.0f64;
        for i in 0..TERRAIN_LENGTH {
            let x = i as f64 * TERRAIN_STEP;
            t.x.push(x);
            match (state, oneshot) {
                (TerrainKind::Grass, false) => {
                    velocity = 0.8 * velocity + 0.01 * np_sign(TERRAIN_HEIGHT - y);
                    if i > TERRAIN_STARTPAD {
                        velocity += rng.uniform(-1.0, 1.0) / SCALE;
                    }
                    y += velocity;
                }
                (TerrainKind::Pit, true) => {
                    counter = rng.integers(3, 5);
                    let poly = [
                        [x, y],
                        [x + TERRAIN_STEP, y],
                        [x + TERRAIN_STEP, y - 4.0 * TERRAIN_STEP],
                        [x, y - 4.0 * TERRAIN_STEP],
                    ];
                    t.obstacles.push(poly.to_vec());
                    let shift = TERRAIN_STEP * counter as f64;
                    t.obstacles
                        .push(poly.iter().map(|p| [p[0] + shift, p[1]]).collect());
                    counter += 2;
                    original_y = y;
                }
                (TerrainKind::Pit, false) => {
                    y = original_y;
                    if counter > 1 {
                        y -= 4.0 * TERRAIN_STEP;
                    }
                }
                (TerrainKind::Stump, true) => {
                    counter = rng.integers(1, 3);
                    let c = counter as f64;
                    t.obstacles.push(vec![
                        [x, y],
                        [x + c * TERRAIN_STEP, y],
                        [x + c * TERRAIN_STEP, y + c * TERRAIN_STEP],
                        [x, y + c * TERRAIN_STEP],
                    ]);
                }
                (TerrainKind::Stairs, true) => {
                    stair_height = if rng.random() > 0.5 { 1 } else { -1 };
                    stair_width = rng.integers(4, 5);
                    stair_steps = rng.integers(3, 5);
                    original_y = y;
                    for s in 0..stair_steps {
                        let (w, h) = (stair_width, stair_height);
                        t.obstacles.push(vec![
                            [
                                x + (s * w) as f64 * TERRAIN_STEP,
                                y + (s * h) as f64 * TERRAIN_STEP,
                            ],
                            [
                                x + ((1 + s) * w) as f64 * TERRAIN_STEP,
                                y + (s * h) as f64 * TERRAIN_STEP,
                            ],
                            [
                                x + ((1 + s) * w) as f64 * TERRAIN_STEP,
                                y + (-1 + s * h) as f64 * TERRAIN_STEP,
                            ],
                            [
                                x + (s * w) as f64 * TERRAIN_STEP,
                                y + (-1 + s * h) as f64 * TERRAIN_STEP,
                            ],
                        ]);
                    }
                    counter = stair_steps * stair_width;
                }
                (TerrainKind::Stairs, false) => {
                    let s = stair_steps * stair_width - counter - stair_height;
                    let n = s as f64 / stair_width as f64;
                    y = original_y + (n * stair_height as f64) * TERRAIN_STEP;
                }
                // GRASS right after a state change: a flat point, no draw.
                (TerrainKind::Grass, true) | (TerrainKind::Stump, false) => {}
            }
            if let Some(o) = state.obstacle() {
                match (oneshot, t.spans.last_mut()) {
                    (false, Some(span)) => span.2 = x + TERRAIN_STEP,
                    _ => t.spans.push((o, x, x + TERRAIN_STEP)),
                }
            }
            oneshot = false;
            t.y.push(y);
            counter -= 1;
            if counter == 0 {
                counter = rng.integers((TERRAIN_GRASS / 2) as i64, TERRAIN_GRASS as i64);
                if state == TerrainKind::Grass && hardcore {
                    state = TerrainKind::from_index(rng.integers(1, 4));
                } else {
                    state = TerrainKind::Grass;
                }
                oneshot = true;
            }
        }
        t
    }

    /// Where a hull at `x` is on this course: the obstacles it has passed and the one it is
    /// over or within [`AT_OBSTACLE_AHEAD`] in front of.
    pub fn course_at(&self, x: f64) -> Course {
        let mut c = Course::default();
        for &(o, from, to) in &self.spans {
            if to <= x {
                c.passed[o as usize] += 1;
            } else if c.at.is_none() && from <= x + AT_OBSTACLE_AHEAD {
                c.at = Some(o);
            }
        }
        c
    }

    /// Creates the static bodies (obstacles in generation order, then the 199 edges) and
    /// returns them in Gymnasium's `self.terrain` order, which is reversed.
    pub fn build(&self, world: &mut World, tag: u64) -> Result<Vec<TerrainBody>, PhysicsError> {
        let mut bodies = Vec::with_capacity(self.obstacles.len() + TERRAIN_LENGTH - 1);
        let polygon_fd = FixtureDef {
            friction: FRICTION,
            ..FixtureDef::default()
        };
        for poly in &self.obstacles {
            let id = world.create_body(BodyKind::Static, [0.0, 0.0], 0.0, tag);
            let pts: Vec<[f32; 2]> = poly.iter().map(|p| [p[0] as f32, p[1] as f32]).collect();
            world.add_polygon(id, &pts, &polygon_fd)?;
            bodies.push(TerrainBody {
                id,
                fill: [255, 255, 255],
                outline: [153, 153, 153],
            });
        }
        let edge_fd = FixtureDef {
            friction: FRICTION,
            category_bits: 0x0001,
            ..FixtureDef::default()
        };
        for i in 0..TERRAIN_LENGTH - 1 {
            let id = world.create_body(BodyKind::Static, [0.0, 0.0], 0.0, tag);
            world.add_edge(
                id,
                [self.x[i] as f32, self.y[i] as f32],
                [self.x[i + 1] as f32, self.y[i + 1] as f32],
                &edge_fd,
            )?;
            let color = [76, if i % 2 == 0 { 255 } else { 204 }, 76];
            bodies.push(TerrainBody {
                id,
                fill: color,
                outline: color,
            });
        }
        bodies.reverse();
        Ok(bodies)
    }
}

/// Gymnasium's `_generate_clouds`: 10 clouds of 5 points, 110 draws.
pub(crate) fn draw_clouds(rng: &mut NpRng, terrain: &mut Terrain) {
    terrain.clouds.clear();
    for _ in 0..TERRAIN_LENGTH / 20 {
        let x = rng.uniform(0.0, TERRAIN_LENGTH as f64) * TERRAIN_STEP;
        let y = VIEWPORT_H / SCALE * 3.0 / 4.0;
        let poly: Vec<[f64; 2]> = (0..5)
            .map(|a| {
                let a = a as f64;
                let px = x
                    + 15.0 * TERRAIN_STEP * (GYM_PI * 2.0 * a / 5.0).sin()
                    + rng.uniform(0.0, 5.0 * TERRAIN_STEP);
                let py = y
                    + 5.0 * TERRAIN_STEP * (GYM_PI * 2.0 * a / 5.0).cos()
                    + rng.uniform(0.0, 5.0 * TERRAIN_STEP);
                [px, py]
            })
            .collect();
        let x1 = poly.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
        let x2 = poly.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max);
        terrain.clouds.push((poly, x1, x2));
    }
}

/// `np.sign` of a double.
fn np_sign(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_terrain_has_no_obstacles_and_hardcore_has_some() {
        let normal = Terrain::generate(&mut NpRng::from_seed(0), false);
        assert!(normal.obstacles.is_empty());
        assert_eq!(normal.x.len(), TERRAIN_LENGTH);
        let hard = Terrain::generate(&mut NpRng::from_seed(0), true);
        assert!(!hard.obstacles.is_empty());
        // The start pad is flat in both.
        assert!(hard.y[..TERRAIN_STARTPAD]
            .iter()
            .all(|y| (y - TERRAIN_HEIGHT).abs() < 1e-9));
    }

    /// The obstacle spans hold the obstacle polygons: one stump each, two walls per pit, 3 or
    /// 4 stair steps per staircase, every polygon starting inside its span (the last span may
    /// be cut by the end of the course, past the finish line); grass has none.
    #[test]
    fn spans_hold_the_obstacles_they_name() {
        assert!(Terrain::generate(&mut NpRng::from_seed(0), false)
            .spans
            .is_empty());
        for seed in 0..30 {
            let t = Terrain::generate(&mut NpRng::from_seed(seed), true);
            assert!(!t.spans.is_empty());
            let mut held = 0;
            for (k, &(o, from, to)) in t.spans.iter().enumerate() {
                assert!(from < to, "seed {seed}, span {k}");
                let cut = to >= TERRAIN_LENGTH as f64 * TERRAIN_STEP - 1e-9;
                let inside = |x: f64| x >= from && (x < to || cut);
                let starts = t.obstacles.iter().filter(|p| inside(p[0][0])).count();
                let want = match o {
                    Obstacle::Stump => 1..=1,
                    Obstacle::Pit => 2..=2,
                    Obstacle::Stairs => 3..=4,
                };
                assert!(want.contains(&starts), "seed {seed}: {o:?} holds {starts}");
                held += starts;
            }
            assert_eq!(held, t.obstacles.len(), "seed {seed}");
        }
    }

    /// `course_at`: obstacles behind the hull are passed; the first one not passed is where
    /// the hull is if it is over it or within `AT_OBSTACLE_AHEAD` in front of it.
    #[test]
    fn course_at_counts_passed_obstacles_and_names_the_one_at_hand() {
        let t = Terrain {
            spans: vec![
                (Obstacle::Stump, 10.0, 11.0),
                (Obstacle::Pit, 20.0, 23.0),
                (Obstacle::Stump, 30.0, 31.0),
            ],
            ..Terrain::default()
        };
        let at = |x| t.course_at(x);
        assert_eq!(at(0.0), Course::default());
        assert_eq!(at(10.0 - AT_OBSTACLE_AHEAD).at, Some(Obstacle::Stump));
        assert_eq!(at(10.5).at, Some(Obstacle::Stump));
        assert_eq!(
            at(15.0),
            Course {
                passed: [1, 0, 0],
                at: None
            }
        );
        assert_eq!(
            at(21.0),
            Course {
                passed: [1, 0, 0],
                at: Some(Obstacle::Pit)
            }
        );
        assert_eq!(
            at(40.0),
            Course {
                passed: [2, 0, 1],
                at: None
            }
        );
    }
}
