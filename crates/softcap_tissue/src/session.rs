//! From a capture and a tet mesh to probing examples (bickel2009 §4.1): the mesh in SI, markers
//! embedded barycentrically, the attached region from the session's support plane, and one
//! [`ProbeExample`] per selected contact frame.

use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use softcap_mcap::capture::{CaptureData, Phase, ProbeLocation, ProbeLocationSettings};
use softcap_mesh::TetMesh;
use softcap_probing::{ObservedMarker, ProbeExample, ProbingSetup, support_nodes};

use crate::error::{Result, TissueError};

/// How frames become examples.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExampleSelection {
    /// Grouping of contact frames into probe locations.
    pub locations: ProbeLocationSettings,
    /// Examples taken per probe location: the loading/hold frames whose force is closest to
    /// k/n of the location's peak force, k = 1..n (n = this). The budget knob of the fit.
    pub examples_per_location: usize,
    /// Use markers that capture filled in (predicted, not measured). Off: only triangulated
    /// markers are compared with the model.
    pub use_filled_markers: bool,
    /// A marker whose rest position lies farther than this from the mesh is an error, m.
    pub max_marker_offset_m: f64,
}

impl Default for ExampleSelection {
    fn default() -> Self {
        Self {
            locations: ProbeLocationSettings::default(),
            examples_per_location: 2,
            use_filled_markers: false,
            max_marker_offset_m: 0.002,
        }
    }
}

/// One selected example with where it came from.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionExample {
    /// The probing example (markers as rest + observed displacement, see [`examples_from_frames`]).
    pub example: ProbeExample,
    /// Probe location index ([`CaptureData::probe_locations`]).
    pub location: usize,
    /// Phase of the frame.
    pub phase: Phase,
    /// Index into [`CaptureData::frames`].
    pub frame_index: usize,
    /// Log time of the frame, ns.
    pub log_time_ns: u64,
}

/// A capture prepared for fitting.
#[derive(Clone, Debug)]
pub struct PreparedSession {
    /// Mesh, markers, regions.
    pub setup: ProbingSetup,
    /// Probe locations of the capture.
    pub locations: Vec<ProbeLocation>,
    /// Every usable contact frame as an example (for held-out evaluation).
    pub all_examples: Vec<SessionExample>,
    /// The examples selected for fitting (a subset of `all_examples`), by frame.
    pub selected: Vec<SessionExample>,
    /// Tip shape of the session's probe (`/capture/session` `tip_shape`: "sphere", "disk", …).
    pub tip_shape: String,
    /// Tip radius of the session's probe, m (0 if unknown).
    pub tip_radius_m: f64,
    /// The session's support plane (attached region).
    pub support: softcap_mcap::SupportPlane,
}

/// Reads a Gmsh 4.1 tet mesh and converts it to metres (`metres_per_unit` of the session).
pub fn read_volume_mesh(path: &Path, metres_per_unit: f64) -> Result<TetMesh> {
    read_volume_mesh_mapped(path, metres_per_unit).map(|(mesh, _)| mesh)
}

/// [`read_volume_mesh`] and, per node of the file (in `$Nodes` order), its index in the returned
/// mesh (`None` for nodes no tet uses, which are dropped).
pub fn read_volume_mesh_mapped(
    path: &Path,
    metres_per_unit: f64,
) -> Result<(TetMesh, Vec<Option<usize>>)> {
    if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
        return Err(TissueError::bad_input(
            path,
            "metres_per_unit",
            format!("{metres_per_unit} is not a positive length unit"),
        ));
    }
    let mut mesh = softcap_mesh::read_msh_tet_mesh(path).map_err(|e| TissueError::ReadMesh {
        path: path.to_path_buf(),
        source: Box::new(e),
    })?;
    if mesh.tets.is_empty() {
        return Err(TissueError::bad_input(
            path,
            "$Elements",
            "no tetrahedra (a volume mesh is needed)",
        ));
    }
    mesh.scale(metres_per_unit);
    let map = drop_unused_vertices(&mut mesh);
    mesh.orient_positive();
    mesh.validate(&softcap_mesh::ValidationSettings::default())
        .map_err(|e| TissueError::ReadMesh {
            path: path.to_path_buf(),
            source: Box::new(e),
        })?;
    Ok((mesh, map))
}

