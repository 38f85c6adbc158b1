//! C3D motion-capture takes (session kind `mocap`, `files.c3d`): already-triangulated marker
//! trajectories from the POINT group and the ANALOG channels, read with the `c3dio` crate and
//! converted to SI (C3D standard, POINT:UNITS, ANALOG:SCALE/GEN_SCALE/OFFSET).

use std::path::{Path, PathBuf};

use nalgebra::Point3;

use crate::error::{CaptureError, Result};

/// Analog channels of a take, one sample vector per channel (already scaled by c3dio:
/// `(raw − OFFSET) · SCALE · GEN_SCALE`, in each channel's ANALOG:UNITS).
#[derive(Debug, Clone, PartialEq)]
pub struct AnalogChannels {
    /// ANALOG:LABELS, trimmed.
    pub labels: Vec<String>,
    /// ANALOG:UNITS, trimmed (may be empty).
    pub units: Vec<String>,
    /// ANALOG:RATE, Hz.
    pub rate_hz: f64,
    /// Samples, `samples[channel][k]` at time `k / rate_hz` from the first frame.
    pub samples: Vec<Vec<f64>>,
}

/// One C3D take in SI units.
#[derive(Debug, Clone, PartialEq)]
pub struct C3dTake {
    /// The file.
    pub path: PathBuf,
    /// POINT:LABELS, trimmed, one per marker.
    pub marker_labels: Vec<String>,
    /// POINT:RATE, Hz.
    pub frame_rate_hz: f64,
    /// First frame number from the header (1-based in C3D).
    pub first_frame: usize,
    /// Marker positions `positions_m[frame][marker]`, m; `None` where the file marks the
    /// point invalid (negative residual) or all coordinates are exactly zero.
    pub positions_m: Vec<Vec<Option<Point3<f64>>>>,
    /// Analog channels (empty labels when the take has none).
    pub analog: AnalogChannels,
}

impl C3dTake {
    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.positions_m.len()
    }

    /// Time of frame `k` from the start of the take, s.
    pub fn frame_time_s(&self, k: usize) -> f64 {
        k as f64 / self.frame_rate_hz
    }

    /// Index of a marker label.
    pub fn marker_index(&self, label: &str) -> Option<usize> {
        self.marker_labels.iter().position(|l| l == label)
    }

    /// Index of an analog channel label.
    pub fn analog_index(&self, label: &str) -> Option<usize> {
        self.analog.labels.iter().position(|l| l == label)
    }
}

/// Metres per POINT:UNITS (`mm`, `cm`, `m`, case-insensitive, blanks ignored).
pub fn metres_per_point_unit(units: &str) -> Option<f64> {
    match units.trim().to_ascii_lowercase().as_str() {
        "mm" => Some(1e-3),
        "cm" => Some(1e-2),
        "m" => Some(1.0),
        _ => None,
    }
}

