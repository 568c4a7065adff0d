//! The fast recurrent inputs (rank-2 ring, per-slice FFT + factored velocity mixing torus, FFT place) equal
//! the dense double sums over the weight formulas, at sizes where the dense sum is cheap.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hippo_attractor::reference;
use hippo_attractor::{GridModule, GridParams, HdParams, HdRing, PlaceNetwork, PlaceParams};

/// Deterministic pseudo-random activity with some exact zeros (silent units and silent velocity slices).
fn activity(len: usize, seed: u64, zero_every: usize) -> Vec<f64> {
    let mut x = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..len)
        .map(|i| {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let v = (x >> 11) as f64 / (1u64 << 53) as f64;
            if i % zero_every == 0 || v < 0.3 {
                0.0
            } else {
                v
            }
        })
        .collect()
}

/// Largest difference between a double-precision reference and a single-precision result.
fn max_abs_diff_f32(reference: &[f64], single: &[f32]) -> f64 {
    let widened: Vec<f64> = single.iter().map(|&x| f64::from(x)).collect();
    max_abs_diff(reference, &widened)
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn hd_ring_fast_path_equals_dense() {
    for (nt, nv) in [(16, 5), (13, 4), (32, 1)] {
        let p = HdParams {
            n_theta: nt,
            n_nu: nv,
            ..HdParams::default()
        };
        let ring = HdRing::<f64>::new(p.clone()).unwrap();
        let m = activity(nt * nv, 7, 5);
        let mut fast = vec![0.0; m.len()];
        ring.recurrent_input(&m, &mut fast);
        let dense = reference::hd_recurrent(&p, &m);
        let err = max_abs_diff(&fast, &dense);
        assert!(err < 1e-10, "Nθ={nt} Nν={nv}: {err}");
        assert!(
            dense.iter().any(|x| x.abs() > 1e-3),
            "non-trivial comparison"
        );
    }
}

#[test]
fn grid_fast_path_equals_dense_for_every_module() {
    for k in [1usize, 2, 4] {
        for (n, m_nu) in [(8usize, 3usize), (12, 2)] {
            let p = GridParams {
                n_theta: n,
                n_nu: m_nu,
                ..GridParams::for_module(k)
            };
            let module = GridModule::<f64>::new(p.clone()).unwrap();
            let c = p.cell();
            // The module integrates lattice-periodic activity: a random unit cell, tiled.
            let mut cell = activity(c * c * p.n_slices(), k as u64, 7);
            // Silence one whole velocity slice to exercise the skip path.
            cell[..c * c].iter_mut().for_each(|x| *x = 0.0);
            let mut fast_cell = vec![0.0; cell.len()];
            module.recurrent_input(&cell, &mut fast_cell);
            let fast = module.tile(&fast_cell);
            let dense = reference::grid_recurrent(&p, &module.tile(&cell));
            let err = max_abs_diff(&fast, &dense);
            let scale = dense.iter().map(|x| x.abs()).fold(0.0, f64::max);
            assert!(scale > 1.0, "non-trivial comparison");
            assert!(err < 1e-10, "k={k} N={n} M={m_nu}: {err}");
        }
    }
}

#[test]
fn place_fast_path_equals_dense() {
    for n in [8usize, 11] {
        let p = PlaceParams {
            n_theta: n,
            ..PlaceParams::default()
        };
        let mut net = PlaceNetwork::<f64>::new(p.clone()).unwrap();
        let m = activity(n * n, 3, 4);
        let mut fast = vec![0.0; m.len()];
        net.recurrent_input(&m, &mut fast);
        let dense = reference::place_recurrent(&p, &m);
        let err = max_abs_diff(&fast, &dense);
        assert!(err < 1e-10, "N={n}: {err}");
    }
}

#[test]
fn single_precision_fast_path_tracks_double() {
    let p = GridParams {
        n_theta: 16,
        n_nu: 3,
        ..GridParams::for_module(2)
    };
    let m64 = activity(p.cell() * p.cell() * p.n_slices(), 11, 9);
    let m32: Vec<f32> = m64.iter().map(|&x| x as f32).collect();
    let mut h64 = vec![0.0; m64.len()];
    let mut h32 = vec![0.0f32; m32.len()];
    GridModule::<f64>::new(p.clone())
        .unwrap()
        .recurrent_input(&m64, &mut h64);
    GridModule::<f32>::new(p)
        .unwrap()
        .recurrent_input(&m32, &mut h32);
    let scale = h64.iter().map(|x| x.abs()).fold(0.0, f64::max);
    let err = max_abs_diff_f32(&h64, &h32);
    assert!(err < 1e-4 * scale, "{err} vs scale {scale}");
}

/// The default torus size (N = 64: FFT planners pick different algorithms than at N = 8).
#[test]
fn grid_fast_path_equals_dense_at_the_default_torus_size() {
    let p = GridParams {
        n_theta: 64,
        n_nu: 2,
        ..GridParams::for_module(1)
    };
    let module = GridModule::<f64>::new(p.clone()).unwrap();
    let m = activity(p.n_units(), 5, 13);
    let mut fast = vec![0.0; m.len()];
    module.recurrent_input(&m, &mut fast);
    let dense = reference::grid_recurrent(&p, &m);
    let err = max_abs_diff(&fast, &dense);
    assert!(err < 1e-10, "{err}");
}

/// At the default velocity resolution (9×9 slices) the mixing is truncated to its numerical rank (10 modes
/// of 81 in f32): the result still equals the dense double sum, to the type's rounding.
#[test]
fn truncated_velocity_mixing_equals_dense_at_the_default_velocity_size() {
    let p = GridParams {
        n_theta: 8,
        ..GridParams::for_module(1)
    };
    assert_eq!(p.n_slices(), 81, "the default velocity axes");
    let m64 = activity(p.n_units(), 17, 11);
    let dense = reference::grid_recurrent(&p, &m64);
    let scale = dense.iter().map(|x| x.abs()).fold(0.0, f64::max);
    assert!(scale > 1.0, "non-trivial comparison");

    let module64 = GridModule::<f64>::new(p.clone()).unwrap();
    assert!(module64.mixing_rank() < 81);
    let mut h64 = vec![0.0; m64.len()];
    module64.recurrent_input(&m64, &mut h64);
    assert!(max_abs_diff(&h64, &dense) < 1e-10 * scale);

    let module32 = GridModule::<f32>::new(p).unwrap();
    assert!(
        module32.mixing_rank() <= 12,
        "rank {}",
        module32.mixing_rank()
    );
    let m32: Vec<f32> = m64.iter().map(|&x| x as f32).collect();
    let mut h32 = vec![0.0f32; m32.len()];
    module32.recurrent_input(&m32, &mut h32);
    let err = max_abs_diff_f32(&dense, &h32);
    // f32 rounding of sums over 81 slices × 64 units: a few ε of the scale.
    assert!(err < 2e-6 * scale, "{err} vs scale {scale}");
}

/// Folding and tiling are inverse on periodic activity, and folding averages the k² cells.
#[test]
fn fold_tile_round_trip() {
    let p = GridParams {
        n_theta: 16,
        n_nu: 2,
        ..GridParams::for_module(4)
    };
    let module = GridModule::<f64>::new(p.clone()).unwrap();
    let cell = activity(p.cell() * p.cell() * p.n_slices(), 3, 5);
    assert!(max_abs_diff(&module.fold(&module.tile(&cell)), &cell) < 1e-12);
    // In f32 with 16 bumps (256 copies) the round trip is exact: a saved state must resume bit for bit.
    let p16 = GridParams {
        n_theta: 64,
        n_nu: 2,
        ..GridParams::for_module(16)
    };
    let module16 = GridModule::<f32>::new(p16.clone()).unwrap();
    let cell16: Vec<f32> = activity(p16.cell() * p16.cell() * p16.n_slices(), 7, 3)
        .iter()
        .map(|&x| x as f32)
        .collect();
    assert_eq!(module16.fold(&module16.tile(&cell16)), cell16);
}
