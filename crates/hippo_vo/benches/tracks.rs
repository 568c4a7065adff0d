//! Cost of refining KLT matches with a warped window (criterion; `make bench`): 1 000 matches on a
//! KITTI-size textured image pair, 15 px windows as the VO uses there. The affine warp (temporal tracks)
//! and the row shear (stereo) are timed in the same run, each also sampling one window pixel at a time
//! (`…_one_by_one`, the baseline of the eight-lane sampling); compare them as ratios (absolute times on a
//! shared machine are noise). Benches may unwrap.
#![allow(clippy::unwrap_used)]
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use hippo_attractor::{SpatialMemory, SpatialMemoryParams};
use hippo_vo::{refine_matches, GrayImage, RefineParams, Sampling, WarpModel};

const WIDTH: usize = 1241;
const HEIGHT: usize = 376;

/// A smooth texture seen through `warp` (pixel → texture position).
fn image(warp: impl Fn(f64, f64) -> (f64, f64)) -> Vec<u8> {
    let mut out = Vec::with_capacity(WIDTH * HEIGHT);
    for v in 0..HEIGHT {
        for u in 0..WIDTH {
            let (x, y) = warp(u as f64, v as f64);
            let t = 128.0
                + 30.0 * (0.17 * x + 0.09 * y).sin()
                + 25.0 * (-0.11 * x + 0.23 * y + 1.0).sin()
                + 20.0 * (0.29 * x - 0.13 * y + 2.0).sin();
            out.push(t.round().clamp(0.0, 255.0) as u8);
        }
    }
    out
}

fn refine(c: &mut Criterion) {
    let first = image(|u, v| (u, v));
    // The second image: expanded about the image centre by 2 % (a step forward) and, for the stereo
    // pair, shifted by a disparity that grows down the image.
    let expanded = image(|u, v| (620.0 + (u - 620.0) / 1.02, 180.0 + (v - 180.0) / 1.02));
    let right = image(|u, v| (u + 20.0 + 0.05 * (v - 180.0), v));
    let (a, b, r) = (
        GrayImage::new(&first, WIDTH, HEIGHT).unwrap(),
        GrayImage::new(&expanded, WIDTH, HEIGHT).unwrap(),
        GrayImage::new(&right, WIDTH, HEIGHT).unwrap(),
    );
    let points: Vec<[f64; 2]> = (0..1000)
        .map(|i| {
            [
                20.0 + (i % 40) as f64 * 30.0 + 0.3,
                20.0 + (i / 40) as f64 * 13.0 + 0.6,
            ]
        })
        .collect();
    let tracked: Vec<[f64; 2]> = points
        .iter()
        .map(|p| {
            [
                620.0 + (p[0] - 620.0) * 1.02 + 0.2,
                180.0 + (p[1] - 180.0) * 1.02 - 0.2,
            ]
        })
        .collect();
    let stereo: Vec<[f64; 2]> = points
        .iter()
        .map(|p| [p[0] - 20.0 - 0.05 * (p[1] - 180.0) + 0.2, p[1]])
        .collect();
    let params = RefineParams::default();
    let mut group = c.benchmark_group("refine_1000_matches");
    group.bench_function("affine", |bench| {
        bench
            .iter(|| refine_matches(&a, &b, &points, &tracked, WarpModel::Affine, &params).unwrap())
    });
    let mut engine = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    group.bench_function("affine_after_engine_step", |bench| {
        bench.iter_batched(
            || engine.step(0.2, 12.0, 0.1, None).unwrap(),
            |_| refine_matches(&a, &b, &points, &tracked, WarpModel::Affine, &params).unwrap(),
            BatchSize::PerIteration,
        )
    });
    group.bench_function("row_shear", |bench| {
        bench.iter(|| {
            refine_matches(&a, &r, &points, &stereo, WarpModel::RowShear, &params).unwrap()
        })
    });
    // The same refinements sampling one window pixel at a time (CPUs without AVX2): the baseline of the
    // eight-lane sampling, the same results bit for bit.
    let one_by_one = RefineParams {
        sampling: Sampling::OneByOne,
        ..params
    };
    group.bench_function("affine_one_by_one", |bench| {
        bench.iter(|| {
            refine_matches(&a, &b, &points, &tracked, WarpModel::Affine, &one_by_one).unwrap()
        })
    });
    group.bench_function("row_shear_one_by_one", |bench| {
        bench.iter(|| {
            refine_matches(&a, &r, &points, &stereo, WarpModel::RowShear, &one_by_one).unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, refine);
criterion_main!(benches);
