//! Writing a COLMAP model (text or binary) from our cameras and poses: used by the round-trip tests
//! and to hand a rendered sequence to COLMAP tools.

use std::io::Write;
use std::path::Path;

use super::model::{colmap_params, CameraModel};
use crate::error::{Error, Result};
use crate::geometry::{Camera, Pose};
use crate::io::write_atomic_with;

/// A model to write: one camera, registered images, points and what each image observes.
#[derive(Clone, Debug)]
pub struct ColmapExport {
    /// The COLMAP model the camera is written as.
    pub model: CameraModel,
    /// Our camera (SPEC.md §2.1 pixel centres; written with `+0.5` on the principal point).
    pub camera: Camera,
    /// Per image: its name under `images/` and camera-to-world pose `T_wc`.
    pub images: Vec<(String, Pose)>,
    /// World points.
    pub points: Vec<[f64; 3]>,
    /// Per image: `(u, v, point index)` observations, `u, v` in our pixel convention.
    pub observations: Vec<Vec<(f64, f64, usize)>>,
}

/// Write `cameras`, `images` and `points3D` (`.bin` when `binary`, else `.txt`) into `dir`. Image
/// ids are 1-based in `images` order, the camera id is 1, point ids are 1-based.
///
/// # Errors
/// [`Error::InvalidArgument`] when the model cannot express the camera or an observation names a
/// missing point; [`Error::Io`] on a write failure.
pub fn write_model(dir: &Path, e: &ColmapExport, binary: bool) -> Result<()> {
    let params = colmap_params(e.model, &e.camera)?;
    if e.observations.len() != e.images.len() {
        return Err(Error::invalid_argument("observations", "one list per image is required"));
    }
    let mut tracks: Vec<Vec<(u32, u32)>> = vec![Vec::new(); e.points.len()];
    for (i, obs) in e.observations.iter().enumerate() {
        for (k, &(_, _, p)) in obs.iter().enumerate() {
            tracks
                .get_mut(p)
                .ok_or_else(|| Error::invalid_argument("observations", format!("point {p} does not exist")))?
                .push((i as u32 + 1, k as u32));
        }
    }
    std::fs::create_dir_all(dir).map_err(|err| Error::io(dir, err))?;
    let k = &e.camera.pinhole;
    // World-to-camera rotation (w, x, y, z) and translation per image.
    let poses: Vec<([f64; 4], [f64; 3])> = e
        .images
        .iter()
        .map(|(_, p)| {
            let cw = p.inverse();
            let q = cw.rotation.quaternion();
            let t = cw.translation.vector;
            ([q.w, q.i, q.j, q.k], [t.x, t.y, t.z])
        })
        .collect();
    if binary {
        write_atomic_with(&dir.join("cameras.bin"), |w| {
            w.write_all(&1u64.to_le_bytes())?;
            w.write_all(&1u32.to_le_bytes())?;
            w.write_all(&e.model.id().to_le_bytes())?;
            w.write_all(&(k.width as u64).to_le_bytes())?;
            w.write_all(&(k.height as u64).to_le_bytes())?;
            for p in &params {
                w.write_all(&p.to_le_bytes())?;
            }
            Ok(())
        })?;
        write_atomic_with(&dir.join("images.bin"), |w| {
            w.write_all(&(e.images.len() as u64).to_le_bytes())?;
            for (i, ((name, _), (q, t))) in e.images.iter().zip(&poses).enumerate() {
                w.write_all(&(i as u32 + 1).to_le_bytes())?;
                for v in q.iter().chain(t) {
                    w.write_all(&v.to_le_bytes())?;
                }
                w.write_all(&1u32.to_le_bytes())?;
                w.write_all(name.as_bytes())?;
                w.write_all(&[0])?;
                w.write_all(&(e.observations[i].len() as u64).to_le_bytes())?;
                for &(u, v, p) in &e.observations[i] {
                    w.write_all(&(u + 0.5).to_le_bytes())?;
                    w.write_all(&(v + 0.5).to_le_bytes())?;
                    w.write_all(&(p as u64 + 1).to_le_bytes())?;
                }
            }
            Ok(())
        })?;
        write_atomic_with(&dir.join("points3D.bin"), |w| {
            w.write_all(&(e.points.len() as u64).to_le_bytes())?;
            for (j, (x, track)) in e.points.iter().zip(&tracks).enumerate() {
                w.write_all(&(j as u64 + 1).to_le_bytes())?;
                for v in x {
                    w.write_all(&v.to_le_bytes())?;
                }
                w.write_all(&[128, 128, 128])?;
                w.write_all(&0.5f64.to_le_bytes())?;
                w.write_all(&(track.len() as u64).to_le_bytes())?;
                for (im, idx) in track {
                    w.write_all(&im.to_le_bytes())?;
                    w.write_all(&idx.to_le_bytes())?;
                }
            }
            Ok(())
        })
    } else {
        write_atomic_with(&dir.join("cameras.txt"), |w| {
            writeln!(w, "# Camera list with one line of data per camera:")?;
            writeln!(w, "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]")?;
            let p: Vec<String> = params.iter().map(|v| format!("{v:e}")).collect();
            writeln!(w, "1 {} {} {} {}", e.model.name(), k.width, k.height, p.join(" "))?;
            Ok(())
        })?;
        write_atomic_with(&dir.join("images.txt"), |w| {
            writeln!(w, "# Image list with two lines of data per image:")?;
            writeln!(w, "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME")?;
            writeln!(w, "#   POINTS2D[] as (X, Y, POINT3D_ID)")?;
            for (i, ((name, _), (q, t))) in e.images.iter().zip(&poses).enumerate() {
                writeln!(
                    w,
                    "{} {:e} {:e} {:e} {:e} {:e} {:e} {:e} 1 {name}",
                    i + 1,
                    q[0],
                    q[1],
                    q[2],
                    q[3],
                    t[0],
                    t[1],
                    t[2]
                )?;
                let obs: Vec<String> = e.observations[i]
                    .iter()
                    .map(|(u, v, p)| format!("{:e} {:e} {}", u + 0.5, v + 0.5, p + 1))
                    .collect();
                writeln!(w, "{}", obs.join(" "))?;
            }
            Ok(())
        })?;
        write_atomic_with(&dir.join("points3D.txt"), |w| {
            writeln!(w, "# 3D point list with one line of data per point:")?;
            writeln!(w, "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)")?;
            for (j, (x, track)) in e.points.iter().zip(&tracks).enumerate() {
                let t: Vec<String> = track.iter().map(|(a, b)| format!("{a} {b}")).collect();
                writeln!(w, "{} {:e} {:e} {:e} 128 128 128 0.5 {}", j + 1, x[0], x[1], x[2], t.join(" "))?;
            }
            Ok(())
        })
    }
}
