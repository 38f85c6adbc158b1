//! The commands: `softcap tissue fit-dynamic track.mcap --mesh M -o dynamic.mcap [--report DIR]
//! [--json P.json]` and `softcap tissue simulate-dynamic dynamic.mcap --initial track.mcap
//! --frames a..b -o sim.mcap`. Files in, files out; the numerics are in [`super::fit`] and
//! [`super::forward`].

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use softcap_mcap::dynamic::{TrackRecording, read_dynamic_material, read_track};
use softcap_mcap::{Provenance, Recording, Writer, proto, topics, viz, viz_topic};
use softcap_mesh::TetMesh;

use super::fit::{DynamicFit, FitDynamicSettings, fit_sequence};
use super::forward::{DynamicParams, Forward, ForwardSettings};
use super::sequence::{Segment, TrackedSequence};
use crate::Progress;
use crate::error::{Result, TissueError};
use crate::output::tet_mesh_message;

/// What `softcap tissue fit-dynamic` is asked to do.
#[derive(Clone, Debug)]
pub struct FitDynamicConfig {
    /// track.mcap (`softcap tissue track`).
    pub track: PathBuf,
    /// Further track.mcaps: other recorded motions of the same body (same template, support,
    /// gravity and density), fitted jointly with the first (wang2015 §7: each object filmed in a
    /// few motions), joined [`MOTION_GAP_S`] apart by [`TrackedSequence::joined`].
    pub more_tracks: Vec<PathBuf>,
    /// The template tet mesh (session length unit), the static shape of frame 0.
    pub mesh: PathBuf,
    /// dynamic.mcap to write.
    pub output: PathBuf,
    /// Also write report.md and PNG figures here.
    pub report: Option<PathBuf>,
    /// Also write the parameters as JSON here.
    pub json: Option<PathBuf>,
    /// Also write the material for the next tracking pass here ([`tracking_material_message`]).
    pub next_material: Option<PathBuf>,
    /// The `--json` of this loop's earlier passes, oldest first, the last one's next material
    /// being what these tracks were tracked with: the next material is then Anderson-accelerated
    /// over them ([`super::next_pass::anderson_next`], the last [`super::next_pass::ANDERSON_DEPTH`]
    /// used). Empty: the plain loop.
    pub previous_passes: Vec<PathBuf>,
    /// Settings.
    pub settings: FitDynamicSettings,
    /// Command line (provenance).
    pub arguments: Vec<String>,
}

fn read_err(path: &Path) -> impl Fn(softcap_mcap::Error) -> TissueError + '_ {
    move |e| TissueError::ReadMcap {
        path: path.to_path_buf(),
        source: Box::new(e),
    }
}

