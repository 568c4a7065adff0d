//! Block-sparse symmetric normal equations `(H + λI) δ = −g`, factorised by faer's sparse Cholesky.
//!
//! The unknowns are `B`-vectors, one per free vertex. The sparsity pattern depends on the graph only, so
//! everything that depends on the pattern is done once, in [`BlockOrdering::new`] and [`BlockSystem::new`]:
//! - a fill-reducing ordering (approximate minimum degree) of the *block* graph, which keeps each vertex's
//!   `B` unknowns adjacent (they become dense columns of one supernode) and is `B²` times cheaper to
//!   compute than an ordering of the scalar pattern; it does not depend on `B`, so the chordal
//!   initialisation and the solve share it;
//! - the number of blocks in each column of the factor, counted in near-linear time from the ordered
//!   pattern, which gives the factor's size for any `B` before anything that size exists: a system whose
//!   factorisation would not fit in memory is refused ([`MemoryBudget`]), first on that estimate, then
//!   exactly after the symbolic factorisation;
//! - `H` is stored directly in that elimination order and on the triangle the factorisation reads (upper
//!   CSC for faer's simplicial Cholesky, lower CSC for its supernodal one), so the numeric factorisation
//!   neither permutes nor transposes the matrix;
//! - the symbolic factorisation (elimination tree, supernodes), the buffer of the factor `L` and the
//!   factorisation's workspace are allocated once and reused by every Gauss–Newton or Levenberg–Marquardt
//!   iteration. On a 10⁵-vertex grid world the factor alone holds 22.7 M entries (180 MB); allocated
//!   afresh for every factorisation, each iteration paid for zeroing it and for the page faults of
//!   touching it, and for permuting `H` into the elimination order.
//!
//! Callers address blocks and right-hand sides in their own (unpermuted) order; the permutation of the
//! right-hand side, `O(n)`, happens inside [`BlockSystem::solve_damped`].
use crate::error::{MapError, Result};
use crate::memory::MemoryBudget;
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::{amd, SupernodalThreshold};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

/// Where one block of `H` is stored: entry `(r, k)` of the stored block is `values[starts[k] + r]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BlockSlot<const B: usize> {
    starts: [usize; B],
    /// A diagonal block: only its stored triangle is written.
    diagonal: bool,
    /// The stored block is the transpose of the one added (`H[bj, bi]`).
    transpose: bool,
}

pub(crate) struct BlockSystem<const B: usize> {
    n_blocks: usize,
    /// `position[b]`: where block `b` sits in the elimination order.
    position: Vec<usize>,
    /// `H` in the elimination order, on `side` only.
    pattern: SymbolicSparseColMat<usize>,
    side: Side,
    /// Sorted block rows of each block column (in the elimination order) on `side`, the diagonal included.
    block_rows: Vec<Vec<usize>>,
    /// Index into `values` of every scalar diagonal entry `H[c, c]` (elimination order).
    diagonal_slots: Vec<usize>,
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    /// The factor `L` of the last factorisation (reused buffer).
    factor: Vec<f64>,
    /// Workspace of the numeric factorisation and of the triangular solves (reused buffer).
    workspace: MemBuffer,
    /// Right-hand side in the elimination order (reused buffer).
    permuted_rhs: Vec<f64>,
    /// `H[c, c]` saved while the damping is added to the diagonal.
    saved_diagonal: Vec<f64>,
}

fn factorization_error(detail: impl std::fmt::Debug) -> MapError {
    MapError::Factorization {
        detail: format!("{detail:?}"),
    }
}

/// Scalar CSC pattern of a block pattern: `block_rows[c]` are the block rows of block column `c` on
/// `side` (sorted, diagonal included); within the diagonal block only the `side` triangle is stored.
fn scalar_pattern<const B: usize>(
    block_rows: &[Vec<usize>],
    side: Side,
) -> SymbolicSparseColMat<usize> {
    let n = block_rows.len() * B;
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::with_capacity(block_rows.iter().map(|r| r.len() * B * B).sum());
    col_ptr.push(0usize);
    for (bc, rows) in block_rows.iter().enumerate() {
        for k in 0..B {
            for &br in rows {
                let within = match (br == bc, side) {
                    (false, _) => 0..B,
                    (true, Side::Upper) => 0..k + 1,
                    (true, Side::Lower) => k..B,
                };
                row_idx.extend(within.map(|r| br * B + r));
            }
            col_ptr.push(row_idx.len());
        }
    }
    SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx)
}

