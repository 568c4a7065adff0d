//! Grid-by-velocity torus attractor (docs/spec.md §3): units on `(θx, θy) ∈ [0, 2π)²` (N×N)
//! × `(νx, νy) ∈ [−L, L]²` (M×M). Module `k` has `k` bumps per axis (`k²` on the torus).
//!
//! Weights `J = J0 + Jk cos(k·|wrap(θ − θ' − ν')|) · cos(λ|ν − ν'|)` with `h = (1/(N²M²)) Σ J m`.
//! The `Jk` term is translation invariant in θ with a shift that depends only on the presynaptic velocity
//! `ν'`, so for each presynaptic velocity slice it is an exact circular convolution over θ (the kernel has a
//! kink at ±π, so each slice gets its own precomputed kernel spectrum — a phase ramp would not be exact),
//! followed by a dense mixing over velocity: `h(·, ν) = Σ_ν' cos(λ|ν − ν'|) · (K_ν' ⊛ m_ν')`.
//! Silent slices (all zero) are skipped: still exact.
//!
//! Lattice-symmetric subspace. The weights are invariant under translation by `2π/k` along either torus
//! axis, so the subspace of patterns with that period is invariant under the dynamics: a module holding
//! `k²` identical bumps keeps them identical forever in exact arithmetic. We integrate the dynamics *in*
//! that subspace, on one `(N/k)×(N/k)` unit cell with the kernel folded over the `k²` cells
//! (`K_fold(Δ) = Σ_j K(Δ + 2πj/k)`) — exactly the paper's dynamics for such states, `k²` times cheaper.
//! Why: the strongest Fourier modes of `cos(k·r)` on the square torus are not `(k, 0)` but `(2, 1)` for
//! k = 2 and `(3, 3)` for k = 4, so the square `k×k` lattice is not the full network's preferred pattern:
//! in double precision a moving k = 2 or k = 4 lattice broke into other patterns (3, 20 bumps) within a
//! second (see docs/model.md). Restricted to the subspace, the lattice is the stable single bump per cell.
//! Layout: `m[s·C² + iy·C + ix]` over one cell (`C = N/k`) with velocity slice `s = jy·M + jx`;
//! [`GridModule::activity`] and [`GridModule::layer2`] tile it back to the full N×N torus.
//!
//! The velocity mixing runs in frequency space, factored. `V = cos(λ|ν − ν'|)` is a smooth (entire) function
//! of `ν − ν'` over a small range, so its eigenvalues fall off fast: of the 81 of the default module, 10 are
//! above `81·ε·max|σ|` in f32 (the numerical rank, LAPACK's and numpy's convention; 32 in f64). With
//! `V = U diag(σ) Uᵀ` truncated to the numerical rank `r`,
//! `h = U diag(σ) · IFFT(Σ_ν' U[ν', r] · K̂_ν' · m̂_ν')`: every slice is transformed forward once, but only
//! `r` spectra come back (10 instead of 81 inverse FFTs in f32), and the two mixing products are `r/M²` the
//! size of the dense one. The dropped part is below the rounding error of the dense product itself
//! (`tests/exact_recurrent_input.rs` checks the result against the dense double sum in f64 and f32).
use crate::check;
use crate::circular::wrap;
use crate::dynamics::{sum_rows, ImplicitStepper};
use crate::error::{AttractorError, Result};
use crate::fft2::RealFft2;
use crate::lanes;
use crate::real::Real;
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Parameters of one grid-by-velocity module (docs/spec.md §3); defaults from `SpatialMemoryParams`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridParams {
    /// Wave number k: bumps per torus axis (1, 2, 4 in the paper).
    pub k: usize,
    /// Units per torus axis (N).
    pub n_theta: usize,
    /// Units per velocity axis (M).
    pub n_nu: usize,
    /// Half-range `L_t` of each velocity axis (neural units).
    pub nu_max: f64,
    /// Velocity-tuning spread λ of the weights.
    pub lambda: f64,
    /// Uniform inhibition `J0 < 0`.
    pub j0: f64,
    /// Interaction strength `Jk > 0`.
    pub jk: f64,
    /// Velocity input amplitude `I_t`.
    pub input_amp: f64,
    /// Velocity tuning strength `ε ∈ [0, 1]`.
    pub input_tuning: f64,
    /// Velocity tuning width `σ_t` (neural units).
    pub input_sigma: f64,
    /// Gain of the velocity-pinning feedback (0 disables it; see `step`).
    pub pin_gain: f64,
}

