//! Long corrections end when the caller's stop hook says so, at a valid state; graphs whose factorisation
//! would not fit in memory are refused before it is allocated.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use hippo_map::{
    isotropic_information, optimize, optimize_with_stop, relax, relax_with_stop, Corrector, Edge,
    EdgeKind, ExperienceMap, Initialization, Link, MapError, MapParams, Pose2, PoseGraph,
    RelaxationParams, SolverParams, Termination, Vertex,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A hook that says "stop" from its `k + 1`-th call on, counting its calls.
fn stop_after(k: usize, calls: &mut usize) -> impl FnMut() -> bool + '_ {
    move || {
        *calls += 1;
        *calls > k
    }
}

fn odometry_start() -> SolverParams {
    SolverParams {
        initialization: Initialization::Odometry,
        relative_cost_tolerance: 1e-12,
        ..SolverParams::default()
    }
}

#[test]
fn a_stop_hook_ends_the_solve_at_the_last_accepted_iterate() {
    let (_, graph) = common::manhattan_world(3000, 1.0, 2, 5);
    let params = odometry_start();
    let full = optimize(&mut graph.clone(), &params).unwrap();
    assert!(full.iterations >= 3, "{full:?}");
    for k in 0..full.iterations {
        let mut interrupted = graph.clone();
        let mut calls = 0;
        let report =
            optimize_with_stop(&mut interrupted, &params, &mut stop_after(k, &mut calls)).unwrap();
        assert_eq!(report.termination, Termination::Interrupted);
        assert!(!report.converged);
        assert_eq!(report.iterations, k);
        assert_eq!(calls, k + 1, "asked once per iteration");
        assert!(report.final_cost <= report.initial_chi2, "{report:?}");
        assert_eq!(interrupted.chi2(), report.final_chi2, "the graph holds it");
        assert!(interrupted.poses.iter().all(Pose2::is_finite));
        // The same iterate as a solve limited to k iterations.
        let mut limited = graph.clone();
        optimize(
            &mut limited,
            &SolverParams {
                max_iterations: k,
                ..params
            },
        )
        .unwrap();
        assert_eq!(limited.poses, interrupted.poses, "k = {k}");
    }
}

#[test]
fn a_stop_hook_ends_relaxation_after_whole_passes() {
    let (_, graph) = common::manhattan_world(500, 1.0, 2, 6);
    let params = RelaxationParams {
        gain: 0.5,
        passes: 50,
    };
    let mut interrupted = graph.clone();
    let mut calls = 0;
    let report =
        relax_with_stop(&mut interrupted, &params, &mut stop_after(7, &mut calls)).unwrap();
    assert!(report.interrupted);
    assert_eq!(report.passes, 7);
    let mut seven = graph.clone();
    let plain = relax(
        &mut seven,
        &RelaxationParams {
            passes: 7,
            ..params
        },
    )
    .unwrap();
    assert!(!plain.interrupted);
    assert_eq!(seven.poses, interrupted.poses);
}

/// The experience map built from a grid world's graph.
fn map_of(graph: &PoseGraph) -> ExperienceMap {
    let mut map = ExperienceMap::new(MapParams::default()).unwrap();
    for (i, pose) in graph.poses.iter().enumerate() {
        map.add_vertex(Vertex {
            view_cell_id: i as u64,
            place_code_rad: [0.0, 0.0],
            heading_code_rad: 0.0,
            world_from_vertex: *pose,
            odometer_m: i as f64,
        })
        .unwrap();
    }
    for e in &graph.edges {
        map.add_link(Link {
            from: e.from,
            to: e.to,
            from_from_to: e.from_from_to,
            elapsed_s: 1.0,
            kind: e.kind,
            information: e.information,
        })
        .unwrap();
    }
    map
}

#[test]
fn a_stop_hook_ends_a_map_correction_with_either_corrector() {
    let (_, graph) = common::manhattan_world(2000, 1.0, 2, 7);
    let initial_chi2 = graph.chi2();
    let mut map = map_of(&graph);
    let mut calls = 0;
    let report = map
        .correct_with_stop(
            &Corrector::LeastSquares(ExperienceMap::default_least_squares()),
            &mut stop_after(1, &mut calls),
        )
        .unwrap();
    assert!(report.interrupted && !report.converged, "{report:?}");
    assert_eq!(report.iterations, 1);
    assert!(report.final_chi2 < initial_chi2);
    assert_eq!(map.pose_graph().chi2(), report.final_chi2);

    let mut map = map_of(&graph);
    let mut calls = 0;
    let report = map
        .correct_with_stop(
            &Corrector::Relaxation(RelaxationParams::default()),
            &mut stop_after(3, &mut calls),
        )
        .unwrap();
    assert!(report.interrupted && report.iterations == 3, "{report:?}");
    let done = map_of(&graph)
        .correct(&Corrector::Relaxation(RelaxationParams::default()))
        .unwrap();
    assert!(!done.interrupted && done.iterations == 100);
}