/// "No vertex" in the elimination tree's parent and ancestor arrays.
const NONE: usize = usize::MAX;

/// The fill-reducing order of a block pattern, the pattern in that order, and the number of blocks in
/// each column of its Cholesky factor. None of it depends on the block size, so the chordal
/// initialisation (2×2 blocks) and the solve (3×3) share one.
#[derive(Debug, Clone)]
pub(crate) struct BlockOrdering {
    n_blocks: usize,
    /// `position[b]`: where block `b` sits in the elimination order.
    position: Vec<usize>,
    /// Sorted block rows of each block column in the elimination order, upper triangle (rows ≤ column),
    /// and lower triangle (rows ≥ column), the diagonal included in both.
    permuted_upper: Vec<Vec<usize>>,
    permuted_lower: Vec<Vec<usize>>,
    /// Blocks in each block column of the factor `L`, the diagonal block included.
    factor_column_blocks: Vec<usize>,
}

impl BlockOrdering {
    /// Order the blocks coupled by `pairs` (block indices; every block has its diagonal) by approximate
    /// minimum degree and count the factor's blocks, in time about linear in the number of pairs.
    pub fn new(n_blocks: usize, pairs: impl Iterator<Item = (usize, usize)>) -> Result<Self> {
        // Block adjacency, upper triangle (row ≤ column), in the caller's order.
        let mut upper: Vec<Vec<usize>> = (0..n_blocks).map(|b| vec![b]).collect();
        for (a, b) in pairs {
            if a != b {
                upper[a.max(b)].push(a.min(b));
            }
        }
        for rows in &mut upper {
            rows.sort_unstable();
            rows.dedup();
        }

        // Fill-reducing order of the block graph.
        let block_col_ptr: Vec<usize> = std::iter::once(0)
            .chain(upper.iter().scan(0, |acc, r| {
                *acc += r.len();
                Some(*acc)
            }))
            .collect();
        let block_row_idx: Vec<usize> = upper.iter().flatten().copied().collect();
        let nnz_upper = block_row_idx.len();
        let block_pattern = SymbolicSparseColMatRef::new_checked(
            n_blocks,
            n_blocks,
            &block_col_ptr,
            None,
            &block_row_idx,
        );
        let mut order = vec![0usize; n_blocks];
        let mut position = vec![0usize; n_blocks];
        amd::order(
            &mut order,
            &mut position,
            block_pattern,
            amd::Control::default(),
            MemStack::new(&mut MemBuffer::new(amd::order_scratch::<usize>(
                n_blocks, nnz_upper,
            ))),
        )
        .map_err(factorization_error)?;

        // The same pattern relabelled into that order, on both triangles.
        let mut permuted_upper: Vec<Vec<usize>> = vec![Vec::new(); n_blocks];
        let mut permuted_lower: Vec<Vec<usize>> = vec![Vec::new(); n_blocks];
        for (c, rows) in upper.iter().enumerate() {
            for &r in rows {
                let (pr, pc) = (position[r], position[c]);
                let (lo, hi) = (pr.min(pc), pr.max(pc));
                permuted_upper[hi].push(lo);
                permuted_lower[lo].push(hi);
            }
        }
        for rows in permuted_upper.iter_mut().chain(permuted_lower.iter_mut()) {
            rows.sort_unstable();
        }
        let factor_column_blocks = factor_column_counts(&permuted_upper, &permuted_lower);
        Ok(Self {
            n_blocks,
            position,
            permuted_upper,
            permuted_lower,
            factor_column_blocks,
        })
    }

