//! Both correctors on synthetic loops, and the robust loss against false loop closures.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod common;

use hippo_map::{
    ate_rmse_m, optimize, read_g2o, relax, EdgeKind, Initialization, PoseGraph, RelaxationParams,
    RobustLoss, SolverParams,
};

/// Position gap of the loop edge: how far the graph is from agreeing with the closure (metres).
fn closure_gap_m(graph: &PoseGraph) -> f64 {
    let e = graph
        .edges
        .iter()
        .find(|e| e.kind == EdgeKind::Loop)
        .unwrap();
    let r = e.residual(&graph.poses[e.from], &graph.poses[e.to]);
    r[0].hypot(r[1])
}

#[test]
fn both_correctors_close_a_drifting_loop_and_least_squares_reaches_noise_level() {
    let (sigma_xy, sigma_yaw) = (0.05, 0.002);
    let (truth, dead_reckoned) = common::circle_loop(200, sigma_xy, sigma_yaw, 7);
    let drift_gap = closure_gap_m(&dead_reckoned);
    let drift_ate = ate_rmse_m(&dead_reckoned.poses, &truth);

    let mut relaxed = dead_reckoned.clone();
    let relaxation = relax(
        &mut relaxed,
        &RelaxationParams {
            gain: 0.5,
            passes: 2000,
        },
    )
    .unwrap();
    let mut solved = dead_reckoned.clone();
    let lm = optimize(
        &mut solved,
        &SolverParams {
            initialization: Initialization::Current,
            ..Default::default()
        },
    )
    .unwrap();
    let relaxed_ate = ate_rmse_m(&relaxed.poses, &truth);
    let solved_ate = ate_rmse_m(&solved.poses, &truth);
    // Noise level: a Brownian bridge of n steps with per-step position noise σ has RMS deviation
    // σ·sqrt(n/6) per axis; heading noise adds more, so allow twice the 2-D figure.
    let noise_level = 2.0 * sigma_xy * (200.0f64 / 6.0).sqrt() * std::f64::consts::SQRT_2;
    eprintln!(
        "loop of 200: gap {drift_gap:.3} m -> relaxation {:.4} m / LM {:.2e} m; ATE dead reckoning \
         {drift_ate:.3} m, relaxation {relaxed_ate:.3} m (χ² {:.2}), LM {solved_ate:.3} m (χ² {:.2}, {} its); \
         noise level {noise_level:.3} m",
        closure_gap_m(&relaxed), closure_gap_m(&solved), relaxation.final_chi2, lm.final_chi2, lm.iterations
    );
    assert!(
        drift_gap > 1.0,
        "the synthetic odometry should drift visibly, gap {drift_gap}"
    );
    assert!(closure_gap_m(&relaxed) < 0.05 * drift_gap);
    assert!(closure_gap_m(&solved) < 0.05 * drift_gap);
    assert!(lm.converged);
    assert!(
        solved_ate < noise_level,
        "LM ATE {solved_ate} above noise level {noise_level}"
    );
    assert!(solved_ate < 0.5 * drift_ate);
    assert!(lm.final_chi2 <= relaxation.final_chi2);
}

/// Position RMS difference (m) between two solutions with the same fixed vertex (no alignment needed).
fn rms_difference_m(a: &PoseGraph, b: &PoseGraph) -> f64 {
    let sum: f64 = a
        .poses
        .iter()
        .zip(&b.poses)
        .map(|(p, q)| (p.x - q.x).powi(2) + (p.y - q.y).powi(2))
        .sum();
    (sum / a.len() as f64).sqrt()
}

fn robust_params(phi_chi2: f64) -> SolverParams {
    SolverParams {
        initialization: Initialization::Odometry,
        robust_loss: RobustLoss::Dcs { phi_chi2 },
        max_iterations: 300,
        ..Default::default()
    }
}

/// `phi_chi2`: DCS threshold. The benchmark files' informations make inlier χ² tiny (≈ 0.02 per edge),
/// so Φ = 1 (the DCS paper's value) fits them; the synthetic graph's calibrated noise gives inlier χ²
/// distributed as χ²₃ (mean 3), so its Φ sits near the 98 % quantile, 10.
fn outlier_protocol(
    name: &str,
    clean: &PoseGraph,
    counts: &[usize],
    tolerance_m: f64,
    phi_chi2: f64,
) {
    let mut clean_optimum = clean.clone();
    optimize(&mut clean_optimum, &SolverParams::default()).unwrap();
    let clean_chi2 = clean_optimum.chi2();
    for &count in counts {
        let mut corrupted = clean.clone();
        common::add_outliers(&mut corrupted, count, 1000 + count as u64);
        let mut plain = corrupted.clone();
        let plain_report = optimize(&mut plain, &SolverParams::default()).unwrap();
        let mut robust = corrupted.clone();
        let robust_report = optimize(&mut robust, &robust_params(phi_chi2)).unwrap();
        let robust_err = rms_difference_m(&robust, &clean_optimum);
        let plain_err = rms_difference_m(&plain, &clean_optimum);
        // The clean edges' χ² at each solution, against the clean optimum's.
        let robust_clean_chi2 = clean.chi2_at(&robust.poses);
        let plain_clean_chi2 = clean.chi2_at(&plain.poses);
        eprintln!(
            "{name} + {count} outliers: robust RMS to clean optimum {robust_err:.4} m (clean-edge χ² {robust_clean_chi2:.2} \
             vs {clean_chi2:.2}, {} its, {} loops down-weighted); plain {plain_err:.3} m (clean-edge χ² {plain_clean_chi2:.3e})",
            robust_report.iterations, robust_report.downweighted_loops
        );
        assert!(
            robust_err < tolerance_m,
            "{name}+{count}: robust solve {robust_err} m from the clean optimum"
        );
        assert!(
            plain_err > 10.0 * robust_err.max(tolerance_m / 10.0),
            "{name}+{count}: plain {plain_err}"
        );
        assert!(robust_report.downweighted_loops >= count);
        assert!(robust_clean_chi2 < 1.01 * clean_chi2);
        let _ = plain_report;
    }
}

#[test]
fn robust_loss_survives_false_closures_on_a_synthetic_city() {
    let (_, clean) = common::manhattan_world(2000, 1.0, 2, 3);
    outlier_protocol("manhattan2000", &clean, &[10, 100], 0.01, 10.0);
}

#[test]
fn robust_loss_survives_false_closures_on_intel() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let clean = read_g2o(&data.join("posegraphs/intel.g2o")).unwrap();
    outlier_protocol("intel", &clean, &[10, 100], 0.01, 1.0);
}

#[test]
fn robust_loss_survives_false_closures_on_city10000() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let clean = read_g2o(&data.join("posegraphs/city10000.g2o")).unwrap();
    outlier_protocol("city10000", &clean, &[10, 100], 0.01, 1.0);
}
