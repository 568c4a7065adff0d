//! Conversions shared by every binding file: numpy arrays and tuples in (checked for shape and
//! finiteness, any memory layout accepted), numpy arrays out (moved from Rust vectors, no copy), parameters
//! as JSON of the core crates' `Params` structs (whose `Default` is the single source of defaults), and
//! the reports that read like dicts.
use crate::errors::{to_py_err, HippoNavError};
use numpy::{
    IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArray1, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::{de::DeserializeOwned, Serialize};

/// `(x, y, yaw)` as a planar pose crosses the boundary.
pub type PoseTuple = (f64, f64, f64);

/// An any-layout float64 array of exactly `shape`, copied into a flat row-major vector; every value must
/// be finite.
pub fn flat_f64(
    name: &str,
    a: &PyReadonlyArrayDyn<'_, f64>,
    shape: &[usize],
) -> PyResult<Vec<f64>> {
    if a.shape() != shape {
        return Err(HippoNavError::new_err(format!(
            "`{name}` has shape {:?}, expected {:?}",
            a.shape(),
            shape
        )));
    }
    finite(name, a.as_array().iter().copied().collect())
}

/// An any-layout float64 array of shape `(n, cols…)` (n free) into `n` and its row-major values; every
/// value must be finite.
pub fn rows_f64(
    name: &str,
    a: &PyReadonlyArrayDyn<'_, f64>,
    cols: &[usize],
) -> PyResult<(usize, Vec<f64>)> {
    let shape = a.shape();
    if shape.len() != cols.len() + 1 || shape[1..] != *cols {
        return Err(HippoNavError::new_err(format!(
            "`{name}` has shape {shape:?}, expected (n, {})",
            cols.iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok((
        shape[0],
        finite(name, a.as_array().iter().copied().collect())?,
    ))
}

fn finite(name: &str, v: Vec<f64>) -> PyResult<Vec<f64>> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(HippoNavError::new_err(format!(
            "`{name}` holds a NaN or infinity at flat index {i}"
        ))),
        None => Ok(v),
    }
}

/// Candidate cell ids as given: a 1-D integer array (int64, int32, uint64) of any layout, or any sequence
/// of ints.
#[derive(FromPyObject)]
pub enum CandidatesArg<'py> {
    I64(PyReadonlyArray1<'py, i64>),
    I32(PyReadonlyArray1<'py, i32>),
    U64(PyReadonlyArray1<'py, u64>),
    Seq(Vec<i64>),
}

/// Candidate ids as `usize`; a negative id is refused here (the core checks the upper end).
pub fn candidate_ids(c: &CandidatesArg<'_>) -> PyResult<Vec<usize>> {
    let signed = |v: &mut dyn Iterator<Item = i64>| -> PyResult<Vec<usize>> {
        v.enumerate()
            .map(|(position, id)| {
                usize::try_from(id).map_err(|_| {
                    HippoNavError::new_err(format!(
                        "candidate {position} is {id}: view-cell ids are ≥ 0"
                    ))
                })
            })
            .collect()
    };
    match c {
        CandidatesArg::I64(a) => signed(&mut a.as_array().iter().copied()),
        CandidatesArg::I32(a) => signed(&mut a.as_array().iter().map(|&v| i64::from(v))),
        CandidatesArg::U64(a) => Ok(a
            .as_array()
            .iter()
            .map(|&v| usize::try_from(v).unwrap_or(usize::MAX))
            .collect()),
        CandidatesArg::Seq(v) => signed(&mut v.iter().copied()),
    }
}

/// An any-layout uint8 array of shape `(n, cols…)` (n free) into `n` and its row-major bytes.
pub fn rows_u8(
    name: &str,
    a: &PyReadonlyArrayDyn<'_, u8>,
    cols: &[usize],
) -> PyResult<(usize, Vec<u8>)> {
    let shape = a.shape();
    if shape.len() != cols.len() + 1 || shape[1..] != *cols {
        return Err(HippoNavError::new_err(format!(
            "`{name}` has shape {shape:?}, expected (n, {}) uint8",
            cols.iter()
                .map(|c| c.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok((shape[0], a.as_array().iter().copied().collect()))
}

/// A row-major vector as a numpy array of `shape` (moved, not copied).
pub fn to_numpy<'py, T: numpy::Element>(
    py: Python<'py>,
    values: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    values.into_pyarray(py).reshape(shape.to_vec())
}

/// `(a[0], a[1])`: a pair of axes (x, y) as a tuple.
pub fn pair(a: [f64; 2]) -> (f64, f64) {
    (a[0], a[1])
}

/// Parameters from the JSON of their Rust struct (`None`: the defaults); `what` names them in the error.
/// A bad field is named by its path (`grid[1].k`), never by a line and column of JSON nobody wrote.
pub fn params_from_json<P: DeserializeOwned + Default>(
    json: Option<&str>,
    what: &str,
) -> PyResult<P> {
    section_from_json(json, what, "")
}

/// As `params_from_json`, for the parameters of a config-file section: the path of a bad field starts
/// with the section (`engine.hd.n_theta`), as the Python config names it.
pub fn section_from_json<P: DeserializeOwned + Default>(
    json: Option<&str>,
    what: &str,
    section: &str,
) -> PyResult<P> {
    let Some(text) = json else {
        return Ok(P::default());
    };
    let value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| HippoNavError::new_err(format!("invalid {what}: not valid JSON ({e})")))?;
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let field = match (section, path.as_str()) {
            (s, ".") => s.to_string(),
            ("", p) => p.to_string(),
            (s, p) => format!("{s}.{p}"),
        };
        let field = if field.is_empty() {
            "(top level)"
        } else {
            &field
        };
        HippoNavError::new_err(format!(
            "invalid {what}: {field}: {}",
            plain_serde_message(&e.into_inner().to_string())
        ))
    })
}

/// serde's type names said in words: `expected usize` → a whole number ≥ 0; a JSON `null` where a number
/// belongs is what NaN and infinity become in JSON.
fn plain_serde_message(message: &str) -> String {
    let mut out = message.to_string();
    for (rust, words) in [
        ("expected usize", "expected a whole number ≥ 0"),
        ("expected u64", "expected a whole number ≥ 0"),
        (
            "expected u32",
            "expected a whole number from 0 to 4294967295",
        ),
        ("expected f64", "expected a finite number"),
        ("expected f32", "expected a finite number"),
    ] {
        out = out.replace(rust, words);
    }
    if out.starts_with("invalid type: null") {
        out.push_str(" (NaN and infinity are written as null in JSON: give a finite number)");
    }
    out
}

/// Parameters as JSON.
pub fn params_to_json<P: Serialize>(params: &P) -> PyResult<String> {
    serde_json::to_string(params).map_err(to_py_err)
}

/// A report's fields, in order, for `as_dict`, `__getitem__` and `__repr__` (see `report!`).
pub trait ReportFields {
    /// The Python class name.
    const NAME: &'static str;
    /// Every field as `(name, value)`.
    fn fields<'py>(&self, py: Python<'py>) -> PyResult<Vec<(&'static str, Bound<'py, PyAny>)>>;

    /// The fields as a plain dict (e.g. for JSON).
    fn dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (k, v) in self.fields(py)? {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    /// One field by name; a `KeyError` for any other name.
    fn item<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        self.fields(py)?
            .into_iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v)
            .ok_or_else(|| pyo3::exceptions::PyKeyError::new_err(key.to_owned()))
    }

    /// `Name(field=value, …)`.
    fn repr(&self, py: Python<'_>) -> PyResult<String> {
        let parts = self
            .fields(py)?
            .into_iter()
            .map(|(k, v)| Ok(format!("{k}={}", v.repr()?)))
            .collect::<PyResult<Vec<_>>>()?;
        Ok(format!("{}({})", Self::NAME, parts.join(", ")))
    }
}

/// A frozen report class whose every field is written once: its type, its doc (the Python property's
/// docstring) and how it is read from the core crate's report `$r`. Generates the struct (fields readable
/// from Python), `From<core report>`, and `as_dict()`, `report["field"]` and `repr()` over the same list.
macro_rules! report {
    (
        $(#[$meta:meta])*
        $py_name:literal $name:ident from $core:ty, |$r:ident| {
            $( $(#[$field_meta:meta])* $field:ident : $ty:ty = $value:expr ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        #[pyclass(name = $py_name, module = "hippo_nav._core", frozen, eq, mapping, get_all)]
        #[derive(Clone, PartialEq)]
        pub struct $name {
            $( $(#[$field_meta])* $field: $ty, )*
        }

        impl From<$core> for $name {
            fn from($r: $core) -> Self {
                Self { $( $field: $value, )* }
            }
        }

        impl $crate::convert::ReportFields for $name {
            const NAME: &'static str = $py_name;
            fn fields<'py>(
                &self,
                py: Python<'py>,
            ) -> PyResult<Vec<(&'static str, Bound<'py, PyAny>)>> {
                use pyo3::IntoPyObjectExt;
                Ok(vec![ $( (stringify!($field), self.$field.clone().into_bound_py_any(py)?), )* ])
            }
        }

        #[pymethods]
        impl $name {
            /// The fields as a plain dict (e.g. for JSON).
            fn as_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
                $crate::convert::ReportFields::dict(self, py)
            }
            fn __getitem__<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
                $crate::convert::ReportFields::item(self, py, key)
            }
            fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
                $crate::convert::ReportFields::repr(self, py)
            }
        }
    };
}
pub(crate) use report;
