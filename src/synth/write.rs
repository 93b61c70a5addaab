//! Writing a rendered sequence to disk in the DeepVideoMVS layout ([`DvmvsWriter`]): 8-bit PNG
//! colour, 16-bit PNG depth in millimetres, `poses.txt` (T_wc) and `K.txt`.

use std::path::Path;

use super::scene::Scene;
use super::SceneConfig;
use crate::error::Result;
use crate::sequence::DvmvsWriter;

/// Render every frame of `scene` into `dir`, calling `progress(done, total)` after each frame.
///
/// # Errors
/// [`crate::Error::Io`] if a file cannot be written.
pub fn write_scene(scene: &Scene, dir: &Path, mut progress: impl FnMut(usize, usize)) -> Result<()> {
    let mut writer = DvmvsWriter::create(dir, scene.camera())?;
    let n = scene.frames();
    for i in 0..n {
        let frame = scene.render(i)?;
        writer.push(&frame.rgb, &frame.depth, &frame.pose)?;
        progress(i + 1, n);
    }
    writer.finish()
}

/// Generate the scene `cfg` describes and write all its frames into `dir`, silently.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a bad config, [`crate::Error::Io`] on a write failure.
pub fn write_sequence(cfg: &SceneConfig, dir: &Path) -> Result<()> {
    let scene = Scene::generate(cfg)?;
    write_scene(&scene, dir, |_, _| {})
}
