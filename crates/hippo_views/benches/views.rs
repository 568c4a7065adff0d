//! Matching time against the number of stored templates (1 000 and 10 000), pruned search vs the plain
//! brute-force reference measured in the same run. Templates are random smooth textures, and the query is
//! a slightly shifted, noisy copy of one of them (a revisit), as in a loop.
// A benchmark: a panic is the run failing (library code never panics on data, see Cargo.toml).
#![allow(clippy::panic)]
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hippo_views::words::{ratio_test_matches, ratio_test_matches_one_by_one, Descriptor};
use hippo_views::{ViewCellParams, ViewCells};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

fn random_template(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.5f32..1.5)).collect()
}

fn bench_matching(c: &mut Criterion) {
    let params = ViewCellParams::default();
    let n = params.template_len();
    let mut group = c.benchmark_group("view_match");
    group.sample_size(10);
    for count in [1_000usize, 10_000] {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut cells = match ViewCells::new(params.clone()) {
            Ok(c) => c,
            Err(e) => panic!("default parameters rejected: {e}"),
        };
        for _ in 0..count {
            let t = random_template(&mut rng, n);
            if let Err(e) = cells.add(&t) {
                panic!("{e}");
            }
        }
        let target = count / 3;
        let w = params.width_px;
        let stored = cells
            .template(target)
            .map(|t| t.to_vec())
            .unwrap_or_default();
        // Query = stored template shifted right by 3 columns plus noise.
        let query: Vec<f32> = (0..n)
            .map(|i| {
                let (r, x) = (i / w, i % w);
                let v = if x >= 3 { stored[r * w + x - 3] } else { 0.0 };
                v + rng.random_range(-0.2f32..0.2)
            })
            .collect();
        group.bench_with_input(BenchmarkId::new("pruned", count), &query, |b, q| {
            b.iter(|| black_box(cells.best_match(q)))
        });
        group.bench_with_input(BenchmarkId::new("brute_force", count), &query, |b, q| {
            b.iter(|| black_box(cells.best_match_brute_force(q)))
        });
    }
    group.finish();
}

/// The word cells' verification matching: 500 query descriptors (the default `orb_features`) against a
/// stored view's 500, Lowe's ratio test. What it replaced (OpenCV's `knnMatch` and a ratio test in Python) is
/// measured against it in the same run by `tests/benchmarks/test_word_matching_bench.py`.
fn bench_ratio_matches(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut random = |n: usize| -> Vec<Descriptor> {
        (0..n)
            .map(|_| {
                let mut d = [0u8; 32];
                rng.fill(&mut d[..]);
                d
            })
            .collect()
    };
    let (query, stored) = (random(500), random(500));
    c.bench_function("word_ratio_matches_500x500", |b| {
        b.iter(|| black_box(ratio_test_matches(&query, &stored, 0.8)))
    });
    // The baseline in the same run: one stored descriptor at a time (the build before the eight-lane one; the
    // same build where the CPU lacks AVX-512's popcount).
    c.bench_function("word_ratio_matches_500x500_one_by_one", |b| {
        b.iter(|| black_box(ratio_test_matches_one_by_one(&query, &stored, 0.8)))
    });
}

criterion_group!(benches, bench_matching, bench_ratio_matches);
criterion_main!(benches);
