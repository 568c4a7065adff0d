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
/// On x86-64 CPUs with AVX-512's 64-bit popcount (`avx512vpopcntdq`) eight stored descriptors are compared
/// with a query at once ([`ratio_matches_avx512`]); on those with AVX2 and POPCNT the plain loop runs compiled
/// for them. The distances are integers and the nearest and second nearest are the same either way, so the
/// matches are identical (the tests compare every build with a sorted reference).
#[allow(unsafe_code)] // calling the AVX-512 build after the CPU check, as `compare::numerator` does
pub fn ratio_test_matches(
    query: &[Descriptor],
    stored: &[Descriptor],
    ratio: f64,
) -> Vec<(u32, u32)> {
    #[cfg(target_arch = "x86_64")]
    if stored.len() >= 2
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vpopcntdq")
    {
        let (query, stored) = (as_words(query), as_words(stored));
        // SAFETY: the CPU supports AVX-512F and VPOPCNTDQ (checked just above), the only requirement.
        return unsafe { ratio_matches_avx512(&query, &stored, ratio) };
    }
    ratio_test_matches_one_by_one(query, stored, ratio)
}

/// [`ratio_test_matches`] one stored descriptor at a time (the popcount loop, AVX2-compiled where the CPU has
/// it): the same matches; the baseline `benches/views.rs` measures the eight-lane build against.
#[allow(unsafe_code)] // calling the AVX2 build after the CPU check
pub fn ratio_test_matches_one_by_one(
    query: &[Descriptor],
    stored: &[Descriptor],
    ratio: f64,
) -> Vec<(u32, u32)> {
    if stored.len() < 2 {
        return Vec::new();
    }
    let (query, stored) = (as_words(query), as_words(stored));
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt")
    {
        // SAFETY: the CPU supports AVX2 and POPCNT (checked just above), the only requirement.
        return unsafe { ratio_matches_avx2(&query, &stored, ratio) };
    }
    ratio_matches_portable(&query, &stored, ratio)
}

