//! The experience map driven once per camera frame (docs/map.md).
//!
//! Inputs per frame ([`FrameInput`]): the active view-cell id, the place code `(θx, θy)` (rad on the
//! place torus, decoded from the CA3 bump), the heading code `ψ` (rad, from the HD ring), the odometry's
//! planar step `previous_frame_from_frame` as an SE(2) transform (x forward, y left in metres, yaw
//! counter-clockwise in rad, all in the previous frame), the elapsed time (s) and, optionally, a
//! measured loop closure ([`LoopMeasurement`]).
//!
//! Codes live on circles, so distances wrap: `d_place = sqrt(wrap(Δθx)² + wrap(Δθy)²)` and
//! `d_heading = |wrap(Δψ)|`. A vertex's codes "match" the frame when both distances are within
//! [`MapParams::place_threshold_rad`] and [`MapParams::heading_threshold_rad`].
//!
//! Invariants (what makes the map trustworthy):
//! - Odometry links carry the odometry accumulated since the current vertex, nothing else, so a map
//!   without loop closures reproduces the odometry exactly.
//! - The agent never moves onto another vertex without a link that records the move: every change of
//!   the current vertex is a new vertex (odometry link) or a loop closure (loop link).
//! - A loop closure only joins vertices that lie at least [`MapParams::min_loop_separation_m`] apart
//!   along the travelled path (a vertex made a few frames ago is not a place seen again), and only
//!   where the odometry, run forward in the current map, puts the agent: within
//!   `loop_gate_m + loop_gate_per_m · d` (and the heading gate likewise), `d` being the length of the
//!   shortest path through the map's links from the agent to the vertex, i.e. the odometry that relates
//!   the two (`paths`). A closure shortens the paths to the places near it only: a place kilometres
//!   along the graph from the last closure keeps its wide gate. This evidence is independent of the view
//!   injection, which moves the neural codes onto the stored ones.
//! - After the online correction a new loop link must agree with the rest of the map (its χ² below
//!   [`MapParams::max_loop_chi2`]); otherwise it is taken back and the poses restored.
//!
//! Per frame, with the odometry accumulated since the current vertex (`current_from_agent`):
//! 1. [`ClosureMode::Geometric`] (default): a loop closure arrives measured by the caller (stereo
//!    geometry against the frame that created the target vertex). If it passes the gates, a vertex is
//!    made at the agent (odometry link) and a loop link joins it to the target, carrying the measured
//!    transform and its information. Without one, a vertex is made when the codes leave the current
//!    vertex's or the agent is [`MapParams::max_vertex_spacing_m`] away from it.
//! 2. [`ClosureMode::RatSlam`] (the paper's): the current vertex holds the same view cell and matching
//!    codes → stay. Otherwise look for other vertices with the same view cell and matching codes that
//!    pass the gates; none → new vertex; one or more → move onto it and add a loop link carrying the
//!    accumulated odometry, i.e. the claim that the agent now stands exactly on that vertex. Several
//!    candidates are the ambiguous case ([`AmbiguityPolicy`]).
//! 3. Online correction ([`OnlineCorrection`]): least squares after every new loop link (default), or
//!    RatSLAM's relaxation passes every frame once a loop exists.
//!
//! Information of links: odometry links `σ_xy = link_sigma_xy_m + odometry_sigma_xy_per_m · length`,
//! `σ_yaw = link_sigma_yaw_rad + odometry_sigma_yaw_rad_per_m · length` (odometry error grows with the
//! distance driven); geometric loop links the caller's measured information; RatSLAM loop links
//! `ratslam_loop_sigma_*` (the claim is only as good as the vertex spacing).
//!
//! A map can be told it is lost ([`ExperienceMap::start_relocalization`]): it then adds nothing until a
//! frame's codes match a vertex, where it resumes without a link (the pose between is unknown).
use crate::error::{MapError, Result};
use crate::graph::{
    check_information, check_pose, isotropic_information, Edge, EdgeKind, PoseGraph,
};
use crate::paths::path_lengths_m;
use crate::relax::{relax_with_stop, RelaxationParams};
use crate::se2::{wrap_angle, Pose2};
use crate::solve::{optimize_with_stop, Initialization, SolverParams, Termination};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// What to do when several vertices match the frame (RatSLAM closure).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum AmbiguityPolicy {
    /// Close onto the candidate whose map pose is nearest the agent's dead-reckoned pose (default:
    /// odometry is a good prior over short distances).
    NearestPose,
    /// Close onto the candidate with the closest codes.
    NearestCode,
    /// Do not close; create a new vertex instead (never adds a wrong link, may miss a true one).
    CreateVertex,
}

/// How loop closures are found and what their links claim.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClosureMode {
    /// The caller measures each closure (relative pose to the frame that made the target vertex) and
    /// hands it in with the frame; links carry that measurement and its uncertainty.
    Geometric,
    /// The paper's closure: a vertex with the same view cell and matching codes is re-entered and the
    /// link claims the agent stands exactly on it.
    RatSlam,
}

/// Which correction runs while the map is being built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum OnlineCorrection {
    /// Nothing (the final correction is the caller's).
    None,
    /// RatSLAM's continuous correction: `online_relaxation_passes` passes every frame once a loop exists.
    Relaxation,
    /// Levenberg–Marquardt from the current poses after every frame that added a loop link.
    LeastSquares,
}

