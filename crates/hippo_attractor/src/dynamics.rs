//! Time integration shared by every network: `τ dm/dt = −m + [h_rec + J0·⟨m⟩ + I]_+`.
//!
//! Why not explicit Euler: the uniform inhibition `J0·⟨m⟩` (the mean over all units) is the stiff part —
//! it acts on the uniform mode at a rate ≈ (1 + |J0|·fraction active)/τ and forced explicit steps of τ/300 in
//! the prototype. It is rank one, so we treat it implicitly, and integrate the leak exactly (exponential
//! Euler), with the pattern-forming recurrent input `h_rec` and the external input `I` held over the step:
//!
//! `m⁺ = a·m + (1 − a)·[g + J0·s⁺]_+`, with `a = exp(−dt/τ)`, `g = h_rec + I`, `s⁺ = ⟨m⁺⟩`.
//!
//! Taking the mean of both sides gives one monotone scalar equation for `s⁺`:
//! `F(s) = s − a·⟨m⟩ − (1 − a)·⟨[g + J0·s]_+⟩ = 0`. Since `J0 < 0`, `F` is increasing and concave and piecewise
//! linear, so Newton's method from `s = 0` (where `F ≤ 0`) climbs monotonically to the exact root, finishing
//! when the active set stops changing (a handful of passes over the units).
//!
//! A side effect of the exact leak: a bump whose weights shift it by `ν` per unit of recurrent drive moves
//! `(1 − a)·ν` per step, i.e. at `ν/τ_eff` with `τ_eff = dt/(1 − e^{−dt/τ})` (→ τ as dt → 0). The velocity
//! mappings use `τ_eff` so that path integration is exact to first order at any step size.
use crate::lanes;
use crate::real::Real;
use rayon::prelude::*;

/// Decay factor `a = exp(−dt/τ)` of one step.
pub fn decay(dt_s: f64, tau_s: f64) -> f64 {
    (-dt_s / tau_s).exp()
}

/// Effective time constant of the exponential-Euler step (see module docs).
pub fn tau_effective(dt_s: f64, tau_s: f64) -> f64 {
    dt_s / (1.0 - decay(dt_s, tau_s))
}

/// The integrator's memory between steps: the last solved mean activity, a warm start for the next solve.
#[derive(Clone, Copy, Debug, Default)]
pub struct ImplicitStepper {
    mean_guess: f64,
}

impl ImplicitStepper {
    /// One step of `dt_s` (see the module docs); fails if the state diverged.
    pub fn advance<T: Real>(
        &mut self,
        m: &mut [T],
        drive: &[T],
        j0: f64,
        dt_s: f64,
        tau_s: f64,
    ) -> crate::error::Result<()> {
        let mean = step_with_implicit_inhibition(m, drive, j0, decay(dt_s, tau_s), self.mean_guess);
        if !mean.is_finite() {
            return Err(crate::error::AttractorError::Diverged);
        }
        self.mean_guess = mean;
        Ok(())
    }

    /// The warm start of the next solve (part of the state, for save/resume: the solve stops at a
    /// tolerance, so another start gives another last bit).
    pub fn mean_guess(&self) -> f64 {
        self.mean_guess
    }

    /// Restore the warm start (a non-finite value is ignored: the solve then starts cold).
    pub fn set_mean_guess(&mut self, mean_guess: f64) {
        self.mean_guess = if mean_guess.is_finite() {
            mean_guess
        } else {
            0.0
        };
    }
}

/// Sum of consecutive rows of `width` values (e.g. activity summed over the velocity axes).
pub fn sum_rows<T: Real>(m: &[T], width: usize) -> Vec<T> {
    let mut out = vec![T::zero(); width];
    for row in m.chunks(width) {
        for (a, &b) in out.iter_mut().zip(row) {
            *a = *a + b;
        }
    }
    out
}

