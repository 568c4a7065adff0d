//! Chordal initialisation of a pose graph (rotations first, then translations), both linear.
//!
//! 1. Rotations. Write each yaw as the unit complex number `z_i = (cos θ_i, sin θ_i)`. An edge says
//!    `z_j = z_ij · z_i`, which is linear in the unknowns, so `min Σ κ |z_j − z_ij z_i|²` (κ = Ω_yaw,yaw,
//!    the fixed vertex held at its yaw) is a sparse linear least-squares problem with 2×2 blocks. Its
//!    solution is projected back onto the circle, `θ_i = atan2(s_i, c_i)`. Relaxing `|z| = 1` makes the
//!    problem convex, and its minimiser is close to the global optimum on real graphs (Carlone et al.,
//!    "Initialization techniques for 3D SLAM", ICRA 2015), whereas chaining odometry accumulates drift
//!    that can leave Gauss–Newton in a poor local minimum.
//! 2. Translations. With yaws fixed, each edge residual `R_zᵀ(R_iᵀ(t_j − t_i) − t_z)` is linear in the
//!    positions: one more sparse least-squares solve with 2×2 blocks, weighted by `Ω_tt`.
//!
//! Both systems are assembled as normal equations and factorised with faer's sparse Cholesky.
use crate::error::{MapError, Result};
use crate::graph::PoseGraph;
use crate::memory::MemoryBudget;
use crate::se2::Pose2;
use crate::sparse::{BlockOrdering, BlockSystem};

/// Free (non-fixed) vertex index of every vertex; `None` for the fixed one.
pub(crate) fn free_indices(graph: &PoseGraph) -> Vec<Option<usize>> {
    let mut next = 0;
    (0..graph.len())
        .map(|v| {
            if v == graph.fixed {
                None
            } else {
                next += 1;
                Some(next - 1)
            }
        })
        .collect()
}

/// The (free, free) vertex pairs that edges couple: the block pattern of the normal equations.
pub(crate) fn pattern(graph: &PoseGraph, free: &[Option<usize>]) -> Vec<(usize, usize)> {
    graph
        .edges
        .iter()
        .filter_map(|e| Some((free[e.from]?, free[e.to]?)))
        .collect()
}

