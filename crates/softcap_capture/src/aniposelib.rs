//! Reading an aniposelib (Anipose) rig: the calibration TOML written by
//! `aniposelib.cameras.CameraGroup.dump` (`[cam_N]` tables with `name`, `size = [w, h]`,
//! `matrix` (3×3 K), `distortions` (OpenCV k1, k2, p1, p2, k3), `rotation` (Rodrigues vector,
//! world→camera) and `translation` (world→camera)) and labeled 2D points as
//! `point,camera,u,v` CSV rows, so multi-view triangulation can be run on real rigs.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Rotation3, Vector2, Vector3};
use serde::Deserialize;

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::session::{CsvTable, parse_toml};
use crate::triangulate::PixelObservation;

#[derive(Deserialize)]
struct RawAniposeCamera {
    size: [u32; 2],
    matrix: [[f64; 3]; 3],
    distortions: Vec<f64>,
    rotation: [f64; 3],
    translation: [f64; 3],
    #[serde(default)]
    fisheye: bool,
}

/// Reads an aniposelib calibration TOML. Cameras are the `[cam_N]` tables ordered by N (the
/// numeric index, not the lexicographic key order); each camera's id is its table key. The
/// translation is taken as metres (`metres_per_unit` converts other units).
pub fn read_aniposelib_calibration(path: &Path, metres_per_unit: f64) -> Result<Vec<Camera>> {
    let raw: BTreeMap<String, toml::Value> = parse_toml(path)?;
    let mut tables: Vec<(usize, String, RawAniposeCamera)> = Vec::new();
    for (key, value) in raw {
        if key == "metadata" {
            continue;
        }
        let index = key
            .strip_prefix("cam_")
            .and_then(|n| n.parse::<usize>().ok())
            .ok_or_else(|| {
                CaptureError::field(path, 0, &key, "expected tables named cam_<index>")
            })?;
        let cam: RawAniposeCamera = value
            .try_into()
            .map_err(|e: toml::de::Error| CaptureError::field(path, 0, &key, e.message()))?;
        tables.push((index, key, cam));
    }
    tables.sort_by_key(|t| t.0);
    let mut cameras = Vec::with_capacity(tables.len());
    for (_, key, c) in tables {
        let camera_error = |message: String| CaptureError::Camera {
            path: path.to_path_buf(),
            camera: key.clone(),
            message,
        };
        if c.fisheye {
            return Err(camera_error(
                "fisheye cameras are not supported (OpenCV pinhole model only)".into(),
            ));
        }
        if c.distortions.len() > 5 {
            return Err(camera_error(format!(
                "{} distortion coefficients; at most 5 (k1, k2, p1, p2, k3)",
                c.distortions.len()
            )));
        }
        let mut distortion = [0.0; 5];
        distortion[..c.distortions.len()].copy_from_slice(&c.distortions);
        let k = c.matrix;
        if k[0][1].abs() > 1e-12 {
            return Err(camera_error(format!(
                "skew {} in the camera matrix is not supported",
                k[0][1]
            )));
        }
        let rotation = Rotation3::from_scaled_axis(Vector3::from(c.rotation)).into_inner();
        let camera = Camera::new(
            key.clone(),
            c.size[0],
            c.size[1],
            [k[0][0], k[1][1], k[0][2], k[1][2]],
            distortion,
            rotation,
            Vector3::from(c.translation) * metres_per_unit,
        )
        .map_err(|e| camera_error(e.to_string()))?;
        cameras.push(camera);
    }
    if cameras.is_empty() {
        return Err(CaptureError::field(path, 0, "cam_0", "no [cam_N] tables"));
    }
    Ok(cameras)
}

/// Reads labeled 2D points `point,camera,u,v` (camera = calibration table key, e.g. `cam_3`) and
/// groups them per point (ascending point index) into observations of `cameras`.
pub fn read_labeled_points(path: &Path, cameras: &[Camera]) -> Result<Vec<Vec<PixelObservation>>> {
    let t = CsvTable::read(path)?;
    let (cp, cc, cu, cv) = (
        t.require("point")?,
        t.require("camera")?,
        t.require("u")?,
        t.require("v")?,
    );
    let index: BTreeMap<&str, usize> = cameras
        .iter()
        .enumerate()
        .map(|(i, c)| (c.id.as_str(), i))
        .collect();
    let mut points: BTreeMap<usize, Vec<PixelObservation>> = BTreeMap::new();
    for row in &t.rows {
        let p = t.usize_at(row, cp, "point")?;
        let cam = t.str_at(row, cc, "camera")?;
        let &camera = index.get(cam).ok_or_else(|| {
            CaptureError::field(path, row.0, "camera", format!("unknown camera `{cam}`"))
        })?;
        let uv = Vector2::new(t.f64_at(row, cu, "u")?, t.f64_at(row, cv, "v")?);
        let obs = points.entry(p).or_default();
        if obs.iter().any(|o| o.camera == camera) {
            return Err(CaptureError::field(
                path,
                row.0,
                "camera",
                format!("point {p} seen twice by `{cam}`"),
            ));
        }
        obs.push(PixelObservation { camera, uv });
    }
    Ok(points.into_values().collect())
}

/// `(R|t)` of a camera as the Rodrigues vector aniposelib stores (for round trips and tests).
pub fn rodrigues(rotation: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix_unchecked(*rotation).scaled_axis()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rodrigues_round_trip_and_table_order() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("calibration.toml");
        let cam = |i: usize, rx: f64| {
            format!(
                "[cam_{i}]\nname = \"{i}\"\nsize = [640, 480]\nmatrix = [[500.0, 0.0, 320.0], [0.0, 501.0, 240.0], [0.0, 0.0, 1.0]]\ndistortions = [-0.1, 0.01, 0.0, 0.0, 0.0]\nrotation = [{rx}, 0.2, -0.3]\ntranslation = [0.1, 0.0, 1.0]\n\n"
            )
        };
        std::fs::write(&p, cam(10, 0.5) + &cam(2, 0.1) + "[metadata]\n").unwrap();
        let cams = read_aniposelib_calibration(&p, 1.0).unwrap();
        assert_eq!(cams[0].id, "cam_2");
        assert_eq!(cams[1].id, "cam_10");
        let r = rodrigues(&cams[1].rotation);
        assert!((r - Vector3::new(0.5, 0.2, -0.3)).norm() < 1e-12, "{r}");
        assert_eq!(cams[1].intrinsics, [500.0, 501.0, 320.0, 240.0]);
    }
}
