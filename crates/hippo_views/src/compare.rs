//! Normalised template difference with a horizontal shift search.
//!
//! Templates are row-major `height × width` arrays of patch-normalised intensities. For a shift `s`
//! (columns), the query `a` is compared with the stored template `b` where they overlap, pairing
//! `a[r, x]` with `b[r, x − s]`:
//!
//! ```text
//! d(s) = Σ_r Σ_x |a[r,x] − b[r,x−s]|  /  Σ_r Σ_x (|a[r,x]| + |b[r,x−s]|)        (x over the overlap)
//! ```
//!
//! By the triangle inequality `d ∈ [0, 1]`: 0 for identical views, 1 for opposite ones, and ≈ 1/√2 for two
//! unrelated unit-variance textures, whatever the image size, exposure or dataset, so one threshold serves
//! everywhere. Dividing by the overlap's own magnitude also keeps large shifts (less overlap) comparable.
//! The difference of a template is `min_s d(s)` over `s ∈ [−S, S]`; the arg-min shift says how far the
//! scene slid sideways: a positive shift (content moved right) means the camera turned counter-clockwise
//! (left) since the stored view, by `s · field_of_view / width` radians.
//!
//! Layout: templates arrive row-major but are stored and compared column-major (column after column, `height`
//! values each), so that the overlap at any shift is one contiguous run of `(width − |s|) · height` values in
//! both templates: one long, branch-free, vectorised sum per shift instead of `height` short rows.
//!
//! Coarse lower bound: summing `b − a` over blocks of `k` rows before taking absolute values can only
//! shrink the numerator (|Σ e| ≤ Σ |e|) while the denominator is exact (from per-column |·| sums), so
//! `d_coarse(s) ≤ d(s)`: templates whose coarse bound already exceeds the best difference found can be
//! skipped without changing the answer. The search evaluates that bound lazily (`coarse_exceeds`): it only
//! needs to know whether the bound beats a threshold, so it stops at the first shift that cannot be ruled
//! out (cheap when pruning fails) and abandons each shift's sum once it passes the threshold (cheap when
//! pruning succeeds). Whole-column sums (`k` = height) give a much cheaper but looser key (`rank_key`),
//! used only to choose which templates to compare first.

/// Sum of absolute differences of two equal-length slices. Eight independent accumulators let the
/// compiler vectorise (a single f32 accumulator forces strict sequential order).
#[inline]
pub(crate) fn sad(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut lanes = [0.0f32; 8];
    let mut ca = a.chunks_exact(8);
    let mut cb = b.chunks_exact(8);
    for (pa, pb) in (&mut ca).zip(&mut cb) {
        for i in 0..8 {
            lanes[i] += (pa[i] - pb[i]).abs();
        }
    }
    let mut tail = 0.0f32;
    for (p, q) in ca.remainder().iter().zip(cb.remainder()) {
        tail += (p - q).abs();
    }
    lanes.iter().sum::<f32>() + tail
}

/// Values summed between two checks of the early exit in `numerator` (a multiple of `WIDE`).
const CHECK_EVERY: usize = 256;
/// Accumulators of the long sums: four independent vectors of eight, so the adds of consecutive chunks do
/// not wait on each other's latency.
const WIDE: usize = 32;

/// `sad` for long runs, accumulating into `lanes` (not reset) and returning the sum of the last
/// `len % WIDE` values, which do not fill a chunk.
#[inline(always)]
fn sad_wide(a: &[f32], b: &[f32], lanes: &mut [f32; WIDE]) -> f32 {
    let mut ca = a.chunks_exact(WIDE);
    let mut cb = b.chunks_exact(WIDE);
    for (pa, pb) in (&mut ca).zip(&mut cb) {
        for i in 0..WIDE {
            lanes[i] += (pa[i] - pb[i]).abs();
        }
    }
    let mut tail = 0.0f32;
    for (p, q) in ca.remainder().iter().zip(cb.remainder()) {
        tail += (p - q).abs();
    }
    tail
}

/// Row-major `height × width` to column-major (`width × height`).
pub(crate) fn to_column_major(t: &[f32], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; t.len()];
    for (r, row) in t.chunks_exact(width).take(height).enumerate() {
        for (x, &v) in row.iter().enumerate() {
            out[x * height + r] = v;
        }
    }
    out
}

/// Column-major (`width × height`) back to row-major `height × width`.
pub(crate) fn to_row_major(t: &[f32], width: usize, height: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; t.len()];
    for (x, col) in t.chunks_exact(height).take(width).enumerate() {
        for (r, &v) in col.iter().enumerate() {
            out[r * width + x] = v;
        }
    }
    out
}

