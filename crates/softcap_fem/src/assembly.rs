//! Assembly of the reduced (free-DOF) system into a faer sparse matrix and its sparse Cholesky
//! factorization.
//!
//! Dirichlet constraints are handled by **elimination**: constrained DOFs are removed from the
//! system, their prescribed values live in the position vector (so the Newton/fixed-point updates
//! over the free DOFs never see them). The sparsity pattern (lower triangle, CSC, free DOFs in
//! node-major order) is built once per (mesh, constraint set) together with a scatter map from every
//! element-matrix entry to its slot; the symbolic Cholesky factorization (AMD ordering) is computed
//! once and reused for every numeric factorization; a numeric factor serves any number of
//! right-hand sides (bickel2009 appendix: "we compute a sparse Cholesky factorization … and then use
//! this factorization many times").

use crate::FemError;
use crate::element::{Matrix12, StiffnessKind};
use crate::model::ElasticModel;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    LdltRef, LltRef, SymbolicCholesky, SymmetricOrdering, factorize_symbolic_cholesky,
};
use faer::sparse::linalg::lu::{LuRef, NumericLu, SymbolicLu, factorize_symbolic_lu};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::{Matrix3, Vector3};
use std::collections::BTreeMap;

const NONE: u32 = u32::MAX;

/// Prescribed positions of individual degrees of freedom (dof = 3·node + axis), in metres.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DirichletBc {
    /// dof → prescribed position component \[m\]. A BTreeMap keeps iteration deterministic.
    pub values: BTreeMap<usize, f64>,
}

impl DirichletBc {
    /// Empty set.
    pub fn new() -> Self {
        Self::default()
    }
    /// Fixes all three components of `node` at `position_m`.
    pub fn fix_node(&mut self, node: usize, position_m: Vector3<f64>) {
        for c in 0..3 {
            self.values.insert(3 * node + c, position_m[c]);
        }
    }
    /// Fixes one component.
    pub fn fix_dof(&mut self, dof: usize, value_m: f64) {
        self.values.insert(dof, value_m);
    }
    /// Constrained dofs in increasing order.
    pub fn dofs(&self) -> Vec<usize> {
        self.values.keys().copied().collect()
    }
    /// Writes the prescribed values into `x`.
    pub fn apply(&self, x: &mut [Vector3<f64>]) {
        for (&d, &v) in &self.values {
            if d / 3 < x.len() {
                x[d / 3][d % 3] = v;
            }
        }
    }
}

/// Map between global dofs (3·node + axis) and free (unconstrained) dofs.
#[derive(Clone, Debug, PartialEq)]
pub struct DofMap {
    free_of_dof: Vec<u32>,
    dof_of_free: Vec<usize>,
}

impl DofMap {
    /// Free dofs = all dofs except `constrained`.
    pub fn new(num_nodes: usize, constrained: &[usize]) -> Result<Self, FemError> {
        let n = 3 * num_nodes;
        let mut fixed = vec![false; n];
        for &d in constrained {
            if d >= n {
                return Err(FemError::DofOutOfRange {
                    dof: d,
                    num_dofs: n,
                });
            }
            fixed[d] = true;
        }
        let mut free_of_dof = vec![NONE; n];
        let mut dof_of_free = Vec::with_capacity(n);
        for d in 0..n {
            if !fixed[d] {
                free_of_dof[d] = dof_of_free.len() as u32;
                dof_of_free.push(d);
            }
        }
        if dof_of_free.is_empty() {
            return Err(FemError::NoFreeDofs);
        }
        Ok(Self {
            free_of_dof,
            dof_of_free,
        })
    }
    /// Number of free dofs.
    pub fn num_free(&self) -> usize {
        self.dof_of_free.len()
    }
    /// Number of all dofs.
    pub fn num_dofs(&self) -> usize {
        self.free_of_dof.len()
    }
    /// Free index of a global dof, if free.
    pub fn free_index(&self, dof: usize) -> Option<usize> {
        self.free_of_dof
            .get(dof)
            .and_then(|&f| (f != NONE).then_some(f as usize))
    }
    /// Global dof of free index `f`.
    pub fn dof(&self, f: usize) -> usize {
        self.dof_of_free[f]
    }
    /// Gathers the free components of a node-vector field.
    pub fn gather(&self, v: &[Vector3<f64>]) -> Vec<f64> {
        self.dof_of_free.iter().map(|&d| v[d / 3][d % 3]).collect()
    }
    /// Adds a free-dof vector into a node-vector field (scaled by `s`).
    pub fn scatter_add(&self, free: &[f64], s: f64, v: &mut [Vector3<f64>]) {
        for (f, &d) in self.dof_of_free.iter().enumerate() {
            v[d / 3][d % 3] += s * free[f];
        }
    }
}

