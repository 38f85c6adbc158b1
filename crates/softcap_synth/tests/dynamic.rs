//! Dynamic scenarios of the virtual rig (wang2015 §4–5): the session's files, depth images that
//! lie on the truth surface, the sensor noise model, the unseen fraction, determinism.

use std::path::Path;

use softcap_mesh::nalgebra::{Point3, Vector3};
use softcap_mesh::{SurfaceRayCaster, TriLocator, TriMesh};
use softcap_synth::dynamic::{Motion, depth, truth};
use softcap_synth::{Scenario, synthesize};

/// A small, fast release scenario: 100 × 20 × 20 mm bar, 8 frames, 160 × 120 px cameras.
fn small(motion: Motion) -> Scenario {
    let mut s = Scenario::parse(
        Path::new("<test>"),
        "name = \"small\"\nkind = \"dynamic\"\n",
    )
    .unwrap();
    s.object.size_mm = [100.0, 20.0, 20.0];
    s.object.fit_cells = [4, 1, 1];
    s.object.truth_cells = [8, 2, 2];
    s.object.density_kg_m3 = 1100.0;
    s.material.young_pa = 5.0e5;
    s.material.poisson = 0.4;
    let d = &mut s.dynamic;
    d.motion = motion;
    d.frames = 8;
    d.substeps = 4;
    d.rest_frames = 1;
    d.push_frames = 3;
    d.push_force_n = [0.0, 0.2, -0.3];
    d.shake_frames = 5;
    d.sensor.width = 160;
    d.sensor.height = 120;
    d.sensor.focal_px = 145.0;
    d.track_points = 60;
    s
}

#[test]
fn dynamic_session_has_the_format_files_and_a_moving_truth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let r = synthesize(&small(Motion::Release), &out).unwrap();
    assert_eq!(r.frames, 8);
    assert_eq!(r.images, 16);
    let toml = std::fs::read_to_string(out.join("session.toml")).unwrap();
    for key in [
        "kind = \"dynamic\"",
        "depth_cameras = \"rig/depth_cameras.toml\"",
        "interactions = \"interactions.csv\"",
        "[support]",
        "density_kg_m3",
    ] {
        assert!(toml.contains(key), "session.toml lacks {key}:\n{toml}");
    }
    for f in [
        "rig/depth_cameras.toml",
        "trigger.csv",
        "template/volume.msh",
        "interactions.csv",
        "truth/track_points.csv",
        "truth/template_nodes.csv",
        "truth/material.toml",
        "depth/depth0/000007.png",
        "depth/depth1/000000.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let img = image::open(out.join("depth/depth0/000003.png")).unwrap();
    assert!(matches!(img, image::DynamicImage::ImageLuma16(_)));
    assert_eq!((img.width(), img.height()), (160, 120));
    let track = std::fs::read_to_string(out.join("truth/track_points.csv")).unwrap();
    assert_eq!(track.lines().count(), 1 + 8 * 60);
    // the push moves the free end by millimetres
    assert!(
        r.max_marker_displacement_m > 1e-3,
        "{}",
        r.max_marker_displacement_m
    );
    assert!(r.depth_readings > 1000);
    assert!(
        r.unseen_fraction > 0.05 && r.unseen_fraction < 0.6,
        "{}",
        r.unseen_fraction
    );
}

/// Noise off: every depth reading back-projects (softcap_core::Camera::back_project) onto the
/// truth surface; noise on: the readings scatter about it by about σ_z = c z².
#[test]
fn depth_readings_lie_on_the_truth_surface() {
    let mut s = small(Motion::Release);
    let sensor = &mut s.dynamic.sensor;
    sensor.sigma_z_per_m = 0.0;
    sensor.disparity_step_px = 0.0;
    sensor.dropout_probability = 0.0;
    sensor.edge_outlier_probability = 0.0;
    let t = truth::simulate(&s).unwrap();
    let faces = t.mesh.boundary_faces();
    let x = &t.frames[5].positions_m;
    let caster = SurfaceRayCaster::new(x, &faces).unwrap();
    let surface = TriMesh {
        vertices: x.clone(),
        triangles: faces.clone(),
    };
    let locator = TriLocator::new(&surface);
    let aim = Vector3::new(0.05, 0.0, 0.0);
    let cams = depth::rig(&s.dynamic, &aim).unwrap();
    let distances = |noisy: bool| -> Vec<f64> {
        let mut sensor = s.dynamic.sensor.clone();
        if noisy {
            sensor.sigma_z_per_m = 1.425e-3;
        }
        let mut rng = softcap_synth::truth::stream(1, 99);
        let img = depth::render(&cams[0], &caster, x, &sensor, &mut rng);
        let mut out = Vec::new();
        for v in 0..img.height as usize {
            for u in 0..img.width as usize {
                let z = img.depth_m[v * img.width as usize + u];
                if z > 0.0 {
                    let p: Point3<f64> = cams[0].camera.back_project(u as f64, v as f64, z);
                    out.push(locator.locate(&p.coords).unwrap().distance);
                }
            }
        }
        out
    };
    let exact = distances(false);
    assert!(exact.len() > 50, "{} readings", exact.len());
    let worst = exact.iter().fold(0.0f64, |m, d| m.max(*d));
    assert!(worst < 1e-9, "noise-free reading {worst} m off the surface");
    let noisy = distances(true);
    let rms = (noisy.iter().map(|d| d * d).sum::<f64>() / noisy.len() as f64).sqrt();
    // the cameras are 0.8 m away: σ_z ≈ 1.425e-3 · 0.8² ≈ 0.9 mm along the ray, less normal to
    // the surface
    assert!(rms > 2e-4 && rms < 1.5e-3, "noisy rms {rms}");
}

#[test]
fn every_motion_simulates_and_the_same_seed_gives_the_same_files() {
    for motion in [Motion::Drop, Motion::Shake] {
        let dir = tempfile::tempdir().unwrap();
        let s = small(motion);
        let a = synthesize(&s, &dir.path().join("a")).unwrap();
        assert!(
            a.max_marker_displacement_m > 1e-3,
            "{motion:?}: {}",
            a.max_marker_displacement_m
        );
        if motion == Motion::Shake {
            let sm = std::fs::read_to_string(dir.path().join("a/support_motion.csv")).unwrap();
            assert_eq!(sm.lines().count(), 1 + 8);
            synthesize(&s, &dir.path().join("b")).unwrap();
            for f in [
                "depth/depth1/000006.png",
                "truth/track_points.csv",
                "template/volume.msh",
            ] {
                assert_eq!(
                    std::fs::read(dir.path().join("a").join(f)).unwrap(),
                    std::fs::read(dir.path().join("b").join(f)).unwrap(),
                    "{f} differs between two runs with the same seed"
                );
            }
        }
    }
}

#[test]
fn bad_dynamic_scenarios_name_the_field() {
    for (text, field) in [
        ("[dynamic]\nframes = 1\n", "dynamic.frames"),
        ("[dynamic]\nmotion = \"wobble\"\n", "motion"),
        (
            "[dynamic.sensor]\ngrazing_deg = 120.0\n",
            "dynamic.sensor.grazing_deg",
        ),
        ("[dynamic]\ncameras = []\n", "dynamic.cameras"),
    ] {
        let full = format!("name = \"x\"\nkind = \"dynamic\"\n{text}");
        let e = Scenario::parse(Path::new("x.toml"), &full)
            .unwrap_err()
            .to_string();
        assert!(e.contains(field), "{text:?}: {e}");
    }
}
