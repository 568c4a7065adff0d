//! The second image's window sampled eight pixels at a time (AVX2 gathers), for CPUs that have AVX2.
//!
//! Sampling the warped window was half of a refinement's time (perf, `benches/tracks.rs`): per pixel, a
//! position, two row reads and three interpolations, one pixel after another. Here eight lanes take eight
//! window pixels with the very operations of `GrayImage::sample_inside` and `RowPair::sample` (IEEE
//! single precision, no fused multiply–add, the same order), so every sample is the same number bit for
//! bit; the module's tests compare them over every pixel of many windows.
//!
//! Each lane's four neighbours come from two 32-bit gathers at byte offsets: the top pair is the low two
//! bytes of the word at the top-left neighbour, the bottom pair the high two bytes of the word two bytes
//! before the bottom-left neighbour, so that no read passes the image's last byte.
#![allow(unsafe_code)] // gathers and masked loads through raw pointers, in bounds (each function says why)

use super::GrayImage;
use std::arch::x86_64::{
    __m256, __m256i, _mm256_add_epi32, _mm256_add_ps, _mm256_and_si256, _mm256_cmpgt_epi32,
    _mm256_cvtepi32_ps, _mm256_cvttps_epi32, _mm256_mask_i32gather_epi32, _mm256_maskload_ps,
    _mm256_maskstore_ps, _mm256_max_epi32, _mm256_min_epi32, _mm256_mul_ps, _mm256_mullo_epi32,
    _mm256_set1_epi32, _mm256_set1_ps, _mm256_setr_epi32, _mm256_setzero_si256, _mm256_srli_epi32,
    _mm256_sub_ps,
};

const LANES: usize = 8;

/// Whether this CPU runs [`sample_affine`] and [`sample_rows`] (AVX2), and the image is small enough for
/// 32-bit byte offsets.
pub(super) fn usable(image: &GrayImage<'_>) -> bool {
    std::arch::is_x86_feature_detected!("avx2") && image.data.len() <= i32::MAX as usize
}

/// A mask of the first `len` (≤ 8) lanes.
#[target_feature(enable = "avx2")]
fn first_lanes(len: usize) -> __m256i {
    _mm256_cmpgt_epi32(
        _mm256_set1_epi32(len.min(LANES) as i32),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    )
}

/// `top + fy·(bottom − top)` with `top = t0 + fx·(t1 − t0)`, `bottom = b0 + fx·(b1 − b0)`: the two row pairs
/// are bytes 0–1 of `top_words` and bytes 2–3 of `bottom_words` (the module doc).
#[target_feature(enable = "avx2")]
fn blend(top_words: __m256i, bottom_words: __m256i, fx: __m256, fy: __m256) -> __m256 {
    let byte = _mm256_set1_epi32(0xFF);
    let t0 = _mm256_cvtepi32_ps(_mm256_and_si256(top_words, byte));
    let t1 = _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(top_words), byte));
    let b0 = _mm256_cvtepi32_ps(_mm256_and_si256(
        _mm256_srli_epi32::<16>(bottom_words),
        byte,
    ));
    let b1 = _mm256_cvtepi32_ps(_mm256_srli_epi32::<24>(bottom_words));
    let top = _mm256_add_ps(t0, _mm256_mul_ps(fx, _mm256_sub_ps(t1, t0)));
    let bottom = _mm256_add_ps(b0, _mm256_mul_ps(fx, _mm256_sub_ps(b1, b0)));
    _mm256_add_ps(top, _mm256_mul_ps(fy, _mm256_sub_ps(bottom, top)))
}

/// The two gathers of [`blend`]'s words for the top-left neighbours at byte offsets `at` (masked lanes read
/// nothing and give 0).
///
/// # Safety
/// Every lane of `mask` must hold an offset with `0 ≤ at` and `at + width + 1 < data.len()`, and
/// `width ≥ 2`.
#[target_feature(enable = "avx2")]
unsafe fn gather(image: &GrayImage<'_>, at: __m256i, mask: __m256i) -> (__m256i, __m256i) {
    let base = image.data.as_ptr().cast::<i32>();
    let zero = _mm256_setzero_si256();
    let below = _mm256_add_epi32(at, _mm256_set1_epi32(image.width as i32 - 2));
    // SAFETY: the top word reads `at ..= at + 3` and the bottom one `at + width − 2 ..= at + width + 1`,
    // inside `data` by the caller's bounds (width ≥ 3 makes `at + 3 ≤ at + width`); unaligned reads are
    // what a gather of scale 1 does.
    unsafe {
        (
            _mm256_mask_i32gather_epi32::<1>(zero, base, at, mask),
            _mm256_mask_i32gather_epi32::<1>(zero, base, below, mask),
        )
    }
}