/// Thresholds and correction settings. Defaults assume the default torus period of 100 m.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapParams {
    /// Place-code distance (rad on the torus, wrapped) beyond which a new vertex is due. 0.2 rad is
    /// 3.2 m at a 100 m period: a vertex every few metres, as RatSLAM places them on KITTI.
    pub place_threshold_rad: f64,
    /// Heading-code distance (rad, wrapped) beyond which a new vertex is due (0.35 rad ≈ 20°).
    pub heading_threshold_rad: f64,
    /// A new vertex is made at the latest when the agent is this far from the current one (m), so the
    /// map keeps growing where the codes stall (a lesioned or lost place bump).
    pub max_vertex_spacing_m: f64,
    /// How loop closures are found.
    pub closure: ClosureMode,
    /// What to do when several vertices match (RatSLAM mode).
    pub ambiguity: AmbiguityPolicy,
    /// A loop closure joins only vertices at least this far apart along the path travelled (m).
    pub min_loop_separation_m: f64,
    /// Loop gate: the closed-onto pose must lie within `loop_gate_m + loop_gate_per_m · d` of where the
    /// odometry puts the agent, `d` the length (m) of the shortest path through the map's links from the
    /// agent to the closed-onto vertex.
    pub loop_gate_m: f64,
    /// Growth of the loop gate per metre of that path.
    pub loop_gate_per_m: f64,
    /// Heading gate, likewise: `loop_gate_yaw_rad + loop_gate_yaw_rad_per_m · d`.
    pub loop_gate_yaw_rad: f64,
    /// Growth of the heading gate per metre (rad/m).
    pub loop_gate_yaw_rad_per_m: f64,
    /// A new loop link whose χ² after the online correction exceeds this is taken back (16.27 = 99.9 %
    /// of χ² with 3 degrees of freedom). Only applied with least-squares online correction.
    pub max_loop_chi2: f64,
    /// The correction run while the map is built.
    pub online_correction: OnlineCorrection,
    /// Relaxation passes run after every frame once a loop link exists (RatSLAM runs one per frame).
    pub online_relaxation_passes: usize,
    /// Relaxation gain for the online passes (RatSLAM: 0.5).
    pub relaxation_gain: f64,
    /// Levenberg–Marquardt iterations of the online least-squares correction. The new link's χ² is judged
    /// on where they leave the map, so they must be enough to converge on a long drift (KITTI 00's start,
    /// 330 m off after 3.7 km of a 1 %-drifting odometry, needs about 50; at 30 its true closure was refused
    /// as inconsistent); a solve that converges earlier stops there.
    pub online_max_iterations: usize,
    /// Odometry link noise: constant part (m, rad) …
    pub link_sigma_xy_m: f64,
    /// … (rad).
    pub link_sigma_yaw_rad: f64,
    /// … plus a part per metre of link length.
    pub odometry_sigma_xy_per_m: f64,
    /// … (rad/m).
    pub odometry_sigma_yaw_rad_per_m: f64,
    /// Standard deviation of a RatSLAM loop link's claim that the agent is on the vertex (m, rad).
    pub ratslam_loop_sigma_xy_m: f64,
    /// … (rad).
    pub ratslam_loop_sigma_yaw_rad: f64,
}

impl Default for MapParams {
    fn default() -> Self {
        Self {
            place_threshold_rad: 0.2,
            heading_threshold_rad: 0.35,
            max_vertex_spacing_m: 10.0,
            closure: ClosureMode::Geometric,
            ambiguity: AmbiguityPolicy::NearestPose,
            min_loop_separation_m: 50.0,
            loop_gate_m: 10.0,
            loop_gate_per_m: 0.1,
            loop_gate_yaw_rad: 0.35,
            loop_gate_yaw_rad_per_m: 0.001,
            max_loop_chi2: 16.27,
            online_correction: OnlineCorrection::LeastSquares,
            online_relaxation_passes: 1,
            relaxation_gain: 0.5,
            online_max_iterations: 100,
            link_sigma_xy_m: 0.02,
            link_sigma_yaw_rad: 0.001,
            odometry_sigma_xy_per_m: 0.02,
            odometry_sigma_yaw_rad_per_m: 0.0005,
            ratslam_loop_sigma_xy_m: 2.0,
            ratslam_loop_sigma_yaw_rad: 0.1,
        }
    }
}

impl MapParams {
    /// Check every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("place_threshold_rad", self.place_threshold_rad),
            ("heading_threshold_rad", self.heading_threshold_rad),
            ("max_vertex_spacing_m", self.max_vertex_spacing_m),
            ("loop_gate_m", self.loop_gate_m),
            ("loop_gate_yaw_rad", self.loop_gate_yaw_rad),
            ("max_loop_chi2", self.max_loop_chi2),
            ("link_sigma_xy_m", self.link_sigma_xy_m),
            ("link_sigma_yaw_rad", self.link_sigma_yaw_rad),
            ("ratslam_loop_sigma_xy_m", self.ratslam_loop_sigma_xy_m),
            (
                "ratslam_loop_sigma_yaw_rad",
                self.ratslam_loop_sigma_yaw_rad,
            ),
        ];
        for (name, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(MapError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: "must be finite and > 0".into(),
                });
            }
        }
        let non_negative = [
            ("min_loop_separation_m", self.min_loop_separation_m),
            ("loop_gate_per_m", self.loop_gate_per_m),
            ("loop_gate_yaw_rad_per_m", self.loop_gate_yaw_rad_per_m),
            ("odometry_sigma_xy_per_m", self.odometry_sigma_xy_per_m),
            (
                "odometry_sigma_yaw_rad_per_m",
                self.odometry_sigma_yaw_rad_per_m,
            ),
        ];
        for (name, value) in non_negative {
            if !(value.is_finite() && value >= 0.0) {
                return Err(MapError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: "must be finite and >= 0".into(),
                });
            }
        }
        RelaxationParams {
            gain: self.relaxation_gain,
            passes: 0,
        }
        .validate()
    }

    /// Information of an odometry link of the given transform (noise grows with its length).
    pub fn odometry_information(&self, from_from_to: &Pose2) -> [[f64; 3]; 3] {
        let length_m = from_from_to.x.hypot(from_from_to.y);
        isotropic_information(
            self.link_sigma_xy_m + self.odometry_sigma_xy_per_m * length_m,
            self.link_sigma_yaw_rad + self.odometry_sigma_yaw_rad_per_m * length_m,
        )
    }

    /// The loop gate for a vertex `path_m` along the map's links from the agent: (radius m, yaw rad).
    pub fn loop_gate(&self, path_m: f64) -> (f64, f64) {
        (
            self.loop_gate_m + self.loop_gate_per_m * path_m,
            (self.loop_gate_yaw_rad + self.loop_gate_yaw_rad_per_m * path_m)
                .min(std::f64::consts::PI),
        )
    }
}

