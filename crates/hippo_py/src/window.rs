//! Bindings of `hippo_vo`: the sliding-window refinement the stereo VO runs after every keyframe.
//!
//! Poses cross as 4×4 float64 `camera_from_world` matrices; a keyframe's observations as landmark ids
//! (n,) int64, left pixels (n, 2) float64 and right-image columns (n,) float64 (NaN: no right match).
//! The adjustment runs with the interpreter released. `_refine_matches` refines KLT matches with a warped
//! window (`hippo_vo::tracks`); `_frame_offset` fits one frame's disparity offset (`hippo_vo::disparity`).
use crate::convert::{flat_f64, rows_f64, section_from_json, to_numpy};
use crate::errors::{to_py_err, HippoNavError};
use hippo_vo::window::isometry_from_matrix;
use hippo_vo::{
    frame_offset, refine_matches, GrayImage, Observation, OffsetTracks, RefineParams,
    SlidingWindow, StereoCamera, WarpModel, WindowParams,
};
use nalgebra::Matrix4;
use numpy::{
    PyArrayDyn, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
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
    #[pyo3(signature = (fx, fy, cx, cy, baseline_m, params_json=None))]
    fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        baseline_m: f64,
        params_json: Option<&str>,
    ) -> PyResult<Self> {
        let camera = StereoCamera::new(fx, fy, cx, cy, baseline_m).map_err(to_py_err)?;
        let params: WindowParams =
            section_from_json(params_json, "window parameters", "vo.window")?;
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

/// A C-contiguous (H, W) uint8 image as the refinement's view of it.
fn gray<'a>(name: &str, image: &'a PyReadonlyArray2<'_, u8>) -> PyResult<GrayImage<'a>> {
    let shape = image.shape();
    let wrong = || {
        HippoNavError::new_err(format!(
            "`{name}` must be a C-contiguous (H, W) uint8 image"
        ))
    };
    if !image.is_c_contiguous() {
        return Err(wrong());
    }
    let data = image.as_slice().map_err(|_| wrong())?;
    GrayImage::new(data, shape[1], shape[0]).map_err(to_py_err)
}

/// KLT matches refined with a warped window (see `hippo_vo::tracks`): `model` "affine" (temporal tracks)
/// or "row_shear" (rectified stereo). Returns (refined (n, 2) float64, refined (n,) bool); where a match
/// could not be refined its row holds the match as given. Private: used by `hippo_nav.vo.StereoOdometry`.
#[pyfunction]
#[pyo3(signature = (image_a, image_b, points_a, matched_b, model, half_window_px, max_iterations=5, max_shift_px=1.0))]
#[allow(clippy::too_many_arguments, clippy::type_complexity)]
fn _refine_matches<'py>(
    py: Python<'py>,
    image_a: PyReadonlyArray2<'_, u8>,
    image_b: PyReadonlyArray2<'_, u8>,
    points_a: PyReadonlyArrayDyn<'_, f64>,
    matched_b: PyReadonlyArrayDyn<'_, f64>,
    model: &str,
    half_window_px: usize,
    max_iterations: usize,
    max_shift_px: f64,
) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<bool>>)> {
    let model = match model {
        "affine" => WarpModel::Affine,
        "row_shear" => WarpModel::RowShear,
        other => {
            return Err(HippoNavError::new_err(format!(
                "unknown warp model {other:?}: use \"affine\" or \"row_shear\""
            )))
        }
    };
    let (a, b) = (gray("image_a", &image_a)?, gray("image_b", &image_b)?);
    let (n, points) = rows_f64("points_a", &points_a, &[2])?;
    let (m, matched) = rows_f64("matched_b", &matched_b, &[2])?;
    if m != n {
        return Err(HippoNavError::new_err(format!(
            "`points_a` ({n}) and `matched_b` ({m}) must have one row per match"
        )));
    }
    let pairs = |v: &[f64]| -> Vec<[f64; 2]> { v.chunks_exact(2).map(|c| [c[0], c[1]]).collect() };
    let (points, matched) = (pairs(&points), pairs(&matched));
    let params = RefineParams {
        half_window_px,
        max_iterations,
        max_shift_px,
        ..RefineParams::default()
    };
    let refined = py
        .detach(|| refine_matches(&a, &b, &points, &matched, model, &params))
        .map_err(to_py_err)?;
    let ok: Vec<bool> = refined.iter().map(Option::is_some).collect();
    let out: Vec<f64> = refined
        .iter()
        .zip(&matched)
        .flat_map(|(r, m)| r.unwrap_or(*m))
        .collect();
    Ok((to_numpy(py, out, &[n, 2])?, to_numpy(py, ok, &[n])?))
}

