//! AnimFace facial motion-capture CSV reader (`frame,time_s,marker,x_cm,y_cm,z_cm`).
//!
//! Marker positions m_{i,t} of thesis §3.2 in the mocap space (cm). Markers are sorted by
//! name so marker index i is deterministic; every frame must carry every marker exactly once.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::Vector3;

use crate::error::{FaceError, Result};

/// A mocap take: `positions_cm[t][i]` is marker `names[i]` at frame `frames[t]`.
#[derive(Clone, Debug, PartialEq)]
pub struct MocapTake {
    /// Marker names, sorted.
    pub names: Vec<String>,
    /// Source frame numbers, ascending.
    pub frames: Vec<u64>,
    /// Times of the frames, seconds.
    pub times_s: Vec<f64>,
    /// Marker positions per frame, cm, in the mocap space.
    pub positions_cm: Vec<Vec<Vector3<f64>>>,
}

impl MocapTake {
    /// Index of a marker by name.
    pub fn marker_index(&self, name: &str) -> Option<usize> {
        self.names.binary_search_by(|n| n.as_str().cmp(name)).ok()
    }
}

/// Read an AnimFace CSV take. Errors name the file, line and field.
pub fn read_animface_csv(path: &Path) -> Result<MocapTake> {
    let text = std::fs::read_to_string(path).map_err(|source| FaceError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_animface_csv(&text, path)
}

/// Parse AnimFace CSV text (`path` only names the source in errors).
pub fn parse_animface_csv(text: &str, path: &Path) -> Result<MocapTake> {
    let err = |line: usize, field: &str, reason: String| FaceError::Parse {
        path: path.to_path_buf(),
        line,
        field: field.to_string(),
        reason,
    };
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    if header != "frame,time_s,marker,x_cm,y_cm,z_cm" {
        return Err(err(
            1,
            "header",
            format!("expected `frame,time_s,marker,x_cm,y_cm,z_cm`, got `{header}`"),
        ));
    }
    let mut by_frame: BTreeMap<u64, (f64, BTreeMap<String, Vector3<f64>>, usize)> = BTreeMap::new();
    for (k, raw) in lines {
        let line = k + 1;
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let cols: Vec<&str> = raw.split(',').collect();
        if cols.len() != 6 {
            return Err(err(
                line,
                "record",
                format!("expected 6 fields, got {}", cols.len()),
            ));
        }
        let frame: u64 = cols[0]
            .parse()
            .map_err(|e| err(line, "frame", format!("`{}`: {e}", cols[0])))?;
        let num = |i: usize, name: &str| -> Result<f64> {
            let v: f64 = cols[i]
                .parse()
                .map_err(|e| err(line, name, format!("`{}`: {e}", cols[i])))?;
            if !v.is_finite() {
                return Err(err(line, name, format!("non-finite value `{}`", cols[i])));
            }
            Ok(v)
        };
        let time = num(1, "time_s")?;
        let p = Vector3::new(num(3, "x_cm")?, num(4, "y_cm")?, num(5, "z_cm")?);
        let marker = cols[2].trim();
        if marker.is_empty() {
            return Err(err(line, "marker", "empty marker name".into()));
        }
        let entry = by_frame
            .entry(frame)
            .or_insert((time, BTreeMap::new(), line));
        if entry.1.insert(marker.to_string(), p).is_some() {
            return Err(err(
                line,
                "marker",
                format!("marker `{marker}` repeated in frame {frame}"),
            ));
        }
    }
    let Some((_, (_, first, _))) = by_frame.iter().next() else {
        return Err(err(2, "record", "no frames".into()));
    };
    let names: Vec<String> = first.keys().cloned().collect();
    let mut take = MocapTake {
        names,
        frames: Vec::new(),
        times_s: Vec::new(),
        positions_cm: Vec::new(),
    };
    for (frame, (time, markers, line)) in by_frame {
        if markers.len() != take.names.len()
            || !markers.keys().zip(&take.names).all(|(a, b)| a == b)
        {
            return Err(err(
                line,
                "marker",
                format!(
                    "frame {frame} has {} markers, differing from the first frame's {}",
                    markers.len(),
                    take.names.len()
                ),
            ));
        }
        take.frames.push(frame);
        take.times_s.push(time);
        take.positions_cm.push(markers.into_values().collect());
    }
    Ok(take)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects_bad_fields() {
        let ok = "frame,time_s,marker,x_cm,y_cm,z_cm\n0,0.0,B,1,2,3\n0,0.0,A,4,5,6\n1,0.016,A,4,5,7\n1,0.016,B,1,2,3\n";
        let t = parse_animface_csv(ok, Path::new("t.csv")).unwrap();
        assert_eq!(t.names, vec!["A", "B"]);
        assert_eq!(t.positions_cm[1][0], Vector3::new(4.0, 5.0, 7.0));
        let bad = "frame,time_s,marker,x_cm,y_cm,z_cm\n0,0.0,A,1,x,3\n";
        let e = parse_animface_csv(bad, Path::new("t.csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.csv:2") && e.contains("y_cm"), "{e}");
        let missing =
            "frame,time_s,marker,x_cm,y_cm,z_cm\n0,0.0,A,1,2,3\n0,0.0,B,1,2,3\n1,0.1,A,1,2,3\n";
        assert!(parse_animface_csv(missing, Path::new("t.csv")).is_err());
    }
}
