//! Bindings of `hippo_attractor`: the spatial-memory network, bump decoding and Bayesian fusion.
//!
//! Configuration crosses the boundary as JSON of `SpatialMemoryParams` (the Rust defaults are the single
//! source; Python's pydantic model is generated from them). Readouts cross as frozen typed objects
//! (`SpatialReadout`, `ModuleReadout`, `Bump`) that hold the Rust readout and build their Python values
//! when read; activity arrays cross as numpy arrays moved out of Rust vectors without copying.
use crate::convert::{flat_f64, pair, params_to_json, section_from_json, to_numpy};
use crate::errors::{to_py_err, HippoNavError};
use hippo_attractor::{
    find_bumps as decode_bumps, fuse_homocentric, AttractorError, Bump2, FusedEstimate,
    ModuleReadout, SpatialMemory, SpatialMemoryParams, SpatialReadout, ViewInjection, N_MODULES,
};
use numpy::{IntoPyArray, PyArray1, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

/// Like `flat_f64`, for activities: firing rates are never negative.
fn flat_activity(
    name: &str,
    a: &PyReadonlyArrayDyn<'_, f64>,
    shape: &[usize],
) -> PyResult<Vec<f64>> {
    let v = flat_f64(name, a, shape)?;
    if let Some(i) = v.iter().position(|x| *x < 0.0) {
        return Err(HippoNavError::new_err(format!(
            "`{name}` holds a negative value ({}) at flat index {i}: activities are firing rates, ≥ 0",
            v[i]
        )));
    }
    Ok(v)
}

enum Engine {
    F32(Box<SpatialMemory<f32>>),
    F64(Box<SpatialMemory<f64>>),
}

/// Apply `$body` to the engine whatever its precision (`$sm` is bound to it, `$t` to its float type).
macro_rules! with_engine {
    ($engine:expr, $sm:ident, $t:ident, $body:expr) => {
        match $engine {
            Engine::F32($sm) => {
                #[allow(dead_code)]
                type $t = f32;
                $body
            }
            Engine::F64($sm) => {
                #[allow(dead_code)]
                type $t = f64;
                $body
            }
        }
    };
}

/// A familiar view's stored patterns as Python passes them: HD profile, layer-II patterns, strength.
type ViewArg<'a> = (
    PyReadonlyArrayDyn<'a, f64>,
    Vec<Option<PyReadonlyArrayDyn<'a, f64>>>,
    f64,
);
/// A bump as Python sees it: ((centre x, y) rad, (std x, y) rad, peak).
type BumpTuple = ((f64, f64), (f64, f64), f64);
type ArrayPair<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// One bump on the 2-D neural torus (see `hippo_attractor::Bump2`): centre and per-axis standard
/// deviation (rad), and its mass (total activity inside it; 1 for a fused estimate).
#[pyclass(name = "Bump", module = "hippo_nav._core", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyBump {
    inner: Bump2,
}

impl From<FusedEstimate> for PyBump {
    fn from(f: FusedEstimate) -> Self {
        Self {
            inner: Bump2 {
                mean_rad: f.mean_rad,
                std_rad: f.std_rad,
                mass: 1.0,
            },
        }
    }
}

#[pymethods]
impl PyBump {
    #[new]
    #[pyo3(signature = (mean_rad, std_rad, mass=1.0))]
    fn new(mean_rad: (f64, f64), std_rad: (f64, f64), mass: f64) -> Self {
        Self {
            inner: Bump2 {
                mean_rad: [mean_rad.0, mean_rad.1],
                std_rad: [std_rad.0, std_rad.1],
                mass,
            },
        }
    }
    /// Centre (θx, θy) on the torus, rad.
    #[getter]
    fn mean_rad(&self) -> (f64, f64) {
        pair(self.inner.mean_rad)
    }
    /// Per-axis standard deviation (σx, σy), rad.
    #[getter]
    fn std_rad(&self) -> (f64, f64) {
        pair(self.inner.std_rad)
    }
    #[getter]
    fn mass(&self) -> f64 {
        self.inner.mass
    }
    /// Mean of the two per-axis standard deviations, rad.
    #[getter]
    fn width_rad(&self) -> f64 {
        0.5 * (self.inner.std_rad[0] + self.inner.std_rad[1])
    }
    fn __repr__(&self) -> String {
        let b = &self.inner;
        format!(
            "Bump(mean_rad=({:.4}, {:.4}), std_rad=({:.4}, {:.4}), mass={:.4})",
            b.mean_rad[0], b.mean_rad[1], b.std_rad[0], b.std_rad[1], b.mass
        )
    }
}

