//! Renders a BipedalWalker-like 600x400 animation and times rasterisation and GIF
//! encoding (run with `cargo run --release -p rdpg-render --example gif_bench [DIR]`).
//! Writes `bench.gif` and `bench.png` into DIR (default: the system temp dir).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use rdpg_render::{downscale, rasterize, save_png, GifWriter, Scene, Shape};

const W: u32 = 600;
const H: u32 = 400;
const FRAMES: usize = 100;

fn poly(points: Vec<[f32; 2]>, fill: [u8; 3], outline: Option<[u8; 3]>) -> Shape {
    Shape::Polygon {
        points,
        fill,
        outline,
    }
}

/// A scene resembling Gymnasium's BipedalWalker render at time step `t`.
fn walker_scene(t: usize) -> Scene {
    let scroll = t as f32 * 3.0;
    let mut shapes = Vec::new();
    // Sky.
    shapes.push(poly(
        vec![
            [0.0, 0.0],
            [W as f32, 0.0],
            [W as f32, H as f32],
            [0.0, H as f32],
        ],
        [215, 215, 255],
        None,
    ));
    // Clouds.
    for c in 0..4 {
        let cx = 80.0 + 170.0 * c as f32 - scroll * 0.5;
        let cy = 60.0 + 25.0 * (c % 2) as f32;
        let pts = (0..10)
            .map(|k| {
                let a = k as f32 / 10.0 * std::f32::consts::TAU;
                [cx + 40.0 * a.cos(), cy + 12.0 * a.sin()]
            })
            .collect();
        shapes.push(poly(pts, [255, 255, 255], None));
    }
    // Terrain: quads from the ground line down to the bottom, plus grass lines.
    let ground = |x: f32| 300.0 + 12.0 * ((x + scroll) * 0.02).sin();
    let step = 20.0;
    let mut x = -step;
    while x < W as f32 + step {
        let (y0, y1) = (ground(x), ground(x + step));
        let shade = if ((x + scroll) / step) as i32 % 2 == 0 {
            [102, 153, 76]
        } else {
            [102, 230, 76]
        };
        shapes.push(poly(
            vec![[x, y0], [x + step, y1], [x + step, H as f32], [x, H as f32]],
            shade,
            None,
        ));
        x += step;
    }
    // Hull and legs.
    let (hx, hy) = (200.0, 200.0 + 5.0 * (t as f32 * 0.3).sin());
    shapes.push(poly(
        vec![
            [hx - 30.0, hy],
            [hx + 6.0, hy - 30.0],
            [hx + 34.0, hy - 30.0],
            [hx + 34.0, hy + 10.0],
            [hx - 34.0, hy + 10.0],
        ],
        [127, 51, 229],
        Some([76, 76, 127]),
    ));
    for (leg, phase) in [(0, 0.0_f32), (1, std::f32::consts::PI)] {
        let a = (t as f32 * 0.2 + phase).sin() * 0.6;
        let (s, c) = a.sin_cos();
        let (x0, y0) = (hx + 5.0 * leg as f32, hy + 10.0);
        let seg = |x: f32, y: f32, len: f32| {
            let (dx, dy) = (s * len, c * len);
            vec![
                [x - 4.0, y],
                [x + 4.0, y],
                [x + 4.0 + dx, y + dy],
                [x - 4.0 + dx, y + dy],
            ]
        };
        let color = if leg == 0 {
            [178, 101, 152]
        } else {
            [153, 76, 127]
        };
        shapes.push(poly(seg(x0, y0, 34.0), color, Some([76, 76, 127])));
        shapes.push(poly(
            seg(x0 + s * 34.0, y0 + c * 34.0, 34.0),
            color,
            Some([76, 76, 127]),
        ));
    }
    // Lidar.
    for k in 0..10 {
        let a = 1.5 * k as f32 / 10.0;
        shapes.push(Shape::Line {
            from: [hx, hy],
            to: [hx + 160.0 * a.sin(), hy + 160.0 * a.cos()],
            color: [255, 0, 0],
            width: 1.0,
        });
    }
    Scene {
        width: W,
        height: H,
        background: [215, 215, 255],
        shapes,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    let (mut t_raster, mut t_gif, mut t_gif_half) =
        (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let mut kept = Vec::new();
    let mut gif = GifWriter::create(&dir.join("bench.gif"), W, H, 50.0)?;
    let mut gif_half = GifWriter::create(&dir.join("bench_half.gif"), W / 2, H / 2, 50.0)?;
    for t in 0..FRAMES {
        let scene = walker_scene(t);
        let start = Instant::now();
        let frame = rasterize(&scene);
        t_raster += start.elapsed();
        if t == 0 {
            save_png(&frame, &dir.join("bench.png"))?;
        }
        if t % 10 == 0 {
            kept.push(frame.rgb.clone());
        }
        let start = Instant::now();
        gif.push(&frame)?;
        t_gif += start.elapsed();
        let start = Instant::now();
        gif_half.push(&downscale(&frame, 2))?;
        t_gif_half += start.elapsed();
    }
    gif.finish()?;
    gif_half.finish()?;
    let per = |d: Duration| d.as_secs_f64() * 1e3 / FRAMES as f64;
    println!("{FRAMES} frames of {W}x{H}");
    println!("rasterize:               {:.2} ms/frame", per(t_raster));
    println!("GIF push (quantise+LZW): {:.2} ms/frame", per(t_gif));
    println!("downscale(2) + GIF push: {:.2} ms/frame", per(t_gif_half));
    for name in ["bench.gif", "bench_half.gif"] {
        let size = std::fs::metadata(dir.join(name))?.len();
        println!("{name}: {} KiB", size / 1024);
    }
    // Quantisation error of the full-size GIF, on every 10th frame.
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut dec = opts.read_info(std::io::BufReader::new(std::fs::File::open(
        dir.join("bench.gif"),
    )?))?;
    let (mut max_err, mut sum_err, mut n) = (0u8, 0u64, 0u64);
    let mut t = 0;
    while let Some(f) = dec.read_next_frame()? {
        if t % 10 == 0 {
            for (q, o) in f.buffer.chunks_exact(4).zip(kept[t / 10].chunks_exact(3)) {
                for c in 0..3 {
                    let e = q[c].abs_diff(o[c]);
                    max_err = max_err.max(e);
                    sum_err += u64::from(e);
                    n += 1;
                }
            }
        }
        t += 1;
    }
    println!(
        "GIF colour error: mean {:.4}, max {max_err} (per channel, 0-255)",
        sum_err as f64 / n as f64
    );
    println!("wrote {}", dir.display());
    Ok(())
}