/// Rewrites the parameter section without the parameters whose data is empty (a zero among
/// their dimensions, e.g. Vicon's `FORCE_PLATFORM:CORNERS` with dimensions `[3, 4, 0]` when no
/// plate is used). The C3D standard allows them, but `c3dio` 0.8 rejects such a parameter
/// (`InvalidParameterData`); they carry no value, so dropping them loses nothing. Returns `None`
/// when the file has no such parameter or its parameter section cannot be walked (then the
/// bytes are handed to `c3dio` unchanged and it reports the problem).
fn drop_empty_parameters(bytes: &[u8]) -> Option<Vec<u8>> {
    let start = (*bytes.first()? as usize).checked_sub(1)? * 512;
    let n_blocks = *bytes.get(start + 2)? as usize;
    let big_endian = *bytes.get(start + 3)? == 86; // 84 Intel, 85 DEC, 86 MIPS
    let end = (start + n_blocks * 512).min(bytes.len());
    let i16_at = |i: usize| -> Option<i16> {
        let b = [*bytes.get(i)?, *bytes.get(i + 1)?];
        Some(if big_endian {
            i16::from_be_bytes(b)
        } else {
            i16::from_le_bytes(b)
        })
    };
    let mut out: Vec<u8> = bytes[start..start + 4].to_vec();
    let mut dropped = false;
    let mut p = start + 4;
    while p + 2 <= end {
        let name_len = (bytes[p] as i8).unsigned_abs() as usize;
        let id = bytes[p + 1] as i8;
        if name_len == 0 {
            break;
        }
        let q = p + 2 + name_len;
        let offset = i16_at(q)?;
        let next = if offset > 0 { q + offset as usize } else { end };
        if next > end || next <= q + 2 {
            return None;
        }
        let mut empty = false;
        if id > 0 {
            let nd = *bytes.get(q + 3)? as usize;
            let dims = bytes.get(q + 4..q + 4 + nd)?;
            empty = nd > 0 && dims.contains(&0);
        }
        if empty {
            dropped = true;
        } else {
            let rest = &bytes[q + 2..next];
            out.extend_from_slice(&bytes[p..q]);
            let new_offset = i16::try_from(2 + rest.len()).ok()?;
            out.extend_from_slice(&if big_endian {
                new_offset.to_be_bytes()
            } else {
                new_offset.to_le_bytes()
            });
            out.extend_from_slice(rest);
        }
        if offset <= 0 {
            break;
        }
        p = next;
    }
    if !dropped || out.len() > end - start {
        return None;
    }
    out.resize(end - start, 0);
    let mut fixed = bytes.to_vec();
    fixed[start..end].copy_from_slice(&out);
    Some(fixed)
}

/// Caps the header's frame range (words 4 and 5) at the frames the file's bytes can hold.
///
/// `c3dio` 0.8 allocates a `frames × markers` grid from the header alone, before it looks at the
/// parameters or the data, and then takes the frame count from POINT:FRAMES and the data, not
/// from the header: a 6 kB file declaring 1,149 frames of 41,782 markers made it allocate 1.2 GB
/// (found by the `c3d` fuzz target). Real headers are not always consistent (the ezc3d Optotrak
/// take declares 1,149 frames and holds 29), so the range is capped, not refused: a point takes
/// at least 8 bytes (four 16-bit words), so the file holds at most `len / (8 · markers)` frames.
fn cap_header_frames(bytes: &mut [u8]) {
    let Some(start) = bytes
        .first()
        .and_then(|&b| (b as usize).checked_sub(1))
        .map(|b| b * 512)
    else {
        return;
    };
    let (Some(&processor), true) = (bytes.get(start + 3), bytes.len() >= 512) else {
        return;
    };
    let big_endian = processor == 86; // 84 Intel, 85 DEC, 86 MIPS
    let word = |i: usize| {
        let b = [bytes[2 * i], bytes[2 * i + 1]];
        if big_endian {
            u16::from_be_bytes(b)
        } else {
            u16::from_le_bytes(b)
        }
    };
    let (markers, first, last) = (word(1) as usize, word(3), word(4));
    if markers == 0 {
        return;
    }
    let max_frames = (bytes.len() / (8 * markers)).clamp(1, 1 << 16);
    let frames = last.wrapping_sub(first).wrapping_add(1) as usize; // as c3dio counts them
    if last >= first && frames <= max_frames {
        return;
    }
    let capped = first.saturating_add((max_frames - 1) as u16);
    let b = if big_endian {
        capped.to_be_bytes()
    } else {
        capped.to_le_bytes()
    };
    bytes[8..10].copy_from_slice(&b);
}

