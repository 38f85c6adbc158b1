//! The files of a dynamic session (SESSION_FORMAT.md "Dynamic sessions", length unit mm) and of
//! its `truth/`.

use std::fmt::Write as _;

use nalgebra::Vector3;
use softcap_mesh::TetMesh;

use super::depth::{DepthCamera, DepthImage};
use super::settings::Motion;
use super::truth::DynamicTruth;
use super::{Observation, ensure_dir};
use crate::error::{Result, SynthError};
use crate::scenario::Scenario;
use crate::write::{SessionWriter, write_template_meshes};

const M_TO_MM: f64 = 1e3;

fn mm(v: f64) -> String {
    format!("{:.4}", v * M_TO_MM)
}

/// session.toml, rig/depth_cameras.toml, trigger.csv, template/, support_motion.csv,
/// interactions.csv.
pub(super) fn write_static(
    s: &Scenario,
    truth: &DynamicTruth,
    template_frame0: &[Vector3<f64>],
    cams: &[DepthCamera],
    w: &SessionWriter,
) -> Result<()> {
    let d = &s.dynamic;
    w.text("session.toml", &session_toml(s, truth))?;
    w.text("rig/depth_cameras.toml", &depth_cameras_toml(s, cams))?;
    let mut trig = String::from("frame,t_camera_s\n");
    for f in &truth.frames {
        let _ = writeln!(trig, "{},{:.6}", f.frame, f.t_s);
    }
    w.text("trigger.csv", &trig)?;
    write_template_meshes(
        w,
        &TetMesh {
            vertices: template_frame0.to_vec(),
            tets: truth.template_rest.tets.clone(),
        },
    )?;
    if d.motion == Motion::Shake {
        let mut t = String::from("frame,qw,qx,qy,qz,tx,ty,tz\n");
        for (f, m) in truth.frames.iter().zip(&truth.support_motion) {
            let q = m.rotation.quaternion();
            let _ = writeln!(
                t,
                "{},{:.9},{:.9},{:.9},{:.9},{},{},{}",
                f.frame,
                q.w,
                q.i,
                q.j,
                q.k,
                mm(m.translation_m.x),
                mm(m.translation_m.y),
                mm(m.translation_m.z)
            );
        }
        w.text("support_motion.csv", &t)?;
    }
    if !truth.interactions.is_empty() {
        let mut t = String::from("t_start_s,t_end_s\n");
        for (a, b) in &truth.interactions {
            let _ = writeln!(t, "{a:.6},{b:.6}");
        }
        w.text("interactions.csv", &t)?;
    }
    Ok(())
}

fn session_toml(s: &Scenario, truth: &DynamicTruth) -> String {
    let d = &s.dynamic;
    let mut t = String::new();
    let _ = writeln!(t, "format = \"softcap-session/1\"");
    let _ = writeln!(t, "name = \"{}\"", s.name);
    let _ = writeln!(t, "kind = \"dynamic\"");
    let _ = writeln!(t, "length_unit = \"mm\"\n");
    let _ = writeln!(t, "[files]");
    let _ = writeln!(t, "volume = \"template/volume.msh\"");
    let _ = writeln!(t, "surface = \"template/surface.obj\"");
    let _ = writeln!(t, "depth_cameras = \"rig/depth_cameras.toml\"");
    let _ = writeln!(t, "depth = \"depth\"");
    let _ = writeln!(t, "trigger = \"trigger.csv\"");
    if d.motion == Motion::Shake {
        let _ = writeln!(t, "support_motion = \"support_motion.csv\"");
    }
    if !truth.interactions.is_empty() {
        let _ = writeln!(t, "interactions = \"interactions.csv\"");
    }
    let g = truth.material.gravity_m_s2;
    let _ = writeln!(
        t,
        "\n[world]\ngravity = [{:?}, {:?}, {:?}]",
        g[0], g[1], g[2]
    );
    if let Some(p) = &truth.support {
        let _ = writeln!(
            t,
            "\n[support]\nplane_normal = [{:?}, {:?}, {:?}]\nplane_offset = {}\ntolerance = {}",
            p.normal.x,
            p.normal.y,
            p.normal.z,
            mm(p.offset_m),
            mm(p.tolerance_m.max(1e-5))
        );
    }
    let _ = writeln!(
        t,
        "\n[object]\ndensity_kg_m3 = {:?}",
        truth.material.density_kg_m3
    );
    t
}

