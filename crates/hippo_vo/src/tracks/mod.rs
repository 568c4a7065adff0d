//! Sub-pixel refinement of KLT matches with a warped window: removes the bias a translation-only
//! window has on a slanted surface.
//!
//! Pyramidal Lucas–Kanade (OpenCV's `calcOpticalFlowPyrLK`) moves a square window by a translation.
//! Where the image motion varies across the window — a road seen at a grazing angle, whose disparity
//! grows by about `baseline / camera height` px per row and whose forward flow grows with the square of
//! the row — the translation that fits best is the motion of the window's gradient-weighted middle, not
//! of its centre. That bias has one sign wherever the road is seen, so the odometry turns it into a
//! steady pitch (and, through the stereo depths, scale and heading) drift: on the whole-sequence renders
//! 0.11 px of temporal and 0.16 px of stereo bias on road points gave 14–23° of accumulated pitch error.
//!
//! Here each match found by KLT is refined by Gauss–Newton on the same window with a warp that can
//! shear and stretch, started at KLT's translation:
//! - [`WarpModel::Affine`] (temporal tracks): `x_b = c + (I + M)·x`, six parameters;
//! - [`WarpModel::RowShear`] (rectified stereo): the match stays on its row,
//!   `u_b = c_u + (1 + a)·du + b·dv`, three parameters (the disparity and its gradients across the window).
//!
//! Inverse compositional (Baker & Matthews 2004): the window's gradients and Gauss–Newton matrix are
//! computed once on the first image, and each iteration samples the second image once per window pixel.
//! Both windows are compared with their means removed (a small change of exposure between the images
//! does not shift the match). A refinement that fails (a window off the image, a singular system, a move
//! of more than `max_shift_px` from KLT's answer, or a warp beyond `max_deformation`) returns `None`:
//! the caller keeps KLT's match.
//!
//! Sampling the second image is the inner loop: on CPUs with AVX2 it takes eight window pixels at a time
//! (`avx2.rs`) with the same arithmetic, so the results do not depend on the CPU.
use crate::error::{Result, VoError};
use nalgebra::{Cholesky, Matrix6, Vector6};
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
mod avx2;

/// An 8-bit gray image, row-major.
#[derive(Debug, Clone, Copy)]
pub struct GrayImage<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
}

impl<'a> GrayImage<'a> {
    /// A view of `data` as a `width` × `height` image (row-major, `data.len() == width * height`).
    pub fn new(data: &'a [u8], width: usize, height: usize) -> Result<Self> {
        if width < 3 || height < 3 || data.len() != width * height {
            return Err(VoError::BadParameter {
                name: "image",
                value: data.len().to_string(),
                why: "must hold width × height bytes, at least 3 × 3".to_string(),
            });
        }
        Ok(Self {
            data,
            width,
            height,
        })
    }

    /// The (2·reach + 1)² samples around (x, y) at whole-pixel offsets, row-major into `out`, or None when
    /// they are not all inside the image.
    fn window(&self, x: f32, y: f32, reach: usize, out: &mut [f32]) -> Option<()> {
        let (x0, y0) = (
            (x.floor() as isize) - reach as isize,
            (y.floor() as isize) - reach as isize,
        );
        let side = 2 * reach + 1;
        if x0 < 0 || y0 < 0 || x0 as usize + side >= self.width || y0 as usize + side >= self.height
        {
            return None;
        }
        let (fx, fy) = (x - x.floor(), y - y.floor());
        let (w00, w01, w10, w11) = (
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        );
        for (r, row_out) in out.chunks_exact_mut(side).enumerate() {
            let top = &self.data[(y0 as usize + r) * self.width + x0 as usize..][..side + 1];
            let bottom = &self.data[(y0 as usize + r + 1) * self.width + x0 as usize..][..side + 1];
            for (c, o) in row_out.iter_mut().enumerate() {
                *o = w00 * f32::from(top[c])
                    + w01 * f32::from(top[c + 1])
                    + w10 * f32::from(bottom[c])
                    + w11 * f32::from(bottom[c + 1]);
            }
        }
        Some(())
    }

