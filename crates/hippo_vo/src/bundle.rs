//! Stereo bundle adjustment of a few poses and the points they see: Levenberg–Marquardt on the normal
//! equations, the points eliminated by the Schur complement.
//!
//! Why not the map crate's sparse Cholesky: after the points are eliminated, the poses of a window are all
//! joined by shared points, so the reduced system is dense and small (6 unknowns per free pose, at most a
//! few tens of poses); a dense Cholesky of it is the right tool, and the points' 3×3 blocks are inverted
//! one by one. The full system (poses and thousands of points) would be sparse, but factorising it as
//! such fills in the same dense pose block and adds ordering work for nothing.
//!
//! Residual of an observation: the projected (u, v, u_right) minus the measured ones, in pixels, divided by
//! `pixel_sigma_px` (u, v) and `right_sigma_px` (u_right); a missing right-image match leaves (u, v). Loss: Huber on the observation's whole
//! normalised residual (a bad track is one bad observation, not one bad coordinate).
use crate::camera::StereoCamera;
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Matrix6x3, Rotation3, Translation3,
    UnitQuaternion, Vector3, Vector6,
};

/// One observation: pose `pose` saw point `point` at left pixel `left_px` and right column `right_u_px`.
#[derive(Debug, Clone, Copy)]
pub struct BundleObservation {
    /// Index of the pose.
    pub pose: usize,
    /// Index of the point.
    pub point: usize,
    /// Left-image pixel (u, v).
    pub left_px: [f64; 2],
    /// Right-image column, None when the point was not matched in the right image.
    pub right_u_px: Option<f64>,
}

/// Settings of one adjustment.
#[derive(Debug, Clone, Copy)]
pub struct BundleSettings {
    /// Standard deviation of a measured pixel coordinate.
    pub pixel_sigma_px: f64,
    /// Standard deviation of a measured right-image column (a stereo match is less certain than a
    /// temporal track where the surface is slanted: the two views see it differently deformed).
    pub right_sigma_px: f64,
    /// Huber threshold on an observation's normalised residual norm (in σ).
    pub huber_sigma: f64,
    /// Levenberg–Marquardt iterations at most.
    pub max_iterations: usize,
}

impl BundleSettings {
    fn sigmas(&self) -> [f64; 2] {
        [self.pixel_sigma_px, self.right_sigma_px]
    }
}

/// What an adjustment did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BundleReport {
    /// Robust cost (½ Σ ρ) before and after.
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
    /// Accepted iterations.
    pub iterations: usize,
}

/// The normalised residual (u, v, u_right)/σ of an observation (u_right 0 when absent) and its
/// dimension; None when the point is behind the camera.
fn residual(
    camera: &StereoCamera,
    pose: &Isometry3<f64>,
    point: &Vector3<f64>,
    obs: &BundleObservation,
    sigma: [f64; 2],
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let x = pose * nalgebra::Point3::from(*point);
    let projected = camera.project(&x.coords)?;
    let right = obs.right_u_px.map_or(0.0, |u| (projected.z - u) / sigma[1]);
    Some((
        Vector3::new(
            (projected.x - obs.left_px[0]) / sigma[0],
            (projected.y - obs.left_px[1]) / sigma[0],
            right,
        ),
        x.coords,
    ))
}

/// (ρ(s²), weight) of the Huber loss on the squared normalised residual norm `chi2`.
fn huber(chi2: f64, k: f64) -> (f64, f64) {
    let s = chi2.sqrt();
    if s <= k {
        (chi2, 1.0)
    } else {
        (2.0 * k * s - k * k, k / s)
    }
}

/// ½ Σ ρ over the active observations; None when a point falls behind a camera.
fn cost(
    camera: &StereoCamera,
    poses: &[Isometry3<f64>],
    points: &[Vector3<f64>],
    observations: &[BundleObservation],
    settings: &BundleSettings,
) -> Option<f64> {
    let mut total = 0.0;
    for obs in observations {
        let (r, _) = residual(
            camera,
            &poses[obs.pose],
            &points[obs.point],
            obs,
            settings.sigmas(),
        )?;
        total += huber(r.norm_squared(), settings.huber_sigma).0;
    }
    Some(0.5 * total)
}

/// The squared normalised residual norm (χ²) of each observation; +∞ behind the camera.
pub fn chi2(
    camera: &StereoCamera,
    poses: &[Isometry3<f64>],
    points: &[Vector3<f64>],
    observations: &[BundleObservation],
    settings: &BundleSettings,
) -> Vec<f64> {
    observations
        .iter()
        .map(|obs| {
            residual(
                camera,
                &poses[obs.pose],
                &points[obs.point],
                obs,
                settings.sigmas(),
            )
            .map_or(f64::INFINITY, |(r, _)| r.norm_squared())
        })
        .collect()
}