/// A track.mcap as a [`TrackedSequence`] on `mesh` (bad input when they disagree): support,
/// gravity and interactions from its `/capture/session` and `/capture/dynamic`; without those
/// (a track written by another tool) the support is the nodes that never move and gravity is
/// standard, with no interactions.
pub fn sequence_from_track(
    path: &Path,
    track: &TrackRecording,
    mesh: &TetMesh,
    mesh_path: &Path,
) -> Result<TrackedSequence> {
    let n = mesh.vertices.len();
    if track.mesh.vertices_m.len() != n || track.mesh.tets.len() != mesh.tets.len() {
        return Err(TissueError::bad_input(
            mesh_path,
            "mesh",
            format!(
                "has {n} nodes and {} tets but {} was tracked with {} nodes and {} tets",
                mesh.tets.len(),
                path.display(),
                track.mesh.vertices_m.len(),
                track.mesh.tets.len()
            ),
        ));
    }
    if track.mesh.tets != mesh.tets {
        return Err(TissueError::bad_input(
            mesh_path,
            "tets",
            format!("do not match the tets of {}'s /mesh/volume", path.display()),
        ));
    }
    let recording = Recording::open(path).map_err(read_err(path))?;
    let dynamic = match recording.channel(topics::DYNAMIC_SESSION.name()) {
        Some(_) => Some(
            recording
                .read_static(&topics::DYNAMIC_SESSION)
                .map_err(read_err(path))?,
        ),
        None => None,
    };
    let gravity = match recording.channel(topics::SESSION.name()) {
        Some(_) => {
            let s = recording
                .read_static(&topics::SESSION)
                .map_err(read_err(path))?;
            s.gravity_m_s2
                .map(|g| Vector3::new(g.x, g.y, g.z))
                .unwrap_or(softcap_fem::STANDARD_GRAVITY_M_S2)
        }
        None => softcap_fem::STANDARD_GRAVITY_M_S2,
    };
    let positions: Vec<Vec<Vector3<f64>>> = track
        .frames
        .iter()
        .map(|f| f.positions_m.iter().map(|p| Vector3::from(*p)).collect())
        .collect();
    let support_nodes: Vec<usize> = match &dynamic {
        Some(d) => {
            if let Some(&i) = d.support_nodes.iter().find(|&&i| i as usize >= n) {
                return Err(TissueError::bad_input(
                    path,
                    "/capture/dynamic support_nodes",
                    format!("node {i} is past the {n} nodes of {}", mesh_path.display()),
                ));
            }
            d.support_nodes.iter().map(|&i| i as usize).collect()
        }
        None => (0..n)
            .filter(|&i| {
                positions
                    .iter()
                    .all(|f| (f[i] - positions[0][i]).norm() <= 1e-9)
            })
            .collect(),
    };
    Ok(TrackedSequence {
        times_s: track.frames.iter().map(|f| f.t_camera_s).collect(),
        usable: track.frames.iter().map(|f| f.is_tracked()).collect(),
        positions_m: positions,
        support_nodes,
        gravity_m_s2: gravity,
        density_kg_m3: track.material.density_kg_m3,
        interactions_s: dynamic
            .map(|d| {
                d.interactions
                    .iter()
                    .map(|i| [i.t_start_s, i.t_end_s])
                    .collect()
            })
            .unwrap_or_default(),
        velocities_m_s: None,
    })
}

/// Marks unusable the frames of `seq` (read from `track`) whose points the tracked surface
/// explains poorly: `/tissue/track/status` `outlier_fraction` above `max_outlier_fraction`
/// ([`FitDynamicSettings::max_outlier_fraction`]). Where the tracker loses a fast-moving body
/// most of the cloud becomes outliers while the status may still say `converged`; those nodes
/// are not the body's and, fitted as trajectories, bias α and β (the Table 1 protocol tracked
/// from depth, seed 31: α +57.7 %, β −42.6 %; without those 59 of 420 frames −1.2 %, +1.6 %).
/// Returns the frames newly marked.
pub fn drop_lost_frames(
    seq: &mut TrackedSequence,
    track: &TrackRecording,
    max_outlier_fraction: f64,
) -> usize {
    let mut lost = 0;
    for (usable, f) in seq.usable.iter_mut().zip(&track.frames) {
        if *usable && f.status.outlier_fraction > max_outlier_fraction {
            *usable = false;
            lost += 1;
        }
    }
    lost
}

fn metres_per_unit(path: &Path) -> Result<f64> {
    let r = Recording::open(path).map_err(read_err(path))?;
    if r.channel(topics::SESSION.name()).is_none() {
        return Ok(1.0);
    }
    let s = r.read_static(&topics::SESSION).map_err(read_err(path))?;
    Ok(if s.metres_per_unit > 0.0 {
        s.metres_per_unit
    } else {
        1.0
    })
}

/// Time between two recorded motions joined into one sequence, s: marked as an interaction, so
/// no segment spans it; its length only places the second motion's frames on the time axis.
pub const MOTION_GAP_S: f64 = 0.1;

