//! Bindings of `hippo_map`: the experience map, the pose graph, g2o files and both correctors.
//!
//! Parameters cross as JSON of the Rust structs (`MapParams`; the Rust defaults are the single source).
//! Poses cross as `(N, 3)` float64 arrays of `(x_m, y_m, yaw_rad)`; any numpy layout is accepted and
//! checked for shape and finiteness. The interpreter is released while a corrector runs. What a frame or
//! a corrector did comes back as a frozen typed object (`MapFrameOutcome`, `SolveReport`,
//! `RelaxationReport`, `CorrectionReport`); the reports also read like dicts (`report["final_chi2"]`,
//! `as_dict()`).
//!
//! The correctors can be interrupted: while one runs detached, its stop hook ([`SignalPoll`]) takes the
//! interpreter back every 50 ms at most, between iterations, to run Python's signal handlers. When a
//! handler raises (Ctrl-C's `KeyboardInterrupt`), the corrector stops at its current state, which the
//! graph or map keeps (least squares: the last accepted iterate, no worse than the start), and the
//! exception is raised to the caller.
use crate::convert::{flat_f64, params_from_json, params_to_json, report, rows_f64, PoseTuple};
use crate::errors::{to_py_err, HippoNavError};
use hippo_map::{
    isotropic_information, optimize_with_stop, parse_g2o, read_g2o, relax_with_stop, write_g2o,
    ClosureRejection, CorrectionReport, Corrector, Edge, EdgeKind, ExperienceMap, FrameInput,
    FrameOutcome, Initialization, Link, LoopMeasurement, MapParams, Pose2, PoseGraph,
    RelaxationParams, RelaxationReport, RobustLoss, SolveReport, SolverParams, Termination, Vertex,
};
use numpy::{
    IntoPyArray, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// A measured loop closure from Python: target vertex, `agent_from_target`, information (3, 3).
type LoopArg<'py> = (usize, PoseTuple, PyReadonlyArrayDyn<'py, f64>);
/// A loop candidate for Python: vertex, predicted `agent_from_vertex`, distance (m).
type CandidateTuple = (usize, PoseTuple, f64, f64);

/// The view-cell id the map is given for a frame without one (Python's `None`): the map treats it as
/// one more id, never made by the view cells (their ids count up from 0).
const NO_VIEW_CELL: u64 = (1 << 63) - 1;

fn pose_of(name: &str, p: PoseTuple) -> PyResult<Pose2> {
    let pose = Pose2::new(p.0, p.1, p.2);
    if !pose.is_finite() {
        return Err(HippoNavError::new_err(format!(
            "`{name}` must be finite, got {p:?}"
        )));
    }
    Ok(pose)
}

fn pose_tuple(p: Pose2) -> PoseTuple {
    (p.x, p.y, p.yaw)
}

fn poses_array<'py>(
    py: Python<'py>,
    poses: impl Iterator<Item = Pose2>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let flat: Vec<f64> = poses.flat_map(|p| p.to_array()).collect();
    let n = flat.len() / 3;
    flat.into_pyarray(py).reshape(vec![n, 3])
}

/// How often a detached corrector runs Python's signal handlers at most: Ctrl-C is answered within this
/// (plus one iteration), and a corrector whose iterations take microseconds does not pay for taking the
/// interpreter back after each one.
const SIGNAL_POLL_INTERVAL: Duration = Duration::from_millis(50);

/// The stop hook of a detached corrector: runs Python's signal handlers (`PyErr_CheckSignals`, which
/// does anything only on the main thread) and keeps the exception one raised.
struct SignalPoll {
    last_poll: Instant,
    raised: Option<PyErr>,
}

impl SignalPoll {
    fn new() -> Self {
        Self {
            last_poll: Instant::now(),
            raised: None,
        }
    }

    fn should_stop(&mut self) -> bool {
        if self.raised.is_some() {
            return true;
        }
        if self.last_poll.elapsed() < SIGNAL_POLL_INTERVAL {
            return false;
        }
        self.last_poll = Instant::now();
        self.raised = Python::attach(|py| py.check_signals()).err();
        self.raised.is_some()
    }

