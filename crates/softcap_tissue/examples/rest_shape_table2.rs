//! wang2015 Table 2 on known truth: a body with a known rest shape X* sags under gravity to its
//! static shape x_s (softcap's corotational statics, Newton); the rest shape is recovered from x_s
//! alone by three solves of wang2015 eq. 7, and each recovered body is let sag again:
//!
//! - Newton on eq. 7 with the exact ∂f/∂X (`softcap_fem::solve_rest_shape`, the solve
//!   `softcap tissue fit-dynamic` uses);
//! - wang2015 §6.1's virtual-force simulation: the force residual drives the rest shape through
//!   a damped artificial-time simulation (`softcap_fem::solve_rest_shape_virtual_force`);
//! - the fixed-point sag inversion X ← X + (x_s − sag(X)), one forward static solve per pass.
//!
//! Every solve and every sag uses the same nodal masses (the body's, lumped on X*: mass is
//! conserved), so the rows compare the solvers on one problem. ΔX is the mean node distance of
//! the recovered rest shape to X*, Δx_s that of its sagged shape to x_s, in metres and per unit
//! of the model's largest dimension (wang2015 normalises its models). The cases: the sagging beam
//! (the bar of Table 1) and a plant-like cantilever (a thin leaf blade, soft, sagging by about a
//! tenth of its length).
//!
//! `cargo run --profile test -p softcap_tissue --example rest_shape_table2`

use nalgebra::Vector3;
use softcap_fem::{
    CorotationalModel, DirichletBc, EquilibriumSettings, LinearParams, RestShapeSettings,
    StaticSolver, VirtualForceSettings, gravity_forces, lumped_masses, solve_rest_shape,
    solve_rest_shape_virtual_force,
};
use softcap_mesh::{TetMesh, box_tet_mesh};
use std::time::Instant;

type Error = Box<dyn std::error::Error>;

/// Mean node distance.
fn mean_distance(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).sum::<f64>() / a.len() as f64
}

/// One body of the table: its tets, parameters, support and nodal load.
struct Body {
    tets: Vec<[usize; 4]>,
    params: LinearParams,
    held: Vec<usize>,
    load: Vec<Vector3<f64>>,
}

impl Body {
    fn model(&self, rest: &[Vector3<f64>]) -> Result<CorotationalModel, Error> {
        let mesh = TetMesh {
            vertices: rest.to_vec(),
            tets: self.tets.clone(),
        };
        Ok(CorotationalModel::homogeneous(&mesh, self.params)?)
    }

    /// The static shape of the body with rest shape `rest` under the load, the held nodes fixed
    /// at `support`.
    fn sag(
        &self,
        rest: &[Vector3<f64>],
        support: &[Vector3<f64>],
    ) -> Result<Vec<Vector3<f64>>, Error> {
        let mut model = self.model(rest)?;
        let mut bc = DirichletBc::new();
        for &i in &self.held {
            bc.fix_node(i, support[i]);
        }
        let mut x = rest.to_vec();
        let report = StaticSolver::with_bc(&model, &bc)?.solve(
            &mut model,
            &mut x,
            &self.load,
            None,
            &EquilibriumSettings::newton(),
        );
        if !report.converged() {
            return Err(format!("static sag did not converge: {:?}", report.status).into());
        }
        Ok(x)
    }
}