/// Columns of the query that overlap the stored template at shift `s`: `x ∈ [x0, x1)`, stored column `x − s`.
#[inline]
pub(crate) fn overlap(shift: isize, width: usize) -> (usize, usize) {
    let w = width as isize;
    (shift.max(0) as usize, (w + shift.min(0)) as usize)
}

/// Shifts in search order 0, −1, +1, −2, +2, …: with strict improvement, ties go to the smallest |s|.
pub(crate) fn shift_order(max_shift: usize) -> impl Iterator<Item = isize> {
    std::iter::once(0).chain((1..=max_shift as isize).flat_map(|s| [-s, s]))
}

/// Derived per-template data used by the search.
#[derive(Debug, Clone)]
pub(crate) struct Summary {
    /// Σ_r |v[r, x]| per column (width values).
    pub col_abs: Vec<f32>,
    /// Row-block sums, column-major (width columns of ceil(height / k) blocks).
    pub coarse: Vec<f32>,
    /// Σ_r v[r, x] per column (width values): the coarsest blocks, for the ranking key.
    pub col_sum: Vec<f32>,
    /// Prefix sums of `col_abs` in f64 (width + 1 values): the denominator at any shift in O(1).
    pub abs_prefix: Vec<f64>,
    /// Mean |v| over the template: its texture.
    pub texture: f32,
}

/// Summary of a column-major template (see the module docs).
pub(crate) fn summarise(t: &[f32], width: usize, height: usize, coarse_rows: usize) -> Summary {
    let n_blocks = height.div_ceil(coarse_rows);
    let mut col_abs = vec![0.0f32; width];
    let mut coarse = vec![0.0f32; n_blocks * width];
    let mut col_sum = vec![0.0f32; width];
    for (x, col) in t.chunks_exact(height).take(width).enumerate() {
        let blocks = &mut coarse[x * n_blocks..(x + 1) * n_blocks];
        for (r, &v) in col.iter().enumerate() {
            col_abs[x] += v.abs();
            blocks[r / coarse_rows] += v;
        }
        col_sum[x] = blocks.iter().sum();
    }
    let mut abs_prefix = Vec::with_capacity(width + 1);
    let mut acc = 0.0f64;
    abs_prefix.push(acc);
    for v in &col_abs {
        acc += f64::from(*v);
        abs_prefix.push(acc);
    }
    let texture = col_abs.iter().sum::<f32>() / (width * height) as f32;
    Summary {
        col_abs,
        coarse,
        col_sum,
        abs_prefix,
        texture,
    }
}

/// The denominator of `d(s)`, Σ over the overlap of the per-column magnitudes of both templates, in O(1)
/// from the f64 prefix sums (a plain f32 sum per shift is a chain of dependent adds that cost as much as
/// the numerator). The exact difference and the bounds share it.
#[inline]
pub(crate) fn denominator(a_sum: &Summary, b_sum: &Summary, shift: isize) -> f32 {
    let (x0, x1) = overlap(shift, a_sum.col_abs.len());
    let bs = (x0 as isize - shift) as usize;
    let be = bs + (x1 - x0);
    ((a_sum.abs_prefix[x1] - a_sum.abs_prefix[x0]) + (b_sum.abs_prefix[be] - b_sum.abs_prefix[bs]))
        as f32
}

/// Numerator of `d(s)` for column-major templates of `rows` values per column: one contiguous run per
/// template (the overlapping columns). Stops early (returning a value > `abort_above`) once the partial sum
/// passes `abort_above`, because the caller only needs to know it cannot win. The exit is tested every
/// `CHECK_EVERY` values on a copy of the running sum, so a value returned without exiting is the same
/// whatever `abort_above` was: the pruned search and the exhaustive one compute identical differences.
///
/// On x86-64 CPUs with AVX2 the same code runs compiled for 256-bit vectors (about 1.6× faster than the
/// baseline SSE2 build). The result is bit-identical either way: the order of every add is fixed by the
/// code, the instruction set only changes how many lanes are added at once.
#[inline]
// Unsafe code is denied in the workspace but here and in `words::ratio_test_matches`: calling the AVX2
// build after the CPU check.
#[allow(unsafe_code)]
pub(crate) fn numerator(
    a: &[f32],
    b: &[f32],
    width: usize,
    rows: usize,
    shift: isize,
    abort_above: f32,
) -> f32 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above), the only requirement of `numerator_avx2`.
        return unsafe { numerator_avx2(a, b, width, rows, shift, abort_above) };
    }
    numerator_portable(a, b, width, rows, shift, abort_above)
}

/// `numerator_portable` compiled with AVX2 enabled.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(unsafe_code)]
unsafe fn numerator_avx2(
    a: &[f32],
    b: &[f32],
    width: usize,
    rows: usize,
    shift: isize,
    abort_above: f32,
) -> f32 {
    numerator_portable(a, b, width, rows, shift, abort_above)
}

