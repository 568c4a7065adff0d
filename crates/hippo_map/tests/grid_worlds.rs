//! The damping schedule on synthetic grid worlds (Manhattan random walks with closures, as in the
//! benchmark): Gauss–Newton first reaches the same optimum as the earlier damped schedule in
//! a fraction of the iterations, also at 10⁵ vertices, where the damped schedule needed 15.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use hippo_map::{optimize, Initialization, SolverParams, Termination};

#[test]
fn grid_world_of_10000_vertices_same_optimum_as_the_damped_schedule_in_fewer_iterations() {
    let (_, graph) = common::manhattan_world(10_000, 1.0, 2, 11);
    let tight = SolverParams {
        relative_cost_tolerance: 1e-10,
        ..SolverParams::default()
    };
    let damped_params = SolverParams {
        initial_lambda_scale: 1e-5,
        max_lambda_decrease: 3.0,
        ..tight
    };
    for initialization in [Initialization::Chordal, Initialization::Odometry] {
        let mut undamped = graph.clone();
        let new = optimize(
            &mut undamped,
            &SolverParams {
                initialization,
                ..tight
            },
        )
        .unwrap();
        let mut damped = graph.clone();
        let old = optimize(
            &mut damped,
            &SolverParams {
                initialization,
                ..damped_params
            },
        )
        .unwrap();
        eprintln!(
            "grid 10⁴ from {initialization:?}: Gauss–Newton first χ² {:.6} in {} its; damped χ² {:.6} in {} its",
            new.final_chi2, new.iterations, old.final_chi2, old.iterations
        );
        assert!(new.converged && old.converged);
        assert!(
            (new.final_chi2 - old.final_chi2).abs() < 1e-8 * old.final_chi2,
            "{new:?} vs {old:?}"
        );
        assert!(
            2 * new.iterations < old.iterations,
            "{} vs {} iterations",
            new.iterations,
            old.iterations
        );
    }
}

#[test]
fn grid_world_of_100000_vertices_converges_in_a_few_gauss_newton_steps() {
    let (_, graph) = common::manhattan_world(100_000, 1.0, 2, 11);
    let mut solved = graph.clone();
    let report = optimize(&mut solved, &SolverParams::default()).unwrap();
    // Polishing the solution at a far tighter tolerance must not find anything left to gain.
    let mut polished = solved.clone();
    let polish = optimize(
        &mut polished,
        &SolverParams {
            initialization: Initialization::Current,
            relative_cost_tolerance: 1e-12,
            ..SolverParams::default()
        },
    )
    .unwrap();
    eprintln!(
        "grid 10⁵ ({} edges) from chordal: χ² {:.4e} -> {:.6e} in {} its ({:?}); polished {:.6e}",
        graph.edges.len(),
        report.initial_chi2,
        report.final_chi2,
        report.iterations,
        report.termination,
        polish.final_chi2
    );
    assert_eq!(report.termination, Termination::CostConverged);
    assert!(
        report.iterations <= 4,
        "{} iterations (the damped schedule needed 15)",
        report.iterations
    );
    assert!((report.final_chi2 - polish.final_chi2).abs() < 1e-9 * report.final_chi2);
}