/// Removes vertices no tet uses (Gmsh files may carry geometry points; they would make the
/// stiffness matrix singular); returns old index → new index.
fn drop_unused_vertices(mesh: &mut TetMesh) -> Vec<Option<usize>> {
    let mut used = vec![false; mesh.vertices.len()];
    for t in &mesh.tets {
        for &v in t {
            if let Some(u) = used.get_mut(v) {
                *u = true;
            }
        }
    }
    if used.iter().all(|&u| u) {
        return (0..mesh.vertices.len()).map(Some).collect();
    }
    let mut map = vec![usize::MAX; mesh.vertices.len()];
    let mut vertices = Vec::with_capacity(mesh.vertices.len());
    for (i, v) in mesh.vertices.iter().enumerate() {
        if used[i] {
            map[i] = vertices.len();
            vertices.push(*v);
        }
    }
    for t in &mut mesh.tets {
        for v in t.iter_mut() {
            if *v < map.len() {
                *v = map[*v];
            }
        }
    }
    mesh.vertices = vertices;
    map.into_iter()
        .map(|m| (m != usize::MAX).then_some(m))
        .collect()
}

/// Length unit of a capture's session (m per unit), 1 when the capture predates the field.
pub fn metres_per_unit(capture: &CaptureData) -> Result<f64> {
    let r = softcap_mcap::Recording::open(&capture.path).map_err(|e| TissueError::ReadMcap {
        path: capture.path.clone(),
        source: Box::new(e),
    })?;
    let s = r
        .read_static(&softcap_mcap::topics::SESSION)
        .map_err(|e| TissueError::ReadMcap {
            path: capture.path.clone(),
            source: Box::new(e),
        })?;
    Ok(if s.metres_per_unit > 0.0 {
        s.metres_per_unit
    } else {
        1.0
    })
}

/// Embeds the capture's object markers in `mesh`, classifies the attached region from the
/// session's support plane and builds the examples. `mesh_path` names the mesh in errors.
pub fn prepare(
    capture: &CaptureData,
    mesh: TetMesh,
    mesh_path: &Path,
    selection: &ExampleSelection,
) -> Result<PreparedSession> {
    let cpath = &capture.path;
    let session = &capture.session;
    if session.object_markers == 0 {
        return Err(TissueError::bad_input(
            cpath,
            "/capture/session object_markers",
            "the session has no object markers",
        ));
    }
    let support = session.support.ok_or_else(|| {
        TissueError::bad_input(
            cpath,
            "/capture/session support",
            "no support plane: the attached region (bickel2009 §4.1) cannot be classified",
        )
    })?;
    let normal = Vector3::from(support.normal);
    let attached = support_nodes(
        &mesh,
        &normal,
        support.offset_m,
        support.tolerance_m.max(1e-9),
    );
    if attached.is_empty() {
        return Err(TissueError::bad_input(
            mesh_path,
            "support",
            format!(
                "no mesh node lies on the session's support plane n·x = {} m (n = {:?}, tolerance {} m): wrong mesh or units?",
                support.offset_m, support.normal, support.tolerance_m
            ),
        ));
    }
    let rest: Vec<Vector3<f64>> = session
        .rest_positions_m
        .iter()
        .map(|p| Vector3::from(*p))
        .collect();
    let locator = softcap_mesh::TetLocator::new(&mesh);
    for (i, p) in rest.iter().enumerate() {
        let d = locator
            .locate(p)
            .map(|e| e.distance)
            .unwrap_or(f64::INFINITY);
        if d > selection.max_marker_offset_m {
            return Err(TissueError::bad_input(
                mesh_path,
                format!("marker {} ({})", i, session.marker_ids[i]),
                format!(
                    "rest position {:?} m lies {:.4} mm outside the mesh (limit {} mm): the mesh does not contain the markers",
                    p,
                    1e3 * d,
                    1e3 * selection.max_marker_offset_m
                ),
            ));
        }
    }
    let setup = ProbingSetup::new(mesh, &rest, attached)?;
    let locations = capture.probe_locations(&selection.locations);
    let phases = capture.phases(&locations);
    let all_examples = examples_from_frames(capture, &setup, &locations, &phases, selection);
    if all_examples.is_empty() {
        return Err(TissueError::bad_input(
            cpath,
            "/capture/probe",
            "no contact frame with probe tip, axis, force and observed markers: nothing to fit",
        ));
    }
    let selected = select_examples(&all_examples, &locations, selection);
    Ok(PreparedSession {
        setup,
        locations,
        all_examples,
        selected,
        tip_shape: session.tip_shape.clone(),
        tip_radius_m: session.tip_radius_m,
        support,
    })
}