fn main() -> Result<(), Error> {
    println!(
        "| model | tip sag | rest-shape solve | iterations | time | ΔX m | ΔX / size | Δx_s m | Δx_s / size |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    // (name, mesh min, max, cells, E)
    let cases = [
        (
            "sagging beam 200 × 30 × 20 mm, E 1 MPa",
            [0.0, -0.015, -0.01],
            [0.2, 0.015, 0.01],
            [12, 2, 2],
            1.0e6,
        ),
        (
            "plant-like leaf blade 200 × 60 × 6 mm, E 2 MPa",
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
        let params = LinearParams::from_young_poisson(young, 0.45)?;
        let masses = lumped_masses(&CorotationalModel::homogeneous(&rest, params)?, 1100.0);
        let body = Body {
            tets: rest.tets.clone(),
            params,
            held: held.clone(),
            load: gravity_forces(&masses, Vector3::new(0.0, 0.0, -9.80665)),
        };
        let xs = body.sag(&rest.vertices, &rest.vertices)?;
        let tip = rest
            .vertices
            .iter()
            .zip(&xs)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        let size = (0..3).map(|k| max[k] - min[k]).fold(0.0, f64::max);
        let model = body.model(&xs)?;
        let dofs: Vec<usize> = held
            .iter()
            .flat_map(|&i| [3 * i, 3 * i + 1, 3 * i + 2])
            .collect();
        let row = |method: &str, iterations: String, x: &[Vector3<f64>], seconds: f64| {
            let again = body.sag(x, &xs)?;
            let dx = mean_distance(x, &rest.vertices);
            let dxs = mean_distance(&again, &xs);
            println!(
                "| {name} | {:.1} mm | {method} | {iterations} | {seconds:.3} s | {dx:.1e} | {:.1e} | {dxs:.1e} | {:.1e} |",
                tip * 1e3,
                dx / size,
                dxs / size,
            );
            Ok::<(), Error>(())
        };

        let t = Instant::now();
        let newton = solve_rest_shape(
            &model,
            &xs,
            &body.load,
            &dofs,
            None,
            &RestShapeSettings::default(),
        )?;
        let seconds = t.elapsed().as_secs_f64();
        row(
            "Newton on eq. 7 (`solve_rest_shape`)",
            format!("{} ({:?})", newton.report.iterations, newton.report.status),
            &newton.rest_positions_m,
            seconds,
        )?;

        let t = Instant::now();
        let monotone = RestShapeSettings {
            max_growth: 1.0,
            ..RestShapeSettings::default()
        };
        let stalled = solve_rest_shape(&model, &xs, &body.load, &dofs, None, &monotone)?;
        let seconds = t.elapsed().as_secs_f64();
        row(
            "Newton, monotone backtracking on ‖r‖ (`max_growth` 1)",
            format!(
                "{} ({:?}, ‖r‖ {:.3} of {:.3} N)",
                stalled.report.iterations,
                stalled.report.status,
                stalled.report.residual_norm_n,
                stalled.report.load_norm_n
            ),
            &stalled.rest_positions_m,
            seconds,
        )?;

        let t = Instant::now();
        let settings = VirtualForceSettings::default();
        let virtual_force = solve_rest_shape_virtual_force(
            &model, &masses, &xs, &body.load, &dofs, None, &settings,
        )?;
        let seconds = t.elapsed().as_secs_f64();
        row(
            &format!(
                "wang2015 §6.1 virtual-force simulation (h {} s, c {} 1/s)",
                settings.time_step_s, settings.damping_per_s
            ),
            format!(
                "{} steps ({:?})",
                virtual_force.report.iterations, virtual_force.report.status
            ),
            &virtual_force.rest_positions_m,
            seconds,
        )?;

        // Fixed-point sag inversion: X ← X + (x_s − sag(X)), each pass one forward static solve.
        let t = Instant::now();
        let mut x_rest = xs.clone();
        let mut passes = 0;
        for _ in 0..100 {
            passes += 1;
            let sagged = body.sag(&x_rest, &xs)?;
            let miss = mean_distance(&sagged, &xs);
            for ((r, s), o) in x_rest.iter_mut().zip(&sagged).zip(&xs) {
                *r += o - s;
            }
            if miss < 1e-9 * size {
                break;
            }
        }
        let seconds = t.elapsed().as_secs_f64();
        row(
            "fixed-point sag inversion",
            format!("{passes} static solves"),
            &x_rest,
            seconds,
        )?;
    }
    Ok(())
}
