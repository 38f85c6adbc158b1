//! Multi-material 3MF of a layered design (one object per material): written with `threemf`,
//! read back with `threemf`, geometry checked by volume.

use softcap_design::*;

#[test]
fn design_3mf_round_trip_one_object_per_material() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("design.3mf");
    let names: Vec<String> = (0..9).map(|m| format!("base {m}")).collect();
    // Layers bottom → top: 0, 3, 3, 5, 0 (material 0 twice, not adjacent; 3 twice, adjacent).
    let design = [0, 3, 3, 5, 0];
    let thickness = [0.004, 0.005, 0.006, 0.005, 0.005];
    write_design_3mf(&path, &design, &thickness, [0.04, 0.05, 0.025], &names).unwrap();
    assert!(
        std::fs::read_dir(dir.path()).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp"))
    );
    let parts = read_design_3mf(&path).unwrap();
    assert_eq!(parts.len(), 3, "one object per material used");
    let by_name = |m: usize| {
        parts
            .iter()
            .find(|p| p.name.starts_with(&format!("material {m}:")))
            .unwrap()
    };
    // Material 0: two disjoint slabs (4 mm + 5 mm), 3: one merged 11 mm slab, 5: 5 mm.
    let area = 40.0 * 50.0;
    for (m, slabs, height_mm) in [(0, 2, 9.0), (3, 1, 11.0), (5, 1, 5.0)] {
        let p = by_name(m);
        assert_eq!(p.vertices.len(), 8 * slabs);
        assert_eq!(p.triangles.len(), 12 * slabs);
        assert!(
            (p.volume_mm3() - area * height_mm).abs() < 1e-9,
            "{m}: {}",
            p.volume_mm3()
        );
    }
    assert_eq!(by_name(0).base_index, 0);
    assert_eq!(by_name(3).base_index, 1);
    assert_eq!(by_name(5).base_index, 2);
    let total: f64 = parts.iter().map(|p| p.volume_mm3()).sum();
    assert!((total - area * 25.0).abs() < 1e-9);
    // Top of material 0's upper slab is the block top (25 mm).
    let zmax = by_name(0).vertices.iter().map(|v| v[2]).fold(0.0, f64::max);
    assert!((zmax - 25.0).abs() < 1e-12);
}

#[test]
fn reading_a_non_3mf_names_the_file_and_bad_designs_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("not.3mf");
    std::fs::write(&bad, b"plain text").unwrap();
    let e = read_design_3mf(&bad).unwrap_err().to_string();
    assert!(e.contains("not.3mf"), "{e}");
    let names = vec!["a".to_string()];
    let out = dir.path().join("x.3mf");
    assert!(write_design_3mf(&out, &[0, 1], &[0.01, 0.01], [0.04, 0.05, 0.02], &names).is_err());
    assert!(write_design_3mf(&out, &[0], &[0.01, 0.01], [0.04, 0.05, 0.02], &names).is_err());
    assert!(!out.exists());
}