/// Reusable per-chunk buffers of [`SystemPattern::assemble_linearized`] (element forces and
/// matrices), kept by the solvers so that iterations do not reallocate them.
#[derive(Clone, Debug, Default)]
pub struct AssemblyScratch {
    forces: Vec<[Vector3<f64>; 4]>,
    matrices: Vec<Matrix12>,
}

/// Slot of the stored lower entry of free dofs (i, j), either order, in a lower-triangular CSC
/// pattern with sorted row indices (NONE outside the pattern).
fn lower_slot(symbolic: &SymbolicSparseColMat<usize>, i: usize, j: usize) -> u32 {
    let (r, c) = if i >= j { (i, j) } else { (j, i) };
    let cp = symbolic.col_ptr();
    let rows = &symbolic.row_idx()[cp[c]..cp[c + 1]];
    match rows.binary_search(&r) {
        Ok(k) => (cp[c] + k) as u32,
        Err(_) => NONE,
    }
}

/// Lower-triangular CSC pattern of the reduced stiffness matrix with element scatter maps.
#[derive(Clone, Debug)]
pub struct SystemPattern {
    dofs: DofMap,
    symbolic: SymbolicSparseColMat<usize>,
    /// Element scatter map, compacted: the entries of element e are
    /// `element_offsets[e] .. element_offsets[e + 1]` of `element_slots` (slot in the value array)
    /// and `element_local` (column-major index i + 12 j of the local entry (i, j) of the 12×12
    /// element matrix); only the local entries that land in the stored lower triangle are listed,
    /// each global entry once per element.
    element_offsets: Vec<usize>,
    element_slots: Vec<u32>,
    element_local: Vec<u8>,
    /// per node: slots of its 3×3 diagonal block (NONE where constrained).
    node_slots: Vec<[u32; 9]>,
}

impl SystemPattern {
    /// Builds the pattern of the free-dof system of a mesh with `tets` over `num_nodes` nodes.
    pub fn new(num_nodes: usize, tets: &[[usize; 4]], dofs: DofMap) -> Result<Self, FemError> {
        let mut nbrs: Vec<Vec<usize>> = (0..num_nodes).map(|i| vec![i]).collect();
        for (t, tet) in tets.iter().enumerate() {
            for &a in tet {
                if a >= num_nodes {
                    return Err(FemError::VertexOutOfRange {
                        tet: t,
                        vertex: a,
                        num_vertices: num_nodes,
                    });
                }
                for &b in tet {
                    nbrs[a].push(b);
                }
            }
        }
        for n in &mut nbrs {
            n.sort_unstable();
            n.dedup();
        }
        let nf = dofs.num_free();
        let mut col_ptr = Vec::with_capacity(nf + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0usize);
        for j in 0..nf {
            let node = dofs.dof(j) / 3;
            for &m in &nbrs[node] {
                for c in 0..3 {
                    if let Some(i) = dofs.free_index(3 * m + c)
                        && i >= j
                    {
                        row_idx.push(i);
                    }
                }
            }
            col_ptr.push(row_idx.len());
        }
        let symbolic = SymbolicSparseColMat::new_checked(nf, nf, col_ptr, None, row_idx);
        let slot = |i: usize, j: usize| lower_slot(&symbolic, i, j);
        let mut element_offsets = Vec::with_capacity(tets.len() + 1);
        let mut element_slots = Vec::with_capacity(78 * tets.len());
        let mut element_local = Vec::with_capacity(78 * tets.len());
        element_offsets.push(0);
        for tet in tets {
            for li in 0..12 {
                let Some(fi) = dofs.free_index(3 * tet[li / 3] + li % 3) else {
                    continue;
                };
                for lj in 0..12 {
                    let Some(fj) = dofs.free_index(3 * tet[lj / 3] + lj % 3) else {
                        continue;
                    };
                    // Store each global lower entry once: local (li, lj) with fi ≥ fj.
                    if fi >= fj {
                        let k = slot(fi, fj);
                        if k != NONE {
                            element_slots.push(k);
                            element_local.push((li + 12 * lj) as u8);
                        }
                    }
                }
            }
            element_offsets.push(element_slots.len());
        }
        let mut node_slots = Vec::with_capacity(num_nodes);
        for n in 0..num_nodes {
            let mut s = [NONE; 9];
            for a in 0..3 {
                for b in 0..3 {
                    if let (Some(fi), Some(fj)) =
                        (dofs.free_index(3 * n + a), dofs.free_index(3 * n + b))
                        && fi >= fj
                    {
                        s[a * 3 + b] = slot(fi, fj);
                    }
                }
            }
            node_slots.push(s);
        }
        Ok(Self {
            dofs,
            symbolic,
            element_offsets,
            element_slots,
            element_local,
            node_slots,
        })
    }

