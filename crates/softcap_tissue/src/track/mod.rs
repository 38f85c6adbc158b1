//! `softcap tissue track`: physics-based probabilistic tracking of a tet mesh through the point
//! clouds of a dynamic capture (wang2015 §5, after Schulman et al. 2013).
//!
//! | module | what | paper |
//! |---|---|---|
//! | [`samples`] | surface samples s_k embedded in the tet mesh (the GMM components) | §5, mesh embedding |
//! | [`em`] | E-step: p(z_kn) with isotropic σ², uniform outlier weight w; W_k, ĉ_k, σ²_ML | §5, eq. 4 |
//! | [`forces`] | M-step virtual forces f_k = η Σ_n p(z_kn) σ⁻² (c_n − s_k) as a Newton term | eq. 5 |
//! | [`tracker`] | per frame: visibility, EM with σ annealing, implicit step of eq. 3 under gravity and support | §5, eq. 3 |
//! | [`output`] | track.mcap: `/tissue/track/nodes`, `/tissue/track/status`, `/viz/…`, report | |
//! | [`eval`] | surface-point error against a synthetic session's truth (tests, benches, examples) | |
//!
//! The default material (no `--material`) is a soft corotational solid (wang2015 eq. 1). A
//! supported body starts in equilibrium at frame 0: its rest shape is solved from the frame-0
//! shape under gravity and support (eq. 7, `softcap_fem::solve_rest_shape`); where no rest shape
//! explains the observed sag with the given material (a too soft material: Newton does not
//! converge), the frame-0 shape is the rest shape and its weight is balanced by a constant
//! counter-force (for a linear model gravity then only shifts the equilibrium, which the data
//! fixes), and the report says so. A free body (no support) keeps gravity and its frame-0 shape.

pub mod anderson;
pub mod em;
pub mod eval;
pub mod forces;
pub mod output;
pub mod samples;
pub mod tracker;

use std::path::{Path, PathBuf};

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use softcap_fem::{
    CorotationalModel, Integrator, LinearParams, RayleighDamping, RestShapeSettings,
    gravity_forces, lumped_masses, solve_rest_shape,
};
use softcap_mcap::dynamic::{DynamicCaptureData, read_dynamic_material};
use softcap_mcap::proto;
use softcap_mesh::TetMesh;

use crate::Progress;
use crate::error::{Result, TissueError};
use tracker::{Attachment, FrameTrack, Tracker, ViewCamera};