/// Runs the fit and writes dynamic.mcap (and the report / JSON when asked).
pub fn run(cfg: &FitDynamicConfig, progress: &Progress) -> Result<DynamicFit> {
    cfg.settings.validate()?;
    let track = read_track(&cfg.track).map_err(read_err(&cfg.track))?;
    let mesh = crate::session::read_volume_mesh(&cfg.mesh, metres_per_unit(&cfg.track)?)?;
    let max_outlier = cfg.settings.max_outlier_fraction;
    let mut seq = sequence_from_track(&cfg.track, &track, &mesh, &cfg.mesh)?;
    let mut lost = drop_lost_frames(&mut seq, &track, max_outlier);
    for path in &cfg.more_tracks {
        let more = read_track(path).map_err(read_err(path))?;
        let mut next = sequence_from_track(path, &more, &mesh, &cfg.mesh)?;
        lost += drop_lost_frames(&mut next, &more, max_outlier);
        seq = seq.joined(&next, MOTION_GAP_S).ok_or_else(|| {
            TissueError::bad_input(
                path,
                "track",
                format!(
                    "is not a motion of the body of {} (support nodes, gravity or density differ)",
                    cfg.track.display()
                ),
            )
        })?;
    }
    if lost > 0 {
        eprintln!(
            "{lost} tracked frames left out: outlier fraction above {max_outlier} (the tracker lost the body)"
        );
    }
    let previous = cfg
        .previous_passes
        .iter()
        .map(|p| read_pass_json(p, cfg.settings.control_points))
        .collect::<Result<Vec<_>>>()?;
    let fit = fit_sequence(&mesh, &seq, &cfg.settings, progress)?;
    write_dynamic(cfg, &mesh, &fit)?;
    let next = match &cfg.next_material {
        Some(p) => {
            let next = next_pass_parameters(&fit, &previous, &cfg.settings);
            write_next_material(cfg, p, &mesh, &fit, &next)?;
            Some(next)
        }
        None => None,
    };
    if let Some(p) = &cfg.json {
        let text = json(&fit, next.as_deref());
        softcap_app::write_atomic(p, text.as_bytes()).map_err(|e| TissueError::Output {
            path: p.clone(),
            reason: e.to_string(),
        })?;
    }
    if let Some(dir) = &cfg.report {
        super::report::write_report(dir, &mesh, &seq, &fit, &cfg.settings)?;
    }
    Ok(fit)
}

/// The `/tissue/dynamic_material` message of a fit (E per tet of the given mesh, rest shape).
pub fn material_message(fit: &DynamicFit) -> proto::DynamicMaterial {
    proto::DynamicMaterial {
        element: "corotational".into(),
        young_pa: fit.young_pa_tets.clone(),
        poisson: fit.poisson,
        density_kg_m3: fit.density_kg_m3,
        rayleigh_alpha_per_s: fit.damping.alpha_per_s,
        rayleigh_beta_s: fit.damping.beta_s,
        rest_positions_m: fit.rest_m.iter().flat_map(|v| [v.x, v.y, v.z]).collect(),
    }
}

/// An earlier pass's `--json`: its fit's E per control point, α, β and, when it wrote one, the
/// next material's (what the pass after it tracked with).
#[derive(Clone, Debug, serde::Deserialize)]
pub struct PassJson {
    /// The fit's parameters (the JSON's top-level `E_pa`, `alpha`, `beta`).
    #[serde(flatten)]
    pub fit: PassParameters,
    /// The `--next-material` written; absent when the pass wrote none (the plain loop's, read as
    /// the fit's with [`super::fit::young_for_tracking`]).
    pub next_material: Option<PassParameters>,
}

/// E per control point (Pa), α (1/s), β (s), as a `--json` writes them.
#[derive(Clone, Debug, serde::Deserialize)]
pub struct PassParameters {
    /// E per control point, Pa.
    #[serde(rename = "E_pa")]
    pub young_pa: Vec<f64>,
    /// Rayleigh α, 1/s.
    pub alpha: f64,
    /// Rayleigh β, s.
    pub beta: f64,
}