    /// Entries of the factor `L` of the scalar matrix with `block × block` blocks: a block column with
    /// `c` blocks holds `block²(c − 1)` entries below its diagonal block and `block(block + 1)/2` in it.
    /// faer's supernodal factor may store a few more (it pads supernodes that it merges).
    pub fn factor_entries(&self, block: usize) -> u64 {
        let (b, diagonal) = (block as u64, (block * (block + 1) / 2) as u64);
        self.factor_column_blocks
            .iter()
            .map(|&c| {
                (b * b)
                    .saturating_mul(c as u64 - 1)
                    .saturating_add(diagonal)
            })
            .fold(0u64, u64::saturating_add)
    }

    /// Bytes of the factor's values (f64) for `block × block` blocks: what any factorisation allocates.
    pub fn factor_bytes(&self, block: usize) -> u64 {
        self.factor_entries(block).saturating_mul(F64_BYTES)
    }
}

const F64_BYTES: u64 = std::mem::size_of::<f64>() as u64;

/// Number of entries in each column of the Cholesky factor of a symmetric pattern (the diagonal
/// included), given both triangles: the row-subtree algorithm of Gilbert, Ng and Peyton (1994) as in
/// CSparse's `cs_counts` (Davis, "Direct Methods for Sparse Linear Systems", §4.5). It takes time
/// `O(nnz · α(n))`, not `O(nnz(L))` as walking the row subtrees does (what faer's symbolic analysis
/// does): that is what lets a factor of 10¹¹ entries be refused in a fraction of a second.
fn factor_column_counts(upper: &[Vec<usize>], lower: &[Vec<usize>]) -> Vec<usize> {
    let n = upper.len();
    // Elimination tree (cs_etree), with path compression through `ancestor`.
    let mut parent = vec![NONE; n];
    let mut ancestor = vec![NONE; n];
    for (k, rows) in upper.iter().enumerate() {
        for &row in rows {
            let mut i = row;
            while i != NONE && i < k {
                let next = ancestor[i];
                ancestor[i] = k;
                if next == NONE {
                    parent[i] = k;
                }
                i = next;
            }
        }
    }
    // Postorder of the tree (cs_post): children lists, then an iterative depth-first search.
    let mut head = vec![NONE; n];
    let mut next = vec![NONE; n];
    for j in (0..n).rev() {
        if parent[j] != NONE {
            next[j] = head[parent[j]];
            head[parent[j]] = j;
        }
    }
    let mut post = Vec::with_capacity(n);
    let mut stack = Vec::new();
    for root in (0..n).filter(|&j| parent[j] == NONE) {
        stack.push(root);
        while let Some(&p) = stack.last() {
            let child = head[p];
            if child == NONE {
                stack.pop();
                post.push(p);
            } else {
                head[p] = next[child];
                stack.push(child);
            }
        }
    }
    // first[j]: postorder index of j's first descendant; a leaf starts its count at 1.
    let mut first = vec![NONE; n];
    let mut delta = vec![0isize; n];
    for (k, &j) in post.iter().enumerate() {
        delta[j] = isize::from(first[j] == NONE);
        let mut v = j;
        while v != NONE && first[v] == NONE {
            first[v] = k;
            v = parent[v];
        }
    }
    // Skeleton entries add one to their column, and each overlap of two row subtrees takes one off at
    // their least common ancestor (found by union–find over the postorder).
    let mut max_first = vec![NONE; n];
    let mut previous_leaf = vec![NONE; n];
    let mut set: Vec<usize> = (0..n).collect();
    for &j in &post {
        if parent[j] != NONE {
            delta[parent[j]] -= 1;
        }
        for &i in &lower[j] {
            // cs_leaf: is j a leaf of the i-th row subtree?
            if i <= j || (max_first[i] != NONE && first[j] <= max_first[i]) {
                continue;
            }
            max_first[i] = first[j];
            let previous = previous_leaf[i];
            previous_leaf[i] = j;
            delta[j] += 1;
            if previous != NONE {
                let mut q = previous;
                while q != set[q] {
                    q = set[q];
                }
                let mut s = previous;
                while s != q {
                    let up = set[s];
                    set[s] = q;
                    s = up;
                }
                delta[q] -= 1;
            }
        }
        if parent[j] != NONE {
            set[j] = parent[j];
        }
    }
    // Sum the deltas up the tree (a parent's index is above its children's).
    for j in 0..n {
        if parent[j] != NONE {
            delta[parent[j]] += delta[j];
        }
    }
    // Every column holds at least its diagonal; the sums are exact, the bound only guards the cast.
    delta.into_iter().map(|d| d.max(1) as usize).collect()
}

