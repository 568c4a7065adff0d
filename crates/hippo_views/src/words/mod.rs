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
