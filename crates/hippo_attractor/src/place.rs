//! CA3 place-cell torus (docs/spec.md §5): N×N units, `J(θ | θ') = J0 + J1 cos(|wrap(θ − θ')|)`,
//! `τ dm/dt = −m + [h + I_grid]_+` with `h = (1/N²) Σ J m` (an exact FFT convolution).
//!
//! The input is the Gaussian place input of the fused grid estimate (docs/spec.md §4):
//! `I_grid(θ) = A / sqrt(2π σx σy) · exp(−wrap(θx − μx)²/(2σx²) − wrap(θy − μy)²/(2σy²))`.
use crate::check;
use crate::circular::wrap;
use crate::dynamics::ImplicitStepper;
use crate::error::Result;
use crate::fft2::{Fft2Scratch, RealFft2};
use crate::fusion::FusedEstimate;
use crate::real::Real;
use rustfft::num_complex::Complex;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Parameters of the CA3 place torus (docs/spec.md §5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaceParams {
    /// Units per torus axis (N).
    pub n_theta: usize,
    /// Uniform inhibition `J0 ≤ 0`.
    pub j0: f64,
    /// Interaction strength `J1 > 0`.
    pub j1: f64,
    /// Amplitude A of the Gaussian grid input.
    pub input_amp: f64,
}

impl Default for PlaceParams {
    fn default() -> Self {
        Self {
            n_theta: 64,
            j0: -2.0,
            j1: 1.5,
            input_amp: 1.0,
        }
    }
}

impl PlaceParams {
    /// Check every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        check::size("place.n_theta", self.n_theta, 4, 4096)?;
        check::non_positive("place.j0", self.j0)?;
        check::at_least("place.j0", self.j0, -check::MAX_GAIN)?;
        check::positive("place.j1", self.j1)?;
        check::at_most("place.j1", self.j1, check::MAX_GAIN)?;
        check::positive("place.input_amp", self.input_amp)?;
        check::at_most("place.input_amp", self.input_amp, check::MAX_GAIN)?;
        Ok(())
    }
}

/// The CA3 place torus, driven by the fused grid estimate.
pub struct PlaceNetwork<T: Real> {
    params: PlaceParams,
    /// Mean of the cosine kernel over the torus. Its DC part acts like uniform inhibition (it is negative)
    /// and is exactly rank one here, so it joins J0 in the implicit solve instead of the explicit input.
    kernel_mean: f64,
    fft: RealFft2<T>,
    kernel_spectrum: Vec<Complex<T>>,
    scratch: Fft2Scratch<T>,
    m: Vec<T>,
    drive: Vec<T>,
    stepper: ImplicitStepper,
    input: Vec<T>,
}

impl<T: Real> PlaceNetwork<T> {
    /// A torus at rest (no bump yet); `SpatialMemory::reset` seeds it.
    pub fn new(params: PlaceParams) -> Result<Self> {
        params.validate()?;
        let n = params.n_theta;
        let fft = RealFft2::<T>::new(n);
        let mut kernel_mean = 0.0;
        for dy in 0..n {
            for dx in 0..n {
                kernel_mean += place_kernel(n, dx, dy);
            }
        }
        kernel_mean /= (n * n) as f64;
        let kernel_spectrum = fft.kernel_spectrum(|dx, dy| place_kernel(n, dx, dy) - kernel_mean);
        let scratch = fft.scratch();
        Ok(Self {
            kernel_mean,
            fft,
            kernel_spectrum,
            scratch,
            m: vec![T::zero(); n * n],
            stepper: ImplicitStepper::default(),
            drive: vec![T::zero(); n * n],
            input: vec![T::zero(); n * n],
            params,
        })
    }

    /// The torus' parameters.
    pub fn params(&self) -> &PlaceParams {
        &self.params
    }
    /// The integrator's warm start (part of the state, for save/resume).
    pub fn warm_start(&self) -> f64 {
        self.stepper.mean_guess()
    }