/// Settings of the tracker (TOML-loadable; every field has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackSettings {
    /// Default material (no `--material`): Young's modulus, Pa.
    pub young_pa: f64,
    /// Default material: Poisson ratio.
    pub poisson: f64,
    /// Default Rayleigh α, 1/s.
    pub rayleigh_alpha_per_s: f64,
    /// Default Rayleigh β, s.
    pub rayleigh_beta_s: f64,
    /// Density, kg/m³ (default: the session's).
    pub density_kg_m3: Option<f64>,
    /// How a supported body's rest shape is chosen when the material gives none.
    pub rest_shape: RestShapeChoice,
    /// Time integrator of the M-step.
    pub integrator: Integrator,
    /// Newton iterations per M-step (one: a generalized EM, see [`tracker`]).
    pub newton_iterations: usize,
    /// Steps of the material's prediction per frame interval h: the material alone over h in
    /// `substeps` steps of h / `substeps` predicts the frame (x_p, v_p, a_p), and the M-step is
    /// one Newmark step over h around that prediction (from the start state whose Newmark
    /// relations give v_p, a_p at x_p; see `tracker`): the data pull as with one step. 1: the
    /// M-step's own prediction (one step over h). More: modes with ω h > 1 (a stiff body filmed
    /// slowly) are predicted as the material moves them. Needs the Newmark integrator. Default 1:
    /// 4 tracks `bar8ab`'s 30 Hz bends with a good material at 0.28 mm (was 0.78–0.84) but the
    /// 30 Hz bar push and release (`scripts/track-table`, 60 frames) worse: FElupe's truth
    /// 0.27 → 2.39 mm with the default material, 0.34 → 1.18 mm with the true one; softcap's
    /// 0.47 → 2.91 mm with the true one (single frames off by up to 12 mm).
    pub substeps: usize,
    /// Outlier weight w of the GMM.
    pub outlier_weight: f64,
    /// σ at the first EM iteration of a frame, m.
    pub sigma_start_m: f64,
    /// Floor of σ, m (sensor noise and sample spacing).
    pub sigma_min_m: f64,
    /// Annealing factor a: σ ← max(σ_min, min(σ_ML, a σ)).
    pub sigma_anneal: f64,
    /// Components beyond this many σ from a point are left out.
    pub cutoff_sigmas: f64,
    /// A point cannot belong to a sample whose normal is more than 60° from its own.
    pub normal_gate: bool,
    /// Spacing of the surface samples, m.
    pub sample_spacing_m: f64,
    /// EM iterations per frame: at least / at most.
    pub min_em_iterations: usize,
    /// See `min_em_iterations`.
    pub max_em_iterations: usize,
    /// Converged when no node moves more than this in an M-step at σ_min, m.
    pub em_tolerance_m: f64,
    /// At σ_min, Anderson acceleration of the EM iterates over this many past iterations (0:
    /// plain EM iterations).
    pub anderson_memory: usize,
    /// Virtual-force scale: η = data_weight · M / (N h²) · σ_min², M the body's mass, N the
    /// frame's points (see [`tracker`]).
    pub data_weight: f64,
    /// Only samples some depth camera can see attract points.
    pub visibility: bool,
    /// A sample is hidden when the surface crosses its camera ray more than this before it, m.
    pub visibility_tolerance_m: f64,
    /// Samples whose normal is further than this from the direction to the camera are unseen.
    pub grazing_deg: f64,
    /// An M-step moving a node further than this is a divergence, m.
    pub divergence_step_m: f64,
    /// Frame interval used for η (0: the median interval of the capture), s.
    pub nominal_frame_interval_s: f64,
    /// At σ_min, the EM iterations after the first solve their M-step with the factorization of
    /// the first (a chord step; with the Anderson acceleration the same fixed point, reached in
    /// as many iterations).
    pub reuse_factorization: bool,
    /// Progress bar on stderr (when it is a terminal).
    pub progress: bool,
}

impl Default for TrackSettings {
    fn default() -> Self {
        Self {
            young_pa: 1.0e5,
            poisson: 0.4,
            rayleigh_alpha_per_s: 1.0,
            rayleigh_beta_s: 2.0e-3,
            density_kg_m3: None,
            rest_shape: RestShapeChoice::Solve,
            integrator: Integrator::NewmarkAverageAcceleration,
            newton_iterations: 1,
            substeps: 1,
            outlier_weight: 0.1,
            sigma_start_m: 0.01,
            sigma_min_m: 0.0015,
            sigma_anneal: 0.5,
            cutoff_sigmas: 3.5,
            normal_gate: true,
            sample_spacing_m: 0.003,
            min_em_iterations: 3,
            max_em_iterations: 8,
            em_tolerance_m: 5.0e-5,
            anderson_memory: 2,
            data_weight: 64.0,
            visibility: true,
            visibility_tolerance_m: 0.002,
            grazing_deg: 85.0,
            divergence_step_m: 0.2,
            nominal_frame_interval_s: 0.0,
            reuse_factorization: true,
            progress: true,
        }
    }
}

impl TrackSettings {
    /// Checks ranges; the error names the setting.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, problem: String| {
            Err(TissueError::BadSettings {
                field: field.into(),
                problem,
            })
        };
        let positive = [
            ("young_pa", self.young_pa),
            ("sigma_start_m", self.sigma_start_m),
            ("sigma_min_m", self.sigma_min_m),
            ("cutoff_sigmas", self.cutoff_sigmas),
            ("data_weight", self.data_weight),
            ("divergence_step_m", self.divergence_step_m),
            ("em_tolerance_m", self.em_tolerance_m),
        ];
        for (f, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return bad(f, format!("must be positive and finite, got {v}"));
            }
        }
        if !(self.poisson > -1.0 && self.poisson < 0.5) {
            return bad(
                "poisson",
                format!("must be in (−1, 0.5), got {}", self.poisson),
            );
        }
        if !(0.0..1.0).contains(&self.outlier_weight) {
            return bad("outlier_weight", "must be in [0, 1)".into());
        }
        if !(self.sigma_anneal > 0.0 && self.sigma_anneal <= 1.0) {
            return bad("sigma_anneal", "must be in (0, 1]".into());
        }
        for (f, v) in [
            ("rayleigh_alpha_per_s", self.rayleigh_alpha_per_s),
            ("rayleigh_beta_s", self.rayleigh_beta_s),
            ("sample_spacing_m", self.sample_spacing_m),
            ("visibility_tolerance_m", self.visibility_tolerance_m),
            ("nominal_frame_interval_s", self.nominal_frame_interval_s),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(f, format!("must be ≥ 0 and finite, got {v}"));
            }
        }
        if let Some(d) = self.density_kg_m3
            && !(d > 0.0 && d.is_finite())
        {
            return bad("density_kg_m3", format!("must be positive, got {d}"));
        }
        if self.substeps == 0 {
            return bad("substeps", "must be ≥ 1".into());
        }
        if self.substeps > 1 && self.integrator != Integrator::NewmarkAverageAcceleration {
            return bad(
                "substeps",
                "more than one needs the integrator NewmarkAverageAcceleration".into(),
            );
        }
        if self.max_em_iterations == 0 || self.newton_iterations == 0 {
            return bad(
                "max_em_iterations",
                "EM and Newton iterations must be ≥ 1".into(),
            );
        }
        Ok(())
    }
}