    /// The corrector's result, unless a signal handler raised: then its exception (the corrector has
    /// already left its interrupted state in place).
    fn finish<T>(self, result: hippo_map::Result<T>) -> PyResult<T> {
        match self.raised {
            Some(err) => Err(err),
            None => result.map_err(to_py_err),
        }
    }
}

/// Solver settings that cross from Python; `None` keeps the Rust default.
struct SolverOverrides {
    relative_cost_tolerance: Option<f64>,
    initial_lambda_scale: Option<f64>,
    max_lambda_decrease: Option<f64>,
    max_factor_bytes: Option<u64>,
}

fn solver_params(
    initialization: &str,
    robust_loss: Option<&str>,
    robust_scale_chi2: f64,
    max_iterations: usize,
    overrides: SolverOverrides,
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
    let defaults = SolverParams::default();
    Ok(SolverParams {
        initialization,
        robust_loss,
        max_iterations,
        relative_cost_tolerance: overrides
            .relative_cost_tolerance
            .unwrap_or(defaults.relative_cost_tolerance),
        initial_lambda_scale: overrides
            .initial_lambda_scale
            .unwrap_or(defaults.initial_lambda_scale),
        max_lambda_decrease: overrides
            .max_lambda_decrease
            .unwrap_or(defaults.max_lambda_decrease),
        max_factor_bytes: overrides.max_factor_bytes,
        ..defaults
    })
}

fn termination_name(t: Termination) -> &'static str {
    match t {
        Termination::CostConverged => "cost_converged",
        Termination::GradientConverged => "gradient_converged",
        Termination::NothingToDo => "nothing_to_do",
        Termination::NoFurtherDecrease => "no_further_decrease",
        Termination::MaxIterations => "max_iterations",
        Termination::Interrupted => "interrupted",
    }
}

report! {
    /// What a least-squares solve did (see `hippo_map::SolveReport`).
    "SolveReport" PySolveReport from SolveReport, |r| {
        /// Accepted and rejected Levenberg–Marquardt iterations (each one factorisation).
        iterations: usize = r.iterations,
        /// `χ²` (plain, all edges) at the start, after initialisation.
        initial_chi2: f64 = r.initial_chi2,
        /// `χ²` (plain, all edges) at the end.
        final_chi2: f64 = r.final_chi2,
        /// The minimised objective at the end (equals `final_chi2` without a robust loss).
        final_cost: f64 = r.final_cost,
        /// Whether a convergence test was met.
        converged: bool = r.converged,
        /// Why the solve stopped: "cost_converged", "gradient_converged", "nothing_to_do",
        /// "no_further_decrease", "max_iterations" or "interrupted" (a stop hook; from Python the
        /// signal handler's exception is raised instead).
        termination: &'static str = termination_name(r.termination),
        /// Loop edges whose final robust weight is below ½ (treated as outliers); 0 without a robust loss.
        downweighted_loops: usize = r.downweighted_loops,
    }
}

report! {
    /// What relaxation passes did (see `hippo_map::RelaxationReport`).
    "RelaxationReport" PyRelaxationReport from RelaxationReport, |r| {
        /// Relaxation passes run.
        iterations: usize = r.passes,
        /// `χ²` before the first pass.
        initial_chi2: f64 = r.initial_chi2,
        /// `χ²` after the last pass.
        final_chi2: f64 = r.final_chi2,
    }
}

report! {
    /// What `ExperienceMap.correct` did, with either corrector (see `hippo_map::CorrectionReport`).
    "CorrectionReport" PyCorrectionReport from CorrectionReport, |r| {
        /// Relaxation passes or Levenberg–Marquardt iterations.
        iterations: usize = r.iterations,
        /// `χ²` of the map before the correction (after initialisation for least squares).
        initial_chi2: f64 = r.initial_chi2,
        /// `χ²` after the correction.
        final_chi2: f64 = r.final_chi2,
        /// Whether least squares converged (always False for relaxation, which has no test).
        converged: bool = r.converged,
    }
}

