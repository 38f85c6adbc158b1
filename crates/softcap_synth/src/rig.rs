//! The camera rig: cameras in a triangle above the object (`softcap_core::camera`, OpenCV
//! Brown–Conrady model), visibility of markers (image bounds, facing, occlusion by the probe) and
//! the 2D detections with noise, dropouts and spurious blobs.

use nalgebra::{Isometry3, Matrix3, Point3, Vector2, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use softcap_core::Camera;

use crate::error::Result;
use crate::scenario::Scenario;
use crate::truth::{FrameTruth, ProbeGeometry, Truth};

const MM: f64 = 1e-3;

/// The rig's cameras (world→camera extrinsics in metres).
pub fn cameras(s: &Scenario, block_size_m: &Vector3<f64>) -> Result<Vec<Camera>> {
    let r = &s.rig;
    let aim = r
        .aim_mm
        .map(|a| Vector3::from(a) * MM)
        .unwrap_or(Vector3::new(
            0.5 * block_size_m.x,
            0.5 * block_size_m.y,
            block_size_m.z + r.aim_above_top_mm * MM,
        ));
    let n = r.cameras;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let az = std::f64::consts::TAU * k as f64 / n as f64 + 0.35;
        let tilt = r.tilt_deg.to_radians();
        let dir_to_cam = Vector3::new(tilt.sin() * az.cos(), tilt.sin() * az.sin(), tilt.cos());
        let centre = aim + dir_to_cam * (r.distance_mm * MM);
        let zc = (aim - centre).normalize();
        let hint = if zc.cross(&Vector3::z()).norm() > 1e-6 {
            Vector3::z()
        } else {
            Vector3::y()
        };
        let xc = zc.cross(&hint).normalize();
        let yc = zc.cross(&xc);
        let rot = Matrix3::from_rows(&[xc.transpose(), yc.transpose(), zc.transpose()]);
        let t = -(rot * centre);
        // Slightly different intrinsics per camera, like a real calibrated rig.
        let fx = r.focal_px * (1.0 + 0.003 * k as f64);
        let fy = fx * (1.0 - 0.0007 * (k as f64 + 1.0));
        let cx = 0.5 * (r.width as f64 - 1.0) + 0.8 * k as f64 - 0.6;
        let cy = 0.5 * (r.height as f64 - 1.0) - 0.5 * k as f64 + 0.3;
        out.push(Camera::new(
            format!("cam{k}"),
            r.width,
            r.height,
            [fx, fy, cx, cy],
            r.distortion,
            rot,
            t,
        )?);
    }
    Ok(out)
}

/// Smallest ray parameter t > `t_min` at which `o + t d` enters the finite cylinder with axis
/// from `a` along unit `axis` for `length`, radius `radius` (side and both caps).
pub fn ray_cylinder(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    a: &Vector3<f64>,
    axis: &Vector3<f64>,
    length: f64,
    radius: f64,
    t_min: f64,
) -> Option<f64> {
    let mut best: Option<f64> = None;
    let mut consider = |t: f64| {
        if t > t_min && best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    };
    let w = o - a;
    let dp = d - axis * d.dot(axis);
    let wp = w - axis * w.dot(axis);
    let qa = dp.norm_squared();
    let qb = 2.0 * dp.dot(&wp);
    let qc = wp.norm_squared() - radius * radius;
    if qa > 1e-300 {
        let disc = qb * qb - 4.0 * qa * qc;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            for t in [(-qb - sq) / (2.0 * qa), (-qb + sq) / (2.0 * qa)] {
                let h = (w + d * t).dot(axis);
                if (0.0..=length).contains(&h) {
                    consider(t);
                }
            }
        }
    }
    let dn = d.dot(axis);
    if dn.abs() > 1e-300 {
        for h in [0.0, length] {
            let t = (h - w.dot(axis)) / dn;
            let p = w + d * t;
            if (p - axis * p.dot(axis)).norm_squared() <= radius * radius {
                consider(t);
            }
        }
    }
    best
}

/// Smallest t > `t_min` where the ray enters the sphere (centre c, radius r).
pub fn ray_sphere(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    c: &Vector3<f64>,
    r: f64,
    t_min: f64,
) -> Option<f64> {
    let w = o - c;
    let qa = d.norm_squared();
    let qb = 2.0 * d.dot(&w);
    let qc = w.norm_squared() - r * r;
    let disc = qb * qb - 4.0 * qa * qc;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    [(-qb - sq) / (2.0 * qa), (-qb + sq) / (2.0 * qa)]
        .into_iter()
        .find(|&t| t > t_min)
}

