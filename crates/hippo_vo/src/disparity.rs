//! One frame's estimate of the stereo pair's disparity offset, from the motion (the fit behind the Python
//! `hippo_nav.vo.disparity.frame_offset_px`; docs/vo.md, "Disparity self-calibration").
//!
//! A right image shifted against its calibration by δ px makes every depth `fx·b / (d − δ)`, wrong by a
//! factor that grows with depth, and no rigid step moves near and far points alike under such depths: the
//! motion measures δ. The fit is a two-frame stereo bundle adjustment with one extra unknown ε: the step
//! (rotation ω and translation τ, a left perturbation), the inverse depth ρ of every point along the ray of
//! its previous left pixel, and ε, from four residuals per point: the previous right column (measured
//! disparity + ε against `fx·b·ρ`), the current left pixel (u and v), and the current right column
//! (corrected by ε), where matched. Gauss–Newton with a Huber weight; the points are eliminated by the
//! Schur complement (one unknown each), leaving a 7×7 system.
//!
//! It ran in numpy, about 2.7 ms a fit on the VO's thread, nearly all of it per-call overhead on 200
//! points; here 0.28 ms (docs/vo.md, "Disparity self-calibration").
use crate::camera::StereoCamera;
use nalgebra::{Matrix3, Rotation3, SMatrix, SVector, Vector3};

/// Gauss–Newton iterations at most (each a full relinearisation; the offset's update below 1e-4 px stops it).
const ITERATIONS: usize = 4;
/// Fewer points than this cannot tell an offset from the step.
const MIN_POINTS: usize = 12;

/// One frame's tracks for [`frame_offset`]: the previous frame's stereo points, their current pixels.
#[derive(Debug, Clone, Copy)]
pub struct OffsetTracks<'a> {
    /// Points of the previous left camera (m, z > 0), from its own disparities with the offset in use.
    pub prev_points_m: &'a [[f64; 3]],
    /// Their current left pixels (u, v).
    pub left_px: &'a [[f64; 2]],
    /// Their current right-image columns, corrected by the offset in use (read where `has_right`).
    pub right_u_px: &'a [f64],
    /// Whether the current right column was matched.
    pub has_right: &'a [bool],
}

/// The fitted offset (px, to add to the one in use) and its standard error (px): the formal one scaled by
/// the residuals' robust scatter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetEstimate {
    /// ε, px.
    pub offset_px: f64,
    /// Its standard error, px.
    pub sigma_px: f64,
}

/// The offset fitted to one frame's tracks, starting from the step `rotation`, `translation`
/// (`cur_from_prev`), or None when it cannot be fitted (too few points, a point behind a camera, a singular
/// system, a non-finite result). With `reject_px`, the points whose largest residual stays above it after the
/// fit are dropped and the fit run again once (mistracks a wide gate let in).
pub fn frame_offset(
    camera: &StereoCamera,
    rotation: &Matrix3<f64>,
    translation: &Vector3<f64>,
    tracks: &OffsetTracks<'_>,
    huber_px: f64,
    reject_px: Option<f64>,
) -> Option<OffsetEstimate> {
    let n = tracks.prev_points_m.len();
    if tracks.left_px.len() != n || tracks.right_u_px.len() != n || tracks.has_right.len() != n {
        return None;
    }
    if n < MIN_POINTS || !tracks.prev_points_m.iter().all(|p| p[2] > 0.0) {
        return None;
    }
    let fit = Fit::run(camera, rotation, translation, tracks, huber_px)?;
    if let Some(reject_px) = reject_px {
        let keep: Vec<bool> = fit.worst_px.iter().map(|w| *w <= reject_px).collect();
        if keep.iter().any(|k| !k) {
            let pick = |i: usize| keep[i];
            let prev: Vec<[f64; 3]> = filtered(tracks.prev_points_m, pick);
            let left: Vec<[f64; 2]> = filtered(tracks.left_px, pick);
            let right: Vec<f64> = filtered(tracks.right_u_px, pick);
            let has: Vec<bool> = filtered(tracks.has_right, pick);
            let kept = OffsetTracks {
                prev_points_m: &prev,
                left_px: &left,
                right_u_px: &right,
                has_right: &has,
            };
            return frame_offset(camera, rotation, translation, &kept, huber_px, None);
        }
    }
    fit.estimate()
}

