//! The experience map driven once per camera frame (SPEC §8).
//!
//! Inputs per frame ([`FrameInput`]): the active view-cell id, the place code `(θx, θy)` (rad on the
//! place torus, decoded from the CA3 bump), the heading code `ψ` (rad, from the HD ring), the VO's planar
//! step `previous_frame_from_frame` as an SE(2) transform (x forward, y left in metres, yaw
//! counter-clockwise in rad, all in the previous frame) and the elapsed time (s).
//!
//! Codes live on circles, so distances wrap: `d_place = sqrt(wrap(Δθx)² + wrap(Δθy)²)` and
//! `d_heading = |wrap(Δψ)|`. A vertex "matches" the frame when it holds the same view cell and both
//! distances are within [`MapParams::place_threshold_rad`] and [`MapParams::heading_threshold_rad`].
//!
//! Per frame, with the odometry accumulated since the current vertex (`current_from_agent`):
//! 1. The current vertex matches → stay on it.
//! 2. Otherwise look for matching vertices (same view cell, close codes). None → create a vertex at
//!    `world_from_current ⊕ current_from_agent`, linked to the current one by that transform (an
//!    odometry link). One or more → re-entry: move to one of them and, unless the two vertices are
//!    already linked, add a loop link carrying the accumulated transform, i.e. the claim that the agent
//!    now stands on the matched vertex. Several candidates are the ambiguous case: the place code only
//!    repeats every torus period and a view cell may be shared, so [`AmbiguityPolicy`] decides, and the
//!    outcome lists every candidate so the caller can see it happened.
//! 3. Once the map holds a loop link, `online_relaxation_passes` relaxation passes run each frame
//!    (RatSLAM's continuous correction); [`ExperienceMap::correct`] runs either corrector on demand.
//!
//! A map can be told it is lost ([`ExperienceMap::start_relocalization`]): it then adds nothing until a
//! frame matches a vertex, where it resumes without a link (the pose between is unknown).
use crate::error::{MapError, Result};
use crate::graph::{check_pose, isotropic_information, Edge, EdgeKind, PoseGraph};
use crate::relax::{relax, RelaxationParams};
use crate::se2::{wrap_angle, Pose2};
use crate::solve::{optimize, Initialization, SolverParams};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;

/// What to do when several vertices match the frame.
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

/// Thresholds and correction settings. Defaults assume the SPEC's torus period of about 100 m.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapParams {
    /// Place-code distance (rad on the torus, wrapped) beyond which a new vertex is due. 0.2 rad is
    /// 3.2 m at a 100 m period: a vertex every few metres, as RatSLAM places them on KITTI.
    pub place_threshold_rad: f64,
    /// Heading-code distance (rad, wrapped) beyond which a new vertex is due (0.35 rad ≈ 20°).
    pub heading_threshold_rad: f64,
    pub ambiguity: AmbiguityPolicy,
    /// Relaxation passes run after every frame once a loop link exists (RatSLAM runs one per frame).
    pub online_relaxation_passes: usize,
    /// Relaxation gain for the online passes (RatSLAM: 0.5).
    pub relaxation_gain: f64,
    /// Standard deviation of a link's position (m) and yaw (rad), for the least-squares corrector.
    pub link_sigma_xy_m: f64,
    pub link_sigma_yaw_rad: f64,
}

impl Default for MapParams {
    fn default() -> Self {
        Self {
            place_threshold_rad: 0.2,
            heading_threshold_rad: 0.35,
            ambiguity: AmbiguityPolicy::NearestPose,
            online_relaxation_passes: 1,
            relaxation_gain: 0.5,
            link_sigma_xy_m: 0.1,
            link_sigma_yaw_rad: 0.01,
        }
    }
}

impl MapParams {
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("place_threshold_rad", self.place_threshold_rad),
            ("heading_threshold_rad", self.heading_threshold_rad),
            ("link_sigma_xy_m", self.link_sigma_xy_m),
            ("link_sigma_yaw_rad", self.link_sigma_yaw_rad),
        ];
        for (what, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(MapError::InvalidParameter {
                    what,
                    requirement: "finite and > 0",
                    value,
                });
            }
        }
        RelaxationParams {
            gain: self.relaxation_gain,
            passes: 0,
        }
        .validate()
    }
}

/// One experience: what the agent saw and coded there, and where the map puts it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Vertex {
    pub view_cell_id: u64,
    /// `(θx, θy)`, rad on the place torus.
    pub place_code_rad: [f64; 2],
    pub heading_code_rad: f64,
    pub world_from_vertex: Pose2,
}

