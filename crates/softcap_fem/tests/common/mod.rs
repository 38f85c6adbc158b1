//! Shared helpers of the analytic benchmark tests.
#![allow(dead_code)]

use softcap_fem::DirichletBc;
use softcap_fem::nalgebra::Vector3;
use softcap_mesh::TetMesh;

/// A tensor-product tet mesh on given (sorted) coordinate lines: `box_tet_mesh` on the index grid,
/// vertices moved to the coordinates (piecewise-linear map per axis keeps every tet valid).
pub fn graded_box(xs: &[f64], ys: &[f64], zs: &[f64]) -> TetMesh {
    let cells = [xs.len() - 1, ys.len() - 1, zs.len() - 1];
    let mut mesh = softcap_mesh::box_tet_mesh(
        [0.0; 3],
        [cells[0] as f64, cells[1] as f64, cells[2] as f64],
        cells,
    );
    for v in &mut mesh.vertices {
        let (i, j, k) = (
            v.x.round() as usize,
            v.y.round() as usize,
            v.z.round() as usize,
        );
        *v = Vector3::new(xs[i], ys[j], zs[k]);
    }
    mesh
}

/// Coordinates 0..=fine_len with uniform spacing h0, then geometric growth `ratio` up to ≥ total.
pub fn graded_line(h0: f64, fine_len: f64, ratio: f64, total: f64) -> Vec<f64> {
    let mut c = vec![0.0];
    let n = (fine_len / h0).round() as usize;
    for i in 1..=n {
        c.push(i as f64 * h0);
    }
    let mut h = h0;
    while *c.last().unwrap() < total - 1e-12 {
        h *= ratio;
        let next = (c.last().unwrap() + h).min(total);
        c.push(next);
    }
    c
}

/// Nodal forces of a uniform traction `t` [Pa] on the boundary faces selected by `select`
/// (each face's area force split equally among its three nodes).
pub fn traction_forces(
    mesh: &TetMesh,
    select: impl Fn(&[Vector3<f64>; 3]) -> bool,
    t: Vector3<f64>,
) -> Vec<Vector3<f64>> {
    let mut f = vec![Vector3::zeros(); mesh.vertices.len()];
    for face in mesh.boundary_faces() {
        let p = [
            mesh.vertices[face[0]],
            mesh.vertices[face[1]],
            mesh.vertices[face[2]],
        ];
        if select(&p) {
            let area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
            for &n in &face {
                f[n] += t * (area / 3.0);
            }
        }
    }
    f
}

/// The supports of the block tests: every node at z = `base` clamped and, for a quarter model
/// (`symmetry`), the normal dof of the nodes on the planes x = 0 and y = 0 fixed; with the nodes
/// at z = `top` (the contact candidates).
pub fn block_supports(
    mesh: &TetMesh,
    base: f64,
    top: f64,
    symmetry: bool,
) -> (DirichletBc, Vec<usize>) {
    let mut bc = DirichletBc::new();
    let mut top_nodes = Vec::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if (v.z - base).abs() < 1e-12 {
            bc.fix_node(i, *v);
        }
        if symmetry && v.x.abs() < 1e-12 {
            bc.fix_dof(3 * i, 0.0);
        }
        if symmetry && v.y.abs() < 1e-12 {
            bc.fix_dof(3 * i + 1, 0.0);
        }
        if (v.z - top).abs() < 1e-12 {
            top_nodes.push(i);
        }
    }
    (bc, top_nodes)
}