fn bumps_tuple<'py>(py: Python<'py>, bumps: &[Bump2]) -> PyResult<Bound<'py, PyTuple>> {
    PyTuple::new(py, bumps.iter().map(|&inner| PyBump { inner }))
}

/// One grid module's part of a readout (see `hippo_attractor::ModuleReadout`).
#[pyclass(name = "ModuleReadout", module = "hippo_nav._core", frozen, eq)]
#[derive(PartialEq)]
pub struct PyModuleReadout {
    inner: ModuleReadout,
}

#[pymethods]
impl PyModuleReadout {
    /// Bumps per torus axis (1, 2, 4).
    #[getter]
    fn k(&self) -> usize {
        self.inner.k
    }
    #[getter]
    fn lesioned(&self) -> bool {
        self.inner.lesioned
    }
    /// Every bump of the layer-II pattern, strongest first (none when lesioned).
    #[getter]
    fn bumps<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        bumps_tuple(py, &self.inner.bumps)
    }
    /// Centre of the bump being followed (θx, θy), rad.
    #[getter]
    fn tracked_rad(&self) -> (f64, f64) {
        pair(self.inner.tracked_rad)
    }
    /// Unwrapped displacement of the followed bump since reset (x, y), m.
    #[getter]
    fn position_m(&self) -> (f64, f64) {
        pair(self.inner.position_m)
    }
    fn __repr__(&self) -> String {
        let m = &self.inner;
        format!(
            "ModuleReadout(k={}, lesioned={}, bumps={}, tracked_rad=({:.4}, {:.4}), position_m=({:.3}, {:.3}))",
            m.k,
            if m.lesioned { "True" } else { "False" },
            m.bumps.len(),
            m.tracked_rad[0],
            m.tracked_rad[1],
            m.position_m[0],
            m.position_m[1]
        )
    }
}

/// What the network reads out after a frame (see `hippo_attractor::SpatialReadout`). Frozen; nested
/// values are built when read, so a readout costs one small object per frame.
#[pyclass(name = "SpatialReadout", module = "hippo_nav._core", frozen, eq)]
#[derive(PartialEq)]
pub struct PySpatialReadout {
    inner: SpatialReadout,
}

#[pymethods]
impl PySpatialReadout {
    /// Network time since construction, s.
    #[getter]
    fn time_s(&self) -> f64 {
        self.inner.time_s
    }
    /// Decoded heading ψ in [0, 2π), rad.
    #[getter]
    fn heading_rad(&self) -> f64 {
        self.inner.hd.heading_rad
    }
    /// Angular velocity decoded from the HD bump's velocity position, rad/s.
    #[getter]
    fn yaw_rate_rad_s(&self) -> f64 {
        self.inner.hd.yaw_rate_rad_s
    }
    /// Mean activity of the HD ring (0 means its bump died).
    #[getter]
    fn hd_mean_activity(&self) -> f64 {
        self.inner.hd.mean_activity
    }
    /// One readout per grid module, coarsest first (`N_MODULES` of them).
    #[getter]
    fn modules<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(
            py,
            self.inner
                .modules
                .iter()
                .map(|m| PyModuleReadout { inner: m.clone() }),
        )
    }
    /// The Bayesian fusion of the homocentric bumps; None if every module is lesioned or silent.
    #[getter]
    fn fused(&self) -> Option<PyBump> {
        self.inner.fused.map(PyBump::from)
    }
    /// The CA3 place bump; None if the place network is silent.
    #[getter]
    fn place(&self) -> Option<PyBump> {
        self.inner.place.map(|inner| PyBump { inner })
    }
    /// Unwrapped place-code displacement since reset (x, y), m.
    #[getter]
    fn place_position_m(&self) -> (f64, f64) {
        pair(self.inner.place_position_m)
    }
    /// Integration sub-steps taken for the last frame.
    #[getter]
    fn substeps(&self) -> usize {
        self.inner.substeps
    }
    fn __repr__(&self) -> String {
        let r = &self.inner;
        format!(
            "SpatialReadout(time_s={:.3}, heading_rad={:.4}, place_position_m=({:.3}, {:.3}), bumps={:?}, substeps={})",
            r.time_s,
            r.hd.heading_rad,
            r.place_position_m[0],
            r.place_position_m[1],
            r.modules.iter().map(|m| m.bumps.len()).collect::<Vec<_>>(),
            r.substeps
        )
    }
}

