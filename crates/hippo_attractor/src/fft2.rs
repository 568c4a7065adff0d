//! 2-D real FFT on an `n × n` periodic grid (row-major `[iy][ix]`), for exact circular convolutions.
//!
//! Rows go through `realfft` (n/2 + 1 bins), then the half-spectrum is transposed so that each column is
//! contiguous and one `rustfft` call transforms all columns. Spectra are stored in that transposed layout
//! `[kx][ky]`, which is all the caller needs: it only multiplies spectra pointwise.
use crate::real::Real;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

pub struct RealFft2<T: Real> {
    n: usize,
    r2c: Arc<dyn RealToComplex<T>>,
    c2r: Arc<dyn ComplexToReal<T>>,
    col_fwd: Arc<dyn Fft<T>>,
    col_inv: Arc<dyn Fft<T>>,
}

/// Per-thread work buffers.
pub struct Fft2Scratch<T: Real> {
    row: Vec<T>,
    row_spec: Vec<Complex<T>>,
    half: Vec<Complex<T>>,
    fft_scratch: Vec<Complex<T>>,
    /// A spectrum buffer for [`RealFft2::convolve`].
    spectrum: Vec<Complex<T>>,
}

impl<T: Real> RealFft2<T> {
    pub fn new(n: usize) -> Self {
        let mut rp = RealFftPlanner::<T>::new();
        let mut cp = FftPlanner::<T>::new();
        Self {
            n,
            r2c: rp.plan_fft_forward(n),
            c2r: rp.plan_fft_inverse(n),
            col_fwd: cp.plan_fft_forward(n),
            col_inv: cp.plan_fft_inverse(n),
        }
    }

    pub fn n(&self) -> usize {
        self.n
    }

    /// Number of complex values in a spectrum: `(n/2 + 1) · n`.
    pub fn spectrum_len(&self) -> usize {
        (self.n / 2 + 1) * self.n
    }

    pub fn scratch(&self) -> Fft2Scratch<T> {
        let nh = self.n / 2 + 1;
        let s = self
            .col_fwd
            .get_inplace_scratch_len()
            .max(self.col_inv.get_inplace_scratch_len())
            .max(self.r2c.get_scratch_len())
            .max(self.c2r.get_scratch_len());
        Fft2Scratch {
            row: vec![T::zero(); self.n],
            row_spec: vec![Complex::default(); nh],
            half: vec![Complex::default(); nh * self.n],
            fft_scratch: vec![Complex::default(); s],
            spectrum: vec![Complex::default(); nh * self.n],
        }
    }

    /// Forward transform of `input` (n·n) into `spectrum` ([`Self::spectrum_len`], transposed half spectrum).
    pub fn forward(&self, input: &[T], spectrum: &mut [Complex<T>], scratch: &mut Fft2Scratch<T>) {
        let n = self.n;
        let nh = n / 2 + 1;
        for iy in 0..n {
            scratch.row.copy_from_slice(&input[iy * n..(iy + 1) * n]);
            // Lengths are ours, so the only possible error (buffer size) cannot happen.
            let _ = self.r2c.process_with_scratch(
                &mut scratch.row,
                &mut scratch.row_spec,
                &mut scratch.fft_scratch,
            );
            for kx in 0..nh {
                spectrum[kx * n + iy] = scratch.row_spec[kx];
            }
        }
        self.col_fwd
            .process_with_scratch(spectrum, &mut scratch.fft_scratch);
    }

    /// Inverse transform of `spectrum` (destroyed) into `out` (n·n), scaled by `scale`
    /// (pass `1/n²` for a true inverse).
    pub fn inverse(
        &self,
        spectrum: &mut [Complex<T>],
        out: &mut [T],
        scale: T,
        scratch: &mut Fft2Scratch<T>,
    ) {
        let n = self.n;
        let nh = n / 2 + 1;
        self.col_inv
            .process_with_scratch(spectrum, &mut scratch.fft_scratch);
        for kx in 0..nh {
            for iy in 0..n {
                scratch.half[iy * nh + kx] = spectrum[kx * n + iy];
            }
        }
        for iy in 0..n {
            scratch
                .row_spec
                .copy_from_slice(&scratch.half[iy * nh..(iy + 1) * nh]);
            // A real signal's DC (and, for even n, Nyquist) bins are real; rounding leaves tiny imaginary
            // parts that realfft would reject, so drop them.
            scratch.row_spec[0].im = T::zero();
            if n.is_multiple_of(2) {
                scratch.row_spec[nh - 1].im = T::zero();
            }
            let _ = self.c2r.process_with_scratch(
                &mut scratch.row_spec,
                &mut scratch.row,
                &mut scratch.fft_scratch,
            );
            for (o, &r) in out[iy * n..(iy + 1) * n].iter_mut().zip(&scratch.row) {
                *o = r * scale;
            }
        }
    }

    /// Spectrum of a kernel given as a function of the grid offset `(dx, dy)`, in the transposed layout.
    pub fn kernel_spectrum(&self, kernel: impl Fn(usize, usize) -> f64) -> Vec<Complex<T>> {
        let n = self.n;
        let mut values = vec![T::zero(); n * n];
        for iy in 0..n {
            for ix in 0..n {
                values[iy * n + ix] = T::of(kernel(ix, iy));
            }
        }
        let mut spectrum = vec![Complex::default(); self.spectrum_len()];
        self.forward(&values, &mut spectrum, &mut self.scratch());
        spectrum
    }

    /// Circular convolution `out = scale · (kernel ⊛ input)` with a precomputed kernel spectrum.
    pub fn convolve(
        &self,
        input: &[T],
        kernel_spectrum: &[Complex<T>],
        out: &mut [T],
        scale: T,
        scratch: &mut Fft2Scratch<T>,
    ) {
        let mut spectrum = std::mem::take(&mut scratch.spectrum);
        self.forward(input, &mut spectrum, scratch);
        for (s, k) in spectrum.iter_mut().zip(kernel_spectrum) {
            *s = *s * *k;
        }
        self.inverse(&mut spectrum, out, scale * self.inverse_scale(), scratch);
        scratch.spectrum = spectrum;
    }

    /// `1/n²`: the factor that makes [`Self::inverse`] a true inverse.
    pub fn inverse_scale(&self) -> T {
        T::one() / T::of((self.n * self.n) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn convolution_matches_direct_sum() {
        for n in [5usize, 8, 12] {
            let fft = RealFft2::<f64>::new(n);
            let kernel = |dx: usize, dy: usize| ((dx * 3 + dy * 7) % 5) as f64 - 1.5;
            let spec = fft.kernel_spectrum(kernel);
            let input: Vec<f64> = (0..n * n).map(|i| ((i * 13) % 11) as f64 * 0.1).collect();
            let mut out = vec![0.0; n * n];
            let mut s = fft.scratch();
            fft.convolve(&input, &spec, &mut out, 1.0, &mut s);
            for y in 0..n {
                for x in 0..n {
                    let mut acc = 0.0;
                    for yp in 0..n {
                        for xp in 0..n {
                            acc += kernel((x + n - xp) % n, (y + n - yp) % n) * input[yp * n + xp];
                        }
                    }
                    assert!((acc - out[y * n + x]).abs() < 1e-10, "n={n} ({x},{y})");
                }
            }
        }
    }
}
