//! The floating-point type the networks run in: `f32` (fast, the default for SLAM) or `f64` (exactness tests).
use realfft::num_traits::{Float, FromPrimitive};
use realfft::FftNum;
use std::iter::Sum;

/// The float type a network runs in (`f32` for speed, `f64` for reference checks).
pub trait Real: FftNum + Float + FromPrimitive + Sum + Default + Send + Sync + 'static {
    /// `c = a · b` for row-major `a` (m×k), `b` (k×n), `c` (m×n), with faer's GEMM, blocks of rows on rayon's
    /// threads. Each thread clears its vector registers after faer's kernels (`hippo_simd`: the engine's own
    /// SSE code, and the odometry's refinement on the same threads, ran up to 2.7× slower otherwise). Every
    /// row is computed on one thread by the same kernel whatever the number of threads.
    fn gemm(m: usize, k: usize, n: usize, a: &[Self], b: &[Self], c: &mut [Self]);

    /// Lossy conversion from f64 (never fails for f32/f64).
    #[inline]
    fn of(x: f64) -> Self {
        Self::from_f64(x).unwrap_or_else(Self::zero)
    }
    /// The value as `f64`.
    #[inline]
    fn f64(self) -> f64 {
        self.to_f64().unwrap_or(f64::NAN)
    }
}
/// Rows of the product one task computes (8 of the default module's 81 velocity slices).
const ROWS_PER_TASK: usize = 8;

macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            fn gemm(m: usize, k: usize, n: usize, a: &[Self], b: &[Self], c: &mut [Self]) {
                use faer::{Accum, MatMut, MatRef, Par};
                use rayon::prelude::*;
                if m == 0 || n == 0 {
                    return;
                }
                if k == 0 {
                    c.fill(0.0);
                    return;
                }
                let b = MatRef::from_row_major_slice(b, k, n);
                c.par_chunks_mut(ROWS_PER_TASK * n)
                    .zip(a.par_chunks(ROWS_PER_TASK * k))
                    .for_each(|(c, a)| {
                        let rows = a.len() / k;
                        let a = MatRef::from_row_major_slice(a, rows, k);
                        let c = MatMut::from_row_major_slice_mut(c, rows, n);
                        faer::linalg::matmul::matmul(c, Accum::Replace, a, b, 1.0, Par::Seq);
                        hippo_simd::clear_upper_halves();
                    });
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);

#[cfg(test)]
mod tests {
    use super::*;

    fn product<T: Real>(m: usize, k: usize, n: usize, threads: usize) -> Vec<T> {
        let a: Vec<T> = (0..m * k)
            .map(|i| T::of(((i * 7) % 13) as f64 - 6.0))
            .collect();
        let b: Vec<T> = (0..k * n)
            .map(|i| T::of(((i * 5) % 11) as f64 * 0.25))
            .collect();
        let mut c = vec![T::of(99.0); m * n];
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| T::gemm(m, k, n, &a, &b, &mut c));
        c
    }

    #[test]
    fn the_product_is_exact_and_the_same_on_any_number_of_threads() {
        // Small integers and quarters: every sum is exact, so the product must equal the naive one; rows
        // beyond a whole block (21 = 2·8 + 5), a single row and an empty inner dimension included.
        for (m, k, n) in [(21, 10, 37), (1, 3, 5), (8, 1, 64), (5, 0, 4)] {
            let c = product::<f64>(m, k, n, 2);
            for i in 0..m {
                for j in 0..n {
                    let naive: f64 = (0..k)
                        .map(|l| {
                            (((i * k + l) * 7) % 13) as f64 - 6.0
                        } * ((((l * n + j) * 5) % 11) as f64 * 0.25))
                        .sum();
                    assert_eq!(c[i * n + j], naive, "({m}, {k}, {n}) at ({i}, {j})");
                }
            }
            let one: Vec<u32> = product::<f32>(m, k, n, 1)
                .iter()
                .map(|x| x.to_bits())
                .collect();
            let two: Vec<u32> = product::<f32>(m, k, n, 2)
                .iter()
                .map(|x| x.to_bits())
                .collect();
            assert_eq!(one, two, "({m}, {k}, {n})");
        }
    }
}
