//! A hierarchical vocabulary of binary words (DBoW2-style) and tf-idf bag-of-words vectors.
//!
//! Training (`Vocabulary::train`) clusters 256-bit descriptors recursively: every node splits its
//! descriptors into at most `branching` clusters by k-majority (k-means in Hamming space: a centroid
//! bit is set when more than half of its members have it), seeded by k-means++ (the next seed drawn
//! with probability ∝ d², d its Hamming distance to the nearest seed so far). A node becomes a leaf —
//! a *word* — at depth `levels` or when it holds no more than `branching` distinct descriptors. The
//! random draws come from a ChaCha8 stream seeded per node from `seed`, so a vocabulary depends only on
//! its inputs (never on the thread count: assignments are per descriptor, sums are integer counts).
//!
//! A descriptor's word is the leaf reached by descending to the nearest child (ties to the first).
//! Each word has an inverse document frequency `idf = ln(N / nᵢ)` over the N training images, nᵢ of
//! which contain it: words found everywhere (texture of asphalt, sky edges) weigh nothing.
//! An image's bag of words is its tf-idf vector `vᵢ = (countᵢ / n) · idfᵢ`, normalised to unit L1 norm
//! (stored sparse, sorted by word).

use super::{hamming, Descriptor, WordId};
use crate::error::ViewError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Assignment passes of k-majority per node at most (it converges in a handful on real descriptors).
const MAX_KMAJORITY_ITERATIONS: usize = 10;

/// A sparse, L1-normalised tf-idf vector: (word, weight) sorted by word, weights > 0 summing to 1
/// (empty when no descriptor carried weight).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BowVector {
    /// (word, weight), sorted by word.
    pub entries: Vec<(WordId, f32)>,
}

impl BowVector {
    /// Whether no word carries weight.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// DBoW2's L1 similarity of two L1-normalised vectors, `1 − ½‖v − w‖₁` ∈ [0, 1] (1 identical, 0
    /// disjoint words), summed over the common words only: `½ Σ (|vᵢ| + |wᵢ| − |vᵢ − wᵢ|)`.
    pub fn score(&self, other: &BowVector) -> f32 {
        let (mut i, mut j, mut sum) = (0, 0, 0.0f32);
        let (a, b) = (&self.entries, &other.entries);
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    sum += pair_score(a[i].1, b[j].1);
                    i += 1;
                    j += 1;
                }
            }
        }
        sum
    }
}

/// One word's contribution to the L1 similarity.
#[inline]
pub(crate) fn pair_score(v: f32, w: f32) -> f32 {
    0.5 * (v + w - (v - w).abs())
}

/// A node of the vocabulary tree. The root (index 0) has no centroid of its own.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Node {
    pub(crate) centroid: Descriptor,
    /// Children occupy `nodes[first_child .. first_child + n_children]`; none for a word.
    pub(crate) first_child: u32,
    pub(crate) n_children: u32,
    /// The word of a leaf, `NO_WORD` for an inner node.
    pub(crate) word: WordId,
}

pub(crate) const NO_WORD: WordId = WordId::MAX;

/// The vocabulary: its tree and the words' inverse document frequencies.
#[derive(Debug, Clone, PartialEq)]
pub struct Vocabulary {
    pub(crate) branching: usize,
    pub(crate) levels: usize,
    pub(crate) nodes: Vec<Node>,
    pub(crate) idf: Vec<f32>,
}

/// What `Vocabulary::train` needs besides the descriptors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrainingParams {
    /// Children per node (DBoW2's k; 10 is usual).
    pub branching: usize,
    /// Depth of the tree (DBoW2's L): up to branching^levels words.
    pub levels: usize,
    /// Seed of the k-means++ draws (the same seed and data give the same vocabulary).
    pub seed: u64,
}

