//! Scene rasterisation on top of `tiny-skia`.
//!
//! Geometry is clipped here, in `f64`, to the image rectangle grown by a small margin
//! before it reaches `tiny-skia`: the part of a shape that can touch the image is kept
//! exactly, and `tiny-skia` only ever sees coordinates of the order of the image size,
//! whatever the input (far-away vertices, huge line widths).

use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Stroke, Transform};

use crate::{Frame, Rgb, Scene, Shape};

/// How far (in pixels) outside the image geometry is kept when clipping. Anything
/// farther than this cannot affect an image pixel, even through anti-aliasing or a
/// 1-px outline.
const CLIP_MARGIN: f64 = 4.0;

/// Polygons whose summed absolute fan-triangle area is below this (in square pixels)
/// are skipped: they cannot cover more than 1/1000 of a pixel in total.
const MIN_AREA: f64 = 1e-3;

/// Rasterises `scene` into an RGB [`Frame`] of `scene.width` x `scene.height`.
///
/// The frame is filled with `scene.background`, then the shapes are painted in order
/// (later ones on top), all anti-aliased, with coordinates in image pixels (x right,
/// y down; pixel `(i, j)` covers the square `[i, i+1] x [j, j+1]`, so its centre is
/// at `(i + 0.5, j + 0.5)`):
///
/// - [`Shape::Polygon`] is filled with the **non-zero winding** rule (convex and
///   simple concave polygons look the same under either rule; self-intersecting ones
///   are filled wherever the winding number is non-zero). The optional outline is an
///   anti-aliased 1-px hairline along the closed boundary, drawn over the fill.
/// - [`Shape::Line`] is a segment `width` pixels wide with butt (flat) ends that stop
///   exactly at `from` and `to`. Widths below 1 px give proportionally fainter lines.
///
/// Shapes partly or wholly outside the image are clipped. Shapes that cannot be
/// drawn are skipped silently: polygons with fewer than 3 points, zero area (all
/// points collinear) or any non-finite coordinate; lines with non-finite coordinates
/// or width, zero length, or width `<= 0`. This never panics.
///
/// Each shape is anti-aliased on its own, so two shapes sharing an edge that does not
/// lie on pixel boundaries let a faint trace of what is below show through along it
/// (as with most immediate-mode rasterisers, pygame's included).
///
/// A zero-sized scene gives an empty frame. A scene too large for `tiny-skia`
/// (width above about 536 million pixels) gives a frame filled with the background
/// only.
pub fn rasterize(scene: &Scene) -> Frame {
    let (w, h) = (scene.width, scene.height);
    if w == 0 || h == 0 {
        return Frame {
            width: w,
            height: h,
            rgb: Vec::new(),
        };
    }
    let Some(mut pixmap) = Pixmap::new(w, h) else {
        return Frame::new(w, h, scene.background);
    };
    let [r, g, b] = scene.background;
    pixmap.fill(Color::from_rgba8(r, g, b, 255));

    let clip = ClipRect {
        x0: -CLIP_MARGIN,
        y0: -CLIP_MARGIN,
        x1: f64::from(w) + CLIP_MARGIN,
        y1: f64::from(h) + CLIP_MARGIN,
    };
    for shape in &scene.shapes {
        match shape {
            Shape::Polygon {
                points,
                fill,
                outline,
            } => draw_polygon(&mut pixmap, &clip, points, *fill, *outline),
            Shape::Line {
                from,
                to,
                color,
                width,
            } => draw_line(&mut pixmap, &clip, *from, *to, *color, *width),
        }
    }

    // Every pixel is opaque (opaque background, opaque paint), so the premultiplied
    // RGBA data is plain RGBA: drop the alpha byte.
    let mut rgb = Vec::with_capacity(w as usize * h as usize * 3);
    for px in pixmap.data().chunks_exact(4) {
        rgb.extend_from_slice(&px[..3]);
    }
    Frame {
        width: w,
        height: h,
        rgb,
    }
}

fn paint(color: Rgb) -> Paint<'static> {
    let mut paint = Paint::default();
    paint.set_color_rgba8(color[0], color[1], color[2], 255);
    paint.anti_alias = true;
    paint
}

fn closed_path(points: &[[f64; 2]]) -> Option<tiny_skia::Path> {
    let (first, rest) = points.split_first()?;
    let mut pb = PathBuilder::with_capacity(points.len() + 1, points.len() + 1);
    pb.move_to(first[0] as f32, first[1] as f32);
    for p in rest {
        pb.line_to(p[0] as f32, p[1] as f32);
    }
    pb.close();
    pb.finish()
}

fn draw_polygon(
    pixmap: &mut Pixmap,
    clip: &ClipRect,
    points: &[[f32; 2]],
    fill: Rgb,
    outline: Option<Rgb>,
) {
    if points.iter().flatten().any(|c| !c.is_finite()) {
        return;
    }
    let pts: Vec<[f64; 2]> = points
        .iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1])])
        .collect();
    paint_polygon(pixmap, clip, &pts, fill, outline);
}

/// Clips and paints a polygon with finite coordinates (skipping degenerate ones).
fn paint_polygon(
    pixmap: &mut Pixmap,
    clip: &ClipRect,
    points: &[[f64; 2]],
    fill: Rgb,
    outline: Option<Rgb>,
) {
    if is_degenerate(points) {
        return;
    }
    let clipped = clip.clip_polygon(points);
    if clipped.len() < 3 {
        return;
    }
    let Some(path) = closed_path(&clipped) else {
        return;
    };
    pixmap.fill_path(
        &path,
        &paint(fill),
        FillRule::Winding,
        Transform::identity(),
        None,
    );
    if let Some(color) = outline {
        // Width 1 with anti-aliasing is drawn as a coverage-based hairline. Edges that
        // the clip introduced lie `CLIP_MARGIN` px outside the image, out of sight.
        let stroke = Stroke {
            width: 1.0,
            ..Stroke::default()
        };
        pixmap.stroke_path(&path, &paint(color), &stroke, Transform::identity(), None);
    }
}

