//! Bindings of `hippo_map`: the experience map, the pose graph, g2o files and both correctors.
//!
//! Parameters cross as JSON of the Rust structs (`MapParams`; the Rust defaults are the single source).
//! Poses cross as `(N, 3)` float64 arrays of `(x_m, y_m, yaw_rad)`; any numpy layout is accepted and
//! checked for shape and finiteness. The interpreter is released while a corrector runs.
use crate::errors::{to_py_err, HippoNavError};
use hippo_map::{
    optimize, parse_g2o, read_g2o, relax, write_g2o, Corrector, Edge, EdgeKind, ExperienceMap,
    FrameInput, Initialization, Link, MapParams, Pose2, PoseGraph, RelaxationParams, RobustLoss,
    SolverParams, Vertex,
};
use numpy::{
    IntoPyArray, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

fn pose_of(name: &str, p: (f64, f64, f64)) -> PyResult<Pose2> {
    let pose = Pose2::new(p.0, p.1, p.2);
    if !pose.is_finite() {
        return Err(HippoNavError::new_err(format!(
            "`{name}` must be finite, got {p:?}"
        )));
    }
    Ok(pose)
}

/// Any-layout float64 array of shape `(n, cols)` (n free) into row-major values; checks finiteness.
fn rows_f64(
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
    let v: Vec<f64> = a.as_array().iter().copied().collect();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(HippoNavError::new_err(format!(
            "`{name}` holds a NaN or infinity at flat index {i}"
        )));
    }
    Ok((shape[0], v))
}

fn poses_array<'py>(
    py: Python<'py>,
    poses: impl Iterator<Item = Pose2>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let flat: Vec<f64> = poses.flat_map(|p| p.to_array()).collect();
    let n = flat.len() / 3;
    flat.into_pyarray(py).reshape(vec![n, 3])
}

fn solver_params(
    initialization: &str,
    robust_loss: Option<&str>,
    robust_scale_chi2: f64,
    max_iterations: usize,
) -> PyResult<SolverParams> {
    let initialization = match initialization {
        "current" => Initialization::Current,
        "odometry" => Initialization::Odometry,
        "chordal" => Initialization::Chordal,
        other => {
            return Err(HippoNavError::new_err(format!(
                "initialization must be 'current', 'odometry' or 'chordal', not {other:?}"
            )))
        }
    };
    let robust_loss = match robust_loss {
        None => RobustLoss::None,
        Some("dcs") => RobustLoss::Dcs {
            phi_chi2: robust_scale_chi2,
        },
        Some("cauchy") => RobustLoss::Cauchy {
            scale_chi2: robust_scale_chi2,
        },
        Some(other) => {
            return Err(HippoNavError::new_err(format!(
                "robust_loss must be None, 'dcs' or 'cauchy', not {other:?}"
            )))
        }
    };
    Ok(SolverParams {
        initialization,
        robust_loss,
        max_iterations,
        ..SolverParams::default()
    })
}

fn report_dict<'py>(py: Python<'py>, items: &[(&str, Py<PyAny>)]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in items {
        d.set_item(*k, v)?;
    }
    Ok(d)
}

/// A planar pose graph (g2o `EdgeSE2` cost).
#[pyclass(name = "PoseGraph", module = "hippo_nav._core")]
#[derive(Clone)]
pub struct PyPoseGraph {
    graph: PoseGraph,
}

