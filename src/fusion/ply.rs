//! Meshes as binary PLY (SPEC.md §16.4): `format binary_little_endian 1.0`, `element vertex N` with
//! `float x y z` and `uchar red green blue` (15 bytes), `element face M` with `property list uchar
//! int vertex_indices` (13 bytes a triangle). Opens in MeshLab, CloudCompare and Open3D. The parser
//! reads back exactly this layout (tests, and anyone checking a file we wrote).

use std::io::Write;
use std::path::Path;

use super::mesh::Mesh;
use crate::error::{Error, Result};
use crate::io::write_atomic_with;

/// Write `mesh` to `path` atomically, with one `comment` line.
///
/// # Errors
/// [`Error::Io`] naming `path`.
pub fn write_mesh_ply(path: &Path, mesh: &Mesh, comment: &str) -> Result<()> {
    let comment = comment.replace(['\n', '\r'], " ");
    write_atomic_with(path, |out| {
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n\
             property float x\nproperty float y\nproperty float z\nproperty uchar red\n\
             property uchar green\nproperty uchar blue\nelement face {}\n\
             property list uchar int vertex_indices\nend_header\n",
            mesh.vertices.len(),
            mesh.triangles.len()
        )?;
        let mut buf = Vec::with_capacity(mesh.vertices.len() * 15);
        for (p, c) in mesh.vertices.iter().zip(&mesh.colours) {
            for v in p {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            buf.extend_from_slice(c);
        }
        out.write_all(&buf)?;
        buf.clear();
        for t in &mesh.triangles {
            buf.push(3);
            for &i in t {
                buf.extend_from_slice(&(i as i32).to_le_bytes());
            }
        }
        out.write_all(&buf)
    })
}

/// Read a mesh written by [`write_mesh_ply`] (that exact layout).
///
/// # Errors
/// [`Error::BadFile`] naming `path` for another layout, a short payload, a non-triangle face or
/// an index out of range.
pub fn read_mesh_ply(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |what: &str| Error::bad_file(path, what.to_string());
    let end = b"end_header\n";
    let header_len =
        bytes.windows(end.len()).position(|w| w == end).ok_or_else(|| bad("no end_header line"))? + end.len();
    let header = std::str::from_utf8(&bytes[..header_len]).map_err(|_| bad("header is not text"))?;
    let (mut nv, mut nf) = (None, None);
    let mut props = Vec::new();
    for line in header.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["element", "vertex", n] => nv = n.parse::<usize>().ok(),
            ["element", "face", n] => nf = n.parse::<usize>().ok(),
            ["property", rest @ ..] => props.push(rest.join(" ")),
            ["format", fmt, _] if *fmt != "binary_little_endian" => {
                return Err(bad("not binary_little_endian"))
            }
            _ => {}
        }
    }
    let want = [
        "float x",
        "float y",
        "float z",
        "uchar red",
        "uchar green",
        "uchar blue",
        "list uchar int vertex_indices",
    ];
    if props != want {
        return Err(bad(&format!("unexpected properties {props:?}")));
    }
    let (nv, nf) = (nv.ok_or_else(|| bad("no vertex count"))?, nf.ok_or_else(|| bad("no face count"))?);
    let body = &bytes[header_len..];
    if body.len() != nv.saturating_mul(15).saturating_add(nf.saturating_mul(13)) {
        return Err(bad("payload size does not match the element counts"));
    }
    let f32_at = |o: usize| f32::from_le_bytes([body[o], body[o + 1], body[o + 2], body[o + 3]]);
    let mut mesh = Mesh::default();
    for v in 0..nv {
        let o = v * 15;
        mesh.vertices.push([f32_at(o), f32_at(o + 4), f32_at(o + 8)]);
        mesh.colours.push([body[o + 12], body[o + 13], body[o + 14]]);
    }
    let faces = &body[nv * 15..];
    for t in 0..nf {
        let o = t * 13;
        if faces[o] != 3 {
            return Err(bad(&format!("face {t} has {} vertices, expected 3", faces[o])));
        }
        let idx = |k: usize| {
            let p = o + 1 + 4 * k;
            i32::from_le_bytes([faces[p], faces[p + 1], faces[p + 2], faces[p + 3]])
        };
        let tri = [idx(0), idx(1), idx(2)];
        if tri.iter().any(|&i| i < 0 || i as usize >= nv) {
            return Err(bad(&format!("face {t} has an index out of range")));
        }
        mesh.triangles.push(tri.map(|i| i as u32));
    }
    Ok(mesh)
}