fn depth_cameras_toml(s: &Scenario, cams: &[DepthCamera]) -> String {
    let sensor = &s.dynamic.sensor;
    let mut t =
        String::from("# depth cameras (SESSION_FORMAT.md \"Dynamic sessions\"), length unit mm\n");
    for c in cams {
        let cam = &c.camera;
        let [fx, fy, cx, cy] = cam.intrinsics;
        let [k1, k2, p1, p2, k3] = cam.distortion;
        let r = cam.rotation;
        let tr = cam.translation_m * M_TO_MM;
        let _ = writeln!(
            t,
            "\n[[camera]]\nid = \"{}\"\nwidth = {}\nheight = {}\nfx = {fx:?}\nfy = {fy:?}\ncx = {cx:?}\ncy = {cy:?}\n\
             k1 = {k1:?}\nk2 = {k2:?}\np1 = {p1:?}\np2 = {p2:?}\nk3 = {k3:?}\n\
             rotation = [{:?}, {:?}, {:?}, {:?}, {:?}, {:?}, {:?}, {:?}, {:?}]\n\
             translation = [{:?}, {:?}, {:?}]\ndepth_scale = {:?}\nmin_depth = {:?}\nmax_depth = {:?}",
            cam.id,
            cam.width,
            cam.height,
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
            tr.x,
            tr.y,
            tr.z,
            sensor.depth_scale_mm,
            sensor.min_depth_mm,
            sensor.max_depth_mm
        );
    }
    t
}

/// depth/<camera>/<frame>.png: 16-bit grayscale.
pub(super) fn write_depth_png(
    w: &SessionWriter,
    camera: &str,
    frame: usize,
    img: &DepthImage,
    counts: &[u16],
) -> Result<()> {
    let dir = w.path(&format!("depth/{camera}"));
    ensure_dir(&dir)?;
    let path = dir.join(format!("{frame:06}.png"));
    let buf: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
        image::ImageBuffer::from_raw(img.width, img.height, counts.to_vec()).ok_or_else(|| {
            SynthError::Image {
                path: path.clone(),
                message: "depth buffer size disagrees with the image size".into(),
            }
        })?;
    buf.save_with_format(&path, image::ImageFormat::Png)
        .map_err(|e| SynthError::Image {
            path: path.clone(),
            message: e.to_string(),
        })
}

/// truth/: track_points.csv, template_nodes.csv, template_rest.csv, material.toml, README.md,
/// scenario.toml.
pub(super) fn write_truth(
    s: &Scenario,
    truth: &DynamicTruth,
    obs: &Observation,
    w: &SessionWriter,
) -> Result<()> {
    let mut t = String::from("frame,id,x,y,z,seen\n");
    for (f, (points, seen)) in truth
        .frames
        .iter()
        .zip(obs.track_points_m.iter().zip(&obs.seen))
    {
        for (id, (p, v)) in points.iter().zip(seen).enumerate() {
            let _ = writeln!(
                t,
                "{},{id},{},{},{},{}",
                f.frame,
                mm(p.x),
                mm(p.y),
                mm(p.z),
                u8::from(*v)
            );
        }
    }
    w.text("truth/track_points.csv", &t)?;
    let mut t = String::from("frame,node,x,y,z\n");
    for (f, nodes) in truth.frames.iter().zip(&obs.template_nodes_m) {
        for (i, p) in nodes.iter().enumerate() {
            let _ = writeln!(t, "{},{i},{},{},{}", f.frame, mm(p.x), mm(p.y), mm(p.z));
        }
    }
    w.text("truth/template_nodes.csv", &t)?;
    let mut t = String::from("node,x,y,z\n");
    for (i, p) in truth.template_rest.vertices.iter().enumerate() {
        let _ = writeln!(t, "{i},{},{},{}", mm(p.x), mm(p.y), mm(p.z));
    }
    w.text("truth/template_rest.csv", &t)?;
    w.text("truth/material.toml", &material_toml(truth))?;
    w.text("truth/README.md", &readme(s, truth, obs))?;
    w.text(
        "truth/scenario.toml",
        &toml::to_string(s).unwrap_or_else(|e| format!("# scenario not serialisable: {e}\n")),
    )
}