#[inline(always)]
fn numerator_portable(
    a: &[f32],
    b: &[f32],
    width: usize,
    rows: usize,
    shift: isize,
    abort_above: f32,
) -> f32 {
    let (x0, x1) = overlap(shift, width);
    let bs = (x0 as isize - shift) as usize;
    let run_a = &a[x0 * rows..x1 * rows];
    let run_b = &b[bs * rows..(bs + x1 - x0) * rows];
    let mut lanes = [0.0f32; WIDE];
    let mut tail = 0.0f32;
    for (pa, pb) in run_a.chunks(CHECK_EVERY).zip(run_b.chunks(CHECK_EVERY)) {
        tail += sad_wide(pa, pb, &mut lanes);
        let partial = lanes_total(&lanes) + tail;
        if partial > abort_above {
            return partial;
        }
    }
    lanes_total(&lanes) + tail
}

/// Sum of the lanes in a fixed order that vectorises (the four vectors first, then their eight lanes).
#[inline(always)]
fn lanes_total(lanes: &[f32; WIDE]) -> f32 {
    let mut v = [0.0f32; 8];
    for (i, x) in v.iter_mut().enumerate() {
        *x = (lanes[i] + lanes[i + 8]) + (lanes[i + 16] + lanes[i + 24]);
    }
    v.iter().sum()
}

/// Normalised difference of two zero-magnitude-safe templates: 1 (no evidence) when both are blank.
#[inline]
pub(crate) fn ratio(num: f32, den: f32) -> f32 {
    if den > f32::MIN_POSITIVE {
        num / den
    } else {
        1.0
    }
}

/// Best (difference, shift) between query `a` and stored `b` over all shifts, or `None` when it is above
/// `beat`. Exact: an early exit only drops a shift whose partial sum already proves `d(s)` exceeds the
/// best so far (with a relative slack of 1e-6 against rounding), so the surviving shifts are computed
/// exactly as a plain search computes them.
#[allow(clippy::too_many_arguments)]
pub(crate) fn best_shift(
    a: &[f32],
    a_sum: &Summary,
    b: &[f32],
    b_sum: &Summary,
    width: usize,
    height: usize,
    max_shift: usize,
    beat: f32,
) -> Option<(f32, isize)> {
    let mut best: Option<(f32, isize)> = None;
    for s in shift_order(max_shift) {
        let limit = best.map_or(beat, |(d, _)| d.min(beat));
        let den = denominator(a_sum, b_sum, s);
        let abort_above = if limit.is_finite() {
            limit * den * (1.0 + 1e-6)
        } else {
            f32::INFINITY
        };
        let num = numerator(a, b, width, height, s, abort_above);
        let d = ratio(num, den);
        let improves = best.is_none_or(|(bd, _)| d < bd);
        if improves && d <= beat {
            best = Some((d, s));
        }
    }
    best
}

/// Coarse lower bound of `min_s d(s)` (see the module docs), computed in full (reference for the tests).
#[cfg(test)]
pub(crate) fn coarse_bound(
    a_sum: &Summary,
    b_sum: &Summary,
    width: usize,
    max_shift: usize,
) -> f32 {
    let rows = a_sum.coarse.len() / width;
    shift_order(max_shift)
        .map(|s| {
            let den = denominator(a_sum, b_sum, s);
            ratio(
                numerator(&a_sum.coarse, &b_sum.coarse, width, rows, s, f32::INFINITY),
                den,
            )
        })
        .fold(f32::INFINITY, f32::min)
}

/// Whether the coarse bound proves `d(s) > threshold` at every shift, i.e. the template cannot beat
/// `threshold`. Stops at the first shift whose bound is not above the threshold, and abandons a shift's
/// block sum as soon as it passes it, so a failed test costs about one shift of the coarse bound.
pub(crate) fn coarse_exceeds(
    a_sum: &Summary,
    b_sum: &Summary,
    width: usize,
    max_shift: usize,
    threshold: f32,
) -> bool {
    let rows = a_sum.coarse.len() / width;
    for s in shift_order(max_shift) {
        let den = denominator(a_sum, b_sum, s);
        if den <= f32::MIN_POSITIVE {
            return false; // blank overlap: d(s) = 1 by convention, never ruled out here
        }
        let limit = threshold * den;
        if numerator(&a_sum.coarse, &b_sum.coarse, width, rows, s, limit) <= limit {
            return false;
        }
    }
    true
}

