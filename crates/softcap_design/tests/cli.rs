//! `softcap-design` end to end: library → target → search (design.mcap, design.json,
//! curves.png); bad input exits with 2 naming the file.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_softcap-design"))
}

#[test]
fn library_target_search_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let lib = dir.path().join("lib.json");
    assert!(
        bin()
            .args(["library", "-o"])
            .arg(&lib)
            .status()
            .unwrap()
            .success()
    );
    // A 3-material sub-library keeps the test fast (2 layers: 9 designs).
    let all: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    let small = dir.path().join("small.json");
    std::fs::write(
        &small,
        serde_json::to_string(&vec![all[0].clone(), all[3].clone(), all[7].clone()]).unwrap(),
    )
    .unwrap();
    let target = dir.path().join("target.json");
    let st = bin()
        .args(["target", "--materials"])
        .arg(&small)
        .args(["--design", "2,0", "-o"])
        .arg(&target)
        .status()
        .unwrap();
    assert!(st.success());
    let search = |out: &std::path::Path| {
        let o = bin()
            .args(["search", "--materials"])
            .arg(&small)
            .arg("--target")
            .arg(&target)
            .arg("-o")
            .arg(out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let out = dir.path().join("out");
    search(&out);
    let d: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("design.json")).unwrap()).unwrap();
    assert_eq!(d["design"], serde_json::json!([2, 0]));
    assert!(d["rms_error_m"].as_f64().unwrap() < 1e-12);
    assert!(std::fs::metadata(out.join("curves.png")).unwrap().len() > 1000);
    // design.mcap: provenance and one /design/report; a rerun with the same arguments (the
    // provenance records them) reproduces its content digest (what `softcap inspect digest` and
    // `make -f pipelines/design.mk digests` print).
    let digest = || {
        let rec = softcap_mcap::Recording::open(out.join("design.mcap")).unwrap();
        assert!(rec.provenance().unwrap().is_some());
        assert_eq!(rec.messages_on("/design/report").unwrap().len(), 1);
        rec.digest().unwrap()
    };
    let first = digest();
    search(&out);
    assert_eq!(digest(), first);
    // The print file: one object per material (2 layers of materials 2 and 0).
    let parts = softcap_design::read_design_3mf(&out.join("design.3mf")).unwrap();
    assert_eq!(parts.len(), 2);
    let volume: f64 = parts.iter().map(|p| p.volume_mm3()).sum();
    assert!((volume - 40.0 * 50.0 * 25.0).abs() < 1e-6, "{volume}");
}

#[test]
fn fit_base_rejects_a_file_that_is_not_a_capture_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("capture.mcap");
    std::fs::write(&bad, b"not an mcap file").unwrap();
    let out = dir.path().join("lib.json");
    let o = bin()
        .arg("fit-base")
        .arg(&bad)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("capture.mcap"));
    assert!(!out.exists());
}

#[test]
fn bad_target_exits_2_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let lib = dir.path().join("lib.json");
    assert!(
        bin()
            .args(["library", "-o"])
            .arg(&lib)
            .status()
            .unwrap()
            .success()
    );
    let target = dir.path().join("target.json");
    std::fs::write(
        &target,
        "{\"layers\": 5, \"forces_n\": [1.0], \"displacements_m\": [0.0]",
    )
    .unwrap();
    let o = bin()
        .args(["search", "--materials"])
        .arg(&lib)
        .arg("--target")
        .arg(&target)
        .arg("-o")
        .arg(dir.path().join("o"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("target.json"));
    assert!(!dir.path().join("o").exists());
}

/// `--help`/`--version` exit 0; a missing and a malformed library JSON are bad input (2), each
/// named once.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    let bin = env!("CARGO_BIN_EXE_softcap-design");
    assert_help_version_usage(bin);
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("t.json");
    let out = dir.path().join("t-out.json");
    for (name, content) in [("missing.json", None), ("bad.json", Some("{ not json"))] {
        let lib = dir.path().join(name);
        if let Some(c) = content {
            std::fs::write(&lib, c).unwrap();
        }
        let r = run(
            bin,
            &[
                "target",
                "--materials",
                lib.to_str().unwrap(),
                "--design",
                "0,1",
                "-o",
                target.to_str().unwrap(),
            ],
        );
        assert_error_names_once(&r, 2, &lib);
    }
    assert!(!target.exists() && !out.exists());
}

/// Crash safety (docs/reliability.md): `design search` SIGKILLed at random moments leaves
/// nothing or a complete design.mcap; two processes writing one output folder at once leave one
/// complete file. `scripts/kill-test` runs 50 trials (`SOFTCAP_KILL_TRIALS`).
#[test]
fn search_killed_at_random_moments_leaves_nothing_or_a_complete_file() {
    use softcap_app::testing::{kill_trial_count, kill_trials, race_trials};
    let dir = tempfile::tempdir().unwrap();
    let lib = dir.path().join("lib.json");
    assert!(
        bin()
            .args(["library", "-o"])
            .arg(&lib)
            .status()
            .unwrap()
            .success()
    );
    let all: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&lib).unwrap()).unwrap();
    let small = dir.path().join("small.json");
    let three = [all[0].clone(), all[3].clone(), all[7].clone()];
    std::fs::write(&small, serde_json::to_string(&three).unwrap()).unwrap();
    let target = dir.path().join("target.json");
    let st = bin()
        .args(["target", "--materials"])
        .arg(&small)
        .args(["--design", "2,0", "-o"])
        .arg(&target)
        .status()
        .unwrap();
    assert!(st.success());
    let out = dir.path().join("out");
    let search = || {
        let mut c = bin();
        c.args(["search", "--materials"]).arg(&small);
        c.arg("--target").arg(&target).arg("-o").arg(&out);
        c
    };
    let mcap = out.join("design.mcap");
    let complete = |p: &std::path::Path| {
        softcap_mcap::Recording::open(p)
            .map(|_| ())
            .map_err(|e| e.to_string())
    };
    let tally = kill_trials(&search, &mcap, kill_trial_count(3), 331, &complete);
    let raced = race_trials(&search, &mcap, kill_trial_count(1), &complete);
    eprintln!("design search: {tally:?}, {raced} race trials");
}