impl<const B: usize> BlockSystem<B> {
    /// Pattern of `H` in `ordering`'s elimination order, refused by `budget` when the factorisation
    /// would not fit.
    pub fn new(ordering: &BlockOrdering, budget: MemoryBudget) -> Result<Self> {
        Self::with_threshold(ordering, budget, SupernodalThreshold::AUTO)
    }

    /// [`Self::new`] with faer's choice between its simplicial and supernodal factorisations overridden.
    fn with_threshold(
        ordering: &BlockOrdering,
        budget: MemoryBudget,
        supernodal_flop_ratio_threshold: SupernodalThreshold,
    ) -> Result<Self> {
        // The factor's values are the least any factorisation takes: refuse before the symbolic
        // analysis, which takes time (and, simplicial, memory) in proportion to them.
        budget.check(ordering.factor_bytes(B))?;
        let n_blocks = ordering.n_blocks;

        // Symbolic factorisation in that order (no further permutation).
        let upper_pattern = scalar_pattern::<B>(&ordering.permuted_upper, Side::Upper);
        let symbolic = factorize_symbolic_cholesky(
            upper_pattern.as_ref(),
            Side::Upper,
            SymmetricOrdering::Identity,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold,
                ..Default::default()
            },
        )
        .map_err(|e| factorization_error(format!("symbolic analysis: {e:?}")))?;
        // Store the triangle the numeric factorisation reads.
        let (side, pattern, block_rows) = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(_) => {
                (Side::Upper, upper_pattern, ordering.permuted_upper.clone())
            }
            SymbolicCholeskyRaw::Supernodal(_) => {
                drop(upper_pattern);
                (
                    Side::Lower,
                    scalar_pattern::<B>(&ordering.permuted_lower, Side::Lower),
                    ordering.permuted_lower.clone(),
                )
            }
        };
        let diagonal_slots = (0..n_blocks * B)
            .map(|c| match side {
                Side::Lower => pattern.col_ptr()[c],
                Side::Upper => pattern.col_ptr()[c + 1] - 1,
            })
            .collect();
        let workspace_size = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]);
        // Now exactly: the factor's values, the workspace, and the simplicial factor's row indices.
        let row_index_bytes = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => s.len_val() * std::mem::size_of::<usize>(),
            SymbolicCholeskyRaw::Supernodal(_) => 0,
        };
        budget.check(
            (symbolic.len_val() as u64)
                .saturating_mul(F64_BYTES)
                .saturating_add(workspace_size.unaligned_bytes_required() as u64)
                .saturating_add(row_index_bytes as u64),
        )?;
        let nnz = pattern.row_idx().len();
        Ok(Self {
            n_blocks,
            position: ordering.position.clone(),
            pattern,
            side,
            block_rows,
            diagonal_slots,
            factor: vec![0.0; symbolic.len_val()],
            symbolic,
            values: vec![0.0; nnz],
            workspace: MemBuffer::try_new(workspace_size).map_err(factorization_error)?,
            permuted_rhs: vec![0.0; n_blocks * B],
            saved_diagonal: vec![0.0; n_blocks * B],
        })
    }

    pub fn dim(&self) -> usize {
        self.n_blocks * B
    }

    pub fn clear(&mut self) {
        self.values.fill(0.0);
    }

    /// Where block `H[bi, bj]` is stored, for repeated accumulation with [`Self::add_at`].
    pub fn slot(&self, bi: usize, bj: usize) -> BlockSlot<B> {
        let (pi, pj) = (self.position[bi], self.position[bj]);
        let col_ptr = self.pattern.col_ptr();
        if pi == pj {
            // The diagonal block is first (lower) or last (upper) in its column.
            return BlockSlot {
                starts: std::array::from_fn(|k| {
                    let c = pj * B + k;
                    match self.side {
                        Side::Lower => col_ptr[c] - k,
                        Side::Upper => col_ptr[c + 1] - (k + 1),
                    }
                }),
                diagonal: true,
                transpose: false,
            };
        }
        let stored_in_row_of_i = match self.side {
            Side::Upper => pi < pj,
            Side::Lower => pi > pj,
        };
        let (row, col, transpose) = if stored_in_row_of_i {
            (pi, pj, false)
        } else {
            (pj, pi, true)
        };
        // The pattern is built from the same pairs that are added, so the block is always found.
        let p = match self.block_rows[col].binary_search(&row) {
            Ok(p) | Err(p) => p,
        };
        debug_assert_eq!(self.block_rows[col].get(p), Some(&row));
        BlockSlot {
            starts: std::array::from_fn(|k| {
                let c = col * B + k;
                // Entries of the blocks above this one in the column (the lower triangle's diagonal
                // block holds only B − k of them).
                match self.side {
                    Side::Upper => col_ptr[c] + B * p,
                    Side::Lower => col_ptr[c] + (B - k) + B * (p - 1),
                }
            }),
            diagonal: false,
            transpose,
        }
    }

    /// `H[bi, bj] += block` at a slot from [`Self::slot`] (and `H[bj, bi] += blockᵀ` implicitly); for a
    /// diagonal block only the stored triangle of `block` is used.
    #[inline]
    pub fn add_at(&mut self, slot: &BlockSlot<B>, block: &[[f64; B]; B]) {
        for (k, &start) in slot.starts.iter().enumerate() {
            let rows = match (slot.diagonal, self.side) {
                (false, _) => 0..B,
                (true, Side::Lower) => k..B,
                (true, Side::Upper) => 0..k + 1,
            };
            for r in rows {
                self.values[start + r] += if slot.transpose {
                    block[k][r]
                } else {
                    block[r][k]
                };
            }
        }
    }

    /// `H[bi, bj] += block` (see [`Self::add_at`]).
    pub fn add_block(&mut self, bi: usize, bj: usize, block: &[[f64; B]; B]) {
        let slot = self.slot(bi, bj);
        self.add_at(&slot, block);
    }

    /// Diagonal entries `H[i, i]` in the caller's order (the Levenberg–Marquardt scaling).
    pub fn diagonal(&self) -> Vec<f64> {
        let mut out = vec![0.0; self.dim()];
        for (b, &p) in self.position.iter().enumerate() {
            for k in 0..B {
                out[b * B + k] = self.values[self.diagonal_slots[p * B + k]];
            }
        }
        out
    }

    /// Factorise `H + λI` into the reused factor buffer and solve in place for `rhs` (length `dim`,
    /// caller's order). `H` itself is left unchanged. λ = 0 is the undamped (Gauss–Newton) system.
    pub fn solve_damped(&mut self, lambda: f64, rhs: &mut [f64]) -> Result<()> {
        for (saved, &slot) in self.saved_diagonal.iter_mut().zip(&self.diagonal_slots) {
            *saved = self.values[slot];
            self.values[slot] += lambda;
        }
        let factorized = {
            let matrix = SparseColMatRef::new(self.pattern.as_ref(), &self.values);
            self.symbolic
                .factorize_numeric_llt(
                    &mut self.factor,
                    matrix,
                    self.side,
                    Default::default(),
                    Par::Seq,
                    MemStack::new(&mut self.workspace),
                    Default::default(),
                )
                .map(|_| ())
        };
        for (&saved, &slot) in self.saved_diagonal.iter().zip(&self.diagonal_slots) {
            self.values[slot] = saved;
        }
        factorized.map_err(factorization_error)?;

        for (b, &p) in self.position.iter().enumerate() {
            self.permuted_rhs[p * B..(p + 1) * B].copy_from_slice(&rhs[b * B..(b + 1) * B]);
        }
        let n = self.dim();
        LltRef::new(&self.symbolic, &self.factor).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.permuted_rhs, n, 1),
            Par::Seq,
            MemStack::new(&mut self.workspace),
        );
        // A supernodal factor's dense blocks ran faer's GEMM assembly on this thread, which returns with
        // the vector registers dirty: the caller's SSE code would pay for it (`hippo_simd`).
        hippo_simd::clear_upper_halves();
        for (b, &p) in self.position.iter().enumerate() {
            rhs[b * B..(b + 1) * B].copy_from_slice(&self.permuted_rhs[p * B..(p + 1) * B]);
        }
        if let Some(bad) = rhs.iter().find(|v| !v.is_finite()) {
            return Err(MapError::Factorization {
                detail: format!("non-finite solution entry {bad}"),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small SPD system with couplings given in both orders, solved on both storage sides (simplicial
    /// and supernodal factorisation), against the dense matrix.
    #[test]
    fn block_solve_matches_dense_solution() {
        for threshold in [
            SupernodalThreshold::FORCE_SIMPLICIAL,
            SupernodalThreshold::FORCE_SUPERNODAL,
        ] {
            solve_against_dense(threshold);
        }
    }

    fn solve_against_dense(threshold: SupernodalThreshold) {
        const N: usize = 7;
        let pairs = [
            (0, 1),
            (1, 2),
            (2, 3),
            (3, 4),
            (4, 5),
            (5, 6),
            (6, 0),
            (2, 5),
            (4, 1),
        ];
        let mut dense = [[0.0f64; 3 * N]; 3 * N];
        let ordering = BlockOrdering::new(N, pairs.iter().copied()).unwrap();
        let mut system =
            BlockSystem::<3>::with_threshold(&ordering, MemoryBudget::default(), threshold)
                .unwrap();
        let block = |a: usize, b: usize| {
            let mut m = [[0.0; 3]; 3];
            for r in 0..3 {
                for c in 0..3 {
                    m[r][c] = 0.1 * ((a * 7 + b * 3 + r * 5 + c) % 11) as f64 - 0.5;
                }
            }
            m
        };
        for &(a, b) in &pairs {
            let m = block(a, b);
            system.add_block(a, b, &m);
            for r in 0..3 {
                for c in 0..3 {
                    dense[3 * a + r][3 * b + c] += m[r][c];
                    dense[3 * b + c][3 * a + r] += m[r][c];
                }
            }
        }
        for v in 0..N {
            let mut d = [[0.0; 3]; 3];
            for r in 0..3 {
                d[r][r] = 10.0 + r as f64;
                if r > 0 {
                    d[r - 1][r] = 0.3;
                    d[r][r - 1] = 0.3;
                }
            }
            system.add_block(v, v, &d);
            for r in 0..3 {
                for c in 0..3 {
                    dense[3 * v + r][3 * v + c] += d[r][c];
                }
            }
        }
        let lambda = 0.25;
        for i in 0..3 * N {
            dense[i][i] += lambda;
        }
        let rhs: Vec<f64> = (0..3 * N).map(|i| (i as f64 * 0.37).sin()).collect();
        let diagonal = system.diagonal();
        for i in 0..3 * N {
            assert!((diagonal[i] + lambda - dense[i][i]).abs() < 1e-12);
        }
        let mut x = rhs.clone();
        system.solve_damped(lambda, &mut x).unwrap();
        let factor_buffer = system.factor.as_ptr();
        // Residual of the dense system.
        for i in 0..3 * N {
            let ax: f64 = (0..3 * N).map(|j| dense[i][j] * x[j]).sum();
            assert!((ax - rhs[i]).abs() < 1e-10, "row {i}: {ax} vs {}", rhs[i]);
        }
        // H is unchanged by the damped solve: the same solve again gives the same answer.
        let mut again = rhs.clone();
        system.solve_damped(lambda, &mut again).unwrap();
        assert_eq!(x, again);
        assert_eq!(
            system.factor.as_ptr(),
            factor_buffer,
            "the factor's buffer is reused"
        );
    }

    /// Random block patterns: a chain (every vertex joined to the next, as odometry does) plus random
    /// couplings, short and long.
    fn random_pattern(n: usize, extra: usize, seed: u64) -> Vec<(usize, usize)> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut pairs: Vec<(usize, usize)> = (1..n).map(|i| (i - 1, i)).collect();
        for _ in 0..extra {
            pairs.push((rng.random_range(0..n), rng.random_range(0..n)));
        }
        pairs
    }

    /// The near-linear column counts agree with faer's (which walks every row subtree), and the scalar
    /// factor of 3×3 blocks has exactly the entries predicted from them (simplicial, no padding).
    #[test]
    fn factor_column_counts_match_faer_and_predict_the_factor() {
        use faer::sparse::linalg::cholesky::simplicial::prefactorize_symbolic_cholesky;
        for (n, extra, seed) in [
            (1, 0, 0),
            (2, 0, 1),
            (30, 0, 2),
            (60, 8, 3),
            (200, 150, 4),
            (400, 2000, 5),
        ] {
            let ordering =
                BlockOrdering::new(n, random_pattern(n, extra, seed).into_iter()).unwrap();
            let col_ptr: Vec<usize> = std::iter::once(0)
                .chain(ordering.permuted_upper.iter().scan(0, |acc, r| {
                    *acc += r.len();
                    Some(*acc)
                }))
                .collect();
            let row_idx: Vec<usize> = ordering.permuted_upper.iter().flatten().copied().collect();
            let upper = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
            let mut etree = vec![0isize; n];
            let mut faer_counts = vec![0usize; n];
            prefactorize_symbolic_cholesky(
                &mut etree,
                &mut faer_counts,
                upper,
                MemStack::new(&mut MemBuffer::new(StackReq::new::<usize>(n))),
            );
            assert_eq!(
                ordering.factor_column_blocks, faer_counts,
                "n {n} extra {extra}"
            );

            let system = BlockSystem::<3>::with_threshold(
                &ordering,
                MemoryBudget::default(),
                SupernodalThreshold::FORCE_SIMPLICIAL,
            )
            .unwrap();
            assert_eq!(system.factor.len() as u64, ordering.factor_entries(3));
        }
    }

    /// Long couplings fill the factor in; under a cap below its size the system is refused before the
    /// symbolic analysis or any factor-sized buffer, with the bytes it would need.
    #[test]
    fn a_factor_over_the_cap_is_refused_with_its_size() {
        let ordering = BlockOrdering::new(600, random_pattern(600, 3000, 7).into_iter()).unwrap();
        let needed = ordering.factor_bytes(3);
        assert!(needed > 4_000_000, "the pattern fills in: {needed} bytes");
        let err = BlockSystem::<3>::new(
            &ordering,
            MemoryBudget {
                cap_bytes: Some(1_000_000),
                alongside_bytes: 0,
            },
        )
        .err()
        .unwrap();
        match err {
            MapError::FactorTooLarge {
                needed_bytes,
                limit_bytes,
                ..
            } => {
                assert_eq!((needed_bytes, limit_bytes), (needed, 1_000_000));
            }
            other => panic!("expected FactorTooLarge, got {other}"),
        }
        // Values alone fit, the exact total (values, workspace) does not: refused after the analysis.
        let err = BlockSystem::<3>::new(
            &ordering,
            MemoryBudget {
                cap_bytes: Some(needed),
                alongside_bytes: 0,
            },
        )
        .err()
        .unwrap();
        assert!(
            matches!(err, MapError::FactorTooLarge { needed_bytes, .. } if needed_bytes > needed),
            "{err}"
        );
        assert!(BlockSystem::<3>::new(
            &ordering,
            MemoryBudget {
                cap_bytes: Some(4 * needed),
                alongside_bytes: 0
            }
        )
        .is_ok());
    }
}
