//! The whole spatial-memory network (docs/spec.md §1): HD ring → three grid modules → Bayesian
//! fusion → CA3 place torus, stepped per camera frame from (yaw rate, forward speed, dt, optional
//! view injection).
//!
//! A frame of `dt` is split into `ceil(dt / max_substep_s)` equal sub-steps. In each: the ring integrates
//! the yaw rate; its decoded heading ψ turns the speed into a map-frame velocity `V = v (cos ψ, sin ψ)`;
//! every active grid module integrates V; their layer-II bumps are decoded and fused; the fused Gaussian
//! drives the place torus. Lesioned modules are silent: not stepped, not fused.
//!
//! Positions: all modules and the place torus share one neural torus standing for a `torus_period_m` square.
//! Each module's displacement is tracked by following one bump and unwrapping its motion; the place code is
//! unwrapped the same way. Metres = radians · P / 2π.
use crate::check;
use crate::circular::wrap;
use crate::decode::find_bumps;
use crate::dynamics::tau_effective;
use crate::error::{AttractorError, Result};
use crate::fusion::{fuse_homocentric, Bump2, FusedEstimate};
use crate::grid::{GridModule, GridParams};
use crate::hd::{HdParams, HdReadout, HdRing};
use crate::place::{PlaceNetwork, PlaceParams};
use crate::real::Real;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

/// Number of grid modules (wave numbers 1, 2, 4 by default; index 0 is the coarsest, "ventral").
pub const N_MODULES: usize = 3;
/// The strongest view injection (the pipeline's `view_injection.initial_strength` is at most this).
pub const MAX_VIEW_STRENGTH: f64 = 1.0e3;

/// Parameters of the whole network; `Default` is the single source of every default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialMemoryParams {
    /// Membrane time constant τ of every network (s).
    pub tau_s: f64,
    /// Longest integration sub-step (s); a frame is split into equal sub-steps no longer than this.
    pub max_substep_s: f64,
    /// Side of the square that the neural torus stands for (m).
    pub torus_period_m: f64,
    /// The head-direction ring.
    pub hd: HdParams,
    /// Grid modules from coarsest (ventral) to finest (dorsal).
    pub grid: [GridParams; N_MODULES],
    /// The CA3 place torus.
    pub place: PlaceParams,
    /// Fraction of a pattern's maximum above which units seed a bump.
    pub bump_threshold_frac: f64,
    /// Modules switched off ("MEC inactivation"), same order as `grid`.
    pub lesioned: [bool; N_MODULES],
    /// Simulated time to let freshly seeded bumps settle at zero velocity (s).
    pub settle_s: f64,
}

impl Default for SpatialMemoryParams {
    fn default() -> Self {
        Self {
            tau_s: 0.01,
            max_substep_s: 0.025,
            torus_period_m: 100.0,
            hd: HdParams::default(),
            grid: [
                GridParams::for_module(1),
                GridParams::for_module(2),
                GridParams::for_module(4),
            ],
            place: PlaceParams::default(),
            bump_threshold_frac: 0.3,
            lesioned: [false; N_MODULES],
            settle_s: 0.3,
        }
    }
}

impl SpatialMemoryParams {
    /// Check every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<()> {
        // Bounds that keep a typo from hanging a run: a sub-step of 1e-9 s would mean 10⁸ sub-steps per
        // frame, a settle of hours as many before the first frame.
        check::in_range("tau_s", self.tau_s, 1e-4, 10.0)?;
        check::in_range("max_substep_s", self.max_substep_s, 1e-4, 1.0)?;
        if self.max_substep_s > 5.0 * self.tau_s {
            return Err(AttractorError::BadParameter {
                name: "max_substep_s".into(),
                value: self.max_substep_s.to_string(),
                why: format!(
                    "sub-steps longer than 5τ ({} s) do not resolve the attractor dynamics",
                    5.0 * self.tau_s
                ),
            });
        }
        // 0.1 m: a rodent arena's dorsal grid spacing is ~0.3 m, so its torus (P = 4 × spacing) is ~1.2 m.
        check::in_range("torus_period_m", self.torus_period_m, 0.1, 1e5)?;
        check::in_unit_interval("bump_threshold_frac", self.bump_threshold_frac)?;
        check::in_range("settle_s", self.settle_s, 0.0, 10.0)?;
        self.hd.validate()?;
        self.place.validate()?;
        for (index, g) in self.grid.iter().enumerate() {
            g.validate().map_err(|e| e.in_module(index))?;
            if g.n_theta != self.place.n_theta {
                return Err(AttractorError::BadParameter {
                    name: format!("grid[{index}].n_theta"),
                    value: g.n_theta.to_string(),
                    why: format!(
                        "must equal place.n_theta = {} (one shared torus)",
                        self.place.n_theta
                    ),
                });
            }
        }
        Ok(())
    }
}

