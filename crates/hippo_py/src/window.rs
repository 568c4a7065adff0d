//! Bindings of `hippo_vo`: the sliding-window refinement the stereo VO runs after every keyframe.
//!
//! Poses cross as 4×4 float64 `camera_from_world` matrices; a keyframe's observations as landmark ids
//! (n,) int64, left pixels (n, 2) float64 and right-image columns (n,) float64 (NaN: no right match).
//! The adjustment runs with the interpreter released.
use crate::convert::{flat_f64, rows_f64, to_numpy};
use crate::errors::{to_py_err, HippoNavError};
use hippo_vo::window::isometry_from_matrix;
use hippo_vo::{Observation, SlidingWindow, StereoCamera, WindowParams};
use nalgebra::Matrix4;
use numpy::{PyReadonlyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The last keyframes of the VO and their landmarks, refined jointly (see `hippo_vo`). Private: driven by
/// `hippo_nav.vo.StereoOdometry` when `VoParams.window_keyframes` ≥ 2.
#[pyclass(name = "_SlidingWindow", module = "hippo_nav._core")]
pub struct PySlidingWindow {
    inner: SlidingWindow,
}

#[pymethods]
impl PySlidingWindow {
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, baseline_m, max_keyframes=8, fixed_keyframes=0, pixel_sigma_px=1.0, right_sigma_px=1.0, iterations=6, min_shared_landmarks=20, min_disparity_px=1.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        baseline_m: f64,
        max_keyframes: usize,
        fixed_keyframes: usize,
        pixel_sigma_px: f64,
        right_sigma_px: f64,
        iterations: usize,
        min_shared_landmarks: usize,
        min_disparity_px: f64,
    ) -> PyResult<Self> {
        let camera = StereoCamera::new(fx, fy, cx, cy, baseline_m).map_err(to_py_err)?;
        let params = WindowParams {
            max_keyframes,
            fixed_keyframes,
            pixel_sigma_px,
            right_sigma_px,
            iterations,
            min_shared_landmarks,
            min_disparity_px,
            ..WindowParams::default()
        };
        Ok(Self {
            inner: SlidingWindow::new(camera, params).map_err(to_py_err)?,
        })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Landmarks held.
    #[getter]
    fn landmarks(&self) -> usize {
        self.inner.landmarks()
    }

    /// Forget every keyframe and landmark.
    fn clear(&mut self) {
        self.inner.clear();
    }

    /// Add a keyframe and refine the window; a dict: `camera_from_world` (4, 4), `reset`,
    /// `shared_landmarks`, `keyframes`, `landmarks_adjusted`, `new_outliers`, `outlier` (n,) bool (the landmark has an outlier observation: stop tracking it),
    /// `point_camera` (n, 3) (NaN where none), `initial_cost`, `final_cost`.
    fn add_keyframe<'py>(
        &mut self,
        py: Python<'py>,
        camera_from_world: PyReadonlyArrayDyn<'_, f64>,
        landmarks: PyReadonlyArray1<'_, i64>,
        left_px: PyReadonlyArrayDyn<'_, f64>,
        right_u_px: PyReadonlyArray1<'_, f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let m =
            Matrix4::from_row_slice(&flat_f64("camera_from_world", &camera_from_world, &[4, 4])?);
        let pose = isometry_from_matrix(&m).map_err(to_py_err)?;
        let (n, left) = rows_f64("left_px", &left_px, &[2])?;
        if landmarks.len() != n || right_u_px.len() != n {
            return Err(HippoNavError::new_err(format!(
                "`landmarks` ({}), `left_px` ({n}) and `right_u_px` ({}) must have one row per observation",
                landmarks.len(),
                right_u_px.len()
            )));
        }
        let ids = landmarks.as_array();
        let right = right_u_px.as_array();
        let mut observations = Vec::with_capacity(n);
        for i in 0..n {
            let id = u64::try_from(ids[i]).map_err(|_| {
                HippoNavError::new_err(format!("landmark ids must be ≥ 0, got {}", ids[i]))
            })?;
            observations.push(Observation {
                landmark: id,
                left_px: [left[2 * i], left[2 * i + 1]],
                right_u_px: right[i],
            });
        }
        let inner = &mut self.inner;
        let outcome = py
            .detach(|| inner.add_keyframe(pose, &observations))
            .map_err(to_py_err)?;
        let dict = PyDict::new(py);
        let matrix = outcome.camera_from_world.to_homogeneous();
        let rows: Vec<f64> = (0..4)
            .flat_map(|r| (0..4).map(move |c| matrix[(r, c)]))
            .collect();
        dict.set_item("camera_from_world", to_numpy(py, rows, &[4, 4])?)?;
        dict.set_item("reset", outcome.reset)?;
        dict.set_item("shared_landmarks", outcome.shared_landmarks)?;
        dict.set_item("keyframes", outcome.keyframes)?;
        dict.set_item("landmarks_adjusted", outcome.landmarks_adjusted)?;
        dict.set_item("new_outliers", outcome.new_outliers)?;
        dict.set_item("outlier", to_numpy(py, outcome.outlier, &[n])?)?;
        let points: Vec<f64> = outcome.point_camera.iter().flatten().copied().collect();
        dict.set_item("point_camera", to_numpy(py, points, &[n, 3])?)?;
        dict.set_item("initial_cost", outcome.initial_cost)?;
        dict.set_item("final_cost", outcome.final_cost)?;
        Ok(dict)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySlidingWindow>()?;
    Ok(())
}
