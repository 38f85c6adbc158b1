//! The quarter-symmetric composite simulation against the full block (same element size, no
//! symmetry planes): the top-surface displacements of the quarter's nodes.
//!
//! Two full blocks: the *mirrored* one (the quarter mesh reflected about both symmetry planes)
//! must equal the quarter model to solver tolerance — that proves the symmetry boundary
//! conditions and the patch-load split exact; the *regular* full grid (`box_tet_mesh` over the
//! whole block, whose tet diagonals are not mirror-symmetric about the centre planes) differs
//! by the discretization error of the coarse grid.

use softcap_design::*;
use std::sync::Arc;

#[test]
fn quarter_model_matches_full_block() {
    let lib = Arc::new(reference_library());
    let quarter = CompositeSettings::default();
    let full = CompositeSettings {
        quarter_symmetry: false,
        lateral_cells: [4, 6],
        ..CompositeSettings::default()
    };
    let bq = Arc::new(LayeredBlock::uniform(&quarter).unwrap());
    let bf = Arc::new(LayeredBlock::uniform(&full).unwrap());
    let bm = Arc::new(LayeredBlock::mirrored_full(&quarter, &[0.005; 5]).unwrap());
    assert_eq!(bm.mesh.tets.len(), 4 * bq.mesh.tets.len());
    assert_eq!(bm.mesh.vertices.len(), bf.mesh.vertices.len());
    // Quarter top node → full-block node at the same position.
    let map: Vec<usize> = bq
        .top_nodes
        .iter()
        .map(|&i| {
            let p = bq.mesh.vertices[i];
            *bf.top_nodes
                .iter()
                .find(|&&j| (bf.mesh.vertices[j] - p).norm() < 1e-9)
                .unwrap()
        })
        .collect();
    let map_m: Vec<usize> = bq
        .top_nodes
        .iter()
        .map(|&i| {
            let p = bq.mesh.vertices[i];
            bm.top_nodes
                .iter()
                .position(|&j| (bm.mesh.vertices[j] - p).norm() < 1e-9)
                .unwrap()
        })
        .collect();
    let mut sq = CompositeSimulator::new(bq.clone(), lib.clone(), &quarter).unwrap();
    let mut sf = CompositeSimulator::new(bf.clone(), lib.clone(), &full).unwrap();
    let mut sm = CompositeSimulator::new(bm.clone(), lib, &full).unwrap();
    for design in [[0, 3, 6, 2, 8], [5, 5, 1, 7, 0], [2, 2, 2, 2, 2]] {
        let rq = sq.simulate(&design).unwrap();
        let rf = sf.simulate(&design).unwrap();
        let rm = sm.simulate(&design).unwrap();
        let nq = bq.top_nodes.len();
        let nm = bm.top_nodes.len();
        let mut mirror_err = 0.0f64;
        for k in 0..quarter.forces_n.len() {
            for (a, &b) in map_m.iter().enumerate() {
                for c in 0..3 {
                    let d = rq.displacements_m[(k * nq + a) * 3 + c]
                        - rm.displacements_m[(k * nm + b) * 3 + c];
                    mirror_err = mirror_err.max(d.abs());
                }
            }
        }
        println!("{design:?}: quarter − mirrored full block: max {mirror_err:.2e} m");
        assert!(mirror_err < 1e-9, "{mirror_err}");
        let nq = bq.top_nodes.len();
        let nf = bf.top_nodes.len();
        let (mut se, mut n, mut umax) = (0.0, 0, 0.0f64);
        for k in 0..quarter.forces_n.len() {
            for (a, &j) in map.iter().enumerate() {
                let fidx = bf.top_nodes.iter().position(|&t| t == j).unwrap();
                for c in 0..3 {
                    let uq = rq.displacements_m[(k * nq + a) * 3 + c];
                    let uf = rf.displacements_m[(k * nf + fidx) * 3 + c];
                    se += (uq - uf).powi(2);
                    umax = umax.max(uf.abs());
                }
                n += 1;
            }
        }
        let rms = (se / n as f64).sqrt();
        let dp = (rq.probe_displacement_m[4] - rf.probe_displacement_m[4]).abs();
        println!(
            "{design:?}: RMS quarter − full {:.4} mm (max |u| {:.3} mm), probe at 10 N {:.4} vs {:.4} mm",
            rms * 1e3,
            umax * 1e3,
            rq.probe_displacement_m[4] * 1e3,
            rf.probe_displacement_m[4] * 1e3
        );
        // The two meshes differ only in the orientation of the tet split across the symmetry
        // planes, which on this coarse grid (1 × 0.83 × 0.5 cm cells) changes the probe
        // indentation by up to ≈ 8 % (measured: 0.016–0.055 mm RMS, see docs/design.md).
        assert!(rms < 0.08 * umax, "{rms} vs {umax}");
        assert!(dp < 0.1 * rf.probe_displacement_m[4]);
    }
}
