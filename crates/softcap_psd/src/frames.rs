//! Per-vertex normals and local frames (thesis §5.4.2: details live in per-vertex local
//! frames; §5.5.2: normals are updated after the large-scale and after the detail step).
//!
//! Layout is structure-of-arrays in `f32` (`[f32; 3]` per vertex) so the run-time kernels
//! stream memory linearly; vertex→face incidence is a CSR array.

use rayon::prelude::*;

/// Vertices per parallel work item in the run-time kernels.
pub const BLOCK: usize = 2048;

/// Triangle connectivity with vertex→face incidence and one reference neighbour per vertex.
#[derive(Clone, Debug, PartialEq)]
pub struct Topology {
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// CSR offsets into `vertex_faces` (length n + 1).
    pub face_offsets: Vec<u32>,
    /// Incident faces of each vertex.
    pub vertex_faces: Vec<u32>,
    /// Neighbour whose direction defines the tangent `t_v` of the local frame.
    pub reference_neighbour: Vec<u32>,
}

impl Topology {
    /// Build from triangles over `n` vertices. A vertex in no triangle references itself (its
    /// frame falls back to the world axes).
    pub fn new(n: usize, triangles: &[[usize; 3]]) -> Self {
        let mut count = vec![0u32; n + 1];
        for t in triangles {
            for &v in t {
                count[v + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut vertex_faces = vec![0u32; count[n] as usize];
        let mut reference_neighbour: Vec<u32> = (0..n as u32).collect();
        for (f, t) in triangles.iter().enumerate() {
            for k in 0..3 {
                let v = t[k];
                vertex_faces[fill[v] as usize] = f as u32;
                fill[v] += 1;
                if reference_neighbour[v] == v as u32 {
                    reference_neighbour[v] = t[(k + 1) % 3] as u32;
                }
            }
        }
        Self {
            triangles: triangles.iter().map(|t| t.map(|v| v as u32)).collect(),
            face_offsets: count,
            vertex_faces,
            reference_neighbour,
        }
    }

    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.face_offsets.len() - 1
    }
}

#[inline(always)]
pub(crate) fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
pub(crate) fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline(always)]
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
pub(crate) fn normalize(a: [f32; 3], fallback: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt();
    if l > 1e-20 {
        let inv = 1.0 / l;
        [a[0] * inv, a[1] * inv, a[2] * inv]
    } else {
        fallback
    }
}

/// Area-weighted face normals (unnormalised, = cross product) into `face_normals`.
pub fn face_normals(topo: &Topology, positions: &[[f32; 3]], face_normals: &mut [[f32; 3]]) {
    face_normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(b, chunk)| {
            for (k, out) in chunk.iter_mut().enumerate() {
                let t = topo.triangles[b * BLOCK + k];
                let [a, p, q] = t.map(|v| positions[v as usize]);
                *out = cross(sub(p, a), sub(q, a));
            }
        });
}

/// Unit vertex normals: normalised sum of incident area-weighted face normals.
pub fn vertex_normals(topo: &Topology, face_normals: &[[f32; 3]], normals: &mut [[f32; 3]]) {
    normals
        .par_chunks_mut(BLOCK)
        .enumerate()
        .for_each(|(b, chunk)| {
            for (k, out) in chunk.iter_mut().enumerate() {
                let v = b * BLOCK + k;
                let mut s = [0.0f32; 3];
                for &f in &topo.vertex_faces
                    [topo.face_offsets[v] as usize..topo.face_offsets[v + 1] as usize]
                {
                    let n = face_normals[f as usize];
                    s = [s[0] + n[0], s[1] + n[1], s[2] + n[2]];
                }
                *out = normalize(s, [0.0, 0.0, 1.0]);
            }
        });
}

/// Orthonormal local frame `[t, b, n]` of vertex `v`: `n` the vertex normal, `t` the direction to
/// the reference neighbour projected onto the tangent plane, `b = n × t`.
#[inline]
pub fn local_frame(
    topo: &Topology,
    positions: &[[f32; 3]],
    normal: [f32; 3],
    v: usize,
) -> [[f32; 3]; 3] {
    let e = sub(
        positions[topo.reference_neighbour[v] as usize],
        positions[v],
    );
    frame_from_edge(e, normal)
}

