//! Writer for the DeepVideoMVS / 7-Scenes layout, the one format every tool reads and the synthetic
//! renderer writes:
//!
//! ```text
//! DIR/images/00000.png   8-bit RGB
//! DIR/depth/00000.png    16-bit grey, millimetres, 0 = no depth
//! DIR/poses.txt          one line per frame: row-major 4x4 T_wc, 16 numbers, metres
//! DIR/K.txt              3x3 intrinsics, three lines
//! ```
//! Numbers are written with Rust's shortest round-trip formatting, so reading them back gives the
//! same `f64` bits.

use std::io::Write;
use std::path::Path;

use crate::error::{Error, Result};
use crate::geometry::{pose_to_matrix, PinholeCamera, Pose};
use crate::image::{save_depth_png_mm, save_rgb_png, DepthMap, RgbImage};
use crate::io::write_atomic_with;

/// Name of frame `i`'s image and depth files.
pub fn frame_file_name(i: usize) -> String {
    format!("{i:05}.png")
}

/// Writes frames one at a time into a DeepVideoMVS-layout folder, then `poses.txt` and `K.txt`
/// on [`DvmvsWriter::finish`].
#[derive(Debug)]
pub struct DvmvsWriter {
    dir: std::path::PathBuf,
    camera: PinholeCamera,
    poses: Vec<Pose>,
}

impl DvmvsWriter {
    /// Create `dir/images` and `dir/depth`.
    ///
    /// # Errors
    /// [`Error::Io`] if a folder cannot be created.
    pub fn create(dir: &Path, camera: PinholeCamera) -> Result<Self> {
        for sub in ["images", "depth"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
        Ok(Self { dir: dir.to_path_buf(), camera, poses: Vec::new() })
    }

    /// Append one frame (image and depth must match the camera's size).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] on a size mismatch; [`Error::Io`] on a write failure.
    pub fn push(&mut self, rgb: &RgbImage, depth: &DepthMap, pose: &Pose) -> Result<()> {
        let want = (self.camera.height, self.camera.width);
        if (rgb.dim().0, rgb.dim().1) != want || depth.dim() != want {
            return Err(Error::invalid_argument(
                "frame",
                format!(
                    "image {:?} / depth {:?} do not match the camera's {}x{}",
                    rgb.dim(),
                    depth.dim(),
                    want.1,
                    want.0
                ),
            ));
        }
        let name = frame_file_name(self.poses.len());
        save_rgb_png(&self.dir.join("images").join(&name), rgb)?;
        save_depth_png_mm(&self.dir.join("depth").join(&name), depth)?;
        self.poses.push(*pose);
        Ok(())
    }

    /// Write `poses.txt` and `K.txt`.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn finish(self) -> Result<()> {
        write_atomic_with(&self.dir.join("poses.txt"), |w| {
            for p in &self.poses {
                let m = pose_to_matrix(p);
                let row: Vec<String> = (0..16).map(|i| format!("{:e}", m[(i / 4, i % 4)])).collect();
                writeln!(w, "{}", row.join(" "))?;
            }
            Ok(())
        })?;
        let k = self.camera.k();
        write_atomic_with(&self.dir.join("K.txt"), |w| {
            for r in 0..3 {
                writeln!(w, "{:e} {:e} {:e}", k[(r, 0)], k[(r, 1)], k[(r, 2)])?;
            }
            Ok(())
        })
    }
}
