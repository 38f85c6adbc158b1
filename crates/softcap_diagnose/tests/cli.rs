//! The `softcap-diagnose` command line: parsing and exit codes.

use clap::Parser;
use softcap_app::testing::{assert_error_names_once, assert_help_version_usage, run};
use softcap_diagnose::cli::Cli;

const BIN: &str = env!("CARGO_BIN_EXE_softcap-diagnose");

#[test]
fn parses_inputs_outputs_and_settings() {
    let c = Cli::try_parse_from([
        "softcap-diagnose",
        "c.mcap",
        "m.mcap",
        "-o",
        "d.mcap",
        "--json",
        "d.json",
    ])
    .unwrap();
    assert_eq!(c.output.to_str(), Some("d.mcap"));
    assert_eq!(c.json.as_deref().and_then(|p| p.to_str()), Some("d.json"));
    assert!(c.report.is_none() && c.settings.is_none());
    assert!(Cli::try_parse_from(["softcap-diagnose", "c.mcap", "m.mcap"]).is_err());
}

/// `--help`/`--version` exit 0 (`softcap diagnose --help` is this binary's help); a missing and
/// a corrupt capture.mcap are bad input (2), each named once; nothing is written.
#[test]
fn exit_codes_of_help_version_missing_and_bad_file() {
    assert_help_version_usage(BIN);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d.mcap");
    let material = dir.path().join("m.mcap");
    for (name, content) in [("missing.mcap", None), ("bad.mcap", Some("not an mcap"))] {
        let capture = dir.path().join(name);
        if let Some(c) = content {
            std::fs::write(&capture, c).unwrap();
        }
        let r = run(
            BIN,
            &[
                capture.to_str().unwrap(),
                material.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ],
        );
        assert_error_names_once(&r, 2, &capture);
    }
    assert!(!out.exists());
}
