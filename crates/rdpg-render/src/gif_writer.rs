//! Animated GIF output with a fast palette quantiser suited to flat-colour frames.

use std::collections::HashMap;
use std::fs::File;
use std::hash::{BuildHasherDefault, Hasher};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::{Frame, RenderError};

/// The shortest frame delay written, in 1/100 s. Many viewers (browsers included)
/// replace delays below 2 cs by 10 cs, so faster frame rates are not representable.
pub const MIN_DELAY_CS: u16 = 2;

/// If the 256 most frequent colours of a frame cover less than this fraction of its
/// pixels, the frame is not "flat colours plus anti-aliased edges" and is quantised
/// with NeuQuant instead.
const MIN_TOP_COVERAGE: f64 = 0.9;

/// NeuQuant speed (1 best .. 30 fastest) for frames with many colours.
const NEUQUANT_SPEED: i32 = 10;

/// Writes an infinitely looping animated GIF, one [`Frame`] at a time.
///
/// # Timing
///
/// GIF frame delays are whole hundredths of a second, and many viewers play delays
/// below 2 cs as 10 cs, so frame rates above 50 fps are written as 50 fps (2 cs per
/// frame; the animation then plays slower than real time — drop frames to keep
/// time). Below that, the delays follow the ideal timeline `k * 100 / fps` cs rounded
/// to whole centiseconds, so the rounding error does not accumulate: 50 fps is
/// exactly 2 cs per frame, 30 fps gives 3, 4, 3, 3, 4, 3, … cs (10 cs per 3 frames).
/// Delays are capped at 655.35 s.
///
/// # Colours
///
/// Each frame gets its own palette of at most 256 colours. If the frame has at most 256
/// distinct colours it is stored losslessly. Otherwise, if its 256 most frequent
/// colours cover at least 90 % of the pixels (flat-coloured shapes with anti-aliased
/// edges, as in walker renders), those colours form the palette and every other
/// colour is mapped to its nearest palette entry (no dithering). Frames with richer
/// colour content fall back to NeuQuant (`gif::Frame::from_rgb_speed`, speed 10).
///
/// Dropping a `GifWriter` without calling [`finish`](GifWriter::finish) still writes
/// the GIF trailer on a best-effort basis, but errors are then lost.
pub struct GifWriter {
    encoder: gif::Encoder<BufWriter<File>>,
    path: PathBuf,
    width: u32,
    height: u32,
    /// Seconds per frame, as centiseconds (at least `MIN_DELAY_CS`).
    frame_cs: f64,
    frames: u64,
    /// Sum of the delays written so far, in cs.
    elapsed_cs: u64,
}

impl GifWriter {
    /// Creates (or truncates) `path` and writes the GIF header for a `width` x `height`
    /// animation played at `fps` frames per second, looping forever.
    ///
    /// Fails with [`RenderError::InvalidArgument`] if a dimension is 0 or above 65535
    /// or `fps` is not a positive finite number, and with [`RenderError::Io`] or
    /// [`RenderError::Gif`] if the file cannot be written.
    pub fn create(path: &Path, width: u32, height: u32, fps: f32) -> Result<Self, RenderError> {
        let (Ok(w16), Ok(h16)) = (u16::try_from(width), u16::try_from(height)) else {
            return Err(RenderError::InvalidArgument(format!(
                "GIF size {width}x{height} exceeds 65535x65535"
            )));
        };
        if w16 == 0 || h16 == 0 {
            return Err(RenderError::InvalidArgument(format!(
                "GIF size {width}x{height} is empty"
            )));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(RenderError::InvalidArgument(format!(
                "GIF frame rate must be positive and finite, got {fps}"
            )));
        }
        let file = File::create(path).map_err(|source| RenderError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let gif_err = |source| RenderError::Gif {
            path: path.to_path_buf(),
            source,
        };
        let mut encoder =
            gif::Encoder::new(BufWriter::new(file), w16, h16, &[]).map_err(gif_err)?;
        encoder.set_repeat(gif::Repeat::Infinite).map_err(gif_err)?;
        Ok(GifWriter {
            encoder,
            path: path.to_path_buf(),
            width,
            height,
            frame_cs: (100.0 / f64::from(fps)).max(f64::from(MIN_DELAY_CS)),
            frames: 0,
            elapsed_cs: 0,
        })
    }

    /// Quantises `frame` to a palette and appends it to the animation.
    ///
    /// Fails with [`RenderError::InvalidFrame`] if the frame's size differs from the
    /// GIF's or its buffer is inconsistent, and with [`RenderError::Gif`] on write
    /// errors.
    pub fn push(&mut self, frame: &Frame) -> Result<(), RenderError> {
        frame.validate()?;
        if (frame.width, frame.height) != (self.width, self.height) {
            return Err(RenderError::InvalidFrame(format!(
                "frame is {}x{} but the GIF {} is {}x{}",
                frame.width,
                frame.height,
                self.path.display(),
                self.width,
                self.height
            )));
        }
        let mut gif_frame = quantize(frame);
        gif_frame.delay = self.next_delay();
        self.encoder
            .write_frame(&gif_frame)
            .map_err(|source| RenderError::Gif {
                path: self.path.clone(),
                source,
            })
    }

    /// Number of frames pushed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Writes the GIF trailer and flushes the file.
    pub fn finish(self) -> Result<(), RenderError> {
        let path = self.path;
        let mut writer = self
            .encoder
            .into_inner()
            .map_err(|source| RenderError::Gif {
                path: path.clone(),
                source,
            })?;
        writer
            .flush()
            .map_err(|source| RenderError::Io { path, source })
    }

    /// Delay of the next frame in cs: the rounded ideal end time of the frame minus the
    /// time already written, so that rounding errors do not accumulate.
    fn next_delay(&mut self) -> u16 {
        self.frames += 1;
        let target = (self.frames as f64 * self.frame_cs).round() as u64;
        let delay = target
            .saturating_sub(self.elapsed_cs)
            .clamp(u64::from(MIN_DELAY_CS), u64::from(u16::MAX));
        self.elapsed_cs += delay;
        delay as u16
    }
}

impl std::fmt::Debug for GifWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GifWriter")
            .field("path", &self.path)
            .field("width", &self.width)
            .field("height", &self.height)
            .field("frames", &self.frames)
            .field("elapsed_cs", &self.elapsed_cs)
            .finish_non_exhaustive()
    }
}