/// A chain of `n` vertices plus `loops` closures between random far-apart vertices: the closures fill
/// the factor in until it is nearly dense.
fn long_loops(n: usize, loops: usize, seed: u64) -> PoseGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let info = isotropic_information(0.1, 0.01);
    let mut graph = PoseGraph::new();
    for i in 0..n {
        graph.add_vertex(Pose2::new(i as f64, 0.0, 0.0)).unwrap();
    }
    let mut edge = |from: usize, to: usize, kind| {
        graph
            .add_edge(Edge {
                from,
                to,
                from_from_to: Pose2::new(to as f64 - from as f64, 0.0, 0.0),
                information: info,
                kind,
            })
            .unwrap();
    };
    for i in 1..n {
        edge(i - 1, i, EdgeKind::Odometry);
    }
    for _ in 0..loops {
        let (a, b) = (rng.random_range(0..n), rng.random_range(0..n));
        if a.abs_diff(b) > 1 {
            edge(a, b, EdgeKind::Loop);
        }
    }
    graph
}

#[test]
fn a_factor_over_the_cap_is_refused_naming_its_size_and_the_graph_is_left_as_it_was() {
    let graph = long_loops(3000, 6000, 8);
    for initialization in [Initialization::Chordal, Initialization::Current] {
        let mut work = graph.clone();
        let err = optimize(
            &mut work,
            &SolverParams {
                initialization,
                max_factor_bytes: Some(10_000_000),
                ..SolverParams::default()
            },
        )
        .unwrap_err();
        let MapError::FactorTooLarge {
            needed_bytes,
            limit_bytes,
            ..
        } = err
        else {
            panic!("expected FactorTooLarge, got {err}");
        };
        // A chain's factor would hold 3000 · (9 + 6) entries, 0.36 MB; the long closures make it 47 MB
        // (68 MB with the chordal initialisation's alongside).
        assert!(needed_bytes > 40_000_000, "{needed_bytes}");
        assert_eq!(limit_bytes, 10_000_000);
        let message = err_message(&mut graph.clone(), initialization);
        for expected in [
            needed_bytes.to_string().as_str(),
            "10000000 bytes",
            "max_factor_bytes",
            "relaxation",
            "loop closures",
        ] {
            assert!(message.contains(expected), "{expected:?} in {message}");
        }
        assert_eq!(work, graph);
    }
    // The same graph solves under a cap that fits it.
    let mut work = graph.clone();
    let report = optimize(
        &mut work,
        &SolverParams {
            initialization: Initialization::Current,
            max_factor_bytes: Some(u64::MAX),
            ..SolverParams::default()
        },
    )
    .unwrap();
    assert!(report.converged);
}

fn err_message(graph: &mut PoseGraph, initialization: Initialization) -> String {
    optimize(
        graph,
        &SolverParams {
            initialization,
            max_factor_bytes: Some(10_000_000),
            ..SolverParams::default()
        },
    )
    .unwrap_err()
    .to_string()
}

/// The chordal initialisation's factor (2×2 blocks, 4/9 of the solve's 3×3 one) is built at the same
/// time as the solve's, so a chordal start counts both against the cap.
#[test]
fn the_chordal_factor_counts_against_the_cap() {
    let graph = long_loops(600, 600, 9);
    let needed = |initialization| match optimize(
        &mut graph.clone(),
        &SolverParams {
            initialization,
            max_factor_bytes: Some(0),
            ..SolverParams::default()
        },
    ) {
        Err(MapError::FactorTooLarge { needed_bytes, .. }) => needed_bytes as f64,
        other => panic!("{other:?}"),
    };
    let ratio = needed(Initialization::Chordal) / needed(Initialization::Current);
    assert!((1.3..1.5).contains(&ratio), "{ratio}");
}
