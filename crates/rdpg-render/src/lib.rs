//! Pure-Rust 2-D rendering: a [`Scene`] of flat-coloured polygons and lines in pixel
//! coordinates, rasterised to RGB frames, saved as PNG or animated GIF.
//!
//! The scene format is always there; everything that draws or encodes is behind the default
//! `image` feature, so crates that only describe scenes (the environments) build without it:
//! `rasterize` turns a [`Scene`] into a `Frame` (anti-aliased, via `tiny-skia`); `save_png`
//! writes one frame, `GifWriter` an endlessly looping animation, `downscale` shrinks frames
//! for smaller files, and `plot` draws line charts (plotters, with DejaVu Sans embedded from
//! the `dejavu` crate, never the machine's fonts). Everything is pure Rust.

#![warn(missing_docs)]
// No panic reachable from a file or an argument: errors are returned; each remaining invariant
// is allowed where it holds, with its reason.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]

/// An RGB colour.
pub type Rgb = [u8; 3];

/// One drawable item, in image pixel coordinates (x right, y down).
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A filled polygon (convex or not), optionally outlined.
    Polygon {
        /// Vertices in order.
        points: Vec<[f32; 2]>,
        /// Fill colour.
        fill: Rgb,
        /// Outline colour, drawn 1 px wide.
        outline: Option<Rgb>,
    },
    /// A line segment.
    Line {
        /// Start point.
        from: [f32; 2],
        /// End point.
        to: [f32; 2],
        /// Colour.
        color: Rgb,
        /// Width in pixels.
        width: f32,
    },
}

/// A frame to draw: background colour and shapes painted in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Background colour.
    pub background: Rgb,
    /// Shapes, painted in order (later ones on top).
    pub shapes: Vec<Shape>,
}

#[cfg(feature = "image")]
mod error;
#[cfg(feature = "image")]
mod frame;
#[cfg(feature = "image")]
mod gif_writer;
#[cfg(feature = "image")]
pub mod plot;
#[cfg(feature = "image")]
mod png_io;
#[cfg(feature = "image")]
mod raster;

#[cfg(feature = "image")]
pub use error::RenderError;
#[cfg(feature = "image")]
pub use frame::{downscale, Frame};
#[cfg(feature = "image")]
pub use gif_writer::{GifWriter, MIN_DELAY_CS};
#[cfg(feature = "image")]
pub use png_io::save_png;
#[cfg(feature = "image")]
pub use raster::rasterize;
