//! Bindings of `hippo_views::words`: vocabularies of binary words and word view cells.
//!
//! Descriptors cross as (n, 32) uint8 arrays (OpenCV's ORB output, any layout), keypoints as (n, 2)
//! float64 pixel positions (the Python wrapper converts). Training, bags and queries run with the interpreter released.
use crate::convert::{candidate_ids, rows_f64, rows_u8, to_numpy, CandidatesArg};
use crate::errors::to_py_err;
use hippo_views::words::{
    ratio_test_matches, BowVector, Descriptor, TrainingParams, Vocabulary, WordCells,
};
use numpy::{IntoPyArray, PyArray1, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

/// (n, 32) uint8 descriptors (OpenCV's ORB output, any layout) as a vector.
fn descriptors(a: &PyReadonlyArrayDyn<'_, u8>) -> PyResult<Vec<Descriptor>> {
    let (_, bytes) = rows_u8("descriptors", a, &[32])?;
    Ok(bytes
        .chunks_exact(32)
        .map(|c| {
            let mut d = [0u8; 32];
            d.copy_from_slice(c);
            d
        })
        .collect())
}

/// (n, 2) float64 pixel positions (x, y), finite, as a vector.
fn keypoints(a: &PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<[f32; 2]>> {
    let (_, values) = rows_f64("keypoints_px", a, &[2])?;
    Ok(values
        .chunks_exact(2)
        .map(|c| [c[0] as f32, c[1] as f32])
        .collect())
}

/// A bag of words: sparse tf-idf weights of one view.
#[pyclass(name = "BagOfWords", module = "hippo_nav._core", frozen)]
pub struct PyBag {
    inner: BowVector,
}

#[pymethods]
impl PyBag {
    fn __len__(&self) -> usize {
        self.inner.entries.len()
    }
    /// Word ids (uint32) and their weights (float32, summing to 1), sorted by word.
    #[allow(clippy::type_complexity)]
    fn entries<'py>(
        &self,
        py: Python<'py>,
    ) -> (Bound<'py, PyArray1<u32>>, Bound<'py, PyArray1<f32>>) {
        let (w, v): (Vec<u32>, Vec<f32>) = self.inner.entries.iter().copied().unzip();
        (w.into_pyarray(py), v.into_pyarray(py))
    }
    /// DBoW2's L1 similarity with another bag, in [0, 1].
    fn score(&self, other: &PyBag) -> f32 {
        self.inner.score(&other.inner)
    }
}

/// A vocabulary of binary words (see `hippo_views::words`). Private: wrapped by
/// `hippo_nav.view_words.Vocabulary`.
#[pyclass(name = "_Vocabulary", module = "hippo_nav._core", frozen)]
pub struct PyVocabulary {
    inner: Vocabulary,
}

#[pymethods]
impl PyVocabulary {
    /// Train on the descriptors of a list of images (each (n, 32) uint8).
    #[staticmethod]
    #[pyo3(signature = (images, branching=10, levels=4, seed=0))]
    fn train(
        py: Python<'_>,
        images: Vec<PyReadonlyArrayDyn<'_, u8>>,
        branching: usize,
        levels: usize,
        seed: u64,
    ) -> PyResult<Self> {
        let images: Vec<Vec<Descriptor>> =
            images.iter().map(descriptors).collect::<PyResult<_>>()?;
        let params = TrainingParams {
            branching,
            levels,
            seed,
        };
        let inner = py
            .detach(|| Vocabulary::train(&images, params))
            .map_err(to_py_err)?;
        Ok(Self { inner })
    }

    /// Read the file format of `to_bytes` (checked: header, length, checksum, structure).
    #[staticmethod]
    fn from_bytes(data: &[u8]) -> PyResult<Self> {
        Ok(Self {
            inner: Vocabulary::from_bytes(data).map_err(to_py_err)?,
        })
    }

    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.inner.to_bytes())
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    #[getter]
    fn branching(&self) -> usize {
        self.inner.branching()
    }

    #[getter]
    fn levels(&self) -> usize {
        self.inner.levels()
    }

    /// Inverse document frequency of every word, float32.
    fn idf<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f32>> {
        self.inner.idf().to_vec().into_pyarray(py)
    }

    /// The word of every descriptor, uint32.
    fn words<'py>(
        &self,
        py: Python<'py>,
        descriptors_u8: PyReadonlyArrayDyn<'_, u8>,
    ) -> PyResult<Bound<'py, PyArray1<u32>>> {
        let d = descriptors(&descriptors_u8)?;
        let inner = &self.inner;
        Ok(py.detach(|| inner.words(&d)).into_pyarray(py))
    }

    /// The tf-idf bag of words of one view's descriptors.
    fn bag(&self, py: Python<'_>, descriptors_u8: PyReadonlyArrayDyn<'_, u8>) -> PyResult<PyBag> {
        let d = descriptors(&descriptors_u8)?;
        let inner = &self.inner;
        Ok(PyBag {
            inner: py.detach(|| inner.bag(&d)),
        })
    }
}

