//! Writer for the native 7-Scenes layout, used by the round-trip tests: per frame
//! `frame-XXXXXX.color.png`, `frame-XXXXXX.depth.png` (16-bit millimetres, 65535 = invalid, in the
//! depth camera) and `frame-XXXXXX.pose.txt` (4x4 `T_wc`, four lines).

use std::io::Write;
use std::path::{Path, PathBuf};

use ndarray::Array2;

use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::image::{save_rgb_png, DepthMap, RgbImage};
use crate::io::write_atomic_with;

/// Writes 7-Scenes frames into one `seq-XX` folder.
#[derive(Debug)]
pub struct SevenScenesWriter {
    dir: PathBuf,
    next: usize,
}

impl SevenScenesWriter {
    /// Create `dir`.
    ///
    /// # Errors
    /// [`Error::Io`] if it cannot be created.
    pub fn create(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        Ok(Self { dir: dir.to_path_buf(), next: 0 })
    }

    /// Append a frame: colour, depth-camera depth (metres; invalid written as 65535) and `T_wc`.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn push(&mut self, rgb: &RgbImage, depth: &DepthMap, pose: &Pose) -> Result<()> {
        let stem = format!("frame-{:06}", self.next);
        save_rgb_png(&self.dir.join(format!("{stem}.color.png")), rgb)?;
        let mm: Array2<u16> = depth.mapv(|z| {
            if crate::image::is_valid_depth(z) {
                (f64::from(z) * 1e3).round().clamp(1.0, 65534.0) as u16
            } else {
                u16::MAX
            }
        });
        let (h, w) = mm.dim();
        let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
            w as u32,
            h as u32,
            mm.into_raw_vec_and_offset().0,
        )
        .expect("buffer has w * h values");
        let path = self.dir.join(format!("{stem}.depth.png"));
        img.save(&path).map_err(|e| Error::bad_file(&path, format!("cannot write depth PNG: {e}")))?;
        let m = pose.to_homogeneous();
        write_atomic_with(&self.dir.join(format!("{stem}.pose.txt")), |f| {
            for r in 0..4 {
                writeln!(f, "{:e}\t{:e}\t{:e}\t{:e}", m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)])?;
            }
            Ok(())
        })?;
        self.next += 1;
        Ok(())
    }
}
