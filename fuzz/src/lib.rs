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
pub fn fuzz(name: &str, data: &[u8]) {
    let target = readers::target(name).expect("a target of readers::TARGETS");
    let _ = (target.read)(scratch(), data);
}
