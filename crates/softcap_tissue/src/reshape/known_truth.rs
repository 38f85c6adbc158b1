//! The known-truth case of saito-barbic Fig. 21 (tests, the `reshape_box` example, benches): a
//! 10 × 6 × 4 cm box template deformed by a known smooth anisotropic map with stretches from 1× to
//! 2×. Per tet, the plastic strain F_p = stretch of the map's gradient has the map itself as its
//! stress-free equilibrium, so the map is the shape a reshape must recover.

use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use softcap_mesh::{TetLocator, TetMesh, box_tet_mesh};

use super::problem::{Attachment, IcpMarker, Landmark, MaterialPoint, ReshapeProblem};

/// The known deformation: a compatible, smooth, anisotropic map with stretches from 1 to 2.
pub fn truth(p: &Vector3<f64>) -> Vector3<f64> {
    let xi = p.x / 0.1;
    Vector3::new(
        p.x * (1.0 + 0.5 * xi),
        p.y * (1.5 - 0.5 * xi),
        0.9 * p.z + 2.0 * (p.x - 0.05).powi(2),
    )
}

/// Random points on the template's boundary faces.
fn boundary_points(mesh: &TetMesh, n: usize, rng: &mut ChaCha8Rng) -> Vec<Vector3<f64>> {
    let faces = mesh.boundary_faces();
    (0..n)
        .map(|_| {
            let f = faces[(rng.random::<f64>() * faces.len() as f64) as usize % faces.len()];
            let (mut a, mut b) = (rng.random::<f64>(), rng.random::<f64>());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let [p, q, r] = f.map(|v| mesh.vertices[v]);
            p * (1.0 - a - b) + q * a + r * b
        })
        .collect()
}

/// The truth of the free-flying case: `truth` followed by a rigid motion (about 29° and 3 cm).
pub fn moved(p: &Vector3<f64>) -> Vector3<f64> {
    let m = Isometry3::new(
        Vector3::new(0.01, -0.02, 0.015),
        Vector3::new(0.3, -0.2, 0.35),
    );
    m.transform_point(&truth(p).into()).coords
}

/// The known-truth problem (12 landmarks, 150 ICP markers on the boundary, the x = 0 face
/// attached) and 400 held-out template boundary points; `free_flying`: no attachments and the
/// targets moved rigidly ([`moved`]).
pub fn problem(free_flying: bool) -> (ReshapeProblem, Vec<Vector3<f64>>) {
    problem_with_cells(free_flying, [8, 5, 3])
}

/// [`problem`] on a template of `cells` box cells (6 tets each).
pub fn problem_with_cells(
    free_flying: bool,
    cells: [usize; 3],
) -> (ReshapeProblem, Vec<Vector3<f64>>) {
    let truth: fn(&Vector3<f64>) -> Vector3<f64> = if free_flying { moved } else { truth };
    let mesh = box_tet_mesh([0.0; 3], [0.1, 0.06, 0.04], cells);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let locator = TetLocator::new(&mesh);
    // Boundary points of the template lie in (or on) one of its tets.
    let embed = |p: &Vector3<f64>| {
        locator
            .locate(p)
            .map_or(MaterialPoint::node(0), |e| MaterialPoint {
                nodes: mesh.tets[e.tet],
                weights: e.weights,
            })
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
            icp_surface: None,
        },
        held_out,
    )
}