/// Units of one module at most (`n_theta² · n_nu²`; the default has 331 776): a typo must not allocate
/// gigabytes.
pub const MAX_GRID_UNITS: usize = 1 << 22;

impl GridParams {
    /// Documented defaults for module `k` (see docs/model.md for how they were chosen).
    pub fn for_module(k: usize) -> Self {
        let nu_max = 0.06;
        Self {
            k,
            n_theta: 64,
            n_nu: 9,
            nu_max,
            lambda: std::f64::consts::PI / (4.0 * nu_max),
            j0: -6000.0,
            jk: 3000.0,
            input_amp: 1.0,
            input_tuning: 0.5,
            input_sigma: 0.5 * nu_max,
            pin_gain: 0.3,
        }
    }

    /// Check every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        check::size("grid.k", self.k, 1, 16)?;
        check::size("grid.n_theta", self.n_theta, 4, 1024)?;
        check::size("grid.n_nu", self.n_nu, 1, 64)?;
        check::positive("grid.nu_max", self.nu_max)?;
        check::at_most("grid.nu_max", self.nu_max, check::MAX_NU)?;
        check::positive("grid.lambda", self.lambda)?;
        check::at_most("grid.lambda", self.lambda, check::MAX_LAMBDA)?;
        check::non_positive("grid.j0", self.j0)?;
        check::at_least("grid.j0", self.j0, -check::MAX_GAIN)?;
        check::positive("grid.jk", self.jk)?;
        check::at_most("grid.jk", self.jk, check::MAX_GAIN)?;
        check::positive("grid.input_amp", self.input_amp)?;
        check::at_most("grid.input_amp", self.input_amp, check::MAX_GAIN)?;
        check::in_unit_interval("grid.input_tuning", self.input_tuning)?;
        check::positive("grid.input_sigma", self.input_sigma)?;
        check::at_most("grid.input_sigma", self.input_sigma, check::MAX_NU)?;
        check::in_unit_interval("grid.pin_gain", self.pin_gain)?;
        check::size(
            "grid.units (n_theta² · n_nu²)",
            self.n_units(),
            1,
            MAX_GRID_UNITS,
        )?;
        if !self.n_theta.is_multiple_of(self.k) || self.n_theta / self.k < 2 {
            return Err(AttractorError::BadParameter {
                name: "grid.n_theta".into(),
                value: self.n_theta.to_string(),
                why: format!(
                    "must be a multiple of k = {} with at least 2 units per bump cell",
                    self.k
                ),
            });
        }
        Ok(())
    }

    /// Velocity slices of the conjunctive layer (`n_nu²`).
    pub fn n_slices(&self) -> usize {
        self.n_nu * self.n_nu
    }

    /// Units of the full 4-D network (N²M²).
    pub fn n_units(&self) -> usize {
        self.n_theta * self.n_theta * self.n_slices()
    }

    /// Units per axis of the unit cell that holds one bump (N/k).
    pub fn cell(&self) -> usize {
        self.n_theta / self.k
    }

    /// The θ part of the weight: `cos(k·|wrap(Δθ − ν')|)`.
    pub fn theta_kernel(&self, dtheta: [f64; 2], nu_pre: [f64; 2]) -> f64 {
        let dx = wrap(dtheta[0] - nu_pre[0]);
        let dy = wrap(dtheta[1] - nu_pre[1]);
        (self.k as f64 * dx.hypot(dy)).cos()
    }

    /// The velocity part of the weight: `cos(λ|ν − ν'|)`.
    pub fn nu_kernel(&self, nu_post: [f64; 2], nu_pre: [f64; 2]) -> f64 {
        (self.lambda * (nu_post[0] - nu_pre[0]).hypot(nu_post[1] - nu_pre[1])).cos()
    }
}

