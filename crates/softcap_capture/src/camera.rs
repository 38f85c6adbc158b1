//! The camera model lives in [`softcap_core::camera`] (pure math shared with the virtual rig);
//! capture only parses `rig/cameras.toml` into it (see `session.rs`).

pub use softcap_core::camera::Camera;