/// An earlier pass's `--json`, with `control_points` E each.
fn read_pass_json(path: &Path, control_points: usize) -> Result<PassJson> {
    let bad = |field: &str, e: String| TissueError::bad_input(path, field, e);
    let text = std::fs::read_to_string(path).map_err(|e| bad("file", e.to_string()))?;
    let j: PassJson = serde_json::from_str(&text).map_err(|e| bad("JSON", e.to_string()))?;
    let next = j.next_material.as_ref().map(|n| n.young_pa.len());
    for (field, n) in [
        ("E_pa", Some(j.fit.young_pa.len())),
        ("next_material.E_pa", next),
    ] {
        if let Some(n) = n.filter(|&n| n != control_points) {
            return Err(bad(
                field,
                format!("has {n} control points, this fit {control_points}"),
            ));
        }
    }
    Ok(j)
}

/// (E per control point, α, β) a fit proposes for the next pass: a control point at an E bound
/// given its nearest free neighbour's E ([`super::fit::young_for_tracking`]).
fn proposed(young_pa: &[f64], alpha: f64, beta: f64, bounds_pa: [f64; 2]) -> Vec<f64> {
    let mut v = super::fit::young_for_tracking(young_pa, bounds_pa);
    v.extend([alpha, beta]);
    v
}

/// The next tracking pass's (E per control point, α, β): what the fit proposes, Anderson-
/// accelerated over the earlier passes when there are any ([`super::next_pass::anderson_next`];
/// a pass's x is the previous pass's next material, its g(x) what its own fit proposed).
pub fn next_pass_parameters(
    fit: &DynamicFit,
    previous: &[PassJson],
    settings: &FitDynamicSettings,
) -> Vec<f64> {
    use super::next_pass::{LoopPass, anderson_next};
    let b = settings.young_bounds_pa;
    let nc = fit.young_pa.len();
    let proposed_by = |j: &PassJson| proposed(&j.fit.young_pa, j.fit.alpha, j.fit.beta, b);
    let next_of = |j: &PassJson| match &j.next_material {
        Some(n) => [n.young_pa.as_slice(), &[n.alpha, n.beta]].concat(),
        None => proposed_by(j),
    };
    let current = proposed(
        &fit.young_pa,
        fit.damping.alpha_per_s,
        fit.damping.beta_s,
        b,
    );
    let mut passes: Vec<LoopPass> = previous
        .windows(2)
        .map(|w| LoopPass {
            tracked_with: next_of(&w[0]),
            proposed: proposed_by(&w[1]),
        })
        .collect();
    passes.push(LoopPass {
        tracked_with: previous.last().map_or_else(|| current.clone(), next_of),
        proposed: current,
    });
    let sigma: Vec<f64> = (0..nc + 2)
        .map(|i| {
            let own = fit.relative_sigma.get(i).copied().unwrap_or(f64::INFINITY);
            let sandwich = fit
                .segment_robust_sigma
                .get(i)
                .copied()
                .filter(|s| s.is_finite())
                .unwrap_or(0.0);
            own.max(sandwich)
        })
        .collect();
    let mut lower = vec![b[0]; nc];
    lower.extend([settings.alpha_bounds_per_s[0], settings.beta_bounds_s[0]]);
    let mut upper = vec![b[1]; nc];
    upper.extend([settings.alpha_bounds_per_s[1], settings.beta_bounds_s[1]]);
    anderson_next(&passes, &sigma, &lower, &upper)
}

/// The material for the next tracking pass (tracking ↔ estimation, wang2015 §7): E per control
/// point, α and β of `next` ([`next_pass_parameters`]) with the fit's Poisson ratio and density,
/// and no rest shape (the tracker solves it for these E from its frame 0).
pub fn tracking_material_message(fit: &DynamicFit, next: &[f64]) -> proto::DynamicMaterial {
    let nc = fit.young_pa.len();
    proto::DynamicMaterial {
        young_pa: fit.control_points.blend(&next[..nc]),
        rayleigh_alpha_per_s: next[nc],
        rayleigh_beta_s: next[nc + 1],
        rest_positions_m: Vec::new(),
        ..material_message(fit)
    }
}

