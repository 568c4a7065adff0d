//! Head-direction-by-velocity ring attractor (docs/spec.md §2): units on `θ_i = 2πi/Nθ`
//! × `ν_j ∈ [−L_r, L_r]`.
//!
//! Weights `J(θ,ν | θ',ν') = J0 + J1 cos(θ − θ' − ν') cos(λ(ν − ν'))`, recurrent input
//! `h = (1/(Nθ Nν)) Σ J m`. The `J1` term is a single harmonic in θ, so with
//! `cos(θ − θ' − ν') = cos θ cos(θ' + ν') + sin θ sin(θ' + ν')` it collapses to two projections per velocity
//! row, `C(ν') = Σ_θ' m cos(θ' + ν')` and `S(ν') = Σ_θ' m sin(θ' + ν')`, mixed over ν: exact in O(Nθ·Nν + Nν²).
//! Layout: `m[j·Nθ + i]` (velocity-major rows of θ).
use crate::check;
use crate::dynamics::{sum_rows, ImplicitStepper};
use crate::error::{AttractorError, Result};
use crate::real::Real;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Parameters of the head-direction-by-velocity ring (docs/spec.md §2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HdParams {
    /// Units around the ring (Nθ).
    pub n_theta: usize,
    /// Units along the angular-velocity axis (Nν).
    pub n_nu: usize,
    /// Half-range `L_r` of the velocity axis (dimensionless neural units, rad per τ).
    pub nu_max: f64,
    /// Velocity-tuning spread λ of the weights; one bump fits when `λ·2L_r ≤ 2π`.
    pub lambda: f64,
    /// Uniform inhibition `J0 < 0`.
    pub j0: f64,
    /// Interaction strength `J1 > 0`.
    pub j1: f64,
    /// Velocity input amplitude `I_r`.
    pub input_amp: f64,
    /// Velocity tuning strength `ε_r ∈ [0, 1]`.
    pub input_tuning: f64,
    /// Velocity tuning width `σ_r` (neural units).
    pub input_sigma: f64,
    /// Gain of the velocity-pinning feedback (0 disables it; see [`HdRing::step`]).
    pub pin_gain: f64,
}

/// Units of the ring at most (`n_theta · n_nu`; the default has 1 920): a typo must not allocate gigabytes.
pub const MAX_HD_UNITS: usize = 1 << 20;

impl Default for HdParams {
    fn default() -> Self {
        // The exact-leak integrator maps ω to u = arctan(τ_eff ω) with τ_eff ≈ 2.7τ at the default step, so
        // the L_r ≈ 0.05 that suits the paper's τ becomes 0.1: turn rates up to ~3.6 rad/s (tight
        // corners at speed; docs/spec.md §2).
        let nu_max = 0.1;
        Self {
            n_theta: 128,
            n_nu: 15,
            nu_max,
            lambda: std::f64::consts::PI / (4.0 * nu_max),
            j0: -20.0,
            j1: 20.0,
            input_amp: 1.0,
            input_tuning: 1.0,
            input_sigma: 0.5 * nu_max,
            pin_gain: 0.3,
        }
    }
}

impl HdParams {
    /// Check every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        check::size("hd.n_theta", self.n_theta, 4, 1 << 16)?;
        check::size("hd.n_nu", self.n_nu, 1, 1024)?;
        check::size("hd.units (n_theta · n_nu)", self.n_units(), 1, MAX_HD_UNITS)?;
        check::positive("hd.nu_max", self.nu_max)?;
        check::at_most("hd.nu_max", self.nu_max, check::MAX_NU)?;
        check::positive("hd.lambda", self.lambda)?;
        check::at_most("hd.lambda", self.lambda, check::MAX_LAMBDA)?;
        check::non_positive("hd.j0", self.j0)?;
        check::at_least("hd.j0", self.j0, -check::MAX_GAIN)?;
        check::positive("hd.j1", self.j1)?;
        check::at_most("hd.j1", self.j1, check::MAX_GAIN)?;
        check::positive("hd.input_amp", self.input_amp)?;
        check::at_most("hd.input_amp", self.input_amp, check::MAX_GAIN)?;
        check::in_unit_interval("hd.input_tuning", self.input_tuning)?;
        check::positive("hd.input_sigma", self.input_sigma)?;
        check::at_most("hd.input_sigma", self.input_sigma, check::MAX_NU)?;
        check::in_unit_interval("hd.pin_gain", self.pin_gain)?;
        Ok(())
    }

    /// Units of the ring (`n_theta · n_nu`).
    pub fn n_units(&self) -> usize {
        self.n_theta * self.n_nu
    }
}

/// Decoded ring state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HdReadout {
    /// Heading ψ in [0, 2π).
    pub heading_rad: f64,
    /// Bump position φ on the velocity axis (neural units).
    pub nu_position: f64,
    /// Decoded angular velocity `tan(φ)/τ_eff` (rad/s).
    pub yaw_rate_rad_s: f64,
    /// Mean activity (0 means the bump died).
    pub mean_activity: f64,
}

