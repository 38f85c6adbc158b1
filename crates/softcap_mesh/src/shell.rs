//! Linear thin-shell deformation with handle constraints (thesis eq. 3.3 / 5.1).
//!
//! The large-scale deformation `u` of a surface minimises the linearised stretching and
//! bending energy (thesis eq. 3.2) subject to prescribed displacements `u_H` of a set of
//! handle vertices:
//!
//! ```text
//! E(u) = k_s · uᵀ(−L)u + k_b · uᵀ L M⁻¹ L u        (discrete form of thesis eq. 3.2)
//! ∂E/∂u_free = 0  ⇔  −k_s Δu + k_b Δ²u = 0          (thesis eq. 3.3 / 5.1)
//! ```
//!
//! with `L` the symmetric cotangent matrix (`L_ij = ½(cot α_ij + cot β_ij)`,
//! `L_ii = −Σ_j L_ij`, negative semidefinite), `M` the diagonal of Voronoi vertex areas and
//! `Δ = M⁻¹L` the discrete Laplace–Beltrami operator of Meyer et al. 2003 (thesis eq. 3.4).
//! Writing `A = k_s(−L) + k_b L M⁻¹ L` and splitting the vertices into free (`F`) and handle
//! (`H`) sets gives the system of thesis §5.3
//!
//! ```text
//! A_FF u_F = −A_FH u_H,       B = −A_FF⁻¹ A_FH,       u = B · u_H .
//! ```
//!
//! We use the symmetric energy form (rather than the row-wise Euler–Lagrange equations) so
//! `A_FF` is symmetric positive definite and one sparse Cholesky factorisation (faer `Llt`)
//! serves every frame and every basis column; at open boundaries the energy form gives the
//! natural boundary conditions. Every connected component must contain at least one handle.
//!
//! Units: `k_b / k_s` has units of length²; the defaults `k_s = 1`, `k_b = 100` are the
//! thesis values for faces modelled in centimetres.

use crate::types::TriMesh;
use faer::sparse::{SparseColMat, SparseColMatRef};
use faer::{Mat, Side};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Errors of the linear shell.
#[derive(Debug, thiserror::Error)]
pub enum ShellError {
    /// The Laplacian is not square or its size differs from the vertex-area array.
    #[error("Laplacian is {rows}×{cols} but {areas} vertex areas were given")]
    ShapeMismatch {
        /// rows of the Laplacian
        rows: usize,
        /// columns of the Laplacian
        cols: usize,
        /// number of vertex areas
        areas: usize,
    },
    /// A vertex has zero, negative or non-finite area (unreferenced or degenerate vertex).
    #[error("vertex {vertex} has area {area}; every vertex needs a positive finite Voronoi area")]
    BadArea {
        /// vertex index
        vertex: usize,
        /// its area
        area: f64,
    },
    /// A handle index is out of range or repeated.
    #[error(
        "handle {handle} (vertex {vertex}) is out of range or repeated (mesh has {n} vertices)"
    )]
    BadHandle {
        /// position in the handle list
        handle: usize,
        /// vertex index given
        vertex: usize,
        /// number of vertices
        n: usize,
    },
    /// A connected component has no handle, so its rigid motion is undetermined.
    #[error("connected component containing vertex {vertex} ({size} vertices) has no handle")]
    ComponentWithoutHandle {
        /// smallest vertex of the component
        vertex: usize,
        /// number of vertices in it
        size: usize,
    },
    /// The handle displacement array has the wrong length.
    #[error("expected {expected} handle displacements, got {got}")]
    DisplacementCount {
        /// number of handles
        expected: usize,
        /// number given
        got: usize,
    },
    /// The stiffnesses are not usable (`k_s ≥ 0`, `k_b ≥ 0`, not both zero).
    #[error("invalid stiffness k_s = {k_s}, k_b = {k_b}")]
    BadStiffness {
        /// stretching stiffness
        k_s: f64,
        /// bending stiffness
        k_b: f64,
    },
    /// The vertex positions (for the nested-dissection ordering) do not match the vertices.
    #[error("expected {expected} vertex positions, got {got}")]
    PositionCount {
        /// number of vertices
        expected: usize,
        /// number given
        got: usize,
    },
    /// [`ShellOrdering::NestedDissection`] was asked for without vertex positions.
    #[error("the nested-dissection ordering needs the vertex positions")]
    MissingPositions,
    /// The free-vertex system is not numerically positive definite.
    #[error("sparse Cholesky of the free-vertex system failed: {reason}")]
    Factorization {
        /// faer's message
        reason: String,
    },
}

/// Stiffnesses of the linear shell (thesis eq. 3.2 / 5.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ShellSettings {
    /// Stretching stiffness `k_s`.
    pub k_s: f64,
    /// Bending stiffness `k_b` (units of `k_s` × length²).
    pub k_b: f64,
}

impl Default for ShellSettings {
    fn default() -> Self {
        Self {
            k_s: 1.0,
            k_b: 100.0,
        }
    }
}

/// A factorised linear shell over a fixed set of handle (constrained) vertices.
///
/// Build once with [`LinearShell::new`]; then [`LinearShell::solve`] gives the deformation for
/// any handle displacements, and [`LinearShell::basis`] the precomputed `B` of thesis §5.3.
pub struct LinearShell {
    n: usize,
    handles: Vec<usize>,
    /// vertex → index among free vertices, or `usize::MAX` for a handle
    free_index: Vec<usize>,
    free: Vec<usize>,
    /// `A_FH` as (free row, handle column, value), sorted by handle column
    a_fh: Vec<(usize, usize, f64)>,
    llt: Factor,
}

impl std::fmt::Debug for LinearShell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinearShell")
            .field("vertices", &self.n)
            .field("handles", &self.handles.len())
            .finish_non_exhaustive()
    }
}

/// Dense basis `B` (n × H, row-major `f32`) with `u = B · u_H` (thesis §5.3).
///
/// Row `v` holds the response of vertex `v` to a unit displacement of each handle; handle rows
/// are unit vectors. `f32` halves memory traffic at run time; rows sum to 1 (the shell reproduces
/// translations) with entries of order 1, so single precision costs ~1e-7 relative accuracy.
#[derive(Clone, Debug, PartialEq)]
pub struct ShellBasis {
    /// number of vertices `n`
    pub n: usize,
    /// number of handles `H`
    pub h: usize,
    /// row-major `n × H` weights
    pub weights: Vec<f32>,
}

impl ShellBasis {
    /// Row `v` of `B`.
    pub fn row(&self, v: usize) -> &[f32] {
        &self.weights[v * self.h..(v + 1) * self.h]
    }

