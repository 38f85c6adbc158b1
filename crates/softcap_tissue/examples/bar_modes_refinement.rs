//! How stiff is a linear-tet bar in bending, per level of uniform refinement? The first natural
//! frequencies of the clamped 200 × 30 × 30 mm bar of the dynamic scenarios (E = 1 MPa, ν = 0.45,
//! ρ = 1100 kg/m³, clamped at x = 0, `softcap_fem::lanczos_modes`, lumped mass) on the template
//! mesh (12 × 2 × 2 cells) and on the bar-release truth mesh (32 × 5 × 5 cells) refined L times,
//! next to Timoshenko beam theory, and with quadratic (10-node) tets on each mesh
//! (`softcap_fem::quadratic`, masses lumped from the once-refined mesh on the same nodes). A
//! fitted E scales with (f_model / f_converged)⁻², so the frequency ratio is the stiffness the
//! mesh adds to a fitted modulus.
//!
//! `cargo run --profile test -p softcap_tissue --example bar_modes_refinement [MAX_LEVEL]`

use softcap_fem::{
    CorotationalModel, LinearParams, ModalSettings, QuadraticModel, QuadraticSolver, lanczos_modes,
    lumped_masses, quadratic_tets,
};

const L: f64 = 0.2;
const A: f64 = 0.03;
const E: f64 = 1.0e6;
const NU: f64 = 0.45;
const RHO: f64 = 1100.0;

/// First bending frequency of a clamped-free Timoshenko beam with a square section, Hz: the
/// Euler–Bernoulli value (β₁L = 1.8751) corrected for shear and rotary inertia to first order,
/// ω² ≈ ω_EB² / (1 + (β₁r)²(1 + E/(κG))), r² = I/A, κ = 10(1+ν)/(12+11ν).
fn timoshenko_hz() -> f64 {
    let b1 = 1.875_104 / L;
    let (area, i) = (A * A, A.powi(4) / 12.0);
    let w_eb = b1 * b1 * (E * i / (RHO * area)).sqrt();
    let g = E / (2.0 * (1.0 + NU));
    let kappa = 10.0 * (1.0 + NU) / (12.0 + 11.0 * NU);
    let r2 = i / area;
    let w = w_eb / (1.0 + b1 * b1 * r2 * (1.0 + E / (kappa * g))).sqrt();
    w / std::f64::consts::TAU
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let max_level: usize = std::env::args().nth(1).map_or(Ok(2), |a| a.parse())?;
    let reference = timoshenko_hz();
    println!(
        "| mesh | elements | level | tets | nodes | f₁ Hz | f₂ Hz | f₂/f₁ | f₁ / Timoshenko {reference:.3} Hz | E factor (f₁/f_T)² | s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let row = |name: &str,
               kind: &str,
               level: usize,
               tets: usize,
               nodes: usize,
               f: &[f64],
               s: f64| {
        println!(
            "| {name} | {kind} | {level} | {tets} | {nodes} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {s:.1} |",
            f[0],
            f[1],
            f[1] / f[0],
            f[0] / reference,
            (f[0] / reference).powi(2)
        );
    };
    for (name, cells, levels) in [
        ("template 12 × 2 × 2", [12, 2, 2], max_level),
        ("bar-release truth 32 × 5 × 5", [32, 5, 5], max_level.min(1)),
    ] {
        let mut mesh =
            softcap_mesh::box_tet_mesh([0.0, -A / 2.0, -A / 2.0], [L, A / 2.0, A / 2.0], cells);
        for level in 0..=levels {
            if level > 0 {
                mesh = softcap_mesh::refine_tets(&mesh).mesh;
            }
            let clamped = |v: &[softcap_fem::nalgebra::Vector3<f64>]| -> Vec<usize> {
                (0..v.len())
                    .filter(|&i| v[i].x <= 1e-9)
                    .flat_map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
                    .collect()
            };
            let p = LinearParams::from_young_poisson(E, NU)?;
            let t0 = std::time::Instant::now();
            let model = CorotationalModel::homogeneous(&mesh, p)?;
            let modes = lanczos_modes(
                &model,
                &lumped_masses(&model, RHO),
                &clamped(&mesh.vertices),
                &ModalSettings {
                    num_modes: 2,
                    tolerance: 1e-8,
                    ..ModalSettings::default()
                },
            )?;
            let f = modes.modes.frequencies_hz();
            let s = t0.elapsed().as_secs_f64();
            row(
                name,
                "linear",
                level,
                mesh.tets.len(),
                mesh.vertices.len(),
                &f,
                s,
            );
            if level == levels {
                continue; // quadratic tets have the nodes of the next level
            }
            let t0 = std::time::Instant::now();
            let q = quadratic_tets(&mesh);
            let fine = softcap_mesh::refine_tets(&mesh).mesh;
            let masses = lumped_masses(&CorotationalModel::homogeneous(&fine, p)?, RHO);
            let model = QuadraticModel::new(&q.nodes, &q.elements, &vec![p; q.elements.len()])?;
            let modes =
                QuadraticSolver::new(&model, masses, &clamped(&q.nodes))?.modes(&model, 2)?;
            let f = modes.frequencies_hz();
            let s = t0.elapsed().as_secs_f64();
            row(
                name,
                "quadratic",
                level,
                q.elements.len(),
                q.nodes.len(),
                &f,
                s,
            );
        }
    }
    Ok(())
}