/// One experience: what the agent saw and coded there, and where the map puts it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Vertex {
    /// The view cell active when the vertex was made.
    pub view_cell_id: u64,
    /// `(θx, θy)`, rad on the place torus.
    pub place_code_rad: [f64; 2],
    /// The HD code ψ (rad).
    pub heading_code_rad: f64,
    /// The vertex's pose in the map frame.
    pub world_from_vertex: Pose2,
    /// Distance travelled (m, along the odometry) when the vertex was made.
    #[serde(default)]
    pub odometer_m: f64,
}

/// A link `from_from_to` (SE(2), metres and rad), the time it took and its information (order x, y,
/// yaw). Odometry links are pure odometry; loop links are measured closures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Link {
    /// Start vertex.
    pub from: usize,
    /// End vertex.
    pub to: usize,
    /// `to` seen from `from`.
    pub from_from_to: Pose2,
    /// Time between the two (s).
    pub elapsed_s: f64,
    /// Odometry or loop link.
    pub kind: EdgeKind,
    /// Information (inverse covariance), order x, y, yaw.
    pub information: [[f64; 3]; 3],
}

/// A loop closure measured by the caller: the target vertex and the pose of that vertex seen from the
/// agent at this frame (`agent_from_target`), with its information (inverse covariance, x, y, yaw).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopMeasurement {
    /// The vertex closed onto.
    pub target: usize,
    /// That vertex seen from the agent.
    pub agent_from_target: Pose2,
    /// Information (inverse covariance), order x, y, yaw.
    pub information: [[f64; 3]; 3],
}

/// One camera frame's worth of input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInput {
    /// The active view cell.
    pub view_cell_id: u64,
    /// `(θx, θy)` of the place bump (rad).
    pub place_code_rad: [f64; 2],
    /// The HD code ψ (rad).
    pub heading_code_rad: f64,
    /// Odometry step `previous_frame_from_frame` (x forward, y left, yaw CCW).
    pub odometry_step: Pose2,
    /// Time since the previous frame (s).
    pub elapsed_s: f64,
    /// A measured loop closure (geometric mode); ignored in RatSLAM mode.
    pub loop_closure: Option<LoopMeasurement>,
}

/// Why a loop closure was not added.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClosureRejection {
    /// The target was made less than `min_loop_separation_m` ago along the path.
    TooRecent,
    /// The closed-onto pose lies outside the loop gate around the odometry's prediction.
    OutsideGate,
    /// After the online correction the link disagreed with the map (χ² above `max_loop_chi2`).
    Inconsistent,
    /// The closure joins two vertices of a session that is not yet joined to the map it started in
    /// ([`ExperienceMap::start_session`]): until then that part has no fixed place, so only a closure onto
    /// an earlier vertex (the join) is taken.
    Unjoined,
}

/// A loop-closure candidate for the caller to verify (see [`ExperienceMap::loop_candidates`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopCandidate {
    /// The vertex a closure may join.
    pub vertex: usize,
    /// The vertex seen from where the odometry puts the agent after this frame's step.
    pub predicted_agent_from_vertex: Pose2,
    /// Distance between the two (m).
    pub distance_m: f64,
    /// Length (m) of the shortest path through the map's links from there to the vertex: the odometry
    /// that relates the two, which the gate (and a caller's search radius) grows with.
    pub path_m: f64,
}

/// What a frame did to the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameOutcome {
    /// The current vertex after the frame; `None` while lost (relocalising) with no match yet.
    pub vertex: Option<usize>,
    /// Whether the frame made a vertex.
    pub created: bool,
    /// `(from, to)` of the loop link added this frame.
    pub loop_closure: Option<(usize, usize)>,
    /// Why this frame's candidate closure was not added.
    pub rejected_closure: Option<ClosureRejection>,
    /// Every matching vertex when more than one matched (RatSLAM mode; sorted by code distance).
    pub ambiguous_candidates: Vec<usize>,
    /// The frame re-found the map after [`ExperienceMap::start_relocalization`], or joined an unjoined
    /// session to it ([`ExperienceMap::start_session`]).
    pub relocalized: bool,
    /// The agent's pose in the map frame after the frame.
    pub world_from_agent: Option<Pose2>,
    /// The agent's pose relative to its vertex (pure odometry since that vertex).
    pub vertex_from_agent: Option<Pose2>,
}

/// Which corrector [`ExperienceMap::correct`] runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Corrector {
    /// RatSLAM-style relaxation passes.
    Relaxation(RelaxationParams),
    /// Sparse Levenberg–Marquardt.
    LeastSquares(SolverParams),
}

/// What a correction did, with either corrector.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CorrectionReport {
    /// Relaxation passes or LM iterations.
    pub iterations: usize,
    /// `χ²` before the correction (after initialisation for least squares).
    pub initial_chi2: f64,
    /// `χ²` after the correction.
    pub final_chi2: f64,
    /// Whether least squares converged (always false for relaxation).
    pub converged: bool,
    /// The stop hook ended the correction early (see [`ExperienceMap::correct_with_stop`]).
    #[serde(default)]
    pub interrupted: bool,
}

