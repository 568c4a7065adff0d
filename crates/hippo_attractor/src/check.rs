//! Parameter and input validation shared by the networks.
use crate::error::{AttractorError, Result};

/// The largest interaction strength, inhibition or input amplitude (|J|, I) a network takes: the defaults
/// are up to 6 000; far beyond, a typo (1e300) validated and left the networks without a bump or NaN.
pub const MAX_GAIN: f64 = 1.0e6;
/// The largest velocity half-range or tuning width (neural units; the defaults 0.03–0.1, 1 for the open field).
pub const MAX_NU: f64 = 10.0;
/// The largest velocity tuning spread λ of the weights (the defaults about 8 and 13).
pub const MAX_LAMBDA: f64 = 1.0e4;

/// `value` finite and at most `max` (with another check for its lower end).
pub fn at_most(name: &'static str, value: f64, max: f64) -> Result<()> {
    if value.is_finite() && value <= max {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: format!("must be finite and ≤ {max}"),
        })
    }
}

/// `value` finite and at least `min` (with another check for its upper end).
pub fn at_least(name: &'static str, value: f64, min: f64) -> Result<()> {
    if value.is_finite() && value >= min {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: format!("must be finite and ≥ {min}"),
        })
    }
}

pub fn positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: "must be finite and > 0".into(),
        })
    }
}

pub fn non_positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value <= 0.0 {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: "must be finite and ≤ 0 (it is the uniform inhibition)".into(),
        })
    }
}

pub fn in_unit_interval(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: "must lie in [0, 1]".into(),
        })
    }
}

/// A finite value in `[min, max]` (bounds that keep a typo from hanging a run or allocating gigabytes).
pub fn in_range(name: &'static str, value: f64, min: f64, max: f64) -> Result<()> {
    if value.is_finite() && (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: format!("must lie in [{min}, {max}]"),
        })
    }
}

pub fn size(name: &'static str, value: usize, min: usize, max: usize) -> Result<()> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(AttractorError::BadParameter {
            name: name.into(),
            value: value.to_string(),
            why: format!("must be between {min} and {max}"),
        })
    }
}

pub fn input(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(AttractorError::NonFinite { name, value })
    }
}

pub fn array_len(name: &'static str, got: usize, expected: usize, shape: String) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(AttractorError::BadShape {
            name,
            got,
            expected,
            shape,
        })
    }
}

/// Firing rates are never negative: a state with a negative activity did not come from these networks.
pub fn array_non_negative<T: crate::real::Real>(name: &'static str, values: &[T]) -> Result<()> {
    match values.iter().position(|v| *v < T::zero()) {
        Some(index) => Err(AttractorError::BadParameter {
            name: name.into(),
            value: format!("a negative value at flat index {index}"),
            why: "activities are firing rates, ≥ 0".into(),
        }),
        None => Ok(()),
    }
}

pub fn array_finite<T: crate::real::Real>(name: &'static str, values: &[T]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(AttractorError::NonFiniteArray { name, index }),
        None => Ok(()),
    }
}

/// `n` evenly spaced velocity-axis values on `[−max, max]` (a single 0 when n = 1).
pub fn velocity_axis(n: usize, max: f64) -> Vec<f64> {
    if n == 1 {
        return vec![0.0];
    }
    (0..n)
        .map(|j| -max + 2.0 * max * j as f64 / (n - 1) as f64)
        .collect()
}

/// `n` evenly spaced angles on `[0, 2π)`.
pub fn angle_axis(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| std::f64::consts::TAU * i as f64 / n as f64)
        .collect()
}
