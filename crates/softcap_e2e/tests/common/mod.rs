//! Shared by the diagnose suite (tests/diagnose_suite.rs), the catalog bench
//! (benches/diagnose_catalog.rs) and the examples: the stage chain synth → capture → tissue fit
//! on a scenario, in-process through each stage's library API.
#![allow(dead_code)]

use softcap_capture::{CaptureSettings, Session, capture, write_capture_mcap};
use softcap_synth::{Scenario, synthesize};
use softcap_tissue::fit::{FitConfig, FitSettings, RECOMMENDED_GAMMA_PRIOR};
use std::path::{Path, PathBuf};
use std::time::Instant;

pub fn suite_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/scenarios/suite")
}

/// The inputs of `softcap diagnose` for one scenario, in a temporary folder.
pub struct Inputs {
    pub dir: tempfile::TempDir,
    pub capture: PathBuf,
    pub material: PathBuf,
    /// Seconds spent in synth, capture, tissue fit.
    pub seconds: [f64; 3],
}

/// The tissue-fit settings of the suite's material: the stage's defaults (`FitSettings::default`,
/// what `softcap tissue fit` runs) except that the shrinkage γ_p of the per-example fits is the
/// fixed [`RECOMMENDED_GAMMA_PRIOR`] instead of the leave-one-location-out choice among
/// `DEFAULT_GAMMA_PRIOR_CANDIDATES` (`gamma_prior_candidates = []`, a documented setting).
///
/// Why: the diagnosis reads the material with `MaterialSource::Auto`, whose default model is the
/// homogeneous baseline of `/tissue/report` (`homogeneous.lambda` / `homogeneous.alpha`, its
/// `homogeneous.patch.load`) on `/mesh/volume` — step 1 of the fit, computed before and
/// independently of γ_p. γ_p shapes only the per-example parameters and the strain-space basis
/// (and the report's `rms.material`, quoted in the diagnosis's material note), which the
/// diagnosis does not simulate. The selection is the expensive part of the fit on the
/// 5,184-tet template: three candidates' per-example fits, each scored by re-simulating every
/// example with a basis built without its location (docs/tissue.md, session 14). Measured:
/// the same homogeneous baseline bit for bit and the same verdicts and held-out numbers
/// (docs/diagnose.md, "Session 14 (speed)"). If the default model ever reads the basis or the
/// per-example parameters, this must go back to `FitSettings::default()`.
///
/// Measuring aid: `SOFTCAP_SUITE_HELDOUT_COMPARISON=1` also scores the homogeneous baseline and
/// the strain-space material leave-one-location-out (`FitSettings::heldout_comparison`, printed
/// in the `TISSUE` line of [`fit_and_print`]).
pub fn suite_fit_settings() -> FitSettings {
    let mut s = FitSettings {
        progress: false,
        gamma_prior_candidates: Vec::new(),
        heldout_comparison: std::env::var_os("SOFTCAP_SUITE_HELDOUT_COMPARISON").is_some(),
        ..Default::default()
    };
    s.example_fit.gamma_prior = RECOMMENDED_GAMMA_PRIOR;
    s
}

/// The diagnosis's default model: `MaterialSource::Auto`, or with the measuring aid
/// `SOFTCAP_SUITE_MATERIAL=basis|homogeneous|example-mean` that material source.
pub fn suite_material_source() -> softcap_diagnose::MaterialSource {
    use softcap_diagnose::MaterialSource;
    match std::env::var("SOFTCAP_SUITE_MATERIAL").as_deref() {
        Err(_) | Ok("auto") => MaterialSource::Auto,
        Ok("basis") => MaterialSource::Basis,
        Ok("homogeneous") => MaterialSource::Homogeneous,
        Ok("example-mean") => MaterialSource::ExampleMean,
        Ok(v) => panic!("SOFTCAP_SUITE_MATERIAL={v}: auto | basis | homogeneous | example-mean"),
    }
}

/// `softcap_tissue::fit::run` on `cfg`; prints one `TISSUE` row: the per-example fits' LM
/// iterations and stop reasons, and with `heldout_comparison` the leave-one-location-out RMS of
/// the homogeneous baseline and the strain-space material (mm).
pub fn fit_and_print(name: &str, cfg: &FitConfig) {
    let o = softcap_tissue::fit::run(cfg).expect("softcap_tissue::fit::run");
    let iterations: Vec<usize> = o.examples.iter().map(|e| e.iterations).collect();
    let stops: Vec<&str> = o.examples.iter().map(|e| e.stop.name()).collect();
    let unconverged = o.examples.iter().filter(|e| !e.stop.converged()).count();
    let heldout = o.heldout.as_ref().map_or(String::new(), |h| {
        format!(
            " | held-out homogeneous {:.4} mm ({} failed), material {:.4} mm ({} failed)",
            1e3 * h.homogeneous_rms_m,
            h.homogeneous_failures,
            1e3 * h.material_rms_m,
            h.material_failures
        )
    });
    println!(
        "TISSUE | {name} | unconverged {unconverged}/{} | iterations {iterations:?} | stops {stops:?} | rms homogeneous {:.4} mm, per-example {:.4} mm, material {:.4} mm{heldout}",
        o.examples.len(),
        1e3 * o.homogeneous_rms_m,
        1e3 * o.example_rms_m,
        1e3 * o.material_rms_m,
    );
}

