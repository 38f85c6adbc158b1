//! A small axis-aligned bounding-box tree for closest-element queries.
//!
//! Written here rather than using parry3d's `Bvh` because the queries need an exact f64
//! point–element distance supplied by the caller (tets, triangles) and a deterministic
//! tie-break (lowest element index), and parry's tree works on glam types and its own shapes.

use nalgebra::Vector3;

#[derive(Clone, Debug)]
struct Node {
    min: Vector3<f64>,
    max: Vector3<f64>,
    /// Leaf: `start..start+count` in `order`; inner: children `left`, `left + 1`… stored as
    /// explicit indices.
    start: usize,
    count: usize,
    left: usize,
    right: usize,
}

/// AABB tree over element boxes.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<usize>,
}

const LEAF_SIZE: usize = 4;

fn box_distance2(min: &Vector3<f64>, max: &Vector3<f64>, p: &Vector3<f64>) -> f64 {
    let mut d2 = 0.0;
    for a in 0..3 {
        let d = (min[a] - p[a]).max(p[a] - max[a]).max(0.0);
        d2 += d * d;
    }
    d2
}

impl Bvh {
    /// Builds the tree over `boxes[i] = (min, max)` by recursive median split of box centres
    /// along the widest axis.
    pub fn new(boxes: &[(Vector3<f64>, Vector3<f64>)]) -> Self {
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * boxes.len() / LEAF_SIZE + 1),
            order: (0..boxes.len()).collect(),
        };
        if !boxes.is_empty() {
            bvh.build(boxes, 0, boxes.len());
        }
        bvh
    }

    fn build(&mut self, boxes: &[(Vector3<f64>, Vector3<f64>)], start: usize, end: usize) -> usize {
        let (mut min, mut max) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        let (mut cmin, mut cmax) = (min, max);
        for &i in &self.order[start..end] {
            min = min.inf(&boxes[i].0);
            max = max.sup(&boxes[i].1);
            let c = (boxes[i].0 + boxes[i].1) * 0.5;
            cmin = cmin.inf(&c);
            cmax = cmax.sup(&c);
        }
        let id = self.nodes.len();
        self.nodes.push(Node {
            min,
            max,
            start,
            count: end - start,
            left: usize::MAX,
            right: usize::MAX,
        });
        if end - start <= LEAF_SIZE {
            return id;
        }
        let axis = (cmax - cmin).imax();
        let mid = (start + end) / 2;
        let key = |i: &usize| boxes[*i].0[axis] + boxes[*i].1[axis];
        self.order[start..end]
            .select_nth_unstable_by(mid - start, |a, b| key(a).total_cmp(&key(b)).then(a.cmp(b)));
        let left = self.build(boxes, start, mid);
        let right = self.build(boxes, mid, end);
        let node = &mut self.nodes[id];
        node.left = left;
        node.right = right;
        node.count = 0;
        id
    }

    /// The element minimising `distance(i)` (ties: lowest index), and that distance.
    /// `distance` must be an exact Euclidean distance from `p` to element `i` (so the box
    /// bound is a valid lower bound); it may return `f64::INFINITY` to exclude an element.
    pub fn closest(
        &self,
        p: &Vector3<f64>,
        mut distance: impl FnMut(usize) -> f64,
    ) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        let mut stack = vec![(0usize, 0.0f64)];
        if self.nodes.is_empty() {
            return None;
        }
        while let Some((id, bound2)) = stack.pop() {
            if let Some((_, d)) = best
                && bound2 > d * d
            {
                continue;
            }
            let node = &self.nodes[id];
            if node.left == usize::MAX {
                for &i in &self.order[node.start..node.start + node.count] {
                    let d = distance(i);
                    let better = match best {
                        None => d.is_finite(),
                        Some((bi, bd)) => d < bd || (d == bd && i < bi),
                    };
                    if better {
                        best = Some((i, d));
                    }
                }
            } else {
                let (l, r) = (&self.nodes[node.left], &self.nodes[node.right]);
                let dl = box_distance2(&l.min, &l.max, p);
                let dr = box_distance2(&r.min, &r.max, p);
                // Push the farther child first so the nearer is explored first.
                if dl <= dr {
                    stack.push((node.right, dr));
                    stack.push((node.left, dl));
                } else {
                    stack.push((node.left, dl));
                    stack.push((node.right, dr));
                }
            }
        }
        best
    }
}
