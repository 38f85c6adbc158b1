//! Mocap / face correspondence (thesis §4.2.1): the space warp
//!
//! c(x) = Σ_i w_i φ(‖x − c_i‖) + q(x),   φ(r) = r³, q quadratic      (thesis eq. 4.1)
//!
//! with centres c_i = m_{i,0} (the neutral mocap frame) interpolating c(m_{i,0}) = f_{i,0} (the
//! marker vertices picked on the scan), and face-space displacements
//! u_{i,t} = c(m_{i,t}) − f_{i,0}. The RBF fit is softcap_core's [`Rbf`] (triharmonic kernel,
//! quadratic tail); because of the tail, c reproduces affine motions exactly.

use nalgebra::Vector3;
use softcap_core::{PolynomialTail, Rbf, RbfKernel, RbfSettings, ScatteredData};

use crate::error::{FaceError, Result};

/// The fitted space warp c: mocap space → face space.
#[derive(Clone, Debug)]
pub struct Correspondence {
    rbf: Rbf,
    face_points: Vec<Vector3<f64>>,
}

impl Correspondence {
    /// Fit c with c(m_{i,0}) = f_{i,0} (thesis eq. 4.1, φ = r³, quadratic q).
    pub fn fit(mocap_neutral: &[Vector3<f64>], face_points: &[Vector3<f64>]) -> Result<Self> {
        if mocap_neutral.len() != face_points.len() {
            return Err(FaceError::InvalidInput {
                what: "correspondence",
                reason: format!(
                    "{} mocap markers but {} face points",
                    mocap_neutral.len(),
                    face_points.len()
                ),
            });
        }
        let pts: Vec<f64> = mocap_neutral.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let vals: Vec<f64> = face_points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        let data =
            ScatteredData::new(&pts, 3, &vals, 3).map_err(|e| FaceError::Core(e.to_string()))?;
        let settings = RbfSettings {
            kernel: RbfKernel::Cubic,
            tail: PolynomialTail::Quadratic,
            ..Default::default()
        };
        let rbf = Rbf::interpolate(&data, &settings).map_err(|e| FaceError::Core(e.to_string()))?;
        Ok(Self {
            rbf,
            face_points: face_points.to_vec(),
        })
    }

    /// c(x).
    pub fn map(&self, x: &Vector3<f64>) -> Result<Vector3<f64>> {
        let y = self
            .rbf
            .evaluate(&[x.x, x.y, x.z])
            .map_err(|e| FaceError::Core(e.to_string()))?;
        Ok(Vector3::new(y[0], y[1], y[2]))
    }

    /// Face-space displacements u_{i,t} = c(m_{i,t}) − f_{i,0} of one mocap frame.
    pub fn displacements(&self, mocap_frame: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>> {
        if mocap_frame.len() != self.face_points.len() {
            return Err(FaceError::InvalidInput {
                what: "mocap frame",
                reason: format!(
                    "{} markers, correspondence has {}",
                    mocap_frame.len(),
                    self.face_points.len()
                ),
            });
        }
        mocap_frame
            .iter()
            .zip(&self.face_points)
            .map(|(m, f)| Ok(self.map(m)? - f))
            .collect()
    }
}
