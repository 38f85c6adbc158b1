//! Conforming local refinement of tet meshes by longest-edge bisection.
//!
//! [`refine_near`] refines the tets that intersect given balls until their longest edge is at most
//! a target length h, and leaves the rest of the mesh as coarse as conformity allows. The only
//! operation is the bisection of an edge (a, b) at its midpoint m: EVERY tet containing both a and
//! b is replaced by its two halves (a → m and b → m), so no hanging node can arise and each half
//! keeps its parent's orientation (m lies on the segment, the signed volume halves).
//!
//! Which edge is bisected follows Rivara's longest-edge bisection (M.-C. Rivara, "Local
//! modification of meshes for adaptive and/or multigrid finite-element methods", J. Comput. Appl.
//! Math. 36, 1991; the longest-edge propagation path, LEPP, of Rivara 1997): the marked tet with
//! the longest edge is taken first; before its longest edge e is bisected, every tet sharing e
//! whose own longest edge is longer has that edge bisected first (recursively), so an edge is
//! only ever bisected when it is the longest edge of every tet containing it. Bisecting the
//! longest edge keeps the children's shapes from degenerating (no proven bound in 3D; the tests
//! state the measured minimum dihedral angle against the input's). Ties in length are broken by
//! the vertex ids (the edge with the smaller sorted pair counts as longer), and the marked tets
//! are taken from a priority queue with the same total order, so the output is deterministic.

use crate::embed::{closest_point_on_triangle, tet_barycentric};
use crate::error::{MeshError, Result};
use crate::refine::RefinedTetMesh;
use crate::types::TetMesh;
use nalgebra::Vector3;
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};

/// A ball in which [`refine_near`] refines.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineBall {
    /// Centre, m (the mesh's frame).
    pub centre_m: Vector3<f64>,
    /// Radius, m (≥ 0; 0 refines the tets containing the centre).
    pub radius_m: f64,
}

/// The six edges of a tet as corner pairs.
const EDGES: [[usize; 2]; 6] = [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]];