/// An odometric link: `from_from_to` (SE(2), metres and rad) and the time it took.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Link {
    pub from: usize,
    pub to: usize,
    pub from_from_to: Pose2,
    pub elapsed_s: f64,
    pub kind: EdgeKind,
}

/// One camera frame's worth of input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameInput {
    pub view_cell_id: u64,
    pub place_code_rad: [f64; 2],
    pub heading_code_rad: f64,
    /// VO step `previous_frame_from_frame` (x forward, y left, yaw CCW).
    pub odometry_step: Pose2,
    pub elapsed_s: f64,
}

/// What a frame did to the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameOutcome {
    /// The current vertex after the frame; `None` while lost (relocalising) with no match yet.
    pub vertex: Option<usize>,
    pub created: bool,
    /// `(from, to)` of the loop link added this frame.
    pub loop_closure: Option<(usize, usize)>,
    /// Every matching vertex when more than one matched (sorted by code distance); empty otherwise.
    pub ambiguous_candidates: Vec<usize>,
    /// The frame re-found the map after [`ExperienceMap::start_relocalization`].
    pub relocalized: bool,
    /// The agent's pose in the map frame after the frame.
    pub world_from_agent: Option<Pose2>,
}

/// Which corrector [`ExperienceMap::correct`] runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Corrector {
    Relaxation(RelaxationParams),
    LeastSquares(SolverParams),
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CorrectionReport {
    /// Relaxation passes or LM iterations.
    pub iterations: usize,
    pub initial_chi2: f64,
    pub final_chi2: f64,
    pub converged: bool,
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
    #[serde(skip)]
    pub(crate) by_view_cell: HashMap<u64, Vec<usize>>,
}

fn place_distance_rad(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    wrap_angle(a[0] - b[0]).hypot(wrap_angle(a[1] - b[1]))
}

