//! Engine benchmarks (`cargo bench -p hippo_attractor`). Criterion measures each case; the final report
//! prints the ratios that matter, measured in this same run (absolute times on shared machines are noise):
//! - the paper-size grid layer (20×20 × 7×7) recurrent input: dense weight matrix vs our fast path;
//! - one default sub-step per module, per network, and one 10 Hz frame of the whole network.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use criterion::{criterion_group, Criterion};
use hippo_attractor::reference::DenseGridWeights;
use hippo_attractor::{
    fuse_homocentric, Bump2, GridModule, GridParams, HdParams, HdRing, PlaceNetwork, PlaceParams,
    SpatialMemory, SpatialMemoryParams,
};
use std::hint::black_box;
use std::time::{Duration, Instant};

const TAU_S: f64 = 0.01;

fn paper_size(k: usize) -> GridParams {
    GridParams {
        n_theta: 20,
        n_nu: 7,
        ..GridParams::for_module(k)
    }
}

fn settled_module(p: GridParams) -> GridModule<f32> {
    let mut g = GridModule::<f32>::new(p).expect("valid benchmark parameters");
    for _ in 0..20 {
        g.step([0.005, 0.0], None, 0.025, TAU_S).expect("stable");
    }
    g
}

fn bench_paper_size_layer(c: &mut Criterion) {
    let mut group = c.benchmark_group("paper_size_grid_layer_20x20x7x7");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(8));
    let p = paper_size(1);
    let g = settled_module(p.clone());
    let m_full = g.activity();
    let dense = DenseGridWeights::<f32>::new(&p);
    let mut h = vec![0.0f32; m_full.len()];
    group.bench_function("dense_weight_matrix", |b| {
        b.iter(|| dense.apply(black_box(&m_full), &mut h))
    });
    let cell = g.cell_activity().to_vec();
    let mut out = vec![0.0f32; cell.len()];
    group.bench_function("fast_k1", |b| {
        b.iter(|| g.recurrent_input(black_box(&cell), &mut out))
    });
    let g4 = settled_module(paper_size(4));
    let cell4 = g4.cell_activity().to_vec();
    let mut out4 = vec![0.0f32; cell4.len()];
    group.bench_function("fast_k4", |b| {
        b.iter(|| g4.recurrent_input(black_box(&cell4), &mut out4))
    });
    group.finish();
}

fn bench_substeps(c: &mut Criterion) {
    let mut group = c.benchmark_group("default_substep");
    group.sample_size(20);
    for k in [1usize, 2, 4] {
        let mut g = settled_module(GridParams::for_module(k));
        group.bench_function(format!("grid_k{k}"), |b| {
            b.iter(|| g.step([0.005, 0.001], None, 0.025, TAU_S).expect("stable"))
        });
    }
    let mut hd = HdRing::<f32>::new(HdParams::default()).expect("valid");
    group.bench_function("hd_ring", |b| {
        b.iter(|| hd.step(0.001, None, 0.025, TAU_S).expect("stable"))
    });
    let mut place = PlaceNetwork::<f32>::new(PlaceParams::default()).expect("valid");
    group.bench_function("place", |b| {
        b.iter(|| place.step(0.025, TAU_S).expect("stable"))
    });
    group.finish();
}

fn bench_frame(c: &mut Criterion) {
    let mut group = c.benchmark_group("frame_10hz");
    group.sample_size(20);
    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).expect("valid");
    group.bench_function("spatial_memory_default", |b| {
        b.iter(|| sm.step(0.2, 12.0, 0.1, None).expect("stable"))
    });
    // The first second of a run: after a reset most units are inhibited and decay towards silence (see
    // `dynamics::SILENT_BELOW`: through the subnormal numbers, these ten frames took about ten times as long).
    group.sample_size(10);
    group.bench_function("first_frames_after_reset", |b| {
        b.iter_batched(
            || SpatialMemory::<f32>::new(SpatialMemoryParams::default()).expect("valid"),
            |mut fresh| {
                for _ in 0..10 {
                    fresh.step(0.2, 12.0, 0.1, None).expect("stable");
                }
                fresh
            },
            criterion::BatchSize::LargeInput,
        )
    });
    group.finish();
}

fn bench_fusion(c: &mut Criterion) {
    let b = |m: f64, s: f64| Bump2 {
        mean_rad: [m, m],
        std_rad: [s, s],
        mass: 1.0,
    };
    let coarse = vec![b(1.0, 1.5)];
    let mid: Vec<Bump2> = (0..4).map(|i| b(1.0 + i as f64 * 1.5, 0.5)).collect();
    let fine: Vec<Bump2> = (0..16).map(|i| b(1.0 + i as f64 * 0.4, 0.2)).collect();
    c.bench_function("fuse_homocentric_1_4_16", |bch| {
        bch.iter(|| fuse_homocentric(black_box(&[&coarse, &mid, &fine]), None).expect("fusable"))
    });
}

/// Median wall time of `f` over `n` runs.
fn median(n: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..n)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[n / 2]
}

/// Ratios measured back to back in this run.
fn ratio_report() {
    let p = paper_size(1);
    let g = settled_module(p.clone());
    let m_full = g.activity();
    let dense = DenseGridWeights::<f32>::new(&p);
    let mut h = vec![0.0f32; m_full.len()];
    let t_dense = median(7, || dense.apply(&m_full, &mut h));
    let cell = g.cell_activity().to_vec();
    let mut out = vec![0.0f32; cell.len()];
    let t_fast = median(51, || g.recurrent_input(&cell, &mut out));
    println!("\n== ratio report (same run) ==");
    println!(
        "paper-size grid layer (20x20x7x7, k=1): dense matrix / fast path = {:.0}x",
        t_dense / t_fast
    );

    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).expect("valid");
    let t_frame = median(21, || {
        sm.step(0.2, 12.0, 0.1, None).expect("stable");
    });
    let subs = sm.substeps_for(0.1).0;
    println!(
        "default frame (4 sub-steps): {:.2} of the 100 ms camera period",
        t_frame / 0.1
    );
    let mut parts = vec![];
    for k in [1usize, 2, 4] {
        let mut g = settled_module(GridParams::for_module(k));
        let t = median(21, || {
            g.step([0.005, 0.001], None, 0.025, TAU_S).expect("stable")
        });
        parts.push((format!("grid k={k}"), t));
    }
    let mut hd = HdRing::<f32>::new(HdParams::default()).expect("valid");
    parts.push((
        "hd ring".into(),
        median(51, || hd.step(0.001, None, 0.025, TAU_S).expect("stable")),
    ));
    let mut place = PlaceNetwork::<f32>::new(PlaceParams::default()).expect("valid");
    parts.push((
        "place".into(),
        median(51, || place.step(0.025, TAU_S).expect("stable")),
    ));
    for (name, t) in parts {
        println!(
            "  per sub-step {name:>9}: {:5.1} % of a frame (x{subs} sub-steps per frame)",
            100.0 * t / t_frame
        );
    }
}

criterion_group!(
    benches,
    bench_paper_size_layer,
    bench_substeps,
    bench_frame,
    bench_fusion
);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    ratio_report();
}