    /// `out[k] = Σ_h B[first + k, h] · u_H[h]` for the vertex rows `first .. first + out.len()`
    /// (thesis §5.3). Callers parallelise by splitting `out` into blocks.
    ///
    /// # Panics
    /// If `handle_displacements.len() != H` or the rows run past `n`.
    pub fn apply_rows(
        &self,
        handle_displacements: &[[f32; 3]],
        first: usize,
        out: &mut [[f32; 3]],
    ) {
        assert_eq!(
            handle_displacements.len(),
            self.h,
            "one displacement per handle"
        );
        assert!(first + out.len() <= self.n, "rows past the last vertex");
        // Structure-of-arrays u_H and 8 independent partial sums per axis so the dot products
        // vectorise (f32 sums are not reassociated by the compiler on its own).
        const LANES: usize = 8;
        let h = self.h;
        let split = h - h % LANES;
        let mut soa = vec![0.0f32; 3 * h];
        for (k, u) in handle_displacements.iter().enumerate() {
            soa[k] = u[0];
            soa[h + k] = u[1];
            soa[2 * h + k] = u[2];
        }
        let (ux, rest) = soa.split_at(h);
        let (uy, uz) = rest.split_at(h);
        for (k, o) in out.iter_mut().enumerate() {
            let row = self.row(first + k);
            let (mut ax, mut ay, mut az) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
            for c in (0..split).step_by(LANES) {
                let w = &row[c..c + LANES];
                let (x, y, z) = (&ux[c..c + LANES], &uy[c..c + LANES], &uz[c..c + LANES]);
                for l in 0..LANES {
                    ax[l] += w[l] * x[l];
                    ay[l] += w[l] * y[l];
                    az[l] += w[l] * z[l];
                }
            }
            let (mut x, mut y, mut z) = (
                ax.iter().sum::<f32>(),
                ay.iter().sum::<f32>(),
                az.iter().sum::<f32>(),
            );
            for c in split..h {
                x += row[c] * ux[c];
                y += row[c] * uy[c];
                z += row[c] * uz[c];
            }
            *o = [x, y, z];
        }
    }

    /// `u = B · u_H` for all vertices (single-threaded; see [`ShellBasis::apply_rows`]).
    pub fn apply(&self, handle_displacements: &[[f32; 3]], out: &mut [[f32; 3]]) {
        assert_eq!(out.len(), self.n, "one output per vertex");
        self.apply_rows(handle_displacements, 0, out);
    }
}

impl LinearShell {
    /// Assemble `A = k_s(−L) + k_b L M⁻¹ L` (thesis eq. 5.1), split it into free and handle
    /// blocks and factorise `A_FF` once (sparse Cholesky).
    ///
    /// `laplacian` is the symmetric cotangent matrix with negative diagonal (see module docs),
    /// `vertex_areas` the Voronoi areas (diagonal of `M`), `handles` the constrained vertices.
    /// Without vertex positions the fill-reducing ordering is AMD; [`LinearShell::from_mesh`]
    /// passes the positions and gets the (much cheaper) nested dissection.
    pub fn new(
        laplacian: SparseColMatRef<'_, usize, f64>,
        vertex_areas: &[f64],
        handles: &[usize],
        settings: &ShellSettings,
    ) -> Result<Self, ShellError> {
        Self::with_ordering(
            laplacian,
            vertex_areas,
            None,
            handles,
            settings,
            ShellOrdering::Auto,
        )
    }

    /// [`LinearShell::new`] with an explicit fill-reducing ordering of the Cholesky factor and,
    /// for the nested dissection, the vertex positions (one per vertex).
    pub fn with_ordering(
        laplacian: SparseColMatRef<'_, usize, f64>,
        vertex_areas: &[f64],
        positions: Option<&[Vector3<f64>]>,
        handles: &[usize],
        settings: &ShellSettings,
        ordering: ShellOrdering,
    ) -> Result<Self, ShellError> {
        let n = vertex_areas.len();
        match positions {
            Some(p) if p.len() != n => {
                return Err(ShellError::PositionCount {
                    expected: n,
                    got: p.len(),
                });
            }
            None if ordering == ShellOrdering::NestedDissection => {
                return Err(ShellError::MissingPositions);
            }
            _ => {}
        }
        if laplacian.nrows() != n || laplacian.ncols() != n {
            return Err(ShellError::ShapeMismatch {
                rows: laplacian.nrows(),
                cols: laplacian.ncols(),
                areas: n,
            });
        }
        let (k_s, k_b) = (settings.k_s, settings.k_b);
        if !(k_s >= 0.0 && k_b >= 0.0 && k_s + k_b > 0.0 && (k_s + k_b).is_finite()) {
            return Err(ShellError::BadStiffness { k_s, k_b });
        }
        for (v, &a) in vertex_areas.iter().enumerate() {
            if !(a > 0.0 && a.is_finite()) {
                return Err(ShellError::BadArea { vertex: v, area: a });
            }
        }
        let mut free_index = vec![0usize; n];
        for (k, &v) in handles.iter().enumerate() {
            if v >= n || free_index[v] == usize::MAX {
                return Err(ShellError::BadHandle {
                    handle: k,
                    vertex: v,
                    n,
                });
            }
            free_index[v] = usize::MAX;
        }
        let mut free = Vec::with_capacity(n - handles.len());
        for v in 0..n {
            if free_index[v] != usize::MAX {
                free_index[v] = free.len();
                free.push(v);
            }
        }

        // Rows of L as sorted (column, value) lists; L is symmetric so columns = rows.
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
        for j in 0..n {
            for (i, &val) in laplacian
                .row_idx_of_col_raw(j)
                .iter()
                .zip(laplacian.val_of_col(j))
            {
                rows[*i].push((j, val));
            }
        }
        check_components(&rows, &free_index)?;

        // A = −k_s L + k_b Σ_k L_ik L_kj / m_k, accumulated row by row into a dense scatter
        // accumulator (Gustavson's sparse product: every entry sums its terms in the order of
        // k, as a per-row ordered map would, at a fraction of the cost on large meshes). Free
        // row `fi` keeps its entries with free column `fj ≤ fi`: stored as column `fi` of the
        // upper triangle (the same symmetric matrix), so A_FF is written directly in CSC.
        let nf = free.len();
        let mut handle_col = vec![usize::MAX; n];
        for (c, &v) in handles.iter().enumerate() {
            handle_col[v] = c;
        }
        let mut acc = vec![0.0f64; n];
        let mut touched_at = vec![usize::MAX; n];
        let mut touched: Vec<usize> = Vec::new();
        let mut col_ptr: Vec<usize> = Vec::with_capacity(nf + 1);
        col_ptr.push(0);
        let mut row_idx: Vec<usize> = Vec::new();
        let mut values: Vec<f64> = Vec::new();
        let mut a_fh = Vec::new();
        for (fi, &i) in free.iter().enumerate() {
            touched.clear();
            let mut touch = |j: usize, touched: &mut Vec<usize>, acc: &mut [f64]| {
                if touched_at[j] != i {
                    touched_at[j] = i;
                    acc[j] = 0.0;
                    touched.push(j);
                }
            };
            for &(k, l_ik) in &rows[i] {
                touch(k, &mut touched, &mut acc);
                acc[k] -= k_s * l_ik;
                if k_b != 0.0 {
                    let s = k_b * l_ik / vertex_areas[k];
                    for &(j, l_kj) in &rows[k] {
                        touch(j, &mut touched, &mut acc);
                        acc[j] += s * l_kj;
                    }
                }
            }
            touched.sort_unstable();
            for &j in &touched {
                let fj = free_index[j];
                if fj == usize::MAX {
                    a_fh.push((fi, handle_col[j], acc[j]));
                } else if fj <= fi {
                    row_idx.push(fj);
                    values.push(acc[j]);
                }
            }
            col_ptr.push(row_idx.len());
        }
        a_fh.sort_by_key(|&(r, c, _)| (c, r));
        let a_ff = SparseColMat::<usize, f64>::new(
            faer::sparse::SymbolicSparseColMat::new_checked(nf, nf, col_ptr, None, row_idx),
            values,
        );
        let free_positions =
            positions.map(|p| free.iter().map(|&v| [p[v].x, p[v].y, p[v].z]).collect());
        let llt = factor_upper(a_ff, ordering, free_positions)?;
        Ok(Self {
            n,
            handles: handles.to_vec(),
            free_index,
            free,
            a_fh,
            llt,
        })
    }

