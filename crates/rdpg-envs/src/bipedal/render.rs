//! The walker drawn as Gymnasium's renderer draws it: sky, parallax clouds, terrain, obstacles,
//! legs, hull, one lidar ray at a time and the start flag, in a 600x400 view that follows the
//! hull.

use super::{
    terrain::Terrain, TerrainBody, SCALE, TERRAIN_HEIGHT, TERRAIN_STEP, VIEWPORT_H, VIEWPORT_W,
};
use rdpg_box2d::{BodyId, RayHit, World};
use rdpg_render::{Scene, Shape};

/// Borrowed state needed to draw one frame.
pub(crate) struct SceneParts<'a> {
    pub world: &'a World,
    pub terrain: &'a Terrain,
    pub terrain_bodies: &'a [TerrainBody],
    pub legs: &'a [BodyId],
    pub hull: Option<BodyId>,
    pub lidar: &'a [RayHit; 10],
    pub lidar_origin: [f32; 2],
    pub scroll: f64,
    pub elapsed: usize,
}

const LEG_COLORS: [([u8; 3], [u8; 3]); 2] = [
    ([178, 101, 152], [127, 76, 101]),
    ([128, 51, 102], [77, 26, 51]),
];

impl SceneParts<'_> {
    /// World metres to view pixels (x right, y down), the view starting at `scroll`.
    fn px(&self, x: f64, y: f64) -> [f32; 2] {
        [
            ((x - self.scroll) * SCALE) as f32,
            (VIEWPORT_H - y * SCALE) as f32,
        ]
    }

    pub fn scene(&self) -> Scene {
        let mut shapes = Vec::new();
        let scroll = self.scroll;
        let view_w = VIEWPORT_W / SCALE;
        for (poly, x1, x2) in &self.terrain.clouds {
            if *x2 < scroll / 2.0 || *x1 > scroll / 2.0 + view_w {
                continue;
            }
            // Clouds move at half speed: drawn at x + scroll / 2.
            let points = poly
                .iter()
                .map(|p| self.px(p[0] + scroll / 2.0, p[1]))
                .collect();
            shapes.push(Shape::Polygon {
                points,
                fill: [255, 255, 255],
                outline: None,
            });
        }
        let n = self.terrain.x.len();
        for i in 0..n.saturating_sub(1) {
            let (xa, xb) = (self.terrain.x[i], self.terrain.x[i + 1]);
            if xb < scroll || xa > scroll + view_w {
                continue;
            }
            let (ya, yb) = (self.terrain.y[i], self.terrain.y[i + 1]);
            let points = vec![
                self.px(xa, ya),
                self.px(xb, yb),
                self.px(xb, 0.0),
                self.px(xa, 0.0),
            ];
            shapes.push(Shape::Polygon {
                points,
                fill: [102, 153, 76],
                outline: None,
            });
        }
        // One lidar ray per frame, sweeping out and back, as Gymnasium's `lidar_render`.
        let k = (self.elapsed + 1) % 100;
        if k < 20 {
            let i = if k < 10 { k } else { 19 - k };
            let o = self.lidar_origin;
            let p = self.lidar[i].point;
            shapes.push(Shape::Line {
                from: self.px(o[0] as f64, o[1] as f64),
                to: self.px(p[0] as f64, p[1] as f64),
                color: [255, 0, 0],
                width: 1.0,
            });
        }
        for t in self.terrain_bodies {
            self.push_body(&mut shapes, t.id, t.fill, t.outline);
        }
        for (j, leg) in self.legs.iter().enumerate() {
            let (fill, outline) = LEG_COLORS[j / 2];
            self.push_body(&mut shapes, *leg, fill, outline);
        }
        if let Some(h) = self.hull {
            self.push_body(&mut shapes, h, [127, 51, 229], [76, 76, 127]);
        }
        let flag_x = TERRAIN_STEP * 3.0;
        let y1 = TERRAIN_HEIGHT;
        let y2 = y1 + 50.0 / SCALE;
        shapes.push(Shape::Line {
            from: self.px(flag_x, y1),
            to: self.px(flag_x, y2),
            color: [0, 0, 0],
            width: 1.0,
        });
        shapes.push(Shape::Polygon {
            points: vec![
                self.px(flag_x, y2),
                self.px(flag_x, y2 - 10.0 / SCALE),
                self.px(flag_x + 25.0 / SCALE, y2 - 5.0 / SCALE),
            ],
            fill: [230, 51, 0],
            outline: Some([0, 0, 0]),
        });
        Scene {
            width: VIEWPORT_W as u32,
            height: VIEWPORT_H as u32,
            background: [215, 215, 255],
            shapes,
        }
    }

    fn push_body(&self, shapes: &mut Vec<Shape>, id: BodyId, fill: [u8; 3], outline: [u8; 3]) {
        let mut f = 0;
        while let Ok(Some(points)) = self.world.fixture_outline(id, f) {
            f += 1;
            let pts: Vec<[f32; 2]> = points
                .iter()
                .map(|p| self.px(p[0] as f64, p[1] as f64))
                .collect();
            if pts.len() > 2 {
                let [x0, x1] = pts
                    .iter()
                    .fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], p| {
                        [a.min(p[0]), b.max(p[0])]
                    });
                if x1 < 0.0 || x0 > VIEWPORT_W as f32 {
                    continue;
                }
                shapes.push(Shape::Polygon {
                    points: pts,
                    fill,
                    outline: Some(outline),
                });
            } else if pts.len() == 2 {
                if pts[1][0] < 0.0 || pts[0][0] > VIEWPORT_W as f32 {
                    continue;
                }
                shapes.push(Shape::Line {
                    from: pts[0],
                    to: pts[1],
                    color: fill,
                    width: 1.0,
                });
            }
        }
    }
}
