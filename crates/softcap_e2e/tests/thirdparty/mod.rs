//! The chain of the third-party truth tests (`thirdparty_diagnose.rs`, `thirdparty_lookalikes.rs`,
//! `thirdparty_pairs.rs`):
//! capture from the unlabeled detections → tissue fit → diagnose on a session of
//! `fixtures/thirdparty/`, in process through each stage's library API, once per test process.
// Each test binary uses a part of it.
#![allow(dead_code)]

use crate::common;
use softcap_capture::{CaptureSettings, MarkerSource, Session, capture, write_capture_mcap};
use softcap_diagnose::{DiagnoseSettings, Diagnosis, RankedHypothesis, RunConfig, StageSettings};
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

pub fn case_dir(case: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../fixtures/thirdparty")
        .join(case)
}

/// `(effect, pair)` of a case from `fixtures/thirdparty/suite.toml` (a small fixed-format file
/// written by the generator: `[case]`, `effect = "…"`, `pair = "…"`).
pub fn suite_entry(case: &str) -> (String, String) {
    let path = case_dir("suite.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let (mut current, mut effect, mut pair) = (String::new(), None, None);
    for line in text.lines().map(str::trim) {
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            current = name.to_string();
        } else if current == case
            && let Some((k, v)) = line.split_once('=')
        {
            let v = v.trim().trim_matches('"').to_string();
            match k.trim() {
                "effect" => effect = Some(v),
                "pair" => pair = Some(v),
                _ => {}
            }
        }
    }
    (
        effect.unwrap_or_else(|| panic!("{}: no effect for [{case}]", path.display())),
        pair.unwrap_or_default(),
    )
}

/// The chain's result on one case.
pub struct Outcome {
    pub diagnosis: Diagnosis,
    /// Capture's camera ↔ DAQ clock offset (`t_daq = offset + (1 + drift) t_camera`), s.
    pub clock_offset_s: Option<f64>,
    /// Seconds in capture, tissue fit, diagnose.
    pub seconds: [f64; 3],
}

/// capture (detections) → tissue fit → diagnose on `fixtures/thirdparty/<case>`.
///
/// Developer aids: `SOFTCAP_THIRDPARTY_CACHE=DIR` keeps each case's capture.mcap and
/// material.mcap in `DIR/<case>/` and reuses them (for iterating on the diagnose stage only; stale
/// when capture or tissue code changes); `SOFTCAP_THIRDPARTY_JSON=DIR` keeps the diagnosis JSON as
/// `DIR/<case>.json`.
pub fn chain(case: &str) -> Outcome {
    chain_with(case, DiagnoseSettings::default())
}

/// [`chain`] with the diagnosis's settings `diagnose`.
pub fn chain_with(case: &str, diagnose: DiagnoseSettings) -> Outcome {
    let dir = tempfile::tempdir().unwrap();
    let cache = std::env::var_os("SOFTCAP_THIRDPARTY_CACHE").map(|d| PathBuf::from(d).join(case));
    let work = cache.clone().unwrap_or_else(|| dir.path().to_path_buf());
    std::fs::create_dir_all(&work).unwrap();
    let capture_path = work.join("capture.mcap");
    let material = work.join("material.mcap");
    let t0 = Instant::now();
    let session = Session::load(&case_dir(case)).unwrap();
    let settings = CaptureSettings {
        source: MarkerSource::Detections,
        ..Default::default()
    };
    let captured = capture(&session, &settings).unwrap();
    let cached = cache.is_some() && capture_path.is_file() && material.is_file();
    if !cached {
        write_capture_mcap(&capture_path, &session, &captured, &settings, &[]).unwrap();
    }
    let t_capture = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    if !cached {
        common::fit_and_print(
            case,
            &softcap_tissue::fit::FitConfig {
                capture: capture_path.clone(),
                mesh: Some(session.volume.clone().expect("template/volume.msh")),
                output: material.clone(),
                report: None,
                settings: common::suite_fit_settings(),
                arguments: vec![],
            },
        );
    }
    let t_tissue = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let diagnosis = softcap_diagnose::run(&RunConfig {
        capture: capture_path,
        material,
        output: dir.path().join("diagnosis.mcap"),
        json: Some(dir.path().join("diagnosis.json")),
        report: None,
        settings: StageSettings {
            diagnose,
            material: common::suite_material_source(),
            ..StageSettings::default()
        },
        arguments: vec![],
        progress: false,
    })
    .unwrap();
    if let Some(keep) = std::env::var_os("SOFTCAP_THIRDPARTY_JSON").map(PathBuf::from) {
        let kept = keep.join(format!("{case}.json")); // a look-alike case is `lookalikes/<name>`
        std::fs::create_dir_all(kept.parent().unwrap()).unwrap();
        std::fs::copy(dir.path().join("diagnosis.json"), kept).unwrap();
    }
    Outcome {
        diagnosis,
        clock_offset_s: captured.sync.map(|s| s.offset_s),
        seconds: [t_capture, t_tissue, t0.elapsed().as_secs_f64()],
    }
}

/// The chain's outcome on `case`, run once per test process (a paired control serves several
/// effect cases; concurrent callers of one case wait for the first).
pub fn outcome(case: &str) -> Arc<Outcome> {
    type Cache = Mutex<HashMap<String, Arc<OnceLock<Arc<Outcome>>>>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let cell = CACHE
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry(case.to_string())
        .or_default()
        .clone();
    cell.get_or_init(|| Arc::new(chain(case))).clone()
}

pub fn ranked<'a>(d: &'a Diagnosis, hypothesis: &str) -> Option<(usize, &'a RankedHypothesis)> {
    d.ranked
        .iter()
        .enumerate()
        .find(|(_, r)| r.hypothesis == hypothesis)
        .map(|(k, r)| (k + 1, r))
}

pub fn summary(d: &Diagnosis) -> Vec<String> {
    d.ranked
        .iter()
        .map(|r| {
            format!(
                "{} {:.4} -> {:.4} mm params={:?}",
                r.hypothesis,
                1e3 * r.heldout_rmse_before_m,
                1e3 * r.heldout_rmse_after_m,
                r.params
            )
        })
        .collect()
}
