//! Cotangent Laplacian (thesis eq. 3.4–3.5): null space, symmetry, sign, sphere convergence;
//! bi-Laplacian; umbrella graph Laplacian (bickel2009 eq. 9).

use faer::sparse::SparseColMat;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_mesh::nalgebra::{DMatrix, Vector3};
use softcap_mesh::*;
use std::path::Path;

fn dense(a: &SparseColMat<usize, f64>) -> DMatrix<f64> {
    let mut d = DMatrix::zeros(a.nrows(), a.ncols());
    let r = a.as_ref();
    let sym = r.symbolic();
    for j in 0..a.ncols() {
        for k in sym.col_range(j) {
            d[(sym.row_idx()[k], j)] += r.val()[k];
        }
    }
    d
}

fn ict_face() -> TriMesh {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/ict-face/neutral.obj");
    read_obj_tri_mesh(p).unwrap()
}

/// Icosphere with jittered vertices (still on the sphere), so angles are irregular.
fn jittered_sphere(level: u32, seed: u64) -> TriMesh {
    let mut m = icosphere(level);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for v in &mut m.vertices {
        let d = Vector3::new(
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
            rng.random_range(-0.1..0.1),
        );
        *v = (*v + d * 0.5f64.powi(level as i32)).normalize();
    }
    m
}

#[test]
fn annihilates_constants_and_is_symmetric_on_ict_face() {
    let face = ict_face();
    let lap = CotanLaplacian::new(&face).unwrap();
    let ones = vec![1.0; face.vertices.len()];
    let l1 = sparse_mul_vec(lap.stiffness.as_ref(), &ones);
    let scale = lap
        .stiffness
        .as_ref()
        .val()
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let worst = l1.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        worst <= 1e-12 * scale,
        "max |L·1| = {worst:e} (max |L_ij| = {scale:e})"
    );
    // Areas sum to the surface area.
    let total: f64 = lap.areas.iter().sum();
    assert!((total - face.area()).abs() < 1e-10 * face.area());
    // Symmetry entry by entry: L − Lᵀ via quadratic forms xᵀLy = yᵀLx for random x, y, and
    // negative semidefiniteness xᵀLx ≤ 0.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = face.vertices.len();
    for _ in 0..20 {
        let x: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let y: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let lx = sparse_mul_vec(lap.stiffness.as_ref(), &x);
        let ly = sparse_mul_vec(lap.stiffness.as_ref(), &y);
        let xlx: f64 = x.iter().zip(&lx).map(|(a, b)| a * b).sum();
        let ylx: f64 = y.iter().zip(&lx).map(|(a, b)| a * b).sum();
        let xly: f64 = x.iter().zip(&ly).map(|(a, b)| a * b).sum();
        assert!(xlx < 0.0, "xᵀLx = {xlx}");
        assert!((ylx - xly).abs() <= 1e-12 * xlx.abs(), "{ylx} vs {xly}");
    }
}

#[test]
fn dense_spectrum_is_nonpositive_with_one_zero() {
    let m = jittered_sphere(1, 3); // 42 vertices
    let lap = CotanLaplacian::new(&m).unwrap();
    let l = dense(&lap.stiffness);
    assert!((&l - l.transpose()).amax() < 1e-14);
    let eig = l.clone().symmetric_eigenvalues();
    let max = eig.max();
    let min = eig.min();
    assert!(max.abs() < 1e-12 * min.abs(), "largest eigenvalue {max:e}");
    let near_zero = eig.iter().filter(|e| e.abs() < 1e-9).count();
    assert_eq!(
        near_zero, 1,
        "connected mesh: one constant mode; spectrum {eig}"
    );
    // Generalised problem L u = λ M u on the sphere: the first nonzero eigenvalues
    // approximate −l(l+1) = −2 (three of them).
    let minv_sqrt = DMatrix::from_diagonal(
        &lap.areas
            .iter()
            .map(|a| 1.0 / a.sqrt())
            .collect::<Vec<_>>()
            .into(),
    );
    let mut g: Vec<f64> = (&minv_sqrt * &l * &minv_sqrt)
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .collect();
    g.sort_by(|a, b| b.total_cmp(a));
    for e in &g[1..4] {
        assert!((e + 2.0).abs() < 0.1, "{e}");
    }
    // Normalised operator and bi-Laplacian agree with the dense products.
    let minv =
        DMatrix::from_diagonal(&lap.areas.iter().map(|a| 1.0 / a).collect::<Vec<_>>().into());
    assert!((dense(&lap.normalized()) - &minv * &l).amax() < 1e-10);
    let bl = dense(&lap.bilaplacian());
    assert!((&bl - &l * &minv * &l).amax() < 1e-9 * bl.amax());
    assert!(bl.symmetric_eigenvalues().min() > -1e-9 * bl.amax());
    assert!((dense(&lap.mass()) - DMatrix::from_diagonal(&lap.areas.clone().into())).amax() == 0.0);
}

/// Solves `(M − L) u = 7 M Y`, the discrete `(I − Δ_S) u = 7Y` whose exact solution is `Y`.
fn poisson_error(lap: &CotanLaplacian, f: &[f64]) -> f64 {
    use faer::linalg::solvers::Solve;
    let n = f.len();
    let a = &lap.mass() - &lap.stiffness;
    let llt = a.sp_cholesky(faer::Side::Lower).expect("M − L is SPD");
    let mut rhs = faer::Mat::<f64>::from_fn(n, 1, |i, _| 7.0 * lap.areas[i] * f[i]);
    llt.solve_in_place(rhs.as_mut());
    (0..n)
        .map(|i| (rhs[(i, 0)] - f[i]).abs())
        .fold(0.0, f64::max)
}