    /// The rows around y ([0, height − 1), checked by the caller) for [`RowPair::sample`].
    // The refinement goes through `row_of` and `pair_at`; a test checks that a pair samples as
    // `sample_inside` does.
    #[cfg(test)]
    fn row_pair(&self, y: f32) -> RowPair<'_> {
        self.pair_at(self.row_of(y))
    }

    /// The row pair that begins at byte `start` (`row_of`'s), with weight `fy`.
    fn pair_at(&self, (start, fy): (usize, f32)) -> RowPair<'_> {
        let w = self.width;
        RowPair {
            top: &self.data[start..start + w],
            bottom: &self.data[start + w..start + 2 * w],
            fy,
        }
    }

    /// (r · width, fy): where the row pair around y begins (its top row r ≤ height − 2) and the weight of
    /// its bottom row.
    fn row_of(&self, y: f32) -> (usize, f32) {
        let y0 = y as i32;
        let fy = y - y0 as f32;
        let r = (y0.max(0) as usize).min(self.height - 2);
        (r * self.width, fy)
    }

    /// Bilinear intensity at (x, y), which the caller has checked to lie in [0, width − 1) × [0, height − 1).
    // Always inlined: called once per window pixel and iteration, it was the refinement's largest cost as
    // a function call (15 % of the VO's time on KITTI 06 in perf).
    #[inline(always)]
    fn sample_inside(&self, x: f32, y: f32) -> f32 {
        // Through i32, not usize: the same whole part (x, y ≥ 0 and far below 2²⁴), with cheaper
        // conversions each way (a quarter of the refinement's time went to the usize ones in perf).
        let (x0, y0) = (x as i32, y as i32);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        // Never above the last valid corner (the caller's check makes it so; the clamp keeps a wrong check from
        // becoming a panic).
        let i = (y0.max(0) as usize * self.width + x0.max(0) as usize)
            .min(self.data.len() - self.width - 2);
        // The four corners through one slice: one bounds check instead of four.
        let w = self.width;
        let d = &self.data[i..i + w + 2];
        let top = f32::from(d[0]) + fx * (f32::from(d[1]) - f32::from(d[0]));
        let bottom = f32::from(d[w]) + fx * (f32::from(d[w + 1]) - f32::from(d[w]));
        top + fy * (bottom - top)
    }
}

/// Two neighbouring image rows and the weight between them: bilinear samples along one row position.
struct RowPair<'a> {
    top: &'a [u8],
    bottom: &'a [u8],
    fy: f32,
}

impl RowPair<'_> {
    /// [`GrayImage::sample_inside`] at (x, the pair's y), the same arithmetic; x in [0, width − 1).
    #[inline(always)]
    fn sample(&self, x: f32) -> f32 {
        let x0 = x as i32;
        let fx = x - x0 as f32;
        let i = (x0.max(0) as usize).min(self.top.len() - 2);
        let (t, b) = (&self.top[i..i + 2], &self.bottom[i..i + 2]);
        let top = f32::from(t[0]) + fx * (f32::from(t[1]) - f32::from(t[0]));
        let bottom = f32::from(b[0]) + fx * (f32::from(b[1]) - f32::from(b[0]));
        top + self.fy * (bottom - top)
    }
}

/// Which warp the window may take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WarpModel {
    /// A general 2-D affine warp (temporal tracks).
    Affine,
    /// A horizontal shift with horizontal stretch and shear, the row kept (a rectified stereo match).
    RowShear,
}

/// Settings of [`refine_matches`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineParams {
    /// Half the window side, px (the window is `2·half + 1` square; use KLT's).
    pub half_window_px: usize,
    /// Gauss–Newton iterations at most.
    pub max_iterations: usize,
    /// Stop when the window's centre moves less than this in an iteration, px.
    pub converged_px: f64,
    /// A refined match farther than this from KLT's is not trusted (KLT's is kept), px.
    pub max_shift_px: f64,
    /// A warp whose linear part differs from the identity by more than this (any entry) is rejected.
    pub max_deformation: f64,
    /// How the second image's window is sampled; the results are the same bit for bit either way.
    pub sampling: Sampling,
}