/// The head-direction-by-velocity ring.
pub struct HdRing<T: Real> {
    params: HdParams,
    theta: Vec<f64>,
    nu: Vec<f64>,
    cos_theta: Vec<T>,
    sin_theta: Vec<T>,
    /// `cos(θ_i + ν_j)`, `sin(θ_i + ν_j)` for the projections.
    cos_shift: Vec<T>,
    sin_shift: Vec<T>,
    /// `cos(λ(ν_j − ν_j'))`.
    nu_mix: Vec<f64>,
    m: Vec<T>,
    drive: Vec<T>,
    stepper: ImplicitStepper,
    /// Integral term of the velocity-pinning loop (neural units).
    pin_bias: f64,
}

impl<T: Real> HdRing<T> {
    /// A ring at rest (no bump yet); `SpatialMemory::reset` seeds it.
    pub fn new(params: HdParams) -> Result<Self> {
        params.validate()?;
        let theta = check::angle_axis(params.n_theta);
        let nu = check::velocity_axis(params.n_nu, params.nu_max);
        let (nt, nv) = (params.n_theta, params.n_nu);
        let mut cos_shift = Vec::with_capacity(nt * nv);
        let mut sin_shift = Vec::with_capacity(nt * nv);
        for &v in &nu {
            for &t in &theta {
                cos_shift.push(T::of((t + v).cos()));
                sin_shift.push(T::of((t + v).sin()));
            }
        }
        let nu_mix = nu
            .iter()
            .flat_map(|&a| nu.iter().map(move |&b| (params.lambda * (a - b)).cos()))
            .collect();
        let mut ring = Self {
            cos_theta: theta.iter().map(|t| T::of(t.cos())).collect(),
            sin_theta: theta.iter().map(|t| T::of(t.sin())).collect(),
            theta,
            nu,
            cos_shift,
            sin_shift,
            nu_mix,
            m: vec![T::zero(); nt * nv],
            stepper: ImplicitStepper::default(),
            drive: vec![T::zero(); nt * nv],
            pin_bias: 0.0,
            params,
        };
        ring.seed(0.0);
        Ok(ring)
    }

    /// The ring's parameters.
    pub fn params(&self) -> &HdParams {
        &self.params
    }

