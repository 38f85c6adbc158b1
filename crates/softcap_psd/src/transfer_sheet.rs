//! The identity-transfer sheet of `softcap-psd evaluate` (thesis §5.4.4, Fig. 5.8 style): the
//! WPSD details learned on the generic ICT face, transferred to each ICT identity and rendered
//! next to the shell alone, the ground truth and the signed detail along the normal.

use std::path::Path;

use nalgebra::Vector3;

use crate::error::{PsdError, Result};
use crate::{
    Animator, EvaluationSettings, FaceRig, FitMode, IctData, Method, frames, greedy_selection,
    identity_correspondence, pose_sets, render, transfer_details,
};

/// Half-range of the signed-detail colour scale: ±0.2 cm = ±2 mm (the ICT face is in cm).
const SIGNED_DETAIL_LIMIT_CM: f32 = 0.2;

/// Column titles of the sheet.
const COLUMNS: [&str; 4] = [
    "large-scale shell only",
    "+ transferred details",
    "ground truth",
    "signed detail along the normal",
];

fn to_f32(x: &[Vector3<f64>]) -> Vec<[f32; 3]> {
    x.iter()
        .map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .collect()
}

/// One identity's errors on the held-out pose of the sheet.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TransferRow {
    /// Identity (`generic` for the source face).
    pub identity: String,
    /// The held-out pose shown.
    pub pose: String,
    /// RMS vertex error of the large-scale shell alone, mm.
    pub large_only_rms_mm: f64,
    /// RMS vertex error with the transferred details, mm.
    pub transferred_rms_mm: f64,
}

fn rms_mm(a: &[[f32; 3]], b: &[Vector3<f64>]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) - y).norm_squared())
        .sum();
    10.0 * (s / a.len() as f64).sqrt()
}

/// Source-face renders and the identity transfer (thesis §5.4.4, Fig. 5.8 style): writes
/// `out/transfer_identities.png` and returns one row of errors per identity.
pub fn transfer_sheet(
    data: &IctData,
    rig: &FaceRig,
    settings: &EvaluationSettings,
    out: &Path,
) -> Result<Vec<TransferRow>> {
    let (training, heldout) = pose_sets(data, settings);
    let poses: Vec<_> = training.iter().map(|r| data.pose(r)).collect();
    let examples = rig.examples(&poses)?;
    let method = Method::Wpsd(FitMode::LeastSquares, rig.edge_weights.clone());
    let steps = greedy_selection(&examples, &method, 0, 12, |_, _| Ok(()))?;
    let basis = steps
        .last()
        .map(|s| s.basis.clone())
        .unwrap_or_else(|| vec![0]);
    let model = method.fit(&examples, &basis)?;
    // the held-out pose with the largest detail (error of the shell alone)
    let pick = heldout
        .iter()
        .map(|r| {
            let p = data.pose(r);
            let (x, _) = rig.large_scale(&rig.handle_positions(&p));
            rms_mm(&x, &p)
        })
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|x| x.0)
        .unwrap_or(0);
    let recipe = &heldout[pick];
    let tile = 200;
    let mut rows = Vec::new();
    let mut grid: Vec<image::RgbImage> = Vec::new();
    let mut targets = vec![("generic".to_string(), data.mesh.vertices.clone())];
    for k in 0..data.identities.names.len() {
        targets.push((
            data.identities.names[k].clone(),
            data.identities.combine(&data.mesh.vertices, &[(k, 1.0)]),
        ));
    }
    for (name, rest) in &targets {
        let mesh = softcap_mesh::TriMesh {
            vertices: rest.clone(),
            triangles: data.mesh.triangles.clone(),
        };
        let trig =
            FaceRig::with_handles(&mesh, rig.handles.clone(), Some(&rig.graph), &settings.rig)?;
        let tmodel = transfer_details(&model, &trig, &identity_correspondence(rest.len()))?;
        let truth = data.expressions.combine(rest, &recipe.weights);
        let hp = trig.handle_positions(&truth);
        let (large, large_n) = trig.large_scale(&hp);
        let mut anim = Animator::new(&trig, &tmodel)?;
        anim.frame(&hp)?;
        rows.push(TransferRow {
            identity: name.clone(),
            pose: recipe.name.clone(),
            large_only_rms_mm: rms_mm(&large, &truth),
            transferred_rms_mm: rms_mm(&anim.positions, &truth),
        });
        // panels: large-scale only | + details | ground truth | signed detail along the normal
        let truth32 = to_f32(&truth);
        let view = render::View::fit(&truth32, tile);
        let tris = &trig.topology.triangles;
        let normals_of = |x: &[[f32; 3]]| {
            let mut f = vec![[0.0; 3]; tris.len()];
            frames::face_normals(&trig.topology, x, &mut f);
            let mut n = vec![[0.0; 3]; x.len()];
            frames::vertex_normals(&trig.topology, &f, &mut n);
            n
        };
        let signed: Vec<[f32; 3]> = (0..large.len())
            .map(|v| {
                let d: f32 = (0..3)
                    .map(|k| (anim.positions[v][k] - large[v][k]) * large_n[v][k])
                    .sum();
                render::diverging(d / SIGNED_DETAIL_LIMIT_CM)
            })
            .collect();
        grid.push(render::render(&view, &large, &large_n, tris, None));
        grid.push(render::render(
            &view,
            &anim.positions,
            &anim.normals,
            tris,
            None,
        ));
        grid.push(render::render(
            &view,
            &truth32,
            &normals_of(&truth32),
            tris,
            None,
        ));
        grid.push(render::render(
            &view,
            &anim.positions,
            &anim.normals,
            tris,
            Some(&signed),
        ));
    }
    let names: Vec<&str> = targets.iter().map(|(n, _)| n.as_str()).collect();
    let sheet = compose_sheet(&grid, &names).map_err(|reason| PsdError::Render {
        path: out.join("transfer_identities.png"),
        reason,
    })?;
    render::save_png(&sheet, &out.join("transfer_identities.png"))?;
    Ok(rows)
}

