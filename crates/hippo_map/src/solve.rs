//! Exact pose-graph correction: sparse nonlinear least squares on SE(2) by Levenberg–Marquardt.
//!
//! Minimises `F(x) = Σ_odometry eᵀΩe + Σ_loop ρ(eᵀΩe)` over all poses but the fixed one, with g2o's
//! `EdgeSE2` residual `e` (see [`crate::graph`]). Poses are updated additively in `(x, y, yaw)` and the
//! yaw is wrapped. Each iteration linearises `e ≈ e₀ + J δ`, assembles `H = Σ w JᵀΩJ` and `g = Σ w JᵀΩe`
//! (`w = ρ'(eᵀΩe)`, iteratively reweighted least squares; `w = 1` off the robust edges), and solves
//! `(H + λI) δ = −g` with faer's sparse Cholesky. The symbolic factorisation is computed once per solve
//! and reused by every iteration. λ follows Nielsen's rule: a step is accepted when it lowers `F`, and
//! `λ` shrinks by `max(1/3, 1 − (2ρ − 1)³)` with `ρ` the ratio of actual to predicted decrease; a rejected
//! step multiplies λ by a growing factor. λ → 0 is Gauss–Newton.
//!
//! Robust loss (loop edges only, odometry is trusted): Cauchy `ρ(s) = c² ln(1 + s/c²)`, or dynamic
//! covariance scaling (DCS, Agarwal et al. ICRA 2013), which as a loss is `ρ(s) = s` for `s ≤ Φ` and
//! `4Φs/(Φ + s) − Φ` beyond, i.e. weight `(2Φ/(Φ + s))²`: a false closure with a large χ² gets almost no
//! weight, so it cannot drag the map. Robust losses are non-convex, so they need a start that does not
//! already trust the closures: [`Initialization::Odometry`] is the usual one for them.
use crate::error::{MapError, Result};
use crate::graph::{EdgeKind, PoseGraph};
use crate::init::{free_indices, initialize_chordal};
use crate::se2::wrap_angle;
use crate::sparse::BlockSystem;
use serde::{Deserialize, Serialize};

/// Loss applied to loop edges.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum RobustLoss {
    /// Plain least squares on every edge.
    None,
    /// Cauchy loss with scale `c²` in χ² units.
    Cauchy { scale_chi2: f64 },
    /// Dynamic covariance scaling with threshold `Φ` in χ² units.
    Dcs { phi_chi2: f64 },
}

impl RobustLoss {
    /// `(ρ(s), ρ'(s))` for a squared Mahalanobis error `s`.
    #[inline]
    fn evaluate(&self, s: f64) -> (f64, f64) {
        match *self {
            RobustLoss::None => (s, 1.0),
            RobustLoss::Cauchy { scale_chi2: c2 } => (c2 * (s / c2).ln_1p(), 1.0 / (1.0 + s / c2)),
            RobustLoss::Dcs { phi_chi2: phi } => {
                if s <= phi {
                    (s, 1.0)
                } else {
                    let w = 2.0 * phi / (phi + s);
                    (4.0 * phi * s / (phi + s) - phi, w * w)
                }
            }
        }
    }

    fn validate(&self) -> Result<()> {
        let (what, value) = match *self {
            RobustLoss::None => return Ok(()),
            RobustLoss::Cauchy { scale_chi2 } => ("Cauchy scale_chi2", scale_chi2),
            RobustLoss::Dcs { phi_chi2 } => ("DCS phi_chi2", phi_chi2),
        };
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(MapError::InvalidParameter {
                what,
                requirement: "finite and > 0",
                value,
            })
        }
    }
}

/// Where the solve starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Initialization {
    /// The poses the graph holds.
    Current,
    /// Dead reckoning along odometry edges (a spanning tree from the fixed vertex).
    Odometry,
    /// Chordal relaxation: rotations, then translations, both linear (see [`crate::init`]).
    Chordal,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SolverParams {
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction of it.
    pub relative_cost_tolerance: f64,
    /// Stop when `max|g|` (gradient of ½F) falls below this.
    pub gradient_tolerance: f64,
    /// Initial λ as a fraction of the largest diagonal entry of `H` (g2o's τ).
    pub initial_lambda_scale: f64,
    pub robust_loss: RobustLoss,
    pub initialization: Initialization,
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            relative_cost_tolerance: 1e-10,
            gradient_tolerance: 1e-9,
            initial_lambda_scale: 1e-5,
            robust_loss: RobustLoss::None,
            initialization: Initialization::Chordal,
        }
    }
}

/// Why the solve stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Termination {
    /// The relative cost decrease fell below tolerance.
    CostConverged,
    /// The gradient fell below tolerance.
    GradientConverged,
    /// No free vertex or no edge: nothing to optimise.
    NothingToDo,
    /// λ grew past any useful value without finding a decrease: a (local) minimum to working precision.
    NoFurtherDecrease,
    MaxIterations,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SolveReport {
    /// Accepted and rejected LM iterations (each one factorisation).
    pub iterations: usize,
    /// `χ²` (plain, all edges) at the start, after initialisation.
    pub initial_chi2: f64,
    /// `χ²` (plain, all edges) at the end.
    pub final_chi2: f64,
    /// The minimised objective `F` at the end (equals `final_chi2` without a robust loss).
    pub final_cost: f64,
    pub converged: bool,
    pub termination: Termination,
    /// Loop edges whose final robust weight is below ½ (treated as outliers); 0 without a robust loss.
    pub downweighted_loops: usize,
}