    /// Restore the integrator's warm start.
    pub fn set_warm_start(&mut self, mean_guess: f64) {
        self.stepper.set_mean_guess(mean_guess);
    }

    /// The activity, layout `[θy][θx]`.
    pub fn activity(&self) -> &[T] {
        &self.m
    }

    /// The Gaussian input from the fused grid estimate, layout `[θy][θx]`.
    pub fn input(&self) -> &[T] {
        &self.input
    }

    /// Replace the whole state (length N², layout `[θy][θx]`); checked before anything changes.
    pub fn set_activity(&mut self, m: &[T]) -> Result<()> {
        let n = self.params.n_theta;
        check::array_len("place activity", m.len(), n * n, format!("({n}, {n})"))?;
        check::array_finite("place activity", m)?;
        check::array_non_negative("place activity", m)?;
        self.m.copy_from_slice(m);
        Ok(())
    }

    /// Recurrent input without the inhibition: `(J1/N²) cos-kernel ⊛ m`.
    pub fn recurrent_input(&mut self, m: &[T], out: &mut [T]) {
        self.zero_mean_recurrent_input(m, out);
        let mean = m.iter().map(|x| x.f64()).sum::<f64>() / m.len() as f64;
        let dc = T::of(self.params.j1 * self.kernel_mean * mean);
        out.iter_mut().for_each(|x| *x = *x + dc);
    }

    /// The recurrent input of the zero-mean part of the kernel (the part integrated explicitly).
    fn zero_mean_recurrent_input(&mut self, m: &[T], out: &mut [T]) {
        let n2 = (self.params.n_theta * self.params.n_theta) as f64;
        let scale = T::of(self.params.j1 / n2);
        self.fft
            .convolve(m, &self.kernel_spectrum, out, scale, &mut self.scratch);
    }

    /// Set the Gaussian place input from a fused grid estimate (or silence it with `None`).
    pub fn set_grid_input(&mut self, estimate: Option<&FusedEstimate>) {
        let n = self.params.n_theta;
        match estimate {
            None => self.input.iter_mut().for_each(|x| *x = T::zero()),
            Some(e) => {
                let [mx, my] = e.mean_rad;
                let [sx, sy] = e.std_rad;
                let amp = self.params.input_amp / (TAU * sx * sy).sqrt();
                for iy in 0..n {
                    let dy = wrap(TAU * iy as f64 / n as f64 - my);
                    for ix in 0..n {
                        let dx = wrap(TAU * ix as f64 / n as f64 - mx);
                        self.input[iy * n + ix] = T::of(
                            amp * (-(dx * dx) / (2.0 * sx * sx) - (dy * dy) / (2.0 * sy * sy))
                                .exp(),
                        );
                    }
                }
            }
        }
    }

    /// Integrate one sub-step `dt_s` with time constant `tau_s`.
    pub fn step(&mut self, dt_s: f64, tau_s: f64) -> Result<()> {
        let mut drive = std::mem::take(&mut self.drive);
        let m = std::mem::take(&mut self.m);
        self.zero_mean_recurrent_input(&m, &mut drive);
        self.m = m;
        for (d, &i) in drive.iter_mut().zip(&self.input) {
            *d = *d + i;
        }
        let inhibition = self.params.j0 + self.params.j1 * self.kernel_mean;
        let stepped = self
            .stepper
            .advance(&mut self.m, &drive, inhibition, dt_s, tau_s);
        self.drive = drive;
        stepped
    }
}

/// `cos(|wrap(Δθ)|)` at grid offset (dx, dy).
pub fn place_kernel(n: usize, dx: usize, dy: usize) -> f64 {
    let tx = wrap(TAU * dx as f64 / n as f64);
    let ty = wrap(TAU * dy as f64 / n as f64);
    tx.hypot(ty).cos()
}