/// Every loading/hold contact frame with a complete probe sample as a [`ProbeExample`]. The
/// observed position of marker i is its embedded rest position plus its displacement from the
/// capture's rest frame, x̄ᵢ = Xᵢ + (xᵢ(t) − xᵢ(0)), so a constant offset between the template
/// and the triangulated rest markers does not enter the fit (bickel2009 fits displacements of
/// the rest shape).
pub fn examples_from_frames(
    capture: &CaptureData,
    setup: &ProbingSetup,
    locations: &[ProbeLocation],
    phases: &[Phase],
    selection: &ExampleSelection,
) -> Vec<SessionExample> {
    let nobj = capture.session.object_markers;
    let rest_embedded = setup.marker_positions(&setup.mesh.vertices);
    let rest_frame = capture.rest_frame().map(|i| &capture.frames[i]);
    let usable = |m: &softcap_mcap::MarkerObservation| {
        (m.id as usize) < nobj && (m.visible || (selection.use_filled_markers && m.filled))
    };
    let mut out = Vec::new();
    for loc in locations {
        for &fi in &loc.frames {
            let phase = phases[fi];
            if !matches!(phase, Phase::Loading | Phase::Hold) {
                continue;
            }
            let f = &capture.frames[fi];
            let Some(probe) = f.probe else { continue };
            let (Some(tip), Some(axis), Some(force)) = (probe.tip_m, probe.axis, probe.force_n)
            else {
                continue;
            };
            let axis = Vector3::from(axis);
            if axis.norm() < 1e-12 {
                continue;
            }
            let observed: Vec<ObservedMarker> = f
                .markers
                .iter()
                .filter(|m| usable(m))
                .filter_map(|m| {
                    let i = m.id as usize;
                    let x = Vector3::from(m.position_m);
                    let x0 = rest_frame
                        .and_then(|r| r.marker(m.id))
                        .filter(|r| usable(r))
                        .map(|r| Vector3::from(r.position_m))?;
                    Some(ObservedMarker {
                        marker: i,
                        position_m: rest_embedded[i] + (x - x0),
                    })
                })
                .collect();
            if observed.is_empty() {
                continue;
            }
            out.push(SessionExample {
                example: ProbeExample {
                    frame: f.frame,
                    time_s: f.t_camera_s,
                    tip_m: Vector3::from(tip),
                    axis: axis.normalize(),
                    force_n: Vector3::from(force),
                    observed,
                },
                location: loc.index,
                phase,
                frame_index: fi,
                log_time_ns: f.log_time_ns,
            });
        }
    }
    out.sort_by_key(|e| e.frame_index);
    out
}

/// Per location, the examples whose force magnitude is closest to k/n of the location's peak,
/// k = 1..n (ties → earlier frame), without repeats; sorted by frame.
pub fn select_examples(
    all: &[SessionExample],
    locations: &[ProbeLocation],
    selection: &ExampleSelection,
) -> Vec<SessionExample> {
    let n = selection.examples_per_location.max(1);
    let mut chosen: Vec<usize> = Vec::new();
    for loc in locations {
        let cands: Vec<usize> = (0..all.len())
            .filter(|&i| all[i].location == loc.index)
            .collect();
        if cands.is_empty() {
            continue;
        }
        let force = |i: usize| all[i].example.force_n.norm();
        let peak = cands.iter().map(|&i| force(i)).fold(0.0, f64::max);
        let mut picked: Vec<usize> = Vec::new();
        for k in 1..=n {
            let target = peak * k as f64 / n as f64;
            let best = cands
                .iter()
                .copied()
                .filter(|i| !picked.contains(i))
                .min_by(|&a, &b| {
                    (force(a) - target)
                        .abs()
                        .total_cmp(&(force(b) - target).abs())
                        .then(a.cmp(&b))
                });
            if let Some(b) = best {
                picked.push(b);
            }
        }
        chosen.extend(picked);
    }
    chosen.sort_unstable();
    chosen.dedup();
    chosen.into_iter().map(|i| all[i].clone()).collect()
}