/// Orthonormal frame `[t, b, n]` from a unit normal `n` and an edge `e` to the reference
/// neighbour: `t = normalize(e − (e·n) n)` (any axis not parallel to `n` if `e ∥ n` or `e = 0`),
/// `b = n × t`. Shared by [`local_frame`] and the run-time detail pass.
#[inline(always)]
pub(crate) fn frame_from_edge(e: [f32; 3], normal: [f32; 3]) -> [[f32; 3]; 3] {
    let d = dot(e, normal);
    let tp = [
        e[0] - d * normal[0],
        e[1] - d * normal[1],
        e[2] - d * normal[2],
    ];
    let mut t = normalize(tp, [0.0; 3]);
    if t == [0.0; 3] {
        // isolated vertex or neighbour along the normal: any axis not parallel to n
        let a = if normal[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let d = dot(a, normal);
        t = normalize(
            [
                a[0] - d * normal[0],
                a[1] - d * normal[1],
                a[2] - d * normal[2],
            ],
            [1.0, 0.0, 0.0],
        );
    }
    let b = cross(normal, t);
    [t, b, normal]
}

/// Express a world vector in the local frame: `(t·x, b·x, n·x)`.
#[inline]
pub fn to_local(frame: &[[f32; 3]; 3], x: [f32; 3]) -> [f32; 3] {
    [dot(frame[0], x), dot(frame[1], x), dot(frame[2], x)]
}

/// World vector of local coordinates `d`: `d_0 t + d_1 b + d_2 n`.
#[inline]
pub fn to_world(frame: &[[f32; 3]; 3], d: [f32; 3]) -> [f32; 3] {
    let [t, b, n] = frame;
    [
        d[0] * t[0] + d[1] * b[0] + d[2] * n[0],
        d[0] * t[1] + d[1] * b[1] + d[2] * n[1],
        d[0] * t[2] + d[1] * b[2] + d[2] * n[2],
    ]
}

/// Test mesh: an `n × n` grid of unit cells, two counter-clockwise triangles per cell, with
/// heights 0.1 · ((7k) mod 5) so that normals and frames vary.
#[cfg(test)]
pub(crate) fn bumpy_grid(n: usize) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let pos = (0..n * n)
        .map(|k| [(k % n) as f32, (k / n) as f32, 0.1 * ((k * 7 % 5) as f32)])
        .collect();
    let mut tris = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = j * n + i;
            tris.push([a, a + 1, a + n + 1]);
            tris.push([a, a + n + 1, a + n]);
        }
    }
    (pos, tris)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal_and_rotate_with_the_mesh() {
        let n = 6;
        let (pos, tris) = bumpy_grid(n);
        let topo = Topology::new(n * n, &tris);
        let normals_of = |p: &[[f32; 3]]| {
            let mut fnrm = vec![[0.0; 3]; tris.len()];
            face_normals(&topo, p, &mut fnrm);
            let mut vn = vec![[0.0; 3]; p.len()];
            vertex_normals(&topo, &fnrm, &mut vn);
            vn
        };
        let vn = normals_of(&pos);
        let r = nalgebra::Rotation3::from_euler_angles(0.4f32, 0.1, -0.7);
        let rot = |x: [f32; 3]| {
            let y = r * nalgebra::Vector3::from(x);
            [y.x, y.y, y.z]
        };
        let pos_r: Vec<[f32; 3]> = pos.iter().map(|&x| rot(x)).collect();
        let vn_r = normals_of(&pos_r);
        for v in 0..n * n {
            let f = local_frame(&topo, &pos, vn[v], v);
            for a in 0..3 {
                for b in 0..3 {
                    let want = if a == b { 1.0 } else { 0.0 };
                    assert!((dot(f[a], f[b]) - want).abs() < 1e-5);
                }
            }
            assert!(vn[v][2] > 0.5, "counter-clockwise grid faces +z");
            // local coordinates of a vector are invariant under a rigid rotation
            let d = [0.3, -0.2, 0.5];
            let w = to_world(&f, d);
            let fr = local_frame(&topo, &pos_r, vn_r[v], v);
            let back = to_local(&fr, rot(w));
            for k in 0..3 {
                assert!((back[k] - d[k]).abs() < 1e-5);
            }
        }
    }
}