fn filtered<T: Copy>(values: &[T], keep: impl Fn(usize) -> bool) -> Vec<T> {
    values
        .iter()
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, v)| *v)
        .collect()
}

/// One residual: its value, its Jacobian on (ω, τ, ε) and on the point's inverse depth.
struct Row {
    residual: f64,
    pose: [f64; 7],
    inverse_depth: f64,
}

/// The state after the last iteration: what the estimate and the refit need.
struct Fit {
    offset_px: f64,
    variance: f64,
    residuals: Vec<f64>,
    worst_px: Vec<f64>,
}

impl Fit {
    fn run(
        camera: &StereoCamera,
        rotation: &Matrix3<f64>,
        translation: &Vector3<f64>,
        tracks: &OffsetTracks<'_>,
        huber_px: f64,
    ) -> Option<Self> {
        let n = tracks.prev_points_m.len();
        let fxb = camera.fx * camera.baseline_m;
        let z0: Vec<f64> = tracks.prev_points_m.iter().map(|p| p[2]).collect();
        // (x/z, y/z, 1): fixed by the previous left pixel.
        let ray: Vec<Vector3<f64>> = tracks
            .prev_points_m
            .iter()
            .map(|p| Vector3::new(p[0] / p[2], p[1] / p[2], 1.0))
            .collect();
        let d_prev: Vec<f64> = z0.iter().map(|z| fxb / z).collect();
        let mut inverse_depth: Vec<f64> = z0.iter().map(|z| 1.0 / z).collect();
        let (mut rotation, mut translation) = (*rotation, *translation);
        let mut offset = 0.0;
        let mut last: Option<(f64, Vec<Row>, Vec<usize>)> = None;
        let mut rows = Vec::with_capacity(4 * n);
        let mut owner = Vec::with_capacity(4 * n);
        for _ in 0..ITERATIONS {
            rows.clear();
            owner.clear();
            let mut moved = Vec::with_capacity(n);
            for i in 0..n {
                let rho = inverse_depth[i];
                let point = ray[i] / rho;
                let x = rotation * point + translation;
                if !(x.z > 0.0 && rho > 0.0) {
                    return None;
                }
                // d x / d ρ: the point slides along its ray.
                moved.push((x, rotation * (-point / rho)));
            }
            // The previous right column: measured d_prev + ε against fx·b·ρ.
            for i in 0..n {
                let mut pose = [0.0; 7];
                pose[6] = 1.0;
                rows.push(Row {
                    residual: d_prev[i] + offset - fxb * inverse_depth[i],
                    pose,
                    inverse_depth: -fxb,
                });
                owner.push(i);
            }
            // The current left pixel (u, then v) and the current right column (corrected by ε).
            for (axis, shift_m, sign) in [(0, 0.0, 0.0), (1, 0.0, 0.0), (0, camera.baseline_m, 1.0)]
            {
                for (i, (x, dx_drho)) in moved.iter().enumerate() {
                    let observed = match (axis, sign > 0.0) {
                        (_, true) if !tracks.has_right[i] => continue,
                        (_, true) => tracks.right_u_px[i],
                        (a, false) => tracks.left_px[i][a],
                    };
                    let (predicted, jac, d_a, d_z) = pixel_row(camera, x, axis, shift_m);
                    let mut pose = [0.0; 7];
                    pose[..6].copy_from_slice(&jac);
                    pose[6] = sign;
                    rows.push(Row {
                        residual: predicted - observed + sign * offset,
                        pose,
                        inverse_depth: d_a * dx_drho[axis] + d_z * dx_drho[2],
                    });
                    owner.push(i);
                }
            }
            // Normal equations with the point block eliminated (Schur complement; one unknown per point).
            let mut a = SMatrix::<f64, 7, 7>::zeros();
            let mut g = SVector::<f64, 7>::zeros();
            let mut d = vec![0.0; n];
            let mut b = vec![SVector::<f64, 7>::zeros(); n];
            let mut g_point = vec![0.0; n];
            for (row, &i) in rows.iter().zip(&owner) {
                let r = row.residual;
                let w = if r.abs() <= huber_px {
                    1.0
                } else {
                    huber_px / r.abs().max(1e-12)
                };
                let j = SVector::<f64, 7>::from(row.pose);
                let jw = j * w;
                a += jw * j.transpose();
                g += jw * r;
                d[i] += w * row.inverse_depth * row.inverse_depth;
                b[i] += jw * row.inverse_depth;
                g_point[i] += w * row.inverse_depth * r;
            }
            let mut reduced = a;
            let mut rhs = g;
            for i in 0..n {
                let di = d[i] + 1e-12;
                d[i] = di;
                reduced -= b[i] * b[i].transpose() / di;
                rhs -= b[i] * (g_point[i] / di);
            }
            let lu = reduced.lu();
            let delta = -lu.solve(&rhs)?;
            let variance = lu.try_inverse()?[(6, 6)];
            for i in 0..n {
                inverse_depth[i] -= (g_point[i] + b[i].dot(&delta)) / d[i];
            }
            let update = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])).into_inner();
            rotation = update * rotation;
            translation = update * translation + Vector3::new(delta[3], delta[4], delta[5]);
            offset += delta[6];
            let done = delta[6].abs() < 1e-4;
            last = Some((
                variance,
                std::mem::take(&mut rows),
                std::mem::take(&mut owner),
            ));
            if done {
                break;
            }
            rows = Vec::with_capacity(4 * n);
            owner = Vec::with_capacity(4 * n);
        }
        let (variance, rows, owner) = last?;
        // A point on the wrong texture keeps a large residual whatever its depth; the offset a right image
        // is shifted by does not (the fit explains it). From the last iteration's residuals.
        let mut worst_px = vec![0.0f64; n];
        for (row, &i) in rows.iter().zip(&owner) {
            worst_px[i] = worst_px[i].max(row.residual.abs());
        }
        Some(Self {
            offset_px: offset,
            variance,
            residuals: rows.iter().map(|r| r.residual).collect(),
            worst_px,
        })
    }

    /// The offset and its standard error: the formal variance scaled by the residuals' own scatter (robust:
    /// from their median absolute value).
    fn estimate(&self) -> Option<OffsetEstimate> {
        let mut magnitudes: Vec<f64> = self.residuals.iter().map(|r| r.abs()).collect();
        let median = median(&mut magnitudes)?;
        let sigma_px = 1.4826 * median * self.variance.max(0.0).sqrt();
        (self.offset_px.is_finite() && sigma_px.is_finite()).then_some(OffsetEstimate {
            offset_px: self.offset_px,
            sigma_px,
        })
    }
}

