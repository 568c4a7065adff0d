//! One map correction at 1 000, 10 000 and 100 000 vertices: the exact sparse least-squares solve
//! (chordal initialisation + Levenberg–Marquardt to convergence) against RatSLAM relaxation passes on the
//! same Manhattan-world graphs (unit grid random walk, closures to earlier poses within 1 m).
//! Before timing, each size prints χ² after the exact solve and after 1, 10 and 100 relaxation passes,
//! so speed and quality can be read side by side.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hippo_map::{optimize, relax, RelaxationParams, SolverParams};
use std::hint::black_box;

fn correction(c: &mut Criterion) {
    let mut group = c.benchmark_group("correction");
    group.sample_size(10);
    for n in [1_000usize, 10_000, 100_000] {
        let (_, graph) = common::manhattan_world(n, 1.0, 2, 11);
        let mut solved = graph.clone();
        let report =
            optimize(&mut solved, &SolverParams::default()).expect("benchmark graph solves");
        let mut line = format!(
            "n={n} edges={} dead-reckoning χ²={:.3e}; exact χ²={:.4e} ({} its)",
            graph.edges.len(),
            graph.chi2(),
            report.final_chi2,
            report.iterations
        );
        for passes in [1usize, 10, 100] {
            let mut relaxed = graph.clone();
            let r = relax(&mut relaxed, &RelaxationParams { gain: 0.5, passes })
                .expect("relaxation runs");
            line += &format!("; relaxation×{passes} χ²={:.4e}", r.final_chi2);
        }
        eprintln!("{line}");
        group.bench_with_input(BenchmarkId::new("least_squares", n), &graph, |b, g| {
            b.iter(|| {
                let mut work = g.clone();
                black_box(optimize(&mut work, &SolverParams::default()).expect("solves"))
            })
        });
        group.bench_with_input(BenchmarkId::new("relaxation_1_pass", n), &graph, |b, g| {
            b.iter(|| {
                let mut work = g.clone();
                black_box(
                    relax(
                        &mut work,
                        &RelaxationParams {
                            gain: 0.5,
                            passes: 1,
                        },
                    )
                    .expect("runs"),
                )
            })
        });
    }
    group.finish();
}

criterion_group!(benches, correction);
criterion_main!(benches);