/// Δ_S Y = −l(l+1) Y for the degree-2 harmonic Y = xy on the refined unit icosphere.
///
/// Three measures (committed reference values in docs/validation.md):
/// - pointwise `max_i |(M⁻¹LY)_i + 6Y_i|`: does NOT converge — at the 12 valence-5 vertices the
///   cotangent operator has an O(1) consistency error (a known property; Xu 2004, Wardetzky et
///   al. 2007); asserted only to stay below 0.1;
/// - area-weighted relative L2 error of `M⁻¹LY + 6Y`: converges at rate ≥ 1 (the bad set shrinks);
/// - the Poisson solution `(M − L)u = 7MY` converges to `Y` in max norm at rate ≈ 2 (weak
///   convergence of the operator, which is what solvers built on it see).
#[test]
fn converges_to_spherical_harmonic_on_refined_sphere() {
    println!("Cotangent Laplacian, unit icosphere, Y = xy (l = 2, Δ_S Y = −6Y)");
    println!(
        "| level | #verts | h (max edge) | max pointwise error | rel. L2 error | L2 rate | max error of Poisson solve | Poisson rate |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut prev: Option<(f64, f64, f64)> = None;
    let mut rates = Vec::new();
    let mut last = (0.0, 0.0, 0.0);
    for level in 1..=6 {
        let m = icosphere(level);
        let lap = CotanLaplacian::new(&m).unwrap();
        let f: Vec<f64> = m.vertices.iter().map(|v| v.x * v.y).collect();
        let df = lap.apply(&f);
        let err: Vec<f64> = df.iter().zip(&f).map(|(d, f)| d + 6.0 * f).collect();
        let max = err.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        let l2 = (err
            .iter()
            .zip(&lap.areas)
            .map(|(e, a)| a * e * e)
            .sum::<f64>()
            / f.iter()
                .zip(&lap.areas)
                .map(|(f, a)| a * 36.0 * f * f)
                .sum::<f64>())
        .sqrt();
        let poisson = poisson_error(&lap, &f);
        let h = m
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .map(|(a, b)| (m.vertices[a] - m.vertices[b]).norm())
            .fold(0.0, f64::max);
        let (rl, rp) = match prev {
            Some((ph, pl, pp)) => (
                (pl / l2).ln() / (ph / h).ln(),
                (pp / poisson).ln() / (ph / h).ln(),
            ),
            None => (f64::NAN, f64::NAN),
        };
        println!(
            "| {level} | {} | {h:.4} | {max:.3e} | {l2:.3e} | {rl:.2} | {poisson:.3e} | {rp:.2} |",
            m.vertices.len()
        );
        if prev.is_some() {
            rates.push((rl, rp));
        }
        prev = Some((h, l2, poisson));
        last = (max, l2, poisson);
        assert!(max < 0.25, "pointwise error {max}");
    }
    for (rl, rp) in &rates {
        assert!(*rl > 1.0, "L2 rate {rl}");
        assert!(*rp > 1.8, "Poisson rate {rp}");
    }
    assert!(last.1 < 1.5e-3 && last.2 < 1e-4, "{last:?}");
}

#[test]
fn bilaplacian_matches_squared_eigenvalue_on_sphere() {
    // Rayleigh quotient Yᵀ(L M⁻¹ L)Y / YᵀMY ≈ (l(l+1))² = 36, converging under refinement.
    let mut errs = Vec::new();
    for level in [3, 4, 5] {
        let m = icosphere(level);
        let lap = CotanLaplacian::new(&m).unwrap();
        let f: Vec<f64> = m.vertices.iter().map(|v| v.x * v.y).collect();
        let bf = sparse_mul_vec(lap.bilaplacian().as_ref(), &f);
        let num: f64 = f.iter().zip(&bf).map(|(a, b)| a * b).sum();
        let den: f64 = f.iter().zip(&lap.areas).map(|(a, m)| a * a * m).sum();
        errs.push((num / den - 36.0).abs() / 36.0);
    }
    println!("bi-Laplacian Rayleigh quotient relative errors (levels 3,4,5): {errs:?}");
    assert!(errs[2] < errs[1] && errs[1] < errs[0], "{errs:?}");
    assert!(errs[2] < 5e-3, "{errs:?}");
}

#[test]
fn umbrella_laplacian_on_tet_adjacency() {
    let mesh = box_tet_mesh([0.0; 3], [1.0; 3], [3, 2, 2]);
    for adj in [
        tet_vertex_adjacency(mesh.vertices.len(), &mesh.tets),
        tet_face_adjacency(&mesh.tets),
    ] {
        let l = umbrella_laplacian(&adj);
        let d = dense(&l);
        assert!((&d - d.transpose()).amax() == 0.0);
        let ones = vec![1.0; adj.len()];
        assert!(sparse_mul_vec(l.as_ref(), &ones).iter().all(|v| *v == 0.0));
        // (Lp)_i = Σ_j (p_i − p_j).
        let p: Vec<f64> = (0..adj.len()).map(|i| (i as f64 * 0.37).sin()).collect();
        let lp = sparse_mul_vec(l.as_ref(), &p);
        for (i, nb) in adj.iter().enumerate() {
            let expect: f64 = nb.iter().map(|&j| p[i] - p[j]).sum();
            assert!((lp[i] - expect).abs() < 1e-12, "{} vs {expect}", lp[i]);
        }
        assert!(d.symmetric_eigenvalues().min() > -1e-10);
    }
}

#[test]
fn unused_vertex_has_no_area() {
    let mut m = icosphere(0);
    m.vertices.push(Vector3::new(3.0, 0.0, 0.0));
    assert!(matches!(
        CotanLaplacian::new(&m),
        Err(MeshError::UnusedVertex { vertex: 12 })
    ));
}