    /// [`LinearShell::new`] with the cotangent Laplacian and mixed Voronoi areas of `mesh`
    /// ([`crate::laplacian`], thesis eq. 3.4–3.5), factored in the geometric nested-dissection
    /// order of its vertex positions.
    pub fn from_mesh(
        mesh: &TriMesh,
        handles: &[usize],
        settings: &ShellSettings,
    ) -> Result<Self, ShellError> {
        let lap = crate::laplacian::cotan_laplacian(mesh);
        let areas = crate::laplacian::voronoi_areas(mesh);
        Self::with_ordering(
            lap.as_ref(),
            &areas,
            Some(&mesh.vertices),
            handles,
            settings,
            ShellOrdering::Auto,
        )
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.n
    }

    /// The handle (constrained) vertices, in the order of the displacement arrays.
    pub fn handles(&self) -> &[usize] {
        &self.handles
    }

    /// Deformation `u` (n displacements) interpolating `handle_displacements` exactly:
    /// one forward/backward substitution with the stored factor, `u_F = −A_FF⁻¹ A_FH u_H`.
    pub fn solve(
        &self,
        handle_displacements: &[Vector3<f64>],
    ) -> Result<Vec<Vector3<f64>>, ShellError> {
        let h = self.handles.len();
        if handle_displacements.len() != h {
            return Err(ShellError::DisplacementCount {
                expected: h,
                got: handle_displacements.len(),
            });
        }
        let mut rhs = Mat::<f64>::zeros(self.free.len(), 3);
        for &(r, c, val) in &self.a_fh {
            for d in 0..3 {
                rhs[(r, d)] -= val * handle_displacements[c][d];
            }
        }
        self.llt.solve_in_place(rhs.as_mut());
        let mut u = vec![Vector3::zeros(); self.n];
        for (fi, &v) in self.free.iter().enumerate() {
            u[v] = Vector3::new(rhs[(fi, 0)], rhs[(fi, 1)], rhs[(fi, 2)]);
        }
        for (c, &v) in self.handles.iter().enumerate() {
            u[v] = handle_displacements[c];
        }
        Ok(u)
    }

    /// The basis `B = −A_FF⁻¹ A_FH` (thesis §5.3): one solve per handle column, computed in
    /// column blocks of up to 48 right-hand sides (one pass over the factor serves a whole
    /// block: the supernodal triangular solves become dense block operations), so peak memory
    /// stays at `n_free × 48` doubles; handle rows are unit vectors.
    pub fn basis(&self) -> ShellBasis {
        let h = self.handles.len();
        let mut weights = vec![0.0f32; self.n * h];
        for (c, &v) in self.handles.iter().enumerate() {
            weights[v * h + c] = 1.0;
        }
        const COLS: usize = 48;
        let mut start = 0;
        let mut entry = 0;
        while start < h {
            let end = (start + COLS).min(h);
            let mut rhs = Mat::<f64>::zeros(self.free.len(), end - start);
            while entry < self.a_fh.len() && self.a_fh[entry].1 < end {
                let (r, c, val) = self.a_fh[entry];
                rhs[(r, c - start)] = -val;
                entry += 1;
            }
            self.llt.solve_sparse_rhs_in_place(&mut rhs);
            let cols: Vec<&[f64]> = (0..end - start).map(|j| rhs.col_as_slice(j)).collect();
            for (fi, &v) in self.free.iter().enumerate() {
                for (w, col) in weights[v * h + start..v * h + end].iter_mut().zip(&cols) {
                    *w = col[fi] as f32;
                }
            }
            start = end;
        }
        ShellBasis {
            n: self.n,
            h,
            weights,
        }
    }

    /// Nonzeros of the Cholesky factor `L` (fill of the chosen ordering).
    pub fn factor_nonzeros(&self) -> usize {
        self.llt.len()
    }

    /// Multiply–add count of the numeric factorization, `Σ_j c_j²` over the columns of `L`
    /// with `c_j` nonzeros each (the cost the ordering decides; the supernodal factor's
    /// relaxed supernodes included).
    pub fn factor_flops(&self) -> f64 {
        use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
        match self.llt.symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(sym) => {
                let ptr = sym.col_ptr_for_row_idx();
                (0..sym.n_supernodes())
                    .map(|s| {
                        let size = sym.supernode_end()[s] - sym.supernode_begin()[s];
                        let below = (ptr[s + 1] - ptr[s]) as f64;
                        (1..=size).map(|c| (c as f64 + below).powi(2)).sum::<f64>()
                    })
                    .sum()
            }
            SymbolicCholeskyRaw::Simplicial(sym) => sym
                .col_ptr()
                .windows(2)
                .map(|w| ((w[1] - w[0]) as f64).powi(2))
                .sum(),
        }
    }

    /// Whether vertex `v` is a handle.
    pub fn is_handle(&self, v: usize) -> bool {
        self.free_index[v] == usize::MAX
    }
}

/// Fill-reducing ordering of the shell's sparse Cholesky factor.
///
/// Measured on the ≈600k-vertex face (ICT face 3× midpoint-subdivided, 41 handles, test profile,
/// CPU seconds under load; docs/notes/2026-11-26-shell-nested-dissection.md): AMD nnz(L) 156.5 M, 138.5 G multiply-adds,
/// numeric factor 8.7 s; the geometric nested dissection 138.1 M, 90.4 G, 6.4 s (its ordering
/// and symbolic analysis cost 3.6 s against 1.5 s for AMD) — so `Auto` uses it whenever positions
/// are given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShellOrdering {
    /// [`ShellOrdering::NestedDissection`] when vertex positions are given, else AMD.
    #[default]
    Auto,
    /// faer's approximate minimum degree.
    Amd,
    /// [`geometric_nested_dissection`] of the matrix graph (needs vertex positions).
    NestedDissection,
}

