//! Module lesions ("MEC inactivation"), view-cell injection, and the errors bad input gets.
// A test or benchmark: a failed unwrap is the check failing (library code never unwraps, see Cargo.toml).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use hippo_attractor::wrap_angle as wrap;
use hippo_attractor::{AttractorError, SpatialMemory, SpatialMemoryParams, ViewInjection};

fn place_width_rad(sm: &mut SpatialMemory<f32>, lesioned: [bool; 3]) -> (f64, f64) {
    sm.set_lesions(lesioned);
    let mut widths = vec![];
    let mut fused = vec![];
    for _ in 0..10 {
        let r = sm.step(0.0, 0.0, 0.1, None).unwrap();
        let p = r.place.expect("place bump");
        widths.push(0.5 * (p.std_rad[0] + p.std_rad[1]));
        let f = r.fused.expect("fused estimate");
        fused.push(0.5 * (f.std_rad[0] + f.std_rad[1]));
    }
    (
        widths[5..].iter().sum::<f64>() / 5.0,
        fused[5..].iter().sum::<f64>() / 5.0,
    )
}

/// docs/spec.md §4 and §6: every lesion widens the place field; losing the dorsal (finest,
/// smallest σ) module widens it more than losing the ventral (coarsest) one:
/// σ_yellow > σ_green > σ_red.
#[test]
fn lesions_widen_the_place_bump_in_the_order_the_theory_predicts() {
    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    let (red, red_in) = place_width_rad(&mut sm, [false, false, false]);
    let (green, green_in) = place_width_rad(&mut sm, [true, false, false]);
    let (yellow, yellow_in) = place_width_rad(&mut sm, [false, false, true]);
    assert!(
        yellow_in > green_in && green_in > red_in,
        "fused widths {red_in} {green_in} {yellow_in}"
    );
    assert!(
        yellow > green && green > red,
        "place widths red {red} green {green} yellow {yellow}"
    );
    // The theory's closed form, from the measured module widths, predicts the fused widths.
    place_width_rad(&mut sm, [false, false, false]);
    let r = sm.readout();
    let sig: Vec<f64> = r
        .modules
        .iter()
        .map(|m| {
            let b = &m.bumps[0];
            0.5 * (b.std_rad[0] + b.std_rad[1])
        })
        .collect();
    let fuse = |s: &[f64]| 1.0 / s.iter().map(|x| 1.0 / (x * x)).sum::<f64>().sqrt();
    assert!((fuse(&sig[1..]) - green_in).abs() / green_in < 0.1);
    assert!((fuse(&sig[..2]) - yellow_in).abs() / yellow_in < 0.1);
}

/// All modules lesioned: nothing to fuse, the place input goes silent, but nothing fails.
#[test]
fn lesioning_every_module_silences_the_place_input_without_failing() {
    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    sm.set_lesions([true, true, true]);
    let r = sm.step(0.0, 5.0, 0.1, None).unwrap();
    assert!(r.fused.is_none());
    assert!(r.modules.iter().all(|m| m.bumps.is_empty()));
}

/// A familiar view injects the stored HD and grid patterns and pulls a drifted state back.
#[test]
fn view_injection_recalls_the_stored_heading_and_position() {
    let mut sm = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    let stored = ViewInjection {
        hd_profile: sm.hd.theta_profile(),
        grid_layer2: [
            Some(sm.grids[0].layer2()),
            Some(sm.grids[1].layer2()),
            Some(sm.grids[2].layer2()),
        ],
        strength: 0.0,
    };
    let start = sm.readout();
    // Drift away: turn by ~0.5 rad and drive ~6 m.
    for _ in 0..5 {
        sm.step(1.0, 12.0, 0.1, None).unwrap();
    }
    let away = sm.readout();
    let heading_gap =
        |r: &hippo_attractor::SpatialReadout| wrap(r.hd.heading_rad - start.hd.heading_rad).abs();
    let place_gap = |r: &hippo_attractor::SpatialReadout| {
        let (a, b) = (r.place.unwrap().mean_rad, start.place.unwrap().mean_rad);
        wrap(a[0] - b[0]).hypot(wrap(a[1] - b[1]))
    };
    assert!(heading_gap(&away) > 0.3 && place_gap(&away) > 0.2);
    let view = ViewInjection {
        strength: 3.0,
        ..stored
    };
    for _ in 0..10 {
        sm.step(0.0, 0.0, 0.1, Some(&view)).unwrap();
    }
    let back = sm.readout();
    assert!(
        heading_gap(&back) < 0.25 * heading_gap(&away),
        "heading {} → {}",
        heading_gap(&away),
        heading_gap(&back)
    );
    assert!(
        place_gap(&back) < 0.25 * place_gap(&away),
        "place {} → {}",
        place_gap(&away),
        place_gap(&back)
    );
}

