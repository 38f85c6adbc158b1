//! Landmark table: which face-scan vertex carries each mocap marker (thesis §4.2.1, "the user
//! first manually selects the corresponding vertex positions f_{i,0} ∈ F").
//!
//! Instead of clicking, [`derive_landmarks`] registers the neutral mocap frame rigidly to the
//! scan by iterative closest points (start: translate the nose-tip marker onto the scan's
//! most protruding vertex; then alternate closest vertices and a least-squares rigid fit,
//! Horn 1987 via SVD) and takes each marker's closest vertex. The committed table
//! `fixtures/animface-mocap/ict_landmarks.csv` was produced this way and is checked by a test.

use nalgebra::{Matrix3, Vector3};

use crate::error::{FaceError, Result};

/// One row of the landmark table.
#[derive(Clone, Debug, PartialEq)]
pub struct Landmark {
    /// Mocap marker name.
    pub marker: String,
    /// Face-scan vertex index.
    pub vertex: usize,
    /// Distance from the registered marker to that vertex (cm).
    pub residual_cm: f64,
}

fn closest(vertices: &[Vector3<f64>], p: &Vector3<f64>) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (i, v) in vertices.iter().enumerate() {
        let d = (v - p).norm_squared();
        if d < best.1 {
            best = (i, d);
        }
    }
    (best.0, best.1.sqrt())
}

/// Least-squares rigid transform (R, t) with R a + t ≈ b (Horn / Kabsch via SVD).
pub fn rigid_fit(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> (Matrix3<f64>, Vector3<f64>) {
    let n = a.len() as f64;
    let ca = a.iter().sum::<Vector3<f64>>() / n;
    let cb = b.iter().sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (p, q) in a.iter().zip(b) {
        h += (p - ca) * (q - cb).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return (Matrix3::identity(), cb - ca);
    };
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    (r, cb - r * ca)
}

/// Register the markers to the scan (ICP, `iterations` rounds) and return, per marker, the
/// closest vertex. `nose_marker` indexes the marker on the nose tip.
pub fn derive_landmarks(
    names: &[String],
    markers: &[Vector3<f64>],
    vertices: &[Vector3<f64>],
    nose_marker: usize,
    iterations: usize,
) -> Result<Vec<Landmark>> {
    if markers.is_empty()
        || vertices.is_empty()
        || nose_marker >= markers.len()
        || names.len() != markers.len()
    {
        return Err(FaceError::InvalidInput {
            what: "landmarks",
            reason: "empty markers/vertices or bad nose index".into(),
        });
    }
    let tip = vertices
        .iter()
        .copied()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .unwrap_or_default();
    let mut r = Matrix3::identity();
    let mut t = tip - markers[nose_marker];
    for _ in 0..iterations {
        let moved: Vec<Vector3<f64>> = markers.iter().map(|m| r * m + t).collect();
        let targets: Vec<Vector3<f64>> = moved
            .iter()
            .map(|p| vertices[closest(vertices, p).0])
            .collect();
        (r, t) = rigid_fit(markers, &targets);
    }
    // Closest vertex per marker; a vertex already taken by another marker is skipped so
    // every marker gets its own handle vertex.
    let mut taken = std::collections::BTreeSet::new();
    let mut out = Vec::with_capacity(markers.len());
    for (m, name) in markers.iter().zip(names) {
        let p = r * m + t;
        let mut order: Vec<(f64, usize)> = vertices
            .iter()
            .enumerate()
            .map(|(i, v)| ((v - p).norm(), i))
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let Some(&(residual_cm, vertex)) = order.iter().find(|(_, i)| !taken.contains(i)) else {
            return Err(FaceError::InvalidInput {
                what: "landmarks",
                reason: "more markers than vertices".into(),
            });
        };
        taken.insert(vertex);
        out.push(Landmark {
            marker: name.clone(),
            vertex,
            residual_cm,
        });
    }
    Ok(out)
}

/// Parse the landmark CSV `marker,vertex,residual_cm`.
pub fn parse_landmarks_csv(text: &str, path: &std::path::Path) -> Result<Vec<Landmark>> {
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate().skip(1) {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let c: Vec<&str> = line.split(',').collect();
        let err = |field: &str, reason: String| FaceError::Parse {
            path: path.to_path_buf(),
            line: k + 1,
            field: field.into(),
            reason,
        };
        if c.len() != 3 {
            return Err(err("record", format!("expected 3 fields, got {}", c.len())));
        }
        let vertex = c[1]
            .parse()
            .map_err(|e| err("vertex", format!("`{}`: {e}", c[1])))?;
        let residual_cm = c[2]
            .parse()
            .map_err(|e| err("residual_cm", format!("`{}`: {e}", c[2])))?;
        out.push(Landmark {
            marker: c[0].to_string(),
            vertex,
            residual_cm,
        });
    }
    Ok(out)
}

/// Format the landmark table as CSV.
pub fn landmarks_csv(rows: &[Landmark]) -> String {
    let mut s = String::from("marker,vertex,residual_cm\n");
    for r in rows {
        s.push_str(&format!("{},{},{:.4}\n", r.marker, r.vertex, r.residual_cm));
    }
    s
}
