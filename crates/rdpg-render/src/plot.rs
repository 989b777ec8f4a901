//! Line charts (learning curves) drawn with plotters into a [`Frame`]: axes with numeric ticks,
//! labels, a legend, a shaded band per series (e.g. the spread over seeds), text in DejaVu Sans
//! from the `dejavu` crate (never the machine's fonts).

use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::{Frame, RenderError, Rgb};

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
    /// `(x, low, high)`: a band shaded in the series' colour (e.g. mean ± std over seeds);
    /// empty for none.
    pub band: Vec<(f64, f64, f64)>,
}

/// A line chart.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Title above the chart.
    pub title: String,
    /// Label under the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
}

/// The font family every chart's text uses, registered once from the `dejavu` crate.
const FAMILY: &str = "sans-serif";

fn register_font() -> Result<(), RenderError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(RenderError::InvalidArgument(
            "the embedded DejaVu Sans font did not load".into(),
        ))
    }
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

fn plot_err(e: impl std::fmt::Display) -> RenderError {
    RenderError::InvalidArgument(format!("drawing a chart: {e}"))
}

/// `lo..hi` widened to a non-empty range with a margin of 5 % on each side.
fn padded(lo: f64, hi: f64) -> std::ops::Range<f64> {
    let (lo, hi) = if lo.is_finite() && hi.is_finite() {
        (lo, hi)
    } else {
        (0.0, 1.0)
    };
    let span = if hi > lo { hi - lo } else { lo.abs().max(1.0) };
    (lo - 0.05 * span)..(hi + 0.05 * span)
}

impl LinePlot {
    fn draw(&self, area: &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), RenderError> {
        let finite = |(x, y): &(f64, f64)| x.is_finite() && y.is_finite();
        let xs = self
            .series
            .iter()
            .flat_map(|s| s.points.iter().filter(|p| finite(p)).map(|p| p.0));
        let ys = self.series.iter().flat_map(|s| {
            s.points
                .iter()
                .filter(|p| finite(p))
                .map(|p| p.1)
                .chain(s.band.iter().flat_map(|b| [b.1, b.2]))
                .filter(|v| v.is_finite())
        });
        let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
        let (y0, y1) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
            (a.min(y), b.max(y))
        });
        let mut chart = ChartBuilder::on(area)
            .caption(&self.title, (FAMILY, 18))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(58)
            .build_cartesian_2d(padded(x0, x1), padded(y0, y1))
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .x_desc(&self.x_label)
            .y_desc(&self.y_label)
            .x_labels(6)
            .y_labels(6)
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .light_line_style(RGBColor(238, 238, 238))
            .label_style((FAMILY, 12))
            .axis_desc_style((FAMILY, 13))
            .draw()
            .map_err(plot_err)?;
        for s in &self.series {
            let c = RGBColor(s.color[0], s.color[1], s.color[2]);
            let band: Vec<&(f64, f64, f64)> = s
                .band
                .iter()
                .filter(|b| b.0.is_finite() && b.1.is_finite() && b.2.is_finite())
                .collect();
            if band.len() >= 2 {
                let outline: Vec<(f64, f64)> = band
                    .iter()
                    .map(|b| (b.0, b.2))
                    .chain(band.iter().rev().map(|b| (b.0, b.1)))
                    .collect();
                chart
                    .draw_series(std::iter::once(Polygon::new(outline, c.mix(0.2).filled())))
                    .map_err(plot_err)?;
            }
            // Non-finite points break the line into segments; the legend names the first.
            let mut segments: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
            for p in &s.points {
                match segments.last_mut() {
                    Some(seg) if finite(p) => seg.push(*p),
                    Some(seg) if !seg.is_empty() => segments.push(Vec::new()),
                    _ => {}
                }
            }
            for (k, seg) in segments.into_iter().filter(|g| !g.is_empty()).enumerate() {
                let drawn = chart
                    .draw_series(LineSeries::new(seg, c.stroke_width(2)))
                    .map_err(plot_err)?;
                if k == 0 {
                    drawn.label(s.name.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2))
                    });
                }
            }
        }
        if self.series.iter().any(|s| s.points.iter().any(finite)) {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerRight)
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(160, 160, 160))
                .label_font((FAMILY, 12))
                .draw()
                .map_err(plot_err)?;
        }
        Ok(())
    }
}

/// Charts laid out in a grid of `cols` columns, each `w x h` pixels, on a white background.
pub fn figure(plots: &[LinePlot], cols: usize, w: u32, h: u32) -> Result<Frame, RenderError> {
    register_font()?;
    let cols = cols.max(1);
    let rows = plots.len().div_ceil(cols).max(1);
    let (width, height) = (w * cols as u32, h * rows as u32);
    if width == 0 || height == 0 {
        return Err(RenderError::InvalidArgument(format!(
            "a {width}x{height} figure"
        )));
    }
    let mut rgb = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        let areas = root.split_evenly((rows, cols));
        for (p, area) in plots.iter().zip(&areas) {
            p.draw(area)?;
        }
        root.present().map_err(plot_err)?;
    }
    Ok(Frame { width, height, rgb })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(50_000.0), "50k");
        assert_eq!(tick_label(2_000_000.0), "2M");
        assert_eq!(tick_label(-250.0), "-250");
        assert_eq!(tick_label(0.25), "0.25");
    }

    #[test]
    fn a_chart_draws_its_lines_band_and_text() {
        let plot = LinePlot {
            title: "eval".into(),
            x_label: "env steps".into(),
            y_label: "return".into(),
            series: vec![Series {
                name: "rdpg".into(),
                points: vec![
                    (0.0, -1200.0),
                    (25_000.0, -600.0),
                    (f64::NAN, 0.0),
                    (50_000.0, -200.0),
                    (75_000.0, -100.0),
                ],
                color: PALETTE[3],
                band: vec![
                    (0.0, -1300.0, -1100.0),
                    (25_000.0, -800.0, -400.0),
                    (50_000.0, -300.0, -100.0),
                ],
            }],
        };
        let frame = figure(&[plot.clone(), plot], 2, 400, 300).unwrap();
        assert_eq!((frame.width, frame.height), (800, 300));
        let px = |f: &dyn Fn(&[u8]) -> bool| frame.rgb.chunks(3).filter(|p| f(p)).count();
        let red = px(&|p| p[0] > 150 && p[1] < 100 && p[2] < 100);
        // The band: the series colour at 20 % over white.
        let pink = px(&|p| p[0] > 235 && (190..235).contains(&p[1]) && (190..235).contains(&p[2]));
        let dark = px(&|p| p.iter().all(|&c| c < 90));
        assert!(red > 300, "series line: {red} red pixels");
        assert!(pink > 2000, "band: {pink} pink pixels");
        assert!(dark > 1000, "axes and text: {dark} dark pixels");
        // No series, an empty range: still a chart, no error.
        let empty = LinePlot {
            series: vec![],
            ..LinePlot {
                title: "t".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                series: vec![],
            }
        };
        assert!(figure(&[empty], 1, 200, 150).is_ok());
        assert!(figure(&[], 1, 0, 150).is_err());
    }
}