/// Patterns stored by a view cell and injected when it is recognised (docs/spec.md §7).
#[derive(Clone, Debug)]
pub struct ViewInjection<T> {
    /// HD θ-profile (Nθ), replicated along ν.
    pub hd_profile: Vec<T>,
    /// Layer-II pattern (N²) of each grid module, replicated along both velocity axes; `None` skips one.
    pub grid_layer2: [Option<Vec<T>>; N_MODULES],
    /// Injection strength multiplying the stored patterns (the pipeline decays it while a view persists).
    pub strength: f64,
}

/// One grid module's part of a readout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModuleReadout {
    /// Bumps per torus axis (1, 2, 4).
    pub k: usize,
    /// Whether the module is switched off.
    pub lesioned: bool,
    /// Every bump of the layer-II pattern, strongest first.
    pub bumps: Vec<Bump2>,
    /// Centre of the bump being followed (rad).
    pub tracked_rad: [f64; 2],
    /// Unwrapped displacement of the followed bump since reset, in metres.
    pub position_m: [f64; 2],
}

/// What the network reads out after a frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpatialReadout {
    /// Network time since construction (s).
    pub time_s: f64,
    /// The decoded heading and angular velocity.
    pub hd: HdReadout,
    /// One readout per grid module, coarsest first.
    pub modules: Vec<ModuleReadout>,
    /// The Bayesian fusion of the homocentric bumps (None if every module is lesioned or silent).
    pub fused: Option<FusedEstimate>,
    /// The CA3 place bump (None if the place network is silent).
    pub place: Option<Bump2>,
    /// Unwrapped place-code displacement since reset (m).
    pub place_position_m: [f64; 2],
    /// Integration sub-steps taken for the last frame.
    pub substeps: usize,
}

/// Everything but the activity arrays that a resumed run needs (small; serialisable).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AuxState {
    /// Network time (s).
    pub time_s: f64,
    /// The HD ring's pinning integral.
    pub hd_pin_bias: f64,
    /// Each grid module's pinning integral.
    pub grid_pin_bias: [[f64; 2]; N_MODULES],
    /// The bump each module follows (rad).
    pub tracked_rad: [[f64; 2]; N_MODULES],
    /// Each module's unwrapped bump position (rad).
    pub module_pos_rad: [[f64; 2]; N_MODULES],
    /// The place bump followed (rad), if any.
    pub place_tracked_rad: Option<[f64; 2]>,
    /// The place code's unwrapped position (rad).
    pub place_pos_rad: [f64; 2],
    /// The last fused estimate (the prior of the next fusion).
    pub last_fused: Option<FusedEstimate>,
    /// Which modules are switched off.
    pub lesioned: [bool; N_MODULES],
    /// The integrators' warm starts: HD ring, each grid module, place network (absent in older saves: a
    /// cold start, which changes only the last bits).
    #[serde(default)]
    pub warm_starts: Option<WarmStarts>,
}

/// The integrators' warm starts (see [`crate::dynamics::ImplicitStepper`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WarmStarts {
    /// The HD ring's.
    pub hd: f64,
    /// Each grid module's.
    pub grid: [f64; N_MODULES],
    /// The place network's.
    pub place: f64,
}

/// The whole spatial-memory network, stepped once per camera frame.
pub struct SpatialMemory<T: Real> {
    params: SpatialMemoryParams,
    /// The head-direction ring.
    pub hd: HdRing<T>,
    /// The grid modules, coarsest first.
    pub grids: Vec<GridModule<T>>,
    /// The CA3 place torus.
    pub place: PlaceNetwork<T>,
    tracked: [[f64; 2]; N_MODULES],
    module_pos_rad: [[f64; 2]; N_MODULES],
    place_tracked: Option<[f64; 2]>,
    place_pos_rad: [f64; 2],
    last_bumps: Vec<Vec<Bump2>>,
    last_fused: Option<FusedEstimate>,
    last_place: Option<Bump2>,
    time_s: f64,
    last_substeps: usize,
}