#[pymethods]
impl PyPoseGraph {
    /// Build from arrays: `poses (N, 3)`, `edges (E, 2)` vertex indices, `measurements (E, 3)` as
    /// `from_from_to`, `information (E, 3, 3)`, `is_loop (E,)` booleans. Vertex 0 is fixed.
    #[staticmethod]
    fn from_arrays(
        poses: PyReadonlyArrayDyn<'_, f64>,
        edges: PyReadonlyArrayDyn<'_, i64>,
        measurements: PyReadonlyArrayDyn<'_, f64>,
        information: PyReadonlyArrayDyn<'_, f64>,
        is_loop: PyReadonlyArrayDyn<'_, bool>,
    ) -> PyResult<Self> {
        let (n, p) = rows_f64("poses", &poses, &[3])?;
        let (m, z) = rows_f64("measurements", &measurements, &[3])?;
        let (m_info, info) = rows_f64("information", &information, &[3, 3])?;
        if edges.shape() != [m, 2] || m_info != m || is_loop.shape() != [m] {
            return Err(HippoNavError::new_err(format!(
                "edges {:?}, information {:?} and is_loop {:?} must have shapes (E, 2), (E, 3, 3), (E,) with E = {m} \
                 (the rows of measurements)",
                edges.shape(),
                information.shape(),
                is_loop.shape()
            )));
        }
        let ends: Vec<i64> = edges.as_array().iter().copied().collect();
        let loops: Vec<bool> = is_loop.as_array().iter().copied().collect();
        let mut graph = PoseGraph::new();
        for k in 0..n {
            graph
                .add_vertex(Pose2::new(p[3 * k], p[3 * k + 1], p[3 * k + 2]))
                .map_err(to_py_err)?;
        }
        for k in 0..m {
            let [a, b] = [ends[2 * k], ends[2 * k + 1]];
            if a < 0 || b < 0 {
                return Err(HippoNavError::new_err(format!(
                    "edge {k} has a negative vertex index ({a}, {b})"
                )));
            }
            let i = &info[9 * k..9 * k + 9];
            graph
                .add_edge(Edge {
                    from: a as usize,
                    to: b as usize,
                    from_to: Pose2::new(z[3 * k], z[3 * k + 1], z[3 * k + 2]),
                    information: [[i[0], i[1], i[2]], [i[3], i[4], i[5]], [i[6], i[7], i[8]]],
                    kind: if loops[k] {
                        EdgeKind::Loop
                    } else {
                        EdgeKind::Odometry
                    },
                })
                .map_err(|e| HippoNavError::new_err(format!("edge {k}: {e}")))?;
        }
        Ok(Self { graph })
    }

    /// Read a g2o file (VERTEX_SE2 / EDGE_SE2 / FIX).
    #[staticmethod]
    fn read_g2o(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let graph = py.detach(|| read_g2o(&path)).map_err(to_py_err)?;
        Ok(Self { graph })
    }

    /// Parse g2o text.
    #[staticmethod]
    fn parse_g2o(text: &str) -> PyResult<Self> {
        Ok(Self {
            graph: parse_g2o(text).map_err(to_py_err)?,
        })
    }

    fn write_g2o(&self, path: PathBuf) -> PyResult<()> {
        write_g2o(&self.graph, &path).map_err(to_py_err)
    }

    fn __len__(&self) -> usize {
        self.graph.len()
    }

    /// `(N, 3)` poses `(x_m, y_m, yaw_rad)` of `world_from_vertex`.
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_array(py, self.graph.poses.iter().copied())
    }

    /// `(E, 2)` int64 vertex indices of the edges.
    fn edges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let flat: Vec<i64> = self
            .graph
            .edges
            .iter()
            .flat_map(|e| [e.from as i64, e.to as i64])
            .collect();
        let m = self.graph.edges.len();
        flat.into_pyarray(py).reshape([m, 2])
    }

    /// `(E,)` booleans: which edges are loop closures.
    fn is_loop<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<bool>> {
        let v: Vec<bool> = self
            .graph
            .edges
            .iter()
            .map(|e| e.kind == EdgeKind::Loop)
            .collect();
        v.into_pyarray(py)
    }

    /// `χ² = Σ eᵀΩe` (g2o's convention; GTSAM reports half).
    fn chi2(&self) -> f64 {
        self.graph.chi2()
    }

    /// Levenberg–Marquardt on faer's sparse Cholesky. Returns the report as a dict.
    #[pyo3(signature = (initialization="chordal", robust_loss=None, robust_scale_chi2=1.0, max_iterations=100))]
    fn optimize<'py>(
        &mut self,
        py: Python<'py>,
        initialization: &str,
        robust_loss: Option<&str>,
        robust_scale_chi2: f64,
        max_iterations: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        let params = solver_params(
            initialization,
            robust_loss,
            robust_scale_chi2,
            max_iterations,
        )?;
        let graph = &mut self.graph;
        let r = py.detach(|| optimize(graph, &params)).map_err(to_py_err)?;
        report_dict(
            py,
            &[
                (
                    "iterations",
                    r.iterations.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "initial_chi2",
                    r.initial_chi2.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "final_chi2",
                    r.final_chi2.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "final_cost",
                    r.final_cost.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "converged",
                    pyo3::types::PyBool::new(py, r.converged)
                        .to_owned()
                        .into_any()
                        .unbind(),
                ),
                (
                    "termination",
                    format!("{:?}", r.termination)
                        .into_pyobject(py)?
                        .into_any()
                        .unbind(),
                ),
                (
                    "downweighted_loops",
                    r.downweighted_loops.into_pyobject(py)?.into_any().unbind(),
                ),
            ],
        )
    }

    /// RatSLAM-style relaxation passes. Returns the report as a dict.
    #[pyo3(signature = (passes=100, gain=0.5))]
    fn relax<'py>(
        &mut self,
        py: Python<'py>,
        passes: usize,
        gain: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let graph = &mut self.graph;
        let r = py
            .detach(|| relax(graph, &RelaxationParams { gain, passes }))
            .map_err(to_py_err)?;
        report_dict(
            py,
            &[
                (
                    "iterations",
                    r.passes.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "initial_chi2",
                    r.initial_chi2.into_pyobject(py)?.into_any().unbind(),
                ),
                (
                    "final_chi2",
                    r.final_chi2.into_pyobject(py)?.into_any().unbind(),
                ),
            ],
        )
    }

    /// Replace the poses by dead reckoning along the odometry edges.
    fn initialize_from_odometry(&mut self) -> PyResult<()> {
        self.graph.initialize_from_odometry().map_err(to_py_err)
    }
}