/// Descriptors as four 64-bit words each.
fn as_words(descriptors: &[Descriptor]) -> Vec<[u64; 4]> {
    descriptors.iter().map(words_of).collect()
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

/// The ratio test of `ratio_matches_portable`, eight stored descriptors at a time.
///
/// The stored descriptors are laid out word by word (each 512-bit register holds one 64-bit word of eight
/// descriptors), so a query's distances to eight of them are four XORs, four popcounts and three adds. Each
/// of the eight lanes keeps the nearest and second nearest of its own share (every eighth descriptor), the
/// nearest's index the first that reached it; the lanes are then merged. The last block's empty lanes (`len`
/// not a multiple of 8) are held at a distance no descriptor has. That is the same nearest distance, the same first index reaching it and the same
/// second nearest as one pass in order: the matches are identical to the portable loop's. 500 × 500
/// descriptors take about a quarter of the one-by-one loop's time (`benches/views.rs`,
/// `word_ratio_matches_500x500` against `…_one_by_one`).
///
/// # Safety
/// The CPU must support AVX-512F and AVX-512 VPOPCNTDQ.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vpopcntdq")]
#[allow(unsafe_code)]
unsafe fn ratio_matches_avx512(
    query: &[[u64; 4]],
    stored: &[[u64; 4]],
    ratio: f64,
) -> Vec<(u32, u32)> {
    use std::arch::x86_64::{
        __m512i, _mm512_add_epi64, _mm512_cmplt_epu64_mask, _mm512_loadu_si512,
        _mm512_mask_mov_epi64, _mm512_min_epu64, _mm512_popcnt_epi64, _mm512_set1_epi64,
        _mm512_setr_epi64, _mm512_storeu_si512, _mm512_xor_si512,
    };
    const LANES: usize = 8;
    let blocks = stored.len().div_ceil(LANES);
    // Word `w` of the stored descriptors `8b .. 8b + 8` at `columns[4b + w]` (0 where a lane is empty), and
    // each block's lanes that hold a descriptor.
    let mut columns: Vec<[u64; LANES]> = Vec::with_capacity(blocks * 4);
    let mut filled: Vec<u8> = Vec::with_capacity(blocks);
    for block in stored.chunks(LANES) {
        columns.extend((0..4).map(|word| {
            std::array::from_fn(|lane| block.get(lane).map_or(0, |descriptor| descriptor[word]))
        }));
        filled.push((0xFFu16 >> (LANES - block.len())) as u8);
    }
    let load = |column: &[u64; LANES]| -> __m512i {
        // SAFETY: `column` is 64 readable bytes; the load is unaligned.
        unsafe { _mm512_loadu_si512(column.as_ptr().cast()) }
    };
    let store = |v: __m512i| -> [u64; LANES] {
        let mut out = [0u64; LANES];
        // SAFETY: `out` is 64 writable bytes; the store is unaligned.
        unsafe { _mm512_storeu_si512(out.as_mut_ptr().cast(), v) };
        out
    };
    let mut out = Vec::new();
    for (qi, q) in query.iter().enumerate() {
        let words = q.map(|w| _mm512_set1_epi64(w as i64));
        let far = _mm512_set1_epi64(i64::MAX);
        let (mut lane_best, mut lane_second) = (far, far);
        let mut lane_index = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
        let mut index = lane_index;
        let step = _mm512_set1_epi64(LANES as i64);
        for (block, &lanes) in columns.chunks_exact(4).zip(&filled) {
            let bits = |w: usize| _mm512_popcnt_epi64(_mm512_xor_si512(words[w], load(&block[w])));
            let d = _mm512_add_epi64(
                _mm512_add_epi64(bits(0), bits(1)),
                _mm512_add_epi64(bits(2), bits(3)),
            );
            let d = _mm512_mask_mov_epi64(far, lanes, d); // an empty lane is never nearer
                                                          // As the loop in order: nearer than the nearest, the nearest becomes the second; else the
                                                          // second is the nearer of the two.
            let nearer = _mm512_cmplt_epu64_mask(d, lane_best);
            lane_second =
                _mm512_mask_mov_epi64(_mm512_min_epu64(lane_second, d), nearer, lane_best);
            lane_best = _mm512_mask_mov_epi64(lane_best, nearer, d);
            lane_index = _mm512_mask_mov_epi64(lane_index, nearer, index);
            index = _mm512_add_epi64(index, step);
        }
        let (lane_best, lane_second, lane_index) =
            (store(lane_best), store(lane_second), store(lane_index));
        // The nearest: the smallest lane nearest, at the first index among the lanes that reach it.
        let mut winner = 0usize;
        for lane in 1..LANES {
            let (d, i) = (lane_best[lane], lane_index[lane]);
            if d < lane_best[winner] || (d == lane_best[winner] && i < lane_index[winner]) {
                winner = lane;
            }
        }
        // The second nearest: every lane's second and every other lane's nearest.
        let mut runner_up = u64::MAX;
        for lane in 0..LANES {
            runner_up = runner_up.min(lane_second[lane]);
            if lane != winner {
                runner_up = runner_up.min(lane_best[lane]);
            }
        }
        let best = lane_best[winner] as u32; // at most 256: the caller gives at least two descriptors
        let second = runner_up.min(u64::from(u32::MAX)) as u32;
        let best_index = lane_index[winner] as usize;
        if f64::from(best) < ratio * f64::from(second) {
            out.push((qi as u32, best_index as u32));
        }
    }
    out
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
                    *byte = if x.is_multiple_of(3) {
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
            for ratio in [0.6, 0.8, 1.0] {
                let reference = sorted_reference(&query, &stored, ratio);
                assert_eq!(ratio_test_matches(&query, &stored, ratio), reference);
                assert_eq!(
                    ratio_test_matches_one_by_one(&query, &stored, ratio),
                    reference
                );
                // The portable build too, whatever this CPU dispatches to.
                assert_eq!(
                    ratio_matches_portable(&as_words(&query), &as_words(&stored), ratio),
                    reference
                );
            }
        }
        // The eight-lane build against the same reference, at every stored count around its blocks of eight
        // (the last block part empty, or lanes empty in every block), where this CPU has it.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vpopcntdq")
        {
            for n in 2..42 {
                let (query, stored) = (descriptors(n as u64, 50), descriptors(n as u64 + 300, n));
                for ratio in [0.6, 0.8, 1.0] {
                    // SAFETY: the CPU has AVX-512F and VPOPCNTDQ (checked above).
                    #[allow(unsafe_code)]
                    let fast = unsafe {
                        ratio_matches_avx512(&as_words(&query), &as_words(&stored), ratio)
                    };
                    assert_eq!(fast, sorted_reference(&query, &stored, ratio), "{n} stored");
                }
            }
        }
        // An exact copy is its own nearest, unless another stored descriptor ties with it.
        let stored = descriptors(5, 30);
        let matches = ratio_test_matches(&stored, &stored, 0.8);
        assert!(matches.iter().all(|&(q, s)| q == s));
        assert!(ratio_test_matches(&stored, &stored[..1], 0.8).is_empty());
    }
}
