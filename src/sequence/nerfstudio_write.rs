//! Writer for `transforms.json` sequences (nerfstudio layout), used by the round-trip tests:
//! `images/frame_00001.png`, optional `depth/frame_00001.png` (16-bit millimetres) and
//! `transforms.json` with OpenGL-axes camera-to-world matrices.

use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector4};
use serde_json::{json, Value};

use crate::error::{Error, Result};
use crate::geometry::{Camera, Pose};
use crate::image::{save_depth_png_mm, save_rgb_png, DepthMap, RgbImage};
use crate::io::write_atomic_with;

/// Writes frames one at a time, then `transforms.json` on [`NerfstudioWriter::finish`].
#[derive(Debug)]
pub struct NerfstudioWriter {
    dir: PathBuf,
    camera: Camera,
    per_frame_intrinsics: bool,
    frames: Vec<Value>,
}

impl NerfstudioWriter {
    /// Create `dir/images` and `dir/depth`. With `per_frame_intrinsics` every frame carries the
    /// intrinsics instead of the top level.
    ///
    /// # Errors
    /// [`Error::Io`] if a folder cannot be created.
    pub fn create(dir: &Path, camera: Camera, per_frame_intrinsics: bool) -> Result<Self> {
        for sub in ["images", "depth"] {
            let p = dir.join(sub);
            std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        }
        Ok(Self { dir: dir.to_path_buf(), camera, per_frame_intrinsics, frames: Vec::new() })
    }

    fn intrinsics(&self) -> serde_json::Map<String, Value> {
        let k = &self.camera.pinhole;
        let d = self.camera.distortion.unwrap_or_default();
        let v = json!({
            "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx + 0.5, "cy": k.cy + 0.5, "w": k.width, "h": k.height,
            "k1": d.k1, "k2": d.k2, "p1": d.p1, "p2": d.p2,
        });
        v.as_object().cloned().unwrap_or_default()
    }

    /// Append one frame; `depth` (metres) is written as a millimetre PNG when given.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn push(&mut self, rgb: &RgbImage, depth: Option<&DepthMap>, pose: &Pose) -> Result<()> {
        let name = format!("frame_{:05}.png", self.frames.len() + 1);
        save_rgb_png(&self.dir.join("images").join(&name), rgb)?;
        let gl = pose.to_homogeneous() * Matrix4::from_diagonal(&Vector4::new(1.0, -1.0, -1.0, 1.0));
        let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| gl[(r, c)]).collect()).collect();
        let mut f = serde_json::Map::new();
        f.insert("file_path".into(), json!(format!("images/{name}")));
        f.insert("transform_matrix".into(), json!(rows));
        if let Some(d) = depth {
            save_depth_png_mm(&self.dir.join("depth").join(&name), d)?;
            f.insert("depth_file_path".into(), json!(format!("depth/{name}")));
        }
        if self.per_frame_intrinsics {
            f.extend(self.intrinsics());
        }
        self.frames.push(Value::Object(f));
        Ok(())
    }

    /// Write `transforms.json`.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn finish(self) -> Result<()> {
        let mut top = if self.per_frame_intrinsics { serde_json::Map::new() } else { self.intrinsics() };
        top.insert("camera_model".into(), json!("OPENCV"));
        top.insert("frames".into(), Value::Array(self.frames));
        let text = serde_json::to_string_pretty(&Value::Object(top)).expect("JSON values serialise");
        write_atomic_with(&self.dir.join("transforms.json"), |w| w.write_all(text.as_bytes()))
    }
}
