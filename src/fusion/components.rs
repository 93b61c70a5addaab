//! Small disconnected pieces of a mesh removed (SPEC.md §16.3a): triangles sharing a vertex are
//! connected; a connected component with fewer than `min_triangles` triangles is dropped, and the
//! vertices no kept triangle uses go with it. Floating blobs of wrong depth that the multi-view
//! check let through are such pieces. Sequential and order-preserving: the kept vertices and
//! triangles keep their relative order, so the result is the same bits on every run.

use super::mesh::Mesh;

/// What [`remove_small_components`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ComponentReport {
    /// Connected components before.
    pub components: usize,
    /// Components removed (fewer than the threshold's triangles).
    pub removed_components: usize,
    /// Triangles removed.
    pub removed_triangles: usize,
}

/// Union-find root of `i`, with path halving.
fn root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[parent[i as usize] as usize];
        parent[i as usize] = p;
        i = p;
    }
    i
}

/// `mesh` without its connected components of fewer than `min_triangles` triangles (0 or 1 keeps
/// everything), and what was removed. Vertices no triangle uses are dropped as well only when
/// something is removed.
///
/// # Panics
/// If a triangle names a vertex the mesh does not have.
pub fn remove_small_components(mesh: &Mesh, min_triangles: usize) -> (Mesh, ComponentReport) {
    let n = mesh.vertices.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for t in &mesh.triangles {
        let (a, b, c) = (root(&mut parent, t[0]), root(&mut parent, t[1]), root(&mut parent, t[2]));
        // Union by the smaller index, so the roots do not depend on anything but the mesh.
        let r = a.min(b).min(c);
        for x in [a, b, c] {
            parent[x as usize] = r;
        }
    }
    let roots: Vec<u32> = mesh.triangles.iter().map(|t| root(&mut parent, t[0])).collect();
    let mut size = vec![0usize; n];
    for &r in &roots {
        size[r as usize] += 1;
    }
    let components = size.iter().filter(|&&s| s > 0).count();
    let small = |r: u32| size[r as usize] < min_triangles;
    let removed_components = size.iter().filter(|&&s| s > 0 && s < min_triangles).count();
    let mut report = ComponentReport { components, removed_components, removed_triangles: 0 };
    if removed_components == 0 {
        return (mesh.clone(), report);
    }
    let kept: Vec<[u32; 3]> =
        mesh.triangles.iter().zip(&roots).filter(|&(_, &r)| !small(r)).map(|(t, _)| *t).collect();
    report.removed_triangles = mesh.triangles.len() - kept.len();
    // Vertices in their old order, those of kept triangles only.
    let mut used = vec![false; n];
    for t in &kept {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut new_index = vec![u32::MAX; n];
    let mut out = Mesh::default();
    for (i, _) in used.iter().enumerate().filter(|(_, &u)| u) {
        new_index[i] = out.vertices.len() as u32;
        out.vertices.push(mesh.vertices[i]);
        if let Some(c) = mesh.colours.get(i) {
            out.colours.push(*c);
        }
    }
    out.triangles = kept.iter().map(|t| t.map(|v| new_index[v as usize])).collect();
    (out, report)
}
