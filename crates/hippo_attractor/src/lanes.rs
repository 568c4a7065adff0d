//! Vectorisable reductions over activity arrays (the integrator's inner loops).
//!
//! A float sum written as one running total cannot be vectorised: the compiler may not reorder float
//! additions. These keep `LANES` independent partial sums, which it turns into SIMD adds. The last partial
//! block is padded (with zeros, or with −∞ where only positive values count) rather than finished by a
//! scalar tail loop, because such a tail made the compiler abandon the vectorised loop (8× slower, measured).
//! For the same reason they are never inlined: inlined into the callers' rayon closures, the loops came out
//! half scalar again.
use crate::real::Real;

const LANES: usize = 16;

/// `Σ x` (partial sums in `T`, at most `len/LANES` terms each; combined in f64).
#[inline(never)]
pub fn sum<T: Real>(x: &[T]) -> f64 {
    let mut sums = [T::zero(); LANES];
    let blocks = x.chunks_exact(LANES);
    let mut last = [T::zero(); LANES];
    last[..blocks.remainder().len()].copy_from_slice(blocks.remainder());
    for block in blocks {
        add_block(&mut sums, block);
    }
    add_block(&mut sums, &last);
    sums.iter().map(|s| s.f64()).sum()
}

#[inline(always)]
fn add_block<T: Real>(sums: &mut [T; LANES], block: &[T]) {
    for i in 0..LANES {
        sums[i] = sums[i] + block[i];
    }
}

/// `(Σ [x + offset]_+, #{x + offset > 0})`.
#[inline(never)]
pub fn positive_part<T: Real>(x: &[T], offset: T) -> (f64, usize) {
    let mut sums = [T::zero(); LANES];
    let mut counts = [T::zero(); LANES];
    let blocks = x.chunks_exact(LANES);
    let mut last = [T::neg_infinity(); LANES];
    last[..blocks.remainder().len()].copy_from_slice(blocks.remainder());
    for block in blocks {
        add_positive_block(&mut sums, &mut counts, block, offset);
    }
    add_positive_block(&mut sums, &mut counts, &last, offset);
    let sum = sums.iter().map(|s| s.f64()).sum();
    // Each lane counts at most len/LANES units: exact in f32 for any realistic chunk.
    let count: f64 = counts.iter().map(|c| c.f64()).sum();
    (sum, count as usize)
}

#[inline(always)]
fn add_positive_block<T: Real>(
    sums: &mut [T; LANES],
    counts: &mut [T; LANES],
    block: &[T],
    offset: T,
) {
    let (zero, one) = (T::zero(), T::one());
    for i in 0..LANES {
        let v = block[i] + offset;
        let positive = v > zero;
        sums[i] = sums[i] + if positive { v } else { zero };
        counts[i] = counts[i] + if positive { one } else { zero };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn match_the_plain_loops_at_every_length() {
        for len in [0usize, 1, 5, 16, 17, 33, 4096, 4099] {
            let x: Vec<f64> = (0..len).map(|i| ((i as f64) * 0.37).sin()).collect();
            let plain: f64 = x.iter().sum();
            assert!((sum(&x) - plain).abs() < 1e-9, "len {len}");
            let (s, n) = positive_part(&x, -0.25);
            let want_s: f64 = x.iter().map(|v| (v - 0.25).max(0.0)).sum();
            let want_n = x.iter().filter(|v| **v - 0.25 > 0.0).count();
            assert!((s - want_s).abs() < 1e-9, "len {len}");
            assert_eq!(n, want_n, "len {len}");
        }
    }
}
