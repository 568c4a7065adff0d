//! Bindings of `hippo_views`: local view cells.
//!
//! Templates cross as (height, width) float arrays of any layout (float32 or float64; copied once into a
//! contiguous float32 buffer). Parameters cross as JSON of `ViewCellParams` (the Rust defaults are the
//! single source). Searches run with the interpreter released.
use crate::convert::{candidate_ids, params_to_json, section_from_json, to_numpy, CandidatesArg};
use crate::errors::{to_py_err, HippoNavError};
use hippo_views::{ViewCellParams, ViewCells, ViewObservation, ViewStatus};
use numpy::{IntoPyArray, PyArray1, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// A template array as given: float32 or float64.
#[derive(FromPyObject)]
enum TemplateArg<'py> {
    F32(PyReadonlyArrayDyn<'py, f32>),
    F64(PyReadonlyArrayDyn<'py, f64>),
}

/// Check the shape and copy to a contiguous row-major float32 vector (finiteness is checked by the core).
fn template_vec(t: &TemplateArg<'_>, p: &ViewCellParams) -> PyResult<Vec<f32>> {
    let shape = match t {
        TemplateArg::F32(a) => a.shape().to_vec(),
        TemplateArg::F64(a) => a.shape().to_vec(),
    };
    if shape != [p.height_px, p.width_px] {
        return Err(HippoNavError::new_err(format!(
            "template has shape {shape:?}, expected ({}, {}) = (height_px, width_px); make it with \
             hippo_nav.view_cells.TemplateViewCells.template_from_image with the same parameters",
            p.height_px, p.width_px
        )));
    }
    Ok(match t {
        TemplateArg::F32(a) => a.as_array().iter().copied().collect(),
        TemplateArg::F64(a) => a.as_array().iter().map(|&v| v as f32).collect(),
    })
}

/// What one observation did (see `hippo_views::ViewObservation`).
#[pyclass(name = "ViewObservation", module = "hippo_nav._core", frozen, eq)]
#[derive(PartialEq)]
pub struct PyViewObservation {
    inner: ViewObservation,
}

#[pymethods]
impl PyViewObservation {
    /// "familiar", "new" or "uninformative".
    #[getter]
    fn status(&self) -> &'static str {
        match self.inner.status {
            ViewStatus::Familiar => "familiar",
            ViewStatus::New => "new",
            ViewStatus::Uninformative => "uninformative",
        }
    }
    /// The matched or created cell; None when the view was uninformative.
    #[getter]
    fn cell_id(&self) -> Option<usize> {
        self.inner.cell_id
    }
    #[getter]
    fn is_new(&self) -> bool {
        self.inner.status == ViewStatus::New
    }
    /// Best normalised difference among the cells stored before this view, in [0, 1].
    #[getter]
    fn difference(&self) -> f32 {
        self.inner.difference
    }
    #[getter]
    fn shift_px(&self) -> i32 {
        self.inner.shift_px
    }
    /// Camera heading now minus its heading when the cell was stored (radians, counter-clockwise positive).
    #[getter]
    fn relative_heading_rad(&self) -> f64 {
        self.inner.relative_heading_rad
    }
    fn __repr__(&self) -> String {
        format!(
            "ViewObservation(status={:?}, cell_id={:?}, difference={:.4}, shift_px={}, relative_heading_rad={:.4})",
            self.status(),
            self.inner.cell_id,
            self.inner.difference,
            self.inner.shift_px,
            self.inner.relative_heading_rad
        )
    }
}

/// Local view cells: stored templates and a fast exact best-match search. Private: wrapped by
/// `hippo_nav.view_cells.TemplateViewCells`.
#[pyclass(name = "_ViewCells", module = "hippo_nav._core")]
pub struct PyViewCells {
    cells: ViewCells,
}

#[pymethods]
impl PyViewCells {
    /// `params_json`: JSON of every view-cell parameter (use `hippo_nav.view_cells.TemplateViewConfig`);
    /// None = defaults.
    #[new]
    #[pyo3(signature = (params_json=None))]
    fn new(params_json: Option<&str>) -> PyResult<Self> {
        let params: ViewCellParams = section_from_json(params_json, "view-cell config", "views")?;
        Ok(Self {
            cells: ViewCells::new(params).map_err(to_py_err)?,
        })
    }

    /// The resolved parameters as JSON.
    fn params_json(&self) -> PyResult<String> {
        params_to_json(self.cells.params())
    }

    fn __len__(&self) -> usize {
        self.cells.len()
    }

    /// Match a (height, width) template; store it as a new cell when it is novel. `candidates`: cell ids
    /// to match against (None = every cell).
    #[pyo3(signature = (template, candidates=None))]
    fn observe(
        &mut self,
        py: Python<'_>,
        template: TemplateArg<'_>,
        candidates: Option<CandidatesArg<'_>>,
    ) -> PyResult<PyViewObservation> {
        let t = template_vec(&template, self.cells.params())?;
        let ids = candidates.as_ref().map(candidate_ids).transpose()?;
        let cells = &mut self.cells;
        let inner = py
            .detach(|| match &ids {
                None => cells.observe(&t),
                Some(ids) => cells.observe_among(&t, ids),
            })
            .map_err(to_py_err)?;
        Ok(PyViewObservation { inner })
    }

    /// Store a template as a new cell without matching (e.g. to restore saved cells); returns its id.
    fn add(&mut self, template: TemplateArg<'_>) -> PyResult<usize> {
        let t = template_vec(&template, self.cells.params())?;
        self.cells.add(&t).map_err(to_py_err)
    }

    /// Best stored cell: (cell_id, difference, shift_px), or None when there is none to match.
    /// `candidates`: cell ids to search (None = every cell).
    #[pyo3(signature = (template, candidates=None))]
    fn best_match(
        &self,
        py: Python<'_>,
        template: TemplateArg<'_>,
        candidates: Option<CandidatesArg<'_>>,
    ) -> PyResult<Option<(usize, f32, i32)>> {
        let t = template_vec(&template, self.cells.params())?;
        let ids = candidates.as_ref().map(candidate_ids).transpose()?;
        let cells = &self.cells;
        let m = py
            .detach(|| match &ids {
                None => cells.best_match(&t),
                Some(ids) => cells.best_match_among(&t, ids),
            })
            .map_err(to_py_err)?;
        Ok(m.map(|m| (m.cell_id, m.difference, m.shift_px)))
    }

    /// The same as `best_match` by plain exhaustive search (reference for tests and benchmarks).
    fn best_match_brute_force(
        &self,
        py: Python<'_>,
        template: TemplateArg<'_>,
    ) -> PyResult<Option<(usize, f32, i32)>> {
        let t = template_vec(&template, self.cells.params())?;
        let cells = &self.cells;
        let m = py
            .detach(|| cells.best_match_brute_force(&t))
            .map_err(to_py_err)?;
        Ok(m.map(|m| (m.cell_id, m.difference, m.shift_px)))
    }

    /// Difference and best shift against every cell, in id order: (float32 (n,), int32 (n,)).
    #[allow(clippy::type_complexity)]
    fn differences<'py>(
        &self,
        py: Python<'py>,
        template: TemplateArg<'_>,
    ) -> PyResult<(Bound<'py, PyArray1<f32>>, Bound<'py, PyArray1<i32>>)> {
        let t = template_vec(&template, self.cells.params())?;
        let cells = &self.cells;
        let all = py.detach(|| cells.differences(&t)).map_err(to_py_err)?;
        let (d, s): (Vec<f32>, Vec<i32>) = all.into_iter().unzip();
        Ok((d.into_pyarray(py), s.into_pyarray(py)))
    }

    /// Stored template of cell `cell_id`, shape (height, width).
    fn template<'py>(
        &self,
        py: Python<'py>,
        cell_id: usize,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let p = self.cells.params();
        let t = self.cells.template(cell_id).map_err(to_py_err)?;
        to_numpy(py, t, &[p.height_px, p.width_px])
    }

    /// Every stored template, shape (len, height, width).
    fn templates<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let p = self.cells.params();
        to_numpy(
            py,
            self.cells.templates(),
            &[self.cells.len(), p.height_px, p.width_px],
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyViewCells>()?;
    m.add_class::<PyViewObservation>()?;
    Ok(())
}
