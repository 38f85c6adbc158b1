//! The truth's local refinement along the probe's contact paths (`object.truth_refine_edge_mm`,
//! `softcap_synth::truth::refined_truth_mesh`): off by default, conforming, confined to the balls
//! of the contact rule, planar top and bottom faces, deterministic.

use softcap_synth::Scenario;
use softcap_synth::truth::{
    Block, ProbeGeometry, contact_refinement_balls, refined_truth_mesh, schedule, stream,
};
use std::path::Path;

fn suite(name: &str) -> Scenario {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures/scenarios/suite")
        .join(format!("{name}.toml"));
    Scenario::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn truth_refinement_is_off_by_default_and_local_conforming_and_deterministic() {
    let mut s = suite("probe-friction");
    let mut rng = stream(s.seed, 1);
    let block = Block::new(&s, &mut rng);
    let (_, frames) = schedule(&s, &block, &mut rng);
    // Off (the default): the structured mesh itself.
    assert_eq!(s.object.truth_refine_edge_mm, 0.0);
    let off = refined_truth_mesh(&s, &block, &frames).unwrap();
    assert_eq!(off.vertices, block.truth_mesh.vertices);
    assert_eq!(off.tets, block.truth_mesh.tets);

    // The balls: one per distinct below-surface tip pose, radius twice the Hertz contact radius.
    let probe = ProbeGeometry::new(&s);
    let balls = contact_refinement_balls(&probe, block.top_m(), &frames);
    let r = s.probe.radius_mm * 1e-3;
    let loaded: Vec<_> = frames.iter().filter(|f| f.depth_m > 0.0).collect();
    assert!(!balls.is_empty() && balls.len() <= loaded.len());
    for b in &balls {
        assert_eq!(b.centre_m.z, block.top_m());
        let f = loaded
            .iter()
            .find(|f| {
                let t = f.world_from_probe.translation.vector;
                t.x == b.centre_m.x && t.y == b.centre_m.y
            })
            .expect("every ball sits over a loaded tip pose");
        assert!((b.radius_m - 2.0 * (r * f.depth_m).sqrt()).abs() < 1e-15);
    }

    let h_mm = 2.0;
    s.object.truth_refine_edge_mm = h_mm;
    let refined = refined_truth_mesh(&s, &block, &frames).unwrap();
    let again = refined_truth_mesh(&s, &block, &frames).unwrap();
    assert_eq!(refined.vertices, again.vertices, "deterministic");
    assert_eq!(refined.tets, again.tets, "deterministic");
    let (n0, t0) = (block.truth_mesh.vertices.len(), block.truth_mesh.tets.len());
    let (n1, t1) = (refined.vertices.len(), refined.tets.len());
    println!("truth mesh {t0} tets / {n0} vertices → {t1} tets / {n1} vertices at h {h_mm} mm");
    assert!(t1 > t0 && n1 > n0);
    // The structured vertices keep their indices and positions.
    assert_eq!(&refined.vertices[..n0], &block.truth_mesh.vertices[..]);
    // Same volume, positively oriented tets.
    let vol = |m: &softcap_mesh::TetMesh| (0..m.tets.len()).map(|t| m.tet_volume(t)).sum::<f64>();
    assert!((vol(&refined) - vol(&block.truth_mesh)).abs() < 1e-12 * vol(&block.truth_mesh));
    assert!((0..t1).all(|t| refined.tet_volume(t) > 0.0));
    // Every vertex inside the block; the top and bottom planes stay exact (contact candidates
    // and the bonded support are selected by z).
    let top = block.top_m();
    let on_top = |m: &softcap_mesh::TetMesh| m.vertices.iter().filter(|v| v.z == top).count();
    let on_bottom = |m: &softcap_mesh::TetMesh| m.vertices.iter().filter(|v| v.z == 0.0).count();
    assert!(refined.vertices.iter().all(|v| v.z >= 0.0 && v.z <= top));
    assert!(on_top(&refined) > on_top(&block.truth_mesh));
    assert!(on_bottom(&refined) >= on_bottom(&block.truth_mesh));
    // Tets whose centroid lies well inside a ball are refined to h; the structured mesh's
    // longest edge (its cell diagonal) is > 2 h, so refinement reached every ball.
    let structured_longest = (0..t0)
        .map(|t| block.truth_mesh.tet_longest_edge(t))
        .fold(0.0, f64::max);
    assert!(structured_longest > 2.0 * h_mm * 1e-3);
    let mut inside = 0;
    let mut far_coarse = 0;
    for t in 0..t1 {
        let c = refined.tets[t]
            .iter()
            .map(|&i| refined.vertices[i])
            .sum::<nalgebra::Vector3<f64>>()
            / 4.0;
        let d = balls
            .iter()
            .map(|b| (c - b.centre_m).norm() - b.radius_m)
            .fold(f64::INFINITY, f64::min);
        let l = refined.tet_longest_edge(t);
        if d < 0.0 {
            inside += 1;
            assert!(l <= h_mm * 1e-3 * (1.0 + 1e-9), "tet {t}: edge {l}");
        } else if d > structured_longest && l > 2.0 * h_mm * 1e-3 {
            far_coarse += 1;
        }
    }
    println!("{inside} tets centred inside the balls, {far_coarse} coarse tets far from them");
    assert!(inside > 0 && far_coarse > 0, "refinement is local");
}
