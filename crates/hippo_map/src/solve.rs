//! Exact pose-graph correction: sparse nonlinear least squares on SE(2), Gauss–Newton first and
//! Levenberg–Marquardt when a step fails.
//!
//! Minimises `F(x) = Σ_odometry eᵀΩe + Σ_loop ρ(eᵀΩe)` over all poses but the fixed one, with g2o's
//! `EdgeSE2` residual `e` (see [`crate::graph`]). Poses are updated additively in `(x, y, yaw)` and the
//! yaw is wrapped. Each iteration
//! 1. linearises `e ≈ e₀ + J δ` and assembles `H = Σ w JᵀΩJ` and `g = Σ w JᵀΩe` (`w = ρ'(eᵀΩe)`,
//!    iteratively reweighted least squares; `w = 1` off the robust edges);
//! 2. solves `(H + λI) δ = −g` with faer's sparse Cholesky ([`crate::sparse`]: ordering, symbolic
//!    factorisation, the factor's and the workspace's memory are set up once per solve);
//! 3. accepts the step when it lowers `F`, else rejects it and raises λ.
//!
//! **Damping schedule.** The first step is undamped (λ = 0, Gauss–Newton, as GTSAM's λ₀ = 10⁻⁵ is in
//! effect on these costs). A pose graph's slow modes — a long corridor bending, a grid world shearing as
//! a whole — have eigenvalues of `H` many orders of magnitude below its largest diagonal entry (≈ 1/n² of
//! it for a chain of n poses), so any λ comparable to them turns the step into gradient descent along
//! exactly the directions that carry the correction. The schedule before (λ₀ = 10⁻⁵·max diag(H), shrinking
//! at most 3× per accepted step, Nielsen's rule) needed 10–17 iterations where Gauss–Newton needs 3–4,
//! and, started from dead reckoning, crept into a poor local minimum of city10000 (χ² 1 484.7 instead of
//! 511.99) that the full Gauss–Newton step jumps over. Only when a step does not lower `F` does λ become
//! `fallback_lambda_scale · max diag(H)` (growing `ν`-fold, ν doubling, on further rejections); accepted
//! steps then shrink it by `max(1/max_lambda_decrease, 1 − (2ρ − 1)³)`, `ρ` the ratio of actual to
//! predicted decrease, back towards Gauss–Newton. The solve stops when an accepted step lowers `F` by less
//! than `relative_cost_tolerance` of it, or when a rejected step was predicted to gain less than that.
//!
//! **Stopping and memory.** [`optimize_with_stop`] asks a caller's hook before every iteration and stops
//! at the last accepted iterate ([`Termination::Interrupted`]). Before anything is factorised, the size
//! of the factors is read off the graph's pattern and checked against
//! [`SolverParams::max_factor_bytes`] or the memory available ([`MapError::FactorTooLarge`]).
//!
//! Robust loss (loop edges only, odometry is trusted): Cauchy `ρ(s) = c² ln(1 + s/c²)`, or dynamic
//! covariance scaling (DCS, Agarwal et al. ICRA 2013), which as a loss is `ρ(s) = s` for `s ≤ Φ` and
//! `4Φs/(Φ + s) − Φ` beyond, i.e. weight `(2Φ/(Φ + s))²`: a false closure with a large χ² gets almost no
//! weight, so it cannot drag the map. Robust losses are non-convex, so they need a start that does not
//! already trust the closures: [`Initialization::Odometry`] is the usual one for them.
use crate::error::{MapError, Result};
use crate::graph::{matrix3, Edge, EdgeKind, PoseGraph};
use crate::init::{free_indices, initialize_chordal_with, pattern};
use crate::memory::MemoryBudget;
use crate::se2::{wrap_angle, Pose2};
use crate::sparse::{BlockOrdering, BlockSlot, BlockSystem};
use nalgebra::{Matrix3, Rotation2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// Loss applied to loop edges.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum RobustLoss {
    /// Plain least squares on every edge.
    None,
    /// Cauchy loss with scale `c²` in χ² units.
    Cauchy {
        /// `c²`.
        scale_chi2: f64,
    },
    /// Dynamic covariance scaling with threshold `Φ` in χ² units.
    Dcs {
        /// `Φ`.
        phi_chi2: f64,
    },
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
        let (name, value) = match *self {
            RobustLoss::None => return Ok(()),
            RobustLoss::Cauchy { scale_chi2 } => ("Cauchy scale_chi2", scale_chi2),
            RobustLoss::Dcs { phi_chi2 } => ("DCS phi_chi2", phi_chi2),
        };
        if value.is_finite() && value > 0.0 {
            Ok(())
        } else {
            Err(MapError::BadParameter {
                name,
                value: value.to_string(),
                why: "must be finite and > 0".into(),
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

/// Settings of [`optimize`]. Missing fields of a serialised value take their defaults.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SolverParams {
    /// Iterations (factorisations, accepted or not) at most.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction of it (Ceres's
    /// `function_tolerance`, GTSAM's `relativeErrorTol`). Gauss–Newton converges quadratically, so the
    /// cost is then exact to about the square of this.
    pub relative_cost_tolerance: f64,
    /// Stop when `max|g|` (gradient of ½F) falls below this.
    pub gradient_tolerance: f64,
    /// λ of the first step as a fraction of the largest diagonal entry of `H` (g2o's τ). 0 (default):
    /// the first step is Gauss–Newton; 10⁻⁵ with `max_lambda_decrease = 3` is the schedule before.
    pub initial_lambda_scale: f64,
    /// λ after the first rejected step, as a fraction of the largest diagonal entry of `H` (when the
    /// current λ times ν is smaller).
    pub fallback_lambda_scale: f64,
    /// On an accepted step λ shrinks by at most this factor (Nielsen's rule uses 3, GTSAM 10).
    pub max_lambda_decrease: f64,
    /// Loss on loop edges.
    pub robust_loss: RobustLoss,
    /// Where the poses start.
    pub initialization: Initialization,
    /// Bytes the sparse Cholesky factors (the factor's values, the factorisation's workspace; with
    /// [`Initialization::Chordal`] the initialisation's and the solve's together, as they are built at
    /// the same time) may take; a graph that needs more is refused with [`MapError::FactorTooLarge`]
    /// before anything that size is allocated. `None` (default): the memory the system has available
    /// when the solve starts (Linux: `MemAvailable`, or less under a cgroup limit; elsewhere an assumed
    /// 4 GiB), checked only above 64 MiB. A value replaces that check (e.g. to count on swap).
    pub max_factor_bytes: Option<u64>,
}

impl SolverParams {
    fn validate(&self) -> Result<()> {
        self.robust_loss.validate()?;
        let checks: [(&'static str, f64, &'static str, bool); 4] = [
            (
                "relative_cost_tolerance",
                self.relative_cost_tolerance,
                "finite and >= 0",
                self.relative_cost_tolerance >= 0.0,
            ),
            (
                "initial_lambda_scale",
                self.initial_lambda_scale,
                "finite and >= 0 (0 starts with a Gauss-Newton step)",
                self.initial_lambda_scale >= 0.0,
            ),
            (
                "fallback_lambda_scale",
                self.fallback_lambda_scale,
                "finite and > 0",
                self.fallback_lambda_scale > 0.0,
            ),
            (
                "max_lambda_decrease",
                self.max_lambda_decrease,
                "finite and >= 1",
                self.max_lambda_decrease >= 1.0,
            ),
        ];
        for (name, value, requirement, ok) in checks {
            if !(ok && value.is_finite()) {
                return Err(MapError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: format!("must be {requirement}"),
                });
            }
        }
        Ok(())
    }
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            relative_cost_tolerance: 1e-6,
            gradient_tolerance: 1e-9,
            initial_lambda_scale: 0.0,
            fallback_lambda_scale: 1e-5,
            max_lambda_decrease: 10.0,
            robust_loss: RobustLoss::None,
            initialization: Initialization::Chordal,
            max_factor_bytes: None,
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
    /// The iteration limit was reached.
    MaxIterations,
    /// The caller's stop hook asked to stop (see [`optimize_with_stop`]); the poses are the last accepted
    /// iterate, whose cost is at most the initial one.
    Interrupted,
}

/// What a least-squares solve did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SolveReport {
    /// Accepted and rejected iterations (each one factorisation).
    pub iterations: usize,
    /// `χ²` (plain, all edges) at the start, after initialisation.
    pub initial_chi2: f64,
    /// `χ²` (plain, all edges) at the end.
    pub final_chi2: f64,
    /// The minimised objective `F` at the end (equals `final_chi2` without a robust loss).
    pub final_cost: f64,
    /// Whether a convergence test was met.
    pub converged: bool,
    /// Why the solve stopped.
    pub termination: Termination,
    /// Loop edges whose final robust weight is below ½ (treated as outliers); 0 without a robust loss.
    pub downweighted_loops: usize,
}

/// The residual `e` and its partial derivatives w.r.t. `(x, y, yaw)` of `from` and `to`.
#[inline]
fn linearize(
    from: &Pose2,
    to: &Pose2,
    measured: &Pose2,
) -> (Vector3<f64>, Matrix3<f64>, Matrix3<f64>) {
    // d = R_iᵀ(t_j − t_i), e_t = R_zᵀ(d − t_z), e_yaw = wrap(θ_j − θ_i − θ_z).
    let d = from.rotation().inverse() * (to.translation_m() - from.translation_m());
    let measured_inv = measured.rotation().inverse();
    let e_t = measured_inv * (d - measured.translation_m());
    let e = Vector3::new(e_t.x, e_t.y, wrap_angle(to.yaw - from.yaw - measured.yaw));
    // A = R_zᵀ R_iᵀ = R(−(θ_i + θ_z)); ∂e_t/∂θ_i = R_zᵀ (d_y, −d_x).
    let a = Rotation2::new(-(from.yaw + measured.yaw));
    let a = a.matrix();
    let dth = measured_inv * Vector2::new(d.y, -d.x);
    #[rustfmt::skip]
    let j_from = Matrix3::new(
        -a[(0, 0)], -a[(0, 1)], dth.x,
        -a[(1, 0)], -a[(1, 1)], dth.y,
        0.0, 0.0, -1.0,
    );
    #[rustfmt::skip]
    let j_to = Matrix3::new(
        a[(0, 0)], a[(0, 1)], 0.0,
        a[(1, 0)], a[(1, 1)], 0.0,
        0.0, 0.0, 1.0,
    );
    (e, j_from, j_to)
}

/// A nalgebra 3×3 block as rows (how the block system takes them).
#[inline]
fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    m.transpose().into()
}