fn write_next_material(
    cfg: &FitDynamicConfig,
    path: &Path,
    mesh: &TetMesh,
    fit: &DynamicFit,
    next: &[f64],
) -> Result<()> {
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let provenance = Provenance::new("tissue fit-dynamic", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter());
    let mut w = Writer::create(path, &provenance).map_err(err)?;
    w.write_static(&topics::VOLUME_MESH, &tet_mesh_message(mesh))
        .map_err(err)?;
    w.write_static(
        &topics::DYNAMIC_MATERIAL,
        &tracking_material_message(fit, next),
    )
    .map_err(err)?;
    w.finish().map_err(err)?;
    Ok(())
}

/// A JSON number, or `null` for a non-finite value (an uncertainty the data do not bound, the
/// trajectory RMS of a simulation that did not finish).
fn json_number(x: f64) -> String {
    if x.is_finite() {
        format!("{x:e}")
    } else {
        "null".into()
    }
}

/// `{"E": [per control point], "alpha": …, "beta": …}` of a relative 1-σ vector (E_c…, α, β).
fn json_sigma(sigma: &[f64], nc: usize) -> String {
    let at = |k: usize| sigma.get(k).map_or("null".into(), |&x| json_number(x));
    let e = (0..nc).map(at).collect::<Vec<_>>().join(", ");
    format!(
        "{{\"E\": [{e}], \"alpha\": {}, \"beta\": {}}}",
        at(nc),
        at(nc + 1)
    )
}

/// The `--json` document (keys as in the issue; `E_pa` per control point). The relative 1-σ of
/// E_c, α, β: `relative_sigma` from s²(JᵀJ)⁻¹, which takes the residuals as independent, and the
/// sandwich (cluster-robust) ones `sigma_segment_robust` (one cluster per segment: spatially
/// correlated tracking noise and a start state's error carried through its segment) and
/// `sigma_frame_robust` (one cluster per frame); `null` where the data do not bound one (e.g. the
/// segment sandwich of a single segment). See [`DynamicFit::segment_robust_sigma`].
/// `neighbour_correlation` and `observable` per control point: [`DynamicFit::observable`].
/// `next_material` (with `--next-material`): the E per control point, α and β written there
/// ([`next_pass_parameters`]), read back by the next pass's `--previous-passes`.
pub fn json(fit: &DynamicFit, next: Option<&[f64]>) -> String {
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:e}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let nc = fit.young_pa.len();
    let cps = fit
        .control_points
        .positions_m
        .iter()
        .map(|p| format!("[{:e}, {:e}, {:e}]", p.x, p.y, p.z))
        .collect::<Vec<_>>()
        .join(", ");
    format!(
        "{{\n  \"E_pa\": [{}],\n  \"control_points_m\": [{cps}],\n  \"E_pa_tets\": [{}],\n  \"nu\": {:e},\n  \"alpha\": {:e},\n  \"beta\": {:e},\n  \"density_kg_m3\": {:e},\n  \"trajectory_rmse_m\": {},\n  \"relative_sigma\": {},\n  \"sigma_segment_robust\": {},\n  \"sigma_frame_robust\": {},\n  \"neighbour_correlation\": [{}],\n  \"observable\": [{}],\n  \"status\": \"{}\"{}\n}}\n",
        list(&fit.young_pa),
        list(&fit.young_pa_tets),
        fit.poisson,
        fit.damping.alpha_per_s,
        fit.damping.beta_s,
        fit.density_kg_m3,
        json_number(fit.rms_m),
        json_sigma(&fit.relative_sigma, nc),
        json_sigma(&fit.segment_robust_sigma, nc),
        json_sigma(&fit.frame_robust_sigma, nc),
        fit.neighbour_correlation
            .iter()
            .map(|&x| json_number(x))
            .collect::<Vec<_>>()
            .join(", "),
        fit.observable
            .iter()
            .map(bool::to_string)
            .collect::<Vec<_>>()
            .join(", "),
        fit.status.replace('"', "'"),
        next.map_or(String::new(), |v| {
            let (e, ab) = v.split_at(nc);
            format!(
                ",\n  \"next_material\": {{\"E_pa\": [{}], \"alpha\": {:e}, \"beta\": {:e}}}",
                list(e),
                ab[0],
                ab[1]
            )
        }),
    )
}