#[inline]
fn mat2_mul(a: &[[f64; 2]; 2], b: &[[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let mut out = [[0.0; 2]; 2];
    for r in 0..2 {
        for c in 0..2 {
            out[r][c] = a[r][0] * b[0][c] + a[r][1] * b[1][c];
        }
    }
    out
}

#[inline]
fn transpose2(a: &[[f64; 2]; 2]) -> [[f64; 2]; 2] {
    [[a[0][0], a[1][0]], [a[0][1], a[1][1]]]
}

#[inline]
fn mat2_vec(a: &[[f64; 2]; 2], v: [f64; 2]) -> [f64; 2] {
    [
        a[0][0] * v[0] + a[0][1] * v[1],
        a[1][0] * v[0] + a[1][1] * v[1],
    ]
}

#[inline]
fn rotation(yaw: f64) -> [[f64; 2]; 2] {
    let (s, c) = yaw.sin_cos();
    [[c, -s], [s, c]]
}

fn scaled(a: &[[f64; 2]; 2], k: f64) -> [[f64; 2]; 2] {
    [[a[0][0] * k, a[0][1] * k], [a[1][0] * k, a[1][1] * k]]
}

/// Replace the graph's poses by the chordal estimate (the fixed vertex keeps its pose). A graph whose
/// factorisation would not fit in the memory available is refused ([`MapError::FactorTooLarge`]).
pub fn initialize_chordal(graph: &mut PoseGraph) -> Result<()> {
    initialize_chordal_with(graph, None, MemoryBudget::default())
}

/// [`initialize_chordal`] with the elimination order of the graph's pattern when the caller has it (the
/// solve's, which is the same) and the memory the factorisation may take.
pub(crate) fn initialize_chordal_with(
    graph: &mut PoseGraph,
    ordering: Option<&BlockOrdering>,
    budget: MemoryBudget,
) -> Result<()> {
    if graph.is_empty() {
        return Err(MapError::EmptyGraph);
    }
    // Disconnected vertices would make the systems singular: report them by name instead.
    let mut probe = graph.clone();
    probe.initialize_from_odometry()?;
    let free = free_indices(graph);
    let n_free = graph.len() - 1;
    if n_free == 0 {
        return Ok(());
    }
    let own_ordering;
    let ordering = match ordering {
        Some(ordering) => ordering,
        None => {
            own_ordering = BlockOrdering::new(n_free, pattern(graph, &free).into_iter())?;
            &own_ordering
        }
    };
    let fixed_pose = graph.poses[graph.fixed];

    // Step 1: rotations as unit complex numbers.
    let mut system = BlockSystem::<2>::new(ordering, budget)?;
    let mut rhs = vec![0.0; 2 * n_free];
    let z_fixed = [fixed_pose.yaw.cos(), fixed_pose.yaw.sin()];
    for e in &graph.edges {
        let kappa = e.information[2][2];
        // z_j − M z_i with M = multiplication by z_ij.
        let m = rotation(e.from_from_to.yaw);
        let mt = transpose2(&m);
        let identity_k = [[kappa, 0.0], [0.0, kappa]];
        match (free[e.from], free[e.to]) {
            (Some(i), Some(j)) => {
                system.add_block(i, i, &identity_k);
                system.add_block(j, j, &identity_k);
                system.add_block(i, j, &scaled(&mt, -kappa));
            }
            (None, Some(j)) => {
                system.add_block(j, j, &identity_k);
                let b = mat2_vec(&m, z_fixed);
                rhs[2 * j] += kappa * b[0];
                rhs[2 * j + 1] += kappa * b[1];
            }
            (Some(i), None) => {
                system.add_block(i, i, &identity_k);
                let b = mat2_vec(&mt, z_fixed);
                rhs[2 * i] += kappa * b[0];
                rhs[2 * i + 1] += kappa * b[1];
            }
            (None, None) => {}
        }
    }
    system.solve_damped(0.0, &mut rhs)?;
    let mut yaw = vec![fixed_pose.yaw; graph.len()];
    for (v, f) in free.iter().enumerate() {
        if let Some(i) = f {
            yaw[v] = rhs[2 * i + 1].atan2(rhs[2 * i]);
        }
    }

    // Step 2: translations with the yaws held.
    system.clear();
    let mut rhs = vec![0.0; 2 * n_free];
    let t_fixed = [fixed_pose.x, fixed_pose.y];
    for e in &graph.edges {
        let omega = [
            [e.information[0][0], e.information[0][1]],
            [e.information[1][0], e.information[1][1]],
        ];
        // r = A t_j − A t_i − R_zᵀ t_z with A = R_zᵀ R_iᵀ.
        let rzt = transpose2(&rotation(e.from_from_to.yaw));
        let a = mat2_mul(&rzt, &transpose2(&rotation(yaw[e.from])));
        let at_omega = mat2_mul(&transpose2(&a), &omega);
        let h = mat2_mul(&at_omega, &a);
        let mut constant = mat2_vec(&rzt, [e.from_from_to.x, e.from_from_to.y]);
        constant = [-constant[0], -constant[1]];
        match (free[e.from], free[e.to]) {
            (Some(i), Some(j)) => {
                system.add_block(i, i, &h);
                system.add_block(j, j, &h);
                system.add_block(i, j, &scaled(&h, -1.0));
                // rhs_i = +Aᵀ Ω c, rhs_j = −Aᵀ Ω c (from −J_kᵀ Ω c with J_i = −A, J_j = A).
                let g = mat2_vec(&at_omega, constant);
                rhs[2 * i] += g[0];
                rhs[2 * i + 1] += g[1];
                rhs[2 * j] -= g[0];
                rhs[2 * j + 1] -= g[1];
            }
            (None, Some(j)) => {
                let at = mat2_vec(&a, t_fixed);
                let c = [constant[0] - at[0], constant[1] - at[1]];
                system.add_block(j, j, &h);
                let g = mat2_vec(&at_omega, c);
                rhs[2 * j] -= g[0];
                rhs[2 * j + 1] -= g[1];
            }
            (Some(i), None) => {
                let at = mat2_vec(&a, t_fixed);
                let c = [constant[0] + at[0], constant[1] + at[1]];
                system.add_block(i, i, &h);
                let g = mat2_vec(&at_omega, c);
                rhs[2 * i] += g[0];
                rhs[2 * i + 1] += g[1];
            }
            (None, None) => {}
        }
    }
    system.solve_damped(0.0, &mut rhs)?;
    for (v, f) in free.iter().enumerate() {
        graph.poses[v] = match f {
            Some(i) => Pose2::new(rhs[2 * i], rhs[2 * i + 1], yaw[v]),
            None => fixed_pose,
        };
    }
    Ok(())
}