/// Objective `F` and plain `χ²` at the given poses.
fn objective(graph: &PoseGraph, poses: &[Pose2], loss: &RobustLoss) -> (f64, f64) {
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

/// Where each edge's three blocks of `H` (`from,from`, `to,to`, `from,to`) are stored; `None` for a block
/// that touches the fixed vertex.
type EdgeSlots = [Option<BlockSlot<3>>; 3];

fn edge_slots(edges: &[Edge], free: &[Option<usize>], system: &BlockSystem<3>) -> Vec<EdgeSlots> {
    edges
        .iter()
        .map(|e| {
            let (i, j) = (free[e.from], free[e.to]);
            [
                i.map(|i| system.slot(i, i)),
                j.map(|j| system.slot(j, j)),
                i.zip(j).map(|(i, j)| system.slot(i, j)),
            ]
        })
        .collect()
}

/// Step 1, linearise and assemble: `H = Σ w JᵀΩJ` and `g = Σ w JᵀΩe` at `poses` (`w` the IRLS weight of
/// a loop edge under the robust loss, 1 otherwise), into `system` and `gradient`. Returns `max|g|`.
fn linearize_and_assemble(
    edges: &[Edge],
    poses: &[Pose2],
    loss: &RobustLoss,
    free: &[Option<usize>],
    slots: &[EdgeSlots],
    system: &mut BlockSystem<3>,
    gradient: &mut [f64],
) -> f64 {
    system.clear();
    gradient.fill(0.0);
    for (e, [slot_ii, slot_jj, slot_ij]) in edges.iter().zip(slots) {
        let (res, j_from, j_to) = linearize(&poses[e.from], &poses[e.to], &e.from_from_to);
        let omega = matrix3(&e.information);
        let weight = match e.kind {
            EdgeKind::Loop => loss.evaluate(res.dot(&(omega * res))).1,
            EdgeKind::Odometry => 1.0,
        };
        // w JᵀΩ for each end, then its products with e (gradient) and with J (Hessian blocks).
        let jto_from = weight * j_from.transpose() * omega;
        let jto_to = weight * j_to.transpose() * omega;
        for (vertex, jto) in [(e.from, &jto_from), (e.to, &jto_to)] {
            if let Some(b) = free[vertex] {
                let g = jto * res;
                for r in 0..3 {
                    gradient[3 * b + r] += g[r];
                }
            }
        }
        if let Some(slot) = slot_ii {
            system.add_at(slot, &rows(&(jto_from * j_from)));
        }
        if let Some(slot) = slot_jj {
            system.add_at(slot, &rows(&(jto_to * j_to)));
        }
        if let Some(slot) = slot_ij {
            system.add_at(slot, &rows(&(jto_from * j_to)));
        }
    }
    gradient.iter().fold(0.0f64, |m, g| m.max(g.abs()))
}

/// `x ⊞ δ`: poses moved by the step (additive in `(x, y, yaw)`, yaw wrapped); the fixed vertex stays.
fn apply_step(poses: &[Pose2], free: &[Option<usize>], step: &[f64], out: &mut [Pose2]) {
    for ((p, f), o) in poses.iter().zip(free).zip(out.iter_mut()) {
        *o = match f {
            Some(i) => Pose2::new(
                p.x + step[3 * i],
                p.y + step[3 * i + 1],
                wrap_angle(p.yaw + step[3 * i + 2]),
            ),
            None => *p,
        };
    }
}

/// The λ schedule (see the module docs).
struct Damping {
    lambda: f64,
    /// Growth factor of λ over consecutive rejections (Nielsen's ν).
    nu: f64,
    /// The least λ after a rejection: `fallback_lambda_scale · max diag(H)`.
    fallback: f64,
    /// λ shrinks by at most this factor per accepted step.
    max_decrease: f64,
}

impl Damping {
    fn new(params: &SolverParams, max_diagonal: f64) -> Self {
        let scale = max_diagonal.max(1e-12);
        Self {
            lambda: params.initial_lambda_scale * scale,
            nu: 2.0,
            fallback: params.fallback_lambda_scale * scale,
            max_decrease: params.max_lambda_decrease,
        }
    }

    /// A step lowered the cost; `rho` is the ratio of actual to predicted decrease.
    fn accept(&mut self, rho: f64) {
        self.lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / self.max_decrease);
        self.nu = 2.0;
    }

    /// A step did not lower the cost (or `H + λI` was not numerically positive definite). Returns false
    /// once λ has grown past any useful value.
    fn reject(&mut self) -> bool {
        self.lambda = (self.lambda * self.nu).max(self.fallback);
        self.nu *= 2.0;
        self.lambda.is_finite() && self.lambda <= 1e32
    }
}

