//! `softcap inspect plot`: a PNG time series of numeric fields of one channel.
//!
//! A field is named by a path into the decoded protobuf message (proto field names):
//! `force_n.z`, `markers[3].position_m.x` (fourth element), `markers[id=7].position_m.z`
//! (the element whose `id` is 7), `entries[key=lm.cost].number`. 64-bit integers and
//! default-valued fields are handled (a proto3 field left at its default is read as 0).
//! The x axis is the message log time in seconds, or another field with `--x`.

use std::path::Path;

use plotters::prelude::*;
use serde_json::Value;
use softcap_app::{Error, IntoError, Result};
use softcap_mcap::Recording;

use crate::inspect::decode_messages;

/// One plotted series: the field path and its (x, y) samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub field: String,
    pub points: Vec<(f64, f64)>,
}

/// One step of a field path.
#[derive(Debug, Clone, PartialEq)]
enum Step {
    Key(String),
    Index(usize),
    Select { key: String, value: String },
}

/// Parses `a.b[3].c[id=7].d` into steps; a bad path is a bad-input error naming it.
fn parse_path(path: &str) -> Result<Vec<Step>> {
    let bad = |why: &str| Error::bad_input(format!("field `{path}`: {why}"));
    let mut steps = Vec::new();
    for part in path.split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if name.is_empty() && steps.is_empty() {
            return Err(bad("empty field name"));
        }
        if !name.is_empty() {
            steps.push(Step::Key(name.to_string()));
        }
        while !rest.is_empty() {
            let close = rest.find(']').ok_or_else(|| bad("unclosed `[`"))?;
            let inner = &rest[1..close];
            match inner.split_once('=') {
                Some((k, v)) => steps.push(Step::Select {
                    key: k.trim().to_string(),
                    value: v.trim().to_string(),
                }),
                None => {
                    steps.push(Step::Index(inner.trim().parse().map_err(|_| {
                        bad(&format!("`[{inner}]` is not an index or key=value"))
                    })?))
                }
            }
            rest = &rest[close + 1..];
            if !rest.is_empty() && !rest.starts_with('[') {
                return Err(bad("unexpected text after `]`"));
            }
        }
    }
    if steps.is_empty() {
        return Err(bad("empty path"));
    }
    Ok(steps)
}

/// Numeric value of a JSON scalar (numbers, numeric strings for 64-bit integers, booleans).
fn number(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.parse().ok(),
        Value::Bool(b) => Some(f64::from(u8::from(*b))),
        _ => None,
    }
}

/// Scalar equality used by `[key=value]` selectors: numeric when both sides are numbers.
fn matches(v: &Value, want: &str) -> bool {
    match (number(v), want.parse::<f64>()) {
        (Some(a), Ok(b)) => a == b,
        _ => v.as_str() == Some(want),
    }
}

/// Follows `steps` into `v`. `None` when the path does not exist in this message.
fn follow<'a>(v: &'a Value, steps: &[Step]) -> Option<&'a Value> {
    let mut cur = v;
    for s in steps {
        cur = match s {
            Step::Key(k) => cur.get(k)?,
            Step::Index(i) => cur.get(*i)?,
            Step::Select { key, value } => cur
                .as_array()?
                .iter()
                .find(|e| e.get(key).is_some_and(|x| matches(x, value)))?,
        };
    }
    Some(cur)
}

/// Extracts the series of `fields` (y) against `x_field` (or log time in seconds) from the
/// messages of `topic`. Messages where a path is absent are skipped for that series; a
/// path that resolves in no message at all is bad input.
pub fn extract(
    r: &Recording,
    topic: &str,
    fields: &[String],
    x_field: Option<&str>,
) -> Result<Vec<Series>> {
    if r.channel(topic).is_none() {
        return Err(Error::bad_input(format!(
            "{}: no channel `{topic}`",
            r.path().display()
        )));
    }
    let paths = fields
        .iter()
        .map(|f| parse_path(f))
        .collect::<Result<Vec<_>>>()?;
    let x_path = x_field.map(parse_path).transpose()?;
    let messages = decode_messages(r, Some(topic), true)?;
    let mut series: Vec<Series> = fields
        .iter()
        .map(|f| Series {
            field: f.clone(),
            points: Vec::new(),
        })
        .collect();
    for m in &messages {
        let x = match &x_path {
            Some(p) => match follow(&m.message, p).and_then(number) {
                Some(x) => x,
                None => continue,
            },
            None => m.log_time_ns as f64 * 1e-9,
        };
        for (s, p) in series.iter_mut().zip(&paths) {
            if let Some(y) = follow(&m.message, p).and_then(number) {
                s.points.push((x, y));
            }
        }
    }
    for s in &series {
        if s.points.is_empty() {
            return Err(Error::bad_input(format!(
                "{}: field `{}` is not a number in any message of `{topic}`",
                r.path().display(),
                s.field
            )));
        }
    }
    Ok(series)
}