/// The summary report.
pub fn report_message(fit: &DynamicFit) -> proto::Report {
    use proto::key_value::Value;
    let kv = |key: String, value: Value, unit: &str| proto::KeyValue {
        key,
        value: Some(value),
        unit: unit.into(),
    };
    let nc = fit.young_pa.len();
    let mut entries = vec![kv("status".into(), Value::Text(fit.status.clone()), "")];
    for (c, e) in fit.young_pa.iter().enumerate() {
        entries.push(kv(format!("young_{c}"), Value::Number(*e), "Pa"));
        entries.push(kv(
            format!("young_{c}_relative_sigma"),
            Value::Number(fit.relative_sigma[c]),
            "",
        ));
    }
    entries.extend([
        kv("poisson".into(), Value::Number(fit.poisson), ""),
        kv(
            "rayleigh_alpha".into(),
            Value::Number(fit.damping.alpha_per_s),
            "1/s",
        ),
        kv(
            "rayleigh_alpha_relative_sigma".into(),
            Value::Number(fit.relative_sigma[nc]),
            "",
        ),
        kv(
            "rayleigh_beta".into(),
            Value::Number(fit.damping.beta_s),
            "s",
        ),
        kv(
            "rayleigh_beta_relative_sigma".into(),
            Value::Number(fit.relative_sigma[nc + 1]),
            "",
        ),
        kv(
            "trajectory_rmse_initial".into(),
            Value::Number(fit.rms_initial_m),
            "m",
        ),
        kv(
            "trajectory_rmse_warm_start".into(),
            Value::Number(fit.rms_warm_m),
            "m",
        ),
        kv(
            "trajectory_rmse_warm_start_segments".into(),
            Value::Number(fit.rms_warm_segments as f64),
            "",
        ),
        kv("trajectory_rmse".into(), Value::Number(fit.rms_m), "m"),
        kv(
            "warm_start_young".into(),
            Value::Number(fit.warm_young_pa),
            "Pa",
        ),
    ]);
    if let Some(coarse) = &fit.coarse_young_pa {
        for (c, e) in coarse.iter().enumerate() {
            entries.push(kv(format!("coarse_young_{c}"), Value::Number(*e), "Pa"));
        }
    }
    entries.extend([
        kv(
            "simulations".into(),
            Value::Integer(fit.simulations as i64),
            "",
        ),
        kv(
            "segment_simulations".into(),
            Value::Integer(fit.segment_simulations as i64),
            "",
        ),
        kv(
            "start_state_modes".into(),
            Value::Integer(fit.start_state_modes as i64),
            "",
        ),
        kv("segments".into(), Value::Integer(fit.segments as i64), ""),
        kv(
            "frames_simulated".into(),
            Value::Integer(fit.frames as i64),
            "",
        ),
        kv(
            "fit_mesh_nodes".into(),
            Value::Integer(fit.fit_mesh_size.0 as i64),
            "",
        ),
        kv(
            "fit_mesh_tets".into(),
            Value::Integer(fit.fit_mesh_size.1 as i64),
            "",
        ),
        kv(
            "rest_shape".into(),
            Value::Text(fit.rest_status.clone()),
            "",
        ),
    ]);
    for m in &fit.measured_modes {
        entries.push(kv(
            format!("mode_{}_measured", m.mode),
            Value::Number(m.omega_rad_s / std::f64::consts::TAU),
            "Hz",
        ));
        if let Some(f) = fit.fitted_frequencies_hz.get(m.mode) {
            entries.push(kv(
                format!("mode_{}_fitted", m.mode),
                Value::Number(*f),
                "Hz",
            ));
        }
        entries.push(kv(
            format!("mode_{}_damping_ratio", m.mode),
            Value::Number(m.zeta),
            "",
        ));
    }
    proto::Report {
        title: "tissue fit-dynamic (wang2015 §6, Algorithm 1)".into(),
        entries,
    }
}

