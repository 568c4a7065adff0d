//! The least-squares corrector against the standard 2-D pose-graph benchmarks (`posegraphs/` in the
//! test data folder, see `common::shared_data`): from a chordal initialisation (not the file's own
//! poses) it must reach the reference χ² within 0.1 %. The relaxation's χ² after its passes is
//! printed beside it. Skips when the data is absent.
mod common;

use hippo_map::{optimize, read_g2o, relax, Initialization, RelaxationParams, SolverParams};

/// (file, reference χ² from the data README).
const REFERENCES: [(&str, f64); 5] = [
    ("intel.g2o", 45.005),
    ("city10000.g2o", 511.99),
    ("kitti_00.g2o", 98.32),
    ("kitti_02.g2o", 78.76),
    ("kitti_05.g2o", 157.10),
];

fn check(file: &str, reference_chi2: f64) {
    let Some(data) = common::shared_data() else {
        return;
    };
    let path = data.join("posegraphs").join(file);
    let graph = read_g2o(&path).unwrap();
    let mut solved = graph.clone();
    let report = optimize(
        &mut solved,
        &SolverParams {
            initialization: Initialization::Chordal,
            ..SolverParams::default()
        },
    )
    .unwrap();
    let mut relaxed = graph.clone();
    relaxed.initialize_from_odometry().unwrap();
    let relaxation = relax(
        &mut relaxed,
        &RelaxationParams {
            gain: 0.5,
            passes: 100,
        },
    )
    .unwrap();
    eprintln!(
        "{file}: LM χ² {:.3} (reference {reference_chi2}, start {:.3e}) in {} iterations, {:?}; \
         relaxation χ² {:.3e} after {} passes from odometry",
        report.final_chi2,
        report.initial_chi2,
        report.iterations,
        report.termination,
        relaxation.final_chi2,
        relaxation.passes
    );
    assert!(report.converged, "{file}: {report:?}");
    let relative = (report.final_chi2 - reference_chi2) / reference_chi2;
    assert!(
        relative.abs() < 1e-3,
        "{file}: χ² {} vs reference {reference_chi2}",
        report.final_chi2
    );
    assert!(relaxation.final_chi2 > report.final_chi2);
}

#[test]
fn intel_reaches_reference_optimum() {
    check(REFERENCES[0].0, REFERENCES[0].1);
}

#[test]
fn city10000_reaches_reference_optimum() {
    check(REFERENCES[1].0, REFERENCES[1].1);
}

#[test]
fn kitti_00_reaches_reference_optimum() {
    check(REFERENCES[2].0, REFERENCES[2].1);
}

#[test]
fn kitti_02_reaches_reference_optimum() {
    check(REFERENCES[3].0, REFERENCES[3].1);
}

#[test]
fn kitti_05_reaches_reference_optimum() {
    check(REFERENCES[4].0, REFERENCES[4].1);
}
