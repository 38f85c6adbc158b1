//! Settings files: every stage reads its `…Settings` struct from TOML the same way.

use std::path::Path;

use serde::de::DeserializeOwned;

use crate::error::{IntoError, Result};

/// Reads `path` as TOML into `T`; an unreadable file, a TOML/field error or a `nan` / `inf`
/// value is bad input naming the file (and the line and the field).
pub fn load_toml<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).bad_input_with(|| path.display().to_string())?;
    if let Some(bad) = non_finite(&text) {
        return Err(crate::Error::bad_input(format!(
            "{}: {bad}",
            path.display()
        )));
    }
    toml::from_str(&text).bad_input_with(|| path.display().to_string())
}

/// A `nan` or `±inf` value in a TOML file: where it is.
#[derive(Clone, Debug, PartialEq)]
pub struct NonFinite {
    /// Dotted key (`camera[1].fx`).
    pub key: String,
    /// 1-based line.
    pub line: usize,
    /// The value.
    pub value: f64,
}

impl std::fmt::Display for NonFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "line {}: {} = {}: not a finite number",
            self.line, self.key, self.value
        )
    }
}

/// The first non-finite float (`nan`, `inf`, `-inf`: valid TOML, never a valid softcap input) in
/// TOML `text`, or `None` (also when `text` is not TOML: the parser reports that).
pub fn non_finite(text: &str) -> Option<NonFinite> {
    fn walk(v: &toml::Value, key: &str) -> Option<(String, f64)> {
        match v {
            toml::Value::Float(x) if !x.is_finite() => Some((key.to_string(), *x)),
            toml::Value::Array(a) => a
                .iter()
                .enumerate()
                .find_map(|(i, v)| walk(v, &format!("{key}[{i}]"))),
            toml::Value::Table(t) => t.iter().find_map(|(k, v)| {
                walk(
                    v,
                    &if key.is_empty() {
                        k.clone()
                    } else {
                        format!("{key}.{k}")
                    },
                )
            }),
            _ => None,
        }
    }
    // Cheap exit: every non-finite TOML float is spelled with `nan` or `inf`.
    if !(text.contains("nan") || text.contains("inf")) {
        return None;
    }
    let table: toml::Table = text.parse().ok()?;
    let (key, value) = walk(&toml::Value::Table(table), "")?;
    let name = key.rsplit('.').next().unwrap_or(&key);
    let name = name.split('[').next().unwrap_or(name);
    let is_token = |l: &str| {
        l.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .any(|w| w == "nan" || w == "inf")
    };
    let line = text
        .lines()
        .position(|l| l.trim_start().starts_with(name) && is_token(l))
        .or_else(|| text.lines().position(is_token))
        .map_or(1, |i| i + 1);
    Some(NonFinite { key, line, value })
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
        std::fs::write(&p, "# notes\nsteps = 4\n[fit]\nscale = [1.0,\n  -inf]\n").unwrap();
        let e = load_toml::<S>(&p).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let m = e.message();
        assert!(
            m.contains("line 5: fit.scale[1] = -inf: not a finite number"),
            "{m}"
        );
        assert_eq!(
            non_finite("a = 1.0\nb = \"nan inf\"\n[c]\nd = nan\n").map(|n| (n.key, n.line)),
            Some(("c.d".into(), 4))
        );
        assert_eq!(non_finite("a = 1.0\nb = \"nan\"\n"), None);
        let e = load_toml::<S>(&dir.path().join("missing.toml")).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert_eq!(e.message().matches("missing.toml").count(), 1);
    }
}