/// Leaf size of the shell's [`geometric_nested_dissection`] (leaves ordered by AMD).
pub const NESTED_DISSECTION_LEAF: usize = 256;

/// Numeric sparse Cholesky factor `P A Pᵀ = L Lᵀ` (faer's low-level API, so that the
/// fill-reducing ordering can be chosen).
struct Factor {
    symbolic: faer::sparse::linalg::cholesky::SymbolicCholesky<usize>,
    values: Vec<f64>,
}

impl Factor {
    /// `rhs ← A⁻¹ rhs` (forward and backward substitution, all columns in one pass).
    fn solve_in_place(&self, rhs: faer::MatMut<'_, f64>) {
        use faer::dyn_stack::{MemBuffer, MemStack};
        let par = faer::get_global_parallelism();
        let mut mem = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(rhs.ncols(), par),
        );
        faer::sparse::linalg::cholesky::LltRef::new(&self.symbolic, &self.values)
            .solve_in_place_with_conj(faer::Conj::No, rhs, par, MemStack::new(&mut mem));
    }

    /// `rhs ← A⁻¹ rhs` for right-hand sides with few nonzero rows (the basis columns −A_FH are
    /// nonzero only next to the handles). The forward substitution `L y = P b` visits only the
    /// supernodes reached from those rows — their elimination-tree ancestors (the reach of a
    /// sparse triangular solve, Gilbert & Peierls 1988; Davis 2006 §3.2): a supernode whose rows
    /// are still all zero when its turn comes contributes nothing and is skipped. The backward
    /// substitution `Lᵀ x = y` is dense (every row of B is wanted). Same arithmetic as
    /// [`Factor::solve_in_place`] on the visited supernodes, so the result is identical.
    fn solve_sparse_rhs_in_place(&self, rhs: &mut Mat<f64>) {
        use faer::dyn_stack::{MemBuffer, MemStack};
        use faer::prelude::{Reborrow, ReborrowMut};
        use faer::sparse::linalg::cholesky::SymbolicCholeskyRaw;
        use faer::sparse::linalg::cholesky::supernodal::SupernodalLltRef;
        let SymbolicCholeskyRaw::Supernodal(sym) = self.symbolic.raw() else {
            return self.solve_in_place(rhs.as_mut());
        };
        let (n, k) = (sym.nrows(), rhs.ncols());
        let par = faer::get_global_parallelism();
        // x = P rhs
        let mut x = Mat::<f64>::zeros(n, k);
        let perm = self.symbolic.perm().map(|p| p.arrays());
        for j in 0..k {
            gather(
                rhs.col_as_slice(j),
                x.col_as_slice_mut(j),
                perm.map(|(fwd, _)| fwd),
            );
        }
        let ns = sym.n_supernodes();
        let mut supernode_of_row = vec![0usize; n];
        for s in 0..ns {
            for r in sym.supernode_begin()[s]..sym.supernode_end()[s] {
                supernode_of_row[r] = s;
            }
        }
        let mut live = vec![false; ns];
        for j in 0..k {
            for (i, &xi) in x.col_as_slice(j).iter().enumerate() {
                if xi != 0.0 {
                    live[supernode_of_row[i]] = true;
                }
            }
        }
        let llt = SupernodalLltRef::new(sym, &self.values);
        let mut tmp: Vec<f64> = Vec::new();
        for s in 0..ns {
            if !live[s] {
                continue;
            }
            let node = llt.supernode(s);
            let ls = node.val();
            let size = ls.ncols();
            let (top, bottom) = ls.split_at_row(size);
            let pattern = node.pattern();
            let mut x_top = x.as_mut().subrows_mut(node.start(), size);
            faer::linalg::triangular_solve::solve_lower_triangular_in_place_with_conj(
                top,
                faer::Conj::No,
                x_top.rb_mut(),
                par,
            );
            if pattern.is_empty() {
                continue;
            }
            tmp.clear();
            tmp.resize(pattern.len() * k, 0.0);
            let mut update = faer::MatMut::from_column_major_slice_mut(&mut tmp, pattern.len(), k);
            faer::linalg::matmul::matmul(
                update.rb_mut(),
                faer::Accum::Replace,
                bottom,
                x_top.rb(),
                1.0,
                par,
            );
            for (j, upd) in tmp.chunks_exact(pattern.len()).enumerate() {
                let xj = x.col_as_slice_mut(j);
                for (&i, &u) in pattern.iter().zip(upd) {
                    xj[i] -= u;
                }
            }
            for &i in pattern {
                live[supernode_of_row[i]] = true;
            }
        }
        let mut mem = MemBuffer::new(sym.solve_in_place_scratch::<f64>(k, par));
        llt.l_transpose_solve_with_conj(faer::Conj::No, x.as_mut(), par, MemStack::new(&mut mem));
        // rhs = Pᵀ x
        for j in 0..k {
            gather(
                x.col_as_slice(j),
                rhs.col_as_slice_mut(j),
                perm.map(|(_, inv)| inv),
            );
        }
    }

    /// Nonzeros stored in `L`.
    fn len(&self) -> usize {
        self.values.len()
    }
}

/// Sparse Cholesky of the symmetric matrix given by its upper triangle (CSC), faer's
/// supernodal/simplicial factorization with the chosen fill-reducing ordering.
fn factor_upper(
    a_ff: SparseColMat<usize, f64>,
    ordering: ShellOrdering,
    positions: Option<Vec<[f64; 3]>>,
) -> Result<Factor, ShellError> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::cholesky::{SymmetricOrdering, factorize_symbolic_cholesky};
    let err = |e: &dyn std::fmt::Debug| ShellError::Factorization {
        reason: format!("{e:?}"),
    };
    let n = a_ff.nrows();
    let positions = match ordering {
        ShellOrdering::Amd => None,
        ShellOrdering::Auto | ShellOrdering::NestedDissection => positions,
    };
    let perm = if let Some(positions) = positions {
        let (col_ptr, row_idx) = (a_ff.symbolic().col_ptr(), a_ff.symbolic().row_idx());
        // symmetric adjacency (both directions, no diagonal)
        let mut xadj = vec![0usize; n + 1];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                if i != j {
                    xadj[i + 1] += 1;
                    xadj[j + 1] += 1;
                }
            }
        }
        for v in 0..n {
            xadj[v + 1] += xadj[v];
        }
        let mut fill = xadj.clone();
        let mut adj = vec![0usize; xadj[n]];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                if i != j {
                    adj[fill[i]] = j;
                    fill[i] += 1;
                    adj[fill[j]] = i;
                    fill[j] += 1;
                }
            }
        }
        let fwd = geometric_nested_dissection(&xadj, &adj, &positions, NESTED_DISSECTION_LEAF);
        let mut inv = vec![0usize; n];
        for (new, &old) in fwd.iter().enumerate() {
            inv[old] = new;
        }
        Some(faer::perm::Perm::new_checked(
            fwd.into_boxed_slice(),
            inv.into_boxed_slice(),
            n,
        ))
    } else {
        None
    };
    let ordering = match &perm {
        Some(p) => SymmetricOrdering::Custom(p.as_ref()),
        None => SymmetricOrdering::Amd,
    };
    let symbolic =
        factorize_symbolic_cholesky(a_ff.symbolic(), Side::Upper, ordering, Default::default())
            .map_err(|e| err(&e))?;
    let mut values = Vec::new();
    values
        .try_reserve_exact(symbolic.len_val())
        .map_err(|e| err(&e))?;
    values.resize(symbolic.len_val(), 0.0);
    let par = faer::get_global_parallelism();
    let mut mem =
        MemBuffer::try_new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()))
            .map_err(|e| err(&e))?;
    symbolic
        .factorize_numeric_llt::<f64>(
            &mut values,
            a_ff.as_ref(),
            Side::Upper,
            Default::default(),
            par,
            MemStack::new(&mut mem),
            Default::default(),
        )
        .map_err(|e| err(&e))?;
    Ok(Factor { symbolic, values })
}

