//! Dense-weight reference implementations of the recurrent inputs (the `J1`/`Jk` terms, without the uniform
//! inhibition): a direct double sum over all unit pairs, straight from the weight formulas. For tests
//! (the fast paths must equal these) and benchmarks (the cost the fast paths avoid) — never for running.
use crate::check::{angle_axis, velocity_axis};
use crate::grid::{slice_velocities, GridParams};
use crate::hd::HdParams;
use crate::place::PlaceParams;
use std::f64::consts::TAU;

/// HD ring: `h(θ,ν) = (J1/(NθNν)) Σ cos(θ − θ' − ν') cos(λ(ν − ν')) m(θ',ν')`, layout `[ν][θ]`.
pub fn hd_recurrent(p: &HdParams, m: &[f64]) -> Vec<f64> {
    let theta = angle_axis(p.n_theta);
    let nu = velocity_axis(p.n_nu, p.nu_max);
    let (nt, nv) = (p.n_theta, p.n_nu);
    let mut h = vec![0.0; nt * nv];
    for j in 0..nv {
        for i in 0..nt {
            let mut acc = 0.0;
            for jp in 0..nv {
                for ip in 0..nt {
                    acc += (theta[i] - theta[ip] - nu[jp]).cos()
                        * (p.lambda * (nu[j] - nu[jp])).cos()
                        * m[jp * nt + ip];
                }
            }
            h[j * nt + i] = p.j1 * acc / (nt * nv) as f64;
        }
    }
    h
}

/// Grid module: `h(θ,ν) = (Jk/(N²M²)) Σ cos(k|wrap(θ − θ' − ν')|) cos(λ|ν − ν'|) m(θ',ν')`.
pub fn grid_recurrent(p: &GridParams, m: &[f64]) -> Vec<f64> {
    let weights = DenseGridWeights::<f64>::new(p);
    let mut h = vec![0.0; m.len()];
    weights.apply(m, &mut h);
    h
}

/// Place torus: `h(θ) = (J1/N²) Σ cos(|wrap(θ − θ')|) m(θ')`.
pub fn place_recurrent(p: &PlaceParams, m: &[f64]) -> Vec<f64> {
    let n = p.n_theta;
    let mut h = vec![0.0; n * n];
    for y in 0..n {
        for x in 0..n {
            let mut acc = 0.0;
            for yp in 0..n {
                for xp in 0..n {
                    let dx = crate::circular::wrap(TAU * (x as f64 - xp as f64) / n as f64);
                    let dy = crate::circular::wrap(TAU * (y as f64 - yp as f64) / n as f64);
                    acc += dx.hypot(dy).cos() * m[yp * n + xp];
                }
            }
            h[y * n + x] = p.j1 * acc / (n * n) as f64;
        }
    }
    h
}

/// The full weight matrix of a grid module (what the paper stored: 3 GB of f64 at 20×20×7×7).
pub struct DenseGridWeights<T> {
    n_units: usize,
    weights: Vec<T>,
}

impl<T: crate::real::Real> DenseGridWeights<T> {
    /// The dense weight matrix of a grid module (`(M²N²)²` entries: small modules only).
    pub fn new(p: &GridParams) -> Self {
        let n = p.n_theta;
        let n2 = n * n;
        let slices = slice_velocities(&velocity_axis(p.n_nu, p.nu_max));
        let n_units = p.n_units();
        let scale = p.jk / n_units as f64;
        let theta = |u: usize| {
            let t = u % n2;
            [
                TAU * (t % n) as f64 / n as f64,
                TAU * (t / n) as f64 / n as f64,
            ]
        };
        let mut weights = Vec::with_capacity(n_units * n_units);
        for post in 0..n_units {
            let (tp, vp) = (theta(post), slices[post / n2]);
            for pre in 0..n_units {
                let (tq, vq) = (theta(pre), slices[pre / n2]);
                let w = p.theta_kernel([tp[0] - tq[0], tp[1] - tq[1]], vq) * p.nu_kernel(vp, vq);
                weights.push(T::of(scale * w));
            }
        }
        Self { n_units, weights }
    }

    /// `h = W m` (dense matrix–vector product).
    pub fn apply(&self, m: &[T], h: &mut [T]) {
        for (row, out) in self.weights.chunks(self.n_units).zip(h.iter_mut()) {
            *out = row
                .iter()
                .zip(m)
                .fold(T::zero(), |acc, (&w, &x)| acc + w * x);
        }
    }
}