/// Sum and count of the positive entries of `drive + offset` (chunked, parallel, f64 across chunks).
fn positive_part<T: Real>(drive: &[T], offset: T) -> (f64, usize) {
    drive
        .par_chunks(CHUNK)
        .map(|c| lanes::positive_part(c, offset))
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

const CHUNK: usize = 4096;

/// Activity below this is zero: the unit is silent.
///
/// An inhibited unit decays by `a` every sub-step, and after a reset most units are inhibited: without a
/// floor their activity went on down through f32's subnormal numbers (below 1.2e-38), whose arithmetic is
/// about a hundred times slower on x86, in the update here and in the transforms of the recurrent input
/// (products of tiny activity and small kernel coefficients), until it underflowed. The first ten frames after
/// a reset took about 460 ms instead of 75 (`cargo bench -p hippo_attractor --bench attractor`,
/// `first_frames_after_reset`). At 1e-30 the products stay normal, and a slice of units that has fallen
/// silent is skipped by the grid's transforms. The floor is thirty orders below a bump's activity: the
/// decoded bumps, the trajectories and every record but the recorded rates' last 1e-29 are the same bit for
/// bit (real KITTI 06, docs/results.md "Cost").
pub const SILENT_BELOW: f64 = 1e-30;

/// Mean of a state vector (chunked, parallel).
pub fn mean<T: Real>(m: &[T]) -> f64 {
    m.par_chunks(CHUNK).map(lanes::sum).sum::<f64>() / m.len() as f64
}

/// One step in place. `drive` is `g = h_rec + I` (everything but the inhibition); `j0 ≤ 0`; `guess` is a
/// starting point for the mean (the previous step's is ideal). Returns the new mean activity.
pub fn step_with_implicit_inhibition<T: Real>(
    m: &mut [T],
    drive: &[T],
    j0: f64,
    a: f64,
    guess: f64,
) -> f64 {
    let n = m.len() as f64;
    let old_mean = mean(m);
    let gain = 1.0 - a;
    // Newton on the concave increasing F: from the right of the root the first step lands on the left,
    // from the left it climbs monotonically; a linear piece is solved exactly, so it stops when the
    // active set repeats.
    let mut s = if guess.is_finite() {
        guess.max(0.0)
    } else {
        0.0
    };
    let mut last_active = usize::MAX;
    for _ in 0..64 {
        let (sum_pos, active) = positive_part(drive, T::of(j0 * s));
        let f = s - a * old_mean - gain * sum_pos / n;
        let df = 1.0 - gain * j0 * active as f64 / n;
        let next = (s - f / df).max(0.0);
        let done = active == last_active || f.abs() <= 1e-13 * (1.0 + s.abs());
        s = next;
        if done {
            break;
        }
        last_active = active;
    }
    let a_t = T::of(a);
    let gain_t = T::of(gain);
    let j0s = T::of(j0 * s);
    let zero = T::zero();
    let silent_below = T::of(SILENT_BELOW);
    m.par_chunks_mut(CHUNK)
        .zip(drive.par_chunks(CHUNK))
        .for_each(|(mc, dc)| {
            for (mi, &g) in mc.iter_mut().zip(dc) {
                let v = g + j0s;
                let next = a_t * *mi + gain_t * if v > zero { v } else { zero };
                *mi = if next < silent_below { zero } else { next };
            }
        });
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit held below threshold decays geometrically and falls silent (exactly zero) at `SILENT_BELOW`,
    /// never passing through the subnormal numbers, in f32 and in f64.
    #[test]
    fn inhibited_units_fall_silent_instead_of_decaying_into_subnormals() {
        fn check<T: Real>() {
            let mut m: Vec<T> = (0..64).map(|i| T::of(1.0 + i as f64)).collect();
            let drive = vec![T::of(-1.0); 64]; // every unit inhibited
            for step in 0..3000 {
                step_with_implicit_inhibition(&mut m, &drive, -5.0, 0.9, 0.0);
                let tiny = m
                    .iter()
                    .find(|&&x| x != T::zero() && x.f64() < SILENT_BELOW);
                assert!(
                    tiny.is_none(),
                    "step {step}: activity {:?}",
                    tiny.map(|x| x.f64())
                );
            }
            assert!(
                m.iter().all(|&x| x == T::zero()),
                "0.9^3000 of at most 64 is silent"
            );
        }
        check::<f32>();
        check::<f64>();
    }

    /// The returned mean is the mean of the updated state: the implicit equation is solved exactly.
    #[test]
    fn implicit_mean_is_self_consistent() {
        let drive: Vec<f64> = (0..500)
            .map(|i| ((i as f64) * 0.37).sin() * 2.0 + 0.3)
            .collect();
        let mut m: Vec<f64> = (0..500).map(|i| ((i as f64) * 0.11).cos().abs()).collect();
        let s = step_with_implicit_inhibition(&mut m, &drive, -5.0, decay(0.01, 0.01), 0.0);
        let mean = m.iter().sum::<f64>() / m.len() as f64;
        assert!((s - mean).abs() < 1e-12, "{s} vs {mean}");
    }

    /// With J0 implicit, a huge inhibition does not make the uniform mode oscillate even at dt = 5τ.
    #[test]
    fn strong_inhibition_is_stable_at_large_steps() {
        let drive = vec![1.0f64; 100];
        let mut m = vec![0.0f64; 100];
        let a = decay(0.05, 0.01);
        let mut means = vec![];
        for _ in 0..20 {
            means.push(step_with_implicit_inhibition(
                &mut m, &drive, -200.0, a, 0.5,
            ));
        }
        // Fixed point of m = [1 − 200 m]_+ is 1/201; approached monotonically.
        let target = 1.0 / 201.0;
        assert!((means.last().unwrap() - target).abs() < 1e-9);
        assert!(means.windows(2).all(|w| w[1] >= w[0] - 1e-15));
    }

    #[test]
    fn effective_tau_tends_to_tau() {
        assert!((tau_effective(1e-6, 0.01) - 0.01).abs() < 1e-6);
        assert!(tau_effective(0.01, 0.01) > 0.015);
    }
}