/// How [`refine_matches`] samples the second image's window (module doc, last paragraph).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Sampling {
    /// Eight pixels at a time on CPUs with AVX2, else one at a time.
    #[default]
    Fastest,
    /// One pixel at a time everywhere: the baseline `benches/tracks.rs` measures the eight-lane sampling
    /// against, and what the tests compare it with.
    OneByOne,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            half_window_px: 7,
            max_iterations: 5,
            converged_px: 0.01,
            max_shift_px: 1.0,
            max_deformation: 0.5,
            sampling: Sampling::Fastest,
        }
    }
}

impl RefineParams {
    fn check(&self) -> Result<()> {
        if !(1..=32).contains(&self.half_window_px) {
            return Err(VoError::BadParameter {
                name: "half_window_px",
                value: self.half_window_px.to_string(),
                why: "must be in 1..=32".to_string(),
            });
        }
        for (name, value) in [
            ("converged_px", self.converged_px),
            ("max_shift_px", self.max_shift_px),
            ("max_deformation", self.max_deformation),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(VoError::BadParameter {
                    name,
                    value: value.to_string(),
                    why: "must be finite and > 0".to_string(),
                });
            }
        }
        Ok(())
    }
}

/// The matches `matched_b` (in `b`) of the points `points_a` (in `a`), refined (module doc); `None` where
/// the refinement failed and the caller should keep the match it had. `points_a` and `matched_b` are
/// (x, y) pixel positions, one per match.
pub fn refine_matches(
    a: &GrayImage<'_>,
    b: &GrayImage<'_>,
    points_a: &[[f64; 2]],
    matched_b: &[[f64; 2]],
    model: WarpModel,
    params: &RefineParams,
) -> Result<Vec<Option<[f64; 2]>>> {
    params.check()?;
    if points_a.len() != matched_b.len() {
        return Err(VoError::BadParameter {
            name: "matched_b",
            value: matched_b.len().to_string(),
            why: "must hold one match per point".to_string(),
        });
    }
    #[cfg(target_arch = "x86_64")]
    let lanes = params.sampling == Sampling::Fastest && avx2::usable(b);
    #[cfg(not(target_arch = "x86_64"))]
    let lanes = false;
    // Matches are independent, so the result does not depend on the number of threads. Two threads halve
    // the VO's own time (criterion); in the whole pipeline the other stages already fill both cores and the
    // frame rate was the same either way (docs/vo.md).
    Ok(points_a
        .par_iter()
        .zip(matched_b.par_iter())
        .with_min_len(64)
        .map_init(
            || Window::new(params.half_window_px, model, lanes),
            |window, (p, m)| window.refine(a, b, *p, *m, params),
        )
        .collect())
}

/// Scratch space for one window, reused from match to match.
// `lanes`, `du` and `dv` serve the eight-lane sampling, which only x86-64 builds have.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
struct Window {
    model: WarpModel,
    lanes: bool, // sample eight pixels at a time (`avx2`; the caller checked the CPU)
    side: usize, // window side, px
    offsets: Vec<[f32; 2]>, // (du, dv) of each window pixel, row-major
    du: Vec<f32>, // the offsets' du, for the eight-lane sampling
    dv: Vec<f32>, // and their dv
    rows: Vec<(usize, f32)>, // each window row's row pair (`GrayImage::row_of`), row-shear sampling
    patch: Vec<f32>, // the first image around the point, (side + 2)² (the window and a border)
    template: Vec<f32>, // the first image's window, mean removed
    descent: Vec<[f32; 6]>, // steepest-descent images (gradient · ∂warp/∂p), per pixel
    warped: Vec<f32>, // the second image's window under the current warp
}

impl Window {
    fn new(half: usize, model: WarpModel, lanes: bool) -> Self {
        let h = half as i32;
        let offsets: Vec<[f32; 2]> = (-h..=h)
            .flat_map(|dv| (-h..=h).map(move |du| [du as f32, dv as f32]))
            .collect();
        let n = offsets.len();
        let side = 2 * half + 1;
        Self {
            model,
            lanes,
            side,
            du: offsets.iter().map(|o| o[0]).collect(),
            dv: offsets.iter().map(|o| o[1]).collect(),
            rows: Vec::with_capacity(side),
            offsets,
            patch: vec![0.0; (side + 2) * (side + 2)],
            template: vec![0.0; n],
            warped: vec![0.0; n],
            descent: vec![[0.0; 6]; n],
        }
    }

