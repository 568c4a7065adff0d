//! The store of word view cells and its inverted index.

use super::vocabulary::{pair_score, BowVector, Vocabulary};
use super::{Descriptor, WordId};
use crate::error::ViewError;

/// What a word view cell keeps of the view that made it: its bag of words, and its features (pixel
/// positions and descriptors) for the geometric check of a later match.
#[derive(Debug, Clone, PartialEq)]
pub struct WordCell {
    /// The view's tf-idf bag of words.
    pub bag: BowVector,
    /// Pixel positions (x, y) of the view's features, in the image the descriptors were taken from.
    pub keypoints_px: Vec<[f32; 2]>,
    /// The features' descriptors, one per keypoint.
    pub descriptors: Vec<Descriptor>,
}

/// Word view cells: bags of words with an inverted index (word → the cells holding it, with their
/// weights), so a query's similarity to every cell is accumulated over its own words only.
#[derive(Debug, Clone)]
pub struct WordCells {
    vocabulary: Vocabulary,
    cells: Vec<WordCell>,
    inverted: Vec<Vec<(u32, f32)>>,
}

impl WordCells {
    /// An empty store whose views are quantised by `vocabulary`.
    pub fn new(vocabulary: Vocabulary) -> Self {
        let inverted = vec![Vec::new(); vocabulary.len()];
        Self {
            vocabulary,
            cells: Vec::new(),
            inverted,
        }
    }

    /// The vocabulary views are quantised by.
    pub fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }

    /// Number of stored cells.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether no cell is stored.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Cell `id`.
    pub fn cell(&self, id: usize) -> Result<&WordCell, ViewError> {
        self.cells.get(id).ok_or(ViewError::UnknownCell {
            id,
            count: self.cells.len(),
        })
    }

    /// Store a view as a new cell and return its id. Keypoints must be finite, one per descriptor.
    pub fn add(
        &mut self,
        keypoints_px: Vec<[f32; 2]>,
        descriptors: Vec<Descriptor>,
    ) -> Result<usize, ViewError> {
        let bag = self.bag(&keypoints_px, &descriptors)?;
        self.add_with_bag(keypoints_px, descriptors, bag)
    }

    /// The bag of words of a view (checking its features like `add`).
    pub fn bag(
        &self,
        keypoints_px: &[[f32; 2]],
        descriptors: &[Descriptor],
    ) -> Result<BowVector, ViewError> {
        check_features(keypoints_px, descriptors)?;
        Ok(self.vocabulary.bag(descriptors))
    }

    /// `add` with the bag already computed by `bag` (a query that turned out novel).
    pub fn add_with_bag(
        &mut self,
        keypoints_px: Vec<[f32; 2]>,
        descriptors: Vec<Descriptor>,
        bag: BowVector,
    ) -> Result<usize, ViewError> {
        check_features(&keypoints_px, &descriptors)?;
        if let Some(&(w, _)) = bag
            .entries
            .iter()
            .find(|e| e.0 as usize >= self.inverted.len())
        {
            return Err(ViewError::BadParameter {
                name: "bag",
                value: w.to_string(),
                why: format!(
                    "word outside this vocabulary of {} words",
                    self.inverted.len()
                ),
            });
        }
        let id = self.cells.len();
        let id32 = u32::try_from(id).map_err(|_| ViewError::BadParameter {
            name: "cells",
            value: id.to_string(),
            why: "more than 2³² word view cells".into(),
        })?;
        for &(w, weight) in &bag.entries {
            self.inverted[w as usize].push((id32, weight));
        }
        self.cells.push(WordCell {
            bag,
            keypoints_px,
            descriptors,
        });
        Ok(id)
    }

    /// The `top_k` cells most similar to `bag` (DBoW2's L1 score, > 0), best first, ties to the lower
    /// id; among `candidates` only when given (ids of stored cells; duplicates are fine).
    pub fn query(
        &self,
        bag: &BowVector,
        candidates: Option<&[usize]>,
        top_k: usize,
    ) -> Result<Vec<(usize, f32)>, ViewError> {
        let n = self.cells.len();
        let mut allowed: Option<Vec<bool>> = None;
        if let Some(ids) = candidates {
            let mut mask = vec![false; n];
            for (position, &id) in ids.iter().enumerate() {
                if id >= n {
                    return Err(ViewError::UnknownCandidate {
                        id,
                        position,
                        count: n,
                    });
                }
                mask[id] = true;
            }
            allowed = Some(mask);
        }
        let mut score = vec![0.0f32; n];
        for &(w, v) in &bag.entries {
            let Some(postings) = self.inverted.get(w as usize) else {
                continue;
            };
            for &(cell, weight) in postings {
                score[cell as usize] += pair_score(v, weight);
            }
        }
        let mut ranked: Vec<(usize, f32)> = score
            .into_iter()
            .enumerate()
            .filter(|&(id, s)| s > 0.0 && allowed.as_ref().is_none_or(|m| m[id]))
            .collect();
        ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        ranked.truncate(top_k);
        Ok(ranked)
    }

    /// Words of every cell's features are not kept; this recomputes a cell's word list (e.g. to show it).
    pub fn words_of(&self, id: usize) -> Result<Vec<WordId>, ViewError> {
        Ok(self.vocabulary.words(&self.cell(id)?.descriptors))
    }
}

fn check_features(keypoints_px: &[[f32; 2]], descriptors: &[Descriptor]) -> Result<(), ViewError> {
    if keypoints_px.len() != descriptors.len() {
        return Err(ViewError::BadParameter {
            name: "keypoints_px",
            value: keypoints_px.len().to_string(),
            why: format!(
                "need one keypoint per descriptor ({} descriptors)",
                descriptors.len()
            ),
        });
    }
    if let Some(i) = keypoints_px
        .iter()
        .position(|k| !(k[0].is_finite() && k[1].is_finite()))
    {
        return Err(ViewError::BadParameter {
            name: "keypoints_px",
            value: format!("{:?}", keypoints_px[i]),
            why: format!("keypoint {i} is not finite"),
        });
    }
    Ok(())
}