/// Geometric nested dissection of a graph whose vertices have positions (George 1973, "Nested
/// dissection of a regular finite element mesh"; the coordinate-bisection variant of Heath &
/// Raghavan 1995, with the cut position chosen for the smallest separator). A part is cut by a
/// plane normal to a coordinate axis; the separator is the vertices on one side of the plane
/// that have a neighbour on the other side (removing it disconnects the halves, so no fill
/// crosses the cut). Of all planes normal to the three axes that leave at least
/// [`NESTED_DISSECTION_BALANCE`] of the part on each side, the one with the smallest separator
/// is taken: on a surface a plane meets the mesh in curves, and where the mesh is dense or
/// strongly curved (nose, eyes, mouth of a face) a median cut is 1.5–2× longer than the best
/// nearby one. The two halves are ordered recursively and the separator last. Parts of at most
/// `leaf_size` vertices are ordered by faer's approximate minimum degree on their induced
/// subgraph (they are eliminated before every separator around them, so their local order
/// decides only their own fill). The vertex lists of a part are kept sorted along each axis
/// (filtered, not re-sorted, when a part is split), so all cuts of a part cost one sweep per
/// axis over its edges.
///
/// `xadj`/`adj` is the symmetric adjacency in CSR without self loops, `positions[v]` the
/// position of vertex `v`. Deterministic (coordinates ordered by (value, index)). Returns the
/// elimination order (`order[k]` = vertex eliminated k-th).
pub fn geometric_nested_dissection(
    xadj: &[usize],
    adj: &[usize],
    positions: &[[f64; 3]],
    leaf_size: usize,
) -> Vec<usize> {
    let n = xadj.len().saturating_sub(1);
    assert_eq!(positions.len(), n, "one position per vertex");
    let leaf_size = leaf_size.max(2);
    let mut order = Vec::with_capacity(n);
    // part label of each vertex; a part is the set of vertices carrying its label
    let mut label = vec![0u32; n];
    let mut next_label = 1u32;
    // side of the chosen cut (0, 1; 2 = separator), only meaningful inside the current part
    let mut side = vec![0u8; n];
    let mut local = vec![usize::MAX; n];
    let mut counts = vec![[0u32; 2]; n];
    let mut degree = vec![0u32; n];
    enum Task {
        /// a part: its vertices sorted along x, y and z
        Split([Vec<usize>; 3]),
        Emit(Vec<usize>),
    }
    let sorted_along = |axis: usize| {
        let mut all: Vec<usize> = (0..n).collect();
        all.sort_unstable_by(|&a, &b| {
            positions[a][axis]
                .total_cmp(&positions[b][axis])
                .then(a.cmp(&b))
        });
        all
    };
    let mut stack = vec![Task::Split([
        sorted_along(0),
        sorted_along(1),
        sorted_along(2),
    ])];
    while let Some(task) = stack.pop() {
        let sorted = match task {
            Task::Emit(sep) => {
                order.extend(sep);
                continue;
            }
            Task::Split(sorted) => sorted,
        };
        let lab = next_label;
        next_label += 1;
        for &v in &sorted[0] {
            label[v] = lab;
        }
        if sorted[0].len() <= leaf_size {
            order_leaf_amd(xadj, adj, &sorted[0], lab, &label, &mut local, &mut order);
            continue;
        }
        for &v in &sorted[0] {
            degree[v] = adj[xadj[v]..xadj[v + 1]]
                .iter()
                .filter(|&&w| label[w] == lab)
                .count() as u32;
        }
        // large parts (where the separators decide most of the fill) try all three axes,
        // smaller ones the axis of the longest extent
        let extent = |a: usize| {
            let (first, last) = (sorted[a][0], sorted[a][sorted[a].len() - 1]);
            positions[last][a] - positions[first][a]
        };
        let axes: Vec<usize> = if sorted[0].len() > NESTED_DISSECTION_ALL_AXES {
            vec![0, 1, 2]
        } else {
            vec![
                (0..3)
                    .max_by(|&a, &b| extent(a).total_cmp(&extent(b)))
                    .unwrap_or(0),
            ]
        };
        let (axis, rank, cut_side) = best_cut(
            xadj,
            adj,
            &sorted,
            &axes,
            lab,
            &label,
            &degree,
            &mut side,
            &mut counts,
        );
        for (k, &v) in sorted[axis].iter().enumerate() {
            side[v] = u8::from(k >= rank);
        }
        let sep: Vec<usize> = sorted[axis]
            .iter()
            .copied()
            .filter(|&v| {
                side[v] == cut_side
                    && adj[xadj[v]..xadj[v + 1]]
                        .iter()
                        .any(|&w| label[w] == lab && side[w] != cut_side)
            })
            .collect();
        for &v in &sep {
            side[v] = 2;
        }
        let halves: [[Vec<usize>; 3]; 2] = [0u8, 1].map(|s| {
            [0, 1, 2].map(|a| {
                sorted[a]
                    .iter()
                    .copied()
                    .filter(|&v| side[v] == s)
                    .collect()
            })
        });
        let [first, second] = halves;
        if first[0].is_empty() || second[0].is_empty() {
            // the cut separates nothing (a near-clique): order the part as a leaf
            order_leaf_amd(xadj, adj, &sorted[0], lab, &label, &mut local, &mut order);
            continue;
        }
        stack.push(Task::Emit(sep));
        stack.push(Task::Split(second));
        stack.push(Task::Split(first));
    }
    order
}

