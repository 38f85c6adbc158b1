//! Figures of `softcap face track --report DIR`: per camera, `splines_<camera>.png` (six frames
//! of the take with each wrinkle's valley spline and cross-section valleys drawn over the image)
//! and `depth_width_<camera>.png` (median d and w of each wrinkle's cross-sections over the
//! frames it is visible in).

use std::path::Path;

use plotters::prelude::*;

use crate::error::{FaceError, Result};
use crate::take::{Take, read_png};
use crate::take_track::CameraTrack;
use crate::video::{FrameWrinkle, WrinkleStatus};

const COLORS: [RGBColor; 4] = [
    RGBColor(230, 40, 40),
    RGBColor(40, 200, 60),
    RGBColor(250, 200, 0),
    RGBColor(220, 60, 220),
];

fn fig_err(path: &Path, e: impl std::fmt::Display) -> FaceError {
    FaceError::Image {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// Write the report figures of `tracks` into `dir`.
pub fn write_report(dir: &Path, take: &Take, tracks: &[CameraTrack]) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| FaceError::Io {
        path: dir.to_path_buf(),
        source: e,
    })?;
    for (cam, track) in take.cameras.iter().zip(tracks) {
        splines_figure(&dir.join(format!("splines_{}.png", track.id)), cam, track)?;
        depth_width_figure(&dir.join(format!("depth_width_{}.png", track.id)), track)?;
    }
    Ok(())
}

/// Median of the converged sections' (d, w) of a wrinkle in one frame, when visible.
fn median_dw(fw: &FrameWrinkle) -> Option<(f64, f64)> {
    if fw.status != WrinkleStatus::Visible {
        return None;
    }
    let t = fw.tracked.as_ref()?;
    let mut d: Vec<f64> = t
        .sections
        .iter()
        .filter(|s| s.converged)
        .map(|s| s.depth_px)
        .collect();
    let mut w: Vec<f64> = t
        .sections
        .iter()
        .filter(|s| s.converged)
        .map(|s| s.width_px)
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    w.sort_by(f64::total_cmp);
    Some((d[d.len() / 2], w[w.len() / 2]))
}

fn splines_figure(path: &Path, cam: &crate::take::TakeCamera, track: &CameraTrack) -> Result<()> {
    let n = track.frames.len();
    let picks: Vec<usize> = (0..6).map(|i| i * (n - 1) / 5).collect();
    let (w, h) = (cam.camera.width, cam.camera.height);
    let images = picks
        .iter()
        .map(|&t| read_png(&cam.frames[t], w, h))
        .collect::<Result<Vec<_>>>()?;
    let panel = (3 * w + 80, 3 * h + 70);
    softcap_figure::draw_png(path, (3 * panel.0, 2 * panel.1), |root| {
        for ((area, &t), img) in root.split_evenly((2, 3)).iter().zip(&picks).zip(&images) {
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!("{} frame {t}", track.id),
                    (softcap_figure::FONT_FAMILY, 18),
                )
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(44)
                .build_cartesian_2d(-0.5..w as f64 - 0.5, h as f64 - 0.5..-0.5)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("image column u (px)")
                .y_desc("image row v (px)")
                .draw()?;
            chart.draw_series(img.data.iter().enumerate().map(|(i, p)| {
                let (x, y) = ((i % img.width) as f64, (i / img.width) as f64);
                let g = |c: f64| (255.0 * c.clamp(0.0, 1.0).powf(1.0 / 2.2)) as u8;
                Rectangle::new(
                    [(x - 0.5, y - 0.5), (x + 0.5, y + 0.5)],
                    RGBColor(g(p[0]), g(p[1]), g(p[2])).filled(),
                )
            }))?;
            for fw in &track.frames[t] {
                let Some(tr) = &fw.tracked else { continue };
                let color = COLORS[fw.id % COLORS.len()];
                let style = if fw.status == WrinkleStatus::Visible {
                    color.stroke_width(2)
                } else {
                    color.mix(0.5).stroke_width(1)
                };
                let steps = 60;
                chart.draw_series(LineSeries::new(
                    (0..=steps).map(|i| {
                        let x =
                            tr.spline.x0 + (tr.spline.x1 - tr.spline.x0) * i as f64 / steps as f64;
                        let v = tr.spline.eval(x);
                        (v.x, v.y)
                    }),
                    style,
                ))?;
                if fw.status == WrinkleStatus::Visible {
                    chart.draw_series(tr.sections.iter().filter(|s| s.converged).map(|s| {
                        Circle::new((s.valley_px[0], s.valley_px[1]), 3, WHITE.filled())
                    }))?;
                }
            }
        }
        Ok(())
    })
    .map_err(|e| fig_err(path, e))
}

fn depth_width_figure(path: &Path, track: &CameraTrack) -> Result<()> {
    let n = track.frames.len();
    let n_wrinkles = track.frames.first().map_or(0, Vec::len);
    let series: Vec<Vec<(usize, f64, f64)>> = (0..n_wrinkles)
        .map(|k| {
            track
                .frames
                .iter()
                .enumerate()
                .filter_map(|(t, row)| row.get(k).and_then(median_dw).map(|(d, w)| (t, d, w)))
                .collect()
        })
        .collect();
    let max = |f: fn(&(usize, f64, f64)) -> f64| {
        series.iter().flatten().map(f).fold(1.0f64, f64::max) * 1.15
    };
    let (d_max, w_max) = (max(|s| s.1), max(|s| s.2));
    softcap_figure::draw_png(path, (900, 640), |root| {
        let areas = root.split_evenly((2, 1));
        for (which, area) in areas.iter().enumerate() {
            let (label, top) = if which == 0 {
                ("depth d (px)", d_max)
            } else {
                ("width w (px)", w_max)
            };
            let mut chart = ChartBuilder::on(area)
                .caption(
                    format!(
                        "{}: {label} per frame (median over cross-sections, visible frames)",
                        track.id
                    ),
                    (softcap_figure::FONT_FAMILY, 16),
                )
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..(n.max(2) - 1) as f64, 0.0..top)?;
            chart
                .configure_mesh()
                .x_desc("take frame")
                .y_desc(label)
                .draw()?;
            for (k, s) in series.iter().enumerate() {
                let color = COLORS[k % COLORS.len()];
                let pts: Vec<(f64, f64)> = s
                    .iter()
                    .map(|&(t, d, w)| (t as f64, if which == 0 { d } else { w }))
                    .collect();
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))?
                    .label(format!("wrinkle {k}"))
                    .legend(move |(x, y)| Circle::new((x, y), 3, color.filled()));
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()?;
        }
        Ok(())
    })
    .map_err(|e| fig_err(path, e))
}