fn write_dynamic(cfg: &FitDynamicConfig, mesh: &TetMesh, fit: &DynamicFit) -> Result<()> {
    let path = &cfg.output;
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: path.clone(),
        reason: e.to_string(),
    };
    let settings = toml::to_string(&cfg.settings).map_err(|e| TissueError::BadSettings {
        field: "settings".into(),
        problem: e.to_string(),
    })?;
    let mut provenance = Provenance::new("tissue fit-dynamic", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter())
        .with_settings(settings);
    for p in std::iter::once(&cfg.track)
        .chain(&cfg.more_tracks)
        .chain([&cfg.mesh])
    {
        provenance.add_input(p).map_err(read_err(p))?;
    }
    let mut w = Writer::create(path, &provenance).map_err(err)?;
    w.write_static(&topics::VOLUME_MESH, &tet_mesh_message(mesh))
        .map_err(err)?;
    w.write_static(&topics::DYNAMIC_MATERIAL, &material_message(fit))
        .map_err(err)?;
    w.write_static(&topics::DYNAMIC_FIT_REPORT, &report_message(fit))
        .map_err(err)?;
    w.finish().map_err(err)?;
    Ok(())
}

/// What `softcap tissue simulate-dynamic` is asked to do.
#[derive(Clone, Debug)]
pub struct SimulateDynamicConfig {
    /// dynamic.mcap (`tissue fit-dynamic`).
    pub material: PathBuf,
    /// track.mcap giving the initial state (and support, gravity).
    pub initial: PathBuf,
    /// First and last frame (inclusive) of the track to simulate over.
    pub frames: (u64, u64),
    /// sim.mcap to write.
    pub output: PathBuf,
    /// Segment simulation settings.
    pub forward: ForwardSettings,
    /// Command line (provenance).
    pub arguments: Vec<String>,
}

/// What a simulate-dynamic run produced.
#[derive(Clone, Debug, PartialEq)]
pub struct SimulateDynamicOutcome {
    /// Frames simulated (after the initial one).
    pub frames: usize,
    /// RMS distance to the tracked nodes over those frames, m.
    pub rms_m: f64,
    /// Steps whose Newton iterations hit their limit.
    pub max_iteration_steps: usize,
}

/// The tracked body's tet mesh as track.mcap carries it (the template, in its node order).
pub fn tracked_mesh(track: &TrackRecording) -> TetMesh {
    TetMesh {
        vertices: track
            .mesh
            .vertices_m
            .iter()
            .map(|p| Vector3::from(*p))
            .collect(),
        tets: track.mesh.tets.clone(),
    }
}