/// Cheap key for the order of comparison: the bound with whole columns as blocks (a lower bound too, but
/// too loose to prune; only its ranking is used, so any rounding in it is harmless).
pub(crate) fn rank_key(a_sum: &Summary, b_sum: &Summary, width: usize, max_shift: usize) -> f32 {
    shift_order(max_shift)
        .map(|s| {
            let (x0, x1) = overlap(s, width);
            let bs = (x0 as isize - s) as usize;
            let num = sad(&a_sum.col_sum[x0..x1], &b_sum.col_sum[bs..bs + (x1 - x0)]);
            ratio(num, denominator(a_sum, b_sum, s))
        })
        .fold(f32::INFINITY, f32::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic pseudo-random values in [−1, 1) (a small LCG keeps the unit tests dependency-free).
    fn noise(seed: u64, n: usize) -> Vec<f32> {
        let mut x = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((x >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
            })
            .collect()
    }

    fn plain_difference(a: &[f32], b: &[f32], w: usize, h: usize, s: isize) -> f32 {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for r in 0..h {
            for x in 0..w as isize {
                let xb = x - s;
                if xb >= 0 && xb < w as isize {
                    let (p, q) = (a[r * w + x as usize] as f64, b[r * w + xb as usize] as f64);
                    num += (p - q).abs();
                    den += p.abs() + q.abs();
                }
            }
        }
        (num / den) as f32
    }

    #[test]
    fn fast_difference_matches_the_definition_and_the_bound_holds() {
        let (w, h, k, smax) = (37, 13, 4, 6);
        for seed in 0..30 {
            let a = noise(seed, w * h);
            let mut b = noise(seed + 1000, w * h);
            if seed % 3 == 0 {
                // Partly similar pairs make the bound non-trivial.
                for (bv, av) in b.iter_mut().zip(&a) {
                    *bv = 0.7 * av + 0.3 * *bv;
                }
            }
            let (ca, cb) = (to_column_major(&a, w, h), to_column_major(&b, w, h));
            assert_eq!(to_row_major(&ca, w, h), a);
            let (sa, sb) = (summarise(&ca, w, h, k), summarise(&cb, w, h, k));
            let (best, _) = best_shift(&ca, &sa, &cb, &sb, w, h, smax, f32::INFINITY).unwrap();
            let plain = shift_order(smax)
                .map(|s| plain_difference(&a, &b, w, h, s))
                .fold(f32::INFINITY, f32::min);
            assert!(
                (best - plain).abs() < 1e-5,
                "seed {seed}: {best} vs {plain}"
            );
            let bound = coarse_bound(&sa, &sb, w, smax);
            assert!(
                bound <= best + 1e-6,
                "seed {seed}: bound {bound} above exact {best}"
            );
            assert!(bound > 0.0);
            let key = rank_key(&sa, &sb, w, smax);
            assert!(
                key <= bound + 1e-5,
                "seed {seed}: key {key} above bound {bound}"
            );
            for thr in [bound * 0.99, bound * 1.01, best * 0.5, best] {
                assert_eq!(
                    coarse_exceeds(&sa, &sb, w, smax, thr),
                    bound > thr,
                    "seed {seed}: threshold {thr}, bound {bound}"
                );
            }
            let plain: f64 = sa.col_abs[3..]
                .iter()
                .chain(&sb.col_abs[..w - 3])
                .map(|&v| f64::from(v))
                .sum();
            assert!((f64::from(denominator(&sa, &sb, 3)) - plain).abs() <= 1e-6 * plain);
        }
    }

    #[test]
    fn numerator_is_the_same_on_every_instruction_set_and_exit_threshold() {
        let (w, h) = (64, 24);
        for seed in 0..10 {
            let a = noise(seed, w * h);
            let b = noise(seed + 77, w * h);
            for s in [-8isize, -3, 0, 5, 8] {
                let full = numerator_portable(&a, &b, w, h, s, f32::INFINITY);
                assert_eq!(numerator(&a, &b, w, h, s, f32::INFINITY), full);
                // A threshold the sum passes exits early with a value above it; one it never reaches
                // returns the full sum, bit for bit.
                assert!(numerator(&a, &b, w, h, s, 0.5 * full) > 0.5 * full);
                assert_eq!(numerator(&a, &b, w, h, s, full), full);
                // The definition, on the row-major templates.
                let (ra, rb) = (to_row_major(&a, w, h), to_row_major(&b, w, h));
                let mut plain = 0.0f64;
                for r in 0..h {
                    for x in s.max(0)..w as isize + s.min(0) {
                        let (p, q) = (ra[r * w + x as usize], rb[r * w + (x - s) as usize]);
                        plain += f64::from((p - q).abs());
                    }
                }
                assert!(
                    (f64::from(full) - plain).abs() < 1e-5 * plain,
                    "seed {seed}, shift {s}"
                );
            }
        }
    }

    #[test]
    fn sad_handles_tails() {
        let a: Vec<f32> = (0..19).map(|i| i as f32).collect();
        let b = vec![0.0f32; 19];
        assert_eq!(sad(&a, &b), (0..19).sum::<i32>() as f32);
    }
}
