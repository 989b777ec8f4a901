//! Arrays across the Python boundary as bytes of little-endian `f32`, and the `ValueError` of
//! bad input. Shared by both extension modules of the package: `rdpg-py-policy` includes this
//! file by path rather than a crate of its own for three functions.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

/// A Python `ValueError` with `e`'s message.
pub fn value_err(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `f32`s from little-endian bytes, exactly `n` of them.
pub fn f32s(bytes: &[u8], n: usize, what: &str) -> PyResult<Vec<f32>> {
    if n.checked_mul(4) != Some(bytes.len()) {
        return Err(value_err(format!(
            "{what}: {} bytes, expected {n} float32 values",
            bytes.len(),
        )));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

/// `v` as little-endian bytes.
pub fn f32_bytes<'py>(py: Python<'py>, v: &[f32]) -> Bound<'py, PyBytes> {
    let raw: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    PyBytes::new(py, &raw)
}