/// First hit of a ray with the probe (tip and shaft), if any.
pub fn ray_probe(
    probe: &ProbeGeometry,
    world_from_probe: &Isometry3<f64>,
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    t_min: f64,
) -> Option<f64> {
    let axis_in = world_from_probe.rotation * Vector3::z();
    let up = -axis_in;
    let tip = world_from_probe.translation.vector;
    let (tip_hit, shaft_start) = if probe.thickness_m > 0.0 {
        (
            ray_cylinder(o, d, &tip, &up, probe.thickness_m, probe.radius_m, t_min),
            probe.thickness_m,
        )
    } else {
        (
            ray_sphere(o, d, &(tip + up * probe.radius_m), probe.radius_m, t_min),
            probe.radius_m,
        )
    };
    let shaft_len = probe.shaft_length_m - shaft_start;
    let shaft = if shaft_len > 0.0 {
        ray_cylinder(
            o,
            d,
            &(tip + up * shaft_start),
            &up,
            shaft_len,
            probe.shaft_radius_m,
            t_min,
        )
    } else {
        None
    };
    match (tip_hit, shaft) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// One labelled 2D observation of a marker or shaft marker before noise.
#[derive(Clone, Debug, PartialEq)]
pub struct Projection {
    /// Marker id (object marker or shaft marker).
    pub id: String,
    /// Colour name.
    pub color: String,
    /// Exact projection of the marker centre, px.
    pub uv: Vector2<f64>,
    /// World position, m.
    pub position_m: Vector3<f64>,
}

/// Markers (object then shaft) visible in `cam` at frame `f`: inside the image (3 px margin),
/// facing the camera (object markers), not hidden by the probe.
pub fn visible(truth: &Truth, marker_color: &str, cam: &Camera, f: &FrameTruth) -> Vec<Projection> {
    let centre = cam.centre_world().coords;
    let mut out = Vec::new();
    let inside = |uv: &Vector2<f64>| {
        uv.x >= 3.0
            && uv.y >= 3.0
            && uv.x <= cam.width as f64 - 4.0
            && uv.y <= cam.height as f64 - 4.0
    };
    let pose = &f.spec.world_from_probe;
    let hidden = |p: &Vector3<f64>, skip_probe_margin: f64| {
        let d = p - centre;
        let len = d.norm();
        let dir = d / len;
        ray_probe(&truth.probe, pose, &centre, &dir, 1e-9)
            .is_some_and(|t| t < len - skip_probe_margin)
    };
    // Shaft markers are spheres around the shaft: only the tip can hide them.
    let tip_only = ProbeGeometry {
        shaft_length_m: 0.0,
        ..truth.probe.clone()
    };
    let hidden_by_tip = |p: &Vector3<f64>| {
        let d = p - centre;
        let len = d.norm();
        ray_probe(&tip_only, pose, &centre, &(d / len), 1e-9).is_some_and(|t| t < len)
    };
    for (i, p) in f.markers_m.iter().enumerate() {
        let n = f.marker_normals[i];
        let to_cam = (centre - p).normalize();
        if n.dot(&to_cam) < 0.2 {
            continue;
        }
        let Some(uv) = cam.project(&Point3::from(*p)) else {
            continue;
        };
        if !inside(&uv) || hidden(p, 1e-6) {
            continue;
        }
        out.push(Projection {
            id: truth.block.marker_ids[i].clone(),
            color: marker_color.to_string(),
            uv,
            position_m: *p,
        });
    }
    for ((id, _, color), p) in truth
        .probe
        .shaft_markers
        .iter()
        .zip(truth.probe.shaft_marker_positions(pose))
    {
        let Some(uv) = cam.project(&Point3::from(p)) else {
            continue;
        };
        // The marker sphere itself sits around the shaft: only other probe parts hide it.
        if !inside(&uv) || hidden_by_tip(&p) {
            continue;
        }
        out.push(Projection {
            id: id.clone(),
            color: color.clone(),
            uv,
            position_m: p,
        });
    }
    out
}

/// One detection row.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectionRow {
    /// Frame.
    pub frame: usize,
    /// Pixel centroid.
    pub uv: Vector2<f64>,
    /// Colour.
    pub color: String,
    /// Marker id (None for spurious blobs).
    pub label: Option<String>,
}

/// Detections of one camera over all frames: true projections + Gaussian noise, random dropouts
/// (object markers only),
/// persistent background specks and occasional random spurious blobs.
pub fn detections(
    s: &Scenario,
    truth: &Truth,
    cam: &Camera,
    rng: &mut ChaCha8Rng,
) -> Vec<DetectionRow> {
    let o = &s.output;
    let noise = Normal::new(0.0, o.detection_noise_px.max(0.0)).expect("σ ≥ 0 is finite");
    let colors = ["blue", "red", "yellow"];
    let (w, h) = (cam.width as f64, cam.height as f64);
    let specks: Vec<(Vector2<f64>, &str)> = (0..o.persistent_specks)
        .map(|_| {
            (
                Vector2::new(
                    rng.random_range(10.0..w - 10.0),
                    rng.random_range(10.0..h - 10.0),
                ),
                // Background specks look like the painted markers (a stray paint drop).
                s.object.marker_color.as_str(),
            )
        })
        .collect();
    let mut rows = Vec::new();
    for f in &truth.frames {
        for p in visible(truth, &s.object.marker_color, cam, f) {
            // Dropouts hit the small painted discs; the large shaft spheres are always found
            // when in view (a frame without a probe pose is not what the suite tests).
            let drop = rng.random::<f64>() < o.dropout_probability;
            if drop && !p.id.starts_with("shaft") {
                continue;
            }
            let uv = p.uv + Vector2::new(noise.sample(rng), noise.sample(rng));
            rows.push(DetectionRow {
                frame: f.spec.frame,
                uv,
                color: p.color,
                label: Some(p.id),
            });
        }
        for (uv, c) in &specks {
            rows.push(DetectionRow {
                frame: f.spec.frame,
                uv: uv + Vector2::new(noise.sample(rng), noise.sample(rng)),
                color: c.to_string(),
                label: None,
            });
        }
        if rng.random::<f64>() < o.spurious_probability {
            rows.push(DetectionRow {
                frame: f.spec.frame,
                uv: Vector2::new(
                    rng.random_range(5.0..w - 5.0),
                    rng.random_range(5.0..h - 5.0),
                ),
                color: colors[rng.random_range(0..colors.len())].to_string(),
                label: None,
            });
        }
    }
    rows
}
