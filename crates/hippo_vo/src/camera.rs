//! The rectified stereo pair: projection of a point in the left camera into the left pixel and the right
//! image's column, with the Jacobian the bundle adjustment needs.
use crate::error::{Result, VoError};
use nalgebra::{Matrix3, Vector3};

/// Pinhole intrinsics shared by both images of a rectified pair, and the baseline (right camera at +x).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCamera {
    /// Focal lengths, px.
    pub fx: f64,
    /// Focal length along the rows, px.
    pub fy: f64,
    /// Principal point, px.
    pub cx: f64,
    /// Principal point row, px.
    pub cy: f64,
    /// Distance from the left to the right camera, m (> 0).
    pub baseline_m: f64,
}

impl StereoCamera {
    /// A checked camera: positive finite focal lengths and baseline, finite principal point.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, baseline_m: f64) -> Result<Self> {
        for (name, value) in [("fx", fx), ("fy", fy), ("baseline_m", baseline_m)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(VoError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: "must be finite and > 0 (check the calibration's P0 and P1)".to_string(),
                });
            }
        }
        for (name, value) in [("cx", cx), ("cy", cy)] {
            if !value.is_finite() {
                return Err(VoError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: "must be finite".to_string(),
                });
            }
        }
        Ok(Self {
            fx,
            fy,
            cx,
            cy,
            baseline_m,
        })
    }

    /// (u, v, u_right) of a point `x` in the left camera frame; None when it is not in front (z ≤ 1 mm).
    pub fn project(&self, x: &Vector3<f64>) -> Option<Vector3<f64>> {
        if x.z <= 1e-3 {
            return None;
        }
        let inv_z = 1.0 / x.z;
        let u = self.fx * x.x * inv_z + self.cx;
        Some(Vector3::new(
            u,
            self.fy * x.y * inv_z + self.cy,
            u - self.fx * self.baseline_m * inv_z,
        ))
    }

    /// d(u, v, u_right)/dx at `x` (z > 0).
    pub fn jacobian(&self, x: &Vector3<f64>) -> Matrix3<f64> {
        let inv_z = 1.0 / x.z;
        let inv_z2 = inv_z * inv_z;
        Matrix3::new(
            self.fx * inv_z,
            0.0,
            -self.fx * x.x * inv_z2,
            0.0,
            self.fy * inv_z,
            -self.fy * x.y * inv_z2,
            self.fx * inv_z,
            0.0,
            -self.fx * (x.x - self.baseline_m) * inv_z2,
        )
    }

    /// The point in the left camera frame seen at left pixel (u, v) with right column `u_right`; None when
    /// the disparity is below `min_disparity_px` (too far to place).
    pub fn triangulate(
        &self,
        u: f64,
        v: f64,
        u_right: f64,
        min_disparity_px: f64,
    ) -> Option<Vector3<f64>> {
        let disparity = u - u_right;
        if !(disparity.is_finite() && disparity >= min_disparity_px) {
            return None;
        }
        let z = self.fx * self.baseline_m / disparity;
        Some(Vector3::new(
            (u - self.cx) * z / self.fx,
            (v - self.cy) * z / self.fy,
            z,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn triangulation_inverts_projection_and_the_jacobian_matches_differences() {
        let camera = StereoCamera::new(700.0, 710.0, 600.0, 180.0, 0.54).unwrap();
        let x = Vector3::new(-3.0, 1.2, 17.0);
        let p = camera.project(&x).unwrap();
        let back = camera.triangulate(p.x, p.y, p.z, 0.5).unwrap();
        assert_relative_eq!(back, x, epsilon = 1e-9);
        let jac = camera.jacobian(&x);
        for axis in 0..3 {
            let mut dx = Vector3::zeros();
            dx[axis] = 1e-6;
            let numeric =
                (camera.project(&(x + dx)).unwrap() - camera.project(&(x - dx)).unwrap()) / 2e-6;
            assert_relative_eq!(numeric, jac.column(axis).into_owned(), epsilon = 1e-5);
        }
        assert!(camera.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(camera.triangulate(10.0, 0.0, 10.2, 0.5).is_none());
        assert!(StereoCamera::new(700.0, 700.0, 0.0, 0.0, -0.5).is_err());
    }
}
