//! Foxglove well-known twins of softcap messages, for the `/viz/...` channels.
//!
//! The Foxglove schemas and encoders come from the `foxglove` crate (default features off: no
//! websocket server, no async runtime) — it ships the official `foxglove.*` protobuf schemas
//! with their descriptor sets and an `Encode` impl per message, so nothing is vendored here.
//! Write the results with [`crate::Writer::write_foxglove`] on [`crate::viz_topic`]`(topic)`.

use foxglove::messages::{
    ArrowPrimitive, Color, FrameTransform, PackedElementField, Point3, PointCloud, Pose,
    Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp, TriangleListPrimitive,
    Vector3, packed_element_field::NumericType,
};

use crate::proto::{self, MarkerFrame, PointCloudFrame, ProbeSample, TetMesh, TriMesh};

/// The frame all softcap positions are expressed in.
pub const WORLD_FRAME: &str = "world";

/// Visual sizes of the twins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VizSettings {
    /// Marker sphere diameter, metres.
    pub marker_diameter_m: f64,
    /// Force arrow length per newton, metres / N.
    pub arrow_m_per_n: f64,
    /// Probe shaft arrow length, metres.
    pub probe_shaft_m: f64,
}

impl Default for VizSettings {
    fn default() -> Self {
        Self {
            marker_diameter_m: 0.004,
            arrow_m_per_n: 0.01,
            probe_shaft_m: 0.05,
        }
    }
}

/// `log_time` (ns) as a Foxglove timestamp.
pub fn timestamp(log_time_ns: u64) -> Timestamp {
    let sec = (log_time_ns / 1_000_000_000).min(u64::from(u32::MAX)) as u32;
    Timestamp::new(sec, (log_time_ns % 1_000_000_000) as u32)
}

fn color(r: f64, g: f64, b: f64) -> Option<Color> {
    Some(Color { r, g, b, a: 1.0 })
}

fn vec3(v: &proto::Vec3) -> Vector3 {
    Vector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// Quaternion rotating +x onto the direction `d` (Foxglove arrows point along their pose's +x).
/// Returns identity for a zero vector.
pub fn rotation_x_to(d: [f64; 3]) -> Quaternion {
    let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if n == 0.0 || !n.is_finite() {
        return Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        };
    }
    let (dx, dy, dz) = (d[0] / n, d[1] / n, d[2] / n);
    // q = (1 + x·d, x × d), normalized; x × d = (0, -dz, dy).
    let w = 1.0 + dx;
    if w < 1e-12 {
        // d = -x: half turn about z.
        return Quaternion {
            x: 0.0,
            y: 0.0,
            z: 1.0,
            w: 0.0,
        };
    }
    let (qx, qy, qz) = (0.0, -dz, dy);
    let qn = (w * w + qx * qx + qy * qy + qz * qz).sqrt();
    Quaternion {
        x: qx / qn,
        y: qy / qn,
        z: qz / qn,
        w: w / qn,
    }
}

fn entity(id: &str, log_time_ns: u64) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(log_time_ns)),
        frame_id: WORLD_FRAME.into(),
        id: id.into(),
        ..Default::default()
    }
}