/// The experience map (SPEC §8), driven once per camera frame.
#[pyclass(name = "ExperienceMap", module = "hippo_nav._core")]
pub struct PyExperienceMap {
    map: ExperienceMap,
}

#[pymethods]
impl PyExperienceMap {
    /// `params_json`: JSON of `MapParams` (all fields; use the Python `MapParams`), or None for defaults.
    #[new]
    #[pyo3(signature = (params_json=None))]
    fn new(params_json: Option<&str>) -> PyResult<Self> {
        let params: MapParams = match params_json {
            None => MapParams::default(),
            Some(s) => serde_json::from_str(s)
                .map_err(|e| HippoNavError::new_err(format!("invalid map params: {e}")))?,
        };
        Ok(Self {
            map: ExperienceMap::new(params).map_err(to_py_err)?,
        })
    }

    /// The default `MapParams` as JSON (the single source of the defaults).
    #[staticmethod]
    fn default_params_json() -> PyResult<String> {
        serde_json::to_string(&MapParams::default()).map_err(to_py_err)
    }

    fn params_json(&self) -> PyResult<String> {
        serde_json::to_string(self.map.params()).map_err(to_py_err)
    }

    /// One camera frame. `odometry_step` is `previous_frame_from_frame` as `(dx_forward_m, dy_left_m,
    /// dyaw_rad)`. Returns a dict: vertex, created, loop_closure, ambiguous_candidates, relocalized,
    /// world_from_agent.
    fn on_frame<'py>(
        &mut self,
        py: Python<'py>,
        view_cell_id: u64,
        place_code_rad: (f64, f64),
        heading_code_rad: f64,
        odometry_step: (f64, f64, f64),
        elapsed_s: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let input = FrameInput {
            view_cell_id,
            place_code_rad: [place_code_rad.0, place_code_rad.1],
            heading_code_rad,
            odometry_step: pose_of("odometry_step", odometry_step)?,
            elapsed_s,
        };
        let out = self.map.on_frame(&input).map_err(to_py_err)?;
        let d = PyDict::new(py);
        d.set_item("vertex", out.vertex)?;
        d.set_item("created", out.created)?;
        d.set_item("loop_closure", out.loop_closure)?;
        d.set_item("ambiguous_candidates", out.ambiguous_candidates)?;
        d.set_item("relocalized", out.relocalized)?;
        d.set_item(
            "world_from_agent",
            out.world_from_agent.map(|p| (p.x, p.y, p.yaw)),
        )?;
        Ok(d)
    }

    /// Add a vertex directly; returns its index.
    fn add_vertex(
        &mut self,
        view_cell_id: u64,
        place_code_rad: (f64, f64),
        heading_code_rad: f64,
        world_from_vertex: (f64, f64, f64),
    ) -> PyResult<usize> {
        self.map
            .add_vertex(Vertex {
                view_cell_id,
                place_code_rad: [place_code_rad.0, place_code_rad.1],
                heading_code_rad,
                world_from_vertex: pose_of("world_from_vertex", world_from_vertex)?,
            })
            .map_err(to_py_err)
    }

    /// Add a link `from_from_to` between existing vertices; returns its index.
    #[pyo3(signature = (from_vertex, to_vertex, from_from_to, elapsed_s, is_loop=false))]
    fn add_link(
        &mut self,
        from_vertex: usize,
        to_vertex: usize,
        from_from_to: (f64, f64, f64),
        elapsed_s: f64,
        is_loop: bool,
    ) -> PyResult<usize> {
        self.map
            .add_link(Link {
                from: from_vertex,
                to: to_vertex,
                from_from_to: pose_of("from_from_to", from_from_to)?,
                elapsed_s,
                kind: if is_loop {
                    EdgeKind::Loop
                } else {
                    EdgeKind::Odometry
                },
            })
            .map_err(to_py_err)
    }

    fn __len__(&self) -> usize {
        self.map.vertices().len()
    }

    #[getter]
    fn current_vertex(&self) -> Option<usize> {
        self.map.current_vertex()
    }

    #[getter]
    fn world_from_agent(&self) -> Option<(f64, f64, f64)> {
        self.map.world_from_agent().map(|p| (p.x, p.y, p.yaw))
    }

    /// `(N, 3)` vertex poses `(x_m, y_m, yaw_rad)` in the map frame.
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_array(py, self.map.vertices().iter().map(|v| v.world_from_vertex))
    }

    /// The whole graph as numpy arrays (dict): poses (N,3), view_cell_ids (N,), place_codes_rad (N,2),
    /// heading_codes_rad (N,), links (E,2), link_transforms (E,3), link_elapsed_s (E,), link_is_loop (E,).
    fn export<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let v = self.map.vertices();
        let l = self.map.links();
        let d = PyDict::new(py);
        d.set_item("poses", self.poses(py)?)?;
        d.set_item(
            "view_cell_ids",
            v.iter()
                .map(|x| x.view_cell_id)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        let codes: Vec<f64> = v.iter().flat_map(|x| x.place_code_rad).collect();
        d.set_item(
            "place_codes_rad",
            codes.into_pyarray(py).reshape([v.len(), 2])?,
        )?;
        d.set_item(
            "heading_codes_rad",
            v.iter()
                .map(|x| x.heading_code_rad)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        let ends: Vec<i64> = l
            .iter()
            .flat_map(|x| [x.from as i64, x.to as i64])
            .collect();
        d.set_item("links", ends.into_pyarray(py).reshape([l.len(), 2])?)?;
        d.set_item(
            "link_transforms",
            poses_array(py, l.iter().map(|x| x.from_from_to))?,
        )?;
        d.set_item(
            "link_elapsed_s",
            l.iter()
                .map(|x| x.elapsed_s)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        d.set_item(
            "link_is_loop",
            l.iter()
                .map(|x| x.kind == EdgeKind::Loop)
                .collect::<Vec<_>>()
                .into_pyarray(py),
        )?;
        Ok(d)
    }

    /// The map as a `PoseGraph` (link information from the params' sigmas; vertex 0 fixed).
    fn pose_graph(&self) -> PyPoseGraph {
        PyPoseGraph {
            graph: self.map.pose_graph(),
        }
    }

    /// Correct the vertex poses. `method`: "least_squares" (LM; starts from the current poses by default)
    /// or "relaxation" (`passes` passes at `gain`). Returns iterations, initial_chi2, final_chi2, converged.
    #[pyo3(signature = (method="least_squares", passes=100, gain=0.5, initialization="current", robust_loss=None,
                        robust_scale_chi2=1.0, max_iterations=100))]
    #[allow(clippy::too_many_arguments)]
    fn correct<'py>(
        &mut self,
        py: Python<'py>,
        method: &str,
        passes: usize,
        gain: f64,
        initialization: &str,
        robust_loss: Option<&str>,
        robust_scale_chi2: f64,
        max_iterations: usize,
    ) -> PyResult<Bound<'py, PyDict>> {
        let corrector = match method {
            "least_squares" => Corrector::LeastSquares(solver_params(
                initialization,
                robust_loss,
                robust_scale_chi2,
                max_iterations,
            )?),
            "relaxation" => Corrector::Relaxation(RelaxationParams { gain, passes }),
            other => {
                return Err(HippoNavError::new_err(format!(
                    "method must be 'least_squares' or 'relaxation', not {other:?}"
                )))
            }
        };
        let map = &mut self.map;
        let r = py.detach(|| map.correct(&corrector)).map_err(to_py_err)?;
        let d = PyDict::new(py);
        d.set_item("iterations", r.iterations)?;
        d.set_item("initial_chi2", r.initial_chi2)?;
        d.set_item("final_chi2", r.final_chi2)?;
        d.set_item("converged", r.converged)?;
        Ok(d)
    }

    /// Forget the agent's place: frames only look for a vertex to resume from.
    fn start_relocalization(&mut self) {
        self.map.start_relocalization();
    }

    /// Save to a versioned, checksummed file (written atomically).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let map = &self.map;
        py.detach(|| map.save(&path)).map_err(to_py_err)
    }

    /// Load a saved map; a truncated, corrupted or foreign file raises `HippoNavError`.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let map = py
            .detach(|| ExperienceMap::load(&path))
            .map_err(to_py_err)?;
        Ok(Self { map })
    }

    /// Write the map's pose graph as g2o.
    fn write_g2o(&self, path: PathBuf) -> PyResult<()> {
        write_g2o(&self.map.pose_graph(), &path).map_err(to_py_err)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyPoseGraph>()?;
    m.add_class::<PyExperienceMap>()?;
    Ok(())
}