/// What step 3 decided.
enum Verdict {
    Continue { relinearize: bool },
    Stop(Termination),
}

/// One solve's state: the poses, the linear system at them and every buffer, allocated once (the
/// pattern, ordering and symbolic factorisation of `H`, the factor, `g`, `δ`, the candidate poses).
struct Solver<'p> {
    params: &'p SolverParams,
    work: PoseGraph,
    /// Free (non-fixed) index of every vertex.
    free: Vec<Option<usize>>,
    system: BlockSystem<3>,
    /// Storage of each edge's blocks of `H`, looked up once.
    slots: Vec<EdgeSlots>,
    gradient: Vec<f64>,
    step: Vec<f64>,
    candidate: Vec<Pose2>,
    /// `F` at `work.poses`.
    cost: f64,
    /// Set at the first linearisation (it scales with `H`).
    damping: Option<Damping>,
}

impl<'p> Solver<'p> {
    fn new(
        work: PoseGraph,
        system: BlockSystem<3>,
        cost: f64,
        params: &'p SolverParams,
    ) -> Result<Self> {
        let free = free_indices(&work);
        let n_free = work.len() - 1;
        Ok(Self {
            params,
            slots: edge_slots(&work.edges, &free, &system),
            system,
            free,
            gradient: vec![0.0; 3 * n_free],
            step: vec![0.0; 3 * n_free],
            candidate: work.poses.clone(),
            work,
            cost,
            damping: None,
        })
    }