impl<T: Real> SpatialMemory<T> {
    /// A network of the given parameters, its bumps seeded at heading 0 and phase (0, 0).
    pub fn new(params: SpatialMemoryParams) -> Result<Self> {
        params.validate()?;
        let mut sm = Self {
            hd: HdRing::new(params.hd.clone())?,
            grids: params
                .grid
                .iter()
                .map(|g| GridModule::new(g.clone()))
                .collect::<Result<_>>()?,
            place: PlaceNetwork::new(params.place.clone())?,
            tracked: [[0.0; 2]; N_MODULES],
            module_pos_rad: [[0.0; 2]; N_MODULES],
            place_tracked: None,
            place_pos_rad: [0.0; 2],
            last_bumps: vec![Vec::new(); N_MODULES],
            last_fused: None,
            last_place: None,
            time_s: 0.0,
            last_substeps: 0,
            params,
        };
        sm.reset(0.0, [0.0, 0.0])?;
        Ok(sm)
    }

    /// The network's parameters.
    pub fn params(&self) -> &SpatialMemoryParams {
        &self.params
    }

    /// Sub-step length and count for a frame of `dt_s`.
    pub fn substeps_for(&self, dt_s: f64) -> (usize, f64) {
        let n = (dt_s / self.params.max_substep_s).ceil().max(1.0) as usize;
        (n, dt_s / n as f64)
    }

    /// Seed every network (heading ψ, torus phase) and let the bumps settle at zero velocity.
    pub fn reset(&mut self, heading_rad: f64, phase_rad: [f64; 2]) -> Result<()> {
        check::input("heading_rad", heading_rad)?;
        check::input("phase_rad", phase_rad[0])?;
        check::input("phase_rad", phase_rad[1])?;
        self.hd.seed(heading_rad);
        for g in &mut self.grids {
            g.seed(phase_rad);
        }
        self.place
            .set_activity(&vec![T::zero(); self.params.place.n_theta.pow(2)])?;
        self.tracked = [phase_rad; N_MODULES];
        self.place_tracked = None;
        self.last_fused = None;
        self.time_s = 0.0;
        let settle_steps = (self.params.settle_s / self.params.max_substep_s).ceil() as usize;
        let dt = self.params.max_substep_s;
        for _ in 0..settle_steps {
            self.substep(0.0, 0.0, dt, None)?;
        }
        // Follow, in each module, the bump nearest the seeded phase.
        for (m, bumps) in self.last_bumps.iter().enumerate() {
            if let Some(b) = nearest(bumps, phase_rad) {
                self.tracked[m] = b.mean_rad;
            }
        }
        self.module_pos_rad = [[0.0; 2]; N_MODULES];
        self.place_tracked = self.last_place.map(|b| b.mean_rad);
        self.place_pos_rad = [0.0; 2];
        self.time_s = 0.0;
        Ok(())
    }

    /// The non-array part of the state (for save and resume).
    pub fn aux_state(&self) -> AuxState {
        AuxState {
            time_s: self.time_s,
            hd_pin_bias: self.hd.pin_bias(),
            grid_pin_bias: [
                self.grids[0].pin_bias(),
                self.grids[1].pin_bias(),
                self.grids[2].pin_bias(),
            ],
            tracked_rad: self.tracked,
            module_pos_rad: self.module_pos_rad,
            place_tracked_rad: self.place_tracked,
            place_pos_rad: self.place_pos_rad,
            last_fused: self.last_fused,
            lesioned: self.params.lesioned,
            warm_starts: Some(WarmStarts {
                hd: self.hd.warm_start(),
                grid: [
                    self.grids[0].warm_start(),
                    self.grids[1].warm_start(),
                    self.grids[2].warm_start(),
                ],
                place: self.place.warm_start(),
            }),
        }
    }

