//! Pictures of a mesh (SPEC.md §16.6): a z-buffer rasteriser with back-face culling, vertex
//! colours interpolated over each triangle and a head light (`shade = 0.3 + 0.7 max(0, n·l)`, `l`
//! toward the viewer). Two views: a pinhole camera at a pose, and an orthographic "dollhouse" view
//! from above at an oblique angle.

use nalgebra::{Matrix3, Vector3};
use ndarray::Array3;

use super::mesh::Mesh;
use crate::geometry::{PinholeCamera, Pose};

/// Background grey level of the pictures.
const BACKGROUND: f32 = 40.0;

/// How world points reach the picture.
#[derive(Clone, Copy, Debug)]
pub enum View {
    /// A pinhole camera (the picture has the camera's size) at pose `T_wc`.
    Pinhole {
        /// Intrinsics and picture size.
        camera: PinholeCamera,
        /// Camera-to-world pose.
        pose: Pose,
    },
    /// Orthographic: `R_cw` rotates world points into view axes (x right, y down, z away from the
    /// viewer); pixel `= scale (x - centre.x, y - centre.y) + (W/2, H/2)`.
    Ortho {
        /// World-to-view rotation.
        r_cw: Matrix3<f64>,
        /// View-axes point at the picture centre.
        centre: [f64; 2],
        /// Pixels per metre.
        scale: f64,
        /// Picture width and height.
        size: (usize, usize),
    },
}

impl View {
    fn size(&self) -> (usize, usize) {
        match self {
            View::Pinhole { camera, .. } => (camera.width, camera.height),
            View::Ortho { size, .. } => *size,
        }
    }

    /// `(u, v, depth)` of a world point, and the unit direction from it toward the viewer.
    fn project(&self, p: Vector3<f64>) -> Option<([f64; 3], Vector3<f64>)> {
        match self {
            View::Pinhole { camera, pose } => {
                let c = pose.inverse_transform_point(&p.into());
                let uv = camera.project(&c.coords)?;
                let to_eye = (pose.translation.vector - p).normalize();
                Some(([uv.x, uv.y, c.z], to_eye))
            }
            View::Ortho { r_cw, centre, scale, size } => {
                let c = r_cw * p;
                let u = scale * (c.x - centre[0]) + size.0 as f64 / 2.0;
                let v = scale * (c.y - centre[1]) + size.1 as f64 / 2.0;
                Some(([u, v, c.z], -r_cw.row(2).transpose()))
            }
        }
    }

    /// An oblique orthographic view of `mesh` looking down at `elevation_deg` from horizontal along
    /// `forward`, with `up` the world's up direction; the 2nd-98th percentile of the vertices fills
    /// the picture.
    pub fn oblique(
        mesh: &Mesh,
        up: Vector3<f64>,
        forward: Vector3<f64>,
        elevation_deg: f64,
        size: (usize, usize),
    ) -> View {
        let up = up.normalize();
        let fwd_h = (forward - up * forward.dot(&up))
            .try_normalize(1e-9)
            .unwrap_or_else(|| up.cross(&Vector3::x()).normalize());
        let e = elevation_deg.to_radians();
        let z = (fwd_h * e.cos() - up * e.sin()).normalize();
        let y = -(up - z * up.dot(&z)).normalize();
        let x = y.cross(&z);
        let r_cw = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
        let (mut xs, mut ys): (Vec<f64>, Vec<f64>) = mesh
            .vertices
            .iter()
            .map(|v| {
                let c = r_cw * Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                (c.x, c.y)
            })
            .unzip();
        let range = |v: &mut Vec<f64>| -> (f64, f64) {
            if v.is_empty() {
                return (-1.0, 1.0);
            }
            v.sort_by(f64::total_cmp);
            let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
            (q(0.02), q(0.98))
        };
        let ((x0, x1), (y0, y1)) = (range(&mut xs), range(&mut ys));
        let scale = 0.9 * (size.0 as f64 / (x1 - x0).max(1e-6)).min(size.1 as f64 / (y1 - y0).max(1e-6));
        View::Ortho { r_cw, centre: [(x0 + x1) / 2.0, (y0 + y1) / 2.0], scale, size }
    }
}