/// The whole spatial-memory network (HD ring, `N_MODULES` grid modules, place torus). Private: wrapped by
/// `hippo_nav.engine.SpatialMemory`.
#[pyclass(name = "_SpatialMemory", module = "hippo_nav._core")]
pub struct PySpatialMemory {
    engine: Engine,
}

fn to_vec<T: hippo_attractor::Real>(v: Vec<f64>) -> Vec<T> {
    v.into_iter().map(T::of).collect()
}

fn into_numpy<'py, T: hippo_attractor::Real + numpy::Element>(
    py: Python<'py>,
    v: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    // Expose float64 regardless of the engine's precision: one dtype for callers.
    to_numpy(py, v.into_iter().map(|x| x.f64()).collect(), shape)
}

/// A parameter refused when the engine is built, named by its path in the config file (`engine.hd.n_theta`).
fn engine_config_err(err: AttractorError) -> PyErr {
    match err {
        AttractorError::BadParameter { name, value, why } => HippoNavError::new_err(format!(
            "invalid engine config: engine.{name} = {value}: {why}"
        )),
        other => to_py_err(other),
    }
}

#[pymethods]
impl PySpatialMemory {
    /// `params_json`: JSON of the engine parameters (missing fields are an error: use the Python
    /// `EngineConfig`). `dtype`: "float32" (fast, default) or "float64".
    #[new]
    #[pyo3(signature = (params_json=None, dtype="float32"))]
    fn new(py: Python<'_>, params_json: Option<&str>, dtype: &str) -> PyResult<Self> {
        let params: SpatialMemoryParams =
            section_from_json(params_json, "engine config", "engine")?;
        let engine = match dtype {
            "float32" => py
                .detach(|| SpatialMemory::<f32>::new(params))
                .map(|s| Engine::F32(Box::new(s))),
            "float64" => py
                .detach(|| SpatialMemory::<f64>::new(params))
                .map(|s| Engine::F64(Box::new(s))),
            other => {
                return Err(HippoNavError::new_err(format!(
                    "dtype must be 'float32' or 'float64', not {other:?}"
                )))
            }
        }
        .map_err(engine_config_err)?;
        Ok(Self { engine })
    }

    /// The resolved parameters as JSON.
    fn params_json(&self) -> PyResult<String> {
        with_engine!(&self.engine, sm, T, params_to_json(sm.params()))
    }