fn material_toml(truth: &DynamicTruth) -> String {
    let m = &truth.material;
    format!(
        "# The simulated material (SI). The rest shape of the template's nodes is truth/template_rest.csv (mm):\n\
         # the stress-free box, not the frame-0 shape in template/volume.msh.\n\
         model = \"stable-neo-hookean\"\nsolver = \"{}\"\nyoung_pa = {:?}\npoisson = {:?}\ndensity_kg_m3 = {:?}\n\
         rayleigh_alpha_per_s = {:?}\nrayleigh_beta_s = {:?}\ngravity_m_s2 = [{:?}, {:?}, {:?}]\n\
         rest_shape = \"truth/template_rest.csv\"\ntruth_tets = {}\ntemplate_tets = {}\n",
        truth.solver,
        m.young_pa,
        m.poisson,
        m.density_kg_m3,
        m.rayleigh_alpha_per_s,
        m.rayleigh_beta_s,
        m.gravity_m_s2[0],
        m.gravity_m_s2[1],
        m.gravity_m_s2[2],
        truth.mesh.tets.len(),
        truth.template_rest.tets.len()
    )
}

fn readme(s: &Scenario, truth: &DynamicTruth, obs: &Observation) -> String {
    let d = &s.dynamic;
    let [l, wd, h] = s.object.size_mm;
    let motion = match d.motion {
        Motion::Release => format!(
            "release: clamped at x = 0, sagging under gravity in frame 0; a hand pushes {:?} N (total, smoothstep over {} frames) on the boundary nodes within {} mm of the push point and lets go; interactions.csv holds the push",
            d.push_force_n, d.push_frames, d.push_radius_mm
        ),
        Motion::Drop => format!(
            "drop: free block held {} mm above the floor z = 0, tilted {} deg about x, let go at t = 0; the floor is a penalty contact (factor {}); interactions.csv holds the contact intervals",
            d.drop_height_mm, d.drop_tilt_deg, d.floor_penalty_factor
        ),
        Motion::Shake => format!(
            "shake: clamped at x = 0, the clamp translates {:?} mm and rotates {:?} deg (amplitudes) at {} Hz under a Hann window over {} frames (support_motion.csv), then rings freely",
            d.shake_amplitude_mm, d.shake_rotation_deg, d.shake_frequency_hz, d.shake_frames
        ),
    };
    let motion = truth.motion_note.clone().unwrap_or(motion);
    let m = &truth.material;
    let sensor = &d.sensor;
    format!(
        "# Ground truth of {} (synthetic, softcap synth, dynamic)\n\n\
         - Object: box {l} x {wd} x {h} mm; {motion}.\n\
         - Truth: {} on {} tets; E = {} Pa, nu = {}, density {} kg/m^3, Rayleigh alpha = {} 1/s, beta = {} s, gravity {:?} m/s^2; {} steps needed sub-stepping.\n\
         - Template: template/volume.msh, {} tets, its nodes carried by the truth to frame 0 (truth/template_nodes.csv every frame; rest positions truth/template_rest.csv).\n\
         - Cameras: {} depth cameras at {} Hz, {} x {} px, f = {} px; noise sigma_z = {} z^2 (m), disparity step {} px (baseline {} mm), grazing holes beyond {} deg, dropout {}, flying pixels at silhouettes with probability {}.\n\
         - Track points: {} material points on the surface (truth/track_points.csv, `seen` = some camera sees it); unseen fraction over all frames {:.3}.\n\
         - {} valid depth readings in all.\n\
         - Seed {}.\n",
        s.name,
        truth.solver,
        truth.mesh.tets.len(),
        m.young_pa,
        m.poisson,
        m.density_kg_m3,
        m.rayleigh_alpha_per_s,
        m.rayleigh_beta_s,
        m.gravity_m_s2,
        truth.retried_steps,
        truth.template_rest.tets.len(),
        d.cameras.len(),
        d.frame_rate_hz,
        sensor.width,
        sensor.height,
        sensor.focal_px,
        sensor.sigma_z_per_m,
        sensor.disparity_step_px,
        sensor.baseline_mm,
        sensor.grazing_deg,
        sensor.dropout_probability,
        sensor.edge_outlier_probability,
        d.track_points,
        obs.unseen_fraction(),
        obs.readings.iter().sum::<usize>(),
        s.seed
    )
}
