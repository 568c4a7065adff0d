//! Angles on the circle. `wrap(d) = mod(d + π, 2π) − π` is the signed distance used throughout the
//! model (docs/spec.md, Notation and units).
use std::f64::consts::{PI, TAU};

/// Signed circular difference in `[−π, π)`.
#[inline]
pub fn wrap(d: f64) -> f64 {
    // Bump decoding calls this for every unit against every bump; almost every argument is a difference
    // of two angles in [0, 2π), within one turn, and the remainder (a libm fmod) dominated the decoder.
    let r = if (-PI..PI).contains(&d) {
        d
    } else if (PI..3.0 * PI).contains(&d) {
        d - TAU
    } else if (-3.0 * PI..-PI).contains(&d) {
        d + TAU
    } else {
        (d + PI).rem_euclid(TAU) - PI
    };
    // Rounding can land exactly on π.
    if r >= PI {
        r - TAU
    } else {
        r
    }
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