/// The rest shape of a supported body (a free body always keeps its frame-0 shape and gravity).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestShapeChoice {
    /// Solve it from the frame-0 shape under gravity (wang2015 eq. 7); if that fails, `balanced`.
    Solve,
    /// The frame-0 shape, its weight balanced by a constant counter-force (frame 0 is an
    /// equilibrium, gravity does not act on the motion).
    Balanced,
    /// The frame-0 shape under full gravity (wang2015's first tracking iteration: the body sags
    /// from frame 0 on unless the data hold it).
    Frame0,
}

/// What `softcap tissue track` is asked to do.
#[derive(Clone, Debug)]
pub struct TrackConfig {
    /// capture.mcap of a dynamic session.
    pub capture: PathBuf,
    /// The template tet mesh (session length unit), e.g. `S/template/volume.msh`.
    pub mesh: PathBuf,
    /// A dynamic material (`/tissue/dynamic_material`), else the settings' default.
    pub material: Option<PathBuf>,
    /// Extra attachment nodes: CSV with a `node` column (0-based).
    pub attach: Option<PathBuf>,
    /// track.mcap to write.
    pub output: PathBuf,
    /// Settings.
    pub settings: TrackSettings,
    /// Command line (provenance).
    pub arguments: Vec<String>,
}

/// What a run produced (also in the report of track.mcap).
#[derive(Clone, Debug, PartialEq)]
pub struct TrackOutcome {
    /// Per frame.
    pub frames: Vec<FrameTrack>,
    /// Template nodes.
    pub nodes: usize,
    /// Template tets.
    pub tets: usize,
    /// Surface samples.
    pub samples: usize,
    /// Where the material came from: `default` | the material file.
    pub material_source: String,
    /// How the rest shape was chosen.
    pub rest_shape: String,
    /// Wall time of the tracking loop, s (not written to the MCAP).
    pub wall_s: f64,
}

impl TrackOutcome {
    /// Frames with each status, in the order converged, max-iterations, diverged, no-points.
    pub fn status_counts(&self) -> [usize; 4] {
        let c = |s: &str| self.frames.iter().filter(|f| f.status == s).count();
        [
            c("converged"),
            c("max-iterations"),
            c("diverged"),
            c("no-points"),
        ]
    }

    /// Mean of the per-frame residuals (finite ones), m.
    pub fn mean_residual_m(&self) -> f64 {
        let r: Vec<f64> = self
            .frames
            .iter()
            .map(|f| f.residual_m)
            .filter(|v| v.is_finite())
            .collect();
        r.iter().sum::<f64>() / r.len().max(1) as f64
    }
}

/// The material the tracker simulates with.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackMaterial {
    /// Young's modulus per tet, Pa.
    pub young_pa: Vec<f64>,
    /// Poisson ratio.
    pub poisson: f64,
    /// Density, kg/m³.
    pub density_kg_m3: f64,
    /// Rayleigh damping.
    pub damping: RayleighDamping,
    /// Rest shape, m (None: solve / frame 0).
    pub rest_m: Option<Vec<Vector3<f64>>>,
    /// `default` or the file it came from.
    pub source: String,
}