/// One grid-by-velocity torus with `k` bumps per axis, integrated in its lattice-symmetric unit cell.
pub struct GridModule<T: Real> {
    params: GridParams,
    nu: Vec<f64>,
    fft: RealFft2<T>,
    /// One kernel spectrum per presynaptic velocity slice.
    kernel_spectra: Vec<Vec<Complex<T>>>,
    /// The velocity mixing `cos(λ|ν_s − ν_s'|)` factored as `mix_out · mix_in` (see module docs).
    mix: VelocityMix<T>,
    m: Vec<T>,
    drive: Vec<T>,
    stepper: ImplicitStepper,
    work: MixWork<T>,
    /// Integral term of the velocity-pinning loop (neural units).
    pin_bias: [f64; 2],
}

impl<T: Real> GridModule<T> {
    /// A module at rest (no bump yet); `SpatialMemory::reset` seeds it.
    pub fn new(params: GridParams) -> Result<Self> {
        params.validate()?;
        let n = params.n_theta;
        let (k, c) = (params.k, params.cell());
        let nu = check::velocity_axis(params.n_nu, params.nu_max);
        let fft = RealFft2::<T>::new(c);
        let slices = slice_velocities(&nu);
        // Kernel folded over the k² cells: the exact recurrent input for cell-periodic activity.
        let kernel_spectra = slices
            .par_iter()
            .map(|&v| {
                fft.kernel_spectrum(|dx, dy| {
                    let mut acc = 0.0;
                    for jy in 0..k {
                        for jx in 0..k {
                            let tx = TAU * (dx + jx * c) as f64 / n as f64;
                            let ty = TAU * (dy + jy * c) as f64 / n as f64;
                            acc += params.theta_kernel([tx, ty], v);
                        }
                    }
                    acc
                })
            })
            .collect();
        let dense_mix: Vec<f64> = slices
            .iter()
            .flat_map(|&a| slices.iter().map(move |&b| (a, b)))
            .map(|(a, b)| params.nu_kernel(a, b))
            .collect();
        let mix = VelocityMix::new(&dense_mix, slices.len());
        let units = c * c * params.n_slices();
        let work = MixWork::new(&fft, &mix, slices.len());
        let mut module = Self {
            nu,
            fft,
            kernel_spectra,
            mix,
            m: vec![T::zero(); units],
            stepper: ImplicitStepper::default(),
            drive: vec![T::zero(); units],
            work,
            pin_bias: [0.0; 2],
            params,
        };
        module.seed([0.0, 0.0]);
        Ok(module)
    }

