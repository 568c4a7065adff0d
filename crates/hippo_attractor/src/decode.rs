//! Bump decoding on a 2-D neural torus (docs/spec.md §4).
//!
//! Bumps are found by wrap-aware clustering, never by assuming a square lattice (the k = 2 and k = 4
//! patterns sit in offset rows): units above `threshold_frac · max` form 4-connected components on the
//! torus; every active unit is then given to the nearest component's centre, and each bump gets its centre
//! (local circular mean around the component) and per-axis activity-weighted variance
//! `σ² = Σ m·wrap(θ − μ)² / Σ m` (the paper's `1/n` normalisation is not reproducible).
use crate::circular::{wrap, wrap_2pi};
use crate::fusion::Bump2;
use crate::real::Real;
use std::f64::consts::TAU;

/// Find every bump of an N×N pattern (`[iy][ix]`). Bumps are sorted by decreasing mass.
pub fn find_bumps<T: Real>(pattern: &[T], n: usize, threshold_frac: f64) -> Vec<Bump2> {
    let p: Vec<f64> = pattern.iter().map(|x| x.f64().max(0.0)).collect();
    let max = p.iter().cloned().fold(0.0, f64::max);
    if !(max > 0.0 && max.is_finite()) || p.len() != n * n || p.iter().any(|x| !x.is_finite()) {
        return Vec::new();
    }
    let threshold = threshold_frac * max;
    let angle = |i: usize| TAU * i as f64 / n as f64;
    // 1. Components of supra-threshold units (4-neighbourhood, periodic).
    let mut label = vec![usize::MAX; n * n];
    let mut seeds: Vec<[f64; 2]> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..n * n {
        if p[start] <= threshold || label[start] != usize::MAX {
            continue;
        }
        let id = seeds.len();
        label[start] = id;
        stack.push(start);
        let (ax, ay) = (angle(start % n), angle(start / n));
        let (mut sx, mut sy, mut w) = (0.0, 0.0, 0.0);
        while let Some(u) = stack.pop() {
            let (x, y) = (u % n, u / n);
            sx += p[u] * wrap(angle(x) - ax);
            sy += p[u] * wrap(angle(y) - ay);
            w += p[u];
            for (nx, ny) in [
                ((x + 1) % n, y),
                ((x + n - 1) % n, y),
                (x, (y + 1) % n),
                (x, (y + n - 1) % n),
            ] {
                let v = ny * n + nx;
                if p[v] > threshold && label[v] == usize::MAX {
                    label[v] = id;
                    stack.push(v);
                }
            }
        }
        seeds.push([wrap_2pi(ax + sx / w), wrap_2pi(ay + sy / w)]);
    }
    // 2. Every active unit joins the nearest seed; refine centre, then variance around it.
    // The per-axis differences to each seed depend on one coordinate only: tabled once per column and
    // row (n·seeds wraps instead of n²·seeds; the same numbers, the decoder's largest cost before).
    let k = seeds.len();
    let table = |axis: usize, around: &[[f64; 2]]| -> Vec<f64> {
        (0..n)
            .flat_map(|i| around.iter().map(move |c| wrap(angle(i) - c[axis])))
            .collect()
    };
    let (seed_dx, seed_dy) = (table(0, &seeds), table(1, &seeds));
    let mut owner = vec![usize::MAX; n * n];
    let mut acc = vec![[0.0f64; 3]; k];
    for y in 0..n {
        let dy = &seed_dy[y * k..][..k];
        for x in 0..n {
            let u = y * n + x;
            if p[u] > 0.0 {
                let dx = &seed_dx[x * k..][..k];
                let mut best = (f64::INFINITY, 0);
                for i in 0..k {
                    let d = dx[i].powi(2) + dy[i].powi(2);
                    if d < best.0 {
                        best = (d, i);
                    }
                }
                let b = best.1;
                owner[u] = b;
                acc[b][0] += p[u] * dx[b];
                acc[b][1] += p[u] * dy[b];
                acc[b][2] += p[u];
            }
        }
    }
    let centres: Vec<[f64; 2]> = seeds
        .iter()
        .zip(&acc)
        .map(|(s, a)| [wrap_2pi(s[0] + a[0] / a[2]), wrap_2pi(s[1] + a[1] / a[2])])
        .collect();
    let (centre_dx, centre_dy) = (table(0, &centres), table(1, &centres));
    let mut var = vec![[0.0f64; 2]; k];
    for y in 0..n {
        for x in 0..n {
            let u = y * n + x;
            if owner[u] != usize::MAX {
                let b = owner[u];
                var[b][0] += p[u] * centre_dx[x * k + b].powi(2);
                var[b][1] += p[u] * centre_dy[y * k + b].powi(2);
            }
        }
    }
    let mut bumps: Vec<Bump2> = centres
        .iter()
        .zip(&acc)
        .zip(&var)
        .map(|((c, a), v)| Bump2 {
            mean_rad: *c,
            std_rad: [(v[0] / a[2]).sqrt(), (v[1] / a[2]).sqrt()],
            mass: a[2],
        })
        .collect();
    bumps.sort_by(|a, b| b.mass.total_cmp(&a.mass));
    bumps
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian_pattern(n: usize, centres: &[[f64; 2]], s: f64) -> Vec<f64> {
        let mut p = vec![0.0; n * n];
        for y in 0..n {
            for x in 0..n {
                for c in centres {
                    let dx = wrap(TAU * x as f64 / n as f64 - c[0]);
                    let dy = wrap(TAU * y as f64 / n as f64 - c[1]);
                    let v = (-(dx * dx + dy * dy) / (2.0 * s * s)).exp() - 0.05;
                    p[y * n + x] += v.max(0.0);
                }
            }
        }
        p
    }

    #[test]
    fn finds_wrapped_bumps_with_their_centres() {
        // One bump straddles the (0, 0) corner: clustering must be wrap-aware.
        let centres = [[0.05, 6.2], [3.0, 3.0], [1.5, 4.7]];
        let bumps = find_bumps(&gaussian_pattern(64, &centres, 0.25), 64, 0.3);
        assert_eq!(bumps.len(), 3);
        for c in centres {
            let b = bumps
                .iter()
                .min_by(|a, b| {
                    let da = wrap(a.mean_rad[0] - c[0]).hypot(wrap(a.mean_rad[1] - c[1]));
                    let db = wrap(b.mean_rad[0] - c[0]).hypot(wrap(b.mean_rad[1] - c[1]));
                    da.total_cmp(&db)
                })
                .unwrap();
            assert!(wrap(b.mean_rad[0] - c[0]).abs() < 0.02, "{b:?} vs {c:?}");
            assert!(wrap(b.mean_rad[1] - c[1]).abs() < 0.02, "{b:?} vs {c:?}");
            // Truncated Gaussian: width a bit below σ = 0.25.
            assert!(b.std_rad[0] > 0.15 && b.std_rad[0] < 0.25, "{b:?}");
        }
    }

    #[test]
    fn silent_pattern_has_no_bump() {
        assert!(find_bumps(&[0.0f64; 16], 4, 0.3).is_empty());
    }

    #[test]
    fn tabled_differences_give_the_direct_sums_bit_for_bit() {
        // The decoder tables each unit's per-axis differences to the seeds and centres; the assignment,
        // centres and widths must equal the sums taken unit by unit (here recomputed directly from the
        // decoder's own centres: every active unit joins the nearest one).
        let n = 32;
        let centres = [[0.3, 5.9], [2.0, 2.2], [4.4, 1.0], [5.5, 4.6]];
        let pattern = gaussian_pattern(n, &centres, 0.4);
        let bumps = find_bumps(&pattern, n, 0.3);
        assert_eq!(bumps.len(), 4);
        let angle = |i: usize| TAU * i as f64 / n as f64;
        for b in &bumps {
            let (mut mass, mut v) = (0.0, [0.0f64; 2]);
            for y in 0..n {
                for x in 0..n {
                    let p = pattern[y * n + x];
                    let own = bumps
                        .iter()
                        .map(|o| {
                            let d = |a: usize| wrap(angle([x, y][a]) - o.mean_rad[a]).powi(2);
                            d(0) + d(1)
                        })
                        .collect::<Vec<_>>();
                    let nearest = own.iter().cloned().fold(f64::INFINITY, f64::min);
                    let d = |a: usize| wrap(angle([x, y][a]) - b.mean_rad[a]).powi(2);
                    if p > 0.0 && d(0) + d(1) == nearest {
                        mass += p;
                        v[0] += p * d(0);
                        v[1] += p * d(1);
                    }
                }
            }
            // Units join the nearest *seed*, and the seeds sit within a fraction of a unit of the centres:
            // the same units here, so the same sums.
            assert_eq!(b.mass.to_bits(), mass.to_bits(), "{b:?}");
            for (std, sum) in b.std_rad.iter().zip(v) {
                assert_eq!(std.to_bits(), (sum / mass).sqrt().to_bits(), "{b:?}");
            }
        }
    }
}