/// Runs the tracker on `cfg` and writes track.mcap.
pub fn run(cfg: &TrackConfig) -> Result<TrackOutcome> {
    cfg.settings.validate()?;
    let capture = DynamicCaptureData::read(&cfg.capture).map_err(|e| TissueError::ReadMcap {
        path: cfg.capture.clone(),
        source: Box::new(e),
    })?;
    let mesh = crate::session::read_volume_mesh(&cfg.mesh, capture.metres_per_unit)?;
    check_mesh_matches_capture(&cfg.mesh, &mesh, &capture)?;
    let material = track_material(cfg, &capture, &mesh)?;
    let attachment = attachment(cfg, &capture, &mesh)?;
    let held = attachment.nodes.clone();
    let outcome = track(&capture, &mesh, &material, attachment, &cfg.settings)?;
    output::write_track(cfg, &mesh, &material, &outcome, &held)?;
    Ok(outcome)
}

/// Tracks every frame of `capture` with `mesh` (frame-0 shape) and `material` (in memory; no
/// files). `attachment` holds the supported nodes.
pub fn track(
    capture: &DynamicCaptureData,
    mesh: &TetMesh,
    material: &TrackMaterial,
    attachment: Attachment,
    settings: &TrackSettings,
) -> Result<TrackOutcome> {
    let mut settings = settings.clone();
    if settings.nominal_frame_interval_s <= 0.0 {
        settings.nominal_frame_interval_s = median_interval(capture);
    }
    let gravity = Vector3::from(capture.session.gravity_m_s2);
    let (model, loads, rest_shape) = rest_model(mesh, material, &attachment, gravity, &settings)?;
    let masses = lumped_masses(&model, material.density_kg_m3);
    let cameras = view_cameras(&capture.dynamic)?;
    let mut tracker = Tracker::new(
        mesh,
        model,
        masses,
        loads,
        attachment,
        cameras,
        material.damping,
        settings.nominal_frame_interval_s,
        &settings,
    )?;
    let progress = Progress::new(settings.progress);
    let bar = progress.bar("tracking", capture.frames.len() as u64);
    let started = std::time::Instant::now();
    let mut frames = Vec::with_capacity(capture.frames.len());
    for f in &capture.frames {
        let points: Vec<Vector3<f64>> = f.points_m.iter().map(|p| Vector3::from(*p)).collect();
        let normals: Vec<Vector3<f64>> = f.normals.iter().map(|p| Vector3::from(*p)).collect();
        let support = f.support_motion.map(|m| {
            let [w, x, y, z] = m.quaternion_wxyz;
            (
                UnitQuaternion::new_normalize(nalgebra::Quaternion::new(w, x, y, z)),
                Vector3::from(m.translation_m),
            )
        });
        frames.push(tracker.track(f.frame, f.t_camera_s, &points, &normals, support.as_ref()));
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(TrackOutcome {
        frames,
        nodes: mesh.vertices.len(),
        tets: mesh.tets.len(),
        samples: tracker.sample_count(),
        material_source: material.source.clone(),
        rest_shape,
        wall_s: started.elapsed().as_secs_f64(),
    })
}

fn median_interval(capture: &DynamicCaptureData) -> f64 {
    let mut d: Vec<f64> = capture
        .frames
        .windows(2)
        .map(|w| w[1].t_camera_s - w[0].t_camera_s)
        .filter(|v| *v > 0.0)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(1.0 / 30.0)
}

/// The corotational model over the rest shape (see [`RestShapeChoice`]), the constant external
/// forces (gravity, or gravity balanced) and a one-line account of the choice.
fn rest_model(
    mesh: &TetMesh,
    material: &TrackMaterial,
    attachment: &Attachment,
    gravity: Vector3<f64>,
    settings: &TrackSettings,
) -> Result<(CorotationalModel, Vec<Vector3<f64>>, String)> {
    let params: Vec<LinearParams> = material
        .young_pa
        .iter()
        .map(|&e| LinearParams::from_young_poisson(e, material.poisson))
        .collect::<std::result::Result<_, _>>()?;
    let frame0 = CorotationalModel::new(mesh, params.clone())?;
    let masses = lumped_masses(&frame0, material.density_kg_m3);
    let load = gravity_forces(&masses, gravity);
    if let Some(rest) = &material.rest_m {
        let m = CorotationalModel::new(
            &TetMesh {
                vertices: rest.clone(),
                tets: mesh.tets.clone(),
            },
            params,
        )?;
        return Ok((m, load, format!("given by {}", material.source)));
    }
    if attachment.nodes.is_empty() || gravity.norm() == 0.0 {
        return Ok((
            frame0,
            load,
            "the frame-0 shape (free or weightless body)".into(),
        ));
    }
    let n = load.len();
    let balanced = |why: String| (frame0.clone(), vec![Vector3::zeros(); n], why);
    match settings.rest_shape {
        RestShapeChoice::Frame0 => {
            return Ok((
                frame0.clone(),
                load,
                "the frame-0 shape under full gravity".into(),
            ));
        }
        RestShapeChoice::Balanced => {
            return Ok(balanced("the frame-0 shape, its weight balanced".into()));
        }
        RestShapeChoice::Solve => {}
    }
    let dofs: Vec<usize> = attachment
        .nodes
        .iter()
        .flat_map(|&n| [3 * n, 3 * n + 1, 3 * n + 2])
        .collect();
    let rest = solve_rest_shape(
        &frame0,
        &mesh.vertices,
        &load,
        &dofs,
        None,
        &RestShapeSettings::default(),
    )?;
    if rest.report.converged() {
        Ok((
            rest.model,
            load,
            format!(
                "solved from frame 0 under gravity (wang2015 eq. 7), {} Newton iterations",
                rest.report.iterations
            ),
        ))
    } else {
        Ok(balanced(format!(
            "the frame-0 shape, its weight balanced: no rest shape explains the frame-0 sag with this material (eq. 7 solve: {:?} after {} iterations, residual {:.2e} of {:.2e} N)",
            rest.report.status,
            rest.report.iterations,
            rest.report.residual_norm_n,
            rest.report.load_norm_n
        )))
    }
}

/// The material from `--material`, or the settings' default with the session's density.
fn track_material(
    cfg: &TrackConfig,
    capture: &DynamicCaptureData,
    mesh: &TetMesh,
) -> Result<TrackMaterial> {
    let s = &cfg.settings;
    if let Some(path) = &cfg.material {
        let m = read_dynamic_material(path, mesh.tets.len(), mesh.vertices.len()).map_err(|e| {
            TissueError::ReadMcap {
                path: path.clone(),
                source: Box::new(e),
            }
        })?;
        return Ok(material_from_proto(
            &m,
            mesh.tets.len(),
            &path.display().to_string(),
        ));
    }
    let density = s
        .density_kg_m3
        .or(capture.session.density_kg_m3)
        .ok_or_else(|| {
            TissueError::bad_input(
                &cfg.capture,
                "/capture/session density_kg_m3",
                "the session gives no density and the settings none either",
            )
        })?;
    Ok(TrackMaterial {
        young_pa: vec![s.young_pa; mesh.tets.len()],
        poisson: s.poisson,
        density_kg_m3: density,
        damping: RayleighDamping {
            alpha_per_s: s.rayleigh_alpha_per_s,
            beta_s: s.rayleigh_beta_s,
        },
        rest_m: None,
        source: "default".into(),
    })
}

/// A validated `softcap.DynamicMaterial` as the tracker's material.
pub fn material_from_proto(m: &proto::DynamicMaterial, tets: usize, source: &str) -> TrackMaterial {
    TrackMaterial {
        young_pa: if m.young_pa.len() == 1 {
            vec![m.young_pa[0]; tets]
        } else {
            m.young_pa.clone()
        },
        poisson: m.poisson,
        density_kg_m3: m.density_kg_m3,
        damping: RayleighDamping {
            alpha_per_s: m.rayleigh_alpha_per_s,
            beta_s: m.rayleigh_beta_s,
        },
        rest_m: (!m.rest_positions_m.is_empty()).then(|| {
            m.rest_positions_m
                .chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect()
        }),
        source: source.into(),
    }
}

/// Supported nodes: the capture's node list or support plane, plus `--attach`.
fn attachment(
    cfg: &TrackConfig,
    capture: &DynamicCaptureData,
    mesh: &TetMesh,
) -> Result<Attachment> {
    let n = mesh.vertices.len();
    let mut nodes: Vec<usize> = Vec::new();
    for &i in &capture.dynamic.support_nodes {
        if i as usize >= n {
            return Err(TissueError::bad_input(
                &cfg.capture,
                "/capture/dynamic support_nodes",
                format!("node {i} is past the {n} nodes of {}", cfg.mesh.display()),
            ));
        }
        nodes.push(i as usize);
    }
    if let Some(p) = &capture.session.support {
        nodes.extend((0..n).filter(|&i| {
            let x = mesh.vertices[i];
            p.signed_distance_m(&[x.x, x.y, x.z]) <= p.tolerance_m
        }));
    }
    if let Some(path) = &cfg.attach {
        nodes.extend(read_attach_csv(path, n)?);
    }
    nodes.sort_unstable();
    nodes.dedup();
    Ok(Attachment {
        frame0_m: nodes.iter().map(|&i| mesh.vertices[i]).collect(),
        nodes,
    })
}

/// `--attach FILE`: a `node` column of 0-based node indices.
fn read_attach_csv(path: &Path, nodes: usize) -> Result<Vec<usize>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| TissueError::bad_input(path, "file", e.to_string()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let header = lines.next().map(|(_, l)| l.trim()).unwrap_or("");
    let col = header
        .split(',')
        .position(|h| h.trim() == "node")
        .ok_or_else(|| TissueError::bad_input(path, "line 1", "needs a `node` column"))?;
    let mut out = Vec::new();
    for (i, line) in lines {
        let field = line.split(',').nth(col).unwrap_or("").trim();
        let v: usize = field.parse().map_err(|_| {
            TissueError::bad_input(
                path,
                format!("line {}, node", i + 1),
                format!("`{field}` is not a node index"),
            )
        })?;
        if v >= nodes {
            return Err(TissueError::bad_input(
                path,
                format!("line {}, node", i + 1),
                format!("node {v} is past the mesh's {nodes} nodes"),
            ));
        }
        out.push(v);
    }
    Ok(out)
}

/// The capture's depth cameras as the tracker sees them.
fn view_cameras(d: &proto::DynamicSession) -> Result<Vec<ViewCamera>> {
    d.cameras
        .iter()
        .map(|c| {
            let r = nalgebra::Matrix3::from_row_slice(&c.rotation);
            let t = c.translation_m.unwrap_or_default();
            let dist: [f64; 5] =
                c.distortion
                    .as_slice()
                    .try_into()
                    .map_err(|_| TissueError::BadInput {
                        path: PathBuf::from("/capture/dynamic"),
                        field: format!("camera {} distortion", c.id),
                        problem: format!(
                            "needs 5 coefficients (k1 k2 p1 p2 k3), got {}",
                            c.distortion.len()
                        ),
                    })?;
            let camera = softcap_core::Camera::new(
                c.id.clone(),
                c.width,
                c.height,
                [c.fx, c.fy, c.cx, c.cy],
                dist,
                r,
                Vector3::new(t.x, t.y, t.z),
            )
            .map_err(|e| TissueError::BadInput {
                path: PathBuf::from("/capture/dynamic"),
                field: format!("camera {}", c.id),
                problem: e.to_string(),
            })?;
            Ok(ViewCamera {
                camera,
                min_depth_m: c.min_depth_m,
                max_depth_m: c.max_depth_m,
            })
        })
        .collect()
}

/// Bad input when the mesh and the capture do not describe the same object: fewer than 30 % of
/// frame 0's points lie within 2 cm of the mesh surface (wrong mesh, wrong unit, wrong session).
fn check_mesh_matches_capture(
    mesh_path: &Path,
    mesh: &TetMesh,
    capture: &DynamicCaptureData,
) -> Result<()> {
    let Some(f0) = capture.frames.first() else {
        return Ok(());
    };
    if f0.points_m.is_empty() {
        return Ok(());
    }
    let surface = softcap_mesh::TriMesh {
        vertices: mesh.vertices.clone(),
        triangles: mesh.boundary_faces(),
    };
    let locator = softcap_mesh::TriLocator::new(&surface);
    let step = (f0.points_m.len() / 500).max(1);
    let (mut near, mut all) = (0usize, 0usize);
    for p in f0.points_m.iter().step_by(step) {
        all += 1;
        if locator
            .locate(&Vector3::from(*p))
            .is_some_and(|e| e.distance <= 0.02)
        {
            near += 1;
        }
    }
    if (near as f64) < 0.3 * all as f64 {
        return Err(TissueError::bad_input(
            mesh_path,
            "mesh",
            format!(
                "does not match {}: only {near} of {all} frame-0 points lie within 2 cm of its surface (wrong mesh, length unit or session?)",
                capture.path.display()
            ),
        ));
    }
    Ok(())
}
