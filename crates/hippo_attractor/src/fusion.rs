//! Bayesian (precision-weighted) fusion of the grid modules' bumps (docs/spec.md §4).
//!
//! Per axis, with the coarsest module's bump as reference `μ_ref`:
//! `1/σ_f² = Σ_m 1/σ_m²`, `μ_f = wrap(μ_ref + σ_f² Σ_m wrap(μ_m − μ_ref)/σ_m²)`.
//! This is the mean of the product of Gaussians, taken on the circle around the reference; the paper's
//! nested-wrap formula is a sloppy form of it.
use crate::circular::wrap;
use crate::error::{AttractorError, Result};
use serde::{Deserialize, Serialize};

/// One bump on the 2-D neural torus: centre (rad) and per-axis standard deviation (rad).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bump2 {
    /// Centre `(θx, θy)` on the torus (rad).
    pub mean_rad: [f64; 2],
    /// Per-axis standard deviation `(σx, σy)` (rad).
    pub std_rad: [f64; 2],
    /// Total activity inside the bump (used to rank bumps, not in the fusion).
    pub mass: f64,
}

/// Result of fusing several modules' homocentric bumps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FusedEstimate {
    /// Fused centre `(θx, θy)` on the torus (rad).
    pub mean_rad: [f64; 2],
    /// Per-axis standard deviation of the fused estimate (rad).
    pub std_rad: [f64; 2],
}

/// The narrowest bump the fusion takes (rad): a unit is about 0.1 rad wide on the default torus.
pub const MIN_BUMP_STD_RAD: f64 = 1e-12;

/// Fuse one bump per module. `bumps[0]` is the reference (the coarsest module present).
pub fn fuse_bumps(bumps: &[Bump2]) -> Result<FusedEstimate> {
    let reference = bumps.first().ok_or(AttractorError::NothingToFuse)?;
    let mut mean_rad = [0.0; 2];
    let mut std_rad = [0.0; 2];
    for axis in 0..2 {
        let mut precision = 0.0;
        let mut weighted_offset = 0.0;
        for b in bumps {
            let s = b.std_rad[axis];
            // Narrower than MIN_BUMP_STD_RAD its precision 1/σ² overflows (σ = 1e-160 fused to NaN).
            if !(s.is_finite() && s >= MIN_BUMP_STD_RAD && b.mean_rad[axis].is_finite()) {
                return Err(AttractorError::BadBump(format!(
                    "bump with centre {:?} and std {:?}: std must be finite and at least {MIN_BUMP_STD_RAD:e} rad",
                    b.mean_rad, b.std_rad
                )));
            }
            let p = 1.0 / (s * s);
            precision += p;
            weighted_offset += p * wrap(b.mean_rad[axis] - reference.mean_rad[axis]);
        }
        let var = 1.0 / precision;
        mean_rad[axis] =
            crate::circular::wrap_2pi(reference.mean_rad[axis] + var * weighted_offset);
        std_rad[axis] = var.sqrt();
    }
    Ok(FusedEstimate { mean_rad, std_rad })
}

/// Choose, from each finer module, the bump nearest (torus distance) to the running estimate and fuse.
///
/// `modules[0]` must be the coarsest module. A module with no bump (lesioned, or silent) is passed as an
/// empty slice and simply leaves the fusion. The reference is the coarsest present module's bump nearest to
/// `prior` (the previous estimate, so that the code stays continuous when the coarsest module has several
/// bumps, e.g. after a ventral lesion), or its strongest bump without a prior.
pub fn fuse_homocentric(
    modules: &[&[Bump2]],
    prior: Option<[f64; 2]>,
) -> Result<(FusedEstimate, Vec<Bump2>)> {
    if let Some(p) = prior {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return Err(AttractorError::BadBump(format!(
                "prior {p:?}: the previous estimate must be finite (or None)"
            )));
        }
    }
    let mut chosen: Vec<Bump2> = Vec::with_capacity(modules.len());
    for bumps in modules.iter().filter(|b| !b.is_empty()) {
        let pick = if chosen.is_empty() {
            match prior {
                Some(p) => *bumps
                    .iter()
                    .min_by(|a, b| {
                        torus_distance(a.mean_rad, p).total_cmp(&torus_distance(b.mean_rad, p))
                    })
                    .ok_or(AttractorError::NothingToFuse)?,
                None => *bumps
                    .iter()
                    .max_by(|a, b| a.mass.total_cmp(&b.mass))
                    .ok_or(AttractorError::NothingToFuse)?,
            }
        } else {
            let estimate = fuse_bumps(&chosen)?;
            *bumps
                .iter()
                .min_by(|a, b| {
                    torus_distance(a.mean_rad, estimate.mean_rad)
                        .total_cmp(&torus_distance(b.mean_rad, estimate.mean_rad))
                })
                .ok_or(AttractorError::NothingToFuse)?
        };
        chosen.push(pick);
    }
    let fused = fuse_bumps(&chosen)?;
    Ok((fused, chosen))
}

