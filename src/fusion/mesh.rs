//! The zero level set of a TSDF as a triangle mesh: masked surface nets (SPEC.md §16.3).
//!
//! An **edge** between neighbouring grid points `a`, `b` is *active* when both are observed
//! (`W > 0`) and `T` changes sign (`T_a < 0 ≠ T_b < 0`); as in Open3D's marching cubes there is
//! no other filter (a filter on single edges, such as dropping jumps from `T = +1`, opens holes
//! in closed surfaces where it applies to some edges of a cell face only). Its crossing is the linear
//! zero `a + T_a / (T_a - T_b) (b - a)`, with the colour interpolated alike. A **cell** (the cube
//! of 8 grid points with min corner `(i, j, k)`) with an active edge gets one vertex: the mean of
//! its edges' crossings (and colours). Every active edge not on the volume's border is shared by
//! four cells, all with a vertex: it gives one quad (two triangles), oriented so that its normal
//! points toward `T > 0` (free space, the cameras). Where the observed region ends, a cell face
//! can have an odd number of active edges and the mesh has boundary edges; a closed observed
//! surface gives a closed mesh.

use std::collections::HashMap;

use super::tsdf::Tsdf;

/// A triangle mesh with vertex colours, world frame, metres.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Vertex colours, 0-255.
    pub colours: Vec<[u8; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from the side the normal points to.
    pub triangles: Vec<[u32; 3]>,
}

/// Edge counts of a mesh: how closed it is.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EdgeReport {
    /// Distinct undirected edges.
    pub edges: usize,
    /// Edges used by exactly one triangle (0 for a closed mesh).
    pub boundary: usize,
    /// Edges used by more than two triangles.
    pub non_manifold: usize,
}

impl Mesh {
    /// Count boundary and non-manifold edges.
    pub fn edge_report(&self) -> EdgeReport {
        let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        EdgeReport {
            edges: uses.len(),
            boundary: uses.values().filter(|&&n| n == 1).count(),
            non_manifold: uses.values().filter(|&&n| n > 2).count(),
        }
    }

    /// Unit normal of triangle `t` (zero for a degenerate one).
    pub fn triangle_normal(&self, t: usize) -> [f64; 3] {
        let [a, b, c] = self.triangles[t].map(|i| self.vertices[i as usize].map(f64::from));
        let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if l > 0.0 {
            n.map(|x| x / l)
        } else {
            [0.0; 3]
        }
    }
}

/// The crossing on the edge from grid point `a` to its `+axis` neighbour, if the edge is active:
/// `(s, T_a < 0)` with `s` the fraction of the way to the neighbour.
#[inline]
fn crossing(v: &Tsdf, a: usize, b: usize) -> Option<(f64, bool)> {
    let (wa, wb) = (v.weight[a], v.weight[b]);
    let (ta, tb) = (v.tsdf[a] as f64, v.tsdf[b] as f64);
    if wa > 0.0 && wb > 0.0 && (ta < 0.0) != (tb < 0.0) {
        Some((ta / (ta - tb), ta < 0.0))
    } else {
        None
    }
}

/// Extract the mesh of the zero level set of `volume` (module docs). Deterministic: vertices in
/// cell order (x fastest), quads in edge order.
pub fn extract_mesh(volume: &Tsdf) -> Mesh {
    let g = volume.grid;
    let [nx, ny, nz] = g.dims;
    if nx < 2 || ny < 2 || nz < 2 {
        return Mesh::default();
    }
    let step = [1, nx, nx * ny];
    let cell_index = |i: usize, j: usize, k: usize| (k * (ny - 1) + j) * (nx - 1) + i;
    let mut cell_vertex = vec![u32::MAX; (nx - 1) * (ny - 1) * (nz - 1)];
    let mut mesh = Mesh::default();
    // The 12 edges of a cell: (corner offset, axis).
    let mut cell_edges = Vec::with_capacity(12);
    for axis in 0..3 {
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        for (db, dc) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let mut off = [0usize; 3];
            off[b] = db;
            off[c] = dc;
            cell_edges.push((off, axis));
        }
    }
    for k in 0..nz - 1 {
        for j in 0..ny - 1 {
            for i in 0..nx - 1 {
                let (mut sum, mut col, mut n) = ([0.0f64; 3], [0.0f64; 3], 0usize);
                for &(off, axis) in &cell_edges {
                    let a = g.index(i + off[0], j + off[1], k + off[2]);
                    let b = a + step[axis];
                    let Some((s, _)) = crossing(volume, a, b) else { continue };
                    for d in 0..3 {
                        let base = [i, j, k][d] + off[d];
                        sum[d] += base as f64 + if d == axis { s } else { 0.0 };
                        col[d] += (1.0 - s) * volume.colour[a][d] as f64 + s * volume.colour[b][d] as f64;
                    }
                    n += 1;
                }
                if n == 0 {
                    continue;
                }
                cell_vertex[cell_index(i, j, k)] = mesh.vertices.len() as u32;
                let p = [0, 1, 2].map(|d| (g.origin[d] + sum[d] / n as f64 * g.voxel) as f32);
                mesh.vertices.push(p);
                mesh.colours.push(col.map(|c| (c / n as f64).round().clamp(0.0, 255.0) as u8));
            }
        }
    }
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = [i, j, k];
                for axis in 0..3 {
                    let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                    let dims = [nx, ny, nz];
                    // The edge must have a neighbour along `axis`, and the four cells around it
                    // (offsets -1/0 along b and c) must exist.
                    if p[axis] + 1 >= dims[axis]
                        || p[b] == 0
                        || p[c] == 0
                        || p[b] + 1 >= dims[b]
                        || p[c] + 1 >= dims[c]
                    {
                        continue;
                    }
                    let a = g.index(i, j, k);
                    let Some((_, inside_first)) = crossing(volume, a, a + step[axis]) else { continue };
                    let cell = |db: usize, dc: usize| {
                        let mut q = p;
                        q[b] = q[b] + db - 1;
                        q[c] = q[c] + dc - 1;
                        cell_vertex[cell_index(q[0], q[1], q[2])]
                    };
                    // Counter-clockwise around +axis (b, c cyclic after axis).
                    let mut quad = [cell(0, 0), cell(1, 0), cell(1, 1), cell(0, 1)];
                    debug_assert!(quad.iter().all(|&v| v != u32::MAX), "active edge without vertices");
                    if !inside_first {
                        quad.reverse();
                    }
                    mesh.triangles.push([quad[0], quad[1], quad[2]]);
                    mesh.triangles.push([quad[0], quad[2], quad[3]]);
                }
            }
        }
    }
    mesh
}