    /// The module's parameters.
    pub fn params(&self) -> &GridParams {
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

    /// Integral term of the velocity-pinning loop (part of the state, for save/resume).
    pub fn pin_bias(&self) -> [f64; 2] {
        self.pin_bias
    }

    /// Restore the pinning loop's integral term (clamped to the velocity axis).
    pub fn set_pin_bias(&mut self, bias: [f64; 2]) {
        let lim = self.params.nu_max;
        self.pin_bias = [bias[0].clamp(-lim, lim), bias[1].clamp(-lim, lim)];
    }

    /// The integrated state: one unit cell per velocity slice (`M² · C²`).
    pub fn cell_activity(&self) -> &[T] {
        &self.m
    }

    /// The full conjunctive activity (`M² · N²`, layout `[νy][νx][θy][θx]`), tiled from the cell.
    pub fn activity(&self) -> Vec<T> {
        self.tile(&self.m)
    }

    /// The activity's shape, for messages.
    pub fn shape(&self) -> String {
        let (n, m) = (self.params.n_theta, self.params.n_nu);
        format!("(n_nu_y={m}, n_nu_x={m}, n_theta_y={n}, n_theta_x={n})")
    }

    /// Set the state from a full conjunctive activity; it is projected onto the lattice-symmetric
    /// subspace (the average over the k² cells).
    pub fn set_activity(&mut self, m: &[T]) -> Result<()> {
        check::array_len(
            "grid activity",
            m.len(),
            self.params.n_units(),
            self.shape(),
        )?;
        check::array_finite("grid activity", m)?;
        check::array_non_negative("grid activity", m)?;
        self.m = self.fold(m);
        Ok(())
    }

    /// Tile cell-layout slices (`S · C²`) to full-torus slices (`S · N²`).
    pub fn tile(&self, cells: &[T]) -> Vec<T> {
        let (n, c) = (self.params.n_theta, self.params.cell());
        let mut out = Vec::with_capacity(cells.len() / (c * c) * n * n);
        for slice in cells.chunks(c * c) {
            for iy in 0..n {
                for ix in 0..n {
                    out.push(slice[(iy % c) * c + ix % c]);
                }
            }
        }
        out
    }

    /// Average full-torus slices (`S · N²`) over the k² cells into cell layout (`S · C²`).
    pub fn fold(&self, full: &[T]) -> Vec<T> {
        let (n, c, k) = (self.params.n_theta, self.params.cell(), self.params.k);
        let inv = 1.0 / (k * k) as f64;
        let mut out = Vec::with_capacity(full.len() / (n * n) * c * c);
        for slice in full.chunks(n * n) {
            for iy in 0..c {
                for ix in 0..c {
                    // Summed in f64: k² copies of one f32 value then average back to exactly that value,
                    // so a tiled state folds to itself (a saved state resumes bit for bit).
                    let mut acc = 0.0;
                    for jy in 0..k {
                        for jx in 0..k {
                            acc += slice[(iy + jy * c) * n + ix + jx * c].f64();
                        }
                    }
                    out.push(T::of(acc * inv));
                }
            }
        }
        out
    }

    /// Velocity of each slice along one axis (neural units).
    pub fn nu_axis(&self) -> &[f64] {
        &self.nu
    }

    /// Seed the lattice (`k` bumps per axis, one of them at `phase_rad`), concentrated at zero velocity.
    pub fn seed(&mut self, phase_rad: [f64; 2]) {
        let (n, c) = (self.params.n_theta, self.params.cell());
        self.pin_bias = [0.0; 2];
        let k = self.params.k as f64;
        let slices = slice_velocities(&self.nu);
        let w = 0.5 * self.params.nu_max;
        for (s, v) in slices.iter().enumerate() {
            let g = (-(v[0] * v[0] + v[1] * v[1]) / (2.0 * w * w)).exp();
            for iy in 0..c {
                for ix in 0..c {
                    let tx = TAU * ix as f64 / n as f64 - phase_rad[0];
                    let ty = TAU * iy as f64 / n as f64 - phase_rad[1];
                    let bump = ((k * tx).cos() + 1.0) * ((k * ty).cos() + 1.0) * 0.25;
                    self.m[s * c * c + iy * c + ix] = T::of(bump.powi(4) * g);
                }
            }
        }
    }

    /// Neural velocity target `u = (1/k) arctan(2π τ_eff V k / P)` per axis for a map-frame velocity.
    pub fn velocity_target(
        &self,
        velocity_m_s: [f64; 2],
        torus_period_m: f64,
        tau_eff_s: f64,
    ) -> Result<[f64; 2]> {
        let k = self.params.k as f64;
        let mut u = [0.0; 2];
        for a in 0..2 {
            check::input("velocity_m_s", velocity_m_s[a])?;
            u[a] = (TAU * tau_eff_s * velocity_m_s[a] * k / torus_period_m).atan() / k;
            if u[a].abs() > self.params.nu_max {
                let vmax = (self.params.nu_max * k).tan() * torus_period_m / (TAU * tau_eff_s * k);
                return Err(AttractorError::OutOfRange {
                    name: "velocity_m_s",
                    value: velocity_m_s[a],
                    why: format!(
                        "grid module k={} represents |V| ≤ {vmax:.1} m/s per axis with a {torus_period_m} m \
                         torus at this step size; raise grid nu_max or torus_period_m",
                        self.params.k
                    ),
                });
            }
        }
        Ok(u)
    }

    /// Recurrent input without the uniform inhibition for a cell-layout state `m` (`M²·C²`), into `out`
    /// (same layout). Tiled to the full torus, it equals the dense sum over the full network for the
    /// tiled activity.
    pub fn recurrent_input(&self, m: &[T], out: &mut [T]) {
        let mut work = MixWork::new(&self.fft, &self.mix, self.params.n_slices());
        self.recurrent_input_with(m, out, &mut work);
    }

    /// Number of velocity eigenmodes kept by the factored mixing (see module docs).
    pub fn mixing_rank(&self) -> usize {
        self.mix.rank
    }

    fn recurrent_input_with(&self, m: &[T], out: &mut [T], work: &mut MixWork<T>) {
        let n2 = self.params.cell() * self.params.cell();
        let ns = self.params.n_slices();
        let len = self.fft.spectrum_len();
        // The sum runs over the full torus (N² units per slice); the folded kernel accounts for the k²
        // copies of each cell unit.
        let full = self.params.n_theta * self.params.n_theta;
        let scale = T::of(self.params.jk / (full * ns) as f64) * self.fft.inverse_scale();
        let active: Vec<bool> = m
            .chunks(n2)
            .map(|c| c.iter().any(|&x| x != T::zero()))
            .collect();
        let MixWork {
            spectra,
            modes,
            mode_spectra,
        } = work;
        // 1. Per presynaptic slice: its spectrum times that slice's kernel spectrum (silent slices skipped).
        spectra
            .par_chunks_mut(len)
            .zip(m.par_chunks(n2))
            .enumerate()
            .filter(|(s, _)| active[*s])
            .for_each_init(
                || self.fft.scratch(),
                |scratch, (s, (spec, m_s))| {
                    self.fft.forward(m_s, spec, scratch);
                    for (x, &k) in spec.iter_mut().zip(&self.kernel_spectra[s]) {
                        *x = *x * k;
                    }
                },
            );
        // 2. Project onto each kept velocity eigenmode, in frequency space, and transform it back.
        let spectra: &[Complex<T>] = spectra;
        mode_spectra
            .par_chunks_mut(len)
            .zip(modes.par_chunks_mut(n2))
            .enumerate()
            .for_each_init(
                || self.fft.scratch(),
                |scratch, (r, (acc, mode))| {
                    acc.iter_mut().for_each(|x| *x = Complex::default());
                    for (s, spec) in spectra.chunks(len).enumerate() {
                        if active[s] {
                            let w = self.mix.input[r * ns + s];
                            for (a, &x) in acc.iter_mut().zip(spec) {
                                *a = *a + x * w;
                            }
                        }
                    }
                    self.fft.inverse(acc, mode, scale, scratch);
                },
            );
        // 3. Back to velocity slices, one GEMM: h(·, s) = Σ_r U[s, r] σ_r mode_r.
        T::gemm(ns, self.mix.rank, n2, &self.mix.output, modes, out);
    }

    /// One integration step with velocity target `u` and an optional view input: a layer-II pattern (N²),
    /// replicated along both velocity axes, already scaled by its injection strength.
    ///
    /// Velocity pinning: the bump moves at the activity-weighted mean velocity `ν̄` of its units, which the
    /// recurrent velocity coupling pulls toward the sampled grid points of the velocity axis (with M = 9 a
    /// bump can stall between slices at low speed). The input is therefore centred at `u + b`, where the
    /// bias `b` integrates `pin_gain · (u − ν̄)`, so that `ν̄` follows the target on average — a calibration loop, not part of the
    /// paper's model; `pin_gain = 0` gives the plain model.
    pub fn step(&mut self, u: [f64; 2], view: Option<&[T]>, dt_s: f64, tau_s: f64) -> Result<()> {
        let n2 = self.params.cell() * self.params.cell();
        let view_cell = view.map(|p| self.fold(p));
        let nu_bar = self.nu_position();
        let lim = self.params.nu_max;
        for a in 0..2 {
            // Feed-forward target plus an integral correction (a PI loop without lag on velocity changes).
            let bias = self.pin_bias[a] + self.params.pin_gain * (u[a] - nu_bar[a]);
            self.pin_bias[a] = bias.clamp(-lim, lim);
        }
        let u = [
            (u[0] + self.pin_bias[0]).clamp(-lim, lim),
            (u[1] + self.pin_bias[1]).clamp(-lim, lim),
        ];
        let mut drive = std::mem::take(&mut self.drive);
        let mut work = std::mem::take(&mut self.work);
        self.recurrent_input_with(&self.m, &mut drive, &mut work);
        let p = &self.params;
        let slices = slice_velocities(&self.nu);
        let two_s2 = 2.0 * p.input_sigma * p.input_sigma;
        drive.par_chunks_mut(n2).enumerate().for_each(|(s, d)| {
            let v = slices[s];
            let dist2 = (v[0] - u[0]).powi(2) + (v[1] - u[1]).powi(2);
            let input = T::of(
                p.input_amp * (1.0 - p.input_tuning + p.input_tuning * (-dist2 / two_s2).exp()),
            );
            match &view_cell {
                Some(pattern) => d
                    .iter_mut()
                    .zip(pattern)
                    .for_each(|(x, &w)| *x = *x + input + w),
                None => d.iter_mut().for_each(|x| *x = *x + input),
            }
        });
        let stepped = self.stepper.advance(&mut self.m, &drive, p.j0, dt_s, tau_s);
        self.drive = drive;
        self.work = work;
        stepped
    }

    /// Layer-II ("pure grid cell") pattern: the activity summed over both velocity axes (N², `[iy][ix]`).
    pub fn layer2(&self) -> Vec<T> {
        self.tile(&sum_rows(&self.m, self.params.cell() * self.params.cell()))
    }

    /// Activity-weighted mean position on the velocity axes (what sets the bump speed).
    pub fn nu_position(&self) -> [f64; 2] {
        let n2 = self.params.cell() * self.params.cell();
        let slices = slice_velocities(&self.nu);
        let (mut sx, mut sy, mut total) = (0.0, 0.0, 0.0);
        for (s, slice) in self.m.chunks(n2).enumerate() {
            let w = lanes::sum(slice);
            sx += w * slices[s][0];
            sy += w * slices[s][1];
            total += w;
        }
        if total > 0.0 {
            [sx / total, sy / total]
        } else {
            [0.0, 0.0]
        }
    }
}

/// The velocity mixing matrix `V` (S×S, symmetric) factored as `V ≈ output · input` with
/// `input = Uᵀ` (rank×S) and `output = U diag(σ)` (S×rank), keeping the eigenvalues above `S·ε·max|σ|`.
struct VelocityMix<T> {
    input: Vec<T>,
    output: Vec<T>,
    rank: usize,
}

impl<T: Real> VelocityMix<T> {
    fn new(dense: &[f64], n: usize) -> Self {
        let c = faer::Mat::<f64>::from_fn(n, n, |i, j| dense[i * n + j]);
        let eigen = c.self_adjoint_eigen(faer::Side::Lower);
        hippo_simd::clear_upper_halves(); // faer's kernels ran on this thread (`Real::gemm`)
        let Ok(eigen) = eigen else {
            // The symmetric eigensolver does not fail on a small finite matrix; if it ever did, the
            // identity factorisation is the dense product itself (exact, just slower).
            return Self {
                input: (0..n * n)
                    .map(|i| if i / n == i % n { T::one() } else { T::zero() })
                    .collect(),
                output: dense.iter().map(|&x| T::of(x)).collect(),
                rank: n,
            };
        };
        let sigma = eigen.S().column_vector();
        let u = eigen.U();
        let largest = (0..n).map(|i| sigma[i].abs()).fold(0.0, f64::max);
        let keep: Vec<usize> = (0..n)
            .filter(|&i| sigma[i].abs() > largest * n as f64 * T::epsilon().f64())
            .collect();
        let rank = keep.len();
        let input = keep
            .iter()
            .flat_map(|&r| (0..n).map(move |s| T::of(u[(s, r)])))
            .collect();
        let output = (0..n)
            .flat_map(|s| keep.iter().map(move |&r| T::of(u[(s, r)] * sigma[r])))
            .collect();
        Self {
            input,
            output,
            rank,
        }
    }
}

/// Work buffers of the recurrent input: the kernel-weighted spectrum of every slice (S), and each kept
/// eigenmode's spectrum and pattern (rank).
#[derive(Default)]
struct MixWork<T> {
    spectra: Vec<Complex<T>>,
    mode_spectra: Vec<Complex<T>>,
    modes: Vec<T>,
}

impl<T: Real> MixWork<T> {
    fn new(fft: &RealFft2<T>, mix: &VelocityMix<T>, n_slices: usize) -> Self {
        let len = fft.spectrum_len();
        Self {
            spectra: vec![Complex::default(); n_slices * len],
            mode_spectra: vec![Complex::default(); mix.rank * len],
            modes: vec![T::zero(); mix.rank * fft.n() * fft.n()],
        }
    }
}

/// Velocity of each slice `s = jy·M + jx`: `(ν_jx, ν_jy)`.
pub fn slice_velocities(nu: &[f64]) -> Vec<[f64; 2]> {
    nu.iter()
        .flat_map(|&vy| nu.iter().map(move |&vx| [vx, vy]))
        .collect()
}
