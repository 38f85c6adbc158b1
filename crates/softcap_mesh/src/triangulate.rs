//! Triangulation of planar-ish polygons by ear clipping.

use nalgebra::Vector3;

/// Triangulates the polygon `poly` (vertex indices into `positions`, in order) into
/// `poly.len() − 2` triangles with the polygon's orientation.
///
/// Triangles pass through unchanged. Larger polygons are projected onto the plane of their
/// Newell normal and ear-clipped (an ear is a convex corner whose triangle contains no other
/// polygon vertex), so concave quads and pentagons are split correctly. If no ear is found
/// (self-intersecting or degenerate polygon) the remainder is fan-triangulated.
pub fn triangulate_polygon(positions: &[Vector3<f64>], poly: &[usize]) -> Vec<[usize; 3]> {
    let n = poly.len();
    if n < 3 {
        return Vec::new();
    }
    if n == 3 {
        return vec![[poly[0], poly[1], poly[2]]];
    }
    // Newell normal.
    let mut normal = Vector3::zeros();
    for i in 0..n {
        let a = positions[poly[i]];
        let b = positions[poly[(i + 1) % n]];
        normal += a.cross(&b);
    }
    let normal = normal.normalize();
    if !normal.iter().all(|v| v.is_finite()) {
        return fan(poly);
    }
    let mut remaining: Vec<usize> = poly.to_vec();
    let mut out = Vec::with_capacity(n - 2);
    let cross_n = |a: usize, b: usize, c: usize| -> f64 {
        let (pa, pb, pc) = (positions[a], positions[b], positions[c]);
        (pb - pa).cross(&(pc - pa)).dot(&normal)
    };
    while remaining.len() > 3 {
        let m = remaining.len();
        let mut clipped = false;
        for i in 0..m {
            let (a, b, c) = (
                remaining[(i + m - 1) % m],
                remaining[i],
                remaining[(i + 1) % m],
            );
            if cross_n(a, b, c) <= 0.0 {
                continue; // reflex or flat corner
            }
            let inside = remaining.iter().any(|&p| {
                p != a
                    && p != b
                    && p != c
                    && cross_n(a, b, p) >= 0.0
                    && cross_n(b, c, p) >= 0.0
                    && cross_n(c, a, p) >= 0.0
            });
            if !inside {
                out.push([a, b, c]);
                remaining.remove(i);
                clipped = true;
                break;
            }
        }
        if !clipped {
            out.extend(fan(&remaining));
            return out;
        }
    }
    out.push([remaining[0], remaining[1], remaining[2]]);
    out
}

fn fan(poly: &[usize]) -> Vec<[usize; 3]> {
    (1..poly.len() - 1)
        .map(|i| [poly[0], poly[i], poly[i + 1]])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn concave_quad_is_split_at_reflex_corner() {
        // Dart: vertex 2 is reflex; the fan from 0 would produce a triangle outside the polygon.
        let p = vec![
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(2.0, 1.0, 0.0),
            Vector3::new(0.0, 0.2, 0.0),
            Vector3::new(-2.0, 1.0, 0.0),
        ];
        let poly = [1, 2, 3, 0];
        let tris = triangulate_polygon(&p, &poly);
        assert_eq!(tris.len(), 2);
        let area: f64 = tris
            .iter()
            .map(|t| 0.5 * (p[t[1]] - p[t[0]]).cross(&(p[t[2]] - p[t[0]])).z)
            .sum();
        // Shoelace area of the dart: 2 * 0.5 * |(2,1) x (0,0.2)| = 0.4, all triangles positive.
        assert!((area - 0.4).abs() < 1e-12);
        for t in &tris {
            assert!((p[t[1]] - p[t[0]]).cross(&(p[t[2]] - p[t[0]])).z > 0.0);
        }
    }
}