/// Left-multiplied update exp(δ)·T, δ = (ω, τ): R ← Exp(ω)R, t ← Exp(ω)t + τ.
fn retract(pose: &Isometry3<f64>, delta: &Vector6<f64>) -> Isometry3<f64> {
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::new(
        delta.fixed_rows::<3>(0).into_owned(),
    ));
    let translation = rotation * pose.translation.vector + delta.fixed_rows::<3>(3);
    Isometry3::from_parts(Translation3::from(translation), rotation * pose.rotation)
}

/// Refine `poses[fixed..]` and every point from the observations (poses `..fixed` stay as given). Points
/// no observation of a free pose sees stay too. Returns the robust cost before and after.
pub fn adjust(
    camera: &StereoCamera,
    poses: &mut [Isometry3<f64>],
    fixed: usize,
    points: &mut [Vector3<f64>],
    observations: &[BundleObservation],
    settings: &BundleSettings,
) -> BundleReport {
    let n_free = poses.len().saturating_sub(fixed);
    let Some(initial) = cost(camera, poses, points, observations, settings) else {
        return BundleReport {
            initial_cost: f64::INFINITY,
            final_cost: f64::INFINITY,
            iterations: 0,
        };
    };
    let mut report = BundleReport {
        initial_cost: initial,
        final_cost: initial,
        iterations: 0,
    };
    if n_free == 0 || observations.is_empty() {
        return report;
    }
    // Observations grouped by point (the Schur complement works point by point).
    let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); points.len()];
    for (i, obs) in observations.iter().enumerate() {
        by_point[obs.point].push(i);
    }
    let mut lambda = 1e-4;
    let sigma = settings.sigmas();
    for _ in 0..settings.max_iterations {
        // Linearise: per observation the pose block Jᵀ W J pieces, per point its 3×3 block.
        let mut h_pp = vec![Matrix6::<f64>::zeros(); n_free];
        let mut g_p = vec![Vector6::<f64>::zeros(); n_free];
        let mut h_ll = vec![Matrix3::<f64>::zeros(); points.len()];
        let mut g_l = vec![Vector3::<f64>::zeros(); points.len()];
        let mut h_pl = vec![Matrix6x3::<f64>::zeros(); observations.len()];
        for (i, obs) in observations.iter().enumerate() {
            let pose = &poses[obs.pose];
            let Some((r, x)) = residual(camera, pose, &points[obs.point], obs, sigma) else {
                return report; // cost() above would have said so; kept for safety
            };
            let (_, w) = huber(r.norm_squared(), settings.huber_sigma);
            let mut d_pixel = camera.jacobian(&x);
            d_pixel.row_mut(0).scale_mut(1.0 / sigma[0]);
            d_pixel.row_mut(1).scale_mut(1.0 / sigma[0]);
            if obs.right_u_px.is_none() {
                d_pixel.row_mut(2).fill(0.0);
            } else {
                d_pixel.row_mut(2).scale_mut(1.0 / sigma[1]);
            }
            let j_point = d_pixel * pose.rotation.to_rotation_matrix().matrix();
            h_ll[obs.point] += w * j_point.transpose() * j_point;
            g_l[obs.point] += w * j_point.transpose() * r;
            if obs.pose >= fixed {
                // dx/dδ = [−[x]×, I]
                let mut j_pose = nalgebra::Matrix3x6::<f64>::zeros();
                j_pose
                    .fixed_view_mut::<3, 3>(0, 0)
                    .copy_from(&(-d_pixel * x.cross_matrix()));
                j_pose.fixed_view_mut::<3, 3>(0, 3).copy_from(&d_pixel);
                let k = obs.pose - fixed;
                h_pp[k] += w * j_pose.transpose() * j_pose;
                g_p[k] += w * j_pose.transpose() * r;
                h_pl[i] = w * j_pose.transpose() * j_point;
            }
        }
        let current = report.final_cost;
        let mut accepted = false;
        for _ in 0..8 {
            let Some((d_pose, d_point)) = solve(
                &h_pp,
                &g_p,
                &h_ll,
                &g_l,
                &h_pl,
                observations,
                &by_point,
                fixed,
                lambda,
            ) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial_poses = poses.to_vec();
            for (k, delta) in d_pose.iter().enumerate() {
                trial_poses[fixed + k] = retract(&poses[fixed + k], delta);
            }
            let trial_points: Vec<Vector3<f64>> =
                points.iter().zip(&d_point).map(|(p, d)| p + d).collect();
            match cost(camera, &trial_poses, &trial_points, observations, settings) {
                Some(trial) if trial < current => {
                    poses.copy_from_slice(&trial_poses);
                    points.copy_from_slice(&trial_points);
                    report.final_cost = trial;
                    report.iterations += 1;
                    lambda = (lambda / 3.0).max(1e-9);
                    accepted = true;
                    break;
                }
                _ => lambda *= 4.0,
            }
        }
        if !accepted || current - report.final_cost < 1e-6 * current {
            break;
        }
    }
    report
}

