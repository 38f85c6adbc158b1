//! Dynamic sessions (SESSION_FORMAT.md "Dynamic sessions"): depth images back-projected through
//! the distortion model into world-frame clouds with normals; PLY input; bad input exits 2 naming
//! the file and writes nothing.

use std::path::Path;
use std::process::Command;

use softcap_capture::{DepthCaptureSettings, Session, capture_dynamic, nalgebra::Vector3};
use softcap_mcap::dynamic::DynamicCaptureData;

const W: u32 = 48;
const H: u32 = 36;

/// A session with one depth camera looking straight down (+z camera = −z world) at a plane
/// z = 0 from 500 mm, with slight distortion; `frames` frames; depth in mm, scale 0.1 mm.
fn write_session(dir: &Path, frames: usize) {
    std::fs::create_dir_all(dir.join("rig")).unwrap();
    std::fs::create_dir_all(dir.join("template")).unwrap();
    std::fs::write(
        dir.join("session.toml"),
        "format = \"softcap-session/1\"\nname = \"plane\"\nkind = \"dynamic\"\nlength_unit = \"mm\"\n\n\
         [files]\nvolume = \"template/volume.msh\"\ndepth_cameras = \"rig/depth_cameras.toml\"\n\
         depth = \"depth\"\ntrigger = \"trigger.csv\"\n\n[object]\ndensity_kg_m3 = 1000.0\n",
    )
    .unwrap();
    // world→camera: x_c = x, y_c = −y, z_c = −z + 500
    std::fs::write(
        dir.join("rig/depth_cameras.toml"),
        format!(
            "[[camera]]\nid = \"d0\"\nwidth = {W}\nheight = {H}\nfx = 60.0\nfy = 60.5\ncx = 23.7\ncy = 17.4\n\
             k1 = -0.05\nk2 = 0.01\np1 = 0.001\np2 = -0.0005\n\
             rotation = [1, 0, 0, 0, -1, 0, 0, 0, -1]\ntranslation = [0.0, 0.0, 500.0]\n\
             depth_scale = 0.1\nmin_depth = 100.0\nmax_depth = 2000.0\n"
        ),
    )
    .unwrap();
    let mesh = softcap_mesh::box_tet_mesh([-50.0, -50.0, -10.0], [50.0, 50.0, 0.0], [2, 2, 1]);
    softcap_mesh::write_msh(
        dir.join("template/volume.msh"),
        &softcap_mesh::MshMesh::from_tet_mesh(&mesh, None),
    )
    .unwrap();
    let mut trig = String::from("frame,t_camera_s\n");
    for f in 0..frames {
        trig.push_str(&format!("{f},{}\n", f as f64 / 30.0));
        write_depth(dir, f, |u, _| if u < 3 { 0 } else { 5000 });
    }
    std::fs::write(dir.join("trigger.csv"), trig).unwrap();
}

fn write_depth(dir: &Path, frame: usize, count: impl Fn(u32, u32) -> u16) {
    let d = dir.join("depth/d0");
    std::fs::create_dir_all(&d).unwrap();
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(W, H, |u, v| {
        image::Luma([count(u, v)])
    });
    img.save(d.join(format!("{frame:06}.png"))).unwrap();
}

#[test]
fn depth_pixels_back_project_onto_the_plane_with_its_normal() {
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 2);
    let session = Session::load(dir.path()).unwrap();
    let c = capture_dynamic(&session, &DepthCaptureSettings::default()).unwrap();
    assert_eq!(c.frames.len(), 2);
    let f = &c.frames[1];
    // every pixel but the 3 empty columns has a reading; border pixels keep one-sided normals
    assert_eq!(f.points_m.len(), ((W - 3) * H) as usize);
    for (p, n) in f.points_m.iter().zip(&f.normals) {
        assert!(p.z.abs() < 1e-6, "{p}");
        assert!((n - Vector3::new(0.0, 0.0, 1.0)).norm() < 1e-5, "{n}");
    }
    // the distortion model is inverted: a pixel's point reprojects to that pixel
    let cam = &c.cameras[0].camera;
    let p = f.points_m[5].cast::<f64>();
    let uv = cam.project(&p.into()).unwrap();
    assert!(
        (uv.x - (3.0 + 5.0)).abs() < 1e-3 && uv.y.abs() < 1e-3,
        "{uv}"
    );
    // voxel downsampling: 10 mm voxels on a plane seen at ~8 mm per pixel
    let v = capture_dynamic(
        &session,
        &DepthCaptureSettings {
            voxel_size_m: 0.02,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(v.frames[0].points_m.len() < f.points_m.len() / 2);
    assert_eq!(v.frames[0].normals.len(), v.frames[0].points_m.len());
}

#[test]
fn capture_cli_writes_the_clouds_and_a_pointcloud_twin() {
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 3);
    let out = dir.path().join("capture.mcap");
    let st = Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg(dir.path())
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    let data = DynamicCaptureData::read(&out).unwrap();
    assert_eq!(data.frames.len(), 3);
    assert_eq!(data.dynamic.cameras.len(), 1);
    assert_eq!(data.session.kind, "dynamic");
    let r = softcap_mcap::Recording::open(&out).unwrap();
    assert!(r.channel("/viz/capture/points").is_some());
}

fn run_capture(dir: &Path) -> (i32, String, bool) {
    let out = dir.join("capture.mcap");
    let st = Command::new(env!("CARGO_BIN_EXE_softcap-capture"))
        .arg(dir)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    (
        st.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&st.stderr).into_owned(),
        out.exists(),
    )
}

#[test]
fn bad_depth_input_exits_2_naming_the_file_and_writes_nothing() {
    // an 8-bit PNG
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 2);
    let p = dir.path().join("depth/d0/000001.png");
    image::GrayImage::from_pixel(W, H, image::Luma([9]))
        .save(&p)
        .unwrap();
    let (code, err, written) = run_capture(dir.path());
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("000001.png") && err.contains("16-bit"),
        "{err}"
    );
    assert!(!written);
    // a depth image whose size disagrees with its camera
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 2);
    let p = dir.path().join("depth/d0/000000.png");
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(W + 2, H, image::Luma([5000]))
        .save(&p)
        .unwrap();
    let (code, err, written) = run_capture(dir.path());
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("000000.png") && err.contains("camera `d0`"),
        "{err}"
    );
    assert!(!written);
    // a missing frame
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 3);
    std::fs::remove_file(dir.path().join("depth/d0/000002.png")).unwrap();
    let (code, err, written) = run_capture(dir.path());
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("000002.png"), "{err}");
    assert!(!written);
}

#[test]
fn fused_ply_clouds_are_read_in_the_session_unit() {
    let dir = tempfile::tempdir().unwrap();
    write_session(dir.path(), 1);
    let toml = std::fs::read_to_string(dir.path().join("session.toml"))
        .unwrap()
        .replace("depth = \"depth\"\n", "points = \"points\"\n");
    std::fs::write(dir.path().join("session.toml"), toml).unwrap();
    std::fs::create_dir_all(dir.path().join("points")).unwrap();
    std::fs::write(
        dir.path().join("points/000000.ply"),
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n10 20 30\n-5 0 1\n",
    )
    .unwrap();
    let session = Session::load(dir.path()).unwrap();
    let c = capture_dynamic(&session, &DepthCaptureSettings::default()).unwrap();
    assert_eq!(c.frames[0].points_m.len(), 2);
    assert!((c.frames[0].points_m[0] - Vector3::new(0.01f32, 0.02, 0.03)).norm() < 1e-7);
    assert!(c.frames[0].normals.is_empty());
}
