//! Settings files: every stage reads its `…Settings` struct from TOML the same way.

use std::path::Path;

use serde::de::DeserializeOwned;

use crate::error::{IntoError, Result};

/// Reads `path` as TOML into `T`; an unreadable file or a TOML/field error is bad input naming
/// the file (and, from the TOML parser, the line and column).
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).bad_input_with(|| path.display().to_string())?;
    toml::from_str(&text).bad_input_with(|| path.display().to_string())
}

/// [`load_toml`] when a settings file is given, `T::default()` otherwise.
pub fn load_toml_or_default<T: DeserializeOwned + Default>(path: Option<&Path>) -> Result<T> {
    path.map_or_else(|| Ok(T::default()), load_toml)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Default, PartialEq, serde::Deserialize)]
    #[serde(default, deny_unknown_fields)]
    struct S {
        steps: usize,
    }

    #[test]
    fn settings_load_or_fail_naming_the_file_once() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.toml");
        assert_eq!(load_toml_or_default::<S>(None).unwrap(), S::default());
        std::fs::write(&p, "steps = 4\n").unwrap();
        assert_eq!(load_toml::<S>(&p).unwrap(), S { steps: 4 });
        std::fs::write(&p, "stepz = 4\n").unwrap();
        let e = load_toml::<S>(&p).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let m = e.message();
        assert!(m.contains("stepz") && m.contains("line 1"), "{m}");
        assert_eq!(m.matches("s.toml").count(), 1, "{m}");
        let e = load_toml::<S>(&dir.path().join("missing.toml")).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert_eq!(e.message().matches("missing.toml").count(), 1);
    }
}
