//! The vector registers' state between libraries.
//!
//! Compilers end every function that used the 256- or 512-bit registers with `vzeroupper`, so that plain SSE
//! code after it runs at full speed. faer's dense products (the `gemm` crates' kernels, AVX-512 where the CPU
//! has it) return without it. Plain SSE code that runs on that thread next (most of this workspace: it is
//! built for baseline x86-64 so that one wheel runs everywhere) then runs slowly until some compiled AVX
//! function clears them: the odometry's warped-window refinement ran 2.7× slower on rayon's threads after an
//! engine step than before one, on real KITTI 06 (docs/results.md, "Cost"; `cargo bench -p hippo_vo --bench
//! tracks`, `affine_after_engine_step`). Clearing them changes no number: the instruction touches no value a
//! program can see, so no test can tell; the benchmark above measures what it is for.
#![warn(missing_docs)]

/// `vzeroupper` on the calling thread (nothing on a CPU without AVX or off x86-64): after a dense faer
/// product or factorisation that ran on it. A product spread over rayon's threads must be split so that each
/// thread clears its own (`hippo_attractor`'s `Real::gemm`).
pub fn clear_upper_halves() {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        zero_upper();
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)] // the one instruction, on a CPU that the callers checked has AVX
fn zero_upper() {
    #[target_feature(enable = "avx")]
    unsafe fn zero_upper_avx() {
        std::arch::x86_64::_mm256_zeroupper();
    }
    // SAFETY: called only after `is_x86_feature_detected!("avx")` said the CPU has AVX.
    unsafe { zero_upper_avx() }
}