    /// Advance one camera frame. `view`: optional (hd_profile (Nθ,), [layer2 (N,N) or None] × N_MODULES,
    /// strength).
    #[pyo3(signature = (yaw_rate_rad_s, speed_m_s, dt_s, view=None))]
    fn step(
        &mut self,
        py: Python<'_>,
        yaw_rate_rad_s: f64,
        speed_m_s: f64,
        dt_s: f64,
        view: Option<ViewArg<'_>>,
    ) -> PyResult<PySpatialReadout> {
        let view = match view {
            None => None,
            Some((hd, grids, strength)) => {
                let (nt, n) = with_engine!(&self.engine, sm, T, {
                    (sm.params().hd.n_theta, sm.params().place.n_theta)
                });
                if grids.len() != N_MODULES {
                    return Err(HippoNavError::new_err(format!(
                        "view grid patterns: expected {N_MODULES} (one per module, None to skip), got {}",
                        grids.len()
                    )));
                }
                let hd = flat_f64("view hd_profile", &hd, &[nt])?;
                let mut g: [Option<Vec<f64>>; N_MODULES] = Default::default();
                for (i, p) in grids.iter().enumerate() {
                    if let Some(p) = p {
                        g[i] = Some(flat_f64("view grid pattern", p, &[n, n])?);
                    }
                }
                Some((hd, g, strength))
            }
        };
        let inner = with_engine!(&mut self.engine, sm, T, {
            let inj = view.map(|(hd, g, strength)| ViewInjection::<T> {
                hd_profile: to_vec(hd),
                grid_layer2: g.map(|p| p.map(to_vec)),
                strength,
            });
            py.detach(|| sm.step(yaw_rate_rad_s, speed_m_s, dt_s, inj.as_ref()))
        })
        .map_err(to_py_err)?;
        Ok(PySpatialReadout { inner })
    }

    /// The current readout (no integration).
    fn readout(&self) -> PySpatialReadout {
        PySpatialReadout {
            inner: with_engine!(&self.engine, sm, T, sm.readout()),
        }
    }

    /// Re-seed every network at a heading and torus phase and let the bumps settle.
    #[pyo3(signature = (heading_rad=0.0, phase_rad=(0.0, 0.0)))]
    fn reset(&mut self, py: Python<'_>, heading_rad: f64, phase_rad: (f64, f64)) -> PyResult<()> {
        with_engine!(&mut self.engine, sm, T, {
            py.detach(|| sm.reset(heading_rad, [phase_rad.0, phase_rad.1]))
        })
        .map_err(to_py_err)
    }

    /// Switch modules off (True) or on, coarsest first.
    fn set_lesions(&mut self, lesioned: [bool; N_MODULES]) {
        with_engine!(&mut self.engine, sm, T, sm.set_lesions(lesioned))
    }

