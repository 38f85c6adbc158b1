//! Example poses: the compact `SCPOSE01` delta format of `fixtures/ict-face/` and seeded sparse
//! combinations of expressions (the pose sets of thesis §5.5.1, built from ICT-FaceKit).

use crate::error::{PsdError, Result};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;

/// Named per-vertex displacements from a neutral mesh (sparse: untouched vertices omitted).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseDeltas {
    /// Vertices of the neutral mesh.
    pub num_vertices: usize,
    /// Pose names (file stems of the source OBJs).
    pub names: Vec<String>,
    /// Per pose: (vertex, displacement) pairs in the mesh's length unit.
    pub deltas: Vec<Vec<(u32, Vector3<f64>)>>,
}

impl PoseDeltas {
    /// Read an `SCPOSE01` file (format in `fixtures/ict-face/README.md`).
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| PsdError::Io {
            path: path.into(),
            source,
        })?;
        Self::parse(&bytes, path)
    }

    /// Parse `SCPOSE01` bytes; `path` only names the source in errors.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        let mut r = Reader {
            bytes,
            pos: 0,
            path,
        };
        if r.take(8)? != b"SCPOSE01" {
            return Err(r.err("magic is not SCPOSE01"));
        }
        let num_vertices = r.u32()? as usize;
        let num_poses = r.u32()? as usize;
        let scale = f32::from_le_bytes(r.array()?) as f64;
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(r.err("quantisation scale must be positive"));
        }
        let mut names = Vec::with_capacity(num_poses);
        let mut deltas = Vec::with_capacity(num_poses);
        for _ in 0..num_poses {
            let len = u16::from_le_bytes(r.array()?) as usize;
            let name = std::str::from_utf8(r.take(len)?)
                .map_err(|_| r.err("pose name is not UTF-8"))?
                .to_string();
            let nnz = r.u32()? as usize;
            let mut list = Vec::with_capacity(nnz.min(num_vertices));
            for _ in 0..nnz {
                let v = r.u32()?;
                if v as usize >= num_vertices {
                    return Err(r.err(&format!(
                        "vertex {v} out of range ({num_vertices} vertices)"
                    )));
                }
                let mut d = Vector3::zeros();
                for k in 0..3 {
                    d[k] = i16::from_le_bytes(r.array()?) as f64 * scale;
                }
                list.push((v, d));
            }
            names.push(name);
            deltas.push(list);
        }
        if r.pos != bytes.len() {
            return Err(r.err("trailing bytes after the last pose"));
        }
        Ok(Self {
            num_vertices,
            names,
            deltas,
        })
    }

    /// Dense displacement field of pose `k`.
    pub fn dense(&self, k: usize) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.num_vertices];
        for &(v, d) in &self.deltas[k] {
            out[v as usize] = d;
        }
        out
    }

    /// Positions `neutral + Σ_k w_k · delta_k` (the linear blend-shape model of ICT-FaceKit).
    pub fn combine(&self, neutral: &[Vector3<f64>], weights: &[(usize, f64)]) -> Vec<Vector3<f64>> {
        let mut out = neutral.to_vec();
        for &(k, w) in weights {
            for &(v, d) in &self.deltas[k] {
                out[v as usize] += w * d;
            }
        }
        out
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Reader<'a> {
    fn err(&self, reason: &str) -> PsdError {
        PsdError::BadPoseFile {
            path: self.path.into(),
            offset: self.pos,
            reason: reason.into(),
        }
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        if self.pos + n > self.bytes.len() {
            return Err(self.err("file is truncated"));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn array<const N: usize>(&mut self) -> Result<[u8; N]> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }
    fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array()?))
    }
}

/// A pose as blend weights over the expressions of a [`PoseDeltas`].
#[derive(Clone, Debug, PartialEq)]
pub struct PoseRecipe {
    /// Readable name (`jawOpen` or `0.62·jawOpen+0.41·browDown_L`).
    pub name: String,
    /// (expression index, weight).
    pub weights: Vec<(usize, f64)>,
}

/// `count` seeded sparse random combinations of 2..=`max_terms` expressions with weights in
/// [0.3, 1] (thesis §5.5.1 uses a captured performance; ICT-FaceKit gives a linear blend-shape
/// space, so performance frames are emulated by sparse mixtures).
pub fn random_combinations(
    expressions: &PoseDeltas,
    candidates: &[usize],
    count: usize,
    max_terms: usize,
    seed: u64,
) -> Vec<PoseRecipe> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(count);
    while out.len() < count && candidates.len() >= 2 {
        let terms = rng.random_range(2..=max_terms.max(2));
        let mut weights: Vec<(usize, f64)> = Vec::new();
        while weights.len() < terms.min(candidates.len()) {
            let k = candidates[rng.random_range(0..candidates.len())];
            if weights.iter().all(|&(j, _)| j != k) {
                weights.push((k, rng.random_range(0.3..1.0)));
            }
        }
        weights.sort_by_key(|&(k, _)| k);
        let name = weights
            .iter()
            .map(|&(k, w)| format!("{w:.2}·{}", expressions.names[k]))
            .collect::<Vec<_>>()
            .join("+");
        out.push(PoseRecipe { name, weights });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_round_trip_and_truncation() {
        let mut b = b"SCPOSE01".to_vec();
        b.extend(4u32.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        b.extend(0.5f32.to_le_bytes());
        b.extend(3u16.to_le_bytes());
        b.extend(b"abc");
        b.extend(1u32.to_le_bytes());
        b.extend(2u32.to_le_bytes());
        for q in [2i16, -4, 6] {
            b.extend(q.to_le_bytes());
        }
        let p = PoseDeltas::parse(&b, Path::new("x")).unwrap();
        assert_eq!(p.names, ["abc"]);
        assert_eq!(p.dense(0)[2], Vector3::new(1.0, -2.0, 3.0));
        let err = PoseDeltas::parse(&b[..b.len() - 1], Path::new("x")).unwrap_err();
        assert!(err.to_string().contains("truncated"), "{err}");
        let mut bad = b.clone();
        bad[29] = 9; // vertex index 9 ≥ 4
        let err = PoseDeltas::parse(&bad, Path::new("x")).unwrap_err();
        assert!(err.to_string().contains("out of range"), "{err}");
    }
}
