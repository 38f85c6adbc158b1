//! Shell prefactor on the ≈600k-vertex face (ICT face, 3 midpoint subdivisions, 41 marker
//! handles) with each fill-reducing ordering: CPU seconds (user + system of this process, all
//! threads, `/proc/self/stat`) of assembly + factorization, nonzeros of L, and of the basis.
//!
//! `cargo run --release -p softcap_face --example shell_orderings [amd|nd|both] [levels]`

use softcap_face::{parse_landmarks_csv, subdivide_midpoint};
use softcap_mesh::shell::{LinearShell, ShellOrdering, ShellSettings};
use std::path::PathBuf;

fn cpu_s() -> f64 {
    softcap_app::process::cpu_seconds().unwrap_or(0.0)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let which = args.get(1).map_or("both", |s| s.as_str()).to_string();
    let levels: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    let fixtures = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
    let mesh = softcap_mesh::read_obj(fixtures.join("ict-face/neutral.obj"))
        .expect("fixture")
        .to_tri_mesh();
    let path = fixtures.join("animface-mocap/ict_landmarks.csv");
    let table = parse_landmarks_csv(&std::fs::read_to_string(&path).expect("fixture"), &path)
        .expect("table");
    let handles: Vec<usize> = table.iter().map(|r| r.vertex).collect();
    let (mut tris, mut verts) = (mesh.triangles.clone(), mesh.vertices.clone());
    for _ in 0..levels {
        let (t, mut f) = subdivide_midpoint(&tris, &[&verts]).expect("subdivide");
        tris = t;
        verts = f.pop().expect("field");
    }
    let fine = softcap_mesh::TriMesh {
        vertices: verts,
        triangles: tris,
    };
    let (c0, t0) = (cpu_s(), std::time::Instant::now());
    let lap = softcap_mesh::cotan_laplacian(&fine);
    let areas = softcap_mesh::voronoi_areas(&fine);
    println!(
        "cotangent Laplacian + Voronoi areas: CPU {:.2} s (wall {:.2} s)",
        cpu_s() - c0,
        t0.elapsed().as_secs_f64()
    );
    let mut orderings = Vec::new();
    if which != "nd" {
        orderings.push(("AMD", ShellOrdering::Amd));
    }
    if which != "amd" {
        orderings.push(("nested dissection", ShellOrdering::NestedDissection));
    }
    // one probe frame: every handle moved by a smooth field; the orderings must agree on it
    let probe: Vec<nalgebra::Vector3<f64>> = handles
        .iter()
        .map(|&v| {
            let p = fine.vertices[v];
            nalgebra::Vector3::new((0.3 * p.x).sin(), 0.1 * p.y, (0.2 * p.z).cos())
        })
        .collect();
    let mut solutions = Vec::new();
    for (name, ordering) in orderings {
        let (c0, t0) = (cpu_s(), std::time::Instant::now());
        let shell = LinearShell::with_ordering(
            lap.as_ref(),
            &areas,
            Some(&fine.vertices),
            &handles,
            &ShellSettings::default(),
            ordering,
        )
        .expect("shell");
        let (c1, t1) = (cpu_s(), std::time::Instant::now());
        let basis = shell.basis();
        let c2 = cpu_s();
        println!(
            "{} v, {name}: prefactor CPU {:.2} s (wall {:.2} s), nnz(L) {:.1} M, {:.1} G multiply-adds; basis ({} columns) CPU {:.2} s (wall {:.2} s)",
            fine.vertices.len(),
            c1 - c0,
            (t1 - t0).as_secs_f64(),
            shell.factor_nonzeros() as f64 / 1e6,
            shell.factor_flops() / 1e9,
            basis.h,
            c2 - c1,
            t1.elapsed().as_secs_f64()
        );
        solutions.push((name, shell.solve(&probe).expect("solve")));
    }
    if let [(a, ua), (b, ub), ..] = solutions.as_slice() {
        let scale = ua.iter().map(|u| u.norm()).fold(0.0, f64::max);
        let diff = ua
            .iter()
            .zip(ub)
            .map(|(x, y)| (x - y).norm())
            .fold(0.0, f64::max);
        println!(
            "max |u_{a} − u_{b}| = {diff:.2e} (relative to max |u| {:.2e})",
            diff / scale
        );
    }
}