/// The median (the mean of the middle two of an even count), None when empty or not finite.
fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() || values.iter().any(|v| !v.is_finite()) {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let m = values.len() / 2;
    Some(if values.len() % 2 == 1 {
        values[m]
    } else {
        0.5 * (values[m - 1] + values[m])
    })
}

/// (predicted pixel coordinate `axis` (0: u, 1: v) of the point `x` of the current left camera seen by a
/// camera `shift_m` to its right, its Jacobian on a left perturbation (ω, τ) of the pose, and its derivatives
/// on x's `axis` and z components). The point moves by dx = ω × x + τ, so d(pixel)/dω = x × (the gradient).
fn pixel_row(
    camera: &StereoCamera,
    x: &Vector3<f64>,
    axis: usize,
    shift_m: f64,
) -> (f64, [f64; 6], f64, f64) {
    let (focal, centre) = if axis == 0 {
        (camera.fx, camera.cx)
    } else {
        (camera.fy, camera.cy)
    };
    let a = x[axis] - if axis == 0 { shift_m } else { 0.0 };
    let z = x.z;
    let (d_a, d_z) = (focal / z, -focal * a / (z * z));
    let mut jac = [0.0; 6];
    if axis == 0 {
        jac[..3].copy_from_slice(&[x.y * d_z, x.z * d_a - x.x * d_z, -x.y * d_a]);
    } else {
        jac[..3].copy_from_slice(&[x.y * d_z - x.z * d_a, -x.x * d_z, x.x * d_a]);
    }
    jac[3 + axis] = d_a;
    jac[5] = d_z;
    (focal * a / z + centre, jac, d_a, d_z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// (rotation, translation, previous points, current left pixels, current right columns) of [`street`].
    type Street = (
        Matrix3<f64>,
        Vector3<f64>,
        Vec<[f64; 3]>,
        Vec<[f64; 2]>,
        Vec<f64>,
    );

    /// A street seen twice by a stereo pair whose right image is shifted by `shift_px` (its disparities read
    /// `shift_px` short): (previous points as the shifted disparities give them, current left pixels, current
    /// right columns as measured), after a step of 1 m forward and 1° of yaw.
    fn street(camera: &StereoCamera, shift_px: f64, noise_px: f64, seed: u64) -> Street {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let rotation = Rotation3::new(Vector3::new(0.0, 1f64.to_radians(), 0.0)).into_inner();
        let translation = Vector3::new(0.02, 0.0, -1.0);
        let fxb = camera.fx * camera.baseline_m;
        let (mut prev, mut left, mut right) = (Vec::new(), Vec::new(), Vec::new());
        while prev.len() < 200 {
            let z = rng.random_range(4.0..60.0);
            let truth = Vector3::new(
                rng.random_range(-1.0..1.0) * z * 0.6,
                rng.random_range(-0.3..0.2) * z,
                z,
            );
            let x = rotation * truth + translation;
            if x.z < 2.0 {
                continue;
            }
            let mut noise = || noise_px * rng.random_range(-1.0..1.0);
            // The previous frame's point from its measured (shifted) disparity along the true pixel's ray.
            let measured_disparity = fxb / truth.z - shift_px + noise();
            let z_measured = fxb / measured_disparity;
            let ray = truth / truth.z;
            prev.push([ray.x * z_measured, ray.y * z_measured, z_measured]);
            let u = camera.fx * x.x / x.z + camera.cx;
            left.push([u + noise(), camera.fy * x.y / x.z + camera.cy + noise()]);
            right.push(u - fxb / x.z + shift_px + noise());
        }
        (rotation, translation, prev, left, right)
    }

    fn kitti() -> StereoCamera {
        StereoCamera::new(718.856, 718.856, 607.19, 185.22, 0.537).unwrap()
    }

    #[test]
    fn a_shifted_right_image_is_read_from_the_motion() {
        let camera = kitti();
        for (shift_px, seed) in [(1.0, 1), (-0.6, 2), (0.0, 3)] {
            let (rotation, translation, prev, left, right) = street(&camera, shift_px, 0.1, seed);
            let has = vec![true; prev.len()];
            let tracks = OffsetTracks {
                prev_points_m: &prev,
                left_px: &left,
                right_u_px: &right,
                has_right: &has,
            };
            // Started from the step PnP would give on the shifted depths: the truth is near enough.
            let fitted =
                frame_offset(&camera, &rotation, &translation, &tracks, 1.0, Some(3.0)).unwrap();
            assert!(
                (fitted.offset_px - shift_px).abs() < 0.1,
                "shift {shift_px}: fitted {fitted:?}"
            );
            assert!(fitted.sigma_px > 0.0 && fitted.sigma_px < 0.1, "{fitted:?}");
        }
    }

    #[test]
    fn a_mistrack_is_dropped_by_the_refit() {
        let camera = kitti();
        let (rotation, translation, prev, mut left, right) = street(&camera, 0.8, 0.05, 4);
        for l in left.iter_mut().take(12) {
            l[0] += 6.0; // slid along the row onto other texture
        }
        let has = vec![true; prev.len()];
        let tracks = OffsetTracks {
            prev_points_m: &prev,
            left_px: &left,
            right_u_px: &right,
            has_right: &has,
        };
        let refit =
            frame_offset(&camera, &rotation, &translation, &tracks, 1.0, Some(3.0)).unwrap();
        let kept = frame_offset(&camera, &rotation, &translation, &tracks, 1.0, None).unwrap();
        assert!((refit.offset_px - 0.8).abs() < 0.05, "{refit:?}");
        assert!(
            (refit.offset_px - 0.8).abs() < (kept.offset_px - 0.8).abs(),
            "the refit {refit:?} should beat the fit with the mistracks {kept:?}"
        );
    }

    #[test]
    fn too_few_points_or_a_point_behind_give_none() {
        let camera = kitti();
        let (rotation, translation, prev, left, right) = street(&camera, 0.0, 0.1, 5);
        let has = vec![true; prev.len()];
        let few = OffsetTracks {
            prev_points_m: &prev[..11],
            left_px: &left[..11],
            right_u_px: &right[..11],
            has_right: &has[..11],
        };
        assert!(frame_offset(&camera, &rotation, &translation, &few, 1.0, None).is_none());
        let mut behind = prev.clone();
        behind[3][2] = -1.0;
        let tracks = OffsetTracks {
            prev_points_m: &behind,
            left_px: &left,
            right_u_px: &right,
            has_right: &has,
        };
        assert!(frame_offset(&camera, &rotation, &translation, &tracks, 1.0, None).is_none());
    }
}
