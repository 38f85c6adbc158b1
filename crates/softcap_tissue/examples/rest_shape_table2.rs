//! wang2015 Table 2 on known truth: a body with a known rest shape X* sags under gravity to its
//! static shape x_s (softcap's corotational statics, Newton); the rest shape is recovered from x_s
//! alone by the solve `softcap tissue fit-dynamic` uses (wang2015 eq. 7 by Newton with the exact
//! ∂f/∂X, `softcap_fem::solve_rest_shape`), and the recovered body is let sag again. ΔX is the
//! mean node distance of the recovered rest shape to X*, Δx_s that of its sagged shape to x_s, in
//! metres and per unit of the model's largest dimension (wang2015 normalises its models). The
//! cases: the sagging beam (the bar of Table 1) and a plant-like cantilever (a thin leaf blade
//! on a stalk, soft, sagging by about a fifth of its length).
//!
//! `cargo run --profile test -p softcap_tissue --example rest_shape_table2`

use nalgebra::Vector3;
use softcap_fem::{
    CorotationalModel, DirichletBc, EquilibriumSettings, LinearParams, RestShapeSettings,
    StaticSolver, gravity_forces, lumped_masses, solve_rest_shape,
};
use softcap_mesh::{TetMesh, box_tet_mesh};

/// Mean node distance.
fn mean_distance(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).sum::<f64>() / a.len() as f64
}

/// The static shape of `rest` under gravity, the `held` nodes fixed.
fn sag(
    rest: &TetMesh,
    young_pa: f64,
    held: &[usize],
    density: f64,
) -> Result<Vec<Vector3<f64>>, Box<dyn std::error::Error>> {
    let mut model =
        CorotationalModel::homogeneous(rest, LinearParams::from_young_poisson(young_pa, 0.45)?)?;
    let gravity = gravity_forces(
        &lumped_masses(&model, density),
        Vector3::new(0.0, 0.0, -9.80665),
    );
    let mut bc = DirichletBc::new();
    for &i in held {
        bc.fix_node(i, rest.vertices[i]);
    }
    let mut x = rest.vertices.clone();
    let report = StaticSolver::with_bc(&model, &bc)?.solve(
        &mut model,
        &mut x,
        &gravity,
        None,
        &EquilibriumSettings::newton(),
    );
    if !report.converged() {
        return Err(format!("static sag did not converge: {:?}", report.status).into());
    }
    Ok(x)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!(
        "| model | nodes | tets | sag (tip) | ΔX mean m | ΔX / size | Δx_s mean m | Δx_s / size | rest-shape solve | time |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    // (name, mesh min, max, cells, E)
    let cases = [
        (
            "beam 200 × 30 × 20 mm, E 1 MPa",
            [0.0, -0.015, -0.01],
            [0.2, 0.015, 0.01],
            [12, 2, 2],
            1.0e6,
        ),
        (
            "plant leaf 200 × 60 × 6 mm, E 2 MPa",
            [0.0, -0.03, -0.003],
            [0.2, 0.03, 0.003],
            [10, 3, 1],
            2.0e6,
        ),
    ];
    for (name, min, max, cells, young) in cases {
        let rest = box_tet_mesh(min, max, cells);
        let held: Vec<usize> = (0..rest.vertices.len())
            .filter(|&i| rest.vertices[i].x <= 1e-9)
            .collect();
        let density = 1100.0;
        let xs = sag(&rest, young, &held, density)?;
        let tip = rest
            .vertices
            .iter()
            .zip(&xs)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        // Recover X from x_s alone (the model built over x_s, as fit-dynamic does).
        let observed = TetMesh {
            vertices: xs.clone(),
            tets: rest.tets.clone(),
        };
        let model = CorotationalModel::homogeneous(
            &observed,
            LinearParams::from_young_poisson(young, 0.45)?,
        )?;
        let gravity = gravity_forces(
            &lumped_masses(&model, density),
            Vector3::new(0.0, 0.0, -9.80665),
        );
        let dofs: Vec<usize> = held
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let t = std::time::Instant::now();
        let solved = solve_rest_shape(
            &model,
            &xs,
            &gravity,
            &dofs,
            None,
            &RestShapeSettings::default(),
        )?;
        let seconds = t.elapsed().as_secs_f64();
        let recovered = TetMesh {
            vertices: solved.rest_positions_m.clone(),
            tets: rest.tets.clone(),
        };
        let recovered = &recovered;
        let size = (0..3).map(|k| max[k] - min[k]).fold(0.0, f64::max);
        let row = |method: String,
                   x: &[Vector3<f64>],
                   seconds: f64|
         -> Result<(), Box<dyn std::error::Error>> {
            let again = sag(
                &TetMesh {
                    vertices: x.to_vec(),
                    tets: rest.tets.clone(),
                },
                young,
                &held,
                density,
            )?;
            let dx = mean_distance(x, &rest.vertices);
            let dxs = mean_distance(&again, &xs);
            println!(
                "| {name} | {} | {} | {:.1} mm | {dx:.2e} | {:.2e} | {dxs:.2e} | {:.2e} | {method} | {seconds:.2} s |",
                rest.vertices.len(),
                rest.tets.len(),
                tip * 1e3,
                dx / size,
                dxs / size,
            );
            Ok(())
        };
        row(
            format!(
                "Newton on eq. 7: {:?}, {} iterations, residual {:.1e} of {:.1e} N",
                solved.report.status,
                solved.report.iterations,
                solved.report.residual_norm_n,
                solved.report.load_norm_n
            ),
            &recovered.vertices,
            seconds,
        )?;
        // Fixed-point sag inversion: X ← X + (x_s − sag(X)), each pass one forward static solve.
        let t = std::time::Instant::now();
        let mut x_rest = xs.clone();
        let mut passes = 0;
        for _ in 0..100 {
            passes += 1;
            let sagged = sag(
                &TetMesh {
                    vertices: x_rest.clone(),
                    tets: rest.tets.clone(),
                },
                young,
                &held,
                density,
            )?;
            let miss = mean_distance(&sagged, &xs);
            for ((r, s), o) in x_rest.iter_mut().zip(&sagged).zip(&xs) {
                *r += o - s;
            }
            if miss < 1e-9 * size {
                break;
            }
        }
        row(
            format!("fixed-point sag inversion, {passes} static solves"),
            &x_rest,
            t.elapsed().as_secs_f64(),
        )?;
    }
    Ok(())
}
