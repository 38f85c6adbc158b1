//! softcap's fuzz harness: [`readers::TARGETS`] and the scratch folder the fuzz targets write
//! their input files to.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

pub mod readers;

/// A scratch folder of this process (`$TMPDIR/softcap-fuzz-PID`; `scripts/fuzz` removes it).
pub fn scratch() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("softcap-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("creating the fuzz scratch folder");
        dir
    })
}

/// Runs the target `name` on `data`: any `Err` is a clean rejection; a panic is a finding.
///
/// `softcap_mesh::parse_msh_bytes` and `softcap_capture::read_c3d` turn a panic inside the
/// third-party `mshio` and `c3dio` parsers into a bad-file error with `catch_unwind`; libFuzzer's
/// panic hook would abort before that, so the `msh` and `c3d` targets install a silent hook. A panic outside that `catch_unwind` still unwinds into
/// libfuzzer-sys, which reports it as a crash.
pub fn fuzz(name: &str, data: &[u8]) {
    static HOOK: OnceLock<()> = OnceLock::new();
    if name == "msh" || name == "c3d" {
        HOOK.get_or_init(|| std::panic::set_hook(Box::new(|_| {})));
    }
    let target = readers::target(name).expect("a target of readers::TARGETS");
    let _ = (target.read)(scratch(), data);
}
