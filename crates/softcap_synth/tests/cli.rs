//! The `softcap-synth` binary on bad input: one clear error naming the file and the field, exit
//! code 2, and no output folder (not even a half-written one).

use std::path::Path;
use std::process::Command;

fn run(scenario: &Path, out: &Path) -> (i32, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_softcap-synth"))
        .arg("--scenario")
        .arg(scenario)
        .arg("--out")
        .arg(out)
        .output()
        .expect("run softcap-synth");
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

fn nothing_written(out: &Path) {
    assert!(!out.exists(), "{} exists", out.display());
    let mut tmp = out.as_os_str().to_owned();
    tmp.push(".synth-tmp");
    assert!(!Path::new(&tmp).exists(), "temporary folder left behind");
}

#[test]
fn bad_scenarios_exit_2_naming_file_and_field_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, &str, &[&str]); 6] = [
        (
            "malformed.toml",
            "name = \"x\"\n[protocol]\nlocations = = 3\n",
            &["malformed.toml", "line 3"],
        ),
        (
            "unknown-effect.toml",
            "name = \"x\"\neffects = [\"telepathy\"]\n",
            &[
                "unknown-effect.toml",
                "line 2",
                "field `effects`",
                "telepathy",
            ],
        ),
        (
            "missing-name.toml",
            "seed = 3\n[protocol]\nlocations = 2\n",
            &["missing-name.toml", "field `name`", "missing"],
        ),
        (
            "unknown-key.toml",
            "name = \"x\"\n\n[protocol]\nloctions = 3\n",
            &["unknown-key.toml", "line 4", "field `protocol.loctions`"],
        ),
        (
            "wrong-type.toml",
            "name = \"x\"\n[object]\nsize_mm = [40, 40, \"tall\"]\n",
            &["wrong-type.toml", "line 3", "field `object.size_mm`"],
        ),
        (
            "out-of-range.toml",
            "name = \"x\"\n[effect_settings]\nviscoelastic_tau_s = -1.0\n",
            &["out-of-range.toml", "effect_settings.viscoelastic_tau_s"],
        ),
    ];
    for (file, text, expect) in cases {
        let p = dir.path().join(file);
        std::fs::write(&p, text).unwrap();
        let out = dir.path().join(format!("{file}.out"));
        let (code, stderr) = run(&p, &out);
        println!("{file}: exit {code}: {}", stderr.trim());
        assert_eq!(code, 2, "{file}: {stderr}");
        assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");
        for e in expect {
            assert!(stderr.contains(e), "{file}: `{e}` not in {stderr}");
        }
        nothing_written(&out);
    }
    // Effects that cannot be combined, a missing scenario file, a non-empty output folder.
    let p = dir.path().join("combo.toml");
    std::fs::write(
        &p,
        "name = \"x\"\neffects = [\"plasticity\", \"viscoelasticity\"]\n",
    )
    .unwrap();
    let (code, stderr) = run(&p, &dir.path().join("combo.out"));
    assert_eq!(code, 2);
    assert!(
        stderr.contains("combo.toml") && stderr.contains("effects"),
        "{stderr}"
    );
    nothing_written(&dir.path().join("combo.out"));
    let (code, stderr) = run(&dir.path().join("absent.toml"), &dir.path().join("a.out"));
    assert_eq!(code, 2);
    assert!(stderr.contains("absent.toml"), "{stderr}");
    let full = dir.path().join("full");
    std::fs::create_dir(&full).unwrap();
    std::fs::write(full.join("keep.txt"), "x").unwrap();
    let good = dir.path().join("good.toml");
    std::fs::write(&good, "name = \"x\"\n").unwrap();
    let (code, stderr) = run(&good, &full);
    assert_eq!(code, 2, "{stderr}");
    assert!(stderr.contains("not empty"), "{stderr}");
    assert_eq!(std::fs::read_dir(&full).unwrap().count(), 1);
}

/// `--help`/`--version` exit 0; a missing scenario is bad input (2) named once.
#[test]
fn exit_codes_of_help_version_and_missing_file() {
    use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
    let bin = env!("CARGO_BIN_EXE_softcap-synth");
    assert_help_version_usage(bin);
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.toml");
    let out = dir.path().join("s");
    let r = run(
        bin,
        &[
            "--scenario",
            missing.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
    );
    assert_error_names_once(&r, 2, &missing);
    assert!(!out.exists());
}
