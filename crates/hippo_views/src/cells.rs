//! The store of view cells and the search for the best-matching one.
use crate::compare::{
    best_shift, coarse_exceeds, rank_key, summarise, to_column_major, to_row_major, Summary,
};
use crate::error::ViewError;
use crate::params::ViewCellParams;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Templates compared first (those with the lowest ranking keys) to get a good difference to beat.
fn seed_count(n: usize) -> usize {
    (n / 128).clamp(1, 32).min(n)
}

/// Candidate (difference, id, shift); the better of two is the lower difference, ties to the lowest id.
type Candidate = (f32, usize, isize);

fn better(a: Candidate, b: Candidate) -> Candidate {
    if b.0 < a.0 || (b.0 == a.0 && b.1 < a.1) {
        b
    } else {
        a
    }
}

/// Best stored template for a query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewMatch {
    /// The closest stored cell.
    pub cell_id: usize,
    /// Normalised difference in [0, 1] (see `compare`).
    pub difference: f32,
    /// Columns the query is shifted right relative to the stored template.
    pub shift_px: i32,
}

/// What one observation did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewStatus {
    /// The best stored template is below the novelty threshold.
    Familiar,
    /// Nothing stored is close enough: a new cell was created for this view.
    New,
    /// The template has too little texture to recognise anything (blank, blurred or dark frame).
    Uninformative,
}

/// Result of `ViewCells::observe`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewObservation {
    /// New, familiar or uninformative.
    pub status: ViewStatus,
    /// The matched or created cell; `None` when the view was uninformative.
    pub cell_id: Option<usize>,
    /// Best difference found among the cells stored before this view (1 when there were none).
    pub difference: f32,
    /// Best horizontal shift of the match (pixels).
    pub shift_px: i32,
    /// Heading of the camera now minus its heading when the cell was stored (counter-clockwise positive).
    pub relative_heading_rad: f64,
}

/// A checked query: its template column-major (as stored) and its summary.
struct Query {
    columns: Vec<f32>,
    summary: Summary,
}

/// Local view cells: one stored template per cell, in contiguous memory, ids in creation order.
#[derive(Debug, Clone)]
pub struct ViewCells {
    params: ViewCellParams,
    /// Every template column-major (see `compare`), cell after cell.
    templates: Vec<f32>,
    summaries: Vec<Summary>,
}

impl ViewCells {
    /// An empty store with these parameters (checked).
    pub fn new(params: ViewCellParams) -> Result<Self, ViewError> {
        params.validate()?;
        Ok(Self {
            params,
            templates: Vec::new(),
            summaries: Vec::new(),
        })
    }

    /// The store's parameters.
    pub fn params(&self) -> &ViewCellParams {
        &self.params
    }

    /// Number of view cells.
    pub fn len(&self) -> usize {
        self.summaries.len()
    }

    /// Whether no cell is stored.
    pub fn is_empty(&self) -> bool {
        self.summaries.is_empty()
    }

    /// Stored template of cell `id` (row-major height × width; a copy, as cells store them column-major).
    pub fn template(&self, id: usize) -> Result<Vec<f32>, ViewError> {
        if id >= self.len() {
            return Err(ViewError::UnknownCell {
                id,
                count: self.len(),
            });
        }
        let p = &self.params;
        Ok(to_row_major(self.stored(id), p.width_px, p.height_px))
    }

    /// All templates, cell after cell (len × height × width, each row-major), e.g. to save them.
    pub fn templates(&self) -> Vec<f32> {
        let p = &self.params;
        self.templates
            .chunks_exact(p.template_len())
            .flat_map(|t| to_row_major(t, p.width_px, p.height_px))
            .collect()
    }

