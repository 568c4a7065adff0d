//! The floating-point type the networks run in: `f32` (fast, the default for SLAM) or `f64` (exactness tests).
use realfft::num_traits::{Float, FromPrimitive};
use realfft::FftNum;
use std::iter::Sum;

/// The float type a network runs in (`f32` for speed, `f64` for reference checks).
pub trait Real: FftNum + Float + FromPrimitive + Sum + Default + Send + Sync + 'static {
    /// `c = a · b` for row-major `a` (m×k), `b` (k×n), `c` (m×n), with faer's parallel GEMM.
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
macro_rules! impl_real {
    ($t:ty) => {
        impl Real for $t {
            fn gemm(m: usize, k: usize, n: usize, a: &[Self], b: &[Self], c: &mut [Self]) {
                use faer::{Accum, MatMut, MatRef, Par};
                let a = MatRef::from_row_major_slice(a, m, k);
                let b = MatRef::from_row_major_slice(b, k, n);
                let c = MatMut::from_row_major_slice_mut(c, m, n);
                faer::linalg::matmul::matmul(c, Accum::Replace, a, b, 1.0, Par::rayon(0));
            }
        }
    };
}
impl_real!(f32);
impl_real!(f64);
