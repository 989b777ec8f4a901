//! Line charts (learning curves) as [`Scene`]s: axes with numeric ticks, labels, a legend,
//! text drawn from the public-domain 8x8 bitmap font of the `font8x8` crate.

use font8x8::UnicodeFonts;

use crate::{Rgb, Scene, Shape};

/// Distinguishable series colours (Tableau 10).
pub const PALETTE: [Rgb; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// One line of a chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// `(x, y)` points in drawing order; non-finite points break the line.
    pub points: Vec<(f64, f64)>,
    /// Colour.
    pub color: Rgb,
}

/// A line chart.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Title above the chart.
    pub title: String,
    /// Label under the x axis.
    pub x_label: String,
    /// Label of the y axis (written above it).
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
}

const BLACK: Rgb = [0, 0, 0];
const GRID: Rgb = [225, 225, 225];

/// Squares for each lit pixel of `text` in the 8x8 font, top-left at `(x, y)`, each font pixel
/// `scale` image pixels wide. Characters without a glyph are drawn as `?`.
pub fn text(text: &str, x: f32, y: f32, scale: f32, color: Rgb) -> Vec<Shape> {
    let mut shapes = Vec::new();
    for (i, ch) in text.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS
            .get(ch)
            .or_else(|| font8x8::LATIN_FONTS.get(ch))
            .or_else(|| font8x8::BASIC_FONTS.get('?'))
            .unwrap_or([0; 8]);
        let gx = x + i as f32 * 8.0 * scale;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits & (1 << col) != 0 {
                    let (px, py) = (gx + col as f32 * scale, y + row as f32 * scale);
                    shapes.push(Shape::Polygon {
                        points: vec![
                            [px, py],
                            [px + scale, py],
                            [px + scale, py + scale],
                            [px, py + scale],
                        ],
                        fill: color,
                        outline: None,
                    });
                }
            }
        }
    }
    shapes
}

/// Width in pixels of `s` drawn by [`text`] at `scale`.
pub fn text_width(s: &str, scale: f32) -> f32 {
    s.chars().count() as f32 * 8.0 * scale
}

/// About `n` round tick values covering `[lo, hi]` (steps of 1, 2 or 5 times a power of 10).
pub fn nice_ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo || n == 0 {
        return vec![lo];
    }
    let raw = (hi - lo) / n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A tick label: integers without decimals, large values with k / M suffixes.