/// One frame's disparity offset fitted to its motion (see `hippo_vo::disparity`): `cur_from_prev` (4, 4)
/// the step to start from; `prev_points_m` (n, 3), `left_px` (n, 2), `right_u_px` (n,) (finite; read where
/// `has_right`), `has_right` (n,) bool; `camera` = (fx, fy, cx, cy, baseline_m). Returns (offset px, its
/// standard error px), or None when the frame cannot be fitted. Private: used by
/// `hippo_nav.vo.disparity.frame_offset_px`.
#[pyfunction]
#[pyo3(signature = (cur_from_prev, prev_points_m, left_px, right_u_px, has_right, camera, huber_px, reject_px=None))]
#[allow(clippy::too_many_arguments)]
fn _frame_offset(
    py: Python<'_>,
    cur_from_prev: PyReadonlyArrayDyn<'_, f64>,
    prev_points_m: PyReadonlyArrayDyn<'_, f64>,
    left_px: PyReadonlyArrayDyn<'_, f64>,
    right_u_px: PyReadonlyArrayDyn<'_, f64>,
    has_right: PyReadonlyArray1<'_, bool>,
    camera: (f64, f64, f64, f64, f64),
    huber_px: f64,
    reject_px: Option<f64>,
) -> PyResult<Option<(f64, f64)>> {
    let (fx, fy, cx, cy, baseline_m) = camera;
    let camera = StereoCamera::new(fx, fy, cx, cy, baseline_m).map_err(to_py_err)?;
    let pose = flat_f64("cur_from_prev", &cur_from_prev, &[4, 4])?;
    let (n, points) = rows_f64("prev_points_m", &prev_points_m, &[3])?;
    let (n_left, left) = rows_f64("left_px", &left_px, &[2])?;
    let (n_right, right) = rows_f64("right_u_px", &right_u_px, &[])?;
    let has: Vec<bool> = has_right.as_array().iter().copied().collect();
    if n_left != n || n_right != n || has.len() != n {
        return Err(HippoNavError::new_err(format!(
            "`prev_points_m` ({n}), `left_px` ({n_left}), `right_u_px` ({n_right}) and `has_right` ({}) must \
             have one row per track",
            has.len()
        )));
    }
    for (name, value) in [
        ("huber_px", huber_px),
        ("reject_px", reject_px.unwrap_or(1.0)),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(HippoNavError::new_err(format!(
                "`{name}` = {value} must be finite and > 0"
            )));
        }
    }
    let rotation = nalgebra::Matrix3::from_fn(|r, c| pose[4 * r + c]);
    let translation = nalgebra::Vector3::new(pose[3], pose[7], pose[11]);
    let points: Vec<[f64; 3]> = points.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let left: Vec<[f64; 2]> = left.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
    let tracks = OffsetTracks {
        prev_points_m: &points,
        left_px: &left,
        right_u_px: &right,
        has_right: &has,
    };
    let fitted = py.detach(|| {
        frame_offset(
            &camera,
            &rotation,
            &translation,
            &tracks,
            huber_px,
            reject_px,
        )
    });
    Ok(fitted.map(|f| (f.offset_px, f.sigma_px)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySlidingWindow>()?;
    m.add_function(wrap_pyfunction!(_refine_matches, m)?)?;
    m.add_function(wrap_pyfunction!(_frame_offset, m)?)?;
    Ok(())
}
