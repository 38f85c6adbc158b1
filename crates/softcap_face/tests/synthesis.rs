//! Thesis §3.3.1 wrinkle synthesis on a flat skin patch (cm) seen by a pinhole camera: an
//! image-space wrinkle of known (d, w) is projected, the valley offset, and the shell energy
//! (eq. 3.6) minimised; the synthesized cross-section is compared with S(w, d, p).

use softcap_face::nalgebra::{Isometry3, Vector3};
use softcap_face::{
    PinholeCamera, SynthesisSettings, WrinkleCurve, WrinkleSample, project_wrinkle,
    synthesize_wrinkles, wrinkle_profile,
};
use softcap_mesh::TriMesh;

const H: f64 = 0.025; // grid spacing, cm
const N: usize = 61; // vertices per side: [-0.75, 0.75]²

fn grid() -> TriMesh {
    let c = (N - 1) as f64 * H / 2.0;
    let mut vertices = Vec::new();
    for j in 0..N {
        for i in 0..N {
            vertices.push(Vector3::new(i as f64 * H - c, j as f64 * H - c, 0.0));
        }
    }
    let mut triangles = Vec::new();
    for j in 0..N - 1 {
        for i in 0..N - 1 {
            let v = j * N + i;
            if (i + j).is_multiple_of(2) {
                triangles.push([v, v + 1, v + N + 1]);
                triangles.push([v, v + N + 1, v + N]);
            } else {
                triangles.push([v, v + 1, v + N]);
                triangles.push([v + 1, v + N + 1, v + N]);
            }
        }
    }
    TriMesh {
        vertices,
        triangles,
    }
}

/// Camera 10 cm above the patch looking down (−z), 1000 px focal: 0.01 cm per pixel.
fn top_camera() -> PinholeCamera {
    PinholeCamera {
        world_from_camera: Isometry3::new(
            Vector3::new(0.0, 0.0, 10.0),
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
        ),
        focal_px: 1000.0,
        principal_px: [500.0, 500.0],
    }
}

fn straight_wrinkle(
    cam: &PinholeCamera,
    y_cm: f64,
    x_range: (f64, f64),
    d_px: f64,
    w_px: f64,
) -> WrinkleCurve {
    let mut samples = Vec::new();
    let mut x = x_range.0;
    while x <= x_range.1 + 1e-12 {
        let px = cam.project(&Vector3::new(x, y_cm, 0.0)).unwrap();
        samples.push(WrinkleSample {
            valley_px: px,
            depth_px: d_px,
            width_px: w_px,
        });
        x += 0.05;
    }
    WrinkleCurve { samples }
}