    /// The activity, layout `[ν][θ]`.
    pub fn activity(&self) -> &[T] {
        &self.m
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
    pub fn pin_bias(&self) -> f64 {
        self.pin_bias
    }

    /// Restore the pinning loop's integral term (clamped to the velocity axis).
    pub fn set_pin_bias(&mut self, bias: f64) {
        self.pin_bias = bias.clamp(-self.params.nu_max, self.params.nu_max);
    }

    /// Replace the whole state (length Nθ·Nν, layout `[ν][θ]`).
    pub fn set_activity(&mut self, m: &[T]) -> Result<()> {
        check::array_len("hd activity", m.len(), self.m.len(), self.shape())?;
        check::array_finite("hd activity", m)?;
        check::array_non_negative("hd activity", m)?;
        self.m.copy_from_slice(m);
        Ok(())
    }

    /// The activity's shape, for messages.
    pub fn shape(&self) -> String {
        format!(
            "(n_nu={}, n_theta={})",
            self.params.n_nu, self.params.n_theta
        )
    }

    /// Place a cosine bump at `heading_rad` on the zero-velocity row region.
    pub fn seed(&mut self, heading_rad: f64) {
        let nt = self.params.n_theta;
        self.pin_bias = 0.0;
        let width = self.params.nu_max.max(1e-12);
        for (j, &v) in self.nu.iter().enumerate() {
            let g = (-(v * v) / (2.0 * (0.5 * width).powi(2))).exp();
            for (i, &t) in self.theta.iter().enumerate() {
                self.m[j * nt + i] = T::of(((t - heading_rad).cos()).max(0.0) * g);
            }
        }
    }

    /// Neural velocity-axis target `u(V) = arctan(τ_eff V)` for a yaw rate.
    pub fn velocity_target(&self, yaw_rate_rad_s: f64, tau_eff_s: f64) -> Result<f64> {
        check::input("yaw_rate_rad_s", yaw_rate_rad_s)?;
        let u = (tau_eff_s * yaw_rate_rad_s).atan();
        if u.abs() > self.params.nu_max {
            return Err(AttractorError::OutOfRange {
                name: "yaw_rate_rad_s",
                value: yaw_rate_rad_s,
                why: format!(
                    "the ring represents |ω| ≤ {:.3} rad/s at this step size; raise hd.nu_max",
                    self.params.nu_max.tan() / tau_eff_s
                ),
            });
        }
        Ok(u)
    }

    /// Recurrent input without the uniform inhibition: `(J1/(NθNν)) Σ J1-part · m`, into `out`.
    pub fn recurrent_input(&self, m: &[T], out: &mut [T]) {
        let (nt, nv) = (self.params.n_theta, self.params.n_nu);
        let mut c = vec![0.0f64; nv];
        let mut s = vec![0.0f64; nv];
        for j in 0..nv {
            let row = &m[j * nt..(j + 1) * nt];
            let (mut cj, mut sj) = (T::zero(), T::zero());
            let cos_row = &self.cos_shift[j * nt..(j + 1) * nt];
            let sin_row = &self.sin_shift[j * nt..(j + 1) * nt];
            for ((&r, &co), &si) in row.iter().zip(cos_row).zip(sin_row) {
                cj = cj + r * co;
                sj = sj + r * si;
            }
            c[j] = cj.f64();
            s[j] = sj.f64();
        }
        let scale = self.params.j1 / (nt * nv) as f64;
        for j in 0..nv {
            let (mut cm, mut sm) = (0.0, 0.0);
            for jp in 0..nv {
                let w = self.nu_mix[j * nv + jp];
                cm += w * c[jp];
                sm += w * s[jp];
            }
            let (cm, sm) = (T::of(scale * cm), T::of(scale * sm));
            for i in 0..nt {
                out[j * nt + i] = cm * self.cos_theta[i] + sm * self.sin_theta[i];
            }
        }
    }

    /// Activity-weighted mean position on the velocity axis (what sets the bump's angular speed).
    pub fn nu_mean(&self) -> f64 {
        let nt = self.params.n_theta;
        let (mut s, mut w) = (0.0, 0.0);
        for (j, row) in self.m.chunks(nt).enumerate() {
            let r: f64 = row.iter().map(|x| x.f64()).sum();
            s += r * self.nu[j];
            w += r;
        }
        if w > 0.0 {
            s / w
        } else {
            0.0
        }
    }

    /// One integration step of `dt_s` with velocity target `u` and an optional view input (a θ-profile of
    /// length Nθ, replicated along ν, already scaled by its injection strength).
    ///
    /// Velocity pinning (as in the grid modules, see `GridModule::step`): the input is centred at `u + b`,
    /// the bias `b` integrating `pin_gain · (u − ν̄)`, so that the bump's mean velocity `ν̄` follows the target between the sampled
    /// velocity rows; `pin_gain = 0` gives the paper's plain model.
    pub fn step(&mut self, u: f64, view: Option<&[T]>, dt_s: f64, tau_s: f64) -> Result<()> {
        let (nt, nv) = (self.params.n_theta, self.params.n_nu);
        let lim = self.params.nu_max;
        // Feed-forward target plus an integral correction (a PI loop without lag on velocity changes).
        self.pin_bias =
            (self.pin_bias + self.params.pin_gain * (u - self.nu_mean())).clamp(-lim, lim);
        let u = (u + self.pin_bias).clamp(-lim, lim);
        let mut drive = std::mem::take(&mut self.drive);
        self.recurrent_input(&self.m, &mut drive);
        let p = &self.params;
        for j in 0..nv {
            let d = self.nu[j] - u;
            let input = T::of(
                p.input_amp
                    * (1.0 - p.input_tuning
                        + p.input_tuning
                            * (-(d * d) / (2.0 * p.input_sigma * p.input_sigma)).exp()),
            );
            for i in 0..nt {
                drive[j * nt + i] = drive[j * nt + i] + input;
            }
            if let Some(v) = view {
                for i in 0..nt {
                    drive[j * nt + i] = drive[j * nt + i] + v[i];
                }
            }
        }
        let stepped = self.stepper.advance(&mut self.m, &drive, p.j0, dt_s, tau_s);
        self.drive = drive;
        stepped
    }

    /// θ-profile: activity summed over the velocity axis (what a view cell stores).
    pub fn theta_profile(&self) -> Vec<T> {
        sum_rows(&self.m, self.params.n_theta)
    }

    /// ψ = arg Σ m e^{iθ}; φ = arg(Σ m e^{iλν})/λ; ω = tan(φ)/τ_eff.
    pub fn readout(&self, tau_eff_s: f64) -> HdReadout {
        let nt = self.params.n_theta;
        let (mut zc, mut zs, mut vc, mut vs, mut total) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (j, row) in self.m.chunks(nt).enumerate() {
            let lv = self.params.lambda * self.nu[j];
            let mut row_sum = 0.0;
            for (i, &x) in row.iter().enumerate() {
                let x = x.f64();
                zc += x * self.cos_theta[i].f64();
                zs += x * self.sin_theta[i].f64();
                row_sum += x;
            }
            vc += row_sum * lv.cos();
            vs += row_sum * lv.sin();
            total += row_sum;
        }
        let heading = zs.atan2(zc).rem_euclid(TAU);
        let phi = vs.atan2(vc) / self.params.lambda;
        HdReadout {
            heading_rad: if heading >= TAU { 0.0 } else { heading },
            nu_position: phi,
            yaw_rate_rad_s: phi.tan() / tau_eff_s,
            mean_activity: total / self.m.len() as f64,
        }
    }

    /// Preferred heading of each θ unit (rad).
    pub fn theta_axis(&self) -> &[f64] {
        &self.theta
    }

    /// Preferred angular velocity of each ν slice (neural units).
    pub fn nu_axis(&self) -> &[f64] {
        &self.nu
    }
}