    /// The dof map.
    pub fn dofs(&self) -> &DofMap {
        &self.dofs
    }

    /// Number of stored (lower) nonzeros.
    pub fn nnz(&self) -> usize {
        self.symbolic.row_idx().len()
    }

    /// A zeroed value array for this pattern.
    pub fn zeros(&self) -> Vec<f64> {
        vec![0.0; self.nnz()]
    }

    /// Scatter-adds one element matrix.
    pub fn add_element(&self, e: usize, k: &Matrix12, values: &mut [f64]) {
        self.add_element_scaled(e, k, 1.0, values);
    }

    /// Scatter-adds `scale` × one element matrix, each entry scaled as it is added (the same
    /// products as scattering a scaled copy, without forming it).
    pub fn add_element_scaled(&self, e: usize, k: &Matrix12, scale: f64, values: &mut [f64]) {
        let range = self.element_offsets[e]..self.element_offsets[e + 1];
        let k = k.as_slice();
        for (&slot, &local) in self.element_slots[range.clone()]
            .iter()
            .zip(&self.element_local[range])
        {
            values[slot as usize] += k[local as usize] * scale;
        }
    }

    /// Scatter-adds the *transpose* of one element matrix: with [`Self::add_element`] into a second
    /// value array this stores the strictly upper triangle of a non-symmetric system matrix in the
    /// lower-triangle layout (`upper[slot of (i, j)] = A_ji`, i ≥ j), see [`SparseCholesky::factor_general`].
    pub fn add_element_transposed(&self, e: usize, k: &Matrix12, upper: &mut [f64]) {
        let range = self.element_offsets[e]..self.element_offsets[e + 1];
        let k = k.as_slice();
        for (&slot, &local) in self.element_slots[range.clone()]
            .iter()
            .zip(&self.element_local[range])
        {
            // local = li + 12 lj (column-major); the transposed entry is lj + 12 li.
            let (li, lj) = (local as usize % 12, local as usize / 12);
            upper[slot as usize] += k[lj + 12 * li];
        }
    }

    /// Adds a symmetric 3×3 block to the diagonal block of `node` (contact springs).
    pub fn add_node_block(&self, node: usize, m: &Matrix3<f64>, values: &mut [f64]) {
        let s = &self.node_slots[node];
        for a in 0..3 {
            for b in 0..3 {
                let slot = s[a * 3 + b];
                if slot != NONE {
                    values[slot as usize] += m[(a, b)];
                }
            }
        }
    }

    /// Adds the off-diagonal block pair of two distinct nodes a ≠ b of a symmetric coupling: `m` is
    /// the block A_ab (rows of a's dofs, columns of b's) and A_ba = mᵀ is implied, so each stored
    /// lower entry receives its one value. Serves the symmetric and the transposed (`upper`)
    /// value arrays of [`SparseCholesky::factor_general`] alike (for a symmetric coupling both get
    /// the same entries). Constrained dofs are skipped; a free pair outside the pattern (nodes
    /// that share no element) is a broken invariant of the caller (debug assertion), its entries
    /// are dropped in release builds.
    pub fn add_pair_block(&self, a: usize, b: usize, m: &Matrix3<f64>, values: &mut [f64]) {
        debug_assert_ne!(a, b, "add_pair_block of a node with itself");
        for r in 0..3 {
            let Some(fi) = self.dofs.free_index(3 * a + r) else {
                continue;
            };
            for c in 0..3 {
                let Some(fj) = self.dofs.free_index(3 * b + c) else {
                    continue;
                };
                let slot = self.slot(fi, fj);
                debug_assert!(slot != NONE, "nodes {a}, {b} share no element");
                if slot != NONE {
                    values[slot as usize] += m[(r, c)];
                }
            }
        }
    }

    /// Slot of the stored lower entry of free dofs (i, j) in either order (NONE outside the
    /// pattern).
    fn slot(&self, i: usize, j: usize) -> u32 {
        lower_slot(&self.symbolic, i, j)
    }

    /// Diagonal entries of `node`'s free dofs (NaN where constrained).
    pub fn node_diagonal(&self, node: usize, values: &[f64]) -> Vector3<f64> {
        let s = &self.node_slots[node];
        Vector3::from_fn(|a, _| {
            let slot = s[a * 4];
            if slot == NONE {
                f64::NAN
            } else {
                values[slot as usize]
            }
        })
    }

