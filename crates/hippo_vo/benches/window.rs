//! Cost of one keyframe of the VO's windowed refinement (criterion; `make bench`): a simulated street,
//! about 1 000 stereo observations per keyframe as on KITTI, the window full. Windows of 4, 8 and 15
//! keyframes are timed in the same run; compare them as ratios (absolute times on a shared machine are
//! noise). Benches may unwrap.
#![allow(clippy::unwrap_used)]
#[path = "../tests/common/mod.rs"]
mod common;

use common::{camera, observe, rng, street, truth};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use hippo_vo::{SlidingWindow, WindowParams};
use nalgebra::Isometry3;

fn keyframe(c: &mut Criterion) {
    let mut generator = rng(11);
    let points = street(&mut generator);
    let frames: Vec<_> = (0..40)
        .map(|k| observe(&mut generator, &points, &truth(k), 0.5))
        .collect();
    let mut group = c.benchmark_group("window_keyframe");
    for size in [4usize, 8, 15] {
        let params = WindowParams {
            max_keyframes: size,
            ..WindowParams::default()
        };
        let mut window = SlidingWindow::new(camera(), params).unwrap();
        for (k, obs) in frames.iter().enumerate().take(size) {
            window.add_keyframe(truth(k), obs).unwrap();
        }
        let k = size;
        let guess = Isometry3::translation(0.05, 0.0, 0.1) * truth(k);
        group.bench_with_input(BenchmarkId::from_parameter(size), &size, |b, _| {
            b.iter_batched(
                || window.clone(),
                |mut w| w.add_keyframe(guess, &frames[k]).unwrap(),
                criterion::BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, keyframe);
criterion_main!(benches);