    fn check(&self, t: &[f32]) -> Result<Query, ViewError> {
        let p = &self.params;
        if t.len() != p.template_len() {
            return Err(ViewError::BadTemplateSize {
                got: t.len(),
                expected: p.template_len(),
                height_px: p.height_px,
                width_px: p.width_px,
            });
        }
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(ViewError::NonFinite {
                row: i / p.width_px,
                col: i % p.width_px,
                value: t[i],
            });
        }
        let columns = to_column_major(t, p.width_px, p.height_px);
        let summary = summarise(&columns, p.width_px, p.height_px, p.coarse_rows);
        Ok(Query { columns, summary })
    }

    fn store(&mut self, q: Query) -> usize {
        self.templates.extend_from_slice(&q.columns);
        self.summaries.push(q.summary);
        self.len() - 1
    }

    /// Store a template as a new cell (no matching) and return its id; e.g. to restore a saved map.
    pub fn add(&mut self, template: &[f32]) -> Result<usize, ViewError> {
        let q = self.check(template)?;
        Ok(self.store(q))
    }

    fn stored(&self, id: usize) -> &[f32] {
        let n = self.params.template_len();
        &self.templates[id * n..(id + 1) * n]
    }

    fn exact(&self, query: &[f32], q: &Summary, id: usize, beat: f32) -> Option<(f32, isize)> {
        let p = &self.params;
        best_shift(
            query,
            q,
            self.stored(id),
            &self.summaries[id],
            p.width_px,
            p.height_px,
            p.max_shift_px,
            beat,
        )
    }

    /// Compare stored template `id` with the query unless it provably cannot beat the shared best
    /// difference `beat` (f32 bits; differences are ≥ 0 so their bits order like their values): its
    /// whole-column bound `key`, then its coarse bound, exceed it. Lowers `beat` when it finds better.
    fn visit(
        &self,
        query: &[f32],
        q: &Summary,
        id: usize,
        key: f32,
        beat: &AtomicU32,
    ) -> Option<Candidate> {
        let p = &self.params;
        let b = f32::from_bits(beat.load(Ordering::Relaxed));
        if b.is_finite() {
            // The bounds are exact up to rounding: a small slack keeps equal-valued templates in.
            let threshold = b * (1.0 + 1e-5) + 1e-7;
            if key > threshold
                || coarse_exceeds(
                    q,
                    &self.summaries[id],
                    p.width_px,
                    p.max_shift_px,
                    threshold,
                )
            {
                return None;
            }
        }
        let (d, s) = self.exact(query, q, id, b)?;
        beat.fetch_min(d.to_bits(), Ordering::Relaxed);
        Some((d, id, s))
    }

    /// The stored template closest to `template` (ties: lowest id), or `None` when nothing is stored.
    ///
    /// Exact and fast. A cheap whole-column key picks a few likely templates, which are compared first
    /// to get a good difference to beat; then every other template is visited once, in parallel, sharing
    /// the best difference found so far: it is skipped when its coarse lower bound exceeds that difference,
    /// and otherwise compared exactly, each shift abandoned as soon as it cannot win. When the query is
    /// familiar the match is found first and almost everything is skipped after a few block sums; when it
    /// is novel nothing can be skipped, and the failed bound test costs about one shift of the coarse bound,
    /// so the search costs about the plain exhaustive one. The answer is the same as
    /// `best_match_brute_force` whatever the order or thread count: a template is only dropped when it
    /// provably cannot match or beat a difference some template really has.
    pub fn best_match(&self, template: &[f32]) -> Result<Option<ViewMatch>, ViewError> {
        let q = self.check(template)?;
        let all: Vec<usize> = (0..self.len()).collect();
        Ok(self.search(&q, &all))
    }

    /// The closest template among the cells `candidates` only (ties: lowest id), or `None` when the set
    /// is empty: the same search as [`best_match`](Self::best_match), so the same answer as brute force
    /// over those cells, at a cost that grows with the number of candidates instead of the store (e.g.
    /// the cells whose stored place lies near the current estimate). Duplicate ids are allowed; an id of
    /// no stored cell is an error ([`ViewError::UnknownCandidate`]).
    pub fn best_match_among(
        &self,
        template: &[f32],
        candidates: &[usize],
    ) -> Result<Option<ViewMatch>, ViewError> {
        let q = self.check(template)?;
        let ids = self.candidate_ids(candidates)?;
        Ok(self.search(&q, &ids))
    }

    /// Candidate ids sorted and deduplicated (so ties still go to the lowest id), each checked.
    fn candidate_ids(&self, candidates: &[usize]) -> Result<Vec<usize>, ViewError> {
        let count = self.len();
        if let Some((position, &id)) = candidates.iter().enumerate().find(|(_, &id)| id >= count) {
            return Err(ViewError::UnknownCandidate {
                id,
                position,
                count,
            });
        }
        let mut ids = candidates.to_vec();
        ids.sort_unstable();
        ids.dedup();
        Ok(ids)
    }

    /// Pruned exact search over `ids` (sorted, unique, all stored; see `best_match`).
    fn search(&self, query: &Query, ids: &[usize]) -> Option<ViewMatch> {
        let (template, q) = (query.columns.as_slice(), &query.summary);
        let n = ids.len();
        if n == 0 {
            return None;
        }
        let p = &self.params;
        // Entries are (key, position in `ids`); ids are sorted, so position order is id order.
        let by_key = |a: &(f32, usize), b: &(f32, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
        let keys: Vec<f32> = ids
            .par_iter()
            .with_min_len(256)
            .map(|&id| rank_key(q, &self.summaries[id], p.width_px, p.max_shift_px))
            .collect();
        let mut order: Vec<(f32, usize)> = keys.iter().copied().zip(0..).collect();
        let k = seed_count(n);
        if k < n {
            order.select_nth_unstable_by(k, by_key);
            order.truncate(k);
        }
        order.sort_unstable_by(by_key);

        let beat = AtomicU32::new(f32::INFINITY.to_bits());
        let mut seeded = vec![false; n];
        for &(_, i) in &order {
            seeded[i] = true;
        }
        // The most likely template alone, so that the other seeds can already be pruned against it.
        let first = self.visit(template, q, ids[order[0].1], order[0].0, &beat);
        let seeds = order[1..]
            .par_iter()
            .filter_map(|&(key, i)| self.visit(template, q, ids[i], key, &beat))
            .reduce_with(better);
        let rest = (0..n)
            .into_par_iter()
            .with_min_len(32)
            .filter(|&i| !seeded[i])
            .filter_map(|i| self.visit(template, q, ids[i], keys[i], &beat))
            .reduce_with(better);
        let best = [first, seeds, rest].into_iter().flatten().reduce(better);
        best.map(|(d, id, s)| ViewMatch {
            cell_id: id,
            difference: d,
            shift_px: s as i32,
        })
    }

    /// Reference search: every template, every shift, no pruning (for tests and benchmarks).
    pub fn best_match_brute_force(&self, template: &[f32]) -> Result<Option<ViewMatch>, ViewError> {
        Ok(self.differences(template)?.into_iter().enumerate().fold(
            None,
            |best: Option<ViewMatch>, (id, (d, s))| match best {
                Some(b) if b.difference <= d => Some(b),
                _ => Some(ViewMatch {
                    cell_id: id,
                    difference: d,
                    shift_px: s,
                }),
            },
        ))
    }

    /// Exact (difference, shift) of `template` against every stored cell, in id order.
    pub fn differences(&self, template: &[f32]) -> Result<Vec<(f32, i32)>, ViewError> {
        let q = self.check(template)?;
        Ok((0..self.len())
            .into_par_iter()
            .map(|id| {
                self.exact(&q.columns, &q.summary, id, f32::INFINITY)
                    .map_or((1.0, 0), |(d, s)| (d, s as i32))
            })
            .collect())
    }

    /// Match a view and create a cell when it is novel (docs/spec.md §7).
    pub fn observe(&mut self, template: &[f32]) -> Result<ViewObservation, ViewError> {
        self.observe_in(template, None)
    }

    /// [`observe`](Self::observe) with the match restricted to the cells `candidates`: familiar when the
    /// best difference among them is below the novelty threshold, otherwise a new cell is created (also
    /// when the set is empty); an uninformative template changes nothing. Candidate ids are checked (see
    /// [`best_match_among`](Self::best_match_among)) before anything is stored.
    pub fn observe_among(
        &mut self,
        template: &[f32],
        candidates: &[usize],
    ) -> Result<ViewObservation, ViewError> {
        self.observe_in(template, Some(candidates))
    }

    fn observe_in(
        &mut self,
        template: &[f32],
        candidates: Option<&[usize]>,
    ) -> Result<ViewObservation, ViewError> {
        let q = self.check(template)?;
        let ids = match candidates {
            Some(c) => self.candidate_ids(c)?,
            None => (0..self.len()).collect(),
        };
        if q.summary.texture < self.params.min_texture {
            return Ok(ViewObservation {
                status: ViewStatus::Uninformative,
                cell_id: None,
                difference: 1.0,
                shift_px: 0,
                relative_heading_rad: 0.0,
            });
        }
        let best = self.search(&q, &ids);
        let rad_per_px = self.params.heading_rad_per_px();
        match best {
            Some(m) if m.difference < self.params.novelty_threshold => Ok(ViewObservation {
                status: ViewStatus::Familiar,
                cell_id: Some(m.cell_id),
                difference: m.difference,
                shift_px: m.shift_px,
                relative_heading_rad: f64::from(m.shift_px) * rad_per_px,
            }),
            _ => {
                let id = self.store(q);
                Ok(ViewObservation {
                    status: ViewStatus::New,
                    cell_id: Some(id),
                    difference: best.map_or(1.0, |m| m.difference),
                    shift_px: 0,
                    relative_heading_rad: 0.0,
                })
            }
        }
    }
}
