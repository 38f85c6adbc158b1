//! softcap's side of `scripts/peer-indent` (the side-by-side with FElupe): one flat-punch
//! indentation of a third-party suite mesh with the stable neo-Hookean tet, the base bonded and
//! the top-face nodes under the disk displaced by `depth` along −z (x, y free: frictionless), in
//! `steps` equal load steps. Prints the punch force and the solve time as JSON and writes the
//! displacements (mm) to `out.csv`, one `node,ux,uy,uz` row per mesh node.
//!
//! `cargo run --profile demo -p softcap_fem --example peer_indent -- \
//!     volume.msh mu_pa lambda_lame_pa centre_x_mm centre_y_mm radius_mm depth_mm steps out.csv`

use std::io::Write;
use std::time::Instant;

use softcap_fem::nalgebra::Vector3;
use softcap_fem::{
    DirichletBc, ElasticModel, EquilibriumSettings, NeoHookeanModel, NeoHookeanParams, StaticSolver,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 10 {
        return Err("usage: peer_indent volume.msh mu_pa lambda_lame_pa cx_mm cy_mm radius_mm depth_mm steps out.csv".into());
    }
    let num = |i: usize| -> Result<f64, Box<dyn std::error::Error>> {
        a[i].parse::<f64>()
            .map_err(|e| format!("argument {i} `{}`: {e}", a[i]).into())
    };
    let (mu, lame, cx, cy, radius, depth) = (num(2)?, num(3)?, num(4)?, num(5)?, num(6)?, num(7)?);
    let steps = num(8)? as usize;
    let t_load = Instant::now();
    let mut mesh = softcap_mesh::read_msh_tet_mesh(&a[1])?;
    for v in &mut mesh.vertices {
        *v *= 1e-3;
    }
    let model = NeoHookeanModel::homogeneous(&mesh, NeoHookeanParams::from_lame(lame, mu)?)?;
    let top_z = mesh.vertices.iter().map(|v| v.z).fold(f64::MIN, f64::max);
    let mut base = DirichletBc::new();
    let mut punch = Vec::new();
    for (i, v) in mesh.vertices.iter().enumerate() {
        if v.z.abs() < 1e-9 {
            base.fix_node(i, *v);
        } else if (v.z - top_z).abs() < 1e-9
            && ((v.x - cx * 1e-3).powi(2) + (v.y - cy * 1e-3).powi(2)).sqrt() <= radius * 1e-3
        {
            punch.push(i);
        }
    }
    let mut bc = base.clone();
    for &i in &punch {
        bc.fix_dof(3 * i + 2, top_z);
    }
    let mut model = model;
    let mut solver = StaticSolver::with_bc(&model, &bc)?;
    let setup_s = t_load.elapsed().as_secs_f64();
    let settings = EquilibriumSettings {
        residual_tol_rel: 1e-9,
        displacement_tol_rel: 1e-10,
        max_iterations: 50,
        ..EquilibriumSettings::newton()
    };
    let mut x = mesh.vertices.clone();
    let f_ext = vec![Vector3::zeros(); x.len()];
    let t_solve = Instant::now();
    let mut iterations = 0;
    for s in 1..=steps {
        for &i in &punch {
            bc.fix_dof(3 * i + 2, top_z - depth * 1e-3 * s as f64 / steps as f64);
        }
        bc.apply(&mut x);
        let report = solver.solve(&mut model, &mut x, &f_ext, None, &settings);
        iterations += report.iterations;
        if !report.converged() {
            return Err(format!("step {s}: {:?}", report.status).into());
        }
    }
    let solve_s = t_solve.elapsed().as_secs_f64();
    let f_int = model.internal_forces(&x);
    let force_n: f64 = punch.iter().map(|&i| f_int[i].z).sum();
    let mut out = std::io::BufWriter::new(std::fs::File::create(&a[9])?);
    writeln!(out, "node,ux,uy,uz")?;
    for (i, (p, r)) in x.iter().zip(&mesh.vertices).enumerate() {
        let u = (p - r) * 1e3;
        writeln!(out, "{i},{:.9e},{:.9e},{:.9e}", u.x, u.y, u.z)?;
    }
    println!(
        "{{\"force_z_n\": {force_n:.9e}, \"punch_nodes\": {}, \"setup_s\": {setup_s:.4}, \"solve_s\": {solve_s:.4}, \"iterations\": {iterations}}}",
        punch.len()
    );
    Ok(())
}