/// `GrayImage::sample_inside` at `(cx + l0·du + l1·dv, cy + l2·du + l3·dv)` for each window offset
/// `(du, dv)` into `out`, eight at a time; the same numbers.
///
/// # Safety
/// The CPU must support AVX2 ([`usable`]), and `du`, `dv` and `out` must have the same length.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sample_affine(
    image: &GrayImage<'_>,
    centre: [f32; 2],
    l: [f32; 4],
    du: &[f32],
    dv: &[f32],
    out: &mut [f32],
) {
    let (width, height) = (image.width as i32, image.height as i32);
    // `sample_inside`'s clamp: never above the last valid top-left corner.
    let limit = _mm256_set1_epi32((image.data.len() - image.width - 2) as i32);
    let zero = _mm256_setzero_si256();
    let (cx, cy) = (_mm256_set1_ps(centre[0]), _mm256_set1_ps(centre[1]));
    let l = l.map(|v| _mm256_set1_ps(v));
    let mut start = 0;
    while start < out.len() {
        let mask = first_lanes(out.len() - start);
        // SAFETY: the mask admits lanes `start .. min(start + 8, len)`, all inside the three slices.
        let (u, v) = unsafe {
            (
                _mm256_maskload_ps(du.as_ptr().add(start), mask),
                _mm256_maskload_ps(dv.as_ptr().add(start), mask),
            )
        };
        // As written in `refine_with`: (c + l·du) + l·dv, left to right.
        let x = _mm256_add_ps(
            _mm256_add_ps(cx, _mm256_mul_ps(l[0], u)),
            _mm256_mul_ps(l[1], v),
        );
        let y = _mm256_add_ps(
            _mm256_add_ps(cy, _mm256_mul_ps(l[2], u)),
            _mm256_mul_ps(l[3], v),
        );
        let (x0, y0) = (_mm256_cvttps_epi32(x), _mm256_cvttps_epi32(y));
        let fx = _mm256_sub_ps(x, _mm256_cvtepi32_ps(x0));
        let fy = _mm256_sub_ps(y, _mm256_cvtepi32_ps(y0));
        // The whole parts held to the image before the product, so it cannot overflow: inside the image
        // (all the refinement samples) that changes nothing, and elsewhere the offset stays in bounds.
        let xc = _mm256_min_epi32(_mm256_max_epi32(x0, zero), _mm256_set1_epi32(width - 1));
        let yc = _mm256_min_epi32(_mm256_max_epi32(y0, zero), _mm256_set1_epi32(height - 1));
        let at = _mm256_min_epi32(
            _mm256_add_epi32(_mm256_mullo_epi32(yc, _mm256_set1_epi32(width)), xc),
            limit,
        );
        // SAFETY: 0 ≤ at ≤ len − width − 2, so at + width + 1 < len.
        let (top, bottom) = unsafe { gather(image, at, mask) };
        let samples = blend(top, bottom, fx, fy);
        // SAFETY: the same lanes as the loads.
        unsafe { _mm256_maskstore_ps(out.as_mut_ptr().add(start), mask, samples) };
        start += LANES;
    }
}

