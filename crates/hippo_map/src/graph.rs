//! The pose graph shared by both correctors and the g2o reader/writer.
//!
//! Vertex `i` holds `world_from_i`. Edge `(i → j, z, Ω)` measures `i_from_j`; its residual is g2o's
//! `EdgeSE2` error `e = toVector(z⁻¹ ⊕ (x_i⁻¹ ⊕ x_j))`, and the cost of the graph is
//! `χ² = Σ eᵀ Ω e` over all edges (GTSAM reports half of this). Vertex `fixed` (the first one by
//! default) anchors the gauge and never moves.
use crate::error::{MapError, Result};
use crate::se2::Pose2;
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// What created an edge. Loop edges are the ones a robust loss may down-weight.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum EdgeKind {
    /// Dead reckoning between consecutive poses: trusted.
    Odometry,
    /// A place recognised again: may be a false closure.
    Loop,
}

/// One relative-pose measurement `i_from_j` with its information (inverse covariance, order x, y, yaw).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Edge {
    /// Start vertex (index into `poses`).
    pub from: usize,
    /// End vertex.
    pub to: usize,
    // Written `from_to` before one spelling was chosen for the whole map (`Link` has the same field).
    /// `to` seen from `from` (the measurement).
    #[serde(alias = "from_to")]
    pub from_from_to: Pose2,
    /// Information (inverse covariance), order x, y, yaw.
    pub information: [[f64; 3]; 3],
    /// Odometry or loop edge.
    pub kind: EdgeKind,
}

impl Edge {
    /// g2o `EdgeSE2` residual `(e_x, e_y, e_yaw)` at the given poses.
    #[inline]
    pub fn residual(&self, world_from_from: &Pose2, world_from_to: &Pose2) -> [f64; 3] {
        let delta = self
            .from_from_to
            .between(&world_from_from.between(world_from_to));
        [delta.x, delta.y, delta.yaw]
    }

    /// `eᵀ Ω e` at the given poses.
    #[inline]
    pub fn chi2(&self, world_from_from: &Pose2, world_from_to: &Pose2) -> f64 {
        quadratic_form(
            &self.information,
            &self.residual(world_from_from, world_from_to),
        )
    }
}

#[inline]
pub(crate) fn quadratic_form(m: &[[f64; 3]; 3], e: &[f64; 3]) -> f64 {
    let e = Vector3::from(*e);
    e.dot(&(matrix3(m) * e))
}

/// A 3×3 block stored as rows (how edges keep their information) as a nalgebra matrix.
#[inline]
pub(crate) fn matrix3(rows: &[[f64; 3]; 3]) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| rows[r][c])
}

/// Identity information scaled per axis: `diag(1/σ_xy², 1/σ_xy², 1/σ_yaw²)`.
pub fn isotropic_information(sigma_xy_m: f64, sigma_yaw_rad: f64) -> [[f64; 3]; 3] {
    let a = 1.0 / (sigma_xy_m * sigma_xy_m);
    let b = 1.0 / (sigma_yaw_rad * sigma_yaw_rad);
    [[a, 0.0, 0.0], [0.0, a, 0.0], [0.0, 0.0, b]]
}

/// A planar pose graph. `ids` are the caller's vertex ids (g2o ids); edges index `poses` directly.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseGraph {
    /// The caller's vertex ids (g2o ids), one per pose.
    pub ids: Vec<u64>,
    /// `world_from_vertex` of every vertex.
    pub poses: Vec<Pose2>,
    /// The measurements.
    pub edges: Vec<Edge>,
    /// Index of the vertex that anchors the gauge.
    pub fixed: usize,
}