#[test]
fn synthesized_cross_section_matches_truth_profile() {
    let mesh = grid();
    let cam = top_camera();
    // truth in pixels: d = 10 px, w = 20 px → d = 0.1 cm, w = 0.2 cm at 0.01 cm/px
    let (d_px, w_px) = (10.0, 20.0);
    let (d, w) = (0.1, 0.2);
    let y0 = 0.5 * H; // valley midway between two vertex rows
    let curve = straight_wrinkle(&cam, y0, (-0.6, 0.6), d_px, w_px);
    let settings = SynthesisSettings::default();
    let t0 = std::time::Instant::now();
    let out = synthesize_wrinkles(&mesh, &mesh.vertices, &cam, &[curve], &settings).unwrap();
    let secs = t0.elapsed().as_secs_f64();
    assert_eq!(out.regions.len(), 1);
    let r = &out.regions[0];
    println!(
        "region: {} free, {} valley vertices; E {:.4e} → {:.4e} in {} GN iterations (converged {}), {secs:.2} s",
        r.free_vertices,
        r.valley_vertices,
        r.initial_energy,
        r.final_energy,
        r.iterations,
        r.converged
    );
    assert!(r.converged);
    assert!(r.final_energy < 0.5 * r.initial_energy);
    // projected valley: on the line y = y0, z = 0 with d, w in cm
    let pw = &out.projected[0];
    for (k, p) in pw.points.iter().enumerate() {
        assert!((p.y - y0).abs() < 1e-9 && p.z.abs() < 1e-9);
        assert!((pw.depth[k] - d).abs() < 1e-9 && (pw.width[k] - w).abs() < 1e-9);
    }
    // cross-section at the middle column x = 0
    let col = (N - 1) / 2;
    let profile: Vec<(f64, f64)> = (0..N)
        .map(|j| {
            let v = out.vertices[j * N + col];
            (v.y - y0, v.z)
        })
        .collect();
    let mut valley_err: f64 = 0.0;
    for &(p, z) in &profile {
        if p.abs() <= w {
            valley_err = valley_err.max((z - wrinkle_profile(w, d, p)).abs());
        }
    }
    // zero crossings (surface back at rest level) on either side of the valley
    let crossing = |sign: f64| -> f64 {
        let mut pts: Vec<(f64, f64)> = profile
            .iter()
            .copied()
            .filter(|&(p, _)| p * sign >= 0.0)
            .map(|(p, z)| (p.abs(), z))
            .collect();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        for k in 0..pts.len() - 1 {
            let ((p0, z0), (p1, z1)) = (pts[k], pts[k + 1]);
            if z0 < 0.0 && z1 >= 0.0 {
                return p0 + (p1 - p0) * (-z0) / (z1 - z0);
            }
        }
        f64::NAN
    };
    let w_est = 0.5 * (crossing(1.0) + crossing(-1.0));
    let (bulge_p, bulge_z) = profile
        .iter()
        .filter(|(p, _)| p.abs() > w)
        .map(|&(p, z)| (p.abs(), z))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    // the constrained valley's depth: fit d on the valley vertices by least squares on S(w, 1, p)
    let (mut num, mut den) = (0.0, 0.0);
    for &(p, z) in &profile {
        if p.abs() <= w {
            let g = wrinkle_profile(w, 1.0, p);
            num += g * z;
            den += g * g;
        }
    }
    let d_est = num / den;
    let rms_outside = {
        let v: Vec<f64> = profile
            .iter()
            .filter(|(p, _)| p.abs() > w && p.abs() <= 3.0 * w)
            .map(|&(p, z)| z - wrinkle_profile(w, d, p))
            .collect();
        (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt()
    };
    println!(
        "truth d = {d} cm, w = {w} cm; synthesized: valley max |z − S| = {valley_err:.2e} cm, \
         d fit {d_est:.5} cm ({:+.2} %), zero crossing w = {w_est:.4} cm ({:+.1} %), \
         bulge {bulge_z:.4} cm at p = {bulge_p:.3} cm (S: {:.4} cm at 2w = {:.3}), \
         rms(z − S) over w < |p| ≤ 3w = {rms_outside:.4} cm",
        100.0 * (d_est - d) / d,
        100.0 * (w_est - w) / w,
        d * (-2f64).exp(),
        2.0 * w
    );
    // valley vertices carry S exactly (flat patch: smoothed normals are +z)
    assert!(valley_err < 1e-9, "valley error {valley_err}");
    assert!((d_est - d).abs() < 1e-6 * d);
    // outside the valley the surface is the shell's: it returns to rest level within 10 % of w
    // and bulges upward (thesis Fig. 3.4)
    assert!(
        (w_est - w).abs() < 0.10 * w,
        "zero crossing {w_est} vs w = {w}"
    );
    assert!(bulge_z > 0.0);
}

#[test]
fn oblique_camera_projects_valley_onto_surface_and_regions_merge() {
    let mesh = grid();
    // camera tilted 25° about x, looking at the origin from 10 cm
    let tilt = 25f64.to_radians();
    let eye = Vector3::new(0.0, -10.0 * tilt.sin(), 10.0 * tilt.cos());
    let cam = PinholeCamera {
        world_from_camera: Isometry3::new(eye, Vector3::new(std::f64::consts::PI - tilt, 0.0, 0.0)),
        focal_px: 1000.0,
        principal_px: [500.0, 500.0],
    };
    let curve = straight_wrinkle(&cam, 0.2, (-0.5, 0.5), 5.0, 10.0);
    let pw = project_wrinkle(&mesh.vertices, &mesh.triangles, &cam, &curve);
    assert_eq!(pw.points.len(), curve.samples.len());
    let worst = pw
        .points
        .iter()
        .map(|p| (p.y - 0.2).abs().max(p.z.abs()))
        .fold(0.0, f64::max);
    println!("oblique projection: worst distance to the true valley line {worst:.2e} cm");
    assert!(worst < 1e-9);

    // two wrinkles 0.6 cm apart, w = 0.05 cm: separate regions at 4w, one region at 8w
    let cam = top_camera();
    let a = straight_wrinkle(&cam, -0.3 + 0.5 * H, (-0.4, 0.4), 2.5, 5.0);
    let b = straight_wrinkle(&cam, 0.3 + 0.5 * H, (-0.4, 0.4), 2.5, 5.0);
    let narrow = synthesize_wrinkles(
        &mesh,
        &mesh.vertices,
        &cam,
        &[a.clone(), b.clone()],
        &SynthesisSettings::default(),
    )
    .unwrap();
    let wide = synthesize_wrinkles(
        &mesh,
        &mesh.vertices,
        &cam,
        &[a, b],
        &SynthesisSettings {
            influence_widths: 8.0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(narrow.regions.len(), 2);
    assert_eq!(wide.regions.len(), 1);
}
