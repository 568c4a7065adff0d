use criterion::{criterion_group, criterion_main, Criterion};
use hippo_attractor::{fuse_homocentric, Bump2};
use std::hint::black_box;

fn bench_fusion(c: &mut Criterion) {
    let b = |m: f64, s: f64| Bump2 { mean_rad: [m, m], std_rad: [s, s], mass: 1.0 };
    let coarse = vec![b(1.0, 1.5)];
    let mid: Vec<Bump2> = (0..4).map(|i| b(1.0 + i as f64 * 1.5, 0.5)).collect();
    let fine: Vec<Bump2> = (0..16).map(|i| b(1.0 + i as f64 * 0.4, 0.2)).collect();
    c.bench_function("fuse_homocentric_1_4_16", |bch| {
        bch.iter(|| fuse_homocentric(black_box(&[&coarse, &mid, &fine]), None).unwrap())
    });
}

criterion_group!(benches, bench_fusion);
criterion_main!(benches);