impl ExperienceMap {
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
            by_view_cell: HashMap::new(),
        })
    }

    pub fn params(&self) -> &MapParams {
        &self.params
    }
    pub fn vertices(&self) -> &[Vertex] {
        &self.vertices
    }
    pub fn links(&self) -> &[Link] {
        &self.links
    }
    pub fn current_vertex(&self) -> Option<usize> {
        self.current
    }
    pub fn frames(&self) -> u64 {
        self.frames
    }
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
        ] {
            if !value.is_finite() {
                return Err(MapError::NonFinite {
                    what: "vertex code",
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
        if !(link.elapsed_s.is_finite() && link.elapsed_s >= 0.0) {
            return Err(MapError::InvalidParameter {
                what: "link elapsed_s",
                requirement: "finite and >= 0",
                value: link.elapsed_s,
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

    /// Vertices matching the frame's view cell and codes, sorted by normalised code distance.
    fn candidates(&self, input: &FrameInput, exclude: Option<usize>) -> Vec<usize> {
        let Some(list) = self.by_view_cell.get(&input.view_cell_id) else {
            return Vec::new();
        };
        let mut scored: Vec<(f64, usize)> = list
            .iter()
            .filter(|&&v| Some(v) != exclude)
            .filter_map(|&v| {
                let score = self.code_score(&self.vertices[v], input)?;
                Some((score, v))
            })
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

    fn validate_input(input: &FrameInput) -> Result<()> {
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
            return Err(MapError::InvalidParameter {
                what: "elapsed_s",
                requirement: "finite and >= 0",
                value: input.elapsed_s,
            });
        }
        Ok(())
    }

    /// Advance the map by one camera frame (see the module docs for the rule).
    pub fn on_frame(&mut self, input: &FrameInput) -> Result<FrameOutcome> {
        Self::validate_input(input)?;
        self.frames += 1;
        let mut outcome = FrameOutcome {
            vertex: None,
            created: false,
            loop_closure: None,
            ambiguous_candidates: Vec::new(),
            relocalized: false,
            world_from_agent: None,
        };
        if self.lost {
            let candidates = self.candidates(input, None);
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
            outcome.vertex = self.current;
            outcome.world_from_agent = self.world_from_agent();
            return Ok(outcome);
        }
        let Some(current) = self.current else {
            // The first frame founds the map at the origin.
            let index = self.add_vertex(Vertex {
                view_cell_id: input.view_cell_id,
                place_code_rad: input.place_code_rad,
                heading_code_rad: input.heading_code_rad,
                world_from_vertex: Pose2::IDENTITY,
            })?;
            self.current = Some(index);
            outcome.vertex = Some(index);
            outcome.created = true;
            outcome.world_from_agent = self.world_from_agent();
            return Ok(outcome);
        };
        self.current_from_agent = self.current_from_agent.compose(&input.odometry_step);
        self.elapsed_since_current_s += input.elapsed_s;

        let here = &self.vertices[current];
        let stays =
            here.view_cell_id == input.view_cell_id && self.code_score(here, input).is_some();
        if !stays {
            let candidates = self.candidates(input, Some(current));
            let world_from_agent = here.world_from_vertex.compose(&self.current_from_agent);
            let target = match (candidates.len(), self.params.ambiguity) {
                (0, _) => None,
                (1, _) | (_, AmbiguityPolicy::NearestCode) => Some(candidates[0]),
                (_, AmbiguityPolicy::CreateVertex) => None,
                (_, AmbiguityPolicy::NearestPose) => candidates.iter().copied().min_by(|&a, &b| {
                    let da = distance_m(&self.vertices[a].world_from_vertex, &world_from_agent);
                    let db = distance_m(&self.vertices[b].world_from_vertex, &world_from_agent);
                    da.total_cmp(&db).then(a.cmp(&b))
                }),
            };
            if candidates.len() > 1 {
                outcome.ambiguous_candidates = candidates;
            }
            let link = Link {
                from: current,
                to: 0,
                from_from_to: self.current_from_agent,
                elapsed_s: self.elapsed_since_current_s,
                kind: EdgeKind::Odometry,
            };
            match target {
                None => {
                    let index = self.add_vertex(Vertex {
                        view_cell_id: input.view_cell_id,
                        place_code_rad: input.place_code_rad,
                        heading_code_rad: input.heading_code_rad,
                        world_from_vertex: world_from_agent,
                    })?;
                    self.add_link(Link { to: index, ..link })?;
                    outcome.created = true;
                    self.current = Some(index);
                }
                Some(target) => {
                    let already_linked = self.links.iter().any(|l| {
                        (l.from == current && l.to == target)
                            || (l.from == target && l.to == current)
                    });
                    if !already_linked {
                        self.add_link(Link {
                            to: target,
                            kind: EdgeKind::Loop,
                            ..link
                        })?;
                        outcome.loop_closure = Some((current, target));
                    }
                    self.current = Some(target);
                }
            }
            self.current_from_agent = Pose2::IDENTITY;
            self.elapsed_since_current_s = 0.0;
        }
        if self.params.online_relaxation_passes > 0 && self.loop_link_count() > 0 {
            self.correct(&Corrector::Relaxation(RelaxationParams {
                gain: self.params.relaxation_gain,
                passes: self.params.online_relaxation_passes,
            }))?;
        }
        outcome.vertex = self.current;
        outcome.world_from_agent = self.world_from_agent();
        Ok(outcome)
    }

    /// The map as a pose graph (vertex 0 fixed; link information from the params' sigmas).
    pub fn pose_graph(&self) -> PoseGraph {
        let information =
            isotropic_information(self.params.link_sigma_xy_m, self.params.link_sigma_yaw_rad);
        PoseGraph {
            ids: (0..self.vertices.len() as u64).collect(),
            poses: self.vertices.iter().map(|v| v.world_from_vertex).collect(),
            edges: self
                .links
                .iter()
                .map(|l| Edge {
                    from: l.from,
                    to: l.to,
                    from_to: l.from_from_to,
                    information,
                    kind: l.kind,
                })
                .collect(),
            fixed: 0,
        }
    }

    /// Correct the vertex poses with either corrector. The least-squares one starts from the current
    /// poses unless its params say otherwise. Poses change only if the corrector succeeds.
    pub fn correct(&mut self, corrector: &Corrector) -> Result<CorrectionReport> {
        if self.vertices.is_empty() {
            return Err(MapError::EmptyGraph);
        }
        let mut graph = self.pose_graph();
        let report = match corrector {
            Corrector::Relaxation(params) => {
                let r = relax(&mut graph, params)?;
                CorrectionReport {
                    iterations: r.passes,
                    initial_chi2: r.initial_chi2,
                    final_chi2: r.final_chi2,
                    converged: false,
                }
            }
            Corrector::LeastSquares(params) => {
                let r = optimize(&mut graph, params)?;
                CorrectionReport {
                    iterations: r.iterations,
                    initial_chi2: r.initial_chi2,
                    final_chi2: r.final_chi2,
                    converged: r.converged,
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

fn distance_m(a: &Pose2, b: &Pose2) -> f64 {
    (a.x - b.x).hypot(a.y - b.y)
}
