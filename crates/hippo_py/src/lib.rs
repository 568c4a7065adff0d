//! The native module `hippo_nav._core`. Each submodule binds one core crate: it validates and converts
//! Python inputs, releases the interpreter while the core works, and converts the results back.
use pyo3::prelude::*;

mod attractor;
mod errors;
mod map;
mod views;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    errors::register(m)?;
    attractor::register(m)?;
    map::register(m)?;
    views::register(m)?;
    Ok(())
}