    /// Mean |diagonal| of `node`'s free dofs in `values` (0 if the node is fully constrained): the
    /// scale of contact penalties and node-level terms (see [`crate::contact`]).
    pub fn node_stiffness(&self, node: usize, values: &[f64]) -> f64 {
        let d = self.node_diagonal(node, values);
        let (s, k) = d
            .iter()
            .filter(|v| v.is_finite())
            .fold((0.0, 0), |(s, k), v| (s + v.abs(), k + 1));
        if k > 0 { s / k as f64 } else { 0.0 }
    }

    /// Assembles Σ_e (element matrix) over all elements of `model` at `x` into a fresh value array.
    pub fn assemble<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
    ) -> Vec<f64> {
        let mut values = self.zeros();
        for e in 0..model.elements().len() {
            let k = model.element_matrix(e, x, kind);
            self.add_element(e, &k, &mut values);
        }
        values
    }

    /// One pass over the elements of `model` at `x` (chunks of elements evaluated by
    /// [`ElasticModel::linearize_elements`], possibly in parallel, then scattered serially in
    /// element order): the system matrix Σ_e (element matrix) into `values` (overwritten, pattern
    /// order) and f_int(x) into `f_int` (overwritten, one per node). Returns the model energy if
    /// the pass produced it. The same bits as [`Self::assemble`] + [`ElasticModel::internal_forces`].
    /// With `upper` (a model whose element matrices are not symmetric,
    /// [`ElasticModel::tangent_is_symmetric`]) the transposed element matrices are scattered into
    /// it as well ([`Self::add_element_transposed`]): `values` and `upper` together hold the whole
    /// matrix for [`SparseCholesky::factor_general`].
    #[allow(clippy::too_many_arguments)]
    pub fn assemble_linearized<M: ElasticModel + ?Sized>(
        &self,
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        scratch: &mut AssemblyScratch,
        values: &mut Vec<f64>,
        mut upper: Option<&mut Vec<f64>>,
        f_int: &mut Vec<Vector3<f64>>,
    ) -> Option<f64> {
        let n = model.elements().len();
        values.clear();
        values.resize(self.nnz(), 0.0);
        if let Some(u) = upper.as_deref_mut() {
            u.clear();
            u.resize(self.nnz(), 0.0);
        }
        f_int.clear();
        f_int.resize(model.num_nodes(), Vector3::zeros());
        let chunk = crate::model::ELEMENT_CHUNK.min(n.max(1));
        scratch.forces.resize(chunk, [Vector3::zeros(); 4]);
        scratch.matrices.resize(chunk, Matrix12::zeros());
        let mut energy = Some(0.0);
        for start in (0..n).step_by(chunk) {
            let len = chunk.min(n - start);
            let forces = &mut scratch.forces[..len];
            let matrices = &mut scratch.matrices[..len];
            let e = model.linearize_elements(start, x, kind, forces, matrices);
            energy = energy.zip(e).map(|(a, b)| a + b);
            let geoms = &model.elements()[start..start + len];
            for (k, g) in geoms.iter().enumerate() {
                self.add_element(start + k, &matrices[k], values);
                if let Some(u) = upper.as_deref_mut() {
                    self.add_element_transposed(start + k, &matrices[k], u);
                }
                for a in 0..4 {
                    f_int[g.nodes[a]] += forces[k][a];
                }
            }
        }
        energy
    }

    /// faer view of the lower triangle with the given values.
    pub fn matrix<'a>(&'a self, values: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        SparseColMatRef::new(self.symbolic.as_ref(), values)
    }

    /// y = A x for the symmetric matrix stored by its lower triangle (free-dof vectors).
    pub fn mul_vec(&self, values: &[f64], x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; x.len()];
        let cp = self.symbolic.col_ptr();
        let ri = self.symbolic.row_idx();
        for j in 0..x.len() {
            for k in cp[j]..cp[j + 1] {
                let i = ri[k];
                y[i] += values[k] * x[j];
                if i != j {
                    y[j] += values[k] * x[i];
                }
            }
        }
        y
    }
}