    /// Iterate steps 1–3; returns the number of iterations (factorisations) and why it stopped.
    /// `should_stop` is asked before each iteration; the poses are then the last accepted ones.
    fn run(&mut self, should_stop: &mut dyn FnMut() -> bool) -> (usize, Termination) {
        let mut relinearize = true;
        for iteration in 1..=self.params.max_iterations {
            if should_stop() {
                return (iteration - 1, Termination::Interrupted);
            }
            // 1. Linearise and assemble at the current poses (a rejected step keeps H and g).
            if relinearize {
                let max_gradient = linearize_and_assemble(
                    &self.work.edges,
                    &self.work.poses,
                    &self.params.robust_loss,
                    &self.free,
                    &self.slots,
                    &mut self.system,
                    &mut self.gradient,
                );
                if max_gradient < self.params.gradient_tolerance {
                    return (iteration - 1, Termination::GradientConverged);
                }
            }
            let damping = self.damping.get_or_insert_with(|| {
                let max_diagonal = self.system.diagonal().into_iter().fold(0.0f64, f64::max);
                Damping::new(self.params, max_diagonal)
            });

            // 2. Damped step (H + λI) δ = −g, on the reused factorisation buffers.
            for (s, g) in self.step.iter_mut().zip(&self.gradient) {
                *s = -g;
            }
            if self
                .system
                .solve_damped(damping.lambda, &mut self.step)
                .is_err()
            {
                // Not numerically positive definite at this λ: damp harder and retry.
                if !damping.reject() {
                    return (iteration, Termination::NoFurtherDecrease);
                }
                relinearize = false;
                continue;
            }

            // 3. Accept the step if it lowers F, else reject it.
            match self.accept_or_reject() {
                Verdict::Continue { relinearize: again } => relinearize = again,
                Verdict::Stop(termination) => return (iteration, termination),
            }
        }
        (self.params.max_iterations, Termination::MaxIterations)
    }

