//! PNG output.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use crate::{Frame, RenderError};

/// Writes `frame` to `path` as an 8-bit RGB PNG (overwriting an existing file).
///
/// Fails with [`RenderError::InvalidFrame`] if the buffer does not match the size or
/// the frame is empty (PNG cannot store a zero-sized image), and with
/// [`RenderError::Io`] / [`RenderError::Png`] if the file cannot be written.
pub fn save_png(frame: &Frame, path: &Path) -> Result<(), RenderError> {
    frame.validate()?;
    if frame.width == 0 || frame.height == 0 {
        return Err(RenderError::InvalidFrame(format!(
            "cannot save a {}x{} frame as PNG",
            frame.width, frame.height
        )));
    }
    let png_err = |source| RenderError::Png {
        path: path.to_path_buf(),
        source,
    };
    let file = File::create(path).map_err(|source| RenderError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), frame.width, frame.height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(png_err)?;
    writer.write_image_data(&frame.rgb).map_err(png_err)?;
    writer.finish().map_err(png_err)
}