    /// Restore the non-array part of a saved state (pair it with the activity setters).
    pub fn set_aux_state(&mut self, aux: &AuxState) -> Result<()> {
        check::input("time_s", aux.time_s)?;
        check::input("hd_pin_bias", aux.hd_pin_bias)?;
        self.time_s = aux.time_s;
        self.hd.set_pin_bias(aux.hd_pin_bias);
        for (g, b) in self.grids.iter_mut().zip(aux.grid_pin_bias) {
            g.set_pin_bias(b);
        }
        self.tracked = aux.tracked_rad;
        self.module_pos_rad = aux.module_pos_rad;
        self.place_tracked = aux.place_tracked_rad;
        self.place_pos_rad = aux.place_pos_rad;
        self.last_fused = aux.last_fused;
        self.params.lesioned = aux.lesioned;
        if let Some(w) = aux.warm_starts {
            self.hd.set_warm_start(w.hd);
            for (g, start) in self.grids.iter_mut().zip(w.grid) {
                g.set_warm_start(start);
            }
            self.place.set_warm_start(w.place);
        }
        Ok(())
    }

    /// Lesion (`true`) or restore modules. A restored module resumes from its last state.
    pub fn set_lesions(&mut self, lesioned: [bool; N_MODULES]) {
        self.params.lesioned = lesioned;
    }

    fn tau_eff(&self, dt_s: f64) -> f64 {
        tau_effective(dt_s, self.params.tau_s)
    }

    /// Advance one camera frame.
    pub fn step(
        &mut self,
        yaw_rate_rad_s: f64,
        speed_m_s: f64,
        dt_s: f64,
        view: Option<&ViewInjection<T>>,
    ) -> Result<SpatialReadout> {
        check::input("yaw_rate_rad_s", yaw_rate_rad_s)?;
        check::input("speed_m_s", speed_m_s)?;
        check::input("dt_s", dt_s)?;
        if !(dt_s > 0.0 && dt_s <= 10.0) {
            return Err(AttractorError::OutOfRange {
                name: "dt_s",
                value: dt_s,
                why: "a frame must last more than 0 and at most 10 s; split longer gaps".into(),
            });
        }
        if let Some(v) = view {
            self.check_view(v)?;
        }
        let (n, sub_dt) = self.substeps_for(dt_s);
        // Validate the commanded velocities once before touching any state.
        let tau_eff = self.tau_eff(sub_dt);
        self.hd.velocity_target(yaw_rate_rad_s, tau_eff)?;
        for g in &self.grids {
            g.velocity_target([speed_m_s, 0.0], self.params.torus_period_m, tau_eff)?;
            g.velocity_target(
                [speed_m_s / std::f64::consts::SQRT_2; 2],
                self.params.torus_period_m,
                tau_eff,
            )?;
        }
        for _ in 0..n {
            self.substep(yaw_rate_rad_s, speed_m_s, sub_dt, view)?;
        }
        self.last_substeps = n;
        Ok(self.readout())
    }

    fn check_view(&self, v: &ViewInjection<T>) -> Result<()> {
        check::input("view strength", v.strength)?;
        // A negative strength would inject the stored state inverted: the heading flips by π and the
        // place code is pushed away from the stored place. Above MAX_VIEW_STRENGTH (the config's bound on
        // `view_injection.initial_strength`) the injected activity overflows f32 and the networks are NaN
        // from then on.
        check::in_range("view strength", v.strength, 0.0, MAX_VIEW_STRENGTH)?;
        let nt = self.params.hd.n_theta;
        check::array_len(
            "view hd_profile",
            v.hd_profile.len(),
            nt,
            format!("({nt},)"),
        )?;
        check::array_finite("view hd_profile", &v.hd_profile)?;
        let n = self.params.place.n_theta;
        for g in v.grid_layer2.iter().flatten() {
            check::array_len("view grid_layer2", g.len(), n * n, format!("({n}, {n})"))?;
            check::array_finite("view grid_layer2", g)?;
        }
        Ok(())
    }

