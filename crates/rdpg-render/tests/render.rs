//! Integration tests: rasterisation, PNG and GIF round trips.

use std::fs::File;
use std::io::BufReader;
use std::path::PathBuf;

use rdpg_render::{
    downscale, rasterize, save_png, Frame, GifWriter, RenderError, Rgb, Scene, Shape,
};

const BG: Rgb = [10, 20, 30];
const RED: Rgb = [250, 40, 20];
const BLUE: Rgb = [0, 0, 255];

fn scene(shapes: Vec<Shape>) -> Scene {
    Scene {
        width: 64,
        height: 48,
        background: BG,
        shapes,
    }
}

fn poly(points: &[[f32; 2]], fill: Rgb) -> Shape {
    Shape::Polygon {
        points: points.to_vec(),
        fill,
        outline: None,
    }
}

fn px(frame: &Frame, x: u32, y: u32) -> Rgb {
    frame.pixel(x, y).expect("pixel inside frame")
}

/// A fresh path in the system temp dir, unique per test.
fn temp_path(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rdpg-render-tests-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn all_background(frame: &Frame) -> bool {
    frame.rgb.chunks_exact(3).all(|p| p == BG)
}

#[test]
fn triangle_fill_at_centroid_background_outside() {
    let tri = [[10.0, 5.0], [50.0, 10.0], [20.0, 40.0]];
    let f = rasterize(&scene(vec![poly(&tri, RED)]));
    assert_eq!((f.width, f.height, f.rgb.len()), (64, 48, 64 * 48 * 3));
    let cx = (10.0 + 50.0 + 20.0) / 3.0;
    let cy = (5.0 + 10.0 + 40.0) / 3.0;
    assert_eq!(px(&f, cx as u32, cy as u32), RED);
    assert_eq!(px(&f, 0, 0), BG);
    assert_eq!(px(&f, 63, 47), BG);
    assert_eq!(px(&f, 60, 40), BG);
    assert_eq!(px(&f, 2, 45), BG);
}

#[test]
fn antialiased_edge_is_intermediate() {
    // The right edge x = 20.5 cuts the pixel column 20 in half.
    let rect = [[4.0, 4.0], [20.5, 4.0], [20.5, 30.0], [4.0, 30.0]];
    let f = rasterize(&scene(vec![poly(&rect, RED)]));
    assert_eq!(px(&f, 19, 15), RED);
    assert_eq!(px(&f, 21, 15), BG);
    let edge = px(&f, 20, 15);
    for c in 0..3 {
        let (lo, hi) = (BG[c].min(RED[c]), BG[c].max(RED[c]));
        assert!(lo < edge[c] && edge[c] < hi, "edge pixel {edge:?}");
    }
    // Roughly half coverage.
    let mid = (i32::from(BG[0]) + i32::from(RED[0])) / 2;
    assert!((i32::from(edge[0]) - mid).abs() < 40, "edge pixel {edge:?}");
}

#[test]
fn shapes_are_painted_in_order() {
    let big = [[0.0, 0.0], [64.0, 0.0], [64.0, 48.0], [0.0, 48.0]];
    let small = [[20.0, 20.0], [30.0, 20.0], [30.0, 30.0], [20.0, 30.0]];
    let f = rasterize(&scene(vec![poly(&big, RED), poly(&small, BLUE)]));
    assert_eq!(px(&f, 25, 25), BLUE);
    assert_eq!(px(&f, 5, 5), RED);
    let f = rasterize(&scene(vec![poly(&small, BLUE), poly(&big, RED)]));
    assert_eq!(px(&f, 25, 25), RED);
}

#[test]
fn polygon_outline_is_drawn() {
    let sq = [[10.5, 10.5], [30.5, 10.5], [30.5, 30.5], [10.5, 30.5]];
    let shape = Shape::Polygon {
        points: sq.to_vec(),
        fill: RED,
        outline: Some(BLUE),
    };
    let f = rasterize(&scene(vec![shape]));
    assert_eq!(px(&f, 20, 20), RED);
    // The 1-px hairline centred on x = 10.5 covers pixel column 10.
    let left = px(&f, 10, 20);
    assert!(left[2] > 200 && left[0] < 60, "outline pixel {left:?}");
    assert_eq!(px(&f, 8, 20), BG);
    assert_eq!(px(&f, 13, 20), RED);
}

#[test]
fn line_has_width_and_butt_ends() {
    let line = Shape::Line {
        from: [5.0, 20.0],
        to: [40.0, 20.0],
        color: RED,
        width: 4.0,
    };
    let f = rasterize(&scene(vec![line]));
    for y in 18..22 {
        assert_eq!(px(&f, 20, y), RED, "row {y}");
    }
    assert_eq!(px(&f, 20, 17), BG);
    assert_eq!(px(&f, 20, 22), BG);
    assert_eq!(px(&f, 3, 20), BG);
    assert_eq!(px(&f, 41, 20), BG);

    // A diagonal line is anti-aliased.
    let diag = Shape::Line {
        from: [0.0, 0.0],
        to: [64.0, 48.0],
        color: RED,
        width: 1.5,
    };
    let f = rasterize(&scene(vec![diag]));
    let distinct: std::collections::HashSet<&[u8]> = f.rgb.chunks_exact(3).collect();
    assert!(distinct.len() > 3, "expected AA shades");
}

#[test]
fn shapes_outside_or_partly_outside_are_clipped() {
    // Fully outside, in every direction.
    let outside = vec![
        poly(&[[-50.0, -50.0], [-10.0, -50.0], [-10.0, -10.0]], RED),
        poly(&[[100.0, 10.0], [200.0, 10.0], [150.0, 40.0]], RED),
        poly(&[[10.0, 60.0], [30.0, 60.0], [20.0, 90.0]], RED),
        Shape::Line {
            from: [-100.0, -5.0],
            to: [200.0, -5.0],
            color: RED,
            width: 2.0,
        },
    ];
    assert!(all_background(&rasterize(&scene(outside))));

    // Covering everything with absurdly far vertices.
    for far in [1e4_f32, 1e9, 1e30, f32::MAX] {
        let huge = poly(&[[-far, -far], [far, -far], [far, far], [-far, far]], RED);
        let f = rasterize(&scene(vec![huge]));
        assert!(f.rgb.chunks_exact(3).all(|p| p == RED), "far = {far}");
    }

    // A triangle with one vertex very far away still paints its visible part.
    let spike = poly(&[[10.0, 10.0], [20.0, 30.0], [1e12, 20.0]], RED);
    let f = rasterize(&scene(vec![spike]));
    assert_eq!(px(&f, 40, 20), RED);
    assert_eq!(px(&f, 40, 5), BG);

    // A very long and very wide line.
    let wide = Shape::Line {
        from: [-1e20, 24.0],
        to: [1e20, 24.0],
        color: RED,
        width: 1e10,
    };
    let f = rasterize(&scene(vec![wide]));
    assert!(f.rgb.chunks_exact(3).all(|p| p == RED));
}

#[test]
fn degenerate_and_nan_shapes_are_skipped() {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let shapes = vec![
        poly(&[], RED),
        poly(&[[5.0, 5.0]], RED),
        poly(&[[5.0, 5.0], [20.0, 20.0]], RED),
        poly(&[[5.0, 5.0], [20.0, 20.0], [35.0, 35.0]], RED),
        poly(&[[5.0, 5.0], [5.0, 5.0], [5.0, 5.0], [5.0, 5.0]], RED),
        poly(&[[5.0, 5.0], [nan, 20.0], [35.0, 5.0]], RED),
        poly(&[[nan, nan], [nan, nan], [nan, nan]], RED),
        poly(&[[5.0, 5.0], [inf, 20.0], [35.0, 5.0]], RED),
        poly(&[[-inf, -inf], [inf, -inf], [inf, inf], [-inf, inf]], RED),
        Shape::Polygon {
            points: vec![[5.0, 5.0], [20.0, 20.0], [35.0, 35.0]],
            fill: RED,
            outline: Some(BLUE),
        },
        Shape::Line {
            from: [nan, 1.0],
            to: [10.0, 10.0],
            color: RED,
            width: 2.0,
        },
        Shape::Line {
            from: [1.0, 1.0],
            to: [10.0, 10.0],
            color: RED,
            width: nan,
        },
        Shape::Line {
            from: [1.0, 1.0],
            to: [10.0, 10.0],
            color: RED,
            width: 0.0,
        },
        Shape::Line {
            from: [1.0, 1.0],
            to: [10.0, 10.0],
            color: RED,
            width: -3.0,
        },
        Shape::Line {
            from: [10.0, 10.0],
            to: [10.0, 10.0],
            color: RED,
            width: 3.0,
        },
        Shape::Line {
            from: [0.0, 10.0],
            to: [inf, 10.0],
            color: RED,
            width: 3.0,
        },
    ];
    assert!(all_background(&rasterize(&scene(shapes))));
}

#[test]
fn random_shapes_never_panic() {
    // Deterministic LCG; coordinates mix ordinary, huge and non-finite values.
    let mut state = 0x1234_5678_9abc_def0_u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (state >> 33) as u32
    };
    let specials = [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN,
        1e20,
        -1e20,
        0.0,
        1e-30,
    ];
    for _ in 0..200 {
        let coord = |next: &mut dyn FnMut() -> u32| -> f32 {
            let r = next();
            if r.is_multiple_of(10) {
                specials[(r / 10) as usize % specials.len()]
            } else {
                (r % 20_000) as f32 / 100.0 - 50.0
            }
        };
        let mut shapes = Vec::new();
        for _ in 0..10 {
            if next() % 2 == 0 {
                let n = next() % 8;
                let points = (0..n)
                    .map(|_| [coord(&mut next), coord(&mut next)])
                    .collect();
                shapes.push(Shape::Polygon {
                    points,
                    fill: RED,
                    outline: (next() % 2 == 0).then_some(BLUE),
                });
            } else {
                shapes.push(Shape::Line {
                    from: [coord(&mut next), coord(&mut next)],
                    to: [coord(&mut next), coord(&mut next)],
                    color: RED,
                    width: coord(&mut next) / 10.0,
                });
            }
        }
        let f = rasterize(&scene(shapes));
        assert_eq!(f.rgb.len(), 64 * 48 * 3);
    }
}

