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
use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, SparseColMatRef, Triplet};
use faer::{Mat, Side};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

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
    /// The free-vertex system is not numerically positive definite.
    #[error("sparse Cholesky of the free-vertex system failed: {reason}")]
    Factorization {
        /// faer's message
        reason: String,
    },
}

/// Stiffnesses of the linear shell (thesis eq. 3.2 / 5.1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
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
    llt: faer::sparse::linalg::solvers::Llt<usize, f64>,
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
    pub fn new(
        laplacian: SparseColMatRef<'_, usize, f64>,
        vertex_areas: &[f64],
        handles: &[usize],
        settings: &ShellSettings,
    ) -> Result<Self, ShellError> {
        let n = vertex_areas.len();
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

        // A = −k_s L + k_b Σ_k L_ik L_kj / m_k, accumulated row by row.
        let mut a_rows: Vec<BTreeMap<usize, f64>> = vec![BTreeMap::new(); n];
        for i in 0..n {
            let acc = &mut a_rows[i];
            for &(k, l_ik) in &rows[i] {
                *acc.entry(k).or_insert(0.0) -= k_s * l_ik;
                if k_b != 0.0 {
                    let s = k_b * l_ik / vertex_areas[k];
                    for &(j, l_kj) in &rows[k] {
                        *acc.entry(j).or_insert(0.0) += s * l_kj;
                    }
                }
            }
        }

        let nf = free.len();
        let mut ff = Vec::new();
        let mut a_fh = Vec::new();
        let mut handle_col = vec![usize::MAX; n];
        for (c, &v) in handles.iter().enumerate() {
            handle_col[v] = c;
        }
        for (fi, &v) in free.iter().enumerate() {
            for (&j, &val) in &a_rows[v] {
                let fj = free_index[j];
                if fj == usize::MAX {
                    a_fh.push((fi, handle_col[j], val));
                } else if fj <= fi {
                    // lower triangle (row ≥ column) of the symmetric A_FF
                    ff.push(Triplet::new(fi, fj, val));
                }
            }
        }
        a_fh.sort_by_key(|&(r, c, _)| (c, r));
        let a_ff = SparseColMat::<usize, f64>::try_new_from_triplets(nf, nf, &ff).map_err(|e| {
            ShellError::Factorization {
                reason: format!("{e:?}"),
            }
        })?;
        let llt = a_ff
            .sp_cholesky(Side::Lower)
            .map_err(|e| ShellError::Factorization {
                reason: format!("{e:?}"),
            })?;
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
    /// ([`crate::laplacian`], thesis eq. 3.4–3.5).
    pub fn from_mesh(
        mesh: &TriMesh,
        handles: &[usize],
        settings: &ShellSettings,
    ) -> Result<Self, ShellError> {
        let lap = crate::laplacian::cotan_laplacian(mesh);
        let areas = crate::laplacian::voronoi_areas(mesh);
        Self::new(lap.as_ref(), &areas, handles, settings)
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
    /// column blocks so peak memory stays at `n_free × 16` doubles; handle rows are unit vectors.
    pub fn basis(&self) -> ShellBasis {
        let h = self.handles.len();
        let mut weights = vec![0.0f32; self.n * h];
        for (c, &v) in self.handles.iter().enumerate() {
            weights[v * h + c] = 1.0;
        }
        const COLS: usize = 16;
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
            self.llt.solve_in_place(rhs.as_mut());
            for (fi, &v) in self.free.iter().enumerate() {
                for c in start..end {
                    weights[v * h + c] = rhs[(fi, c - start)] as f32;
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

    /// Whether vertex `v` is a handle.
    pub fn is_handle(&self, v: usize) -> bool {
        self.free_index[v] == usize::MAX
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