impl Vocabulary {
    /// Train on the descriptors of a set of images (`images[i]` = the descriptors of image i); the
    /// images define the idf weights, their union the clusters.
    pub fn train(images: &[Vec<Descriptor>], params: TrainingParams) -> Result<Self, ViewError> {
        let TrainingParams {
            branching,
            levels,
            seed,
        } = params;
        if !(2..=64).contains(&branching) {
            return Err(ViewError::BadParameter {
                name: "branching",
                value: branching.to_string(),
                why: "use 2 to 64 children per node (10 is usual)".into(),
            });
        }
        if !(1..=8).contains(&levels) {
            return Err(ViewError::BadParameter {
                name: "levels",
                value: levels.to_string(),
                why: "use 1 to 8 levels (branching^levels words; 3–5 is usual)".into(),
            });
        }
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.is_empty() {
            return Err(ViewError::NoTrainingData);
        }
        let mut nodes = vec![Node {
            centroid: [0; 32],
            first_child: 0,
            n_children: 0,
            word: NO_WORD,
        }];
        // Breadth-first: (node index, depth, member descriptors). Children of a node are contiguous.
        let mut queue = std::collections::VecDeque::from([(0usize, 0usize, all)]);
        let mut n_words: WordId = 0;
        while let Some((node, depth, members)) = queue.pop_front() {
            let distinct = count_distinct(&members, branching + 1);
            if depth == levels || distinct <= branching {
                nodes[node].word = n_words;
                n_words += 1;
                continue;
            }
            let mut rng =
                ChaCha8Rng::seed_from_u64(seed ^ (node as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let (centroids, assignment) = k_majority(&members, branching, &mut rng);
            let first = nodes.len();
            let mut groups: Vec<Vec<Descriptor>> = vec![Vec::new(); centroids.len()];
            for (d, &a) in members.iter().zip(&assignment) {
                groups[a].push(*d);
            }
            let mut n_children = 0u32;
            for (centroid, group) in centroids.into_iter().zip(groups) {
                if group.is_empty() {
                    continue; // a seed that lost every member
                }
                nodes.push(Node {
                    centroid,
                    first_child: 0,
                    n_children: 0,
                    word: NO_WORD,
                });
                queue.push_back((nodes.len() - 1, depth + 1, group));
                n_children += 1;
            }
            nodes[node].first_child = first as u32;
            nodes[node].n_children = n_children;
        }
        let mut vocabulary = Self {
            branching,
            levels,
            nodes,
            idf: vec![0.0; n_words as usize],
        };
        // idf from the images that contain each word.
        let mut containing = vec![0u32; n_words as usize];
        for image in images {
            let mut words: Vec<WordId> = image.iter().map(|d| vocabulary.word(d)).collect();
            words.sort_unstable();
            words.dedup();
            for w in words {
                containing[w as usize] += 1;
            }
        }
        let n_images = images.iter().filter(|i| !i.is_empty()).count().max(1) as f32;
        for (idf, &n) in vocabulary.idf.iter_mut().zip(&containing) {
            // A word no training image contains (possible only through dropped duplicates) gets the
            // weight of the rarest ones.
            *idf = (n_images / n.max(1) as f32).ln();
        }
        Ok(vocabulary)
    }

    /// Number of words (leaves).
    pub fn len(&self) -> usize {
        self.idf.len()
    }

    /// Whether the vocabulary has no word (never, once trained).
    pub fn is_empty(&self) -> bool {
        self.idf.is_empty()
    }

    /// Children per node.
    pub fn branching(&self) -> usize {
        self.branching
    }

    /// Depth of the tree.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Inverse document frequency of every word.
    pub fn idf(&self) -> &[f32] {
        &self.idf
    }

    /// The word of one descriptor: descend to the nearest child (ties to the first) until a leaf.
    pub fn word(&self, descriptor: &Descriptor) -> WordId {
        let mut node = &self.nodes[0];
        while node.word == NO_WORD && node.n_children > 0 {
            let first = node.first_child as usize;
            let children = &self.nodes[first..first + node.n_children as usize];
            let mut best = 0;
            let mut best_distance = u32::MAX;
            for (i, child) in children.iter().enumerate() {
                let d = hamming(descriptor, &child.centroid);
                if d < best_distance {
                    best_distance = d;
                    best = i;
                }
            }
            node = &children[best];
        }
        node.word
    }

    /// The words of many descriptors (one per descriptor, in order).
    pub fn words(&self, descriptors: &[Descriptor]) -> Vec<WordId> {
        descriptors.iter().map(|d| self.word(d)).collect()
    }

    /// The tf-idf bag of words of an image's descriptors (empty for no descriptors).
    pub fn bag(&self, descriptors: &[Descriptor]) -> BowVector {
        self.bag_of_words(&self.words(descriptors))
    }

    /// The tf-idf bag of words from words already looked up.
    pub fn bag_of_words(&self, words: &[WordId]) -> BowVector {
        let mut sorted = words.to_vec();
        sorted.sort_unstable();
        let mut entries: Vec<(WordId, f32)> = Vec::new();
        for w in sorted {
            match entries.last_mut() {
                Some((last, count)) if *last == w => *count += 1.0,
                _ => entries.push((w, 1.0)),
            }
        }
        for (w, weight) in &mut entries {
            *weight *= self.idf.get(*w as usize).copied().unwrap_or(0.0);
        }
        entries.retain(|&(_, weight)| weight > 0.0);
        let total: f32 = entries.iter().map(|e| e.1).sum();
        if total > 0.0 {
            for e in &mut entries {
                e.1 /= total;
            }
        }
        BowVector { entries }
    }
}

/// Distinct descriptors among `members`, counted up to `limit` (enough to know whether a node splits).
fn count_distinct(members: &[Descriptor], limit: usize) -> usize {
    let mut seen: Vec<&Descriptor> = Vec::with_capacity(limit);
    for d in members {
        if !seen.contains(&d) {
            seen.push(d);
            if seen.len() >= limit {
                break;
            }
        }
    }
    seen.len()
}

/// k-majority clustering of `members` into at most `k` clusters; (centroids, assignment per member).
fn k_majority(
    members: &[Descriptor],
    k: usize,
    rng: &mut ChaCha8Rng,
) -> (Vec<Descriptor>, Vec<usize>) {
    let mut centroids = kmeans_pp_seeds(members, k, rng);
    let mut assignment = assign(members, &centroids);
    for _ in 0..MAX_KMAJORITY_ITERATIONS {
        centroids = majorities(members, &assignment, &centroids);
        let next = assign(members, &centroids);
        if next == assignment {
            break;
        }
        assignment = next;
    }
    (centroids, assignment)
}

/// k-means++ seeds: the first uniformly, each next with probability ∝ d² to the nearest seed so far.
fn kmeans_pp_seeds(members: &[Descriptor], k: usize, rng: &mut ChaCha8Rng) -> Vec<Descriptor> {
    let mut seeds = vec![members[rng.random_range(0..members.len())]];
    let mut nearest: Vec<u64> = members
        .iter()
        .map(|d| u64::from(hamming(d, &seeds[0])).pow(2))
        .collect();
    while seeds.len() < k {
        let total: u64 = nearest.iter().sum();
        if total == 0 {
            break; // every member equals a seed
        }
        let mut pick = rng.random_range(0..total);
        let chosen = nearest
            .iter()
            .position(|&w| {
                if pick < w {
                    true
                } else {
                    pick -= w;
                    false
                }
            })
            .unwrap_or(members.len() - 1);
        let seed = members[chosen];
        seeds.push(seed);
        for (n, d) in nearest.iter_mut().zip(members) {
            *n = (*n).min(u64::from(hamming(d, &seed)).pow(2));
        }
    }
    seeds
}

/// Index of the nearest centroid of every member (ties to the first).
fn assign(members: &[Descriptor], centroids: &[Descriptor]) -> Vec<usize> {
    let nearest = |d: &Descriptor| {
        let mut best = (u32::MAX, 0);
        for (j, c) in centroids.iter().enumerate() {
            let h = hamming(d, c);
            if h < best.0 {
                best = (h, j);
            }
        }
        best.1
    };
    if members.len() >= 4096 {
        members.par_iter().map(nearest).collect()
    } else {
        members.iter().map(nearest).collect()
    }
}

/// Bitwise majority of each cluster (a bit is set when more than half of the members have it); a
/// cluster with no members keeps its centroid.
fn majorities(
    members: &[Descriptor],
    assignment: &[usize],
    previous: &[Descriptor],
) -> Vec<Descriptor> {
    let k = previous.len();
    let mut counts = vec![[0u32; 256]; k];
    let mut sizes = vec![0u32; k];
    for (d, &a) in members.iter().zip(assignment) {
        sizes[a] += 1;
        let c = &mut counts[a];
        for (byte, bits) in d.iter().enumerate() {
            for bit in 0..8 {
                c[byte * 8 + bit] += u32::from((bits >> (7 - bit)) & 1);
            }
        }
    }
    (0..k)
        .map(|j| {
            if sizes[j] == 0 {
                return previous[j];
            }
            let mut centroid = [0u8; 32];
            for (byte, out) in centroid.iter_mut().enumerate() {
                for bit in 0..8 {
                    if 2 * counts[j][byte * 8 + bit] > sizes[j] {
                        *out |= 1 << (7 - bit);
                    }
                }
            }
            centroid
        })
        .collect()
}
