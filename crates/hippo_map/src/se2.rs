//! Planar rigid transforms, SE(2).
//!
//! A [`Pose2`] `(x, y, yaw)` is the transform `a_from_b`: it maps a point `p_b` in frame `b` to
//! `p_a = R(yaw)·p_b + (x, y)`. Composition `a_from_c = a_from_b ⊕ b_from_c` is [`Pose2::compose`];
//! the relative transform of `j` seen from `i` is `i_from_j = world_from_i⁻¹ ⊕ world_from_j`
//! ([`Pose2::between`]). Yaw is kept in `[-π, π)` by [`wrap_angle`], the model's
//! `wrap(d) = mod(d+π, 2π) − π`. Odometric steps use the planar convention of docs/spec.md §9:
//! `x` forward, `y` left, yaw counter-clockwise.
//!
//! The algebra is nalgebra's ([`Rotation2`] on [`Vector2`]); the pose itself stays three numbers with the
//! yaw kept as an angle, because that is what is stored, serialized, optimised (additively) and wrapped.
use nalgebra::{Rotation2, Vector2};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// `wrap(d) = mod(d + π, 2π) − π`: the representative of an angle in `[-π, π)`.
#[inline]
pub fn wrap_angle(angle_rad: f64) -> f64 {
    (angle_rad + PI).rem_euclid(2.0 * PI) - PI
}

/// A rigid planar transform `a_from_b` (metres, radians).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose2 {
    /// Forward (m).
    pub x: f64,
    /// Left (m).
    pub y: f64,
    /// Counter-clockwise heading (rad).
    pub yaw: f64,
}

impl Pose2 {
    /// No motion.
    pub const IDENTITY: Pose2 = Pose2 {
        x: 0.0,
        y: 0.0,
        yaw: 0.0,
    };

    /// A pose (the yaw is kept as given; see `wrap_angle`).
    pub fn new(x: f64, y: f64, yaw: f64) -> Self {
        Self { x, y, yaw }
    }

    /// The rotation part `R(yaw)`.
    #[inline]
    pub fn rotation(&self) -> Rotation2<f64> {
        Rotation2::new(self.yaw)
    }

    /// The translation part `(x, y)`, metres.
    #[inline]
    pub fn translation_m(&self) -> Vector2<f64> {
        Vector2::new(self.x, self.y)
    }

    #[inline]
    fn from_parts(translation_m: Vector2<f64>, yaw_rad: f64) -> Pose2 {
        Pose2 {
            x: translation_m.x,
            y: translation_m.y,
            yaw: wrap_angle(yaw_rad),
        }
    }

    /// `self ⊕ other`: apply `other` in the frame of `self`.
    #[inline]
    pub fn compose(&self, other: &Pose2) -> Pose2 {
        Self::from_parts(
            self.translation_m() + self.rotation() * other.translation_m(),
            self.yaw + other.yaw,
        )
    }

    /// `self⁻¹`.
    #[inline]
    pub fn inverse(&self) -> Pose2 {
        Self::from_parts(
            -(self.rotation().inverse() * self.translation_m()),
            -self.yaw,
        )
    }

    /// `self⁻¹ ⊕ other`: the pose of `other` expressed in the frame of `self`.
    #[inline]
    pub fn between(&self, other: &Pose2) -> Pose2 {
        Self::from_parts(
            self.rotation().inverse() * (other.translation_m() - self.translation_m()),
            other.yaw - self.yaw,
        )
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.yaw.is_finite()
    }

    /// `[x, y, yaw]`.
    pub fn to_array(&self) -> [f64; 3] {
        [self.x, self.y, self.yaw]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;

    #[test]
    fn wrap_keeps_angles_in_half_open_interval() {
        assert_abs_diff_eq!(wrap_angle(3.0 * PI), -PI, epsilon = 1e-12);
        assert_abs_diff_eq!(wrap_angle(-0.5), -0.5, epsilon = 1e-12);
        assert_abs_diff_eq!(wrap_angle(2.0 * PI + 0.25), 0.25, epsilon = 1e-12);
    }

    #[test]
    fn compose_inverse_and_between_agree() {
        let a = Pose2::new(1.0, -2.0, 0.7);
        let b = Pose2::new(-0.3, 4.0, -2.9);
        let a_b = a.compose(&b);
        let back = a.between(&a_b);
        assert_abs_diff_eq!(back.x, b.x, epsilon = 1e-12);
        assert_abs_diff_eq!(back.y, b.y, epsilon = 1e-12);
        assert_abs_diff_eq!(back.yaw, b.yaw, epsilon = 1e-12);
        let id = a.compose(&a.inverse());
        assert_abs_diff_eq!(id.x, 0.0, epsilon = 1e-12);
        assert_abs_diff_eq!(id.y, 0.0, epsilon = 1e-12);
        assert_abs_diff_eq!(id.yaw, 0.0, epsilon = 1e-12);
    }

    #[test]
    fn forward_step_moves_along_heading() {
        let facing_north = Pose2::new(0.0, 0.0, PI / 2.0);
        let moved = facing_north.compose(&Pose2::new(2.0, 0.0, 0.0));
        assert_abs_diff_eq!(moved.x, 0.0, epsilon = 1e-12);
        assert_abs_diff_eq!(moved.y, 2.0, epsilon = 1e-12);
    }
}
