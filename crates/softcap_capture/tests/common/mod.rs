//! Shared helpers of the integration tests: the session-min fixture and its truth/ comparison.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::PathBuf;

use softcap_capture::nalgebra::{Point3, Vector3};
use softcap_capture::{CaptureResult, MarkerState};

pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures")
        .join(name)
}

fn rows(path: &PathBuf) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    (
        header,
        lines
            .filter(|l| !l.is_empty())
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect(),
    )
}

/// Accuracy figures against a session's truth/ (read only by tests).
#[derive(Debug)]
pub struct Accuracy {
    pub marker_rms_mm: f64,
    pub marker_max_mm: f64,
    pub visible_rms_mm: f64,
    pub filled_rms_mm: f64,
    pub markers_compared: usize,
    pub filled: usize,
    pub missing: usize,
    pub force_rms_n: f64,
    pub force_max_n: f64,
    pub tip_rms_mm: f64,
    pub tip_max_mm: f64,
    pub clock_offset_error_ms: f64,
    pub clock_drift_error_ppm: f64,
    /// RMS over frames of the axial force error: the magnitude of the captured force vector (0
    /// where capture gives none, as downstream stages read it) against the truth force along the
    /// true shaft axis (from the shaft markers of truth/markers.csv), N.
    pub axial_force_rms_n: f64,
    /// Largest true axial force, N.
    pub axial_force_max_n: f64,
    /// Frame of the largest axial force error, and that error, N.
    pub worst_force_frame: usize,
    pub worst_force_error_n: f64,
    /// Frames in which capture gives no force vector although the true axial force exceeds 5 %
    /// of its maximum (downstream stages would read 0 N there).
    pub unforced_frames: Vec<usize>,
}

pub fn accuracy(session: &str, r: &CaptureResult) -> Accuracy {
    let dir = fixture(session).join("truth");
    let (_, mrows) = rows(&dir.join("markers.csv"));
    let mut truth: BTreeMap<(usize, String), Point3<f64>> = BTreeMap::new();
    let mut shaft: BTreeMap<(usize, String), Point3<f64>> = BTreeMap::new();
    for row in mrows {
        let p = Point3::new(
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
            row[4].parse::<f64>().unwrap(),
        ) * 1e-3;
        if row[1].starts_with("shaft") {
            shaft.insert((row[0].parse().unwrap(), row[1].clone()), p);
        }
        truth.insert((row[0].parse().unwrap(), row[1].clone()), p);
    }
    let (mut s, mut n, mut max, mut sv, mut nv, mut sf, mut nf, mut missing) =
        (0.0, 0, 0.0f64, 0.0, 0, 0.0, 0, 0);
    for f in &r.frames {
        for (i, m) in f.markers.iter().enumerate() {
            let Some(t) = truth.get(&(f.frame, r.marker_ids[i].clone())) else {
                continue;
            };
            if m.state == MarkerState::Missing {
                missing += 1;
                continue;
            }
            let e2 = (m.position_m - t).norm_squared();
            s += e2;
            n += 1;
            max = max.max(e2.sqrt());
            if m.state == MarkerState::Filled {
                sf += e2;
                nf += 1;
            } else {
                sv += e2;
                nv += 1;
            }
        }
    }
    let (_, prows) = rows(&dir.join("probe.csv"));
    let (mut fs, mut fmax, mut ts, mut tmax, mut nt) = (0.0, 0.0f64, 0.0, 0.0f64, 0);
    let (mut axs, mut axmax, mut worst) = (0.0, 0.0f64, (0usize, 0.0f64));
    let mut ntip = 0usize;
    let mut loaded: Vec<(usize, f64, bool)> = Vec::new();
    for row in &prows {
        let frame: usize = row[0].parse().unwrap();
        let ft = Vector3::new(
            row[2].parse().unwrap(),
            row[3].parse().unwrap(),
            row[4].parse::<f64>().unwrap(),
        );
        let tip = Point3::new(
            row[5].parse().unwrap(),
            row[6].parse().unwrap(),
            row[7].parse::<f64>().unwrap(),
        ) * 1e-3;
        fmax = fmax.max(ft.norm());
        let p = r.frames[frame].probe.as_ref().expect("probe sample");
        let fe = p.force_n.unwrap_or_default();
        fs += (fe - ft).norm_squared();
        let near = shaft.get(&(frame, "shaft0".to_string()));
        let far = shaft.get(&(frame, "shaft1".to_string()));
        if let (Some(a), Some(b)) = (near, far) {
            let axial_true = ft.dot(&(a - b).normalize());
            let err = (fe.norm() - axial_true).abs();
            loaded.push((frame, axial_true, p.force_n.is_some()));
            axs += err * err;
            axmax = axmax.max(axial_true.abs());
            if err > worst.1 {
                worst = (frame, err);
            }
        }
        if let Some(t) = p.tip_m {
            let te = (t - tip).norm();
            ts += te * te;
            tmax = tmax.max(te);
            ntip += 1;
        }
        nt += 1;
    }
    let clock = std::fs::read_to_string(dir.join("clock.toml")).unwrap();
    let val = |k: &str| -> f64 {
        clock
            .lines()
            .find(|l| l.starts_with(k))
            .unwrap()
            .split('=')
            .nth(1)
            .unwrap()
            .trim()
            .parse()
            .unwrap()
    };
    let sync = r.sync.expect("sync");
    Accuracy {
        marker_rms_mm: (s / n as f64).sqrt() * 1e3,
        marker_max_mm: max * 1e3,
        visible_rms_mm: (sv / nv.max(1) as f64).sqrt() * 1e3,
        filled_rms_mm: (sf / nf.max(1) as f64).sqrt() * 1e3,
        markers_compared: n,
        filled: nf,
        missing,
        force_rms_n: (fs / nt as f64).sqrt(),
        force_max_n: fmax,
        tip_rms_mm: (ts / ntip.max(1) as f64).sqrt() * 1e3,
        tip_max_mm: tmax * 1e3,
        clock_offset_error_ms: (sync.offset_s - val("offset_s")).abs() * 1e3,
        clock_drift_error_ppm: (sync.drift - val("drift")).abs() * 1e6,
        axial_force_rms_n: (axs / nt as f64).sqrt(),
        axial_force_max_n: axmax,
        worst_force_frame: worst.0,
        worst_force_error_n: worst.1,
        unforced_frames: loaded
            .iter()
            .filter(|(_, f, has)| !has && *f > 0.05 * axmax)
            .map(|(k, _, _)| *k)
            .collect(),
    }
}

/// Copies a fixture session (without truth/) into a fresh temporary folder.
pub fn session_copy(name: &str) -> (tempfile::TempDir, PathBuf) {
    fn copy_dir(src: &std::path::Path, dst: &std::path::Path) {
        std::fs::create_dir_all(dst).unwrap();
        for e in std::fs::read_dir(src).unwrap() {
            let e = e.unwrap();
            let to = dst.join(e.file_name());
            if e.file_type().unwrap().is_dir() {
                if e.file_name() != "truth" {
                    copy_dir(&e.path(), &to);
                }
            } else {
                std::fs::copy(e.path(), &to).unwrap();
            }
        }
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join(name);
    copy_dir(&fixture(name), &dir);
    (tmp, dir)
}
