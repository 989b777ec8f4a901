//! RGB frames and simple image operations on them.

use crate::{RenderError, Rgb};

/// A rasterised RGB image: row-major, 3 bytes (R, G, B) per pixel, no padding, so
/// `rgb.len() == width * height * 3` and pixel `(x, y)` starts at byte
/// `(y * width + x) * 3`.
#[derive(Clone, PartialEq, Eq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixel data, row-major, 3 bytes per pixel.
    pub rgb: Vec<u8>,
}

impl Frame {
    /// A frame of the given size filled with one colour.
    pub fn new(width: u32, height: u32, color: Rgb) -> Self {
        let n = width as usize * height as usize;
        let mut rgb = Vec::with_capacity(n * 3);
        for _ in 0..n {
            rgb.extend_from_slice(&color);
        }
        Frame { width, height, rgb }
    }

    /// The colour of pixel `(x, y)`, or `None` outside the frame (or if the buffer is
    /// too short).
    pub fn pixel(&self, x: u32, y: u32) -> Option<Rgb> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = (y as usize * self.width as usize + x as usize) * 3;
        let p = self.rgb.get(i..i + 3)?;
        Some([p[0], p[1], p[2]])
    }

    /// Checks that the buffer length matches the dimensions.
    pub fn validate(&self) -> Result<(), RenderError> {
        let expected = self.width as u64 * self.height as u64 * 3;
        if self.rgb.len() as u64 != expected {
            return Err(RenderError::InvalidFrame(format!(
                "{}x{} frame needs {expected} bytes of RGB data, has {}",
                self.width,
                self.height,
                self.rgb.len()
            )));
        }
        Ok(())
    }
}

impl std::fmt::Debug for Frame {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Frame")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("rgb", &format_args!("[{} bytes]", self.rgb.len()))
            .finish()
    }
}

/// Shrinks a frame by an integer `factor` with a box filter (each output pixel is the
/// rounded mean of a `factor` x `factor` block).
///
/// The output is `ceil(width / factor)` x `ceil(height / factor)`; blocks cut by the
/// right or bottom edge average only the pixels they contain. A `factor` of 0 or 1
/// returns a copy. The input is expected to satisfy [`Frame::validate`]; missing
/// bytes of a short buffer are read as black.
pub fn downscale(frame: &Frame, factor: u32) -> Frame {
    if factor <= 1 {
        return frame.clone();
    }
    let (w, h, f) = (frame.width as usize, frame.height as usize, factor as usize);
    let (ow, oh) = (w.div_ceil(f), h.div_ceil(f));
    let mut out = Vec::with_capacity(ow * oh * 3);
    let mut sums = vec![0u64; ow * 3];
    for oy in 0..oh {
        sums.iter_mut().for_each(|s| *s = 0);
        let y0 = oy * f;
        let y1 = (y0 + f).min(h);
        for y in y0..y1 {
            let row = frame.rgb.get(y * w * 3..(y + 1) * w * 3).unwrap_or(&[]);
            for (x, px) in row.chunks_exact(3).enumerate() {
                let s = &mut sums[(x / f) * 3..(x / f) * 3 + 3];
                s[0] += u64::from(px[0]);
                s[1] += u64::from(px[1]);
                s[2] += u64::from(px[2]);
            }
        }
        let rows = (y1 - y0) as u64;
        for ox in 0..ow {
            let cols = ((ox * f + f).min(w) - ox * f) as u64;
            let n = rows * cols;
            for c in 0..3 {
                out.push(((sums[ox * 3 + c] + n / 2) / n) as u8);
            }
        }
    }
    Frame {
        width: ow as u32,
        height: oh as u32,
        rgb: out,
    }
}
