//! The native module `hippo_nav._core`. Each submodule binds one core crate: it validates and converts
//! Python inputs (`convert`), releases the interpreter while the core works, and converts the results back;
//! `images` binds the `png` crate (frames decoded faster than OpenCV's libpng).
//! Core errors become `HippoNavError` (`errors`).
use pyo3::prelude::*;

mod attractor;
mod convert;
mod errors;
mod images;
mod map;
mod views;
mod window;
mod words;

/// The default parameters of a core as JSON: `section` "engine" (`SpatialMemoryParams`), "map"
/// (`MapParams`) or "views" (`ViewCellParams`). The Rust `Default`s are the single source of every
/// default; the Python models read theirs from here.
#[pyfunction]
fn default_params_json(section: &str) -> PyResult<String> {
    match section {
        "engine" => convert::params_to_json(&hippo_attractor::SpatialMemoryParams::default()),
        "map" => convert::params_to_json(&hippo_map::MapParams::default()),
        "views" => convert::params_to_json(&hippo_views::ViewCellParams::default()),
        "vo_window" => convert::params_to_json(&hippo_vo::WindowParams::default()),
        other => Err(errors::HippoNavError::new_err(format!(
            "no default parameters for {other:?}; sections: engine, map, views, vo_window"
        ))),
    }
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(default_params_json, m)?)?;
    errors::register(m)?;
    images::register(m)?;
    attractor::register(m)?;
    map::register(m)?;
    views::register(m)?;
    words::register(m)?;
    window::register(m)?;
    Ok(())
}