/// Distance from `p` to the closed tet `x` (0 inside): the nearest of its four faces' closest
/// points (Ericson §5.1.5) when `p` lies outside.
fn tet_distance(x: &[Vector3<f64>; 4], p: &Vector3<f64>) -> f64 {
    if let Some(l) = tet_barycentric(x, p)
        && l.iter().all(|&v| v >= 0.0)
    {
        return 0.0;
    }
    [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| x[i]);
            let w = closest_point_on_triangle(p, &a, &b, &c);
            (a * w[0] + b * w[1] + c * w[2] - p).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The working mesh of [`refine_near`].
struct Bisector {
    vertices: Vec<Vector3<f64>>,
    tets: Vec<[usize; 4]>,
    parent_tet: Vec<usize>,
    midpoint_of: Vec<[usize; 2]>,
    /// The live tets containing each edge [a, b] (a < b).
    edge_tets: HashMap<[usize; 2], Vec<usize>>,
    /// Whether the tet in each slot intersects a ball.
    near: Vec<bool>,
    /// Marked tets (near a ball, longest edge > h): (longest edge, its tet's slot and corners).
    queue: BinaryHeap<Marked>,
    balls: Vec<RefineBall>,
    max_edge_sq: f64,
    max_tets: usize,
}

/// A marked tet in the priority queue: ordered by its longest edge (the total order of
/// [`Bisector::edge_cmp`]), then by slot; `tet` detects a slot reused since.
struct Marked {
    length_sq: f64,
    edge: [usize; 2],
    slot: usize,
    tet: [usize; 4],
}

impl PartialEq for Marked {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Marked {}
impl PartialOrd for Marked {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Marked {
    fn cmp(&self, other: &Self) -> Ordering {
        self.length_sq
            .total_cmp(&other.length_sq)
            .then_with(|| other.edge.cmp(&self.edge))
            .then_with(|| other.slot.cmp(&self.slot))
            .then_with(|| other.tet.cmp(&self.tet))
    }
}

impl Bisector {
    fn length_sq(&self, [a, b]: [usize; 2]) -> f64 {
        (self.vertices[a] - self.vertices[b]).norm_squared()
    }

    /// The total order "longer than": by length, ties to the smaller sorted vertex pair.
    fn edge_cmp(&self, e: [usize; 2], f: [usize; 2]) -> Ordering {
        self.length_sq(e)
            .total_cmp(&self.length_sq(f))
            .then_with(|| f.cmp(&e))
    }

    fn longest_edge(&self, tet: &[usize; 4]) -> [usize; 2] {
        EDGES
            .iter()
            .map(|&[i, j]| [tet[i].min(tet[j]), tet[i].max(tet[j])])
            .max_by(|&e, &f| self.edge_cmp(e, f))
            .expect("six edges")
    }

    fn is_near(&self, tet: &[usize; 4]) -> bool {
        let x = tet.map(|i| self.vertices[i]);
        self.balls
            .iter()
            .any(|b| tet_distance(&x, &b.centre_m) <= b.radius_m)
    }

    /// Registers the tet in `slot` (its edges; the queue when near and too long).
    fn add(&mut self, slot: usize, near: bool) {
        let tet = self.tets[slot];
        for [i, j] in EDGES {
            let e = [tet[i].min(tet[j]), tet[i].max(tet[j])];
            self.edge_tets.entry(e).or_default().push(slot);
        }
        self.near[slot] = near;
        let edge = self.longest_edge(&tet);
        let length_sq = self.length_sq(edge);
        if near && length_sq > self.max_edge_sq {
            self.queue.push(Marked {
                length_sq,
                edge,
                slot,
                tet,
            });
        }
    }

    /// Bisects `e` after the longer edges on its propagation path (module docs).
    fn bisect_lepp(&mut self, e: [usize; 2]) -> Result<()> {
        let mut path = vec![e];
        while let Some(&e) = path.last() {
            let Some(slots) = self.edge_tets.get(&e) else {
                path.pop();
                continue;
            };
            let longest = slots
                .iter()
                .map(|&s| self.longest_edge(&self.tets[s]))
                .max_by(|&f, &g| self.edge_cmp(f, g))
                .expect("a registered edge has a tet");
            if longest == e {
                self.bisect(e)?;
                path.pop();
            } else {
                path.push(longest);
            }
        }
        Ok(())
    }

    /// Replaces every tet containing `e` = [a, b] by its halves a → m and b → m (module docs).
    fn bisect(&mut self, [a, b]: [usize; 2]) -> Result<()> {
        let m = self.vertices.len();
        self.vertices
            .push((self.vertices[a] + self.vertices[b]) * 0.5);
        self.midpoint_of.push([a, b]);
        let mut slots = self.edge_tets.remove(&[a, b]).unwrap_or_default();
        slots.sort_unstable();
        for slot in slots {
            let tet = self.tets[slot];
            for [i, j] in EDGES {
                let f = [tet[i].min(tet[j]), tet[i].max(tet[j])];
                if f != [a, b]
                    && let Some(list) = self.edge_tets.get_mut(&f)
                {
                    list.retain(|&s| s != slot);
                }
            }
            let first = tet.map(|v| if v == b { m } else { v });
            let second = tet.map(|v| if v == a { m } else { v });
            let near = self.near[slot];
            self.tets[slot] = first;
            let other = self.tets.len();
            self.tets.push(second);
            self.parent_tet.push(self.parent_tet[slot]);
            self.near.push(false);
            if self.tets.len() > self.max_tets {
                return Err(MeshError::Refinement {
                    message: format!(
                        "more than {} tets needed for edges ≤ {:e} m",
                        self.max_tets,
                        self.max_edge_sq.sqrt()
                    ),
                });
            }
            // a child can only intersect a ball its parent intersects
            let near_first = near && self.is_near(&first);
            let near_second = near && self.is_near(&second);
            self.add(slot, near_first);
            self.add(other, near_second);
        }
        Ok(())
    }
}

/// Refines `mesh` conformingly until every tet that intersects one of `balls` has its longest edge
/// ≤ `max_edge_m` (to 10⁻⁹ relative: midpoints are rounded, so halving an edge of exactly twice the
/// target must not need another level) (longest-edge bisection, Rivara 1991; module docs). Tets that intersect no ball
/// are split only where a bisected edge is theirs (conformity), and tets none of whose edges is
/// bisected keep their index and corners. The result's `parent_tet` names the input tet each
/// output tet lies in; `midpoint_of[k]` the edge (of input vertices or earlier midpoints) whose
/// midpoint vertex `n + k` is. `mesh` must be positively oriented (the halves keep the sign).
///
/// Errors ([`MeshError::Refinement`]): `max_edge_m` not positive and finite, a ball with a
/// non-finite centre or a negative or non-finite radius, or more than `max_tets` tets needed.
pub fn refine_near(
    mesh: &TetMesh,
    balls: &[RefineBall],
    max_edge_m: f64,
    max_tets: usize,
) -> Result<RefinedTetMesh> {
    let bad = |message: String| Err(MeshError::Refinement { message });
    if !(max_edge_m.is_finite() && max_edge_m > 0.0) {
        return bad(format!("target edge length {max_edge_m} m is not positive"));
    }
    if let Some(b) = balls.iter().find(|b| {
        !(b.centre_m.iter().all(|c| c.is_finite()) && b.radius_m.is_finite() && b.radius_m >= 0.0)
    }) {
        return bad(format!(
            "ball at {:?} with radius {} m is not finite",
            b.centre_m.as_slice(),
            b.radius_m
        ));
    }
    let mut s = Bisector {
        vertices: mesh.vertices.clone(),
        tets: mesh.tets.clone(),
        parent_tet: (0..mesh.tets.len()).collect(),
        midpoint_of: Vec::new(),
        edge_tets: HashMap::new(),
        near: vec![false; mesh.tets.len()],
        queue: BinaryHeap::new(),
        balls: balls.to_vec(),
        // rounded midpoints: an edge within 10⁻⁹ (relative) of the target counts as meeting it
        max_edge_sq: (max_edge_m * (1.0 + 1e-9)).powi(2),
        max_tets,
    };
    for slot in 0..mesh.tets.len() {
        let near = s.is_near(&mesh.tets[slot]);
        s.add(slot, near);
    }
    while let Some(marked) = s.queue.pop() {
        // skip entries whose slot has been bisected since
        if s.tets[marked.slot] == marked.tet {
            s.bisect_lepp(marked.edge)?;
        }
    }
    Ok(RefinedTetMesh {
        mesh: TetMesh {
            vertices: s.vertices,
            tets: s.tets,
        },
        parent_tet: s.parent_tet,
        midpoint_of: s.midpoint_of,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_to_a_tet_is_zero_inside_and_euclidean_outside() {
        let x = [Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()];
        assert_eq!(tet_distance(&x, &Vector3::new(0.1, 0.1, 0.1)), 0.0);
        assert!((tet_distance(&x, &Vector3::new(-0.5, 0.2, 0.2)) - 0.5).abs() < 1e-15);
        assert!((tet_distance(&x, &Vector3::new(2.0, 0.0, 0.0)) - 1.0).abs() < 1e-15);
        let d = tet_distance(&x, &Vector3::new(1.0, 1.0, 1.0));
        assert!((d - (1.0 - 1.0 / 3.0) * 3f64.sqrt()).abs() < 1e-12, "{d}");
    }
}
