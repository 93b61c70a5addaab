//! COLMAP's binary model (`cameras.bin`, `images.bin`, `points3D.bin`), little-endian:
//!
//! ```text
//! cameras.bin   u64 count; per camera: u32 id, i32 model, u64 width, u64 height, f64 params[n(model)]
//! images.bin    u64 count; per image: u32 id, f64 qw qx qy qz, f64 tx ty tz, u32 camera_id,
//!               name (bytes up to a NUL), u64 n2d, per 2D point: f64 x, f64 y, u64 point3D_id (-1: none)
//! points3D.bin  u64 count; per point: u64 id, f64 x y z, u8 r g b, f64 error, u64 track length,
//!               per track element: u32 image_id, u32 point2D_idx
//! ```
//! Errors name the file, the record and its byte offset.

use std::path::Path;

use super::model::{CameraModel, Loc, RawCamera, RawImage, RawPoint};
use crate::error::{Error, Result};

/// A little-endian reader over a whole file that names the file and offset in its errors.
struct Cursor<'a> {
    path: &'a Path,
    bytes: Vec<u8>,
    pos: usize,
    /// Description of what is being read, for truncation messages.
    record: String,
}

impl<'a> Cursor<'a> {
    fn open(path: &'a Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Ok(Self { path, bytes, pos: 0, record: "the header".into() })
    }

    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let end = self.pos + N;
        let Some(s) = self.bytes.get(self.pos..end) else {
            return Err(Error::bad_file(
                self.path,
                format!(
                    "truncated: {} ends at byte {} while reading {what} of {} (needs {N} bytes at offset {})",
                    self.path.display(),
                    self.bytes.len(),
                    self.record,
                    self.pos
                ),
            ));
        };
        self.pos = end;
        Ok(s.try_into().expect("slice of length N"))
    }

    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take::<1>(what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(what)?))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(what)?))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(what)?))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(what)?))
    }
    fn f64s<const N: usize>(&mut self, what: &str) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// A count of records at least `min_size` bytes each, checked against the bytes left so a
    /// corrupt count is an error, not a huge allocation.
    fn count(&mut self, what: &str, min_size: usize) -> Result<usize> {
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.saturating_mul(min_size as u64) > left {
            return Err(Error::bad_file(
                self.path,
                format!(
                    "{what} at byte {} of {} is {n}, but only {left} bytes follow (each entry needs at least \
                     {min_size})",
                    self.pos - 8,
                    self.record
                ),
            ));
        }
        Ok(n as usize)
    }

    fn start(&mut self, kind: &str, index: usize) -> Loc {
        self.record = format!("{kind} record {index} (starting at byte {})", self.pos);
        Loc::Record { index, offset: self.pos }
    }

    fn finish(&self) -> Result<()> {
        if self.pos != self.bytes.len() {
            return Err(Error::bad_file(
                self.path,
                format!(
                    "{} trailing bytes after the last record (at byte {})",
                    self.bytes.len() - self.pos,
                    self.pos
                ),
            ));
        }
        Ok(())
    }
}

pub(crate) fn read_cameras(path: &Path) -> Result<Vec<RawCamera>> {
    let mut c = Cursor::open(path)?;
    let n = c.count("camera count", 24)?;
    let mut out = Vec::with_capacity(n);
    for index in 0..n {
        let loc = c.start("camera", index);
        let id = c.u32("CAMERA_ID")?;
        let model_id = c.i32("model id")?;
        let (model, count) = CameraModel::from_id(model_id)
            .ok_or_else(|| loc.error(path, format!("camera {id}: unknown camera model id {model_id}")))?;
        let width = c.u64("width")? as usize;
        let height = c.u64("height")? as usize;
        let params = (0..count).map(|_| c.f64("camera parameter")).collect::<Result<_>>()?;
        out.push(RawCamera { id, model, width, height, params, loc });
    }
    c.finish()?;
    Ok(out)
}

pub(crate) fn read_images(path: &Path) -> Result<Vec<RawImage>> {
    let mut c = Cursor::open(path)?;
    let n = c.count("image count", 4 + 56 + 4 + 1 + 8)?;
    let mut out = Vec::with_capacity(n);
    for index in 0..n {
        let loc = c.start("image", index);
        let id = c.u32("IMAGE_ID")?;
        let q_wxyz = c.f64s::<4>("quaternion")?;
        let t = c.f64s::<3>("translation")?;
        let camera_id = c.u32("CAMERA_ID")?;
        let mut name = Vec::new();
        loop {
            match c.u8("image name (NUL-terminated)")? {
                0 => break,
                b => name.push(b),
            }
        }
        let name = String::from_utf8(name).map_err(|_| loc.error(path, "image name is not UTF-8"))?;
        let n2d = c.count("2D point count", 24)?;
        let mut observed = Vec::new();
        for _ in 0..n2d {
            let _xy = c.f64s::<2>("2D point")?;
            let p = c.u64("POINT3D_ID")?;
            if p != u64::MAX {
                observed.push(p);
            }
        }
        out.push(RawImage { id, q_wxyz, t, camera_id, name, observed, loc });
    }
    c.finish()?;
    Ok(out)
}

pub(crate) fn read_points(path: &Path) -> Result<Vec<RawPoint>> {
    let mut c = Cursor::open(path)?;
    let n = c.count("point count", 8 + 24 + 3 + 8 + 8)?;
    let mut out = Vec::with_capacity(n);
    for index in 0..n {
        let loc = c.start("point", index);
        let id = c.u64("POINT3D_ID")?;
        let xyz = c.f64s::<3>("point coordinate")?;
        if xyz.iter().any(|v| !v.is_finite()) {
            return Err(loc.error(path, format!("point {id} has a non-finite coordinate {xyz:?}")));
        }
        for _ in 0..3 {
            c.u8("colour")?;
        }
        c.f64("reprojection error")?;
        let track = c.count("track length", 8)?;
        for _ in 0..track {
            c.u32("track IMAGE_ID")?;
            c.u32("track POINT2D_IDX")?;
        }
        out.push(RawPoint { id, xyz });
    }
    c.finish()?;
    Ok(out)
}