/// What every solver builds once per (mesh, constraint set): the free-dof pattern with its
/// scatter maps, the symbolic Cholesky factorization, and the length scale of the convergence
/// test (diagonal of the rest bounding box \[m\]).
pub fn solver_setup<M: ElasticModel + ?Sized>(
    model: &M,
    constrained_dofs: &[usize],
) -> Result<(SystemPattern, SparseCholesky, f64), FemError> {
    let n = model.num_nodes();
    let dofs = DofMap::new(n, constrained_dofs)?;
    let tets: Vec<[usize; 4]> = model.elements().iter().map(|g| g.nodes).collect();
    let pattern = SystemPattern::new(n, &tets, dofs)?;
    let cholesky = SparseCholesky::new(&pattern)?;
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in model.rest_positions() {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    Ok((pattern, cholesky, (hi - lo).norm().max(f64::MIN_POSITIVE)))
}

/// [`solver_setup`] for 10-node tets (`elements`: corners, then edge midpoints) on the nodes
/// `rest`: a 10-node clique's pattern is covered by ten 4-node "tets" — the nodes in five pairs,
/// every two pairs together (each node pair shares at least one of them).
pub(crate) fn quadratic_solver_setup(
    elements: &[[usize; 10]],
    rest: &[Vector3<f64>],
    constrained_dofs: &[usize],
) -> Result<(SystemPattern, SparseCholesky, f64), FemError> {
    let n = rest.len();
    let cover: Vec<[usize; 4]> = elements
        .iter()
        .flat_map(|el| {
            let mut out = Vec::with_capacity(10);
            for p in 0..5 {
                for q in p + 1..5 {
                    out.push([el[2 * p], el[2 * p + 1], el[2 * q], el[2 * q + 1]]);
                }
            }
            out
        })
        .collect();
    let pattern = SystemPattern::new(n, &cover, DofMap::new(n, constrained_dofs)?)?;
    let cholesky = SparseCholesky::new(&pattern)?;
    let (lo, hi) = rest.iter().fold(
        (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        ),
        |(a, b), p| (a.inf(p), b.sup(p)),
    );
    Ok((pattern, cholesky, (hi - lo).norm().max(f64::MIN_POSITIVE)))
}

/// [`free_residual`] with the contact springs' forces at `x` as the boundary forces.
pub(crate) fn contact_residual(
    dofs: &DofMap,
    f_ext: &[Vector3<f64>],
    f_int: &[Vector3<f64>],
    x: &[Vector3<f64>],
    springs: &[crate::contact::ContactSpring],
) -> (Vec<f64>, f64) {
    let mut fc = Vec::new();
    if !springs.is_empty() {
        fc = vec![Vector3::zeros(); x.len()];
        for s in springs {
            fc[s.node] += s.force(&x[s.node]);
        }
    }
    free_residual(dofs, f_ext, f_int, &fc)
}

/// Free-dof residual r = (f_ext − f_int) + f_b (f_b: boundary forces such as contact, one per node
/// or empty) and its scale max(‖f_ext‖₂, ‖f_int‖₂, ‖f_b‖₂) for the relative tolerance of the
/// equilibrium iterations.
pub(crate) fn free_residual(
    dofs: &DofMap,
    f_ext: &[Vector3<f64>],
    f_int: &[Vector3<f64>],
    f_b: &[Vector3<f64>],
) -> (Vec<f64>, f64) {
    let r: Vec<Vector3<f64>> = if f_b.is_empty() {
        f_ext.iter().zip(f_int).map(|(e, i)| e - i).collect()
    } else {
        (0..f_int.len())
            .map(|i| (f_ext[i] - f_int[i]) + f_b[i])
            .collect()
    };
    let norm = |v: &[Vector3<f64>]| v.iter().map(|a| a.norm_squared()).sum::<f64>().sqrt();
    let scale = norm(f_ext).max(norm(f_int)).max(norm(f_b));
    (dofs.gather(&r), scale)
}

/// Which numeric factorization was used.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FactorKind {
    /// LLᵀ (matrix positive definite).
    Llt,
    /// LDLᵀ fallback (symmetric indefinite, e.g. a consistent tangent under compression).
    Ldlt,
    /// Sparse LU with partial pivoting of a non-symmetric matrix ([`SparseCholesky::factor_general`]:
    /// the exact tangent of a model whose forces are not the gradient of an energy).
    Lu,
}

/// The non-symmetric companion of [`SparseCholesky`]: the full (both triangles) structure of a
/// [`SystemPattern`], where each of its entries comes from, and faer's sparse LU (COLAMD column
/// ordering, partial pivoting). Built on the first non-symmetric factorization.
#[derive(Debug)]
struct GeneralLu {
    full: SymbolicSparseColMat<usize>,
    /// Per full entry: 2 × (slot in the lower-layout arrays) + 1 if it is read from the upper array.
    source: Vec<u32>,
    values: Vec<f64>,
    symbolic: SymbolicLu<usize>,
    numeric: NumericLu<usize, f64>,
}

