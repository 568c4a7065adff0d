//! Block-sparse symmetric normal equations `H δ = −g`, factorised by faer's sparse Cholesky.
//!
//! The unknowns are `B`-vectors, one per free vertex. Only the upper triangle of `H` is stored (CSC,
//! `Side::Upper`). The sparsity pattern depends on the graph only, so it is built once together with
//! the symbolic factorisation (fill-reducing ordering and elimination tree), and every Gauss–Newton or
//! Levenberg–Marquardt iteration only refills the values and runs the numeric factorisation.
use crate::error::{MapError, Result};
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{MatMut, Side};

pub(crate) struct BlockSystem<const B: usize> {
    n_blocks: usize,
    symbolic_matrix: SymbolicSparseColMat<usize>,
    /// Sorted block rows (`≤` the column) of each block column; the diagonal is last.
    block_rows: Vec<Vec<usize>>,
    symbolic_llt: SymbolicLlt<usize>,
    pub values: Vec<f64>,
}

impl<const B: usize> BlockSystem<B> {
    /// Pattern of `H` for blocks coupled by `pairs` (free block indices); every block has its diagonal.
    pub fn new(n_blocks: usize, pairs: impl Iterator<Item = (usize, usize)>) -> Result<Self> {
        let mut block_rows: Vec<Vec<usize>> = (0..n_blocks).map(|b| vec![b]).collect();
        for (a, b) in pairs {
            if a != b {
                let (lo, hi) = (a.min(b), a.max(b));
                block_rows[hi].push(lo);
            }
        }
        for rows in &mut block_rows {
            rows.sort_unstable();
            rows.dedup();
        }
        let n = n_blocks * B;
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0usize);
        for (bj, rows) in block_rows.iter().enumerate() {
            for k in 0..B {
                for &bi in rows {
                    let count = if bi == bj { k + 1 } else { B };
                    row_idx.extend((0..count).map(|r| bi * B + r));
                }
                col_ptr.push(row_idx.len());
            }
        }
        let symbolic_matrix = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let symbolic_llt =
            SymbolicLlt::try_new(symbolic_matrix.as_ref(), Side::Upper).map_err(|e| {
                MapError::Factorization {
                    detail: format!("symbolic analysis: {e:?}"),
                }
            })?;
        let nnz = symbolic_matrix.row_idx().len();
        Ok(Self {
            n_blocks,
            symbolic_matrix,
            block_rows,
            symbolic_llt,
            values: vec![0.0; nnz],
        })
    }

    pub fn dim(&self) -> usize {
        self.n_blocks * B
    }

    pub fn clear(&mut self) {
        self.values.fill(0.0);
    }

    /// `H[bi, bj] += block` (and its transpose implicitly); for `bi == bj` only the upper part is used.
    pub fn add_block(&mut self, bi: usize, bj: usize, block: &[[f64; B]; B]) {
        let col_ptr = self.symbolic_matrix.col_ptr();
        if bi == bj {
            let last = self.block_rows[bj].len() - 1;
            for k in 0..B {
                let start = col_ptr[bj * B + k] + B * last;
                for r in 0..=k {
                    self.values[start + r] += block[r][k];
                }
            }
            return;
        }
        let (row, col, transpose) = if bi < bj {
            (bi, bj, false)
        } else {
            (bj, bi, true)
        };
        let Ok(p) = self.block_rows[col].binary_search(&row) else {
            // The pattern is built from the same pairs that are added, so this cannot happen.
            debug_assert!(false, "block ({row}, {col}) missing from the pattern");
            return;
        };
        for k in 0..B {
            let start = col_ptr[col * B + k] + B * p;
            for r in 0..B {
                self.values[start + r] += if transpose { block[k][r] } else { block[r][k] };
            }
        }
    }

    /// Diagonal entries `H[i, i]` (the Levenberg–Marquardt scaling).
    pub fn diagonal(&self) -> Vec<f64> {
        let col_ptr = self.symbolic_matrix.col_ptr();
        (0..self.dim())
            .map(|c| self.values[col_ptr[c + 1] - 1])
            .collect()
    }

    /// Factorise `H + diag(extra)` and solve in place for `rhs` (length `dim`).
    pub fn solve_damped(&self, extra_diagonal: &[f64], rhs: &mut [f64]) -> Result<()> {
        let col_ptr = self.symbolic_matrix.col_ptr();
        let mut values = self.values.clone();
        for (c, add) in extra_diagonal.iter().enumerate() {
            values[col_ptr[c + 1] - 1] += add;
        }
        let matrix = SparseColMatRef::new(self.symbolic_matrix.as_ref(), &values);
        let llt = Llt::try_new_with_symbolic(self.symbolic_llt.clone(), matrix, Side::Upper)
            .map_err(|e| MapError::Factorization {
                detail: format!("{e:?}"),
            })?;
        let n = rhs.len();
        llt.solve_in_place(MatMut::from_column_major_slice_mut(rhs, n, 1));
        if let Some(bad) = rhs.iter().find(|v| !v.is_finite()) {
            return Err(MapError::Factorization {
                detail: format!("non-finite solution entry {bad}"),
            });
        }
        Ok(())
    }
}