/// A (3, 3) information matrix from any numpy layout (checked for shape and finiteness here, for
/// symmetry and positive definiteness by the map).
fn information_of(a: &PyReadonlyArrayDyn<'_, f64>) -> PyResult<[[f64; 3]; 3]> {
    if a.shape() != [3, 3] {
        return Err(HippoNavError::new_err(format!(
            "`information` has shape {:?}, expected (3, 3) (inverse covariance of x, y, yaw)",
            a.shape()
        )));
    }
    let v = flat_f64("information", a, &[3, 3])?;
    Ok([[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]])
}

/// What one frame did to the experience map (see `hippo_map::FrameOutcome`).
#[pyclass(name = "MapFrameOutcome", module = "hippo_nav._core", frozen)]
pub struct PyFrameOutcome {
    inner: FrameOutcome,
}

#[pymethods]
impl PyFrameOutcome {
    /// The current vertex after the frame; None while lost.
    #[getter]
    fn vertex(&self) -> Option<usize> {
        self.inner.vertex
    }
    /// Whether the frame made a vertex.
    #[getter]
    fn created(&self) -> bool {
        self.inner.created
    }
    /// `(from, to)` of the loop link added this frame, or None.
    #[getter]
    fn loop_closure(&self) -> Option<(usize, usize)> {
        self.inner.loop_closure
    }
    /// Why this frame's candidate closure was not added: "too_recent", "outside_gate",
    /// "inconsistent", "unjoined" (inside a session not yet joined to its map), or None.
    #[getter]
    fn rejected_closure(&self) -> Option<&'static str> {
        self.inner.rejected_closure.map(|r| match r {
            ClosureRejection::TooRecent => "too_recent",
            ClosureRejection::OutsideGate => "outside_gate",
            ClosureRejection::Inconsistent => "inconsistent",
            ClosureRejection::Unjoined => "unjoined",
        })
    }
    /// Every matching vertex when more than one matched (RatSLAM mode).
    #[getter]
    fn ambiguous_candidates(&self) -> Vec<usize> {
        self.inner.ambiguous_candidates.clone()
    }
    #[getter]
    fn relocalized(&self) -> bool {
        self.inner.relocalized
    }
    /// The agent's pose `(x, y, yaw)` in the map frame; None while lost.
    #[getter]
    fn world_from_agent(&self) -> Option<PoseTuple> {
        self.inner.world_from_agent.map(pose_tuple)
    }
    /// The agent's pose relative to its vertex (the odometry since that vertex); None while lost.
    #[getter]
    fn vertex_from_agent(&self) -> Option<PoseTuple> {
        self.inner.vertex_from_agent.map(pose_tuple)
    }
    fn __eq__(&self, other: &Self) -> bool {
        self.inner == other.inner
    }
    fn __repr__(&self) -> String {
        format!("{:?}", self.inner)
    }
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
                    from_from_to: Pose2::new(z[3 * k], z[3 * k + 1], z[3 * k + 2]),
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

    /// `(E, 3)` measurements `i_from_j` `(x_m, y_m, yaw_rad)` of the edges.
    fn measurements<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_array(py, self.graph.edges.iter().map(|e| e.from_from_to))
    }

    /// `(E, 3, 3)` information matrices (order x, y, yaw) of the edges.
    fn information<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let flat: Vec<f64> = self
            .graph
            .edges
            .iter()
            .flat_map(|e| e.information.into_iter().flatten())
            .collect();
        let m = self.graph.edges.len();
        flat.into_pyarray(py).reshape(vec![m, 3, 3])
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

    /// Gauss–Newton first, Levenberg–Marquardt when a step fails, on faer's sparse Cholesky (see
    /// `hippo_map::SolverParams` for the tolerances and the damping schedule; `None` keeps a default).
    /// `max_iterations=0` only runs the initialisation. `max_factor_bytes`: the memory the factorisation
    /// may take (None: what the system has available); a graph that needs more raises `HippoNavError`
    /// saying how much. Ctrl-C (a signal handler that raises) stops the solve between iterations and
    /// raises, the graph at the last accepted iterate.
    #[pyo3(signature = (
        initialization="chordal",
        robust_loss=None,
        robust_scale_chi2=1.0,
        max_iterations=100,
        relative_cost_tolerance=None,
        initial_lambda_scale=None,
        max_lambda_decrease=None,
        max_factor_bytes=None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn optimize(
        &mut self,
        py: Python<'_>,
        initialization: &str,
        robust_loss: Option<&str>,
        robust_scale_chi2: f64,
        max_iterations: usize,
        relative_cost_tolerance: Option<f64>,
        initial_lambda_scale: Option<f64>,
        max_lambda_decrease: Option<f64>,
        max_factor_bytes: Option<u64>,
    ) -> PyResult<PySolveReport> {
        let params = solver_params(
            initialization,
            robust_loss,
            robust_scale_chi2,
            max_iterations,
            SolverOverrides {
                relative_cost_tolerance,
                initial_lambda_scale,
                max_lambda_decrease,
                max_factor_bytes,
            },
        )?;
        let graph = &mut self.graph;
        let mut poll = SignalPoll::new();
        let result = py.detach(|| optimize_with_stop(graph, &params, &mut || poll.should_stop()));
        Ok(poll.finish(result)?.into())
    }

    /// RatSLAM-style relaxation passes. Ctrl-C stops them between passes and raises, the graph
    /// relaxed by the passes done.
    #[pyo3(signature = (passes=100, gain=0.5))]
    fn relax(&mut self, py: Python<'_>, passes: usize, gain: f64) -> PyResult<PyRelaxationReport> {
        let graph = &mut self.graph;
        let params = RelaxationParams { gain, passes };
        let mut poll = SignalPoll::new();
        let result = py.detach(|| relax_with_stop(graph, &params, &mut || poll.should_stop()));
        Ok(poll.finish(result)?.into())
    }

    /// Replace the poses by dead reckoning along the odometry edges.
    fn initialize_from_odometry(&mut self) -> PyResult<()> {
        self.graph.initialize_from_odometry().map_err(to_py_err)
    }
}