impl GeneralLu {
    fn new(pattern: &SystemPattern) -> Result<Self, FemError> {
        let lower = &pattern.symbolic;
        let n = lower.ncols();
        let (cp, ri) = (lower.col_ptr(), lower.row_idx());
        // Column c of the full matrix: rows r < c are the transposed lower entries (c, r) (upper
        // array), rows r ≥ c the lower entries of column c. Both come out sorted by row.
        let mut upper_rows: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
        for j in 0..n {
            for (k, &i) in ri.iter().enumerate().take(cp[j + 1]).skip(cp[j]) {
                if i > j {
                    upper_rows[i].push((j, k));
                }
            }
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::with_capacity(2 * ri.len());
        let mut source = Vec::with_capacity(2 * ri.len());
        col_ptr.push(0usize);
        for (c, above) in upper_rows.iter().enumerate() {
            for &(r, k) in above {
                row_idx.push(r);
                source.push(2 * k as u32 + 1);
            }
            for (k, &r) in ri.iter().enumerate().take(cp[c + 1]).skip(cp[c]) {
                row_idx.push(r);
                source.push(2 * k as u32);
            }
            col_ptr.push(row_idx.len());
        }
        let full = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
        let symbolic = factorize_symbolic_lu(full.as_ref(), Default::default()).map_err(|e| {
            FemError::Factorization {
                reason: format!("symbolic LU: {e:?}"),
            }
        })?;
        Ok(Self {
            values: vec![0.0; source.len()],
            full,
            source,
            symbolic,
            numeric: NumericLu::new(),
        })
    }
}

/// Sparse Cholesky of a [`SystemPattern`]'s matrices: symbolic analysis once, numeric factorization
/// per matrix, any number of solves per factor.
#[derive(Debug)]
pub struct SparseCholesky {
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    kind: Option<FactorKind>,
    par: Par,
    /// The LU of [`Self::factor_general`] (built on first use).
    lu: Option<Box<GeneralLu>>,
}

impl SparseCholesky {
    /// Symbolic factorization (AMD fill-reducing ordering) of `pattern`.
    pub fn new(pattern: &SystemPattern) -> Result<Self, FemError> {
        let symbolic = factorize_symbolic_cholesky(
            pattern.symbolic.as_ref(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| FemError::Factorization {
            reason: format!("symbolic: {e:?}"),
        })?;
        let len = symbolic.len_val();
        Ok(Self {
            symbolic,
            l_values: vec![0.0; len],
            kind: None,
            par: Par::Seq,
            lu: None,
        })
    }

    /// Numeric factorization of the matrix A held as `lower` (its lower triangle, pattern order)
    /// and `upper` (`upper[slot of (i, j)] = A_ji`, [`SystemPattern::add_element_transposed`]).
    /// `upper = None` is the symmetric case, [`Self::factor`]. Otherwise A is factored by sparse LU
    /// with partial pivoting ([`FactorKind::Lu`]): a Newton step with the exact non-symmetric
    /// tangent of a non-conservative model (the anisotropic corotational element,
    /// [`crate::AnisotropicModel`]) needs A itself — a symmetric factorization of its lower
    /// triangle solves with a different matrix (the upper triangle replaced by the lower one's
    /// mirror), and Newton's iterations lose their convergence.
    pub fn factor_general(
        &mut self,
        pattern: &SystemPattern,
        lower: &[f64],
        upper: Option<&[f64]>,
    ) -> Result<FactorKind, FemError> {
        let Some(upper) = upper else {
            return self.factor(pattern, lower);
        };
        self.kind = None;
        if !lower.iter().chain(upper).all(|v| v.is_finite()) {
            return Err(FemError::NonFinite {
                what: "stiffness matrix",
            });
        }
        if self.lu.is_none() {
            self.lu = Some(Box::new(GeneralLu::new(pattern)?));
        }
        let Some(lu) = self.lu.as_deref_mut() else {
            unreachable!("set above");
        };
        for (v, &src) in lu.values.iter_mut().zip(&lu.source) {
            let slot = (src / 2) as usize;
            *v = if src % 2 == 1 {
                upper[slot]
            } else {
                lower[slot]
            };
        }
        let a = SparseColMatRef::new(lu.full.as_ref(), &lu.values);
        let req = lu
            .symbolic
            .factorize_numeric_lu_scratch::<f64>(self.par, Default::default());
        let mut buf = MemBuffer::new(req);
        lu.symbolic
            .factorize_numeric_lu(
                &mut lu.numeric,
                a,
                self.par,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .map_err(|e| FemError::Factorization {
                reason: format!("LU: {e:?}"),
            })?;
        self.kind = Some(FactorKind::Lu);
        Ok(FactorKind::Lu)
    }

    /// Numeric factorization of `values` (same pattern): LLᵀ, falling back to LDLᵀ if the matrix is
    /// not positive definite.
    pub fn factor(
        &mut self,
        pattern: &SystemPattern,
        values: &[f64],
    ) -> Result<FactorKind, FemError> {
        if !values.iter().all(|v| v.is_finite()) {
            self.kind = None;
            return Err(FemError::NonFinite {
                what: "stiffness matrix",
            });
        }
        let a = pattern.matrix(values);
        let req = self
            .symbolic
            .factorize_numeric_llt_scratch::<f64>(self.par, Default::default())
            .or(self
                .symbolic
                .factorize_numeric_ldlt_scratch::<f64>(self.par, Default::default()));
        let mut buf = MemBuffer::new(req);
        let llt = self.symbolic.factorize_numeric_llt::<f64>(
            &mut self.l_values,
            a,
            Side::Lower,
            Default::default(),
            self.par,
            MemStack::new(&mut buf),
            Default::default(),
        );
        if llt.is_ok() {
            self.kind = Some(FactorKind::Llt);
            return Ok(FactorKind::Llt);
        }
        let ldlt = self
            .symbolic
            .factorize_numeric_ldlt::<f64>(
                &mut self.l_values,
                a,
                Side::Lower,
                Default::default(),
                self.par,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .map(|_| ());
        match ldlt {
            Ok(()) if self.l_values.iter().all(|v| v.is_finite()) => {
                self.kind = Some(FactorKind::Ldlt);
                Ok(FactorKind::Ldlt)
            }
            Ok(()) => {
                self.kind = None;
                Err(FemError::Factorization {
                    reason: "LDLT produced non-finite values".into(),
                })
            }
            Err(e) => {
                self.kind = None;
                Err(FemError::Factorization {
                    reason: format!("{e:?}"),
                })
            }
        }
    }

    /// Kind of the current numeric factor (None before a successful [`Self::factor`]).
    pub fn kind(&self) -> Option<FactorKind> {
        self.kind
    }

    /// Solves A X = B in place for a column-major block of right-hand sides (`rhs.len()` a
    /// multiple of n).
    pub fn solve_in_place(&self, rhs: &mut [f64]) -> Result<(), FemError> {
        let n = self.symbolic.nrows();
        if n == 0 || !rhs.len().is_multiple_of(n) {
            return Err(FemError::LengthMismatch {
                what: "right-hand side",
                expected: n,
                got: rhs.len(),
            });
        }
        let k = rhs.len() / n;
        let Some(kind) = self.kind else {
            return Err(FemError::Factorization {
                reason: "solve before a successful factorization".into(),
            });
        };
        let mat = MatMut::from_column_major_slice_mut(rhs, n, k);
        if kind == FactorKind::Lu {
            let Some(lu) = self.lu.as_deref() else {
                return Err(FemError::Factorization {
                    reason: "LU solve without an LU factor".into(),
                });
            };
            let mut buf = MemBuffer::new(lu.symbolic.solve_in_place_scratch::<f64>(k, self.par));
            LuRef::new_unchecked(&lu.symbolic, &lu.numeric).solve_in_place_with_conj(
                Conj::No,
                mat,
                self.par,
                MemStack::new(&mut buf),
            );
            return Ok(());
        }
        let mut buf = MemBuffer::new(self.symbolic.solve_in_place_scratch::<f64>(k, self.par));
        let stack = MemStack::new(&mut buf);
        match kind {
            FactorKind::Llt => LltRef::new(&self.symbolic, &self.l_values)
                .solve_in_place_with_conj(Conj::No, mat, self.par, stack),
            FactorKind::Ldlt => LdltRef::new(&self.symbolic, &self.l_values)
                .solve_in_place_with_conj(Conj::No, mat, self.par, stack),
            FactorKind::Lu => unreachable!("handled above"),
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{CorotationalModel, LinearParams};

    /// (Σ_e element matrix of `model` at `x`) · v over the free dofs, element by element (the
    /// reference every assembled matrix is checked against).
    fn element_sum_times<M: ElasticModel>(
        model: &M,
        x: &[Vector3<f64>],
        kind: StiffnessKind,
        dofs: &DofMap,
        v: &[f64],
    ) -> Vec<f64> {
        let mut full = vec![Vector3::zeros(); x.len()];
        dofs.scatter_add(v, 1.0, &mut full);
        let mut out = vec![Vector3::zeros(); x.len()];
        for (e, g) in model.elements().iter().enumerate() {
            let k = model.element_matrix(e, x, kind);
            let mut ue = nalgebra::SVector::<f64, 12>::zeros();
            for a in 0..4 {
                ue.fixed_rows_mut::<3>(3 * a).copy_from(&full[g.nodes[a]]);
            }
            let fe = k * ue;
            for a in 0..4 {
                out[g.nodes[a]] += fe.fixed_rows::<3>(3 * a);
            }
        }
        dofs.gather(&out)
    }

    /// The compact element scatter map adds exactly the stored lower-triangle entries: the
    /// assembled matrix times a vector equals the sum of the element matrices times it.
    #[test]
    fn compact_scatter_assembles_the_element_sum() {
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.02, 0.02], [3, 2, 2]);
        let model = CorotationalModel::homogeneous(
            &mesh,
            LinearParams::from_young_poisson(5e4, 0.4).expect("valid"),
        )
        .expect("valid mesh");
        let fixed: Vec<usize> = vec![0, 1, 2, 7, 3 * 5 + 2];
        let (pattern, _, _) = solver_setup(&model, &fixed).expect("setup");
        let x: Vec<Vector3<f64>> = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| v + Vector3::new(1e-3 * (i as f64).sin(), 0.0, 2e-3 * v.x))
            .collect();
        let values = pattern.assemble(&model, &x, StiffnessKind::Warped);
        let dofs = pattern.dofs();
        let v: Vec<f64> = (0..dofs.num_free())
            .map(|i| (i as f64 * 0.37).cos())
            .collect();
        let y = pattern.mul_vec(&values, &v);
        let reference = element_sum_times(&model, &x, StiffnessKind::Warped, dofs, &v);
        let scale = reference.iter().fold(0.0f64, |m, r| m.max(r.abs()));
        for (a, b) in y.iter().zip(&reference) {
            assert!((a - b).abs() <= 1e-12 * scale, "{a} vs {b}");
        }
    }

    /// The two value arrays of a non-symmetric assembly (`add_element` + `add_element_transposed`)
    /// hold the whole matrix, and its LU solves it: A (A⁻¹ b) = b with A = Σ_e (element matrix),
    /// here the exact tangent of an anisotropic corotational model (not symmetric).
    #[test]
    fn general_lu_solves_the_unsymmetric_element_sum() {
        use crate::{AnisotropicModel, TransverselyIsotropicParams};
        let mesh = softcap_mesh::box_tet_mesh([0.0; 3], [0.03, 0.02, 0.02], [3, 2, 2]);
        let p =
            TransverselyIsotropicParams::from_engineering(2e4, 2e5, 0.4, 0.1, 7e3).expect("valid");
        let fibre = nalgebra::Unit::new_normalize(Vector3::new(1.0, 0.3, 1.0));
        let model = AnisotropicModel::homogeneous(&mesh, p, fibre).expect("valid mesh");
        let fixed: Vec<usize> = (0..mesh.vertices.len())
            .filter(|&i| mesh.vertices[i].z < 1e-12)
            .flat_map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let (pattern, mut factor, _) = solver_setup(&model, &fixed).expect("setup");
        let x: Vec<Vector3<f64>> = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, v)| v + Vector3::new(1e-3 * (i as f64).sin(), 5e-4 * v.z, 2e-3 * v.x))
            .collect();
        let (mut lower, mut upper, mut f_int) = (Vec::new(), Vec::new(), Vec::new());
        pattern.assemble_linearized(
            &model,
            &x,
            StiffnessKind::Consistent,
            &mut AssemblyScratch::default(),
            &mut lower,
            Some(&mut upper),
            &mut f_int,
        );
        assert!(
            lower
                .iter()
                .zip(&upper)
                .any(|(a, b)| (a - b).abs() > 1e-6 * a.abs()),
            "the tangent should not be symmetric"
        );
        let kind = factor
            .factor_general(&pattern, &lower, Some(&upper))
            .expect("LU");
        assert_eq!(kind, FactorKind::Lu);
        let dofs = pattern.dofs();
        let b: Vec<f64> = (0..dofs.num_free())
            .map(|i| (i as f64 * 0.37).cos())
            .collect();
        let mut v = b.clone();
        factor.solve_in_place(&mut v).expect("solve");
        let av = element_sum_times(&model, &x, StiffnessKind::Consistent, dofs, &v);
        let worst = av
            .iter()
            .zip(&b)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-9, "max |A A⁻¹b − b| = {worst:e}");
        // The symmetric factor of the lower triangle alone solves another matrix.
        factor.factor(&pattern, &lower).expect("symmetric factor");
        let mut w = b.clone();
        factor.solve_in_place(&mut w).expect("solve");
        let diff = w
            .iter()
            .zip(&v)
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(diff > 1e-3 * v.iter().fold(0.0f64, |m, a| m.max(a.abs())));
    }
}