    /// One match refined, or None (module doc).
    #[allow(unsafe_code)] // the AVX2 build, on a CPU that `refine_matches` checked has AVX2
    fn refine(
        &mut self,
        a: &GrayImage<'_>,
        b: &GrayImage<'_>,
        point_a: [f64; 2],
        start_b: [f64; 2],
        params: &RefineParams,
    ) -> Option<[f64; 2]> {
        // The row-shear warp's steepest-descent images are zero beyond its three parameters: the sums
        // skip them (the same numbers, less work: docs/vo.md, "Speed").
        #[cfg(target_arch = "x86_64")]
        if self.lanes {
            // SAFETY: AVX2 checked by `refine_matches` (`lanes`).
            return unsafe { self.refine_avx2(a, b, point_a, start_b, params) };
        }
        self.refine_model(a, b, point_a, start_b, params)
    }

    #[inline(always)] // into `refine_avx2` too, so that it is compiled for AVX2 there
    fn refine_model(
        &mut self,
        a: &GrayImage<'_>,
        b: &GrayImage<'_>,
        point_a: [f64; 2],
        start_b: [f64; 2],
        params: &RefineParams,
    ) -> Option<[f64; 2]> {
        match self.model {
            WarpModel::Affine => self.refine_with::<6>(a, b, point_a, start_b, params),
            WarpModel::RowShear => self.refine_with::<3>(a, b, point_a, start_b, params),
        }
    }