/// Parts larger than this try cuts normal to all three axes in
/// [`geometric_nested_dissection`], smaller ones only normal to their longest extent.
pub const NESTED_DISSECTION_ALL_AXES: usize = 16_384;

/// Least fraction of a part on each side of a [`geometric_nested_dissection`] cut.
pub const NESTED_DISSECTION_BALANCE: f64 = 0.3;

/// Smallest-separator cut of a part (all labelled `lab`; `sorted[a]` its vertices sorted along
/// axis `a`) by a plane normal to a coordinate axis: returns (axis, rank, side) — the `rank`
/// lowest vertices along `axis` form side 0, and the separator is the vertices of `side` with a
/// neighbour on the other side. For each axis one sweep moves the vertices from side 1 to
/// side 0 in coordinate order while counting, per vertex, its neighbours on either side, so
/// the boundary sizes of all cut positions cost one pass over the part's edges. Only cuts with
/// at least [`NESTED_DISSECTION_BALANCE`] of the part on each side are candidates (ties: the
/// cut closest to the median, then the lower axis).
fn best_cut(
    xadj: &[usize],
    adj: &[usize],
    sorted: &[Vec<usize>; 3],
    axes: &[usize],
    lab: u32,
    label: &[u32],
    degree: &[u32],
    side: &mut [u8],
    counts: &mut [[u32; 2]],
) -> (usize, usize, u8) {
    let balance = NESTED_DISSECTION_BALANCE;
    let m = sorted[0].len();
    let (lo, hi) = (
        ((m as f64 * balance).ceil() as usize).max(1),
        ((m as f64 * (1.0 - balance)).floor() as usize).min(m - 1),
    );
    // (separator size, distance to the median, axis, rank, side)
    let mut best = (usize::MAX, usize::MAX, 0, m / 2, 0u8);
    for &axis in axes {
        let part = &sorted[axis];
        for &v in part {
            side[v] = 1;
            // [neighbours on side 0, neighbours on side 1]
            counts[v] = [0, degree[v]];
        }
        // b[s] = vertices of side s with a neighbour on the other side
        let mut b = [0usize; 2];
        for (k, &v) in part.iter().enumerate() {
            if k >= lo {
                let (size, s) = if b[1] < b[0] { (b[1], 1) } else { (b[0], 0) };
                let cand = (size, k.abs_diff(m / 2), axis, k, s);
                if (cand.0, cand.1) < (best.0, best.1) {
                    best = cand;
                }
            }
            if k >= hi {
                break;
            }
            // move v to side 0
            if counts[v][0] > 0 {
                b[1] -= 1;
            }
            side[v] = 0;
            if counts[v][1] > 0 {
                b[0] += 1;
            }
            for &w in &adj[xadj[v]..xadj[v + 1]] {
                if label[w] != lab {
                    continue;
                }
                counts[w][1] -= 1;
                counts[w][0] += 1;
                if side[w] == 0 && counts[w][1] == 0 {
                    b[0] -= 1;
                }
                if side[w] == 1 && counts[w][0] == 1 {
                    b[1] += 1;
                }
            }
        }
    }
    (best.2, best.3, best.4)
}

