//! The sliding window on a simulated stereo drive (integration tests may unwrap).
#![allow(clippy::unwrap_used, clippy::expect_used)]
mod common;

use common::{camera, observe, street, truth};
use hippo_vo::{Observation, SlidingWindow, WindowParams};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A noisy frame-to-frame step (what a tracker measures).
fn noisy_step(rng: &mut ChaCha8Rng, step: &Isometry3<f64>, rot: f64, trans: f64) -> Isometry3<f64> {
    let mut n = |s: f64| rng.random_range(-s..s);
    let noise = Isometry3::from_parts(
        Translation3::new(n(trans), n(trans), n(trans)),
        UnitQuaternion::from_euler_angles(n(rot), n(rot), n(rot)),
    );
    noise * step
}

fn position_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.inverse().translation.vector - b.inverse().translation.vector).norm()
}

/// Mean position error of the window's poses (each as refined when it was the newest) and of the chained
/// noisy steps it started from, over a 120 m simulated drive.
fn drive(params: WindowParams) -> (f64, f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let points = street(&mut rng);
    let mut window = SlidingWindow::new(camera(), params).unwrap();
    let (mut chained, mut refined) = (truth(0), truth(0));
    let (mut chain_error, mut refined_error) = (0.0, 0.0);
    for k in 0..120 {
        let obs = observe(&mut rng, &points, &truth(k), 0.5);
        if k > 0 {
            let step = truth(k) * truth(k - 1).inverse(); // cur_from_prev
            let measured = noisy_step(&mut rng, &step, 0.003, 0.03);
            chained = measured * chained;
            refined = measured * refined;
        }
        let outcome = window.add_keyframe(refined, &obs).unwrap();
        assert!(k == 0 || !outcome.reset, "frame {k} reset the window");
        refined = outcome.camera_from_world;
        chain_error += position_error(&chained, &truth(k));
        refined_error += position_error(&refined, &truth(k));
    }
    (refined_error / 120.0, chain_error / 120.0)
}

#[test]
fn refinement_lowers_the_drift_of_a_frame_to_frame_chain() {
    let (refined_error, chain_error) = drive(WindowParams::default());
    // The window ties each pose to the landmarks of the last 8 keyframes: far less drift.
    assert!(
        refined_error < 0.35 * chain_error,
        "refined {refined_error:.3} m vs chained {chain_error:.3} m"
    );
}

#[test]
fn fixed_older_keyframes_place_the_landmarks_better() {
    let (alone, _) = drive(WindowParams::default());
    let (with_fixed, _) = drive(WindowParams {
        fixed_keyframes: 8,
        ..WindowParams::default()
    });
    // Measured: 0.0062 → 0.0043 m.
    assert!(
        with_fixed < 0.85 * alone,
        "{with_fixed:.4} m with 8 fixed keyframes vs {alone:.4} m without"
    );
}

#[test]
fn a_moving_object_in_the_window_does_not_move_the_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let points = street(&mut rng);
    // A car ahead: 150 points 12 m in front of the camera that drive along with it.
    let car: Vec<Vector3<f64>> = (0..150)
        .map(|_| {
            Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-0.5..1.2),
                rng.random_range(11.0..13.0),
            )
        })
        .collect();
    let mut window = SlidingWindow::new(camera(), WindowParams::default()).unwrap();
    let mut last = None;
    for k in 0..12 {
        let pose = truth(k);
        let mut obs = observe(&mut rng, &points, &pose, 0.3);
        obs.truncate(250); // few static points against the car
        let cam = camera();
        for (i, p) in car.iter().enumerate() {
            let px = cam.project(p).unwrap(); // the same pixels in every frame: it moves with us
            obs.push(Observation {
                landmark: 1_000_000 + i as u64,
                left_px: [px.x, px.y],
                right_u_px: px.z,
            });
        }
        // The guess: the truth (a good tracker), so any pull comes from the car.
        last = Some((window.add_keyframe(pose, &obs).unwrap(), pose, obs.len()));
    }
    let (outcome, pose, n) = last.unwrap();
    assert!(
        position_error(&outcome.camera_from_world, &pose) < 0.05,
        "pulled by the car"
    );
    let car_inliers = outcome.outlier[n - 150..].iter().filter(|&&o| !o).count();
    assert!(
        car_inliers < 15,
        "{car_inliers} of the car's 150 points kept as inliers"
    );
    let street_outliers = outcome.outlier[..n - 150].iter().filter(|&&o| o).count();
    assert!(
        street_outliers < 25,
        "{street_outliers} of {} street points called outliers",
        n - 150
    );
}

#[test]
fn a_keyframe_sharing_nothing_starts_a_new_window_at_its_guess() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let points = street(&mut rng);
    let mut window = SlidingWindow::new(camera(), WindowParams::default()).unwrap();
    for k in 0..5 {
        window
            .add_keyframe(truth(k), &observe(&mut rng, &points, &truth(k), 0.3))
            .unwrap();
    }
    // The tracker lost everything (new ids) and its guess is off by 2 m: nothing can correct it, and the
    // window must not pull the old keyframes towards it either.
    let fresh: Vec<Observation> = observe(&mut rng, &points, &truth(5), 0.3)
        .into_iter()
        .map(|o| Observation {
            landmark: o.landmark + 10_000_000,
            ..o
        })
        .collect();
    let guess = Isometry3::translation(2.0, 0.0, 0.0) * truth(5);
    let outcome = window.add_keyframe(guess, &fresh).unwrap();
    assert!(outcome.reset);
    assert_eq!(outcome.keyframes, 1);
    assert!(position_error(&outcome.camera_from_world, &guess) < 1e-12);
    // The next keyframe tracks the fresh points and is refined against the new anchor.
    let next: Vec<Observation> = observe(&mut rng, &points, &truth(6), 0.3)
        .into_iter()
        .map(|o| Observation {
            landmark: o.landmark + 10_000_000,
            ..o
        })
        .collect();
    let guess_next = Isometry3::translation(2.0, 0.0, 0.0) * truth(6);
    let outcome = window
        .add_keyframe(Isometry3::translation(0.05, 0.0, 0.0) * guess_next, &next)
        .unwrap();
    assert!(!outcome.reset);
    assert!(position_error(&outcome.camera_from_world, &guess_next) < 0.02);
}

#[test]
fn bad_input_is_an_error() {
    let mut window = SlidingWindow::new(camera(), WindowParams::default()).unwrap();
    let nan = Observation {
        landmark: 1,
        left_px: [f64::NAN, 2.0],
        right_u_px: 1.0,
    };
    assert!(window.add_keyframe(Isometry3::identity(), &[nan]).is_err());
    let a = Observation {
        landmark: 1,
        left_px: [1.0, 2.0],
        right_u_px: 0.0,
    };
    assert!(window.add_keyframe(Isometry3::identity(), &[a, a]).is_err());
    assert!(SlidingWindow::new(
        camera(),
        WindowParams {
            max_keyframes: 1,
            ..Default::default()
        }
    )
    .is_err());
    let mut m = nalgebra::Matrix4::<f64>::identity();
    m[(0, 0)] = 2.0;
    assert!(hippo_vo::window::isometry_from_matrix(&m).is_err());
    assert!(window.is_empty());
}