/// Reads a C3D take: POINT trajectories (converted to metres) and ANALOG channels.
pub fn read_c3d(path: &Path) -> Result<C3dTake> {
    let format = |message: String| CaptureError::Format {
        path: path.to_path_buf(),
        message,
    };
    if !path.exists() {
        return Err(CaptureError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    let bytes = std::fs::read(path).map_err(|source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut bytes = drop_empty_parameters(&bytes).unwrap_or(bytes);
    cap_header_frames(&mut bytes);
    // c3dio 0.8 panics on some corrupt parameter sections (an integer negation overflow, found
    // by the `c3d` fuzz target); a panic inside it is a bad file, not a bug here.
    let parsed = std::panic::catch_unwind(|| {
        c3dio::C3d::from_bytes(&bytes).map_err(|e| format!("not a readable C3D file: {e:?}"))
    });
    let c3d = match parsed {
        Ok(parsed) => parsed.map_err(format)?,
        Err(_) => {
            return Err(format(
                "not a readable C3D file: the C3D parser failed on its header or parameters".into(),
            ));
        }
    };
    let units: String = c3d.points.units.iter().collect();
    let scale = metres_per_point_unit(&units)
        .ok_or_else(|| format(format!("POINT:UNITS `{}` is not mm, cm or m", units.trim())))?;
    let grid = &c3d.points.points;
    let (n_frames, n_markers) = (grid.rows(), grid.cols());
    let mut labels: Vec<String> = c3d
        .points
        .labels
        .iter()
        .map(|l| l.trim().to_string())
        .collect();
    if labels.len() < n_markers {
        return Err(format(format!(
            "POINT:LABELS has {} labels for {n_markers} markers",
            labels.len()
        )));
    }
    labels.truncate(n_markers);
    let frame_rate_hz = c3d.points.frame_rate as f64;
    if !(frame_rate_hz > 0.0 && frame_rate_hz.is_finite()) {
        return Err(format(format!(
            "POINT:RATE {frame_rate_hz} is not positive"
        )));
    }
    let mut positions_m = Vec::with_capacity(n_frames);
    for f in 0..n_frames {
        let row = (0..n_markers)
            .map(|m| {
                let p = grid.get(f, m)?;
                let [x, y, z] = p.point;
                let valid = p.residual >= 0.0
                    && [x, y, z].iter().all(|v| v.is_finite())
                    && !(x == 0.0 && y == 0.0 && z == 0.0);
                valid.then(|| Point3::new(x as f64, y as f64, z as f64) * scale)
            })
            .collect();
        positions_m.push(row);
    }
    let a = &c3d.analog;
    let n_channels = a.analog.cols();
    let mut samples = vec![Vec::with_capacity(a.analog.rows()); n_channels];
    for k in 0..a.analog.rows() {
        for (c, s) in samples.iter_mut().enumerate() {
            s.push(a.analog.get(k, c).copied().unwrap_or(f64::NAN));
        }
    }
    let analog_labels: Vec<String> = (0..n_channels)
        .map(|c| {
            a.labels
                .get(c)
                .map(|l| l.trim().to_string())
                .unwrap_or_else(|| format!("channel{c}"))
        })
        .collect();
    let analog_units = (0..n_channels)
        .map(|c| {
            a.units
                .get(c)
                .map(|u| u.trim().to_string())
                .unwrap_or_default()
        })
        .collect();
    Ok(C3dTake {
        path: path.to_path_buf(),
        marker_labels: labels,
        frame_rate_hz,
        first_frame: c3d.points.first_frame as usize,
        positions_m,
        analog: AnalogChannels {
            labels: analog_labels,
            units: analog_units,
            rate_hz: a.rate as f64,
            samples,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_units() {
        assert_eq!(metres_per_point_unit("mm  "), Some(1e-3));
        assert_eq!(metres_per_point_unit(" M"), Some(1.0));
        assert_eq!(metres_per_point_unit("in"), None);
    }

    #[test]
    fn garbage_is_a_format_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.c3d");
        std::fs::write(&p, vec![7u8; 300]).unwrap();
        let e = read_c3d(&p).unwrap_err();
        assert!(e.to_string().contains("bad.c3d"), "{e}");
        assert!(e.is_bad_input());
    }
}