    /// HD-by-velocity activity, shape (Nν, Nθ).
    fn hd_activity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        with_engine!(&self.engine, sm, T, {
            let p = &sm.params().hd;
            into_numpy(py, sm.hd.activity().to_vec(), &[p.n_nu, p.n_theta])
        })
    }

    /// HD θ-profile (activity summed over ν), shape (Nθ,).
    fn hd_profile<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        with_engine!(&self.engine, sm, T, {
            let n = sm.params().hd.n_theta;
            into_numpy(py, sm.hd.theta_profile(), &[n])
        })
    }

    /// Conjunctive activity of grid module `index`, shape (M, M, N, N) = (νy, νx, θy, θx).
    fn grid_activity<'py>(
        &self,
        py: Python<'py>,
        index: i64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let index = module_index(index)?;
        with_engine!(&self.engine, sm, T, {
            let g = sm
                .grids
                .get(index)
                .ok_or_else(|| module_index_error(index as i64))?;
            let p = g.params();
            into_numpy(py, g.activity(), &[p.n_nu, p.n_nu, p.n_theta, p.n_theta])
        })
    }

    /// Layer-II pattern of grid module `index` (summed over velocity), shape (N, N) = (θy, θx).
    fn grid_layer2<'py>(
        &self,
        py: Python<'py>,
        index: i64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let index = module_index(index)?;
        with_engine!(&self.engine, sm, T, {
            let g = sm
                .grids
                .get(index)
                .ok_or_else(|| module_index_error(index as i64))?;
            let n = g.params().n_theta;
            into_numpy(py, g.layer2(), &[n, n])
        })
    }

    /// CA3 place activity, shape (N, N) = (θy, θx).
    fn place_activity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        with_engine!(&self.engine, sm, T, {
            let n = sm.params().place.n_theta;
            into_numpy(py, sm.place.activity().to_vec(), &[n, n])
        })
    }

    /// The Gaussian grid input to the place network, shape (N, N).
    fn place_input<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        with_engine!(&self.engine, sm, T, {
            let n = sm.params().place.n_theta;
            into_numpy(py, sm.place.input().to_vec(), &[n, n])
        })
    }

    /// The non-array part of the state (pinning loops, bump tracking, time) as JSON.
    fn aux_state_json(&self) -> PyResult<String> {
        let aux = with_engine!(&self.engine, sm, T, sm.aux_state());
        params_to_json(&aux)
    }

    /// Restore a full network state (activity arrays as returned by the getters, plus `aux_state_json`),
    /// e.g. to resume a run. Everything is validated before anything is changed.
    fn set_state(
        &mut self,
        hd: PyReadonlyArrayDyn<'_, f64>,
        grids: Vec<PyReadonlyArrayDyn<'_, f64>>,
        place: PyReadonlyArrayDyn<'_, f64>,
        aux_json: &str,
    ) -> PyResult<()> {
        let aux: hippo_attractor::AuxState = serde_json::from_str(aux_json)
            .map_err(|e| HippoNavError::new_err(format!("invalid saved network state: {e}")))?;
        let (hp, gp, pp) = with_engine!(&self.engine, sm, T, {
            (
                sm.params().hd.clone(),
                sm.params().grid.clone(),
                sm.params().place.clone(),
            )
        });
        // Every array is checked before anything changes, so a bad state never half-loads.
        let hd = flat_activity("hd activity", &hd, &[hp.n_nu, hp.n_theta])?;
        if grids.len() != N_MODULES {
            return Err(HippoNavError::new_err(format!(
                "grid activities: expected one array per module ({N_MODULES}), got {}",
                grids.len()
            )));
        }
        let mut g = Vec::with_capacity(N_MODULES);
        for (a, p) in grids.iter().zip(&gp) {
            g.push(flat_activity(
                "grid activity",
                a,
                &[p.n_nu, p.n_nu, p.n_theta, p.n_theta],
            )?);
        }
        let place = flat_activity("place activity", &place, &[pp.n_theta, pp.n_theta])?;
        with_engine!(&mut self.engine, sm, T, {
            sm.hd.set_activity(&to_vec::<T>(hd)).map_err(to_py_err)?;
            for (module, a) in sm.grids.iter_mut().zip(g) {
                module.set_activity(&to_vec::<T>(a)).map_err(to_py_err)?;
            }
            sm.place
                .set_activity(&to_vec::<T>(place))
                .map_err(to_py_err)?;
            sm.set_aux_state(&aux).map_err(to_py_err)
        })
    }
}

/// A module index from Python: a negative one is an error naming the argument, not an overflow.
fn module_index(index: i64) -> PyResult<usize> {
    usize::try_from(index).map_err(|_| module_index_error(index))
}

fn module_index_error(index: i64) -> PyErr {
    HippoNavError::new_err(format!(
        "grid module index {index} out of range: there are {N_MODULES} (0 = coarsest)"
    ))
}

/// Bumps of an (N, N) torus pattern: list of (mean_rad (x, y), std_rad (x, y), mass), strongest first.
#[pyfunction]
#[pyo3(signature = (pattern, threshold_frac=0.3))]
fn find_bumps(
    pattern: PyReadonlyArrayDyn<'_, f64>,
    threshold_frac: f64,
) -> PyResult<Vec<BumpTuple>> {
    let shape = pattern.shape().to_vec();
    if shape.len() != 2 || shape[0] != shape[1] || shape[0] < 2 {
        return Err(HippoNavError::new_err(format!(
            "pattern must be a square (N, N) array, got shape {shape:?}"
        )));
    }
    if !(0.0..=1.0).contains(&threshold_frac) {
        return Err(HippoNavError::new_err("threshold_frac must lie in [0, 1]"));
    }
    let n = shape[0];
    let v = flat_f64("pattern", &pattern, &[n, n])?;
    Ok(decode_bumps(&v, n, threshold_frac)
        .into_iter()
        .map(|b| {
            (
                (b.mean_rad[0], b.mean_rad[1]),
                (b.std_rad[0], b.std_rad[1]),
                b.mass,
            )
        })
        .collect())
}