/// Markers as spheres: measured markers green, filled-in (occluded) markers orange.
pub fn markers_scene(frame: &MarkerFrame, log_time_ns: u64, settings: &VizSettings) -> SceneUpdate {
    let d = settings.marker_diameter_m;
    let mut e = entity("markers", log_time_ns);
    e.spheres = frame
        .markers
        .iter()
        .filter_map(|m| {
            let p = m.position_m.as_ref()?;
            let c = if m.filled {
                color(1.0, 0.55, 0.0)
            } else {
                color(0.1, 0.8, 0.2)
            };
            Some(SpherePrimitive {
                pose: Some(Pose {
                    position: Some(vec3(p)),
                    orientation: Some(rotation_x_to([1.0, 0.0, 0.0])),
                }),
                size: Some(Vector3 { x: d, y: d, z: d }),
                color: c,
            })
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// Probe: a sphere at the tip, a grey shaft arrow ending at the tip, and a red force arrow
/// starting at the tip whose length is `|force| · arrow_m_per_n`.
pub fn probe_scene(sample: &ProbeSample, log_time_ns: u64, settings: &VizSettings) -> SceneUpdate {
    let mut e = entity("probe", log_time_ns);
    let tip = sample.tip_m.unwrap_or_default();
    let axis = sample.axis.unwrap_or_default();
    let force = sample.force_n.unwrap_or_default();
    let d = settings.marker_diameter_m;
    e.spheres.push(SpherePrimitive {
        pose: Some(Pose {
            position: Some(vec3(&tip)),
            orientation: Some(rotation_x_to([1.0, 0.0, 0.0])),
        }),
        size: Some(Vector3 { x: d, y: d, z: d }),
        color: color(0.2, 0.4, 1.0),
    });
    let axis_len = (axis.x * axis.x + axis.y * axis.y + axis.z * axis.z).sqrt();
    if axis_len > 0.0 {
        let l = settings.probe_shaft_m;
        let start = proto::Vec3 {
            x: tip.x - axis.x / axis_len * l,
            y: tip.y - axis.y / axis_len * l,
            z: tip.z - axis.z / axis_len * l,
        };
        e.arrows.push(ArrowPrimitive {
            pose: Some(Pose {
                position: Some(vec3(&start)),
                orientation: Some(rotation_x_to([axis.x, axis.y, axis.z])),
            }),
            shaft_length: 0.8 * l,
            shaft_diameter: 0.2 * d,
            head_length: 0.2 * l,
            head_diameter: 0.5 * d,
            color: color(0.6, 0.6, 0.6),
        });
    }
    let f = (force.x * force.x + force.y * force.y + force.z * force.z).sqrt();
    if f > 0.0 {
        let l = f * settings.arrow_m_per_n;
        e.arrows.push(ArrowPrimitive {
            pose: Some(Pose {
                position: Some(vec3(&tip)),
                orientation: Some(rotation_x_to([force.x, force.y, force.z])),
            }),
            shaft_length: 0.8 * l,
            shaft_diameter: 0.3 * d,
            head_length: 0.2 * l,
            head_diameter: 0.8 * d,
            color: color(0.9, 0.1, 0.1),
        });
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

fn triangle_list(positions_m: &[f64], triangles: &[u32]) -> TriangleListPrimitive {
    TriangleListPrimitive {
        pose: Some(Pose {
            position: Some(Vector3::default()),
            orientation: Some(rotation_x_to([1.0, 0.0, 0.0])),
        }),
        points: positions_m
            .chunks_exact(3)
            .map(|p| Point3 {
                x: p[0],
                y: p[1],
                z: p[2],
            })
            .collect(),
        color: Some(Color {
            r: 0.85,
            g: 0.75,
            b: 0.65,
            a: 0.8,
        }),
        colors: Vec::new(),
        indices: triangles.to_vec(),
    }
}

/// A triangle mesh as one indexed triangle list.
pub fn trimesh_scene(mesh: &TriMesh, log_time_ns: u64) -> SceneUpdate {
    let mut e = entity(&format!("mesh/{}", mesh.name), log_time_ns);
    e.triangles
        .push(triangle_list(&mesh.positions_m, &mesh.triangles));
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// A tet mesh shown by its boundary triangles (`surface_triangles`; empty list if none given).
pub fn tetmesh_scene(mesh: &TetMesh, log_time_ns: u64) -> SceneUpdate {
    let mut e = entity(&format!("mesh/{}", mesh.name), log_time_ns);
    e.triangles
        .push(triangle_list(&mesh.positions_m, &mesh.surface_triangles));
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// A fused depth cloud as a Foxglove `PointCloud`: `x, y, z` float32 per point, world frame.
pub fn point_cloud(frame: &PointCloudFrame, log_time_ns: u64) -> PointCloud {
    let mut data = Vec::with_capacity(4 * frame.positions_m.len());
    for v in &frame.positions_m {
        data.extend_from_slice(&v.to_le_bytes());
    }
    let field = |name: &str, offset: u32| PackedElementField {
        name: name.into(),
        offset,
        r#type: NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(timestamp(log_time_ns)),
        frame_id: WORLD_FRAME.into(),
        pose: Some(Pose {
            position: Some(Vector3::default()),
            orientation: Some(rotation_x_to([1.0, 0.0, 0.0])),
        }),
        point_stride: 12,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

/// A tet mesh's boundary at new node positions (`positions_m` flat xyz, the mesh's node order):
/// the `/viz` twin of a per-frame node channel such as `/tissue/track/nodes`.
pub fn deformed_tetmesh_scene(
    mesh: &TetMesh,
    positions_m: &[f64],
    log_time_ns: u64,
) -> SceneUpdate {
    let mut e = entity(&format!("mesh/{}", mesh.name), log_time_ns);
    e.triangles
        .push(triangle_list(positions_m, &mesh.surface_triangles));
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// A `FrameTransform` placing `child` in `parent` (translation in metres, rotation as a unit
/// quaternion `[x, y, z, w]`).
pub fn frame_transform(
    parent: &str,
    child: &str,
    translation_m: [f64; 3],
    rotation_xyzw: [f64; 4],
    log_time_ns: u64,
) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(log_time_ns)),
        parent_frame_id: parent.into(),
        child_frame_id: child.into(),
        translation: Some(Vector3 {
            x: translation_m[0],
            y: translation_m[1],
            z: translation_m[2],
        }),
        rotation: Some(Quaternion {
            x: rotation_xyzw[0],
            y: rotation_xyzw[1],
            z: rotation_xyzw[2],
            w: rotation_xyzw[3],
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(q: &Quaternion, v: [f64; 3]) -> [f64; 3] {
        // v' = v + 2 w (u × v) + 2 u × (u × v)
        let u = [q.x, q.y, q.z];
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let t = cross(u, v);
        let t2 = cross(u, t);
        [
            v[0] + 2.0 * q.w * t[0] + 2.0 * t2[0],
            v[1] + 2.0 * q.w * t[1] + 2.0 * t2[1],
            v[2] + 2.0 * q.w * t[2] + 2.0 * t2[2],
        ]
    }

    #[test]
    fn arrow_rotation_maps_x_onto_direction() {
        for d in [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, -3.0],
            [0.3, -0.4, 1.2],
            [-0.9, 0.1, -0.05],
        ] {
            let q = rotation_x_to(d);
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let r = rotate(&q, [1.0, 0.0, 0.0]);
            for k in 0..3 {
                assert!((r[k] - d[k] / n).abs() < 1e-12, "{d:?} -> {r:?}");
            }
        }
    }
}