/// The experience map with its tracking state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExperienceMap {
    pub(crate) params: MapParams,
    pub(crate) vertices: Vec<Vertex>,
    pub(crate) links: Vec<Link>,
    pub(crate) current: Option<usize>,
    /// Odometry accumulated since the current vertex (`current_from_agent`).
    pub(crate) current_from_agent: Pose2,
    pub(crate) elapsed_since_current_s: f64,
    pub(crate) frames: u64,
    pub(crate) lost: bool,
    /// Distance travelled so far (m) and when the last loop closure was accepted.
    pub(crate) odometer_m: f64,
    pub(crate) odometer_at_last_closure_m: f64,
    /// The first vertex of a session not yet joined to the earlier vertices ([`Self::start_session`]).
    #[serde(default)]
    pub(crate) unjoined_from: Option<usize>,
    #[serde(skip)]
    pub(crate) by_view_cell: HashMap<u64, Vec<usize>>,
}

fn place_distance_rad(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    wrap_angle(a[0] - b[0]).hypot(wrap_angle(a[1] - b[1]))
}

fn distance_m(a: &Pose2, b: &Pose2) -> f64 {
    (a.x - b.x).hypot(a.y - b.y)
}

impl ExperienceMap {
    /// An empty map with these parameters (checked).
    pub fn new(params: MapParams) -> Result<Self> {
        params.validate()?;
        Ok(Self {
            params,
            vertices: Vec::new(),
            links: Vec::new(),
            current: None,
            current_from_agent: Pose2::IDENTITY,
            elapsed_since_current_s: 0.0,
            frames: 0,
            lost: false,
            odometer_m: 0.0,
            odometer_at_last_closure_m: 0.0,
            unjoined_from: None,
            by_view_cell: HashMap::new(),
        })
    }

    /// The map's parameters.
    pub fn params(&self) -> &MapParams {
        &self.params
    }
    /// Every vertex, in the order made.
    pub fn vertices(&self) -> &[Vertex] {
        &self.vertices
    }
    /// Every link, in the order made.
    pub fn links(&self) -> &[Link] {
        &self.links
    }
    /// The vertex the agent is at (`None` while lost).
    pub fn current_vertex(&self) -> Option<usize> {
        self.current
    }
    /// Frames processed.
    pub fn frames(&self) -> u64 {
        self.frames
    }
    /// Distance travelled along the odometry (m).
    pub fn odometer_m(&self) -> f64 {
        self.odometer_m
    }
    /// Loop links in the map.
    pub fn loop_link_count(&self) -> usize {
        self.links
            .iter()
            .filter(|l| l.kind == EdgeKind::Loop)
            .count()
    }

    /// The agent's pose in the map frame (`None` before the first frame or while lost).
    pub fn world_from_agent(&self) -> Option<Pose2> {
        let current = self.current?;
        Some(
            self.vertices[current]
                .world_from_vertex
                .compose(&self.current_from_agent),
        )
    }

    /// The agent's pose relative to its vertex (`None` before the first frame or while lost).
    pub fn vertex_from_agent(&self) -> Option<Pose2> {
        self.current.map(|_| self.current_from_agent)
    }

    pub(crate) fn rebuild_index(&mut self) {
        self.by_view_cell.clear();
        for (i, v) in self.vertices.iter().enumerate() {
            self.by_view_cell.entry(v.view_cell_id).or_default().push(i);
        }
    }

    /// Add a vertex directly (the pipeline normally goes through [`Self::on_frame`]). The first vertex
    /// added becomes the current one.
    pub fn add_vertex(&mut self, vertex: Vertex) -> Result<usize> {
        check_pose("vertex pose", &vertex.world_from_vertex)?;
        for value in [
            vertex.place_code_rad[0],
            vertex.place_code_rad[1],
            vertex.heading_code_rad,
            vertex.odometer_m,
        ] {
            if !value.is_finite() {
                return Err(MapError::NonFinite {
                    what: "vertex code or odometer",
                    value,
                });
            }
        }
        let index = self.vertices.len();
        self.vertices.push(vertex);
        self.by_view_cell
            .entry(vertex.view_cell_id)
            .or_default()
            .push(index);
        if self.current.is_none() && !self.lost {
            self.current = Some(index);
        }
        Ok(index)
    }

    /// Add a link directly between existing vertices.
    pub fn add_link(&mut self, link: Link) -> Result<usize> {
        let len = self.vertices.len();
        for vertex in [link.from, link.to] {
            if vertex >= len {
                return Err(MapError::UnknownVertex { vertex, len });
            }
        }
        if link.from == link.to {
            return Err(MapError::SelfLink { vertex: link.from });
        }
        check_pose("link transform", &link.from_from_to)?;
        check_information(self.links.len(), &link.information)?;
        if !(link.elapsed_s.is_finite() && link.elapsed_s >= 0.0) {
            return Err(MapError::BadParameter {
                name: "link elapsed_s",
                value: link.elapsed_s.to_string(),
                why: "must be finite and >= 0".into(),
            });
        }
        self.links.push(link);
        Ok(self.links.len() - 1)
    }

    /// Forget where the agent is: the next frames only look for a vertex to resume from.
    pub fn start_relocalization(&mut self) {
        self.lost = true;
        self.current = None;
        self.current_from_agent = Pose2::IDENTITY;
        self.elapsed_since_current_s = 0.0;
    }

    /// Start a new session inside this map: a later run that does not know where in the map it starts.
    /// The next frame founds a vertex of its own at the map's origin, joined to nothing; later frames grow
    /// that part as usual (odometry links; closures inside it wait, [`ClosureRejection::Unjoined`]). The
    /// first accepted closure onto an earlier vertex joins it ([`FrameOutcome::relocalized`]): the
    /// session's part is moved rigidly so that the closure holds, the closure becomes a loop link, and the
    /// map is one graph again, corrected as usual. The loop gate does not apply to that closure (the
    /// odometry says nothing about where the session started), so the caller must check it strictly.
    /// The break between sessions counts as `min_loop_separation_m` of travel. On an empty map this is a
    /// plain start.
    pub fn start_session(&mut self) {
        self.lost = false;
        self.current = None;
        self.current_from_agent = Pose2::IDENTITY;
        self.elapsed_since_current_s = 0.0;
        if self.vertices.is_empty() {
            return;
        }
        self.unjoined_from = Some(self.vertices.len());
        self.odometer_m += self.params.min_loop_separation_m;
        self.odometer_at_last_closure_m = self.odometer_m;
    }

