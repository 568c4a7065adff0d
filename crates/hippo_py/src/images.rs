//! PNG frames decoded by the `png` crate (image-rs) instead of OpenCV's libpng: the same pixels in about a
//! quarter of the time (a real KITTI frame, 1226 × 370 gray: about 1.0 against 4.0 ms; loading the pair was
//! about a tenth of a real KITTI frame's CPU, docs/results.md, "Cost").
//!
//! Only the kinds whose pixels OpenCV's `imdecode(IMREAD_UNCHANGED)` gives unchanged are decoded here: 8-bit
//! gray, RGB and RGBA (returned in OpenCV's BGR(A) order), interlaced or not, with no transparency chunk and
//! not animated. Anything else, and any file the crate refuses (a truncated or damaged file, a missing
//! end chunk, a checksum that does not match, a panic inside the crate), is `None`: the caller decodes it
//! with OpenCV as before, so what OpenCV refuses, and the error the user sees, do not change.
use numpy::PyArrayDyn;
use png::{BitDepth, ColorType, Decoder, Transformations};
use pyo3::prelude::*;
use std::io::Cursor;

use crate::convert::to_numpy;

/// The decoded pixels and their shape (rows, columns[, channels]), or None (module doc).
fn decode(data: &[u8]) -> Option<(Vec<u8>, Vec<usize>)> {
    let mut decoder = Decoder::new(Cursor::new(data));
    decoder.set_transformations(Transformations::IDENTITY);
    let mut reader = decoder.read_info().ok()?;
    let info = reader.info();
    if info.bit_depth != BitDepth::Eight || info.trns.is_some() || info.animation_control.is_some()
    {
        return None;
    }
    let channels = match info.color_type {
        ColorType::Grayscale => 1,
        ColorType::Rgb => 3,
        ColorType::Rgba => 4,
        _ => return None,
    };
    let (rows, columns) = (info.height as usize, info.width as usize);
    let mut pixels = vec![0u8; reader.output_buffer_size()?];
    let frame = reader.next_frame(&mut pixels).ok()?;
    // The rest of the file too: OpenCV refuses a file whose chunks after the image are damaged or missing.
    reader.finish().ok()?;
    if frame.line_size != columns * channels || pixels.len() != rows * frame.line_size {
        return None;
    }
    if channels >= 3 {
        // PNG stores red first, OpenCV blue first.
        for pixel in pixels.chunks_exact_mut(channels) {
            pixel.swap(0, 2);
        }
    }
    let shape = if channels == 1 {
        vec![rows, columns]
    } else {
        vec![rows, columns, channels]
    };
    Some((pixels, shape))
}

/// A PNG file's bytes decoded as OpenCV's `imdecode(…, IMREAD_UNCHANGED)` gives them, (rows, columns) uint8
/// or (rows, columns, 3 | 4) in BGR(A), with the interpreter released; None where OpenCV should decode it
/// (another kind of image, or a file this decoder refuses: see the module doc).
#[pyfunction]
fn decode_png<'py>(py: Python<'py>, data: &[u8]) -> PyResult<Option<Bound<'py, PyArrayDyn<u8>>>> {
    // A decoder panic on some file nobody foresaw is one more file to leave to OpenCV, never a crash.
    let decoded = py.detach(|| std::panic::catch_unwind(|| decode(data)).ok().flatten());
    match decoded {
        Some((pixels, shape)) => Ok(Some(to_numpy(py, pixels, &shape)?)),
        None => Ok(None),
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(decode_png, m)?)?;
    Ok(())
}
