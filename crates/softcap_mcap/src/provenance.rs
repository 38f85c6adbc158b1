//! The `softcap.provenance` metadata record written into every softcap file.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::error::{Error, Result};

/// Name of the MCAP metadata record holding the provenance.
pub const PROVENANCE_METADATA: &str = "softcap.provenance";

/// Key of the provenance field that the content digest ignores.
pub const TIMESTAMP_KEY: &str = "timestamp";

/// Key of the provenance field listing the input files (a JSON array of [`InputFile`]).
pub const INPUTS_KEY: &str = "inputs";

/// One input file and its SHA-256.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InputFile {
    /// Path as given on the command line (or found inside an input folder).
    pub path: String,
    /// Lower-case hex SHA-256 of the file's bytes.
    pub sha256: String,
    /// For an MCAP input, its content digest ([`crate::Recording::digest`]), which leaves out the
    /// input's own provenance timestamp. The content digest of a file uses this instead of
    /// `sha256`, so a rerun of a whole pipeline (where every intermediate carries a new
    /// timestamp) gives the same digests downstream.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub content_digest: Option<String>,
}

impl InputFile {
    /// `path` with its SHA-256, plus the content digest when it is an MCAP file.
    fn hash(path: &Path) -> Result<Self> {
        let sha256 = sha256_file(path)?;
        let content_digest = if path.extension().is_some_and(|e| e == "mcap") {
            Some(crate::Recording::open(path)?.digest()?)
        } else {
            None
        };
        Ok(Self {
            path: path.display().to_string(),
            sha256,
            content_digest,
        })
    }
}

/// Where a file came from: stage, code version, arguments, inputs, seed and settings.
///
/// Stored as MCAP metadata `softcap.provenance` with one string value per field; `arguments` and
/// `inputs` are JSON arrays, `seed` is a decimal number or empty, `settings` is the stage's
/// settings serialized as TOML or JSON, `timestamp` is RFC 3339 UTC.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// Stage that wrote the file (`capture`, `tissue fit`, ...).
    pub stage: String,
    /// Version of the crate that wrote it.
    pub crate_version: String,
    /// Git commit of the code, or `unknown`.
    pub git_commit: String,
    /// Full argument list, program name first.
    pub arguments: Vec<String>,
    /// Every input file with its SHA-256, in the order added.
    pub inputs: Vec<InputFile>,
    /// Seed of the stage's random number generator, if it uses one.
    pub seed: Option<u64>,
    /// The stage's settings (TOML or JSON text).
    pub settings: String,
    /// When the file was written (RFC 3339 UTC). Ignored by the content digest.
    pub timestamp: String,
}

impl Provenance {
    /// Provenance for `stage` at `crate_version` (pass `env!("CARGO_PKG_VERSION")`), with the git
    /// commit detected by [`git_commit`], the process's arguments and the current time.
    pub fn new(stage: impl Into<String>, crate_version: impl Into<String>) -> Self {
        Self {
            stage: stage.into(),
            crate_version: crate_version.into(),
            git_commit: git_commit(),
            arguments: std::env::args().collect(),
            inputs: Vec::new(),
            seed: None,
            settings: String::new(),
            timestamp: utc_timestamp(SystemTime::now()),
        }
    }

    /// Replaces the argument list (default: the process's arguments).
    pub fn with_arguments<I, S>(mut self, arguments: I) -> Self
    where
        I: IntoIterator<Item = S>,
        S: Into<String>,
    {
        self.arguments = arguments.into_iter().map(Into::into).collect();
        self
    }