fn draw_line(
    pixmap: &mut Pixmap,
    clip: &ClipRect,
    from: [f32; 2],
    to: [f32; 2],
    color: Rgb,
    width: f32,
) {
    if !(from.iter().chain(&to).all(|c| c.is_finite()) && width.is_finite() && width > 0.0) {
        return;
    }
    let (a, b) = (
        [f64::from(from[0]), f64::from(from[1])],
        [f64::from(to[0]), f64::from(to[1])],
    );
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy);
    if len == 0.0 || !len.is_finite() {
        return;
    }
    // A butt-capped stroke is exactly the rectangle around the segment: fill it as a
    // polygon, which also clips it exactly.
    let half = f64::from(width) / 2.0;
    let (nx, ny) = (-dy / len * half, dx / len * half);
    let quad = [
        [a[0] + nx, a[1] + ny],
        [b[0] + nx, b[1] + ny],
        [b[0] - nx, b[1] - ny],
        [a[0] - nx, a[1] - ny],
    ];
    paint_polygon(pixmap, clip, &quad, color, None);
}

/// True if the polygon cannot cover a visible area: the sum of the absolute areas of
/// its fan triangles (an upper bound on the filled area under any fill rule) is tiny,
/// e.g. because all points are collinear. Non-finite input also counts as degenerate.
fn is_degenerate(points: &[[f64; 2]]) -> bool {
    if points.len() < 3 {
        return true;
    }
    let p0 = points[0];
    let twice_area: f64 = points[1..]
        .windows(2)
        .map(|w| {
            let (u, v) = (
                [w[0][0] - p0[0], w[0][1] - p0[1]],
                [w[1][0] - p0[0], w[1][1] - p0[1]],
            );
            (u[0] * v[1] - u[1] * v[0]).abs()
        })
        .sum();
    !(twice_area.is_finite() && twice_area >= 2.0 * MIN_AREA)
}

/// An axis-aligned clipping rectangle.
struct ClipRect {
    x0: f64,
    y0: f64,
    x1: f64,
    y1: f64,
}

impl ClipRect {
    /// Sutherland–Hodgman clipping against the rectangle. For a non-convex polygon the
    /// result may contain zero-width slivers along the rectangle's border; they lie
    /// outside the image and the winding number of every point inside the rectangle is
    /// unchanged, so the visible fill is exactly that of the original polygon.
    fn clip_polygon(&self, points: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let mut poly = points.to_vec();
        let mut next = Vec::with_capacity(points.len() + 4);
        // (axis, bound, keep values >= bound?)
        for (axis, bound, keep_greater) in [
            (0, self.x0, true),
            (0, self.x1, false),
            (1, self.y0, true),
            (1, self.y1, false),
        ] {
            if poly.is_empty() {
                break;
            }
            next.clear();
            let inside = |p: &[f64; 2]| {
                if keep_greater {
                    p[axis] >= bound
                } else {
                    p[axis] <= bound
                }
            };
            let mut prev = poly[poly.len() - 1];
            let mut prev_in = inside(&prev);
            for &cur in &poly {
                let cur_in = inside(&cur);
                if cur_in != prev_in {
                    let t = (bound - prev[axis]) / (cur[axis] - prev[axis]);
                    let mut p = [
                        prev[0] + t * (cur[0] - prev[0]),
                        prev[1] + t * (cur[1] - prev[1]),
                    ];
                    p[axis] = bound;
                    next.push(p);
                }
                if cur_in {
                    next.push(cur);
                }
                prev = cur;
                prev_in = cur_in;
            }
            std::mem::swap(&mut poly, &mut next);
        }
        poly
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clip_keeps_inside_polygon() {
        let clip = ClipRect {
            x0: 0.0,
            y0: 0.0,
            x1: 10.0,
            y1: 10.0,
        };
        let tri = [[1.0, 1.0], [5.0, 1.0], [1.0, 5.0]];
        assert_eq!(clip.clip_polygon(&tri), tri.to_vec());
    }

    #[test]
    fn clip_cuts_big_square() {
        let clip = ClipRect {
            x0: 0.0,
            y0: 0.0,
            x1: 10.0,
            y1: 10.0,
        };
        let sq = [[-1e30, -1e30], [1e30, -1e30], [1e30, 1e30], [-1e30, 1e30]];
        let out = clip.clip_polygon(&sq);
        assert_eq!(out.len(), 4);
        for p in out {
            assert!((0.0..=10.0).contains(&p[0]) && (0.0..=10.0).contains(&p[1]));
        }
    }

    #[test]
    fn degenerate_detection() {
        assert!(is_degenerate(&[[0.0, 0.0], [1.0, 1.0]]));
        assert!(is_degenerate(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]));
        assert!(is_degenerate(&[[0.0, 0.0], [f64::NAN, 1.0], [2.0, 0.0]]));
        assert!(!is_degenerate(&[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]));
        // A bow-tie has zero signed area but is not degenerate.
        assert!(!is_degenerate(&[
            [0.0, 0.0],
            [2.0, 2.0],
            [2.0, 0.0],
            [0.0, 2.0]
        ]));
    }
}