/// synth → capture (capture.mcap) → `softcap_tissue::fit::run` (material.mcap) with
/// [`suite_fit_settings`], each through the stage's library API as the binaries call it.
///
/// Developer aid: with `SOFTCAP_SUITE_CACHE=DIR`, the capture.mcap / material.mcap of a scenario
/// are kept in `DIR/<name>-<hash of the resolved scenario>/` and reused by later runs (for
/// iterating on the diagnose stage only; stale when synth, capture or tissue code changes —
/// delete DIR then). Unset (CI), every run makes fresh inputs.
///
/// Measuring aid: `SOFTCAP_SUITE_DISK_TIP_LOAD=NAME` (a `softcap_probing::FootprintLoad` name:
/// lumped, consistent, flat-punch, hertz) fits the material with that footprint load for a disk
/// tip (`FitSettings::disk_tip_load`) instead of the default; cached as `material-NAME.mcap`
/// beside the scenario's capture.mcap, refitted from the cached capture (and the template's
/// volume.msh, cached with the synthetic truth's `truth/` folder) without re-running capture.
pub fn prepare_inputs(scenario: &Scenario) -> Inputs {
    let dir = tempfile::tempdir().unwrap();
    let cache = std::env::var_os("SOFTCAP_SUITE_CACHE").map(|d| {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        format!("{scenario:?}").hash(&mut h);
        PathBuf::from(d).join(format!("{}-{:016x}", scenario.name, h.finish()))
    });
    let load = std::env::var("SOFTCAP_SUITE_DISK_TIP_LOAD").ok().map(|n| {
        softcap_probing::FootprintLoad::from_name(&n).unwrap_or_else(|| {
            panic!("SOFTCAP_SUITE_DISK_TIP_LOAD={n}: lumped | consistent | flat-punch | hertz")
        })
    });
    let mut settings = suite_fit_settings();
    let material_name = match load {
        Some(l) => {
            settings.disk_tip_load = l;
            format!("material-{}.mcap", l.name())
        }
        None => "material.mcap".to_string(),
    };
    if let Some(c) = &cache
        && c.join("capture.mcap").is_file()
    {
        if load.is_some() {
            cache_synth_files(scenario, c, dir.path());
        }
        if c.join(&material_name).is_file() {
            return Inputs {
                capture: c.join("capture.mcap"),
                material: c.join(&material_name),
                dir,
                seconds: [0.0; 3],
            };
        }
        if load.is_some() {
            // Refit from the cached capture on the template's cached volume mesh.
            let t0 = Instant::now();
            let material = dir.path().join("material.mcap");
            let volume = c.join("volume.msh");
            fit_material(&c.join("capture.mcap"), &volume, &material, &settings);
            let t_tissue = t0.elapsed().as_secs_f64();
            std::fs::copy(&material, c.join(&material_name)).unwrap();
            return Inputs {
                capture: c.join("capture.mcap"),
                material: c.join(&material_name),
                dir,
                seconds: [0.0, 0.0, t_tissue],
            };
        }
    }
    let inputs = prepare_fresh(scenario, dir, &settings);
    if let Some(c) = &cache {
        std::fs::create_dir_all(c).unwrap();
        std::fs::copy(&inputs.capture, c.join("capture.mcap")).unwrap();
        std::fs::copy(&inputs.material, c.join(&material_name)).unwrap();
    }
    inputs
}

/// Synthesizes `scenario` into `scratch` when the cache folder `c` lacks the template's
/// volume.msh or the synthetic truth (`truth/`: diagnose_floor's FLOOR_FORCE / FLOOR_TRUTH
/// inputs), and copies them there.
fn cache_synth_files(scenario: &Scenario, c: &Path, scratch: &Path) {
    let volume = c.join("volume.msh");
    let truth = c.join("truth");
    if volume.is_file() && truth.join("probe.csv").is_file() {
        return;
    }
    let session_dir = scratch.join("session");
    synthesize(scenario, &session_dir).unwrap();
    let session = Session::load(&session_dir).unwrap();
    std::fs::copy(session.volume.expect("template/volume.msh"), &volume).unwrap();
    std::fs::create_dir_all(&truth).unwrap();
    for e in std::fs::read_dir(session_dir.join("truth")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), truth.join(e.file_name())).unwrap();
    }
}

fn fit_material(capture: &Path, volume: &Path, output: &Path, settings: &FitSettings) {
    fit_and_print(
        &output.display().to_string(),
        &FitConfig {
            capture: capture.to_path_buf(),
            mesh: Some(volume.to_path_buf()),
            output: output.to_path_buf(),
            report: None,
            settings: settings.clone(),
            arguments: vec![],
        },
    );
}

fn prepare_fresh(scenario: &Scenario, dir: tempfile::TempDir, settings: &FitSettings) -> Inputs {
    let session_dir = dir.path().join("session");
    let t0 = Instant::now();
    synthesize(scenario, &session_dir).unwrap();
    let t_synth = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let session = Session::load(&session_dir).unwrap();
    let capture_settings = CaptureSettings::default();
    let result = capture(&session, &capture_settings).unwrap();
    let capture_path = dir.path().join("capture.mcap");
    write_capture_mcap(&capture_path, &session, &result, &capture_settings, &[]).unwrap();
    let t_capture = t0.elapsed().as_secs_f64();

    let t0 = Instant::now();
    let material_path = dir.path().join("material.mcap");
    let volume = session.volume.clone().expect("template/volume.msh");
    fit_material(&capture_path, &volume, &material_path, settings);
    let t_tissue = t0.elapsed().as_secs_f64();
    Inputs {
        dir,
        capture: capture_path,
        material: material_path,
        seconds: [t_synth, t_capture, t_tissue],
    }
}