impl PoseGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Append a vertex; returns its index.
    pub fn add_vertex(&mut self, world_from_vertex: Pose2) -> Result<usize> {
        check_pose("vertex pose", &world_from_vertex)?;
        let index = self.poses.len();
        self.ids.push(index as u64);
        self.poses.push(world_from_vertex);
        Ok(index)
    }

    /// Append an edge after checking its vertices, values and information.
    pub fn add_edge(&mut self, edge: Edge) -> Result<usize> {
        let len = self.poses.len();
        for vertex in [edge.from, edge.to] {
            if vertex >= len {
                return Err(MapError::UnknownVertex { vertex, len });
            }
        }
        if edge.from == edge.to {
            return Err(MapError::SelfLink { vertex: edge.from });
        }
        check_pose("edge measurement", &edge.from_from_to)?;
        let index = self.edges.len();
        check_information(index, &edge.information)?;
        self.edges.push(edge);
        Ok(index)
    }

    /// `χ² = Σ eᵀ Ω e` over every edge (g2o's convention).
    pub fn chi2(&self) -> f64 {
        self.chi2_at(&self.poses)
    }

    /// χ² of this graph's edges evaluated at other poses (same vertex order).
    pub fn chi2_at(&self, poses: &[Pose2]) -> f64 {
        self.edges
            .iter()
            .map(|e| e.chi2(&poses[e.from], &poses[e.to]))
            .sum()
    }

    /// Vertices.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether the graph has no vertex.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Number of edges of each kind, `(odometry, loop)`.
    pub fn edge_counts(&self) -> (usize, usize) {
        let loops = self
            .edges
            .iter()
            .filter(|e| e.kind == EdgeKind::Loop)
            .count();
        (self.edges.len() - loops, loops)
    }

    /// Dead-reckoning initial estimate: walk a breadth-first spanning tree from the fixed vertex,
    /// preferring odometry edges, and chain the measurements. Needs every vertex connected.
    pub fn initialize_from_odometry(&mut self) -> Result<()> {
        if self.poses.is_empty() {
            return Err(MapError::EmptyGraph);
        }
        let n = self.poses.len();
        let mut adjacency: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
        for (k, e) in self.edges.iter().enumerate() {
            adjacency[e.from].push((e.to, k));
            adjacency[e.to].push((e.from, k));
        }
        for list in &mut adjacency {
            // Odometry first so that the tree follows the trajectory, not a possibly false closure.
            list.sort_by_key(|&(other, k)| (self.edges[k].kind == EdgeKind::Loop, other));
        }
        let mut visited = vec![false; n];
        let mut new_poses = self.poses.clone();
        let mut queue = std::collections::VecDeque::new();
        visited[self.fixed] = true;
        queue.push_back(self.fixed);
        // Two sweeps: first odometry only, then anything left through loop edges.
        for allow_loops in [false, true] {
            if allow_loops {
                queue.extend((0..n).filter(|&v| visited[v]));
            }
            while let Some(v) = queue.pop_front() {
                for &(other, k) in &adjacency[v] {
                    let e = &self.edges[k];
                    if visited[other] || (!allow_loops && e.kind == EdgeKind::Loop) {
                        continue;
                    }
                    new_poses[other] = if e.from == v {
                        new_poses[v].compose(&e.from_from_to)
                    } else {
                        new_poses[v].compose(&e.from_from_to.inverse())
                    };
                    visited[other] = true;
                    queue.push_back(other);
                }
            }
        }
        if let Some(vertex) = visited.iter().position(|&seen| !seen) {
            return Err(MapError::Disconnected { vertex });
        }
        self.poses = new_poses;
        Ok(())
    }
}

/// The largest coordinate a pose may have (m): a million kilometres. Beyond it a position is a unit or
/// overflow error, not a place, and the correctors' squares lose every digit of the poses near the origin
/// (a step of 1e200 m was taken, then made every later frame fail; relaxation set such graphs to zero).
pub const MAX_COORDINATE_M: f64 = 1.0e9;

pub(crate) fn check_pose(what: &'static str, pose: &Pose2) -> Result<()> {
    for value in [pose.x, pose.y, pose.yaw] {
        if !value.is_finite() {
            return Err(MapError::NonFinite { what, value });
        }
    }
    for value in [pose.x, pose.y] {
        if value.abs() > MAX_COORDINATE_M {
            return Err(MapError::TooFar {
                what,
                value,
                limit: MAX_COORDINATE_M,
            });
        }
    }
    Ok(())
}

/// Ω must be finite, symmetric and positive definite (checked by a 3×3 Cholesky).
pub(crate) fn check_information(edge: usize, m: &[[f64; 3]; 3]) -> Result<()> {
    let bad = || MapError::BadInformation { edge };
    for r in 0..3 {
        for c in 0..3 {
            if !m[r][c].is_finite() {
                return Err(bad());
            }
            let scale = m[r][c].abs().max(m[c][r].abs()).max(1.0);
            if (m[r][c] - m[c][r]).abs() > 1e-9 * scale {
                return Err(bad());
            }
        }
    }
    let l00 = m[0][0];
    if l00 <= 0.0 {
        return Err(bad());
    }
    let l10 = m[1][0] / l00.sqrt();
    let d1 = m[1][1] - l10 * l10;
    if d1 <= 0.0 {
        return Err(bad());
    }
    let l20 = m[2][0] / l00.sqrt();
    let l21 = (m[2][1] - l20 * l10) / d1.sqrt();
    if m[2][2] - l20 * l20 - l21 * l21 <= 0.0 {
        return Err(bad());
    }
    Ok(())
}

/// Absolute trajectory error (root mean square of position differences, metres) after the best rigid
/// SE(2) alignment of `estimate` onto `reference` (closed-form 2-D Umeyama without scale).
pub fn ate_rmse_m(estimate: &[Pose2], reference: &[Pose2]) -> f64 {
    let n = estimate.len().min(reference.len());
    if n == 0 {
        return 0.0;
    }
    let mean = |p: &[Pose2]| {
        let (sx, sy) = p[..n]
            .iter()
            .fold((0.0, 0.0), |(a, b), q| (a + q.x, b + q.y));
        (sx / n as f64, sy / n as f64)
    };
    let (ex, ey) = mean(estimate);
    let (rx, ry) = mean(reference);
    let (mut sin_sum, mut cos_sum) = (0.0, 0.0);
    for (e, r) in estimate[..n].iter().zip(&reference[..n]) {
        let (ax, ay) = (e.x - ex, e.y - ey);
        let (bx, by) = (r.x - rx, r.y - ry);
        cos_sum += ax * bx + ay * by;
        sin_sum += ax * by - ay * bx;
    }
    let angle = sin_sum.atan2(cos_sum);
    let (s, c) = angle.sin_cos();
    let sq: f64 = estimate[..n]
        .iter()
        .zip(&reference[..n])
        .map(|(e, r)| {
            let (ax, ay) = (e.x - ex, e.y - ey);
            let dx = c * ax - s * ay + rx - r.x;
            let dy = s * ax + c * ay + ry - r.y;
            dx * dx + dy * dy
        })
        .sum();
    (sq / n as f64).sqrt()
}