    /// Sets the RNG seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = Some(seed);
        self
    }

    /// Sets the settings text (serialize the stage's settings struct to TOML or JSON first).
    pub fn with_settings(mut self, settings: impl Into<String>) -> Self {
        self.settings = settings.into();
        self
    }

    /// Hashes an input: a file, or every file below a folder (sorted by path, recursively).
    pub fn with_input(mut self, path: impl AsRef<Path>) -> Result<Self> {
        self.add_input(path)?;
        Ok(self)
    }

    /// Hashes an input in place; see [`Provenance::with_input`].
    pub fn add_input(&mut self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let meta = std::fs::metadata(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            action: "reading input",
            source,
        })?;
        if meta.is_dir() {
            let mut files = Vec::new();
            collect_files(path, &mut files)?;
            files.sort();
            for f in files {
                self.inputs.push(InputFile::hash(&f)?);
            }
        } else {
            self.inputs.push(InputFile::hash(path)?);
        }
        Ok(())
    }

    /// The metadata map written to the file.
    pub fn to_metadata(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("stage".into(), self.stage.clone());
        m.insert("crate_version".into(), self.crate_version.clone());
        m.insert("git_commit".into(), self.git_commit.clone());
        m.insert(
            "arguments".into(),
            serde_json::to_string(&self.arguments).expect("strings serialize"),
        );
        m.insert(
            INPUTS_KEY.into(),
            serde_json::to_string(&self.inputs).expect("strings serialize"),
        );
        m.insert(
            "seed".into(),
            self.seed.map(|s| s.to_string()).unwrap_or_default(),
        );
        m.insert("settings".into(), self.settings.clone());
        m.insert(TIMESTAMP_KEY.into(), self.timestamp.clone());
        m
    }

    /// Parses the metadata map back; `path` names the file in errors.
    pub fn from_metadata(path: &Path, m: &BTreeMap<String, String>) -> Result<Self> {
        let field = |key: &str| -> Result<String> {
            m.get(key).cloned().ok_or_else(|| Error::Provenance {
                path: path.to_path_buf(),
                field: key.into(),
                problem: "missing".into(),
            })
        };
        let bad = |key: &str, problem: String| Error::Provenance {
            path: path.to_path_buf(),
            field: key.into(),
            problem,
        };
        let arguments: Vec<String> = serde_json::from_str(&field("arguments")?)
            .map_err(|e| bad("arguments", format!("not a JSON string array: {e}")))?;
        let inputs: Vec<InputFile> = serde_json::from_str(&field("inputs")?).map_err(|e| {
            bad(
                "inputs",
                format!("not a JSON array of {{path, sha256}}: {e}"),
            )
        })?;
        let seed_text = field("seed")?;
        let seed = if seed_text.is_empty() {
            None
        } else {
            Some(
                seed_text
                    .parse()
                    .map_err(|e| bad("seed", format!("`{seed_text}` is not a u64: {e}")))?,
            )
        };
        Ok(Self {
            stage: field("stage")?,
            crate_version: field("crate_version")?,
            git_commit: field("git_commit")?,
            arguments,
            inputs,
            seed,
            settings: field("settings")?,
            timestamp: field(TIMESTAMP_KEY)?,
        })
    }
}

fn collect_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    let io = |source| Error::Io {
        path: dir.to_path_buf(),
        action: "listing input folder",
        source,
    };
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.is_dir() {
            collect_files(&path, out)?;
        } else {
            out.push(path);
        }
    }
    Ok(())
}

/// Lower-case hex SHA-256 of a file's bytes (streamed).
pub fn sha256_file(path: impl AsRef<Path>) -> Result<String> {
    let path = path.as_ref();
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        action: "hashing input",
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hex::encode(hasher.finalize()))
}

/// The git commit of the code: `$SOFTCAP_GIT_COMMIT` if set, else `git rev-parse HEAD` run in the
/// current directory, else `unknown`.
pub fn git_commit() -> String {
    if let Ok(c) = std::env::var("SOFTCAP_GIT_COMMIT")
        && !c.trim().is_empty()
    {
        return c.trim().to_string();
    }
    std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .stderr(std::process::Stdio::null())
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "unknown".to_string())
}

/// RFC 3339 UTC timestamp with nanoseconds, e.g. `2026-11-21T17:30:00.000000000Z`.
pub fn utc_timestamp(t: SystemTime) -> String {
    let d = t.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs();
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let (y, m, day) = civil_from_days(days);
    format!(
        "{y:04}-{m:02}-{day:02}T{:02}:{:02}:{:02}.{:09}Z",
        rem / 3600,
        (rem % 3600) / 60,
        rem % 60,
        d.subsec_nanos()
    )
}

/// Days since 1970-01-01 → (year, month, day) in the proleptic Gregorian calendar
/// (H. Hinnant, "chrono-compatible low-level date algorithms", `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn timestamps_match_known_dates() {
        assert_eq!(utc_timestamp(UNIX_EPOCH), "1970-01-01T00:00:00.000000000Z");
        // 2000-02-29T12:34:56Z = 951827696 s (leap day of a 400-year leap year).
        let t = UNIX_EPOCH + Duration::new(951_827_696, 5);
        assert_eq!(utc_timestamp(t), "2000-02-29T12:34:56.000000005Z");
        // 2026-11-21T00:00:00Z = 1795219200 s.
        let t = UNIX_EPOCH + Duration::from_secs(1_795_219_200);
        assert_eq!(utc_timestamp(t), "2026-11-21T00:00:00.000000000Z");
    }

    #[test]
    fn sha256_of_known_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("abc.txt");
        std::fs::write(&p, b"abc").unwrap();
        assert_eq!(
            sha256_file(&p).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