/// Draws `series` as lines into a PNG at `output` (written atomically).
pub fn draw(series: &[Series], title: &str, x_label: &str, output: &Path) -> Result<()> {
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in series.iter().flat_map(|s| &s.points) {
        if x.is_finite() && y.is_finite() {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    if !x0.is_finite() {
        return Err(Error::bad_input("nothing finite to plot"));
    }
    let pad = |a: f64, b: f64| {
        let d = if b > a {
            0.05 * (b - a)
        } else {
            0.5 * a.abs().max(1e-12)
        };
        (a - d, b + d)
    };
    let (x0, x1) = pad(x0, x1);
    let (y0, y1) = pad(y0, y1);
    softcap_figure::draw_png(output, (1000, 600), |root| {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(title, (softcap_figure::FONT_FAMILY, 22))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label(series))
            .draw()?;
        for (k, s) in series.iter().enumerate() {
            let color = Palette99::pick(k).to_rgba();
            chart
                .draw_series(LineSeries::new(
                    s.points.iter().copied(),
                    color.stroke_width(2),
                ))?
                .label(with_unit(&s.field))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    })
    .failure_with(|| output.display().to_string())
}

/// The SI unit a softcap field name carries in its suffix (`force_n` → N, `tip_m` → m,
/// `t_camera_s` → s, `reprojection_error_px` → px): the last named step of `path` that has one.
pub fn unit_of(path: &str) -> Option<&'static str> {
    const SUFFIXES: [(&str, &str); 9] = [
        ("_m_s2", "m/s²"),
        ("_kg_m3", "kg/m³"),
        ("_pa", "Pa"),
        ("_px", "px"),
        ("_mm", "mm"),
        ("_n", "N"),
        ("_m", "m"),
        ("_s", "s"),
        ("_v", "V"),
    ];
    path.split('.')
        .rev()
        .map(|step| step.split('[').next().unwrap_or(step))
        .find_map(|name| {
            SUFFIXES
                .iter()
                .find(|(suffix, _)| name.ends_with(suffix))
                .map(|&(_, unit)| unit)
        })
}

/// `field [unit]`, or the field alone when its name carries no unit.
fn with_unit(field: &str) -> String {
    match unit_of(field) {
        Some(u) => format!("{field} [{u}]"),
        None => field.to_string(),
    }
}

/// The y axis names the one unit all series share, else says the units are in the legend.
fn y_label(series: &[Series]) -> String {
    let mut units = series.iter().map(|s| unit_of(&s.field));
    match units.next() {
        Some(Some(u)) if units.all(|v| v == Some(u)) => format!("value [{u}]"),
        _ if series.len() == 1 => "value (dimensionless)".into(),
        _ => "value (units in the legend)".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn paths_follow_keys_indices_and_selectors() {
        let v = json!({"markers": [
            {"id": 3, "position_m": {"x": 1.0, "z": "4"}},
            {"id": "7", "position_m": {"x": 2.5}}
        ], "force_n": {"z": -0.5}});
        let get = |p: &str| follow(&v, &parse_path(p).unwrap()).and_then(number);
        assert_eq!(get("force_n.z"), Some(-0.5));
        assert_eq!(get("markers[1].position_m.x"), Some(2.5));
        assert_eq!(get("markers[id=7].position_m.x"), Some(2.5));
        assert_eq!(get("markers[id=3].position_m.z"), Some(4.0));
        assert_eq!(get("markers[id=9].position_m.x"), None);
        assert_eq!(get("markers[5].id"), None);
        assert!(parse_path("a[1").is_err());
        assert!(parse_path("a[x]").is_err());
        assert!(parse_path("").is_err());
    }

    #[test]
    fn units_come_from_the_field_names() {
        assert_eq!(unit_of("force_n.z"), Some("N"));
        assert_eq!(unit_of("markers[id=7].position_m.z"), Some("m"));
        assert_eq!(unit_of("markers[0].reprojection_error_px"), Some("px"));
        assert_eq!(unit_of("t_camera_s"), Some("s"));
        assert_eq!(unit_of("entries[key=lm.cost].number"), None);
        let series = |f: &[&str]| -> Vec<Series> {
            f.iter()
                .map(|f| Series {
                    field: f.to_string(),
                    points: vec![],
                })
                .collect()
        };
        assert_eq!(y_label(&series(&["force_n.x", "force_n.z"])), "value [N]");
        assert_eq!(
            y_label(&series(&["force_n.z", "tip_m.z"])),
            "value (units in the legend)"
        );
        assert_eq!(with_unit("tip_m.z"), "tip_m.z [m]");
    }
}