    /// Step 3: evaluate `F` at `x ⊞ δ`; keep the step and shrink λ when `F` fell, else grow λ.
    fn accept_or_reject(&mut self) -> Verdict {
        let loss = &self.params.robust_loss;
        let tolerance = self.params.relative_cost_tolerance;
        let Some(damping) = self.damping.as_mut() else {
            return Verdict::Stop(Termination::NoFurtherDecrease);
        };
        apply_step(
            &self.work.poses,
            &self.free,
            &self.step,
            &mut self.candidate,
        );
        let (new_cost, _) = objective(&self.work, &self.candidate, loss);
        // Decrease of F predicted by the damped quadratic model: δᵀ(λδ − g).
        let lambda = damping.lambda;
        let predicted: f64 = self
            .step
            .iter()
            .zip(&self.gradient)
            .map(|(s, g)| s * (lambda * s - g))
            .sum();
        let actual = self.cost - new_cost;
        let relative = actual / self.cost.max(f64::MIN_POSITIVE);
        if actual > 0.0 && predicted > 0.0 {
            std::mem::swap(&mut self.work.poses, &mut self.candidate);
            self.cost = new_cost;
            damping.accept(actual / predicted);
            if relative < tolerance {
                return Verdict::Stop(Termination::CostConverged);
            }
            return Verdict::Continue { relinearize: true };
        }
        // Rounding, not the model, decides the sign of a decrease this small: at the minimum already.
        if predicted < tolerance * self.cost {
            return Verdict::Stop(Termination::CostConverged);
        }
        if damping.reject() {
            Verdict::Continue { relinearize: false }
        } else {
            Verdict::Stop(Termination::NoFurtherDecrease)
        }
    }
}

