//! Word view cells: a view described by its ORB features quantised into a bag of binary words.
//!
//! The paper's view cell recognises a place by comparing whole-image templates; that works when a place
//! looks the same on every pass and fails on real revisits (another lane, another light). Here a view is
//! the set of its ORB features (256-bit descriptors, extracted by the Python side with OpenCV). Features
//! are quantised by a [`Vocabulary`] into words, a view becomes a tf-idf [`BowVector`], and
//! [`WordCells`] finds the stored views most similar to a query through an inverted index (cost set by
//! the query's words, not by the store). The Python side verifies the best few geometrically (descriptor
//! matches that fit one epipolar geometry) before calling a view familiar.
//!
//! Why not the `abow` crate: its training draws from the thread RNG (a vocabulary would differ between
//! runs), it has no idf weights and no inverted index, its bags are dense (one float per word), and its
//! Hamming distance sums into a `u8` (wraps at 256 differing bits).

mod cells;
mod persist;
mod vocabulary;

pub use cells::{WordCell, WordCells};
pub use vocabulary::{BowVector, TrainingParams, Vocabulary};

/// A 256-bit binary descriptor (ORB, BRIEF), as OpenCV writes it: 32 bytes.
pub type Descriptor = [u8; 32];

/// A word of a vocabulary.
pub type WordId = u32;

/// Bits that differ between two descriptors.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    // Byte-wise popcount over the 32 bytes: the plain form, which the compiler can vectorise.
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

/// Brute-force matches of `query` against `stored` with Lowe's ratio test: for each query descriptor its
/// nearest stored one (Hamming), kept when that distance is below `ratio` times the second nearest's.
/// Returns (query index, stored index) pairs in query order: exactly what OpenCV's `BFMatcher(NORM_HAMMING)`
/// `knnMatch(k = 2)` followed by the ratio test gives (a tie for the nearest fails the test in both, so which
/// of the tied ones is nearest never matters), without the Python object OpenCV makes for every candidate
/// match (`tests/view_cells/test_word_matching.py`; speed: `benches/views.rs`,
/// `tests/benchmarks/test_views_bench.py`). Fewer than two stored descriptors: no match (there is no second
/// nearest to test against).
///
/// On x86-64 CPUs with AVX2 and POPCNT the same code runs compiled for them (the distances are integers:
/// identical either way).
#[allow(unsafe_code)] // calling the AVX2 build after the CPU check, as `compare::numerator` does
pub fn ratio_test_matches(
    query: &[Descriptor],
    stored: &[Descriptor],
    ratio: f64,
) -> Vec<(u32, u32)> {
    if stored.len() < 2 {
        return Vec::new();
    }
    let query: Vec<[u64; 4]> = query.iter().map(words_of).collect();
    let stored: Vec<[u64; 4]> = stored.iter().map(words_of).collect();
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt")
    {
        // SAFETY: the CPU supports AVX2 and POPCNT (checked just above), the only requirement.
        return unsafe { ratio_matches_avx2(&query, &stored, ratio) };
    }
    ratio_matches_portable(&query, &stored, ratio)
}

/// A descriptor as four 64-bit words: a popcount each instead of 32.
fn words_of(d: &Descriptor) -> [u64; 4] {
    let mut w = [0u64; 4];
    for (word, bytes) in w.iter_mut().zip(d.chunks_exact(8)) {
        let mut b = [0u8; 8];
        b.copy_from_slice(bytes);
        *word = u64::from_le_bytes(b);
    }
    w
}

/// `ratio_matches_portable` compiled with AVX2 and POPCNT enabled.
///
/// # Safety
/// The CPU must support AVX2 and POPCNT.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
#[allow(unsafe_code)]
unsafe fn ratio_matches_avx2(
    query: &[[u64; 4]],
    stored: &[[u64; 4]],
    ratio: f64,
) -> Vec<(u32, u32)> {
    ratio_matches_portable(query, stored, ratio)
}

#[inline(always)]
fn ratio_matches_portable(query: &[[u64; 4]], stored: &[[u64; 4]], ratio: f64) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for (qi, q) in query.iter().enumerate() {
        let (mut best, mut second, mut best_index) = (u32::MAX, u32::MAX, 0usize);
        for (si, s) in stored.iter().enumerate() {
            let d = (q[0] ^ s[0]).count_ones()
                + (q[1] ^ s[1]).count_ones()
                + (q[2] ^ s[2]).count_ones()
                + (q[3] ^ s[3]).count_ones();
            if d < best {
                second = best;
                best = d;
                best_index = si;
            } else if d < second {
                second = d;
            }
        }
        if f64::from(best) < ratio * f64::from(second) {
            out.push((qi as u32, best_index as u32));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference: every distance, sorted (nearest first, ties by index), then the ratio test.
    fn sorted_reference(
        query: &[Descriptor],
        stored: &[Descriptor],
        ratio: f64,
    ) -> Vec<(u32, u32)> {
        let mut out = Vec::new();
        for (qi, q) in query.iter().enumerate() {
            let mut all: Vec<(u32, usize)> = stored
                .iter()
                .enumerate()
                .map(|(i, s)| (hamming(q, s), i))
                .collect();
            all.sort();
            if all.len() >= 2 && f64::from(all[0].0) < ratio * f64::from(all[1].0) {
                out.push((qi as u32, all[0].1 as u32));
            }
        }
        out
    }

    fn descriptors(seed: u64, n: usize) -> Vec<Descriptor> {
        // A small xorshift: deterministic, and descriptors of few distinct values make ties common.
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..n)
            .map(|_| {
                let mut d = [0u8; 32];
                for byte in d.iter_mut() {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    *byte = if x % 3 == 0 {
                        0xFF
                    } else {
                        (x >> 24) as u8 & 0x0F
                    };
                }
                d
            })
            .collect()
    }

    #[test]
    fn ratio_test_matches_equal_the_sorted_reference_ties_included() {
        for seed in 1..20 {
            let (query, stored) = (descriptors(seed, 60), descriptors(seed + 100, 45));
            let words = |d: &[Descriptor]| d.iter().map(words_of).collect::<Vec<_>>();
            for ratio in [0.6, 0.8, 1.0] {
                let reference = sorted_reference(&query, &stored, ratio);
                assert_eq!(ratio_test_matches(&query, &stored, ratio), reference);
                // The portable build too, whatever this CPU dispatches to.
                assert_eq!(
                    ratio_matches_portable(&words(&query), &words(&stored), ratio),
                    reference
                );
            }
        }
        // An exact copy is its own nearest, unless another stored descriptor ties with it.
        let stored = descriptors(5, 30);
        let matches = ratio_test_matches(&stored, &stored, 0.8);
        assert!(matches.iter().all(|&(q, s)| q == s));
        assert!(ratio_test_matches(&stored, &stored[..1], 0.8).is_empty());
    }
}
