//! The channel and schema catalog: which topics exist, which protobuf message each carries,
//! and the embedded schema (a serialized `FileDescriptorSet`) written into every file.
//!
//! Messages are defined in `proto/softcap/*.proto`; `build.rs` compiles them with `protox`
//! (pure Rust, no `protoc`) and generates the Rust structs with `prost-build` from the same
//! descriptor set, so the structs and the embedded schemas cannot disagree.
//!
//! To add a message: add it to a `.proto` file, list it in the macro
//! invocation below (`impl_softcap_message!`), add its topic constant to [`topics`] and a row to [`CATALOG`] and to
//! `docs/formats.md` (a test checks both).

use std::borrow::Cow;
use std::marker::PhantomData;
use std::sync::OnceLock;

use prost_reflect::DescriptorPool;

use crate::proto;

/// Schema encoding of every softcap domain channel (MCAP well-known schema encoding).
pub const SCHEMA_ENCODING: &str = "protobuf";
/// Message encoding of every softcap domain channel (MCAP well-known message encoding).
pub const MESSAGE_ENCODING: &str = "protobuf";

/// The serialized `FileDescriptorSet` of all softcap `.proto` files (without source info).
/// This is the schema data of every softcap domain channel.
pub fn descriptor_set() -> &'static [u8] {
    include_bytes!(concat!(env!("OUT_DIR"), "/softcap_descriptor_set.bin"))
}

/// The softcap descriptor set as a `prost-reflect` pool (for dynamic decoding).
pub fn descriptor_pool() -> &'static DescriptorPool {
    static POOL: OnceLock<DescriptorPool> = OnceLock::new();
    POOL.get_or_init(|| {
        DescriptorPool::decode(descriptor_set())
            .expect("the descriptor set compiled by build.rs is valid")
    })
}

/// A softcap domain message: a prost message whose schema lives in [`descriptor_set`].
pub trait SoftcapMessage: prost::Message + prost::Name + Default + Clone + PartialEq {
    /// Fully qualified protobuf name, e.g. `softcap.MarkerFrame` (the MCAP schema name).
    fn schema_name() -> String {
        <Self as prost::Name>::full_name()
    }
}

macro_rules! impl_softcap_message {
    ($($t:ident),* $(,)?) => {
        $(impl SoftcapMessage for proto::$t {})*
        /// Schema names of every softcap domain message, in catalog order.
        pub fn message_names() -> Vec<String> {
            vec![$(<proto::$t as prost::Name>::full_name()),*]
        }
    };
}

impl_softcap_message!(
    TriMesh,
    TetMesh,
    MarkerFrame,
    ProbeSample,
    ClockSync,
    CameraStats,
    SessionInfo,
    ElementMaterial,
    StrainSpaceBasis,
    SimulatedMarkers,
    Scalar,
    Report,
    HypothesisScore,
    LocatedResidual,
    Diagnosis,
    ExtendedModel,
    FaceWrinkles,
    PlasticStrains,
    ReshapeConstraints,
    ReshapeQuality,
    DynamicSession,
    PointCloudFrame,
    NodeFrame,
    TrackStatus,
    DynamicMaterial,
    FaceCameras,
    WrinkleTrackFrame,
);

/// A typed channel name: writing or reading through a `Topic<M>` guarantees the channel carries
/// `M` messages.
pub struct Topic<M> {
    name: Cow<'static, str>,
    _message: PhantomData<fn() -> M>,
}

impl<M> Clone for Topic<M> {
    fn clone(&self) -> Self {
        Self {
            name: self.name.clone(),
            _message: PhantomData,
        }
    }
}

impl<M> std::fmt::Debug for Topic<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Topic({})", self.name)
    }
}

impl<M: SoftcapMessage> Topic<M> {
    /// A topic with a fixed name (used for the [`topics`] constants).
    pub const fn new(name: &'static str) -> Self {
        Self {
            name: Cow::Borrowed(name),
            _message: PhantomData,
        }
    }

    /// A topic whose name is built at run time (e.g. `/series/lm_cost`).
    pub fn custom(name: impl Into<String>) -> Self {
        Self {
            name: Cow::Owned(name.into()),
            _message: PhantomData,
        }
    }