/// Check the inputs and return a copy of the graph at the initial estimate chosen in `params`, and the
/// normal equations' set-up when there is anything to solve. Both start from one fill-reducing order of
/// the graph's pattern, which also says how large their factors will be: a graph whose factors would not
/// fit is refused here, before either is built. The two are then independent (the set-up depends on the
/// pattern only) and cost about the same on large graphs (on a 10⁵-vertex grid world the chordal
/// estimate 0.67 s, the set-up 0.26 s), so they run at once on two cores.
fn initial_estimate(
    graph: &PoseGraph,
    params: &SolverParams,
) -> Result<(PoseGraph, Option<BlockSystem<3>>)> {
    params.validate()?;
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
    let to_solve = work.len() >= 2 && !work.edges.is_empty();
    let ordering = to_solve
        .then(|| {
            BlockOrdering::new(
                graph.len() - 1,
                pattern(graph, &free_indices(graph)).into_iter(),
            )
        })
        .transpose()?;
    let chordal = params.initialization == Initialization::Chordal;
    // Each system's budget counts the other's factor, which is alive at the same time.
    let (solve_bytes, chordal_bytes) = match &ordering {
        Some(o) => (
            o.factor_bytes(3),
            if chordal { o.factor_bytes(2) } else { 0 },
        ),
        None => (0, 0),
    };
    let budget = |alongside_bytes| MemoryBudget {
        cap_bytes: params.max_factor_bytes,
        alongside_bytes,
    };
    budget(chordal_bytes).check(solve_bytes)?;
    let (initialized, system) = rayon::join(
        || match params.initialization {
            Initialization::Current => Ok(()),
            Initialization::Odometry => work.initialize_from_odometry(),
            Initialization::Chordal => {
                initialize_chordal_with(&mut work, ordering.as_ref(), budget(solve_bytes))
            }
        },
        || {
            ordering
                .as_ref()
                .map(|o| BlockSystem::<3>::new(o, budget(chordal_bytes)))
                .transpose()
        },
    );
    // An initialisation error (a disconnected vertex) says more than a set-up one.
    initialized?;
    Ok((work, system?))
}

/// Loop edges whose robust weight at the solution is below ½ (0 without a robust loss).
fn downweighted_loops(graph: &PoseGraph, loss: &RobustLoss) -> usize {
    if *loss == RobustLoss::None {
        return 0;
    }
    graph
        .edges
        .iter()
        .filter(|e| {
            e.kind == EdgeKind::Loop
                && loss
                    .evaluate(e.chi2(&graph.poses[e.from], &graph.poses[e.to]))
                    .1
                    < 0.5
        })
        .count()
}

/// Run the initialisation chosen in `params`, then Gauss–Newton / Levenberg–Marquardt (see the module
/// docs); the graph's poses are replaced by the solution only when the solve succeeds.
pub fn optimize(graph: &mut PoseGraph, params: &SolverParams) -> Result<SolveReport> {
    optimize_with_stop(graph, params, &mut || false)
}