/// A step of every free pose and every point.
type Step = (Vec<Vector6<f64>>, Vec<Vector3<f64>>);

/// The damped step (per free pose, per point) by the Schur complement; None when the reduced system is
/// not positive definite.
#[allow(clippy::too_many_arguments)]
fn solve(
    h_pp: &[Matrix6<f64>],
    g_p: &[Vector6<f64>],
    h_ll: &[Matrix3<f64>],
    g_l: &[Vector3<f64>],
    h_pl: &[Matrix6x3<f64>],
    observations: &[BundleObservation],
    by_point: &[Vec<usize>],
    fixed: usize,
    lambda: f64,
) -> Option<Step> {
    let n = h_pp.len();
    let mut s = DMatrix::<f64>::zeros(6 * n, 6 * n);
    let mut b = DVector::<f64>::zeros(6 * n);
    for k in 0..n {
        let mut block = h_pp[k];
        for d in 0..6 {
            block[(d, d)] += lambda * block[(d, d)] + 1e-12;
        }
        s.fixed_view_mut::<6, 6>(6 * k, 6 * k).copy_from(&block);
        b.fixed_rows_mut::<6>(6 * k).copy_from(&(-g_p[k]));
    }
    // Per point: H_ll⁻¹ (damped), and its share of the reduced system.
    let mut h_ll_inv = vec![None; h_ll.len()];
    for (j, obs_of_point) in by_point.iter().enumerate() {
        if obs_of_point.is_empty() {
            continue;
        }
        let mut block = h_ll[j];
        for d in 0..3 {
            block[(d, d)] += lambda * block[(d, d)] + 1e-12;
        }
        let Some(inv) = block.try_inverse() else {
            continue;
        };
        h_ll_inv[j] = Some(inv);
        for &a in obs_of_point {
            let pa = observations[a].pose;
            if pa < fixed {
                continue;
            }
            let wa_inv = h_pl[a] * inv;
            let ka = pa - fixed;
            let update = wa_inv * g_l[j];
            let mut rows = b.fixed_rows_mut::<6>(6 * ka);
            rows += update;
            // S is symmetric and the Cholesky factorisation reads only its lower triangle: each pair of
            // keyframes once, into the block below the diagonal (the diagonal block whole).
            for &c in obs_of_point {
                let pc = observations[c].pose;
                if pc < pa {
                    continue;
                }
                let kc = pc - fixed;
                let block = wa_inv * h_pl[c].transpose();
                if kc == ka {
                    let mut view = s.fixed_view_mut::<6, 6>(6 * ka, 6 * ka);
                    view -= block;
                } else {
                    let mut lower = s.fixed_view_mut::<6, 6>(6 * kc, 6 * ka);
                    lower -= block.transpose();
                }
            }
        }
    }
    let d_pose_all = s.cholesky()?.solve(&b);
    let d_pose: Vec<Vector6<f64>> = (0..n)
        .map(|k| d_pose_all.fixed_rows::<6>(6 * k).into_owned())
        .collect();
    let mut d_point = vec![Vector3::zeros(); h_ll.len()];
    for (j, obs_of_point) in by_point.iter().enumerate() {
        let Some(inv) = h_ll_inv[j] else { continue };
        let mut rhs = -g_l[j];
        for &a in obs_of_point {
            let pa = observations[a].pose;
            if pa >= fixed {
                rhs -= h_pl[a].transpose() * d_pose[pa - fixed];
            }
        }
        d_point[j] = inv * rhs;
    }
    if d_pose.iter().any(|d| !d.iter().all(|v| v.is_finite()))
        || d_point.iter().any(|d| !d.iter().all(|v| v.is_finite()))
    {
        return None;
    }
    Some((d_pose, d_point))
}