    fn substep(
        &mut self,
        yaw_rate_rad_s: f64,
        speed_m_s: f64,
        dt_s: f64,
        view: Option<&ViewInjection<T>>,
    ) -> Result<()> {
        let tau = self.params.tau_s;
        let tau_eff = self.tau_eff(dt_s);
        let scale = |p: &[T], s: f64| -> Vec<T> { p.iter().map(|&x| x * T::of(s)).collect() };
        // 1. Head direction.
        let u_hd = self.hd.velocity_target(yaw_rate_rad_s, tau_eff)?;
        let hd_view = view.map(|v| scale(&v.hd_profile, v.strength));
        self.hd.step(u_hd, hd_view.as_deref(), dt_s, tau)?;
        let heading = self.hd.readout(tau_eff).heading_rad;
        let velocity = [speed_m_s * heading.cos(), speed_m_s * heading.sin()];
        // 2. Grid modules and their bumps. The modules are independent given the velocity, so they step
        // side by side: one parallel region per sub-step, whose threads then share out each module's own
        // parallel loops, instead of a region per loop (one module's loops left the second core idle
        // between them, and waking it ~100 times a frame cost a third of the engine's CPU time).
        let (period, threshold, lesioned) = (
            self.params.torus_period_m,
            self.params.bump_threshold_frac,
            self.params.lesioned,
        );
        let stepped: Vec<Result<Vec<Bump2>>> = self
            .grids
            .par_iter_mut()
            .enumerate()
            .map(|(m, grid)| {
                if lesioned[m] {
                    return Ok(Vec::new());
                }
                let u = grid.velocity_target(velocity, period, tau_eff)?;
                let g_view =
                    view.and_then(|v| v.grid_layer2[m].as_ref().map(|p| scale(p, v.strength)));
                grid.step(u, g_view.as_deref(), dt_s, tau)?;
                Ok(find_bumps(&grid.layer2(), grid.params().n_theta, threshold))
            })
            .collect();
        for (m, bumps) in stepped.into_iter().enumerate() {
            self.last_bumps[m] = bumps?;
            if lesioned[m] {
                continue;
            }
            if let Some(b) = nearest(&self.last_bumps[m], self.tracked[m]) {
                for a in 0..2 {
                    self.module_pos_rad[m][a] += wrap(b.mean_rad[a] - self.tracked[m][a]);
                }
                self.tracked[m] = b.mean_rad;
            }
        }
        // 3. Bayesian fusion (coarsest module first) → place input → place network.
        let slices: Vec<&[Bump2]> = (0..N_MODULES)
            .map(|m| self.last_bumps[m].as_slice())
            .collect();
        let prior = self.last_fused.map(|f| f.mean_rad);
        self.last_fused = match fuse_homocentric(&slices, prior) {
            Ok((f, _)) => Some(f),
            Err(AttractorError::NothingToFuse) => None,
            Err(e) => return Err(e),
        };
        self.place.set_grid_input(self.last_fused.as_ref());
        self.place.step(dt_s, tau)?;
        let n = self.params.place.n_theta;
        self.last_place = find_bumps(self.place.activity(), n, self.params.bump_threshold_frac)
            .into_iter()
            .next();
        if let Some(b) = self.last_place {
            if let Some(prev) = self.place_tracked {
                for (a, previous) in prev.iter().enumerate() {
                    self.place_pos_rad[a] += wrap(b.mean_rad[a] - previous);
                }
            }
            self.place_tracked = Some(b.mean_rad);
        }
        self.time_s += dt_s;
        Ok(())
    }

    /// The readout of the current state (no integration).
    pub fn readout(&self) -> SpatialReadout {
        let to_m = self.params.torus_period_m / TAU;
        let dt = self.params.max_substep_s;
        SpatialReadout {
            time_s: self.time_s,
            hd: self.hd.readout(self.tau_eff(dt)),
            modules: (0..N_MODULES)
                .map(|m| ModuleReadout {
                    k: self.params.grid[m].k,
                    lesioned: self.params.lesioned[m],
                    bumps: self.last_bumps[m].clone(),
                    tracked_rad: self.tracked[m],
                    position_m: [
                        self.module_pos_rad[m][0] * to_m,
                        self.module_pos_rad[m][1] * to_m,
                    ],
                })
                .collect(),
            fused: self.last_fused,
            place: self.last_place,
            place_position_m: [self.place_pos_rad[0] * to_m, self.place_pos_rad[1] * to_m],
            substeps: self.last_substeps,
        }
    }
}

fn nearest(bumps: &[Bump2], to: [f64; 2]) -> Option<Bump2> {
    bumps
        .iter()
        .min_by(|a, b| {
            let da = wrap(a.mean_rad[0] - to[0]).hypot(wrap(a.mean_rad[1] - to[1]));
            let db = wrap(b.mean_rad[0] - to[0]).hypot(wrap(b.mean_rad[1] - to[1]));
            da.total_cmp(&db)
        })
        .copied()
}
