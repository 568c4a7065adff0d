//! The store of view cells and the search for the best-matching one.
use crate::compare::{best_shift, coarse_bound, summarise, Summary};
use crate::error::ViewError;
use crate::params::ViewCellParams;
use rayon::prelude::*;

/// Candidates examined per parallel batch in the pruned search. Fixed (not tied to the thread count) so
/// the result never depends on the machine.
const BATCH: usize = 64;

/// Best stored template for a query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewMatch {
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
    pub status: ViewStatus,
    /// The matched or created cell; `None` when the view was uninformative.
    pub cell_id: Option<usize>,
    /// Best difference found among the cells stored before this view (1 when there were none).
    pub difference: f32,
    pub shift_px: i32,
    /// Heading of the camera now minus its heading when the cell was stored (counter-clockwise positive).
    pub relative_heading_rad: f64,
}

/// Local view cells: one stored template per cell, in contiguous memory, ids in creation order.
#[derive(Debug, Clone)]
pub struct ViewCells {
    params: ViewCellParams,
    templates: Vec<f32>,
    summaries: Vec<Summary>,
}

impl ViewCells {
    pub fn new(params: ViewCellParams) -> Result<Self, ViewError> {
        params.validate()?;
        Ok(Self {
            params,
            templates: Vec::new(),
            summaries: Vec::new(),
        })
    }

    pub fn params(&self) -> &ViewCellParams {
        &self.params
    }

    /// Number of view cells.
    pub fn len(&self) -> usize {
        self.summaries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.summaries.is_empty()
    }

    /// Stored template of cell `id` (row-major height × width).
    pub fn template(&self, id: usize) -> Result<&[f32], ViewError> {
        let n = self.params.template_len();
        if id >= self.len() {
            return Err(ViewError::UnknownCell {
                id,
                count: self.len(),
            });
        }
        Ok(&self.templates[id * n..(id + 1) * n])
    }

    /// All templates, cell after cell (len × height × width), e.g. to save them.
    pub fn templates(&self) -> &[f32] {
        &self.templates
    }

    fn check(&self, t: &[f32]) -> Result<Summary, ViewError> {
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
        Ok(summarise(t, p.width_px, p.height_px, p.coarse_rows))
    }

    /// Store a template as a new cell (no matching) and return its id; e.g. to restore a saved map.
    pub fn add(&mut self, template: &[f32]) -> Result<usize, ViewError> {
        let summary = self.check(template)?;
        self.templates.extend_from_slice(template);
        self.summaries.push(summary);
        Ok(self.len() - 1)
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

    /// The stored template closest to `template` (ties: lowest id), or `None` when nothing is stored.
    ///
    /// Exact and fast: templates are ranked by their coarse lower bound (in parallel), then compared
    /// exactly in that order, batch by batch in parallel, each comparison abandoning a shift as soon as it
    /// cannot beat the best difference found; the search stops when the next lower bound exceeds it.
    pub fn best_match(&self, template: &[f32]) -> Result<Option<ViewMatch>, ViewError> {
        let q = self.check(template)?;
        let p = &self.params;
        let mut ranked: Vec<(f32, usize)> = self
            .summaries
            .par_iter()
            .enumerate()
            .map(|(id, s)| (coarse_bound(&q, s, p.width_px, p.max_shift_px), id))
            .collect();
        ranked.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));

        let mut best: Option<(f32, usize, isize)> = None;
        for batch in ranked.chunks(BATCH) {
            let beat = best.map_or(f32::INFINITY, |b| b.0);
            // Bounds are exact up to rounding: keep a small slack so equal-valued templates are still seen.
            if batch[0].0 > beat * (1.0 + 1e-5) + 1e-7 {
                break;
            }
            let found: Vec<Option<(f32, usize, isize)>> = batch
                .par_iter()
                .map(|&(bound, id)| {
                    if bound > beat * (1.0 + 1e-5) + 1e-7 {
                        return None;
                    }
                    self.exact(template, &q, id, beat).map(|(d, s)| (d, id, s))
                })
                .collect();
            for (d, id, s) in found.into_iter().flatten() {
                if best.is_none_or(|(bd, bid, _)| d < bd || (d == bd && id < bid)) {
                    best = Some((d, id, s));
                }
            }
        }
        Ok(best.map(|(d, id, s)| ViewMatch {
            cell_id: id,
            difference: d,
            shift_px: s as i32,
        }))
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
                self.exact(template, &q, id, f32::INFINITY)
                    .map_or((1.0, 0), |(d, s)| (d, s as i32))
            })
            .collect())
    }

    /// Match a view and create a cell when it is novel (SPEC §7).
    pub fn observe(&mut self, template: &[f32]) -> Result<ViewObservation, ViewError> {
        let q = self.check(template)?;
        if q.texture < self.params.min_texture {
            return Ok(ViewObservation {
                status: ViewStatus::Uninformative,
                cell_id: None,
                difference: 1.0,
                shift_px: 0,
                relative_heading_rad: 0.0,
            });
        }
        let best = self.best_match(template)?;
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
                let id = self.add(template)?;
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