/// Append the vertices of `part` (all labelled `lab`) to `order` in faer's approximate minimum
/// degree order of the subgraph they induce (ties and failures: the given order).
fn order_leaf_amd(
    xadj: &[usize],
    adj: &[usize],
    part: &[usize],
    lab: u32,
    label: &[u32],
    local: &mut [usize],
    order: &mut Vec<usize>,
) {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::sparse::linalg::amd;
    let m = part.len();
    if m <= 2 {
        order.extend_from_slice(part);
        return;
    }
    for (i, &v) in part.iter().enumerate() {
        local[v] = i;
    }
    let mut col_ptr = Vec::with_capacity(m + 1);
    col_ptr.push(0usize);
    let mut row_idx = Vec::new();
    for &v in part {
        let start = row_idx.len();
        row_idx.extend(
            adj[xadj[v]..xadj[v + 1]]
                .iter()
                .filter(|&&w| label[w] == lab)
                .map(|&w| local[w]),
        );
        row_idx[start..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    let (mut perm, mut perm_inv) = (vec![0usize; m], vec![0usize; m]);
    let symbolic =
        faer::sparse::SymbolicSparseColMatRef::new_checked(m, m, &col_ptr, None, &row_idx);
    let mut mem = MemBuffer::new(amd::order_scratch::<usize>(m, row_idx.len()));
    let ok = amd::order(
        &mut perm,
        &mut perm_inv,
        symbolic,
        amd::Control::default(),
        MemStack::new(&mut mem),
    )
    .is_ok();
    if ok {
        order.extend(perm.iter().map(|&i| part[i]));
    } else {
        order.extend_from_slice(part);
    }
    for &v in part {
        local[v] = usize::MAX;
    }
}

/// Every connected component of the Laplacian's graph must contain a handle.
fn check_components(rows: &[Vec<(usize, f64)>], free_index: &[usize]) -> Result<(), ShellError> {
    let n = rows.len();
    let mut seen = vec![false; n];
    let mut stack = Vec::new();
    for s in 0..n {
        if seen[s] {
            continue;
        }
        seen[s] = true;
        stack.push(s);
        let (mut size, mut has_handle) = (0usize, false);
        while let Some(v) = stack.pop() {
            size += 1;
            has_handle |= free_index[v] == usize::MAX;
            for &(w, val) in &rows[v] {
                if val != 0.0 && !seen[w] {
                    seen[w] = true;
                    stack.push(w);
                }
            }
        }
        if !has_handle {
            return Err(ShellError::ComponentWithoutHandle { vertex: s, size });
        }
    }
    Ok(())
}

/// `dst[i] = src[index[i]]` (a row permutation of one column), or a plain copy without `index`.
fn gather(src: &[f64], dst: &mut [f64], index: Option<&[usize]>) {
    match index {
        Some(index) => {
            for (d, &f) in dst.iter_mut().zip(index) {
                *d = src[f];
            }
        }
        None => dst.copy_from_slice(src),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::Triplet;

    /// Path graph with unit spacing: L = second difference (negative semidefinite), M = I.
    fn path_laplacian(n: usize) -> SparseColMat<usize, f64> {
        let mut t = Vec::new();
        for i in 0..n - 1 {
            t.push(Triplet::new(i, i + 1, 1.0));
            t.push(Triplet::new(i + 1, i, 1.0));
            t.push(Triplet::new(i, i, -1.0));
            t.push(Triplet::new(i + 1, i + 1, -1.0));
        }
        SparseColMat::try_new_from_triplets(n, n, &t).unwrap()
    }

    /// With two handles at each end, pure bending (k_s = 0) reproduces any cubic exactly
    /// (the interior rows of L M⁻¹ L are the fourth difference), pure stretching any line.
    #[test]
    fn path_reproduces_cubic_and_linear_fields() {
        let n = 40;
        let lap = path_laplacian(n);
        let areas = vec![1.0; n];
        let handles = [0, 1, n - 2, n - 1];
        let cubic = |x: f64| 0.3 - 0.2 * x + 0.05 * x * x - 0.002 * x * x * x;
        let s = LinearShell::new(
            lap.as_ref(),
            &areas,
            &handles,
            &ShellSettings { k_s: 0.0, k_b: 1.0 },
        )
        .unwrap();
        let uh: Vec<_> = handles
            .iter()
            .map(|&v| Vector3::new(cubic(v as f64), 0.0, 1.0))
            .collect();
        let u = s.solve(&uh).unwrap();
        for v in 0..n {
            assert!(
                (u[v].x - cubic(v as f64)).abs() < 1e-8,
                "v {v}: {} vs {}",
                u[v].x,
                cubic(v as f64)
            );
            assert!((u[v].z - 1.0).abs() < 1e-10);
        }
        let s = LinearShell::new(
            lap.as_ref(),
            &areas,
            &[0, n - 1],
            &ShellSettings { k_s: 1.0, k_b: 0.0 },
        )
        .unwrap();
        let u = s
            .solve(&[Vector3::new(1.0, 2.0, 0.0), Vector3::new(3.0, -2.0, 0.0)])
            .unwrap();
        for v in 0..n {
            let t = v as f64 / (n - 1) as f64;
            assert!((u[v].x - (1.0 + 2.0 * t)).abs() < 1e-10);
            assert!((u[v].y - (2.0 - 4.0 * t)).abs() < 1e-10);
        }
    }

    #[test]
    fn basis_matches_direct_solve() {
        let n = 50;
        let lap = path_laplacian(n);
        let areas: Vec<f64> = (0..n).map(|i| 1.0 + 0.01 * i as f64).collect();
        let handles = [3, 0, 17, 30, 49, 48];
        let s =
            LinearShell::new(lap.as_ref(), &areas, &handles, &ShellSettings::default()).unwrap();
        let uh: Vec<_> = (0..handles.len())
            .map(|k| Vector3::new(k as f64 * 0.1, (k as f64).sin(), -0.5))
            .collect();
        let u = s.solve(&uh).unwrap();
        let b = s.basis();
        let uh32: Vec<[f32; 3]> = uh
            .iter()
            .map(|u| [u.x as f32, u.y as f32, u.z as f32])
            .collect();
        let mut ub = vec![[0.0f32; 3]; n];
        b.apply(&uh32, &mut ub);
        for v in 0..n {
            for d in 0..3 {
                assert!((u[v][d] - ub[v][d] as f64).abs() < 1e-5);
            }
        }
        for (k, &v) in handles.iter().enumerate() {
            assert_eq!(u[v], uh[k]);
        }
    }

    /// The sparse-right-hand-side forward substitution of [`LinearShell::basis`] (supernodes
    /// outside the handles' elimination-tree reach skipped) against full solves, on a grid large
    /// enough for faer's supernodal factor, with scattered interior handles.
    #[test]
    fn supernodal_basis_matches_full_solves() {
        let n = 60;
        let (mesh, _) = grid(n, 0.2);
        let handles: Vec<usize> = (0..9)
            .map(|k| {
                let (i, j) = (5 + (k % 3) * 22, 7 + (k / 3) * 21);
                j * n + i
            })
            .collect();
        let s = LinearShell::from_mesh(&mesh, &handles, &ShellSettings::default()).unwrap();
        assert!(
            matches!(
                s.llt.symbolic.raw(),
                faer::sparse::linalg::cholesky::SymbolicCholeskyRaw::Supernodal(_)
            ),
            "test needs a supernodal factor"
        );
        let b = s.basis();
        let mut worst: f64 = 0.0;
        for c in 0..handles.len() {
            let mut uh = vec![Vector3::zeros(); handles.len()];
            uh[c] = Vector3::new(1.0, 0.0, 0.0);
            let u = s.solve(&uh).unwrap();
            for v in 0..mesh.vertices.len() {
                worst = worst.max((u[v].x - b.row(v)[c] as f64).abs());
            }
        }
        // f32 storage of entries of order 1
        assert!(worst < 1e-6, "basis vs solve {worst:e}");
    }

    /// Regular grid of right-isosceles triangles (cotangent weights = 5-point stencil), with
    /// optional in-plane jitter of the interior; returns mesh and the two outer vertex rings.
    fn grid(n: usize, jitter: f64) -> (TriMesh, Vec<usize>) {
        let h = 1.0 / (n - 1) as f64;
        let mut vertices = Vec::new();
        let mut rings = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let ring = i.min(j).min(n - 1 - i).min(n - 1 - j);
                let (dx, dy) = if ring >= 1 {
                    (
                        jitter * h * ((i * 7 + j * 3) as f64).sin(),
                        jitter * h * ((i * 5 + j * 11) as f64).cos(),
                    )
                } else {
                    (0.0, 0.0)
                };
                vertices.push(Vector3::new(i as f64 * h + dx, j as f64 * h + dy, 0.0));
                if ring < 2 {
                    rings.push(j * n + i);
                }
            }
        }
        let mut triangles = Vec::new();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let a = j * n + i;
                triangles.push([a, a + 1, a + n + 1]);
                triangles.push([a, a + n + 1, a + n]);
            }
        }
        (
            TriMesh {
                vertices,
                triangles,
            },
            rings,
        )
    }

    /// The cotangent Laplacian has linear precision on any planar mesh, so with the two outer
    /// rings as handles every free row of k_s(−L) + k_b L M⁻¹ L vanishes on a linear field:
    /// the shell reproduces it exactly, on a jittered (irregular) flat patch.
    #[test]
    fn flat_patch_reproduces_linear_fields() {
        let (mesh, handles) = grid(14, 0.25);
        let field =
            |p: &Vector3<f64>| Vector3::new(0.1 + 0.3 * p.x - 0.2 * p.y, -0.4 * p.x, 0.05 + p.y);
        let s = LinearShell::from_mesh(&mesh, &handles, &ShellSettings::default()).unwrap();
        let uh: Vec<_> = handles.iter().map(|&v| field(&mesh.vertices[v])).collect();
        let u = s.solve(&uh).unwrap();
        for (v, p) in mesh.vertices.iter().enumerate() {
            assert!(
                (u[v] - field(p)).norm() < 1e-9,
                "vertex {v}: {:?} vs {:?}",
                u[v],
                field(p)
            );
        }
        // the precomputed basis gives the same deformation (f32 storage: 1e-6)
        let b = s.basis();
        let uh32: Vec<[f32; 3]> = uh
            .iter()
            .map(|u| [u.x as f32, u.y as f32, u.z as f32])
            .collect();
        let mut ub = vec![[0.0f32; 3]; mesh.vertices.len()];
        b.apply(&uh32, &mut ub);
        for v in 0..mesh.vertices.len() {
            for d in 0..3 {
                assert!((u[v][d] - ub[v][d] as f64).abs() < 2e-6);
            }
        }
    }

    /// On the regular grid the discrete Laplacian is exact for cubics, so pure bending
    /// (k_s = 0) reproduces the biharmonic field x²y + x³ − 3xy² (Δ²u = 0) exactly.
    #[test]
    fn flat_grid_reproduces_biharmonic_field() {
        let (mesh, handles) = grid(16, 0.0);
        let f = |p: &Vector3<f64>| p.x * p.x * p.y + p.x.powi(3) - 3.0 * p.x * p.y * p.y;
        let s =
            LinearShell::from_mesh(&mesh, &handles, &ShellSettings { k_s: 0.0, k_b: 1.0 }).unwrap();
        let uh: Vec<_> = handles
            .iter()
            .map(|&v| Vector3::new(0.0, 0.0, f(&mesh.vertices[v])))
            .collect();
        let u = s.solve(&uh).unwrap();
        for (v, p) in mesh.vertices.iter().enumerate() {
            assert!(
                (u[v].z - f(p)).abs() < 1e-9,
                "vertex {v}: {} vs {}",
                u[v].z,
                f(p)
            );
        }
        // with stretching on, the same constraints give a different (non-biharmonic) field
        let s = LinearShell::from_mesh(
            &mesh,
            &handles,
            &ShellSettings {
                k_s: 1.0,
                k_b: 1e-3,
            },
        )
        .unwrap();
        let u2 = s.solve(&uh).unwrap();
        let centre = 8 * 16 + 8;
        assert!((u2[centre].z - f(&mesh.vertices[centre])).abs() > 1e-5);
    }

    #[test]
    fn component_without_handle_is_reported() {
        // two disjoint paths, handles only on the first
        let mut t = Vec::new();
        for (a, b) in [(0, 1), (1, 2), (3, 4), (4, 5)] {
            t.push(Triplet::new(a, b, 1.0));
            t.push(Triplet::new(b, a, 1.0));
            t.push(Triplet::new(a, a, -1.0));
            t.push(Triplet::new(b, b, -1.0));
        }
        let lap = SparseColMat::try_new_from_triplets(6, 6, &t).unwrap();
        let err = LinearShell::new(lap.as_ref(), &[1.0; 6], &[0, 2], &ShellSettings::default())
            .unwrap_err();
        assert!(
            matches!(
                err,
                ShellError::ComponentWithoutHandle { vertex: 3, size: 3 }
            ),
            "{err}"
        );
        let err = LinearShell::new(lap.as_ref(), &[1.0; 6], &[0, 0], &ShellSettings::default())
            .unwrap_err();
        assert!(matches!(err, ShellError::BadHandle { handle: 1, .. }));
    }

    /// Geometric nested dissection is a permutation, and the part ordered last (the top
    /// separator) disconnects the rest of a grid graph.
    #[test]
    fn nested_dissection_orders_separators_last() {
        let n = 30;
        let mut nbrs = vec![Vec::new(); n * n];
        let mut positions = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let v = j * n + i;
                positions.push([i as f64, 1.3 * j as f64, 0.0]);
                if i + 1 < n {
                    nbrs[v].push(v + 1);
                    nbrs[v + 1].push(v);
                }
                if j + 1 < n {
                    nbrs[v].push(v + n);
                    nbrs[v + n].push(v);
                }
            }
        }
        let mut xadj = vec![0];
        let mut adj = Vec::new();
        for l in &nbrs {
            adj.extend(l);
            xadj.push(adj.len());
        }
        let order = geometric_nested_dissection(&xadj, &adj, &positions, 16);
        let mut seen = vec![false; n * n];
        for &v in &order {
            assert!(!seen[v], "vertex {v} twice");
            seen[v] = true;
        }
        assert!(seen.iter().all(|&s| s));
        // the longest extent is y: the top separator is one grid row (n vertices) and splits
        // the grid into two halves
        let mut pos = vec![0; n * n];
        for (k, &v) in order.iter().enumerate() {
            pos[v] = k;
        }
        let removed = |v: usize| pos[v] >= n * n - n;
        let top: Vec<usize> = (0..n * n).filter(|&v| removed(v)).collect();
        assert!(
            top.iter().all(|&v| v / n == top[0] / n),
            "top separator is not one row"
        );
        let mut comp = vec![usize::MAX; n * n];
        let mut sizes = Vec::new();
        for s0 in 0..n * n {
            if removed(s0) || comp[s0] != usize::MAX {
                continue;
            }
            let mut stack = vec![s0];
            comp[s0] = sizes.len();
            let mut size = 0;
            while let Some(v) = stack.pop() {
                size += 1;
                for &w in &nbrs[v] {
                    if !removed(w) && comp[w] == usize::MAX {
                        comp[w] = sizes.len();
                        stack.push(w);
                    }
                }
            }
            sizes.push(size);
        }
        assert_eq!(
            sizes.len(),
            2,
            "the last n vertices do not split the grid in two"
        );
        assert!(sizes.iter().all(|&s| s >= (n * n - n) / 2 - n), "{sizes:?}");
        // deterministic
        assert_eq!(
            order,
            geometric_nested_dissection(&xadj, &adj, &positions, 16)
        );
    }

    /// AMD and nested dissection factor the same system: same deformation to round-off.
    /// Nested dissection without positions is an error.
    #[test]
    fn orderings_give_the_same_shell() {
        let (mesh, handles) = grid(40, 0.25);
        let lap = crate::laplacian::cotan_laplacian(&mesh);
        let areas = crate::laplacian::voronoi_areas(&mesh);
        let uh: Vec<_> = handles
            .iter()
            .map(|&v| {
                let p = mesh.vertices[v];
                Vector3::new((3.0 * p.x).sin(), p.x * p.y, (2.0 * p.y).cos())
            })
            .collect();
        let mut solutions = Vec::new();
        for ordering in [ShellOrdering::Amd, ShellOrdering::NestedDissection] {
            let s = LinearShell::with_ordering(
                lap.as_ref(),
                &areas,
                Some(&mesh.vertices),
                &handles,
                &ShellSettings::default(),
                ordering,
            )
            .unwrap();
            assert!(s.factor_nonzeros() > 0 && s.factor_flops() > 0.0);
            solutions.push(s.solve(&uh).unwrap());
        }
        let err = LinearShell::with_ordering(
            lap.as_ref(),
            &areas,
            None,
            &handles,
            &ShellSettings::default(),
            ShellOrdering::NestedDissection,
        )
        .unwrap_err();
        assert!(matches!(err, ShellError::MissingPositions), "{err}");
        let scale = solutions[0].iter().map(|u| u.norm()).fold(0.0, f64::max);
        for (a, b) in solutions[0].iter().zip(&solutions[1]) {
            assert!((a - b).norm() < 1e-9 * scale.max(1.0), "{a:?} vs {b:?}");
        }
    }
}
