//! Exceptions raised by the native module. Every core error becomes a `HippoNavError` (a `ValueError`),
//! so callers can catch our failures without catching unrelated bugs.
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

create_exception!(
    _core,
    HippoNavError,
    PyValueError,
    "Invalid input or parameters given to hippo_nav."
);

/// Map any displayable core error to a `HippoNavError`.
pub fn to_py_err<E: std::fmt::Display>(err: E) -> PyErr {
    HippoNavError::new_err(err.to_string())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("HippoNavError", m.py().get_type::<HippoNavError>())?;
    Ok(())
}