    /// The topic name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Topic of the Foxglove twin of a domain topic: `/viz` + topic (`/capture/markers` →
/// `/viz/capture/markers`).
pub fn viz_topic(topic: &str) -> String {
    format!("/viz{topic}")
}

/// The standard softcap topics. Stages may add their own with [`Topic::custom`]; list new
/// standard ones here, in [`CATALOG`] and in `docs/formats.md`.
pub mod topics {
    use super::Topic;
    use crate::proto::*;

    /// Surface triangle mesh (static, time 0), metres.
    pub const SURFACE_MESH: Topic<TriMesh> = Topic::new("/mesh/surface");
    /// Tetrahedral volume mesh (static, time 0), metres.
    pub const VOLUME_MESH: Topic<TetMesh> = Topic::new("/mesh/volume");
    /// Labelled 3D markers, one message per camera frame, at the frame's time.
    pub const MARKERS: Topic<MarkerFrame> = Topic::new("/capture/markers");
    /// Probe tip, axis, force and raw voltage, one message per camera frame.
    pub const PROBE: Topic<ProbeSample> = Topic::new("/capture/probe");
    /// Camera–DAQ clock estimate (static, time 0).
    pub const CLOCK_SYNC: Topic<ClockSync> = Topic::new("/capture/clock_sync");
    /// Per-camera statistics (one message per camera at time 0).
    pub const CAMERA_STATS: Topic<CameraStats> = Topic::new("/capture/camera_stats");
    /// What capture knew about the session: marker ids, rest positions, gravity, support, probe
    /// tip (static, time 0).
    pub const SESSION: Topic<SessionInfo> = Topic::new("/capture/session");
    /// Capture summary report (time 0).
    pub const CAPTURE_REPORT: Topic<Report> = Topic::new("/capture/report");
    /// Per-example per-tet (λ, α), one message per example at its frame's time.
    pub const ELEMENT_MATERIAL: Topic<ElementMaterial> = Topic::new("/tissue/element_material");
    /// Strain-space RBF material (static, time 0).
    pub const STRAIN_SPACE_BASIS: Topic<StrainSpaceBasis> = Topic::new("/tissue/basis");
    /// Simulated markers, one message per frame/load step.
    pub const SIMULATED_MARKERS: Topic<SimulatedMarkers> = Topic::new("/tissue/simulated_markers");
    /// Tissue stage report (time 0).
    pub const TISSUE_REPORT: Topic<Report> = Topic::new("/tissue/report");
    /// `softcap tissue simulate`: the probe (tip, axis, contact force on the object) at each
    /// load step.
    pub const SIMULATED_PROBE: Topic<ProbeSample> = Topic::new("/tissue/simulated_probe");
    /// `softcap tissue simulate`: node positions at each load step (tets as `/mesh/volume`).
    pub const DEFORMED_MESH: Topic<TetMesh> = Topic::new("/tissue/deformed_mesh");
    /// Diagnosis: verdict, ranked hypotheses, located residuals (static, time 0).
    pub const DIAGNOSIS: Topic<Diagnosis> = Topic::new("/diagnose/diagnosis");
    /// Extended model: the named term and its fitted parameters (static, time 0).
    pub const EXTENDED_MODEL: Topic<ExtendedModel> = Topic::new("/diagnose/extended_model");
    /// Default-model simulation of every recorded frame, at the frame's time.
    pub const BASELINE_MARKERS: Topic<SimulatedMarkers> = Topic::new("/diagnose/baseline_markers");
    /// Extended-model simulation of every recorded frame, at the frame's time.
    pub const EXTENDED_MARKERS: Topic<SimulatedMarkers> = Topic::new("/diagnose/extended_markers");
    /// Diagnose stage report (time 0).
    pub const DIAGNOSE_REPORT: Topic<Report> = Topic::new("/diagnose/report");
    /// Animated face surface, one message per mocap frame at its time (thesis §3.2), metres.
    pub const FACE_MESH: Topic<TriMesh> = Topic::new("/face/mesh");
    /// Wrinkle cross-sections (image and projected world (d, w)), one message per frame.
    pub const FACE_WRINKLES: Topic<FaceWrinkles> = Topic::new("/face/wrinkles");
    /// `softcap face track`: the take's cameras in the face frame (static, time 0).
    pub const FACE_TRACK_CAMERAS: Topic<FaceCameras> = Topic::new("/face/track/cameras");
    /// `softcap face track`: tracked wrinkles, one message per camera and frame at its time.
    pub const FACE_TRACK_WRINKLES: Topic<WrinkleTrackFrame> = Topic::new("/face/track/wrinkles");
    /// `softcap design search`: the design found, its error, the search statistics and the
    /// target and predicted force–displacement curves (static, time 0).
    pub const DESIGN_REPORT: Topic<Report> = Topic::new("/design/report");
    /// `softcap tissue reshape`: the template before reshaping (static, time 0), metres.
    pub const RESHAPE_TEMPLATE: Topic<TetMesh> = Topic::new("/reshape/template");
    /// `softcap tissue reshape`: per-tet plastic strains (static, time 0).
    pub const PLASTIC_STRAINS: Topic<PlasticStrains> = Topic::new("/reshape/plastic_strains");
    /// `softcap tissue reshape`: every constraint with its error (static, time 0), metres.
    pub const RESHAPE_CONSTRAINTS: Topic<ReshapeConstraints> = Topic::new("/reshape/constraints");
    /// `softcap tissue reshape`: mesh quality before and after (static, time 0).
    pub const RESHAPE_QUALITY: Topic<ReshapeQuality> = Topic::new("/reshape/quality");
    /// `softcap tissue reshape` report (time 0).
    pub const RESHAPE_REPORT: Topic<Report> = Topic::new("/reshape/report");
    /// Dynamic session: depth cameras, support nodes, interactions (static, time 0).
    pub const DYNAMIC_SESSION: Topic<DynamicSession> = Topic::new("/capture/dynamic");
    /// World-frame point cloud (all depth cameras fused), one message per camera frame.
    pub const POINTS: Topic<PointCloudFrame> = Topic::new("/capture/points");
    /// `softcap tissue track`: tracked node positions of the template mesh, one per frame.
    pub const TRACK_NODES: Topic<NodeFrame> = Topic::new("/tissue/track/nodes");
    /// `softcap tissue track`: residual, σ, outlier fraction and status, one per frame.
    pub const TRACK_STATUS: Topic<TrackStatus> = Topic::new("/tissue/track/status");
    /// `softcap tissue track`: summary report (time 0).
    pub const TRACK_REPORT: Topic<Report> = Topic::new("/tissue/track/report");
    /// A dynamic material (E per tet, ν, ρ, Rayleigh α and β, rest shape) (static, time 0).
    pub const DYNAMIC_MATERIAL: Topic<DynamicMaterial> = Topic::new("/tissue/dynamic_material");
    /// `softcap tissue fit-dynamic`: fitted parameters, uncertainties, trajectory RMS, modes (time 0).
    pub const DYNAMIC_FIT_REPORT: Topic<Report> = Topic::new("/tissue/dynamic_fit/report");
    /// `softcap tissue simulate-dynamic`: simulated node positions of the template mesh per frame.
    pub const DYNAMIC_SIM_NODES: Topic<NodeFrame> = Topic::new("/tissue/dynamic_sim/nodes");
}

/// One row of the channel catalog (mirrored in `docs/formats.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Topic name.
    pub topic: &'static str,
    /// Protobuf message (MCAP schema name).
    pub schema: &'static str,
    /// True for static data logged once at time 0.
    pub is_static: bool,
    /// Units of the message's numeric fields.
    pub units: &'static str,
}