/// Lays the panels (four per identity, row-major) out under the column titles, names each row's
/// identity, and puts the signed detail's colour bar (quantity and unit) under the last column.
fn compose_sheet(
    grid: &[image::RgbImage],
    identities: &[&str],
) -> std::result::Result<image::RgbImage, String> {
    use plotters::prelude::*;
    const HEADER: u32 = 28;
    const FOOTER: u32 = 74;
    let tw = grid.first().map_or(1, |g| g.width());
    let th = grid.iter().map(|g| g.height()).max().unwrap_or(1);
    let rows = identities.len() as u32;
    let (w, h) = (4 * tw, HEADER + th * rows + FOOTER);
    let mut sheet = image::RgbImage::from_pixel(w, h, image::Rgb([255, 255, 255]));
    for (i, img) in grid.iter().enumerate() {
        image::imageops::overlay(
            &mut sheet,
            img,
            ((i % 4) as u32 * tw) as i64,
            (HEADER + (i / 4) as u32 * th) as i64,
        );
    }
    softcap_figure::register_fonts();
    {
        let root = BitMapBackend::with_buffer(&mut sheet, (w, h)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| e.to_string();
        let title = (softcap_figure::FONT_FAMILY, 16)
            .into_font()
            .color(&BLACK)
            .pos(plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Center,
                plotters::style::text_anchor::VPos::Top,
            ));
        for (c, name) in COLUMNS.iter().enumerate() {
            let x = (c as u32 * tw + tw / 2) as i32;
            root.draw(&Text::new(*name, (x, 6), title.clone()))
                .map_err(|e| err(&e))?;
        }
        let label = (softcap_figure::FONT_FAMILY, 14).into_font().color(&BLACK);
        for (r, name) in identities.iter().enumerate() {
            let y = (HEADER + r as u32 * th + 4) as i32;
            root.draw(&Text::new(*name, (6, y), label.clone()))
                .map_err(|e| err(&e))?;
        }
        let bar = root
            .clone()
            .shrink((3 * tw, HEADER + th * rows), (tw, FOOTER));
        let scale = softcap_figure::ColorScale::symmetric(
            "signed detail along the normal [mm]",
            10.0 * SIGNED_DETAIL_LIMIT_CM as f64,
            softcap_figure::diverging,
        );
        softcap_figure::draw_colorbar(&bar, &scale).map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    Ok(sheet)
}