/// Bayesian fusion of one or more modules' bumps, coarsest module first (docs/spec.md §4).
/// `modules`: per module a list of (mean_rad, std_rad) pairs (an empty list = lesioned).
/// Returns (mean_rad, std_rad, chosen bumps).
#[pyfunction]
#[pyo3(signature = (modules, prior_rad=None))]
#[allow(clippy::type_complexity)]
fn fuse_modules(
    modules: Vec<Vec<((f64, f64), (f64, f64))>>,
    prior_rad: Option<(f64, f64)>,
) -> PyResult<((f64, f64), (f64, f64), Vec<((f64, f64), (f64, f64))>)> {
    let bumps: Vec<Vec<Bump2>> = modules
        .iter()
        .map(|m| {
            m.iter()
                .map(|&(mu, s)| Bump2 {
                    mean_rad: [mu.0, mu.1],
                    std_rad: [s.0, s.1],
                    mass: 1.0,
                })
                .collect()
        })
        .collect();
    let slices: Vec<&[Bump2]> = bumps.iter().map(|b| b.as_slice()).collect();
    let (f, chosen) =
        fuse_homocentric(&slices, prior_rad.map(|p| [p.0, p.1])).map_err(to_py_err)?;
    Ok((
        (f.mean_rad[0], f.mean_rad[1]),
        (f.std_rad[0], f.std_rad[1]),
        chosen
            .iter()
            .map(|b| ((b.mean_rad[0], b.mean_rad[1]), (b.std_rad[0], b.std_rad[1])))
            .collect(),
    ))
}

/// Dense-reference and fast recurrent input of a small grid module, for cross-checks from Python.
#[pyfunction]
fn grid_recurrent_input_check<'py>(
    py: Python<'py>,
    config_json: &str,
    module: i64,
    activity: PyReadonlyArrayDyn<'_, f64>,
) -> PyResult<ArrayPair<'py>> {
    let params: SpatialMemoryParams =
        section_from_json(Some(config_json), "engine config", "engine")?;
    let p = params
        .grid
        .get(module_index(module)?)
        .ok_or_else(|| module_index_error(module))?
        .clone();
    if p.n_units() > 20_000 {
        return Err(HippoNavError::new_err(
            "the dense reference is for small modules only (at most 20 000 units)",
        ));
    }
    let m = flat_f64(
        "activity",
        &activity,
        &[p.n_nu, p.n_nu, p.n_theta, p.n_theta],
    )?;
    let g = hippo_attractor::GridModule::<f64>::new(p.clone()).map_err(to_py_err)?;
    // The engine integrates the lattice-symmetric part; compare on the projected (periodic) activity.
    let cell = g.fold(&m);
    let mut fast_cell = vec![0.0; cell.len()];
    g.recurrent_input(&cell, &mut fast_cell);
    let fast = g.tile(&fast_cell);
    let dense = hippo_attractor::reference::grid_recurrent(&p, &g.tile(&cell));
    Ok((fast.into_pyarray(py), dense.into_pyarray(py)))
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("N_MODULES", N_MODULES)?;
    m.add_class::<PySpatialMemory>()?;
    m.add_class::<PySpatialReadout>()?;
    m.add_class::<PyModuleReadout>()?;
    m.add_class::<PyBump>()?;
    m.add_function(wrap_pyfunction!(find_bumps, m)?)?;
    m.add_function(wrap_pyfunction!(fuse_modules, m)?)?;
    m.add_function(wrap_pyfunction!(grid_recurrent_input_check, m)?)?;
    Ok(())
}