#[test]
fn bad_parameters_are_rejected_with_the_parameter_named() {
    let cases: Vec<(SpatialMemoryParams, &str)> = vec![
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.hd.n_theta = 0;
                p
            },
            "hd.n_theta",
        ),
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.grid[1].n_nu = 0;
                p
            },
            "grid[1].n_nu",
        ),
        (
            SpatialMemoryParams {
                tau_s: f64::NAN,
                ..Default::default()
            },
            "tau_s",
        ),
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.grid[0].jk = f64::INFINITY;
                p
            },
            "grid[0].jk",
        ),
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.grid[2].j0 = 5.0;
                p
            },
            "grid[2].j0",
        ),
        (
            SpatialMemoryParams {
                max_substep_s: 0.2,
                ..Default::default()
            },
            "max_substep_s",
        ),
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.grid[0].n_theta = 32;
                p
            },
            "grid[0].n_theta",
        ),
        // Sizes that would allocate gigabytes, and times that would hang the first frame.
        (
            {
                let mut p = SpatialMemoryParams::default();
                p.hd.n_theta = 1 << 16;
                p.hd.n_nu = 1024;
                p
            },
            "hd.units",
        ),
        (
            {
                let mut p = SpatialMemoryParams::default();
                for g in &mut p.grid {
                    g.n_theta = 1024;
                    g.n_nu = 64;
                }
                p.place.n_theta = 1024;
                p
            },
            "grid[0].units",
        ),
        (
            SpatialMemoryParams {
                settle_s: 1e6,
                ..Default::default()
            },
            "settle_s",
        ),
        (
            SpatialMemoryParams {
                torus_period_m: f64::INFINITY,
                ..Default::default()
            },
            "torus_period_m",
        ),
    ];
    for (params, name) in cases {
        match SpatialMemory::<f32>::new(params) {
            Err(e @ AttractorError::BadParameter { .. }) => {
                assert!(e.to_string().contains(name), "{e}")
            }
            Err(e) => panic!("{name}: unexpected error {e}"),
            Ok(_) => panic!("{name}: accepted"),
        }
    }
}

#[test]
fn bad_inputs_are_rejected_and_leave_the_state_untouched() {
    let p = SpatialMemoryParams {
        settle_s: 0.1,
        ..Default::default()
    };
    let mut sm = SpatialMemory::<f32>::new(p).unwrap();
    sm.step(0.1, 5.0, 0.1, None).unwrap();
    let before = sm.readout();
    let hd_before = sm.hd.activity().to_vec();
    for (w, v, dt) in [
        (f64::NAN, 1.0, 0.1),
        (0.0, f64::INFINITY, 0.1),
        (0.0, 1.0, -0.1),
        (0.0, 1.0, f64::NAN),
    ] {
        assert!(matches!(
            sm.step(w, v, dt, None),
            Err(AttractorError::NonFinite { .. } | AttractorError::OutOfRange { .. })
        ));
    }
    // Absurd speeds and turn rates (a VO failure) are refused, not integrated.
    let e = sm.step(0.0, 500.0, 0.1, None).unwrap_err();
    assert!(e.to_string().contains("m/s"), "{e}");
    assert!(sm.step(50.0, 1.0, 0.1, None).is_err());
    let bad_view = ViewInjection {
        hd_profile: vec![0.0f32; 3],
        grid_layer2: [None, None, None],
        strength: 1.0,
    };
    assert!(matches!(
        sm.step(0.0, 1.0, 0.1, Some(&bad_view)),
        Err(AttractorError::BadShape { .. })
    ));
    let nan_view = ViewInjection {
        hd_profile: vec![f32::NAN; 128],
        grid_layer2: [None, None, None],
        strength: 1.0,
    };
    assert!(matches!(
        sm.step(0.0, 1.0, 0.1, Some(&nan_view)),
        Err(AttractorError::NonFiniteArray { .. })
    ));
    assert_eq!(sm.readout(), before);
    assert_eq!(sm.hd.activity(), &hd_before[..]);
}

/// A saved state (activities and the auxiliary state) restored into a fresh network continues bit for bit:
/// what a run resumed from a saved memory needs (the 16-bump module's fold and the integrators' warm starts
/// are part of it).
#[test]
fn a_restored_state_continues_bit_for_bit() {
    let mut a = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    a.reset(0.4, [1.0, 2.5]).unwrap();
    for k in 0..15 {
        a.step(0.2 * (k as f64 * 0.3).sin(), 6.0, 0.1, None)
            .unwrap();
    }
    let mut b = SpatialMemory::<f32>::new(SpatialMemoryParams::default()).unwrap();
    b.hd.set_activity(a.hd.activity()).unwrap();
    for (g, h) in b.grids.iter_mut().zip(&a.grids) {
        g.set_activity(&h.activity()).unwrap();
    }
    b.place.set_activity(a.place.activity()).unwrap();
    b.set_aux_state(&a.aux_state()).unwrap();
    for k in 0..5 {
        let ra = a.step(0.1, 5.0 + k as f64, 0.1, None).unwrap();
        let rb = b.step(0.1, 5.0 + k as f64, 0.1, None).unwrap();
        assert_eq!(ra.place, rb.place, "step {k}");
        assert_eq!(ra.place_position_m, rb.place_position_m, "step {k}");
        assert_eq!(ra.fused, rb.fused, "step {k}");
    }
    assert_eq!(a.place.activity(), b.place.activity());
}