fn torus_distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    wrap(a[0] - b[0]).hypot(wrap(a[1] - b[1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bump(mx: f64, my: f64, sx: f64, sy: f64) -> Bump2 {
        Bump2 {
            mean_rad: [mx, my],
            std_rad: [sx, sy],
            mass: 1.0,
        }
    }

    /// The paper's table (bold bumps of the 16-, 4- and 1-bump modules) and its fused check value
    /// (docs/spec.md §4).
    #[test]
    fn reproduces_paper_table_check_value() {
        let coarse = bump(1.77, 0.34, 21.39, 20.48);
        let mid = bump(1.75, 6.17, 5.42, 10.84);
        let fine = bump(1.71, 6.20, 1.16, 2.02);
        let f = fuse_bumps(&[coarse, mid, fine]).unwrap();
        assert!((f.mean_rad[0] - 1.712).abs() < 1e-3, "{:?}", f);
        assert!((f.mean_rad[1] - 6.203).abs() < 1e-3, "{:?}", f);
        assert!((f.std_rad[0] - 1.133).abs() < 1e-3, "{:?}", f);
        assert!((f.std_rad[1] - 1.977).abs() < 1e-3, "{:?}", f);
    }

    #[test]
    fn homocentric_selection_picks_the_bump_near_the_reference() {
        let coarse = [bump(1.0, 1.0, 1.0, 1.0)];
        // Four bumps of a k = 2 module; only one sits near (1, 1).
        let mid = [
            bump(1.1, 0.9, 0.3, 0.3),
            bump(1.1 + std::f64::consts::PI, 0.9, 0.3, 0.3),
            bump(1.1, 0.9 + std::f64::consts::PI, 0.3, 0.3),
            bump(
                1.1 + std::f64::consts::PI,
                0.9 + std::f64::consts::PI,
                0.3,
                0.3,
            ),
        ];
        let (fused, chosen) = fuse_homocentric(&[&coarse, &mid], None).unwrap();
        assert_eq!(chosen[1].mean_rad, [1.1, 0.9]);
        assert!(fused.std_rad[0] < 0.3);
        assert!((fused.mean_rad[0] - 1.1).abs() < 0.01);
    }

    #[test]
    fn lesioned_module_leaves_the_fusion_and_widens_it() {
        let coarse = [bump(1.0, 1.0, 2.0, 2.0)];
        let mid = [bump(1.0, 1.0, 0.8, 0.8)];
        let fine = [bump(1.0, 1.0, 0.3, 0.3)];
        let all = fuse_homocentric(&[&coarse, &mid, &fine], None).unwrap().0;
        let no_dorsal = fuse_homocentric(&[&coarse, &mid, &[]], None).unwrap().0;
        let no_ventral = fuse_homocentric(&[&[], &mid, &fine], None).unwrap().0;
        assert!(no_dorsal.std_rad[0] > no_ventral.std_rad[0]);
        assert!(no_ventral.std_rad[0] > all.std_rad[0]);
    }

    #[test]
    fn prior_selects_the_reference_among_several_coarse_bumps() {
        let mid = [bump(1.0, 1.0, 0.3, 0.3), bump(4.1, 4.1, 0.3, 0.3)];
        let (f, _) = fuse_homocentric(&[&[], &mid], Some([4.0, 4.2])).unwrap();
        assert!((f.mean_rad[0] - 4.1).abs() < 1e-9);
    }

    #[test]
    fn rejects_non_positive_width() {
        assert!(fuse_bumps(&[bump(0.0, 0.0, 0.0, 1.0)]).is_err());
        assert!(fuse_bumps(&[]).is_err());
    }
}
