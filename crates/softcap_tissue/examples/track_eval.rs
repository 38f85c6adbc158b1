//! Surface-point error of tracked node trajectories against the truth of a synthetic dynamic
//! session (`truth/track_points.csv`), for `softcap tissue track`'s output and for any other
//! tracker's (the CPD reference of `scripts/cpd_reference.py`):
//!
//! ```text
//! softcap inspect export track.mcap --what nodes -o nodes.csv
//! cargo run -p softcap_tissue --example track_eval -- SESSION nodes.csv [other.csv ...]
//! ```
//!
//! Node CSVs are `frame,node,x,y,z` in metres, nodes in the order of SESSION/template/volume.msh.
//! Also prints the template's own floor: the truth carried by the template's nodes
//! (`truth/template_nodes.csv`). With `--per-frame` first, prints instead a CSV
//! `frame,floor,<each nodes file>` of the per-frame RMS in mm (the reference figure's curves).

use std::path::PathBuf;

use softcap_tissue::track::eval::{read_node_trajectories, read_track_points, surface_point_error};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    let per_frame = args.first().is_some_and(|a| a.as_os_str() == "--per-frame");
    if per_frame {
        args.remove(0);
    }
    let Some((session, tracks)) = args.split_first() else {
        return Err("usage: track_eval [--per-frame] SESSION nodes.csv [more.csv ...]".into());
    };
    let mesh = softcap_tissue::read_volume_mesh(&session.join("template/volume.msh"), 1e-3)?;
    let truth = read_track_points(&session.join("truth/track_points.csv"), 1e-3)?;
    let floor = read_node_trajectories(&session.join("truth/template_nodes.csv"), 1e-3)?;
    let mut rows = vec![("template floor".to_string(), floor)];
    for t in tracks {
        rows.push((t.display().to_string(), read_node_trajectories(t, 1.0)?));
    }
    let errors: Vec<(String, _)> = rows
        .into_iter()
        .map(|(name, nodes)| (name, surface_point_error(&mesh, &nodes, &truth)))
        .collect();
    if per_frame {
        let names: Vec<&str> = errors.iter().map(|(n, _)| n.as_str()).collect();
        println!("frame,{}", names.join(","));
        let frames = errors
            .iter()
            .map(|(_, e)| e.per_frame_rms_m.len())
            .min()
            .unwrap_or(0);
        for k in 0..frames {
            let row: Vec<String> = errors
                .iter()
                .map(|(_, e)| format!("{:.4}", 1e3 * e.per_frame_rms_m[k]))
                .collect();
            println!("{k},{}", row.join(","));
        }
        return Ok(());
    }
    println!("| nodes | frames | RMS mm | seen mm | unseen mm | max mm |");
    println!("|---|---|---|---|---|---|");
    for (name, e) in errors {
        println!(
            "| {name} | {} | {:.3} | {:.3} | {:.3} | {:.3} |",
            e.per_frame_rms_m.len(),
            1e3 * e.rms_m,
            1e3 * e.rms_seen_m,
            1e3 * e.rms_unseen_m,
            1e3 * e.max_m
        );
    }
    Ok(())
}
