//! saito-barbic reshaping against known ground truth (paper Fig. 21).

use softcap_fem::nalgebra::Vector3;
use softcap_mesh::{TetLocator, TetMesh, box_tet_mesh};
use softcap_tissue::reshape::{
    Attachment, IcpMarker, Landmark, MaterialPoint, ReshapeProblem, ReshapeSettings, reshape,
};

/// The known deformation: a compatible, smooth, anisotropic map with stretches from 1 to 2.
fn truth(p: &Vector3<f64>) -> Vector3<f64> {
    let xi = p.x / 0.1;
    Vector3::new(
        p.x * (1.0 + 0.5 * xi),
        p.y * (1.5 - 0.5 * xi),
        0.9 * p.z + 2.0 * (p.x - 0.05).powi(2),
    )
}

struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random points on the template's boundary faces.
fn boundary_points(mesh: &TetMesh, n: usize, rng: &mut Lcg) -> Vec<Vector3<f64>> {
    let faces = mesh.boundary_faces();
    (0..n)
        .map(|_| {
            let f = faces[(rng.next() * faces.len() as f64) as usize % faces.len()];
            let (mut a, mut b) = (rng.next(), rng.next());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let [p, q, r] = f.map(|v| mesh.vertices[v]);
            p * (1.0 - a - b) + q * a + r * b
        })
        .collect()
}

fn problem(free_flying: bool) -> (ReshapeProblem, Vec<Vector3<f64>>) {
    let mesh = box_tet_mesh([0.0; 3], [0.1, 0.06, 0.04], [8, 5, 3]);
    let mut rng = Lcg(7);
    let locator = TetLocator::new(&mesh);
    let embed = |p: &Vector3<f64>| {
        let e = locator.locate(p).unwrap();
        MaterialPoint {
            nodes: mesh.tets[e.tet],
            weights: e.weights,
        }
    };
    let landmarks = boundary_points(&mesh, 12, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| Landmark {
            id: format!("l{i}"),
            point: embed(p),
            target_m: truth(p),
        })
        .collect();
    let icp_markers = boundary_points(&mesh, 150, &mut rng)
        .iter()
        .enumerate()
        .map(|(i, p)| IcpMarker {
            id: format!("m{i}"),
            position_m: truth(p),
        })
        .collect();
    let attachments = if free_flying {
        Vec::new()
    } else {
        mesh.vertices
            .iter()
            .enumerate()
            .filter(|(_, v)| v.x == 0.0)
            .map(|(i, v)| Attachment {
                id: i.to_string(),
                node: i,
                target_m: truth(v),
            })
            .collect()
    };
    let held_out = boundary_points(&mesh, 400, &mut rng);
    (
        ReshapeProblem {
            template: mesh,
            landmarks,
            icp_markers,
            attachments,
            free_flying,
        },
        held_out,
    )
}

#[test]
fn recovers_a_known_anisotropic_plastic_deformation() {
    let (p, held_out) = problem(false);
    let settings = ReshapeSettings::default();
    let t0 = std::time::Instant::now();
    let out = reshape(&p, &settings, &mut |stage, it, e, err| {
        eprintln!("{stage} {it}: E {e:.3e} max err {:.3} mm", err * 1e3)
    })
    .unwrap();
    eprintln!("{:?} in {:?}", out.stages, t0.elapsed());
    let locator = TetLocator::new(&p.template);
    let mut worst: f64 = 0.0;
    let mut mean = 0.0;
    for h in &held_out {
        let e = locator.locate(h).unwrap();
        let x = e.position(&p.template.tets, &out.positions_m);
        let d = (x - truth(h)).norm();
        worst = worst.max(d);
        mean += d / held_out.len() as f64;
    }
    let cmax = out.errors.iter().map(|e| e.error_m).fold(0.0, f64::max);
    eprintln!("held-out mean {:.3} max {:.3} mm; constraints max {:.3} mm; quality {:?}", mean * 1e3, worst * 1e3, cmax * 1e3, out.reshaped_quality);
}