/// Partial derivatives of the residual w.r.t. `(x, y, yaw)` of `from` and `to`.
#[inline]
fn linearize(
    from: &crate::se2::Pose2,
    to: &crate::se2::Pose2,
    measured: &crate::se2::Pose2,
) -> ([f64; 3], [[f64; 3]; 3], [[f64; 3]; 3]) {
    let (si, ci) = from.yaw.sin_cos();
    let (sz, cz) = measured.yaw.sin_cos();
    let (dx, dy) = (to.x - from.x, to.y - from.y);
    // d = R_iᵀ(t_j − t_i), e_t = R_zᵀ(d − t_z), e_yaw = wrap(θ_j − θ_i − θ_z).
    let d = [ci * dx + si * dy, -si * dx + ci * dy];
    let (ux, uy) = (d[0] - measured.x, d[1] - measured.y);
    let e = [
        cz * ux + sz * uy,
        -sz * ux + cz * uy,
        wrap_angle(to.yaw - from.yaw - measured.yaw),
    ];
    // A = R_zᵀ R_iᵀ = R(−(θ_i + θ_z)).
    let (sa, ca) = (from.yaw + measured.yaw).sin_cos();
    let a = [[ca, sa], [-sa, ca]];
    // ∂e_t/∂θ_i = R_zᵀ (d_y, −d_x).
    let dth = [cz * d[1] + sz * (-d[0]), -sz * d[1] + cz * (-d[0])];
    let j_from = [
        [-a[0][0], -a[0][1], dth[0]],
        [-a[1][0], -a[1][1], dth[1]],
        [0.0, 0.0, -1.0],
    ];
    let j_to = [
        [a[0][0], a[0][1], 0.0],
        [a[1][0], a[1][1], 0.0],
        [0.0, 0.0, 1.0],
    ];
    (e, j_from, j_to)
}

#[inline]
fn jt_omega(j: &[[f64; 3]; 3], omega: &[[f64; 3]; 3], weight: f64) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            let mut s = 0.0;
            for k in 0..3 {
                s += j[k][r] * omega[k][c];
            }
            out[r][c] = weight * s;
        }
    }
    out
}

#[inline]
fn mat3_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            out[r][c] = a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c];
        }
    }
    out
}

/// Objective `F` and plain `χ²` at the given poses.
fn objective(graph: &PoseGraph, poses: &[crate::se2::Pose2], loss: &RobustLoss) -> (f64, f64) {
    let mut cost = 0.0;
    let mut chi2 = 0.0;
    for e in &graph.edges {
        let s = e.chi2(&poses[e.from], &poses[e.to]);
        chi2 += s;
        cost += match e.kind {
            EdgeKind::Loop => loss.evaluate(s).0,
            EdgeKind::Odometry => s,
        };
    }
    (cost, chi2)
}

