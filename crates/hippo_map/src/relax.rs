//! The paper's corrector: iterative relaxation of the experience map (Duckett et al. 2002, as in RatSLAM).
//!
//! One pass visits every link `(i → j, z)` once, in order, and moves both ends towards agreement:
//! with the prediction `p̂_j = x_i ⊕ z`, the position error `Δ = t_j − t̂_j` and the heading error
//! `δ = wrap(θ_i + θ_z − θ_j)`, it sets `t_i += gain·Δ`, `t_j −= gain·Δ`, `θ_i −= gain·δ`,
//! `θ_j += gain·δ` (RatSLAM's `exp_correction`, 0.5 by default: a link on its own is satisfied in one
//! visit). Updates are applied immediately (Gauss–Seidel), so a correction spreads along the graph one
//! pass at a time: a loop of `n` vertices needs on the order of `n` passes, and the fixed point is not
//! the least-squares optimum (every link pulls equally, whatever its uncertainty). After the passes the
//! whole map is moved rigidly so that the fixed vertex is back where it was; costs do not change by that.
use crate::error::{MapError, Result};
use crate::graph::PoseGraph;
use crate::se2::{wrap_angle, Pose2};
use serde::{Deserialize, Serialize};

/// RatSLAM-style relaxation settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RelaxationParams {
    /// Fraction of each link's error moved onto each of its ends per visit, in `(0, 1)`.
    pub gain: f64,
    /// Number of passes over all links.
    pub passes: usize,
}

impl Default for RelaxationParams {
    fn default() -> Self {
        Self {
            gain: 0.5,
            passes: 100,
        }
    }
}

impl RelaxationParams {
    pub(crate) fn validate(&self) -> Result<()> {
        if self.gain.is_finite() && self.gain > 0.0 && self.gain < 1.0 {
            Ok(())
        } else {
            Err(MapError::BadParameter {
                name: "relaxation gain",
                value: self.gain.to_string(),
                why: "must be in (0, 1) (RatSLAM uses 0.5)".into(),
            })
        }
    }
}

/// What relaxation passes did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RelaxationReport {
    /// Passes run.
    pub passes: usize,
    /// `χ²` before the first pass.
    pub initial_chi2: f64,
    /// `χ²` after the last pass.
    pub final_chi2: f64,
    /// The stop hook ended the passes early (see [`relax_with_stop`]).
    #[serde(default)]
    pub interrupted: bool,
}

/// Run `params.passes` relaxation passes over the graph's edges (information is ignored, as in RatSLAM).
pub fn relax(graph: &mut PoseGraph, params: &RelaxationParams) -> Result<RelaxationReport> {
    relax_with_stop(graph, params, &mut || false)
}

/// [`relax`] that asks `should_stop` before every pass (on the calling thread) and, when it says so,
/// stops after the passes done so far: the map is re-anchored as after a full run, and the report says
/// `interrupted` with the passes run. Relaxation does not lower `χ²` pass by pass as least squares does,
/// but each pass is whole. The hook is called once per pass (microseconds on a small map): one that does
/// work should keep its own clock.
pub fn relax_with_stop(
    graph: &mut PoseGraph,
    params: &RelaxationParams,
    should_stop: &mut dyn FnMut() -> bool,
) -> Result<RelaxationReport> {
    params.validate()?;
    if graph.is_empty() {
        return Err(MapError::EmptyGraph);
    }
    let initial_chi2 = graph.chi2();
    let anchor = graph.poses[graph.fixed];
    let gain = params.gain;
    let mut passes = 0;
    let mut interrupted = false;
    while passes < params.passes {
        if should_stop() {
            interrupted = true;
            break;
        }
        passes += 1;
        for e in &graph.edges {
            let from = graph.poses[e.from];
            let to = graph.poses[e.to];
            let predicted = from.compose(&e.from_from_to);
            let (dx, dy) = (to.x - predicted.x, to.y - predicted.y);
            let dyaw = wrap_angle(from.yaw + e.from_from_to.yaw - to.yaw);
            graph.poses[e.from] = Pose2::new(
                from.x + gain * dx,
                from.y + gain * dy,
                wrap_angle(from.yaw - gain * dyaw),
            );
            graph.poses[e.to] = Pose2::new(
                to.x - gain * dx,
                to.y - gain * dy,
                wrap_angle(to.yaw + gain * dyaw),
            );
        }
    }
    // Rigid re-anchoring: world_from_v ← anchor ⊕ (moved_anchor⁻¹ ⊕ world_from_v).
    let moved_anchor = graph.poses[graph.fixed];
    let correction = anchor.compose(&moved_anchor.inverse());
    for pose in &mut graph.poses {
        *pose = correction.compose(pose);
    }
    graph.poses[graph.fixed] = anchor;
    Ok(RelaxationReport {
        passes,
        initial_chi2,
        final_chi2: graph.chi2(),
        interrupted,
    })
}