pub fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a >= 1e6 && (v / 1e6).fract().abs() < 1e-9 {
        format!("{}M", v / 1e6)
    } else if a >= 1e6 {
        format!("{:.1}M", v / 1e6)
    } else if a >= 1e4 && (v / 1e3).fract().abs() < 1e-9 {
        format!("{}k", v / 1e3)
    } else if v.fract().abs() < 1e-9 {
        format!("{}", v as i64)
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

impl LinePlot {
    /// The chart drawn into the rectangle `(x0, y0, w, h)` of an image.
    pub fn shapes(&self, x0: f32, y0: f32, w: f32, h: f32) -> Vec<Shape> {
        let mut out = Vec::new();
        let (left, right, top, bottom) = (x0 + 70.0, x0 + w - 15.0, y0 + 40.0, y0 + h - 45.0);
        out.extend(text(
            &self.title,
            x0 + (w - text_width(&self.title, 2.0)) / 2.0,
            y0 + 6.0,
            2.0,
            BLACK,
        ));
        out.extend(text(&self.y_label, left - 60.0, top - 14.0, 1.0, BLACK));
        out.extend(text(
            &self.x_label,
            left + (right - left - text_width(&self.x_label, 1.0)) / 2.0,
            bottom + 28.0,
            1.0,
            BLACK,
        ));
        let pts = || {
            self.series
                .iter()
                .flat_map(|s| s.points.iter())
                .filter(|(x, y)| x.is_finite() && y.is_finite())
        };
        let (mut xlo, mut xhi, mut ylo, mut yhi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(x, y) in pts() {
            xlo = xlo.min(x);
            xhi = xhi.max(x);
            ylo = ylo.min(y);
            yhi = yhi.max(y);
        }
        if xlo > xhi {
            (xlo, xhi, ylo, yhi) = (0.0, 1.0, 0.0, 1.0);
        }
        if xhi - xlo < 1e-12 {
            xhi = xlo + 1.0;
        }
        let pad = ((yhi - ylo) * 0.05).max(1e-9);
        let (ylo, yhi) = if yhi - ylo < 1e-12 {
            (ylo - 1.0, yhi + 1.0)
        } else {
            (ylo - pad, yhi + pad)
        };
        let sx = |x: f64| left + ((x - xlo) / (xhi - xlo)) as f32 * (right - left);
        let sy = |y: f64| bottom - ((y - ylo) / (yhi - ylo)) as f32 * (bottom - top);
        let line = |from: [f32; 2], to: [f32; 2], color: Rgb, width: f32| Shape::Line {
            from,
            to,
            color,
            width,
        };
        for t in nice_ticks(ylo, yhi, 6) {
            let y = sy(t);
            out.push(line([left, y], [right, y], GRID, 1.0));
            let l = tick_label(t);
            out.extend(text(
                &l,
                left - 6.0 - text_width(&l, 1.0),
                y - 4.0,
                1.0,
                BLACK,
            ));
        }
        for t in nice_ticks(xlo, xhi, 6) {
            let x = sx(t);
            out.push(line([x, top], [x, bottom], GRID, 1.0));
            let l = tick_label(t);
            out.extend(text(
                &l,
                x - text_width(&l, 1.0) / 2.0,
                bottom + 8.0,
                1.0,
                BLACK,
            ));
        }
        out.push(line([left, bottom], [right, bottom], BLACK, 1.5));
        out.push(line([left, top], [left, bottom], BLACK, 1.5));
        for s in &self.series {
            let mut prev: Option<[f32; 2]> = None;
            for &(x, y) in &s.points {
                if !(x.is_finite() && y.is_finite()) {
                    prev = None;
                    continue;
                }
                let p = [sx(x), sy(y)];
                if let Some(q) = prev {
                    out.push(line(q, p, s.color, 2.0));
                } else if s.points.len() == 1 {
                    out.push(line([p[0] - 2.0, p[1]], [p[0] + 2.0, p[1]], s.color, 4.0));
                }
                prev = Some(p);
            }
        }
        // Legend, top left inside the axes.
        for (i, s) in self.series.iter().enumerate() {
            let y = top + 8.0 + i as f32 * 14.0;
            out.push(line(
                [left + 8.0, y + 4.0],
                [left + 28.0, y + 4.0],
                s.color,
                3.0,
            ));
            out.extend(text(&s.name, left + 34.0, y, 1.0, BLACK));
        }
        out
    }
}

/// Charts laid out in a grid of `cols` columns, each `w x h` pixels, on a white background.
pub fn figure(plots: &[LinePlot], cols: usize, w: u32, h: u32) -> Scene {
    let cols = cols.max(1);
    let rows = plots.len().div_ceil(cols).max(1);
    let mut shapes = Vec::new();
    for (i, p) in plots.iter().enumerate() {
        let (c, r) = ((i % cols) as f32, (i / cols) as f32);
        shapes.extend(p.shapes(c * w as f32, r * h as f32, w as f32, h as f32));
    }
    Scene {
        width: w * cols as u32,
        height: h * rows as u32,
        background: [255, 255, 255],
        shapes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rasterize;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(
            nice_ticks(0.0, 10.0, 5),
            vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
        );
        assert_eq!(
            nice_ticks(-1300.0, -150.0, 6),
            vec![-1200.0, -1000.0, -800.0, -600.0, -400.0, -200.0]
        );
        assert_eq!(tick_label(50_000.0), "50k");
        assert_eq!(tick_label(2_000_000.0), "2M");
        assert_eq!(tick_label(-250.0), "-250");
        assert_eq!(tick_label(0.25), "0.25");
    }

    #[test]
    fn a_chart_draws_its_lines_and_text() {
        let plot = LinePlot {
            title: "eval".into(),
            x_label: "env steps".into(),
            y_label: "return".into(),
            series: vec![Series {
                name: "rdpg".into(),
                points: vec![(0.0, -1200.0), (25_000.0, -600.0), (50_000.0, -200.0)],
                color: PALETTE[3],
            }],
        };
        let frame = rasterize(&figure(&[plot.clone(), plot], 2, 400, 300));
        assert_eq!((frame.width, frame.height), (800, 300));
        let red = frame
            .rgb
            .chunks(3)
            .filter(|p| p[0] > 150 && p[1] < 100)
            .count();
        let black = frame
            .rgb
            .chunks(3)
            .filter(|p| p.iter().all(|&c| c < 40))
            .count();
        assert!(red > 300, "series line: {red} red pixels");
        assert!(black > 1000, "axes and text: {black} dark pixels");
        // Text renders the glyph pixels of the font.
        // `A` is 0x0C 0x1E 0x33 0x33 0x3F 0x33 0x33 0x00: 28 lit pixels.
        assert_eq!(text("A", 0.0, 0.0, 1.0, BLACK).len(), 28);
    }
}