#[test]
fn empty_scene_sizes() {
    for (w, h) in [(0, 0), (0, 10), (10, 0)] {
        let s = Scene {
            width: w,
            height: h,
            background: BG,
            shapes: vec![poly(&[[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]], RED)],
        };
        let f = rasterize(&s);
        assert_eq!((f.width, f.height, f.rgb.len()), (w, h, 0));
    }
    let one = rasterize(&Scene {
        width: 1,
        height: 1,
        background: BG,
        shapes: vec![],
    });
    assert_eq!(one.rgb, BG.to_vec());
}

#[test]
fn png_round_trip() {
    let tri = [[3.0, 2.0], [60.0, 9.0], [25.0, 45.0]];
    let f = rasterize(&scene(vec![poly(&tri, RED)]));
    let path = temp_path("round_trip.png");
    save_png(&f, &path).unwrap();

    let decoder = png::Decoder::new(BufReader::new(File::open(&path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (64, 48));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    assert_eq!(&buf[..info.buffer_size()], &f.rgb[..]);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn png_errors_name_the_path() {
    let f = Frame::new(4, 4, BG);
    let path = temp_path("no-such-dir").join("x.png");
    let err = save_png(&f, &path).unwrap_err();
    assert!(matches!(err, RenderError::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("x.png"), "{err}");

    let bad = Frame {
        width: 4,
        height: 4,
        rgb: vec![0; 5],
    };
    let err = save_png(&bad, &temp_path("bad.png")).unwrap_err();
    assert!(matches!(err, RenderError::InvalidFrame(_)), "{err:?}");
}

#[test]
fn gif_round_trip_three_frames_looping() {
    let path = temp_path("anim.gif");
    let mut frames = Vec::new();
    for i in 0..3 {
        let x = 10.0 + 15.0 * i as f32;
        let tri = [[x, 5.0], [x + 20.0, 40.0], [x - 8.0, 30.0]];
        frames.push(rasterize(&scene(vec![poly(&tri, RED)])));
    }
    let mut w = GifWriter::create(&path, 64, 48, 50.0).unwrap();
    for f in &frames {
        w.push(f).unwrap();
    }
    assert_eq!(w.frames(), 3);
    w.finish().unwrap();

    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut dec = opts
        .read_info(BufReader::new(File::open(&path).unwrap()))
        .unwrap();
    assert_eq!((dec.width(), dec.height()), (64, 48));
    let mut n = 0;
    while let Some(g) = dec.read_next_frame().unwrap() {
        assert_eq!((g.left, g.top, g.width, g.height), (0, 0, 64, 48));
        assert_eq!(g.delay, 2);
        // Few colours: the GIF is lossless.
        let rgb: Vec<u8> = g
            .buffer
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        assert_eq!(rgb, frames[n].rgb, "frame {n}");
        n += 1;
    }
    assert_eq!(n, 3);
    assert_eq!(dec.repeat(), gif::Repeat::Infinite);
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn gif_rejects_bad_arguments() {
    let path = temp_path("bad.gif");
    for fps in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let err = GifWriter::create(&path, 8, 8, fps).err().unwrap();
        assert!(matches!(err, RenderError::InvalidArgument(_)), "{err:?}");
    }
    for (w, h) in [(0, 8), (8, 0), (70_000, 8)] {
        let err = GifWriter::create(&path, w, h, 50.0).err().unwrap();
        assert!(matches!(err, RenderError::InvalidArgument(_)), "{err:?}");
    }
    let mut w = GifWriter::create(&path, 8, 8, 50.0).unwrap();
    let err = w.push(&Frame::new(9, 8, BG)).unwrap_err();
    assert!(matches!(err, RenderError::InvalidFrame(_)), "{err:?}");
    w.push(&Frame::new(8, 8, BG)).unwrap();
    w.finish().unwrap();
    std::fs::remove_file(&path).unwrap();

    let missing = temp_path("no-such-dir").join("y.gif");
    let err = GifWriter::create(&missing, 8, 8, 50.0).err().unwrap();
    assert!(err.to_string().contains("y.gif"), "{err}");
}

#[test]
fn downscale_box_filter() {
    let mut f = Frame::new(5, 3, [0, 0, 0]);
    // Top-left 2x2 block: three black pixels and one white.
    f.rgb[0..3].copy_from_slice(&[255, 255, 255]);
    let d = downscale(&f, 2);
    assert_eq!((d.width, d.height, d.rgb.len()), (3, 2, 18));
    assert_eq!(d.pixel(0, 0), Some([64, 64, 64]));
    assert_eq!(d.pixel(2, 1), Some([0, 0, 0]));
    assert_eq!(downscale(&f, 1), f);
    assert_eq!(downscale(&f, 0), f);

    let big = Frame::new(600, 400, RED);
    let d = downscale(&big, 3);
    assert_eq!((d.width, d.height), (200, 134));
    assert!(d.rgb.chunks_exact(3).all(|p| p == RED));
}