/// Run the initialisation chosen in `params`, then Levenberg–Marquardt; the graph's poses are replaced
/// by the solution only when the solve succeeds.
pub fn optimize(graph: &mut PoseGraph, params: &SolverParams) -> Result<SolveReport> {
    params.robust_loss.validate()?;
    if graph.is_empty() {
        return Err(MapError::EmptyGraph);
    }
    if graph.fixed >= graph.len() {
        return Err(MapError::UnknownVertex {
            vertex: graph.fixed,
            len: graph.len(),
        });
    }
    let mut work = graph.clone();
    match params.initialization {
        Initialization::Current => {}
        Initialization::Odometry => work.initialize_from_odometry()?,
        Initialization::Chordal => initialize_chordal(&mut work)?,
    }
    let loss = params.robust_loss;
    let (initial_cost, initial_chi2) = objective(&work, &work.poses, &loss);
    let free = free_indices(&work);
    let n_free = work.len() - 1;
    if n_free == 0 || work.edges.is_empty() {
        *graph = work;
        return Ok(SolveReport {
            iterations: 0,
            initial_chi2,
            final_chi2: initial_chi2,
            final_cost: initial_cost,
            converged: true,
            termination: Termination::NothingToDo,
            downweighted_loops: 0,
        });
    }
    let pairs = work
        .edges
        .iter()
        .filter_map(|e| Some((free[e.from]?, free[e.to]?)));
    let mut system = BlockSystem::<3>::new(n_free, pairs)?;
    let mut gradient = vec![0.0; 3 * n_free];
    let mut step = vec![0.0; 3 * n_free];
    let mut candidate = work.poses.clone();
    let mut cost = initial_cost;
    let mut lambda = -1.0;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    let mut relinearize = true;

    while iterations < params.max_iterations {
        if relinearize {
            system.clear();
            gradient.fill(0.0);
            for e in &work.edges {
                let (res, j_from, j_to) =
                    linearize(&work.poses[e.from], &work.poses[e.to], &e.from_to);
                let weight = match e.kind {
                    EdgeKind::Loop => {
                        loss.evaluate(crate::graph::quadratic_form(&e.information, &res))
                            .1
                    }
                    EdgeKind::Odometry => 1.0,
                };
                let blocks = [(free[e.from], &j_from), (free[e.to], &j_to)];
                for (bi, ji) in blocks.iter() {
                    let Some(bi) = *bi else { continue };
                    let jto = jt_omega(ji, &e.information, weight);
                    for r in 0..3 {
                        gradient[3 * bi + r] +=
                            jto[r][0] * res[0] + jto[r][1] * res[1] + jto[r][2] * res[2];
                    }
                    for (bj, jj) in blocks.iter() {
                        let Some(bj) = *bj else { continue };
                        if bi <= bj {
                            system.add_block(bi, bj, &mat3_mul(&jto, jj));
                        }
                    }
                }
            }
            let max_gradient = gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()));
            if max_gradient < params.gradient_tolerance {
                termination = Termination::GradientConverged;
                break;
            }
            if lambda < 0.0 {
                let max_diag = system.diagonal().into_iter().fold(0.0f64, f64::max);
                lambda = params.initial_lambda_scale * max_diag.max(1e-12);
            }
            relinearize = false;
        }
        iterations += 1;
        for (s, g) in step.iter_mut().zip(&gradient) {
            *s = -g;
        }
        let damping = vec![lambda; 3 * n_free];
        if system.solve_damped(&damping, &mut step).is_err() {
            // Numerically indefinite at this λ: damp harder and retry.
            lambda *= nu;
            nu *= 2.0;
            continue;
        }
        for (v, f) in free.iter().enumerate() {
            candidate[v] = match f {
                Some(i) => {
                    let p = work.poses[v];
                    crate::se2::Pose2::new(
                        p.x + step[3 * i],
                        p.y + step[3 * i + 1],
                        wrap_angle(p.yaw + step[3 * i + 2]),
                    )
                }
                None => work.poses[v],
            };
        }
        let (new_cost, _) = objective(&work, &candidate, &loss);
        let predicted: f64 = step
            .iter()
            .zip(&gradient)
            .map(|(s, g)| s * (lambda * s - g))
            .sum();
        let actual = cost - new_cost;
        if actual > 0.0 && predicted > 0.0 {
            let rho = actual / predicted;
            std::mem::swap(&mut work.poses, &mut candidate);
            let relative = actual / cost.max(f64::MIN_POSITIVE);
            cost = new_cost;
            lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
            nu = 2.0;
            relinearize = true;
            if relative < params.relative_cost_tolerance {
                termination = Termination::CostConverged;
                break;
            }
        } else {
            lambda *= nu;
            nu *= 2.0;
            if !lambda.is_finite() || lambda > 1e32 {
                termination = Termination::NoFurtherDecrease;
                break;
            }
        }
    }
    let (final_cost, final_chi2) = objective(&work, &work.poses, &loss);
    let downweighted_loops = if loss == RobustLoss::None {
        0
    } else {
        work.edges
            .iter()
            .filter(|e| {
                e.kind == EdgeKind::Loop
                    && loss
                        .evaluate(e.chi2(&work.poses[e.from], &work.poses[e.to]))
                        .1
                        < 0.5
            })
            .count()
    };
    *graph = work;
    Ok(SolveReport {
        iterations,
        initial_chi2,
        final_chi2,
        final_cost,
        converged: termination != Termination::MaxIterations,
        termination,
        downweighted_loops,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::se2::Pose2;

    #[test]
    fn analytic_jacobians_match_finite_differences() {
        let from = Pose2::new(0.3, -1.2, 2.9);
        let to = Pose2::new(2.1, 0.4, -2.8);
        let z = Pose2::new(1.0, 0.5, 0.4);
        let (e0, j_from, j_to) = linearize(&from, &to, &z);
        let h = 1e-6;
        for k in 0..3 {
            for (which, jac) in [(0, &j_from), (1, &j_to)] {
                let mut a = [from.to_array(), to.to_array()];
                a[which][k] += h;
                let (e1, _, _) = linearize(
                    &Pose2::new(a[0][0], a[0][1], a[0][2]),
                    &Pose2::new(a[1][0], a[1][1], a[1][2]),
                    &z,
                );
                for r in 0..3 {
                    let numeric = wrap_angle(e1[r] - e0[r]) / h;
                    assert!(
                        (numeric - jac[r][k]).abs() < 1e-5,
                        "d e{r}/d x{which}[{k}]: numeric {numeric} analytic {}",
                        jac[r][k]
                    );
                }
            }
        }
        let edge = crate::graph::Edge {
            from: 0,
            to: 1,
            from_to: z,
            information: crate::graph::isotropic_information(1.0, 1.0),
            kind: EdgeKind::Odometry,
        };
        let reference = edge.residual(&from, &to);
        for r in 0..3 {
            assert!((reference[r] - e0[r]).abs() < 1e-12);
        }
    }
}