/// Every standard softcap channel.
pub const CATALOG: &[ChannelInfo] = &[
    ChannelInfo {
        topic: "/mesh/surface",
        schema: "softcap.TriMesh",
        is_static: true,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/mesh/volume",
        schema: "softcap.TetMesh",
        is_static: true,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/capture/markers",
        schema: "softcap.MarkerFrame",
        is_static: false,
        units: "t s, positions m, reprojection error px",
    },
    ChannelInfo {
        topic: "/capture/probe",
        schema: "softcap.ProbeSample",
        is_static: false,
        units: "t s, tip m, axis unit vector, force N, voltage V",
    },
    ChannelInfo {
        topic: "/capture/clock_sync",
        schema: "softcap.ClockSync",
        is_static: true,
        units: "offset s, drift s/s, residual s",
    },
    ChannelInfo {
        topic: "/capture/camera_stats",
        schema: "softcap.CameraStats",
        is_static: true,
        units: "counts, reprojection errors px",
    },
    ChannelInfo {
        topic: "/capture/session",
        schema: "softcap.SessionInfo",
        is_static: true,
        units: "rest positions m, gravity m/s², support offset/tolerance m, density kg/m³, tip radius m",
    },
    ChannelInfo {
        topic: "/capture/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/tissue/element_material",
        schema: "softcap.ElementMaterial",
        is_static: false,
        units: "lambda Pa, alpha Pa, strain 1, residual m",
    },
    ChannelInfo {
        topic: "/tissue/basis",
        schema: "softcap.StrainSpaceBasis",
        is_static: true,
        units: "strain 1, weights Pa",
    },
    ChannelInfo {
        topic: "/tissue/simulated_markers",
        schema: "softcap.SimulatedMarkers",
        is_static: false,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/tissue/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/tissue/simulated_probe",
        schema: "softcap.ProbeSample",
        is_static: false,
        units: "tip m, axis unit vector, force N",
    },
    ChannelInfo {
        topic: "/tissue/deformed_mesh",
        schema: "softcap.TetMesh",
        is_static: false,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/diagnose/diagnosis",
        schema: "softcap.Diagnosis",
        is_static: true,
        units: "rmse m, score 1",
    },
    ChannelInfo {
        topic: "/diagnose/extended_model",
        schema: "softcap.ExtendedModel",
        is_static: true,
        units: "params per entry",
    },
    ChannelInfo {
        topic: "/diagnose/baseline_markers",
        schema: "softcap.SimulatedMarkers",
        is_static: false,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/diagnose/extended_markers",
        schema: "softcap.SimulatedMarkers",
        is_static: false,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/diagnose/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/face/mesh",
        schema: "softcap.TriMesh",
        is_static: false,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/face/wrinkles",
        schema: "softcap.FaceWrinkles",
        is_static: false,
        units: "valley/d/w px; d, w, valley m",
    },
    ChannelInfo {
        topic: "/face/track/cameras",
        schema: "softcap.FaceCameras",
        is_static: true,
        units: "focal, principal point px; position m",
    },
    ChannelInfo {
        topic: "/face/track/wrinkles",
        schema: "softcap.WrinkleTrackFrame",
        is_static: false,
        units: "spline, valley, d, w px; d, w, valley m",
    },
    ChannelInfo {
        topic: "/design/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/reshape/template",
        schema: "softcap.TetMesh",
        is_static: true,
        units: "positions m",
    },
    ChannelInfo {
        topic: "/reshape/plastic_strains",
        schema: "softcap.PlasticStrains",
        is_static: true,
        units: "strain 1",
    },
    ChannelInfo {
        topic: "/reshape/constraints",
        schema: "softcap.ReshapeConstraints",
        is_static: true,
        units: "positions m, errors m",
    },
    ChannelInfo {
        topic: "/reshape/quality",
        schema: "softcap.ReshapeQuality",
        is_static: true,
        units: "angles deg, ratios 1",
    },
    ChannelInfo {
        topic: "/reshape/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/capture/dynamic",
        schema: "softcap.DynamicSession",
        is_static: true,
        units: "camera intrinsics px, translation m, depth scale m, intervals s",
    },
    ChannelInfo {
        topic: "/capture/points",
        schema: "softcap.PointCloudFrame",
        is_static: false,
        units: "t s, positions m, normals unit vectors, support translation m",
    },
    ChannelInfo {
        topic: "/tissue/track/nodes",
        schema: "softcap.NodeFrame",
        is_static: false,
        units: "t s, positions m",
    },
    ChannelInfo {
        topic: "/tissue/track/status",
        schema: "softcap.TrackStatus",
        is_static: false,
        units: "t s, residual m, sigma m, outlier fraction 1",
    },
    ChannelInfo {
        topic: "/tissue/track/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/tissue/dynamic_material",
        schema: "softcap.DynamicMaterial",
        is_static: true,
        units: "E Pa, density kg/m³, alpha 1/s, beta s, rest positions m",
    },
    ChannelInfo {
        topic: "/tissue/dynamic_fit/report",
        schema: "softcap.Report",
        is_static: true,
        units: "per entry",
    },
    ChannelInfo {
        topic: "/tissue/dynamic_sim/nodes",
        schema: "softcap.NodeFrame",
        is_static: false,
        units: "t s, positions m",
    },
];