/// The experience map (docs/spec.md §8), driven once per camera frame.
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
        let params: MapParams = params_from_json(params_json, "map params")?;
        Ok(Self {
            map: ExperienceMap::new(params).map_err(to_py_err)?,
        })
    }

    /// The resolved parameters as JSON.
    fn params_json(&self) -> PyResult<String> {
        params_to_json(self.map.params())
    }

    /// One camera frame. `view_cell_id`: the active view cell, None before the first informative view.
    /// `odometry_step` is `previous_frame_from_frame` as `(dx_forward_m, dy_left_m, dyaw_rad)`.
    /// `loop_closure` (geometric mode) is `(target_vertex, agent_from_target (x, y, yaw), information
    /// (3, 3))`, a closure measured against the frame that made the target vertex.
    #[pyo3(signature = (view_cell_id, place_code_rad, heading_code_rad, odometry_step, elapsed_s, loop_closure=None))]
    fn on_frame(
        &mut self,
        view_cell_id: Option<u64>,
        place_code_rad: (f64, f64),
        heading_code_rad: f64,
        odometry_step: PoseTuple,
        elapsed_s: f64,
        loop_closure: Option<LoopArg<'_>>,
    ) -> PyResult<PyFrameOutcome> {
        let loop_closure = match loop_closure {
            None => None,
            Some((target, agent_from_target, information)) => Some(LoopMeasurement {
                target,
                agent_from_target: pose_of("agent_from_target", agent_from_target)?,
                information: information_of(&information)?,
            }),
        };
        let input = FrameInput {
            view_cell_id: view_cell_id.unwrap_or(NO_VIEW_CELL),
            place_code_rad: [place_code_rad.0, place_code_rad.1],
            heading_code_rad,
            odometry_step: pose_of("odometry_step", odometry_step)?,
            elapsed_s,
            loop_closure,
        };
        let inner = self.map.on_frame(&input).map_err(to_py_err)?;
        Ok(PyFrameOutcome { inner })
    }

    /// Vertices among `vertices` that a closure at the next frame may join (far enough back along the
    /// path, inside the loop gate around where `odometry_step` takes the agent), nearest first, as
    /// `(vertex, predicted_agent_from_vertex (x, y, yaw), distance_m, path_m)`, `path_m` the shortest
    /// path through the map's links from there to the vertex (the gate grows with it).
    fn loop_candidates(
        &self,
        vertices: Vec<usize>,
        odometry_step: PoseTuple,
    ) -> PyResult<Vec<CandidateTuple>> {
        let step = pose_of("odometry_step", odometry_step)?;
        Ok(self
            .map
            .loop_candidates(&vertices, &step)
            .map_err(to_py_err)?
            .into_iter()
            .map(|c| {
                (
                    c.vertex,
                    pose_tuple(c.predicted_agent_from_vertex),
                    c.distance_m,
                    c.path_m,
                )
            })
            .collect())
    }

    /// Vertices within `radius_m` of where `odometry_step` takes the agent, nearest first.
    fn vertices_near(&self, radius_m: f64, odometry_step: PoseTuple) -> PyResult<Vec<usize>> {
        if !(radius_m.is_finite() && radius_m >= 0.0) {
            return Err(HippoNavError::new_err(format!(
                "radius_m must be finite and >= 0, got {radius_m}"
            )));
        }
        let step = pose_of("odometry_step", odometry_step)?;
        self.map.vertices_near(radius_m, &step).map_err(to_py_err)
    }

    /// The loop gate at the agent now: `(radius_m, yaw_rad)` around where the odometry puts it (grows
    /// with the distance travelled since the last accepted closure).
    fn loop_gate(&self) -> (f64, f64) {
        self.map.loop_gate()
    }

    /// Distance travelled so far along the odometry (m).
    #[getter]
    fn odometer_m(&self) -> f64 {
        self.map.odometer_m()
    }

    /// Add a vertex directly; returns its index. `odometer_m`: distance travelled when it was made.
    #[pyo3(signature = (view_cell_id, place_code_rad, heading_code_rad, world_from_vertex, odometer_m=0.0))]
    fn add_vertex(
        &mut self,
        view_cell_id: u64,
        place_code_rad: (f64, f64),
        heading_code_rad: f64,
        world_from_vertex: PoseTuple,
        odometer_m: f64,
    ) -> PyResult<usize> {
        self.map
            .add_vertex(Vertex {
                view_cell_id,
                place_code_rad: [place_code_rad.0, place_code_rad.1],
                heading_code_rad,
                world_from_vertex: pose_of("world_from_vertex", world_from_vertex)?,
                odometer_m,
            })
            .map_err(to_py_err)
    }

    /// Add a link `from_from_to` between existing vertices; returns its index. `information` (3, 3):
    /// None gives an odometry link the params' odometry noise for its length.
    #[pyo3(signature = (from_vertex, to_vertex, from_from_to, elapsed_s, is_loop=false, information=None))]
    fn add_link(
        &mut self,
        from_vertex: usize,
        to_vertex: usize,
        from_from_to: PoseTuple,
        elapsed_s: f64,
        is_loop: bool,
        information: Option<PyReadonlyArrayDyn<'_, f64>>,
    ) -> PyResult<usize> {
        let from_from_to = pose_of("from_from_to", from_from_to)?;
        let information = match information {
            Some(a) => information_of(&a)?,
            None if is_loop => isotropic_information(
                self.map.params().ratslam_loop_sigma_xy_m,
                self.map.params().ratslam_loop_sigma_yaw_rad,
            ),
            None => self.map.params().odometry_information(&from_from_to),
        };
        self.map
            .add_link(Link {
                from: from_vertex,
                to: to_vertex,
                from_from_to,
                elapsed_s,
                kind: if is_loop {
                    EdgeKind::Loop
                } else {
                    EdgeKind::Odometry
                },
                information,
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
    fn world_from_agent(&self) -> Option<PoseTuple> {
        self.map.world_from_agent().map(pose_tuple)
    }

    /// Pose `(x, y, yaw)` of one vertex in the map frame.
    fn vertex_pose(&self, vertex: usize) -> PyResult<PoseTuple> {
        let v = self.map.vertices().get(vertex).ok_or_else(|| {
            HippoNavError::new_err(format!(
                "vertex {vertex} does not exist (the map holds {})",
                self.map.vertices().len()
            ))
        })?;
        Ok(pose_tuple(v.world_from_vertex))
    }

    /// `(N, 3)` vertex poses `(x_m, y_m, yaw_rad)` in the map frame.
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_array(py, self.map.vertices().iter().map(|v| v.world_from_vertex))
    }

    /// The whole graph as numpy arrays (dict): poses (N,3), view_cell_ids (N,), place_codes_rad (N,2),
    /// heading_codes_rad (N,), vertex_odometer_m (N,), links (E,2), link_transforms (E,3),
    /// link_elapsed_s (E,), link_information (E,3,3), link_is_loop (E,).
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
        let info: Vec<f64> = l.iter().flat_map(|x| x.information.concat()).collect();
        d.set_item(
            "link_information",
            info.into_pyarray(py).reshape([l.len(), 3, 3])?,
        )?;
        d.set_item(
            "vertex_odometer_m",
            v.iter()
                .map(|x| x.odometer_m)
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

    /// The map as a `PoseGraph` (every link with its information; vertex 0 fixed).
    fn pose_graph(&self) -> PyPoseGraph {
        PyPoseGraph {
            graph: self.map.pose_graph(),
        }
    }

    /// Correct the vertex poses. `method`: "least_squares" (LM; starts from the current poses by default;
    /// `max_factor_bytes` as in `PoseGraph.optimize`) or "relaxation" (`passes` passes at `gain`).
    /// Ctrl-C stops either between iterations or passes and raises, the map at the corrector's state then.
    #[pyo3(signature = (method="least_squares", passes=100, gain=0.5, initialization="current", robust_loss=None,
                        robust_scale_chi2=1.0, max_iterations=100, max_factor_bytes=None))]
    #[allow(clippy::too_many_arguments)]
    fn correct(
        &mut self,
        py: Python<'_>,
        method: &str,
        passes: usize,
        gain: f64,
        initialization: &str,
        robust_loss: Option<&str>,
        robust_scale_chi2: f64,
        max_iterations: usize,
        max_factor_bytes: Option<u64>,
    ) -> PyResult<PyCorrectionReport> {
        let corrector = match method {
            "least_squares" => Corrector::LeastSquares(solver_params(
                initialization,
                robust_loss,
                robust_scale_chi2,
                max_iterations,
                SolverOverrides {
                    relative_cost_tolerance: None,
                    initial_lambda_scale: None,
                    max_lambda_decrease: None,
                    max_factor_bytes,
                },
            )?),
            "relaxation" => Corrector::Relaxation(RelaxationParams { gain, passes }),
            other => {
                return Err(HippoNavError::new_err(format!(
                    "method must be 'least_squares' or 'relaxation', not {other:?}"
                )))
            }
        };
        let map = &mut self.map;
        let mut poll = SignalPoll::new();
        let result = py.detach(|| map.correct_with_stop(&corrector, &mut || poll.should_stop()));
        Ok(poll.finish(result)?.into())
    }

    /// Forget the agent's place: frames only look for a vertex to resume from.
    fn start_relocalization(&mut self) {
        self.map.start_relocalization();
    }

    /// Start a new session inside this map, not knowing where: the session grows a part of its own
    /// until a closure onto an earlier vertex joins it (no loop gate applies to that closure; check it
    /// strictly). See docs/map.md, "Sessions".
    fn start_session(&mut self) {
        self.map.start_session();
    }

    /// The first vertex of a session not yet joined to the earlier vertices (None: the map is one).
    #[getter]
    fn unjoined_from(&self) -> Option<usize> {
        self.map.unjoined_from()
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

    /// The bytes `save` writes (the versioned, checksummed map format).
    fn to_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = hippo_map::to_bytes(&self.map).map_err(to_py_err)?;
        Ok(PyBytes::new(py, &bytes))
    }

    /// A map from the bytes of `to_bytes` (or a map file), checked as `load` checks a file.
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<Self> {
        let map = py
            .detach(|| hippo_map::from_bytes(data))
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
    m.add_class::<PyFrameOutcome>()?;
    m.add_class::<PySolveReport>()?;
    m.add_class::<PyRelaxationReport>()?;
    m.add_class::<PyCorrectionReport>()?;
    Ok(())
}
