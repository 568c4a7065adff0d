//! Angles on the circle. `wrap(d) = mod(d + π, 2π) − π` is the signed distance used throughout the
//! model (docs/spec.md, Notation and units).
use std::f64::consts::{PI, TAU};

/// Signed circular difference in `[−π, π)`.
#[inline]
pub fn wrap(d: f64) -> f64 {
    (d + PI).rem_euclid(TAU) - PI
}

/// Angle in `[0, 2π)`.
#[inline]
pub fn wrap_2pi(a: f64) -> f64 {
    let r = a.rem_euclid(TAU);
    // rem_euclid can return TAU itself for tiny negative inputs through rounding.
    if r >= TAU {
        0.0
    } else {
        r
    }
}