/// A multiplicative hasher for packed RGB keys (std's SipHash is needlessly slow
/// here, and an identity hash leaves hashbrown's top bits constant).
#[derive(Default)]
struct RgbHasher(u64);

impl Hasher for RgbHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u32(&mut self, n: u32) {
        self.0 = (self.0 ^ u64::from(n)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

type RgbMap<V> = HashMap<u32, V, BuildHasherDefault<RgbHasher>>;

fn pack(px: &[u8]) -> u32 {
    (u32::from(px[0]) << 16) | (u32::from(px[1]) << 8) | u32::from(px[2])
}

fn unpack(c: u32) -> [u8; 3] {
    [(c >> 16) as u8, (c >> 8) as u8, c as u8]
}

/// Builds a GIF frame (local palette, indexed pixels) from a validated RGB frame whose
/// dimensions fit in `u16`.
fn quantize(frame: &Frame) -> gif::Frame<'static> {
    let (w, h) = (frame.width as u16, frame.height as u16);
    let n_pixels = frame.rgb.len() / 3;

    // Histogram of exact colours; runs of equal pixels touch the map once.
    let mut counts: RgbMap<u32> = RgbMap::default();
    let mut run_color = u32::MAX;
    let mut run_len = 0u32;
    for px in frame.rgb.chunks_exact(3) {
        let c = pack(px);
        if c == run_color {
            run_len += 1;
        } else {
            if run_len > 0 {
                *counts.entry(run_color).or_insert(0) += run_len;
            }
            run_color = c;
            run_len = 1;
        }
    }
    if run_len > 0 {
        *counts.entry(run_color).or_insert(0) += run_len;
    }

    // Most frequent first; ties broken by colour value for determinism.
    let mut by_freq: Vec<(u32, u32)> = counts.into_iter().collect();
    by_freq.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let n_palette = by_freq.len().min(256);
    let covered: u64 = by_freq[..n_palette]
        .iter()
        .map(|&(_, n)| u64::from(n))
        .sum();
    if (covered as f64) < MIN_TOP_COVERAGE * n_pixels as f64 {
        return gif::Frame::from_rgb_speed(w, h, &frame.rgb, NEUQUANT_SPEED);
    }

    let palette: Vec<[u8; 3]> = by_freq[..n_palette]
        .iter()
        .map(|&(c, _)| unpack(c))
        .collect();
    let mut index_of: RgbMap<u8> = by_freq
        .iter()
        .enumerate()
        .map(|(i, &(c, _))| {
            let idx = if i < n_palette {
                i
            } else {
                nearest(&palette, unpack(c))
            };
            (c, idx as u8)
        })
        .collect();

    let mut indices = Vec::with_capacity(n_pixels);
    let mut last_color = u32::MAX;
    let mut last_index = 0u8;
    for px in frame.rgb.chunks_exact(3) {
        let c = pack(px);
        if c != last_color {
            last_color = c;
            last_index = *index_of
                .entry(c)
                .or_insert_with(|| nearest(&palette, unpack(c)) as u8);
        }
        indices.push(last_index);
    }
    let palette_bytes: Vec<u8> = palette.into_iter().flatten().collect();
    gif::Frame::from_palette_pixels(w, h, indices, palette_bytes, None)
}

/// Index of the palette entry closest to `c` (weighted squared RGB distance,
/// roughly matching perceived brightness differences).
fn nearest(palette: &[[u8; 3]], c: [u8; 3]) -> usize {
    let mut best = (u32::MAX, 0);
    for (i, p) in palette.iter().enumerate() {
        let d = |k: usize| (i32::from(p[k]) - i32::from(c[k])).unsigned_abs();
        let dist = 2 * d(0) * d(0) + 4 * d(1) * d(1) + 3 * d(2) * d(2);
        if dist < best.0 {
            best = (dist, i);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn delays(fps: f32, n: usize) -> Vec<u16> {
        let dir = std::env::temp_dir().join(format!(
            "rdpg-render-delay-{}-{fps}.gif",
            std::process::id()
        ));
        let mut w = GifWriter::create(&dir, 1, 1, fps).unwrap();
        let d = (0..n).map(|_| w.next_delay()).collect();
        drop(w);
        let _ = std::fs::remove_file(&dir);
        d
    }

    #[test]
    fn delays_follow_fps() {
        assert_eq!(delays(50.0, 4), vec![2, 2, 2, 2]);
        assert_eq!(delays(25.0, 3), vec![4, 4, 4]);
        assert_eq!(delays(30.0, 6), vec![3, 4, 3, 3, 4, 3]);
        // Faster than 50 fps is written at 50 fps.
        assert_eq!(delays(60.0, 3), vec![2, 2, 2]);
        assert_eq!(delays(0.001, 1), vec![u16::MAX]);
        let d = delays(33.0, 330);
        assert_eq!(d.iter().map(|&x| u32::from(x)).sum::<u32>(), 1000);
    }

    #[test]
    fn quantize_exact_when_few_colors() {
        let mut f = Frame::new(4, 2, [1, 2, 3]);
        f.rgb[3..6].copy_from_slice(&[200, 100, 0]);
        let g = quantize(&f);
        let pal = g.palette.as_ref().unwrap();
        for (i, px) in f.rgb.chunks_exact(3).enumerate() {
            let idx = g.buffer[i] as usize;
            assert_eq!(&pal[idx * 3..idx * 3 + 3], px);
        }
    }

    #[test]
    fn quantize_maps_rare_colors_to_nearest() {
        // 301 distinct colours: one dominant, 200 greys seen twice, 100 rare
        // near-greys seen once (45 of which do not fit in the palette).
        let mut f = Frame::new(100, 100, [10, 20, 30]);
        for i in 0..400usize {
            let v = (i / 2) as u8;
            f.rgb[i * 3..i * 3 + 3].copy_from_slice(&[v, v, v]);
        }
        for i in 400..500usize {
            let v = (i - 400) as u8;
            f.rgb[i * 3..i * 3 + 3].copy_from_slice(&[v, v + 1, v]);
        }
        let g = quantize(&f);
        let pal = g.palette.as_ref().unwrap();
        assert!(pal.len() <= 256 * 3);
        for (i, px) in f.rgb.chunks_exact(3).enumerate() {
            let idx = g.buffer[i] as usize;
            let q = &pal[idx * 3..idx * 3 + 3];
            for k in 0..3 {
                assert!(
                    (i32::from(q[k]) - i32::from(px[k])).abs() <= 1,
                    "{q:?} vs {px:?}"
                );
            }
        }
    }

    #[test]
    fn quantize_falls_back_to_neuquant_for_noise() {
        let mut f = Frame::new(64, 64, [0, 0, 0]);
        let mut state = 12345u32;
        for b in f.rgb.iter_mut() {
            state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
            *b = (state >> 16) as u8;
        }
        let g = quantize(&f);
        assert_eq!((g.width, g.height, g.buffer.len()), (64, 64, 64 * 64));
        let pal = g.palette.as_ref().unwrap();
        assert!(pal.len() <= 256 * 3 && pal.len() > 3);
    }
}
