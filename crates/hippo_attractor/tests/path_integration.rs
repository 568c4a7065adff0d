//! Behaviour of the networks at their default sizes: bumps form, move at the commanded speed, and the
//! whole network integrates a car-like 2-D trajectory.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hippo_attractor::find_bumps;
use hippo_attractor::tau_effective;
use hippo_attractor::wrap_angle as wrap;
use hippo_attractor::{
    GridModule, GridParams, HdParams, HdRing, SpatialMemory, SpatialMemoryParams,
};

const TAU_S: f64 = 0.01;

/// A varying turn rate, |ω| ≤ 1 rad/s (hits ±1 and passes through 0).
fn yaw_rate(t: f64) -> f64 {
    0.7 * (0.23 * t).sin() + 0.3 * (0.71 * t).cos()
}

#[test]
fn hd_ring_integrates_a_varying_turn_rate() {
    let mut ring = HdRing::<f32>::new(HdParams::default()).unwrap();
    let dt = 0.025; // the default sub-step; 4 per 10 Hz frame
    let te = tau_effective(dt, TAU_S);
    for _ in 0..20 {
        ring.step(0.0, None, dt, TAU_S).unwrap();
    }
    let mut truth = ring.readout(te).heading_rad;
    let (mut worst_heading, mut worst_rate) = (0.0f64, 0.0f64);
    let steps = (60.0 / dt) as usize;
    for i in 0..steps {
        let w = yaw_rate(i as f64 * dt);
        ring.step(ring.velocity_target(w, te).unwrap(), None, dt, TAU_S)
            .unwrap();
        truth += w * dt;
        let r = ring.readout(te);
        worst_heading = worst_heading.max(wrap(r.heading_rad - truth).abs());
        if i > 40 {
            // 5 % of the rate (rates near zero: 5 % of 0.2 rad/s).
            let err = (r.yaw_rate_rad_s - w).abs() / w.abs().max(0.2);
            worst_rate = worst_rate.max(err);
        }
    }
    assert!(
        worst_heading.to_degrees() < 2.0,
        "heading error {:.3}°",
        worst_heading.to_degrees()
    );
    assert!(
        worst_rate < 0.05,
        "angular velocity error {:.2} %",
        worst_rate * 100.0
    );
}

#[test]
fn every_module_forms_k_squared_bumps() {
    let sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    let r = sm.readout();
    let counts: Vec<usize> = r.modules.iter().map(|m| m.bumps.len()).collect();
    assert_eq!(counts, vec![1, 4, 16]);
    // Sparse: well under half of the layer-II units fire (above 1 % of the peak; the exact leak lets
    // silenced units decay geometrically rather than vanish at once).
    for g in &sm.grids {
        let l2 = g.layer2();
        let peak = l2.iter().cloned().fold(0.0f32, f32::max);
        let active = l2.iter().filter(|&&x| x > 0.01 * peak).count() as f64 / l2.len() as f64;
        assert!(active < 0.45, "k={} active fraction {active}", g.params().k);
    }
    assert!(r.place.is_some(), "place bump formed");
}

#[test]
fn a_grid_bump_moves_at_the_commanded_speed_in_any_direction() {
    let dt = 0.025;
    let te = tau_effective(dt, TAU_S);
    let period_m = 100.0;
    for k in [1usize, 4] {
        for (speed, dir) in [(4.0f64, 0.3f64), (25.0, 2.2)] {
            let mut g = GridModule::<f32>::new(GridParams::for_module(k)).unwrap();
            let v = [speed * dir.cos(), speed * dir.sin()];
            let u = g.velocity_target(v, period_m, te).unwrap();
            for _ in 0..40 {
                g.step(u, None, dt, TAU_S).unwrap();
            }
            let n = g.params().n_theta;
            let mut tracked = find_bumps(&g.layer2(), n, 0.3)[0].mean_rad;
            let mut moved = [0.0f64; 2];
            let steps = 200;
            for _ in 0..steps {
                g.step(u, None, dt, TAU_S).unwrap();
                let bumps = find_bumps(&g.layer2(), n, 0.3);
                let b = bumps
                    .iter()
                    .min_by(|a, b| {
                        let da = wrap(a.mean_rad[0] - tracked[0])
                            .hypot(wrap(a.mean_rad[1] - tracked[1]));
                        let db = wrap(b.mean_rad[0] - tracked[0])
                            .hypot(wrap(b.mean_rad[1] - tracked[1]));
                        da.total_cmp(&db)
                    })
                    .unwrap();
                moved[0] += wrap(b.mean_rad[0] - tracked[0]);
                moved[1] += wrap(b.mean_rad[1] - tracked[1]);
                tracked = b.mean_rad;
            }
            let t = steps as f64 * dt;
            let expected = [
                v[0] * t * std::f64::consts::TAU / period_m,
                v[1] * t * std::f64::consts::TAU / period_m,
            ];
            let err = (moved[0] - expected[0]).hypot(moved[1] - expected[1])
                / expected[0].hypot(expected[1]);
            assert!(
                err < 0.03,
                "k={k} speed {speed}: moved {moved:?} expected {expected:?}"
            );
        }
    }
}

/// A car-like 2-D drive: 60 s at 10 Hz, speeds 1–30 m/s, turning at up to ~1 rad/s.
#[test]
fn whole_network_path_integrates_a_car_trajectory() {
    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    let dt = 0.1;
    let (mut x, mut y, mut yaw, mut dist) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut last = None;
    for f in 0..600 {
        let t = f as f64 * dt;
        let w = yaw_rate(t);
        let speed = 15.5 + 14.5 * (0.13 * t).sin();
        let r = sm.step(w, speed, dt, None).unwrap();
        // Ground truth integrated with the same sub-steps (constant commands within a frame).
        let n = r.substeps as f64;
        for _ in 0..r.substeps {
            yaw += w * dt / n;
            x += speed * yaw.cos() * dt / n;
            y += speed * yaw.sin() * dt / n;
        }
        dist += speed * dt;
        last = Some(r);
    }
    let r = last.unwrap();
    assert!(dist > 900.0);
    for m in &r.modules {
        let err = (m.position_m[0] - x).hypot(m.position_m[1] - y) / dist;
        assert!(
            err < 0.02,
            "module k={} error {:.2} % of {dist:.0} m",
            m.k,
            err * 100.0
        );
    }
    for a in &r.modules {
        for b in &r.modules {
            let gap = (a.position_m[0] - b.position_m[0]).hypot(a.position_m[1] - b.position_m[1]);
            assert!(
                gap / dist < 0.02,
                "modules k={} and k={} disagree by {gap:.1} m",
                a.k,
                b.k
            );
        }
    }
    let place_err = (r.place_position_m[0] - x).hypot(r.place_position_m[1] - y) / dist;
    assert!(
        place_err < 0.02,
        "place code error {:.2} %",
        place_err * 100.0
    );
    assert!(wrap(r.hd.heading_rad - yaw).abs().to_degrees() < 2.0);
}