/// Simulates the fitted material from the tracked state at frame a to frame b (the support
/// follows the track) and writes `/tissue/dynamic_sim/nodes`.
pub fn simulate(cfg: &SimulateDynamicConfig) -> Result<SimulateDynamicOutcome> {
    let track = read_track(&cfg.initial).map_err(read_err(&cfg.initial))?;
    let mesh = tracked_mesh(&track);
    let m = read_dynamic_material(&cfg.material, mesh.tets.len(), mesh.vertices.len())
        .map_err(read_err(&cfg.material))?;
    let seq = sequence_from_track(&cfg.initial, &track, &mesh, &cfg.material)?;
    let (a, b) = cfg.frames;
    let index = |f: u64| track.frames.iter().position(|t| t.frame == f);
    let (Some(start), Some(end)) = (index(a), index(b)) else {
        return Err(TissueError::BadSettings {
            field: "--frames".into(),
            problem: format!("{a}..{b} are not both frames of {}", cfg.initial.display()),
        });
    };
    if end <= start {
        return Err(TissueError::BadSettings {
            field: "--frames".into(),
            problem: format!("{a}..{b}: the last frame must come after the first"),
        });
    }
    let tets = mesh.tets.len();
    let params = DynamicParams {
        young_pa: if m.young_pa.len() == 1 {
            vec![m.young_pa[0]; tets]
        } else {
            m.young_pa.clone()
        },
        poisson: m.poisson,
        damping: softcap_fem::RayleighDamping {
            alpha_per_s: m.rayleigh_alpha_per_s,
            beta_s: m.rayleigh_beta_s,
        },
    };
    let rest: Vec<Vector3<f64>> = if m.rest_positions_m.is_empty() {
        mesh.vertices.clone()
    } else {
        m.rest_positions_m
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect()
    };
    let mut seq = seq;
    seq.density_kg_m3 = m.density_kg_m3;
    let n = mesh.vertices.len();
    let forward = Forward::new(
        &mesh,
        &seq,
        vec![Segment { start, end }],
        vec![true; n],
        &cfg.forward,
    )?;
    let runs = forward.simulate(&params, &rest)?;
    let run = &runs[0];
    if let Some(f) = &run.failure {
        return Err(TissueError::NotConverged {
            what: "dynamic simulation".into(),
            status: f.clone(),
        });
    }
    let rms_m = forward.rms_m(&runs);
    let path = &cfg.output;
    let err = |e: softcap_mcap::Error| TissueError::Output {
        path: path.clone(),
        reason: e.to_string(),
    };
    let mut provenance = Provenance::new("tissue simulate-dynamic", env!("CARGO_PKG_VERSION"))
        .with_arguments(cfg.arguments.iter());
    for p in [&cfg.material, &cfg.initial] {
        provenance.add_input(p).map_err(read_err(p))?;
    }
    let mut w = Writer::create(path, &provenance).map_err(err)?;
    let volume = tet_mesh_message(&mesh);
    w.write_static(&topics::VOLUME_MESH, &volume).map_err(err)?;
    let viz_nodes = viz_topic(topics::DYNAMIC_SIM_NODES.name());
    for (o, x) in run.positions_m.iter().enumerate() {
        let f = &track.frames[start + 1 + o];
        let t = (f.t_camera_s.max(0.0) * 1e9).round() as u64;
        let flat: Vec<f64> = x.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        w.write_foxglove(
            &viz_nodes,
            t,
            &viz::deformed_tetmesh_scene(&volume, &flat, t),
        )
        .map_err(err)?;
        w.write(
            &topics::DYNAMIC_SIM_NODES,
            t,
            &proto::NodeFrame {
                frame: f.frame,
                t_camera_s: f.t_camera_s,
                positions_m: flat,
            },
        )
        .map_err(err)?;
    }
    w.finish().map_err(err)?;
    Ok(SimulateDynamicOutcome {
        frames: run.positions_m.len(),
        rms_m,
        max_iteration_steps: run.max_iteration_steps,
    })
}

#[cfg(test)]
mod tests {

    /// A pass's `--json` read back by `--previous-passes`: the top-level E, α, β and the
    /// `next_material` when written; a count of control points other than the fit's is an error
    /// naming the field.
    #[test]
    fn previous_pass_json_reads_the_fit_and_its_next_material() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("fit.json");
        std::fs::write(
            &p,
            r#"{"E_pa": [1e5, 2e5], "alpha": 0.8, "beta": 1e-3, "status": "converged",
                "next_material": {"E_pa": [1.5e5, 2e5], "alpha": 0.7, "beta": 2e-3}}"#,
        )
        .unwrap();
        let j = read_pass_json(&p, 2).unwrap();
        assert_eq!(
            (j.fit.young_pa.clone(), j.fit.alpha, j.fit.beta),
            (vec![1e5, 2e5], 0.8, 1e-3)
        );
        let n = j.next_material.unwrap();
        assert_eq!((n.young_pa, n.alpha, n.beta), (vec![1.5e5, 2e5], 0.7, 2e-3));
        let e = read_pass_json(&p, 3).unwrap_err().to_string();
        assert!(e.contains("E_pa") && e.contains("2 control points"), "{e}");
    }
    use super::{json_number, read_pass_json};

    /// JSON has no NaN or infinity: a value that is not finite is written `null`, a finite one
    /// round-trips exactly.
    #[test]
    fn non_finite_numbers_are_null() {
        assert_eq!(json_number(f64::NAN), "null");
        assert_eq!(json_number(f64::INFINITY), "null");
        let x = 1.234_567_890_123e-4;
        assert_eq!(json_number(x).parse::<f64>().unwrap(), x);
    }
}