/// [`optimize`] that asks `should_stop` before every iteration (on the calling thread) and, when it says
/// so, ends with [`Termination::Interrupted`], the graph at the last accepted iterate: a valid state
/// whose cost is at most the initial one (after initialisation), never a half-applied step. The
/// initialisation and each factorisation run to their end (a chordal initialisation is two linear
/// solves, about one iteration's time). A hook that does work (e.g. polling signals) should keep its
/// own clock: it is called once per iteration, which on a small graph is every few microseconds.
pub fn optimize_with_stop(
    graph: &mut PoseGraph,
    params: &SolverParams,
    should_stop: &mut dyn FnMut() -> bool,
) -> Result<SolveReport> {
    // Start: checked inputs, initial estimate on a copy.
    let (work, system) = initial_estimate(graph, params)?;
    let loss = params.robust_loss;
    let (initial_cost, initial_chi2) = objective(&work, &work.poses, &loss);
    // A vertex or measurement at an extreme value (1e300) overflows the χ²: nothing can be solved, and
    // "converged" with an infinite χ² would be a lie.
    if !initial_chi2.is_finite() {
        return Err(MapError::NonFinite {
            what:
                "the pose graph's χ² at its initial poses (a vertex or edge holds an extreme value)",
            value: initial_chi2,
        });
    }
    let (iterations, termination, work) = match system {
        None => (0, Termination::NothingToDo, work),
        Some(system) => {
            // Set up once (ordering, symbolic factorisation, buffers), then iterate.
            let mut solver = Solver::new(work, system, initial_cost, params)?;
            let (iterations, termination) = solver.run(should_stop);
            (iterations, termination, solver.work)
        }
    };
    // Report and hand the solution back.
    let (final_cost, final_chi2) = objective(&work, &work.poses, &loss);
    let report = SolveReport {
        iterations,
        initial_chi2,
        final_chi2,
        final_cost,
        converged: !matches!(
            termination,
            Termination::MaxIterations | Termination::Interrupted
        ),
        termination,
        downweighted_loops: downweighted_loops(&work, &loss),
    };
    *graph = work;
    Ok(report)
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
                        (numeric - jac[(r, k)]).abs() < 1e-5,
                        "d e{r}/d x{which}[{k}]: numeric {numeric} analytic {}",
                        jac[(r, k)]
                    );
                }
            }
        }
        let edge = crate::graph::Edge {
            from: 0,
            to: 1,
            from_from_to: z,
            information: crate::graph::isotropic_information(1.0, 1.0),
            kind: EdgeKind::Odometry,
        };
        let reference = edge.residual(&from, &to);
        for r in 0..3 {
            assert!((reference[r] - e0[r]).abs() < 1e-12);
        }
    }

    #[test]
    fn a_graph_whose_chi2_overflows_is_an_error_and_is_left_as_it_was() {
        let mut graph = PoseGraph {
            ids: vec![0, 1],
            poses: vec![Pose2::new(0.0, 0.0, 0.0), Pose2::new(1e300, 0.0, 0.0)],
            edges: Vec::new(),
            fixed: 0,
        };
        graph
            .add_edge(crate::graph::Edge {
                from: 0,
                to: 1,
                from_from_to: Pose2::new(1.0, 0.0, 0.0),
                information: crate::graph::isotropic_information(1.0, 1.0),
                kind: EdgeKind::Odometry,
            })
            .unwrap();
        let params = SolverParams {
            initialization: Initialization::Current,
            ..SolverParams::default()
        };
        let err = optimize(&mut graph, &params).unwrap_err();
        assert!(err.to_string().contains("extreme value"), "{err}");
        assert_eq!(graph.poses[1].x, 1e300);
    }

    #[test]
    fn damping_starts_undamped_falls_back_on_a_failed_step_and_shrinks_back() {
        let params = SolverParams::default();
        let mut damping = Damping::new(&params, 1e4);
        assert_eq!(damping.lambda, 0.0, "the first step is Gauss–Newton");
        damping.accept(1.0);
        assert_eq!(damping.lambda, 0.0, "good steps keep it Gauss–Newton");
        assert!(damping.reject());
        assert_eq!(damping.lambda, 1e-5 * 1e4, "a failed step falls back to LM");
        assert!(damping.reject());
        assert_eq!(
            damping.lambda,
            4e-5 * 1e4,
            "repeated failures grow it ν-fold, ν doubling"
        );
        damping.accept(1.0);
        assert!((damping.lambda - 4e-5 * 1e4 / params.max_lambda_decrease).abs() < 1e-12);
        damping.accept(0.5);
        let before = damping.lambda;
        damping.accept(0.5);
        assert_eq!(damping.lambda, before, "ρ = ½ leaves λ (Nielsen's rule)");
        for _ in 0..60 {
            if !damping.reject() {
                return;
            }
        }
        panic!("λ should exceed its bound after repeated failures");
    }

    #[test]
    fn old_parameter_files_still_read_and_bad_schedules_are_refused() {
        // A SolverParams serialised before the damping fields existed.
        let old = r#"{"max_iterations": 30, "relative_cost_tolerance": 1e-10, "gradient_tolerance": 1e-9,
            "initial_lambda_scale": 1e-5, "robust_loss": "None", "initialization": "Current"}"#;
        let params: SolverParams = serde_json::from_str(old).unwrap();
        assert_eq!(params.max_iterations, 30);
        assert_eq!(params.initial_lambda_scale, 1e-5);
        assert_eq!(
            params.max_lambda_decrease,
            SolverParams::default().max_lambda_decrease
        );
        assert!(params.validate().is_ok());
        for bad in [
            SolverParams {
                initial_lambda_scale: -1.0,
                ..Default::default()
            },
            SolverParams {
                fallback_lambda_scale: 0.0,
                ..Default::default()
            },
            SolverParams {
                max_lambda_decrease: 0.5,
                ..Default::default()
            },
            SolverParams {
                relative_cost_tolerance: f64::NAN,
                ..Default::default()
            },
        ] {
            let err = bad.validate().unwrap_err();
            assert!(matches!(err, MapError::BadParameter { .. }), "{err}");
        }
    }
}