    /// The first vertex of a session not yet joined to the earlier vertices (None: the map is one).
    pub fn unjoined_from(&self) -> Option<usize> {
        self.unjoined_from
    }

    /// Vertices (of `vertices`) that a closure at the next frame may join: far enough back along the
    /// path and inside the loop gate around where the odometry puts the agent after `odometry_step`;
    /// sorted by distance. The caller measures the closure against these and hands it to
    /// [`Self::on_frame`]. Empty before the first frame, while lost, and while a session is unjoined
    /// (only the join may close a loop then, and no gate applies to it).
    pub fn loop_candidates(
        &self,
        vertices: &[usize],
        odometry_step: &Pose2,
    ) -> Result<Vec<LoopCandidate>> {
        check_pose("odometry step", odometry_step)?;
        let Some(agent) = self.world_from_agent() else {
            return Ok(Vec::new());
        };
        if self.unjoined_from.is_some() {
            return Ok(Vec::new());
        }
        let predicted = agent.compose(odometry_step);
        let odometer = self.odometer_m + odometry_step.x.hypot(odometry_step.y);
        let path_m = self.paths_from_agent_m(&self.current_from_agent.compose(odometry_step));
        let mut out = Vec::new();
        for &v in vertices {
            let vertex = self.vertices.get(v).ok_or(MapError::UnknownVertex {
                vertex: v,
                len: self.vertices.len(),
            })?;
            // No path: no odometry relates the two, so nothing says where the vertex is seen from here.
            if odometer - vertex.odometer_m < self.params.min_loop_separation_m
                || path_m[v].is_infinite()
            {
                continue;
            }
            // The vertex may lie up to one vertex spacing from the place the closure puts the agent.
            let radius_m = self.params.loop_gate(path_m[v]).0 + self.params.max_vertex_spacing_m;
            let distance = distance_m(&predicted, &vertex.world_from_vertex);
            if distance <= radius_m && !out.iter().any(|c: &LoopCandidate| c.vertex == v) {
                out.push(LoopCandidate {
                    vertex: v,
                    predicted_agent_from_vertex: predicted.between(&vertex.world_from_vertex),
                    distance_m: distance,
                    path_m: path_m[v],
                });
            }
        }
        out.sort_by(|a, b| {
            a.distance_m
                .total_cmp(&b.distance_m)
                .then(a.vertex.cmp(&b.vertex))
        });
        Ok(out)
    }