    /// [`Window::refine`] compiled for AVX2 (the template's sums in wider registers: 0.94× the affine
    /// refinement's time, `benches/tracks.rs`). Not FMA: a fused multiply–add rounds once where the plain
    /// build rounds twice, and the results must not depend on the CPU.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    unsafe fn refine_avx2(
        &mut self,
        a: &GrayImage<'_>,
        b: &GrayImage<'_>,
        point_a: [f64; 2],
        start_b: [f64; 2],
        params: &RefineParams,
    ) -> Option<[f64; 2]> {
        self.refine_model(a, b, point_a, start_b, params)
    }

    /// The second image under the warp (centre `c`, linear part `l`) at every window pixel, into `warped`.
    /// The warped window lies inside the image (the caller checked its corners).
    #[allow(unsafe_code)] // the eight-lane build, on a CPU that `refine_matches` checked has AVX2
    fn sample(&mut self, b: &GrayImage<'_>, c: [f32; 2], l: [f32; 4]) {
        let [cx, cy] = c;
        if self.model == WarpModel::RowShear {
            // The row-shear warp keeps rows (its l[2] is ±0 and l[3] exactly 1 by construction), so each
            // window row samples one image row pair: its row and weight once per row (the same numbers).
            self.rows.clear();
            for offsets in self.offsets.chunks_exact(self.side) {
                let [du0, dv] = offsets[0];
                self.rows.push(b.row_of(cy + l[2] * du0 + l[3] * dv));
            }
            #[cfg(target_arch = "x86_64")]
            if self.lanes {
                // SAFETY: AVX2 was checked by `refine_matches`; du, dv and warped hold `side` samples a
                // row, and every row start comes from `row_of` (r ≤ height − 2).
                unsafe {
                    avx2::sample_rows(
                        b,
                        [cx, l[0], l[1]],
                        &self.rows,
                        self.side,
                        &self.du,
                        &self.dv,
                        &mut self.warped,
                    )
                };
                return;
            }
            for ((samples, offsets), row) in self
                .warped
                .chunks_exact_mut(self.side)
                .zip(self.offsets.chunks_exact(self.side))
                .zip(self.rows.iter().copied())
            {
                let line = b.pair_at(row);
                for (w, &[du, dv]) in samples.iter_mut().zip(offsets) {
                    *w = line.sample(cx + l[0] * du + l[1] * dv);
                }
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.lanes {
            // SAFETY: AVX2 was checked by `refine_matches`; du, dv and warped have one entry a pixel.
            unsafe { avx2::sample_affine(b, c, l, &self.du, &self.dv, &mut self.warped) };
            return;
        }
        for (w, &[du, dv]) in self.warped.iter_mut().zip(&self.offsets) {
            *w = b.sample_inside(cx + l[0] * du + l[1] * dv, cy + l[2] * du + l[3] * dv);
        }
    }

    /// [`Window::refine`] for a warp of `K` parameters (the steepest-descent entries from `K` on are 0).
    #[inline(always)] // into `refine_avx2` too, so that it is compiled for AVX2 there
    fn refine_with<const K: usize>(
        &mut self,
        a: &GrayImage<'_>,
        b: &GrayImage<'_>,
        point_a: [f64; 2],
        start_b: [f64; 2],
        params: &RefineParams,
    ) -> Option<[f64; 2]> {
        if !(point_a.iter().chain(&start_b).all(|v| v.is_finite())) {
            return None;
        }
        // A rectified stereo match lies on its point's row, whatever row error KLT left.
        let start_b = match self.model {
            WarpModel::Affine => start_b,
            WarpModel::RowShear => [start_b[0], point_a[1]],
        };
        let (px, py) = (point_a[0] as f32, point_a[1] as f32);
        // The template, its gradient (central differences of bilinear samples) and the Gauss–Newton matrix.
        let mut sum = 0.0f32;
        // The first image around the point, one pixel wider than the window on every side (for gradients).
        // Every sample shares the point's sub-pixel offset, so the bilinear weights are computed once.
        let side = self.side + 2;
        a.window(px, py, self.side / 2 + 1, &mut self.patch)?;
        let mut sd_mean = [0.0f32; 6];
        for (i, &[du, dv]) in self.offsets.iter().enumerate() {
            let j = (i / self.side + 1) * side + i % self.side + 1;
            let t = self.patch[j];
            let gx = 0.5 * (self.patch[j + 1] - self.patch[j - 1]);
            let gy = 0.5 * (self.patch[j + side] - self.patch[j - side]);
            let sd = match self.model {
                WarpModel::Affine => [gx, gy, gx * du, gx * dv, gy * du, gy * dv],
                WarpModel::RowShear => [gx, gx * du, gx * dv, 0.0, 0.0, 0.0],
            };
            for r in 0..K {
                sd_mean[r] += sd[r];
            }
            self.template[i] = t;
            self.descent[i] = sd;
            sum += t;
        }
        let count = self.offsets.len() as f32;
        let mean = sum / count;
        self.template.iter_mut().for_each(|t| *t -= mean);
        // The windows are compared with their means removed (an unknown brightness offset, eliminated):
        // the steepest-descent images lose their means too, or every step falls short.
        sd_mean.iter_mut().for_each(|m| *m /= count);
        let mut hessian = [[0.0f32; 6]; 6];
        for sd in &mut self.descent {
            for r in 0..K {
                sd[r] -= sd_mean[r];
            }
            // The upper triangle only (the matrix is symmetric; the lower is mirrored below).
            for (r, row) in hessian.iter_mut().enumerate().take(K) {
                let s = sd[r];
                for c in r..K {
                    row[c] += s * sd[c];
                }
            }
        }
        let mut matrix = Matrix6::<f64>::from_fn(|r, c| f64::from(hessian[r.min(c)][r.max(c)]));
        for r in K..6 {
            matrix[(r, r)] = 1.0; // parameters the model does not have
        }
        let inverse = Cholesky::new(matrix)?.inverse();
        // The warp maps window offsets x to b: centre c, linear part L (2×2, row-major).
        let mut centre = start_b;
        let mut linear = [1.0f64, 0.0, 0.0, 1.0];
        for _ in 0..params.max_iterations {
            let (cx, cy) = (centre[0] as f32, centre[1] as f32);
            let l = linear.map(|v| v as f32);
            // The warped window is a parallelogram: inside the image when its corners are.
            let h = (self.side / 2) as f32;
            let inside = [(-h, -h), (h, -h), (-h, h), (h, h)]
                .iter()
                .all(|&(du, dv)| {
                    let (x, y) = (cx + l[0] * du + l[1] * dv, cy + l[2] * du + l[3] * dv);
                    x >= 0.0 && y >= 0.0 && x < (b.width - 1) as f32 && y < (b.height - 1) as f32
                });
            if !inside {
                return None;
            }
            self.sample(b, [cx, cy], l);
            // In pixel order, as one loop summing while it sampled did (the same mean bit for bit).
            let sum = self.warped.iter().fold(0.0f32, |sum, &w| sum + w);
            let mean = sum / count;
            let mut gradient = [0.0f32; 6];
            for ((w, t), sd) in self.warped.iter().zip(&self.template).zip(&self.descent) {
                let e = w - mean - t;
                for r in 0..K {
                    gradient[r] += sd[r] * e;
                }
            }
            let gradient = gradient.map(f64::from);
            let delta = inverse * Vector6::from(gradient);
            // The increment as a warp of the template's offsets: (ΔL, Δc).
            let (d_linear, d_centre) = match self.model {
                WarpModel::Affine => (
                    [1.0 + delta[2], delta[3], delta[4], 1.0 + delta[5]],
                    [delta[0], delta[1]],
                ),
                WarpModel::RowShear => ([1.0 + delta[1], delta[2], 0.0, 1.0], [delta[0], 0.0]),
            };
            // Inverse compositional update: W ← W ∘ ΔW⁻¹.
            let det = d_linear[0] * d_linear[3] - d_linear[1] * d_linear[2];
            if det.abs() < 1e-6 {
                return None;
            }
            let inv = [
                d_linear[3] / det,
                -d_linear[1] / det,
                -d_linear[2] / det,
                d_linear[0] / det,
            ];
            let inv_c = [
                -(inv[0] * d_centre[0] + inv[1] * d_centre[1]),
                -(inv[2] * d_centre[0] + inv[3] * d_centre[1]),
            ];
            let moved = [
                linear[0] * inv_c[0] + linear[1] * inv_c[1],
                linear[2] * inv_c[0] + linear[3] * inv_c[1],
            ];
            centre = [centre[0] + moved[0], centre[1] + moved[1]];
            linear = [
                linear[0] * inv[0] + linear[1] * inv[2],
                linear[0] * inv[1] + linear[1] * inv[3],
                linear[2] * inv[0] + linear[3] * inv[2],
                linear[2] * inv[1] + linear[3] * inv[3],
            ];
            let identity = [1.0, 0.0, 0.0, 1.0];
            if linear
                .iter()
                .zip(identity)
                .any(|(l, i)| !l.is_finite() || (l - i).abs() > params.max_deformation)
            {
                return None;
            }
            if moved[0].hypot(moved[1]) < params.converged_px {
                break;
            }
        }
        let shift = (centre[0] - start_b[0]).hypot(centre[1] - start_b[1]);
        (centre.iter().all(|v| v.is_finite()) && shift <= params.max_shift_px).then_some(centre)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth texture: a sum of plane waves (wavelengths of 20 px and more, where bilinear interpolation
    /// is accurate), sampled exactly at any position.
    fn texture(x: f64, y: f64) -> f64 {
        let waves = [
            (0.16, 0.09, 0.3, 25.0),
            (-0.12, 0.21, 1.1, 20.0),
            (0.26, -0.15, 2.0, 15.0),
            (0.06, 0.04, 0.7, 18.0),
            (-0.23, -0.06, 1.7, 12.0),
        ];
        128.0
            + waves
                .iter()
                .map(|&(kx, ky, phase, amp)| amp * (kx * x + ky * y + phase).sin())
                .sum::<f64>()
    }

    /// An image whose pixel (u, v) shows the texture at `warp(u, v)`.
    fn render(width: usize, height: usize, warp: impl Fn(f64, f64) -> (f64, f64)) -> Vec<u8> {
        let mut out = Vec::with_capacity(width * height);
        for v in 0..height {
            for u in 0..width {
                let (x, y) = warp(u as f64, v as f64);
                out.push(texture(x, y).round().clamp(0.0, 255.0) as u8);
            }
        }
        out
    }

    #[test]
    fn a_sheared_stereo_match_is_found_at_its_centre() {
        // The right image shows the left one shifted by a disparity that grows by 0.3 px per row (a road
        // seen by a rectified pair): d(v) = 10 + 0.3 (v - 40). A translation fit is off by the weighting;
        // the row-shear warp recovers the centre's disparity.
        let (w, h) = (120, 80);
        let left = render(w, h, |u, v| (u, v));
        let right = render(w, h, |u, v| (u + 10.0 + 0.3 * (v - 40.0), v));
        let (l, r) = (
            GrayImage::new(&left, w, h).unwrap(),
            GrayImage::new(&right, w, h).unwrap(),
        );
        let params = RefineParams::default();
        let points: Vec<[f64; 2]> = (0..5)
            .map(|i| [40.0 + 8.0 * i as f64, 30.0 + 4.0 * i as f64])
            .collect();
        let truth: Vec<f64> = points
            .iter()
            .map(|p| p[0] - (10.0 + 0.3 * (p[1] - 40.0)))
            .collect();
        // Started 0.4 px off, as a biased KLT answer would be.
        let starts: Vec<[f64; 2]> = points
            .iter()
            .zip(&truth)
            .map(|(p, t)| [t + 0.4, p[1]])
            .collect();
        let refined =
            refine_matches(&l, &r, &points, &starts, WarpModel::RowShear, &params).unwrap();
        for ((m, t), p) in refined.iter().zip(&truth).zip(&points) {
            let m = m.expect("refined");
            assert!((m[0] - t).abs() < 0.03, "column {} against {t}", m[0]);
            assert_eq!(m[1], p[1], "a stereo match keeps its row");
        }
    }

    #[test]
    fn an_affine_track_is_found_under_expansion_and_exposure_change() {
        // The second image is the first scaled by 1.08 about (60, 20) and 12 gray levels brighter: a point
        // below the centre of expansion moves down and out, and its window stretches.
        let (w, h) = (120, 80);
        let first = render(w, h, |u, v| (u, v));
        let scale = 1.08;
        let second: Vec<u8> = render(w, h, |u, v| {
            (60.0 + (u - 60.0) / scale, 20.0 + (v - 20.0) / scale)
        })
        .into_iter()
        .map(|g| g.saturating_add(12))
        .collect();
        let (a, b) = (
            GrayImage::new(&first, w, h).unwrap(),
            GrayImage::new(&second, w, h).unwrap(),
        );
        let points = [[50.0, 50.0], [75.0, 45.0], [62.0, 60.0]];
        let truth: Vec<[f64; 2]> = points
            .iter()
            .map(|p| [60.0 + (p[0] - 60.0) * scale, 20.0 + (p[1] - 20.0) * scale])
            .collect();
        let starts: Vec<[f64; 2]> = truth.iter().map(|t| [t[0] - 0.3, t[1] - 0.35]).collect();
        let refined = refine_matches(
            &a,
            &b,
            &points,
            &starts,
            WarpModel::Affine,
            &RefineParams::default(),
        )
        .unwrap();
        for (m, t) in refined.iter().zip(&truth) {
            let m = m.expect("refined");
            assert!(
                (m[0] - t[0]).hypot(m[1] - t[1]) < 0.05,
                "{m:?} against {t:?}"
            );
        }
    }

    #[test]
    fn a_window_without_texture_or_off_the_image_keeps_klt_s_match() {
        let (w, h) = (60, 40);
        let flat = vec![100u8; w * h];
        let textured = render(w, h, |u, v| (u, v));
        let (f, t) = (
            GrayImage::new(&flat, w, h).unwrap(),
            GrayImage::new(&textured, w, h).unwrap(),
        );
        let params = RefineParams::default();
        let one = |image: &GrayImage<'_>, point: [f64; 2], start: [f64; 2]| {
            refine_matches(image, image, &[point], &[start], WarpModel::Affine, &params).unwrap()
        };
        assert_eq!(
            one(&f, [30.0, 20.0], [30.0, 20.0]),
            vec![None],
            "a flat window cannot be refined"
        );
        assert_eq!(
            one(&t, [2.0, 20.0], [2.0, 20.0]),
            vec![None],
            "a window that leaves the image"
        );
        assert_eq!(one(&t, [f64::NAN, 20.0], [30.0, 20.0]), vec![None]);
        assert!(refine_matches(&t, &t, &[[30.0, 20.0]], &[], WarpModel::Affine, &params).is_err());
        assert!(GrayImage::new(&flat, w + 1, h).is_err());
    }

    #[test]
    fn a_row_pair_samples_exactly_as_the_image_does() {
        // The row-shear loop samples through `RowPair`; it must give the generic sample bit for bit, or the
        // refinement's results would depend on which loop ran.
        let (w, h) = (50, 30);
        let textured = render(w, h, |u, v| (1.3 * u + 0.2 * v, v));
        let image = GrayImage::new(&textured, w, h).unwrap();
        for k in 0..2000 {
            let x = (k as f32 * 0.6180339).fract() * (w - 1) as f32;
            let y = (k as f32 * 0.4142135).fract() * (h - 1) as f32;
            let generic = image.sample_inside(x, y);
            let by_row = image.row_pair(y).sample(x);
            assert_eq!(generic.to_bits(), by_row.to_bits(), "at ({x}, {y})");
        }
        // The last column and row a sample may touch.
        let (x, y) = ((w - 1) as f32 - 1e-3, (h - 1) as f32 - 1e-3);
        assert_eq!(
            image.sample_inside(x, y).to_bits(),
            image.row_pair(y).sample(x).to_bits()
        );
    }

    #[test]
    fn eight_lane_sampling_refines_every_match_as_one_pixel_at_a_time() {
        // Both builds over many matches, windows of several sides, both warps, starts up to a pixel off, at
        // the image's edges too (where a window leaves it): the same refined positions bit for bit, and the
        // same failures. On a CPU without AVX2 both run the one-pixel loop.
        let (w, h) = (97, 61);
        let first = render(w, h, |u, v| (u, v));
        let second = render(w, h, |u, v| (3.0 + u / 1.05 + 0.02 * v, -1.0 + v / 1.04));
        let (a, b) = (
            GrayImage::new(&first, w, h).unwrap(),
            GrayImage::new(&second, w, h).unwrap(),
        );
        let points: Vec<[f64; 2]> = (0..600)
            .map(|k| {
                let k = k as f64;
                [
                    (k * 0.618_034).fract() * (w - 1) as f64,
                    (k * 0.414_214).fract() * (h - 1) as f64,
                ]
            })
            .collect();
        let starts: Vec<[f64; 2]> = points
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let off = (
                    (k as f64 * 0.7548).fract() - 0.5,
                    (k as f64 * 0.5698).fract() - 0.5,
                );
                [
                    (p[0] - 3.0) * 1.05 - 0.02 * p[1] + off.0,
                    (p[1] + 1.0) * 1.04 + off.1,
                ]
            })
            .collect();
        let mut refined = 0;
        for half in [3, 6, 7, 9] {
            let params = RefineParams {
                half_window_px: half,
                ..RefineParams::default()
            };
            for model in [WarpModel::Affine, WarpModel::RowShear] {
                let lanes = refine_matches(&a, &b, &points, &starts, model, &params).unwrap();
                let one_by_one = RefineParams {
                    sampling: Sampling::OneByOne,
                    ..params
                };
                let one = refine_matches(&a, &b, &points, &starts, model, &one_by_one).unwrap();
                let bits = |m: &Option<[f64; 2]>| m.map(|m| m.map(f64::to_bits));
                for (k, (x, y)) in lanes.iter().zip(&one).enumerate() {
                    assert_eq!(bits(x), bits(y), "match {k}, half {half}, {model:?}");
                }
                refined += lanes.iter().flatten().count();
            }
        }
        assert!(
            refined > 1000,
            "the comparison must cover refined matches: {refined}"
        );
    }
}
