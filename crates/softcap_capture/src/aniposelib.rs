//! Reading an aniposelib (Anipose) rig: the calibration TOML written by
//! `aniposelib.cameras.CameraGroup.dump` (`[cam_N]` tables with `name`, `size = [w, h]`,
//! `matrix` (3×3 K), `distortions` (OpenCV k1, k2, p1, p2, k3), `rotation` (Rodrigues vector,
//! world→camera) and `translation` (world→camera)) and labeled 2D points as
//! `point,camera,u,v` CSV rows or the `p2d` array of an `.npz` archive, so multi-view
//! triangulation and calibration can be run on real rigs.

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

/// Reads aniposelib's labeled 2D points from an `.npz` archive (`numpy.savez[_compressed]`): the
/// array `p2d`, float64 of shape (cameras, points, 2) with the camera axis in the order of
/// `cameras` (aniposelib's numeric `cam_N` order), NaN where a camera does not see a point.
/// Returns every point's observations (possibly fewer than two), in point order.
///
/// The `.npy` header (a fixed-form Python dict literal with `descr`, `fortran_order`, `shape`) is
/// parsed here rather than by `npyz`, whose literal parser (py_literal, pest) and zip 0.6 would add
/// a parser generator and a second zip crate to every fresh build; the archive itself is read with
/// `zip`, the version the workspace already builds.
pub fn read_npz_points(path: &Path, cameras: &[Camera]) -> Result<Vec<Vec<PixelObservation>>> {
    let format = |message: String| CaptureError::Format {
        path: path.to_path_buf(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut archive = zip::ZipArchive::new(std::io::BufReader::new(file))
        .map_err(|e| format(format!("not an .npz (zip) archive: {e}")))?;
    let mut bytes = Vec::new();
    {
        use std::io::Read as _;
        let mut entry = archive
            .by_name("p2d.npy")
            .map_err(|_| format("no array `p2d` (p2d.npy) in the archive".into()))?;
        entry
            .read_to_end(&mut bytes)
            .map_err(|e| format(format!("p2d.npy: cannot decompress: {e}")))?;
    }
    let npy = NpyHeader::parse(&bytes).map_err(|m| format(format!("p2d.npy: {m}")))?;
    let [n_cameras, n_points, two] =
        <[usize; 3]>::try_from(npy.shape.as_slice()).map_err(|_| {
            format(format!(
                "p2d has shape {:?}; expected (cameras, points, 2)",
                npy.shape
            ))
        })?;
    if two != 2 {
        return Err(format(format!(
            "p2d has shape {:?}; expected (cameras, points, 2)",
            npy.shape
        )));
    }
    if n_cameras != cameras.len() {
        return Err(format(format!(
            "p2d has {n_cameras} cameras, the calibration {}",
            cameras.len()
        )));
    }
    let data = &bytes[npy.data_offset..];
    if data.len() != 8 * n_cameras * n_points * 2 {
        return Err(format(format!(
            "p2d.npy holds {} data bytes; shape {:?} of float64 needs {}",
            data.len(),
            npy.shape,
            8 * n_cameras * n_points * 2
        )));
    }
    let at = |c: usize, p: usize, k: usize| {
        let i = if npy.fortran_order {
            c + n_cameras * (p + n_points * k)
        } else {
            (c * n_points + p) * 2 + k
        };
        let mut b = [0u8; 8];
        b.copy_from_slice(&data[8 * i..8 * i + 8]);
        f64::from_le_bytes(b)
    };
    let mut points = vec![Vec::new(); n_points];
    for (p, obs) in points.iter_mut().enumerate() {
        for c in 0..n_cameras {
            let uv = Vector2::new(at(c, p, 0), at(c, p, 1));
            if uv.x.is_nan() || uv.y.is_nan() {
                continue;
            }
            if !(uv.x.is_finite() && uv.y.is_finite()) {
                return Err(format(format!(
                    "p2d[{c}, {p}] = ({}, {}) is not finite",
                    uv.x, uv.y
                )));
            }
            obs.push(PixelObservation { camera: c, uv });
        }
    }
    Ok(points)
}

/// The header of a `.npy` array (NumPy format 1.0–3.0) of little-endian float64.
struct NpyHeader {
    shape: Vec<usize>,
    fortran_order: bool,
    data_offset: usize,
}

impl NpyHeader {
    fn parse(bytes: &[u8]) -> std::result::Result<Self, String> {
        if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
            return Err("not a .npy array (bad magic)".into());
        }
        let (len, start) = match bytes[6] {
            1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
            2 | 3 if bytes.len() >= 12 => (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            ),
            v => return Err(format!("unsupported .npy format version {v}")),
        };
        let header = bytes
            .get(start..start + len)
            .and_then(|h| std::str::from_utf8(h).ok())
            .ok_or("truncated or non-text header")?;
        let value = |key: &str| -> std::result::Result<&str, String> {
            let at = header
                .find(&format!("'{key}':"))
                .ok_or(format!("header has no `{key}`"))?;
            Ok(header[at + key.len() + 3..].trim_start())
        };
        let descr = value("descr")?;
        if !(descr.starts_with("'<f8'") || descr.starts_with("'float64'")) {
            let shown: String = descr.chars().take(8).collect();
            return Err(format!(
                "dtype {shown}…: expected little-endian float64 ('<f8')"
            ));
        }
        let fortran_order = match value("fortran_order")? {
            v if v.starts_with("True") => true,
            v if v.starts_with("False") => false,
            _ => return Err("fortran_order is neither True nor False".into()),
        };
        let shape_text = value("shape")?;
        let inner = shape_text
            .strip_prefix('(')
            .and_then(|t| t.split(')').next())
            .ok_or("shape is not a tuple")?;
        let shape = inner
            .split(',')
            .map(str::trim)
            .filter(|t| !t.is_empty())
            .map(|t| {
                t.parse::<usize>()
                    .map_err(|_| format!("shape entry `{t}` is not a size"))
            })
            .collect::<std::result::Result<Vec<_>, _>>()?;
        Ok(NpyHeader {
            shape,
            fortran_order,
            data_offset: start + len,
        })
    }
}

/// `(R|t)` of a camera as the Rodrigues vector aniposelib stores (for round trips and tests).
pub fn rodrigues(rotation: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix_unchecked(*rotation).scaled_axis()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `.npz` written the way numpy does (stored and deflated members, C and Fortran order).
    fn write_npz(path: &Path, header: &str, values: &[f64], compress: bool) {
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        npy.extend_from_slice(&(h.len() as u16).to_le_bytes());
        npy.extend_from_slice(h.as_bytes());
        for v in values {
            npy.extend_from_slice(&v.to_le_bytes());
        }
        let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
        let method = if compress {
            zip::CompressionMethod::Deflated
        } else {
            zip::CompressionMethod::Stored
        };
        let options = zip::write::SimpleFileOptions::default().compression_method(method);
        zip.start_file("p2d.npy", options).unwrap();
        std::io::Write::write_all(&mut zip, &npy).unwrap();
        zip.finish().unwrap();
    }

    #[test]
    fn npz_points_in_c_and_fortran_order() {
        let dir = tempfile::tempdir().unwrap();
        let cams: Vec<Camera> = (0..2)
            .map(|i| {
                Camera::new(
                    format!("cam_{i}"),
                    640,
                    480,
                    [500.0, 500.0, 320.0, 240.0],
                    [0.0; 5],
                    Matrix3::identity(),
                    Vector3::new(i as f64, 0.0, 1.0),
                )
                .unwrap()
            })
            .collect();
        // p2d[c, p, k] for 2 cameras × 3 points; camera 1 misses point 2.
        let p2d = |c: usize, p: usize, k: usize| {
            if c == 1 && p == 2 {
                f64::NAN
            } else {
                100.0 * c as f64 + 10.0 * p as f64 + k as f64
            }
        };
        let c_order: Vec<f64> = (0..2)
            .flat_map(|c| (0..3).flat_map(move |p| (0..2).map(move |k| p2d(c, p, k))))
            .collect();
        let f_order: Vec<f64> = (0..2)
            .flat_map(|k| (0..3).flat_map(move |p| (0..2).map(move |c| p2d(c, p, k))))
            .collect();
        for (name, header, values, compress) in [
            (
                "c.npz",
                "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3, 2), }",
                &c_order,
                true,
            ),
            (
                "f.npz",
                "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3, 2), }",
                &f_order,
                false,
            ),
        ] {
            let path = dir.path().join(name);
            write_npz(&path, header, values, compress);
            let points = read_npz_points(&path, &cams).unwrap();
            assert_eq!(points.len(), 3, "{name}");
            assert_eq!(points[2].len(), 1, "{name}: camera 1 misses point 2");
            assert_eq!(points[1][1].camera, 1);
            assert_eq!(points[1][1].uv, Vector2::new(110.0, 111.0), "{name}");
        }
        // Bad input names the problem.
        let path = dir.path().join("bad.npz");
        write_npz(
            &path,
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 2), }",
            &c_order,
            true,
        );
        let e = read_npz_points(&path, &cams).unwrap_err().to_string();
        assert!(e.contains("bad.npz") && e.contains("float64"), "{e}");
        write_npz(
            &path,
            "{'descr': '<f8', 'fortran_order': False, 'shape': (3, 2, 2), }",
            &c_order,
            true,
        );
        let e = read_npz_points(&path, &cams).unwrap_err().to_string();
        assert!(e.contains("3 cameras, the calibration 2"), "{e}");
        std::fs::write(&path, "not a zip").unwrap();
        let e = read_npz_points(&path, &cams).unwrap_err().to_string();
        assert!(e.contains("not an .npz"), "{e}");
    }

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