/// Word view cells: stored views (bag, keypoints, descriptors) and an inverted index. Private: wrapped
/// by `hippo_nav.view_words.WordViewCells`.
#[pyclass(name = "_WordCells", module = "hippo_nav._core")]
pub struct PyWordCells {
    inner: WordCells,
}

#[pymethods]
impl PyWordCells {
    #[new]
    fn new(vocabulary: &PyVocabulary) -> Self {
        Self {
            inner: WordCells::new(vocabulary.inner.clone()),
        }
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// The bag of words of a view (its features checked as `add` does).
    fn bag(
        &self,
        py: Python<'_>,
        keypoints_px: PyReadonlyArrayDyn<'_, f64>,
        descriptors_u8: PyReadonlyArrayDyn<'_, u8>,
    ) -> PyResult<PyBag> {
        let k = keypoints(&keypoints_px)?;
        let d = descriptors(&descriptors_u8)?;
        let inner = &self.inner;
        let bag = py.detach(|| inner.bag(&k, &d)).map_err(to_py_err)?;
        Ok(PyBag { inner: bag })
    }

    /// Store a view as a new cell (with its bag when already computed); returns its id.
    #[pyo3(signature = (keypoints_px, descriptors_u8, bag=None))]
    fn add(
        &mut self,
        keypoints_px: PyReadonlyArrayDyn<'_, f64>,
        descriptors_u8: PyReadonlyArrayDyn<'_, u8>,
        bag: Option<&PyBag>,
    ) -> PyResult<usize> {
        let k = keypoints(&keypoints_px)?;
        let d = descriptors(&descriptors_u8)?;
        match bag {
            Some(b) => self.inner.add_with_bag(k, d, b.inner.clone()),
            None => self.inner.add(k, d),
        }
        .map_err(to_py_err)
    }

    /// The `top_k` most similar cells as [(cell_id, score)], best first (among `candidates` if given).
    #[pyo3(signature = (bag, candidates=None, top_k=5))]
    fn query(
        &self,
        py: Python<'_>,
        bag: &PyBag,
        candidates: Option<CandidatesArg<'_>>,
        top_k: usize,
    ) -> PyResult<Vec<(usize, f32)>> {
        let ids = candidates.as_ref().map(candidate_ids).transpose()?;
        let inner = &self.inner;
        py.detach(|| inner.query(&bag.inner, ids.as_deref(), top_k))
            .map_err(to_py_err)
    }

    /// The stored features of cell `cell_id`: keypoints (n, 2) float32 and descriptors (n, 32) uint8.
    #[allow(clippy::type_complexity)]
    fn features<'py>(
        &self,
        py: Python<'py>,
        cell_id: usize,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f32>>, Bound<'py, PyArrayDyn<u8>>)> {
        let cell = self.inner.cell(cell_id).map_err(to_py_err)?;
        let n = cell.keypoints_px.len();
        let k: Vec<f32> = cell.keypoints_px.iter().flatten().copied().collect();
        let d: Vec<u8> = cell.descriptors.iter().flatten().copied().collect();
        Ok((to_numpy(py, k, &[n, 2])?, to_numpy(py, d, &[n, 32])?))
    }

    /// The bag of cell `cell_id`.
    fn cell_bag(&self, cell_id: usize) -> PyResult<PyBag> {
        Ok(PyBag {
            inner: self.inner.cell(cell_id).map_err(to_py_err)?.bag.clone(),
        })
    }
}

/// Brute-force Hamming matches of `query` against `stored` ((n, 32) uint8 each) with Lowe's ratio test:
/// (query indices, stored indices) as int64 arrays, in query order; what OpenCV's `knnMatch(k=2)` and the
/// ratio test give (`hippo_views::words::ratio_test_matches`), with the interpreter released.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn hamming_ratio_matches<'py>(
    py: Python<'py>,
    query: PyReadonlyArrayDyn<'py, u8>,
    stored: PyReadonlyArrayDyn<'py, u8>,
    ratio: f64,
) -> PyResult<(Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>)> {
    if !(ratio.is_finite() && ratio > 0.0 && ratio <= 1.0) {
        return Err(crate::errors::HippoNavError::new_err(format!(
            "ratio {ratio}: give Lowe's ratio in (0, 1]"
        )));
    }
    let (query, stored) = (descriptors(&query)?, descriptors(&stored)?);
    let pairs = py.detach(|| ratio_test_matches(&query, &stored, ratio));
    let (q, s): (Vec<i64>, Vec<i64>) = pairs
        .iter()
        .map(|&(q, s)| (i64::from(q), i64::from(s)))
        .unzip();
    Ok((q.into_pyarray(py), s.into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(hamming_ratio_matches, m)?)?;
    m.add_class::<PyBag>()?;
    m.add_class::<PyVocabulary>()?;
    m.add_class::<PyWordCells>()?;
    Ok(())
}