/// `RowPair::sample` along window rows: row `k` of `out` (`side` samples) at columns
/// `cx + l0·du + l1·dv` (`column = [cx, l0, l1]`) of that row's offsets, on the row pair `rows[k] = (r·width, fy)` of
/// `GrayImage::row_of`; the same numbers.
///
/// # Safety
/// The CPU must support AVX2 ([`usable`]); `du`, `dv` and `out` hold `side` samples for each of the
/// `rows.len()` rows, and each row start is `r · width` with `r ≤ height − 2`.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sample_rows(
    image: &GrayImage<'_>,
    column: [f32; 3],
    rows: &[(usize, f32)],
    side: usize,
    du: &[f32],
    dv: &[f32],
    out: &mut [f32],
) {
    let zero = _mm256_setzero_si256();
    let last_column = _mm256_set1_epi32(image.width as i32 - 2);
    let [cx, l0, l1] = column.map(|v| _mm256_set1_ps(v));
    for (k, &(row_start, fy)) in rows.iter().enumerate() {
        let fy = _mm256_set1_ps(fy);
        let first = _mm256_set1_epi32(row_start as i32);
        let mut start = k * side;
        let end = start + side;
        while start < end {
            let mask = first_lanes(end - start);
            // SAFETY: the mask admits lanes `start .. min(start + 8, end)`, inside the three slices.
            let (u, v) = unsafe {
                (
                    _mm256_maskload_ps(du.as_ptr().add(start), mask),
                    _mm256_maskload_ps(dv.as_ptr().add(start), mask),
                )
            };
            let x = _mm256_add_ps(
                _mm256_add_ps(cx, _mm256_mul_ps(l0, u)),
                _mm256_mul_ps(l1, v),
            );
            let x0 = _mm256_cvttps_epi32(x);
            let fx = _mm256_sub_ps(x, _mm256_cvtepi32_ps(x0));
            let col = _mm256_min_epi32(_mm256_max_epi32(x0, zero), last_column);
            // SAFETY: at = r·width + column with r ≤ height − 2 and column ≤ width − 2, so
            // at + width + 1 ≤ height·width − 1 < len.
            let (top, bottom) = unsafe { gather(image, _mm256_add_epi32(first, col), mask) };
            let samples = blend(top, bottom, fx, fy);
            // SAFETY: the same lanes as the loads.
            unsafe { _mm256_maskstore_ps(out.as_mut_ptr().add(start), mask, samples) };
            start += LANES;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An image whose bytes take every value, in no smooth pattern (neighbours differ a lot).
    fn noise(width: usize, height: usize) -> Vec<u8> {
        (0..width * height)
            .map(|i| ((i as u64 * 2_654_435_761) >> 13) as u8)
            .collect()
    }

    #[test]
    fn every_lane_samples_as_the_one_pixel_loop() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return; // nothing to compare on this CPU: the one-pixel loop is what runs
        }
        let (w, h) = (53, 29);
        let data = noise(w, h);
        let image = GrayImage::new(&data, w, h).unwrap();
        // Windows of 1–20 pixels (a partial block of every length), warped, anywhere a window's samples
        // stay in [0, w − 1) × [0, h − 1), the last column and row included.
        for k in 0..3000usize {
            let n = 1 + k % 20;
            let du: Vec<f32> = (0..n).map(|i| (i % 5) as f32 - 2.0).collect();
            let dv: Vec<f32> = (0..n).map(|i| (i / 5) as f32 - 2.0).collect();
            let f = |s: f32| (k as f32 * s).fract();
            let l = [
                1.0 + 0.2 * (f(0.31) - 0.5),
                0.1 * f(0.17),
                0.1 * (f(0.23) - 0.5),
                1.0,
            ];
            let centre = [
                3.0 + f(0.618) * (w as f32 - 6.01),
                3.0 + f(0.414) * (h as f32 - 6.01),
            ];
            let mut lanes = vec![f32::NAN; n];
            // SAFETY: AVX2 is present (checked above), the slices have the same length.
            unsafe { sample_affine(&image, centre, l, &du, &dv, &mut lanes) };
            for i in 0..n {
                let (x, y) = (
                    centre[0] + l[0] * du[i] + l[1] * dv[i],
                    centre[1] + l[2] * du[i] + l[3] * dv[i],
                );
                assert_eq!(
                    lanes[i].to_bits(),
                    image.sample_inside(x, y).to_bits(),
                    "({x}, {y})"
                );
            }
            // The same offsets along rows (row-shear: l[2] = 0, l[3] = 1), one row of n pixels.
            let row = image.row_of(centre[1]);
            let mut by_rows = vec![f32::NAN; n];
            // SAFETY: as above; one row of `n` samples, its start from `row_of`.
            unsafe {
                sample_rows(
                    &image,
                    [centre[0], l[0], l[1]],
                    &[row],
                    n,
                    &du,
                    &dv,
                    &mut by_rows,
                )
            };
            let pair = image.pair_at(row);
            for i in 0..n {
                let x = centre[0] + l[0] * du[i] + l[1] * dv[i];
                assert_eq!(by_rows[i].to_bits(), pair.sample(x).to_bits(), "x {x}");
            }
        }
        // The corner a sample may touch last: the byte offsets reach the image's final byte, not past it.
        let last = [(w - 1) as f32 - 1e-3, (h - 1) as f32 - 1e-3];
        let mut one = [f32::NAN];
        // SAFETY: as above.
        unsafe { sample_affine(&image, last, [1.0, 0.0, 0.0, 1.0], &[0.0], &[0.0], &mut one) };
        assert_eq!(
            one[0].to_bits(),
            image.sample_inside(last[0], last[1]).to_bits()
        );
    }
}
