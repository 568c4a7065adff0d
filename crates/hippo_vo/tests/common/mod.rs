//! A simulated stereo drive shared by the tests and the benchmark: a street of points, a trajectory and
//! noisy stereo observations.
#![allow(clippy::unwrap_used, dead_code)]
use hippo_vo::{Observation, StereoCamera};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A seeded generator.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

pub fn camera() -> StereoCamera {
    StereoCamera::new(700.0, 700.0, 620.0, 185.0, 0.54).unwrap()
}

/// A street: points on two facades and the road, 0–200 m ahead.
pub fn street(rng: &mut ChaCha8Rng) -> Vec<Vector3<f64>> {
    (0..4000)
        .map(|_| {
            let z = rng.random_range(0.0..200.0);
            match rng.random_range(0..3) {
                0 => Vector3::new(
                    -6.0 + rng.random_range(-0.5..0.5),
                    rng.random_range(-4.0..1.5),
                    z,
                ),
                1 => Vector3::new(
                    6.0 + rng.random_range(-0.5..0.5),
                    rng.random_range(-4.0..1.5),
                    z,
                ),
                _ => Vector3::new(rng.random_range(-6.0..6.0), 1.6, z),
            }
        })
        .collect()
}

/// camera_from_world of frame `k`: 1 m per frame forward, a slow turn.
pub fn truth(k: usize) -> Isometry3<f64> {
    let yaw = 0.004 * k as f64;
    let world_from_camera = Isometry3::from_parts(
        Translation3::new(0.3 * (k as f64 * 0.05).sin(), 0.0, k as f64),
        UnitQuaternion::from_euler_angles(0.0, yaw, 0.0),
    );
    world_from_camera.inverse()
}

pub fn observe(
    rng: &mut ChaCha8Rng,
    points: &[Vector3<f64>],
    pose: &Isometry3<f64>,
    noise_px: f64,
) -> Vec<Observation> {
    let cam = camera();
    let mut out = Vec::new();
    for (id, p) in points.iter().enumerate() {
        let x = pose * Point3::from(*p);
        if x.z < 2.0 || x.z > 40.0 {
            continue;
        }
        let Some(px) = cam.project(&x.coords) else {
            continue;
        };
        if !(0.0..1240.0).contains(&px.x) || !(0.0..370.0).contains(&px.y) {
            continue;
        }
        let mut n = || rng.random_range(-noise_px..noise_px);
        out.push(Observation {
            landmark: id as u64,
            left_px: [px.x + n(), px.y + n()],
            right_u_px: px.z + n(),
        });
    }
    out
}