/// Render `mesh` seen through `view`: `[H, W, 3]`, 0-255.
pub fn render(mesh: &Mesh, view: &View) -> Array3<f32> {
    let (w, h) = view.size();
    let mut img = Array3::from_elem((h, w, 3), BACKGROUND);
    let mut zbuf = vec![f64::INFINITY; w * h];
    let proj: Vec<Option<([f64; 3], Vector3<f64>)>> = mesh
        .vertices
        .iter()
        .map(|v| view.project(Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64)))
        .collect();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let [Some(a), Some(b), Some(c)] = tri.map(|i| proj[i as usize]) else { continue };
        let n = mesh.triangle_normal(t);
        let n = Vector3::new(n[0], n[1], n[2]);
        let facing = n.dot(&a.1);
        if facing <= 0.0 {
            continue; // back face
        }
        let shade = (0.3 + 0.7 * facing) as f32;
        let (pa, pb, pc) = (a.0, b.0, c.0);
        let area = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0]);
        if area.abs() < 1e-12 {
            continue;
        }
        let xmin = pa[0].min(pb[0]).min(pc[0]).floor().max(0.0) as usize;
        let ymin = pa[1].min(pb[1]).min(pc[1]).floor().max(0.0) as usize;
        let xmax = pa[0].max(pb[0]).max(pc[0]).ceil().min(w as f64 - 1.0);
        let ymax = pa[1].max(pb[1]).max(pc[1]).ceil().min(h as f64 - 1.0);
        if xmax < 0.0 || ymax < 0.0 {
            continue;
        }
        let cols = tri.map(|i| mesh.colours[i as usize].map(f32::from));
        for y in ymin..=ymax as usize {
            for x in xmin..=xmax as usize {
                let (px, py) = (x as f64, y as f64);
                let w0 = ((pb[0] - px) * (pc[1] - py) - (pb[1] - py) * (pc[0] - px)) / area;
                let w1 = ((pc[0] - px) * (pa[1] - py) - (pc[1] - py) * (pa[0] - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * pa[2] + w1 * pb[2] + w2 * pc[2];
                if z >= zbuf[y * w + x] {
                    continue;
                }
                zbuf[y * w + x] = z;
                for k in 0..3 {
                    let c = w0 as f32 * cols[0][k] + w1 as f32 * cols[1][k] + w2 as f32 * cols[2][k];
                    img[[y, x, k]] = (c * shade).clamp(0.0, 255.0);
                }
            }
        }
    }
    img
}

/// Pictures side by side (same height), separated by a 4-pixel white gap; rows stacked likewise.
pub fn tile(rows: &[Vec<Array3<f32>>]) -> Array3<f32> {
    const GAP: usize = 4;
    let row_imgs: Vec<Array3<f32>> = rows
        .iter()
        .map(|r| {
            let h = r.iter().map(|i| i.dim().0).max().unwrap_or(0);
            let w: usize = r.iter().map(|i| i.dim().1).sum::<usize>() + GAP * r.len().saturating_sub(1);
            let mut out = Array3::from_elem((h, w, 3), 255.0f32);
            let mut x0 = 0;
            for i in r {
                let (ih, iw, _) = i.dim();
                out.slice_mut(ndarray::s![..ih, x0..x0 + iw, ..]).assign(i);
                x0 += iw + GAP;
            }
            out
        })
        .collect();
    let w = row_imgs.iter().map(|i| i.dim().1).max().unwrap_or(0);
    let h: usize = row_imgs.iter().map(|i| i.dim().0).sum::<usize>() + GAP * row_imgs.len().saturating_sub(1);
    let mut out = Array3::from_elem((h, w, 3), 255.0f32);
    let mut y0 = 0;
    for i in &row_imgs {
        let (ih, iw, _) = i.dim();
        out.slice_mut(ndarray::s![y0..y0 + ih, ..iw, ..]).assign(i);
        y0 += ih + GAP;
    }
    out
}