    /// Vertices within `radius_m` of where the odometry puts the agent after `odometry_step`, nearest
    /// first (e.g. to choose which views to compare a frame with).
    pub fn vertices_near(&self, radius_m: f64, odometry_step: &Pose2) -> Result<Vec<usize>> {
        check_pose("odometry step", odometry_step)?;
        let Some(agent) = self.world_from_agent() else {
            return Ok(Vec::new());
        };
        if self.unjoined_from.is_some() {
            return Ok(Vec::new());
        }
        let predicted = agent.compose(odometry_step);
        let mut near: Vec<(f64, usize)> = self
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| (distance_m(&predicted, &v.world_from_vertex), i))
            .filter(|&(d, _)| d <= radius_m)
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        Ok(near.into_iter().map(|(_, i)| i).collect())
    }

    /// The loop gate for a vertex as far along the links as the travel since the last closure: (radius m,
    /// yaw rad) around the odometry's prediction. What a search that does not ask the graph may assume;
    /// a vertex farther along the graph has a wider gate ([`Self::loop_candidates`]).
    pub fn loop_gate(&self) -> (f64, f64) {
        self.params
            .loop_gate(self.odometer_m - self.odometer_at_last_closure_m)
    }

    /// Length (m) of the shortest path through the links from the agent, `current_from_agent` off the
    /// current vertex, to every vertex (`f64::INFINITY` where none leads; all of them while lost).
    fn paths_from_agent_m(&self, current_from_agent: &Pose2) -> Vec<f64> {
        let Some(current) = self.current else {
            return vec![f64::INFINITY; self.vertices.len()];
        };
        let links = self
            .links
            .iter()
            .map(|l| (l.from, l.to, l.from_from_to.x.hypot(l.from_from_to.y)));
        let mut length_m = path_lengths_m(self.vertices.len(), links, current);
        let offset_m = current_from_agent.x.hypot(current_from_agent.y);
        length_m.iter_mut().for_each(|l| *l += offset_m);
        length_m
    }

    /// Vertices matching the frame's view cell and codes, sorted by normalised code distance.
    fn code_candidates(&self, input: &FrameInput, exclude: Option<usize>) -> Vec<usize> {
        let Some(list) = self.by_view_cell.get(&input.view_cell_id) else {
            return Vec::new();
        };
        let mut scored: Vec<(f64, usize)> = list
            .iter()
            .filter(|&&v| Some(v) != exclude)
            .filter_map(|&v| Some((self.code_score(&self.vertices[v], input)?, v)))
            .collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        scored.into_iter().map(|(_, v)| v).collect()
    }

    /// Normalised squared code distance, or `None` beyond either threshold.
    fn code_score(&self, vertex: &Vertex, input: &FrameInput) -> Option<f64> {
        let place = place_distance_rad(&vertex.place_code_rad, &input.place_code_rad)
            / self.params.place_threshold_rad;
        let heading = wrap_angle(vertex.heading_code_rad - input.heading_code_rad).abs()
            / self.params.heading_threshold_rad;
        (place <= 1.0 && heading <= 1.0).then_some(place * place + heading * heading)
    }

    fn validate_input(&self, input: &FrameInput) -> Result<()> {
        check_pose("odometry step", &input.odometry_step)?;
        for value in [
            input.place_code_rad[0],
            input.place_code_rad[1],
            input.heading_code_rad,
        ] {
            if !value.is_finite() {
                return Err(MapError::NonFinite {
                    what: "place or heading code",
                    value,
                });
            }
        }
        if !(input.elapsed_s.is_finite() && input.elapsed_s >= 0.0) {
            return Err(MapError::BadParameter {
                name: "elapsed_s",
                value: input.elapsed_s.to_string(),
                why: "must be finite and >= 0".into(),
            });
        }
        if let Some(closure) = &input.loop_closure {
            if closure.target >= self.vertices.len() {
                return Err(MapError::UnknownVertex {
                    vertex: closure.target,
                    len: self.vertices.len(),
                });
            }
            check_pose("loop measurement", &closure.agent_from_target)?;
            check_information(self.links.len(), &closure.information)?;
        }
        // Steps each within bounds can add up beyond them: check where this one would put the agent before
        // anything changes, or the frame fails half-applied when its vertex is made and every later one
        // fails with it.
        if let (false, Some(current)) = (self.lost, self.current) {
            let vertex_from_agent = self.current_from_agent.compose(&input.odometry_step);
            check_pose("the odometry since the current vertex", &vertex_from_agent)?;
            check_pose(
                "the agent's position",
                &self.vertices[current]
                    .world_from_vertex
                    .compose(&vertex_from_agent),
            )?;
        }
        Ok(())
    }

    /// Advance the map by one camera frame (see the module docs for the rule).
    pub fn on_frame(&mut self, input: &FrameInput) -> Result<FrameOutcome> {
        self.validate_input(input)?;
        self.frames += 1;
        let mut outcome = FrameOutcome {
            vertex: None,
            created: false,
            loop_closure: None,
            rejected_closure: None,
            ambiguous_candidates: Vec::new(),
            relocalized: false,
            world_from_agent: None,
            vertex_from_agent: None,
        };
        let step = input.odometry_step;
        self.odometer_m += step.x.hypot(step.y);
        if self.lost {
            self.relocalize(input, &mut outcome);
        } else if let Some(current) = self.current {
            self.current_from_agent = self.current_from_agent.compose(&step);
            self.elapsed_since_current_s += input.elapsed_s;
            let looped = match self.params.closure {
                ClosureMode::Geometric => self.geometric_frame(current, input, &mut outcome)?,
                ClosureMode::RatSlam => self.ratslam_frame(current, input, &mut outcome)?,
            };
            if !looped && self.params.online_correction == OnlineCorrection::Relaxation {
                self.relax_online()?;
            }
        } else {
            // The first frame founds the map at the origin.
            let index = self.new_vertex(input, Pose2::IDENTITY)?;
            self.current = Some(index);
            outcome.created = true;
        }
        outcome.vertex = self.current;
        outcome.world_from_agent = self.world_from_agent();
        outcome.vertex_from_agent = self.vertex_from_agent();
        Ok(outcome)
    }

    /// Lost: resume on the first vertex whose view cell and codes match, without a link.
    fn relocalize(&mut self, input: &FrameInput, outcome: &mut FrameOutcome) {
        let candidates = self.code_candidates(input, None);
        if let Some(&target) = candidates.first() {
            self.lost = false;
            self.current = Some(target);
            self.current_from_agent = Pose2::IDENTITY;
            self.elapsed_since_current_s = 0.0;
            outcome.relocalized = true;
            if candidates.len() > 1 {
                outcome.ambiguous_candidates = candidates;
            }
        }
    }

    /// A vertex at the agent's pose with this frame's codes (not linked, not made current).
    fn new_vertex(&mut self, input: &FrameInput, world_from_vertex: Pose2) -> Result<usize> {
        self.add_vertex(Vertex {
            view_cell_id: input.view_cell_id,
            place_code_rad: input.place_code_rad,
            heading_code_rad: input.heading_code_rad,
            world_from_vertex,
            odometer_m: self.odometer_m,
        })
    }

    /// Make a vertex at the agent, joined to the current one by the accumulated odometry; it becomes
    /// the current vertex.
    fn advance_to_new_vertex(&mut self, current: usize, input: &FrameInput) -> Result<usize> {
        let world_from_agent = self.vertices[current]
            .world_from_vertex
            .compose(&self.current_from_agent);
        let index = self.new_vertex(input, world_from_agent)?;
        self.add_link(Link {
            from: current,
            to: index,
            from_from_to: self.current_from_agent,
            elapsed_s: self.elapsed_since_current_s,
            kind: EdgeKind::Odometry,
            information: self.params.odometry_information(&self.current_from_agent),
        })?;
        self.current = Some(index);
        self.current_from_agent = Pose2::IDENTITY;
        self.elapsed_since_current_s = 0.0;
        Ok(index)
    }

    /// Is the closure onto `target`, putting the agent at `world_from_agent_claimed`, allowed? `path_m`:
    /// the agent's paths through the links ([`Self::paths_from_agent_m`]).
    fn gate(
        &self,
        predicted: &Pose2,
        target: usize,
        world_from_agent_claimed: &Pose2,
        path_m: &[f64],
    ) -> Option<ClosureRejection> {
        let vertex = &self.vertices[target];
        if self.odometer_m - vertex.odometer_m < self.params.min_loop_separation_m {
            return Some(ClosureRejection::TooRecent);
        }
        let path_m = path_m[target];
        if path_m.is_infinite() {
            return Some(ClosureRejection::OutsideGate);
        }
        let (radius_m, yaw_rad) = self.params.loop_gate(path_m);
        let off_m = distance_m(predicted, world_from_agent_claimed);
        let off_yaw = wrap_angle(predicted.yaw - world_from_agent_claimed.yaw).abs();
        (off_m > radius_m || off_yaw > yaw_rad).then_some(ClosureRejection::OutsideGate)
    }

    /// Geometric mode: a measured closure becomes a vertex plus a loop link; otherwise the creation rule.
    /// Returns whether a loop link was added.
    fn geometric_frame(
        &mut self,
        current: usize,
        input: &FrameInput,
        outcome: &mut FrameOutcome,
    ) -> Result<bool> {
        let agent = self.vertices[current]
            .world_from_vertex
            .compose(&self.current_from_agent);
        if let (Some(closure), Some(first)) = (input.loop_closure, self.unjoined_from) {
            if closure.target < first {
                return self.join(current, first, closure, input, outcome);
            }
            outcome.rejected_closure = Some(ClosureRejection::Unjoined);
        } else if let Some(closure) = input.loop_closure {
            let world_from_target = self.vertices[closure.target].world_from_vertex;
            let claimed = world_from_target.compose(&closure.agent_from_target.inverse());
            let path_m = self.paths_from_agent_m(&self.current_from_agent);
            match self.gate(&agent, closure.target, &claimed, &path_m) {
                Some(reason) => outcome.rejected_closure = Some(reason),
                None => return self.close_at_agent(current, &closure, input, outcome),
            }
        }
        let here = &self.vertices[current];
        let codes_stay = self.code_score(here, input).is_some();
        let spacing_m = self.current_from_agent.x.hypot(self.current_from_agent.y);
        if !codes_stay || spacing_m > self.params.max_vertex_spacing_m {
            self.advance_to_new_vertex(current, input)?;
            outcome.created = true;
        }
        Ok(false)
    }

    /// A measured closure taken: a vertex at the agent, joined to the target by a loop link carrying the
    /// measurement, then the online correction (see [`Self::add_loop_link`]). Returns whether it was added.
    fn close_at_agent(
        &mut self,
        current: usize,
        closure: &LoopMeasurement,
        input: &FrameInput,
        outcome: &mut FrameOutcome,
    ) -> Result<bool> {
        let here = self.advance_to_new_vertex(current, input)?;
        outcome.created = true;
        let link = Link {
            from: here,
            to: closure.target,
            from_from_to: closure.agent_from_target,
            elapsed_s: 0.0,
            kind: EdgeKind::Loop,
            information: closure.information,
        };
        self.add_loop_link(link, outcome)
    }

    /// Move vertices `first..` rigidly: `new_world_from_vertex = moved ∘ world_from_vertex`.
    fn move_vertices_from(&mut self, first: usize, moved: &Pose2) {
        for v in &mut self.vertices[first..] {
            v.world_from_vertex = moved.compose(&v.world_from_vertex);
        }
    }

    /// The join of an unjoined session ([`Self::start_session`]) by a closure onto an earlier vertex: the
    /// session's vertices move rigidly to where the closure puts the agent, then the closure is added as
    /// any loop link (vertex at the agent, link, online correction). Returns whether it was added; if not,
    /// the session stays unjoined where it was.
    fn join(
        &mut self,
        current: usize,
        first: usize,
        closure: LoopMeasurement,
        input: &FrameInput,
        outcome: &mut FrameOutcome,
    ) -> Result<bool> {
        let agent = self.vertices[current]
            .world_from_vertex
            .compose(&self.current_from_agent);
        let claimed = self.vertices[closure.target]
            .world_from_vertex
            .compose(&closure.agent_from_target.inverse());
        let map_from_session = claimed.compose(&agent.inverse());
        self.move_vertices_from(first, &map_from_session);
        self.unjoined_from = None;
        if self.close_at_agent(current, &closure, input, outcome)? {
            outcome.relocalized = true;
            return Ok(true);
        }
        self.move_vertices_from(first, &map_from_session.inverse());
        self.unjoined_from = Some(first);
        Ok(false)
    }

    /// RatSLAM mode: stay, re-enter a matching vertex (loop link claiming the agent is on it), or make
    /// a new vertex. Returns whether a loop link was added.
    fn ratslam_frame(
        &mut self,
        current: usize,
        input: &FrameInput,
        outcome: &mut FrameOutcome,
    ) -> Result<bool> {
        let here = &self.vertices[current];
        let agent = here.world_from_vertex.compose(&self.current_from_agent);
        let spacing_m = self.current_from_agent.x.hypot(self.current_from_agent.y);
        let stays = here.view_cell_id == input.view_cell_id
            && self.code_score(here, input).is_some()
            && spacing_m <= self.params.max_vertex_spacing_m;
        if stays {
            return Ok(false);
        }
        let mut candidates = self.code_candidates(input, Some(current));
        if candidates.len() > 1 {
            outcome.ambiguous_candidates = candidates.clone();
        }
        let path_m = if candidates.is_empty() {
            Vec::new()
        } else {
            self.paths_from_agent_m(&self.current_from_agent)
        };
        candidates.retain(|&v| {
            let claimed = self.vertices[v].world_from_vertex;
            match self.gate(&agent, v, &claimed, &path_m) {
                Some(reason) => {
                    outcome.rejected_closure = Some(reason);
                    false
                }
                None => true,
            }
        });
        let target = match (candidates.len(), self.params.ambiguity) {
            (0, _) => None,
            (1, _) | (_, AmbiguityPolicy::NearestCode) => Some(candidates[0]),
            (_, AmbiguityPolicy::CreateVertex) => None,
            (_, AmbiguityPolicy::NearestPose) => candidates.iter().copied().min_by(|&a, &b| {
                let da = distance_m(&self.vertices[a].world_from_vertex, &agent);
                let db = distance_m(&self.vertices[b].world_from_vertex, &agent);
                da.total_cmp(&db).then(a.cmp(&b))
            }),
        };
        let Some(target) = target else {
            self.advance_to_new_vertex(current, input)?;
            outcome.created = true;
            return Ok(false);
        };
        // The claim "the agent stands on `target`": the accumulated odometry from the current vertex.
        let link = Link {
            from: current,
            to: target,
            from_from_to: self.current_from_agent,
            elapsed_s: self.elapsed_since_current_s,
            kind: EdgeKind::Loop,
            information: isotropic_information(
                self.params.ratslam_loop_sigma_xy_m,
                self.params.ratslam_loop_sigma_yaw_rad,
            ),
        };
        if self.add_loop_link(link, outcome)? {
            self.current = Some(target);
            self.current_from_agent = Pose2::IDENTITY;
            self.elapsed_since_current_s = 0.0;
            Ok(true)
        } else {
            self.advance_to_new_vertex(current, input)?;
            outcome.created = true;
            Ok(false)
        }
    }

    /// Add a loop link and run the online correction; a link the corrected map disagrees with is taken
    /// back and the poses restored. Returns whether the link stayed.
    fn add_loop_link(&mut self, link: Link, outcome: &mut FrameOutcome) -> Result<bool> {
        let saved: Vec<Pose2> = self.vertices.iter().map(|v| v.world_from_vertex).collect();
        let index = self.add_link(link)?;
        match self.params.online_correction {
            OnlineCorrection::LeastSquares => {
                self.correct(&Corrector::LeastSquares(SolverParams {
                    initialization: Initialization::Current,
                    max_iterations: self.params.online_max_iterations,
                    ..SolverParams::default()
                }))?;
                let l = &self.links[index];
                let edge = Edge {
                    from: l.from,
                    to: l.to,
                    from_from_to: l.from_from_to,
                    information: l.information,
                    kind: l.kind,
                };
                let chi2 = edge.chi2(
                    &self.vertices[l.from].world_from_vertex,
                    &self.vertices[l.to].world_from_vertex,
                );
                // NaN (a failed solve) counts as inconsistent too.
                if chi2.is_nan() || chi2 > self.params.max_loop_chi2 {
                    self.links.pop();
                    for (v, pose) in self.vertices.iter_mut().zip(saved) {
                        v.world_from_vertex = pose;
                    }
                    outcome.rejected_closure = Some(ClosureRejection::Inconsistent);
                    return Ok(false);
                }
            }
            OnlineCorrection::Relaxation => self.relax_online()?,
            OnlineCorrection::None => {}
        }
        self.odometer_at_last_closure_m = self.odometer_m;
        outcome.loop_closure = Some((link.from, link.to));
        Ok(true)
    }

    fn relax_online(&mut self) -> Result<()> {
        if self.params.online_relaxation_passes > 0 && self.loop_link_count() > 0 {
            self.correct(&Corrector::Relaxation(RelaxationParams {
                gain: self.params.relaxation_gain,
                passes: self.params.online_relaxation_passes,
            }))?;
        }
        Ok(())
    }

    /// The map as a pose graph (vertex 0 fixed; every link with its own information).
    pub fn pose_graph(&self) -> PoseGraph {
        PoseGraph {
            ids: (0..self.vertices.len() as u64).collect(),
            poses: self.vertices.iter().map(|v| v.world_from_vertex).collect(),
            edges: self
                .links
                .iter()
                .map(|l| Edge {
                    from: l.from,
                    to: l.to,
                    from_from_to: l.from_from_to,
                    information: l.information,
                    kind: l.kind,
                })
                .collect(),
            fixed: 0,
        }
    }

    /// Correct the vertex poses with either corrector. The least-squares one starts from the current
    /// poses unless its params say otherwise. Poses change only if the corrector succeeds.
    pub fn correct(&mut self, corrector: &Corrector) -> Result<CorrectionReport> {
        self.correct_with_stop(corrector, &mut || false)
    }

    /// [`Self::correct`] that asks `should_stop` before every iteration or pass (see
    /// [`crate::optimize_with_stop`], [`crate::relax_with_stop`]). When it says so the vertices take the
    /// corrector's state at that point (least squares: the last accepted iterate, no worse than the start)
    /// and the report says `interrupted`.
    pub fn correct_with_stop(
        &mut self,
        corrector: &Corrector,
        should_stop: &mut dyn FnMut() -> bool,
    ) -> Result<CorrectionReport> {
        if self.vertices.is_empty() {
            return Err(MapError::EmptyGraph);
        }
        if let Some(first) = self.unjoined_from {
            return Err(MapError::Unjoined { first });
        }
        let mut graph = self.pose_graph();
        let report = match corrector {
            Corrector::Relaxation(params) => {
                let r = relax_with_stop(&mut graph, params, should_stop)?;
                CorrectionReport {
                    iterations: r.passes,
                    initial_chi2: r.initial_chi2,
                    final_chi2: r.final_chi2,
                    converged: false,
                    interrupted: r.interrupted,
                }
            }
            Corrector::LeastSquares(params) => {
                let r = optimize_with_stop(&mut graph, params, should_stop)?;
                CorrectionReport {
                    iterations: r.iterations,
                    initial_chi2: r.initial_chi2,
                    final_chi2: r.final_chi2,
                    converged: r.converged,
                    interrupted: r.termination == Termination::Interrupted,
                }
            }
        };
        for (v, pose) in self.vertices.iter_mut().zip(&graph.poses) {
            v.world_from_vertex = *pose;
        }
        Ok(report)
    }

    /// Least-squares defaults for a live map: start from the current poses (already good).
    pub fn default_least_squares() -> SolverParams {
        SolverParams {
            initialization: Initialization::Current,
            ..SolverParams::default()
        }
    }
}
