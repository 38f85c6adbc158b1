//! A small z-buffered software rasterizer with Lambert + ambient shading (for the figures in
//! docs/face; orthographic camera looking down −z).

use nalgebra::Vector3;

use crate::image::RgbImage;

/// Vertex normals: area-weighted sums of face normals, normalized.
pub fn vertex_normals(vertices: &[Vector3<f64>], triangles: &[[usize; 3]]) -> Vec<Vector3<f64>> {
    let mut n = vec![Vector3::zeros(); vertices.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i]);
        let f = (b - a).cross(&(c - a));
        for &i in t {
            n[i] += f;
        }
    }
    for v in &mut n {
        let l = v.norm();
        if l > 0.0 {
            *v /= l;
        }
    }
    n
}

/// Orthographic view: the box `[x0, x1] × [y0, y1]` of world x, y fills the image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrthoView {
    /// World x at the left edge.
    pub x0: f64,
    /// World y at the top edge.
    pub y1: f64,
    /// World units per pixel.
    pub units_per_px: f64,
}

impl OrthoView {
    /// A view that fits `vertices` into `width_px` columns with a margin, and its height.
    pub fn fit(vertices: &[Vector3<f64>], width_px: usize) -> (Self, usize) {
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for v in vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
        let m = 0.05 * (hi.x - lo.x).max(hi.y - lo.y);
        let upp = (hi.x - lo.x + 2.0 * m) / width_px as f64;
        let h = ((hi.y - lo.y + 2.0 * m) / upp).ceil() as usize;
        (
            Self {
                x0: lo.x - m,
                y1: hi.y + m,
                units_per_px: upp,
            },
            h,
        )
    }

    fn project(&self, v: &Vector3<f64>) -> [f64; 3] {
        [
            (v.x - self.x0) / self.units_per_px,
            (self.y1 - v.y) / self.units_per_px,
            v.z,
        ]
    }
}

/// Render a shaded mesh: per-pixel interpolated normals, light from `light_dir` (towards the
/// light), albedo `rgb`, ambient term 0.15.
pub fn render_mesh(
    vertices: &[Vector3<f64>],
    triangles: &[[usize; 3]],
    view: &OrthoView,
    width_px: usize,
    height_px: usize,
    light_dir: Vector3<f64>,
    rgb: [f64; 3],
) -> RgbImage {
    let normals = vertex_normals(vertices, triangles);
    let light = light_dir.normalize();
    let mut img = RgbImage::new(width_px, height_px);
    for px in &mut img.data {
        *px = [0.08, 0.08, 0.1];
    }
    let mut zbuf = vec![f64::NEG_INFINITY; width_px * height_px];
    for t in triangles {
        let p = t.map(|i| view.project(&vertices[i]));
        let area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        let xmin = p
            .iter()
            .map(|q| q[0])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let xmax = p
            .iter()
            .map(|q| q[0])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(width_px as f64 - 1.0);
        let ymin = p
            .iter()
            .map(|q| q[1])
            .fold(f64::INFINITY, f64::min)
            .floor()
            .max(0.0) as usize;
        let ymax = p
            .iter()
            .map(|q| q[1])
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(height_px as f64 - 1.0);
        if xmax < 0.0 || ymax < 0.0 {
            continue;
        }
        for y in ymin..=ymax as usize {
            for x in xmin..=xmax as usize {
                let (fx, fy) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((p[1][0] - fx) * (p[2][1] - fy) - (p[2][0] - fx) * (p[1][1] - fy)) / area;
                let w1 = ((p[2][0] - fx) * (p[0][1] - fy) - (p[0][0] - fx) * (p[2][1] - fy)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p[0][2] + w1 * p[1][2] + w2 * p[2][2];
                let i = y * width_px + x;
                if z <= zbuf[i] {
                    continue;
                }
                zbuf[i] = z;
                let n = (normals[t[0]] * w0 + normals[t[1]] * w1 + normals[t[2]] * w2).normalize();
                let shade = 0.15 + 0.85 * n.dot(&light).abs();
                img.data[i] = rgb.map(|c| c * shade);
            }
        }
    }
    img
}
