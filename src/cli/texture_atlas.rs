//! `densefeat texture-atlas`: cut the photo-texture atlas of the realistic synthetic style
//! (`fixtures/textures/atlas.jpg`) from the frames of the TRAINING scenes.
//!
//! Selection is automatic and deterministic: from each source, 16 frames evenly spread over the
//! sequence; in each frame, among 128-pixel windows on a 16-pixel grid, the window that lies on one
//! surface (valid depth on at least 80 % of it, `(p95 - p5) / median` depth at most 0.3) with the
//! most texture (mean absolute grey gradient in 1.5..14), neither flat nor clipped. The chosen
//! windows are pasted into a grid of 8 columns (whole rows only) and written as JPEG; `crops.txt`
//! lists, per tile, the scene, frame and window.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use clap::Args;
use ndarray::{s, Array2, Array3};

use densefeat::error::{Error, Result};
use densefeat::image::{load_depth_png, load_rgb, to_gray};
use densefeat::io::write_atomic;
use densefeat::synth::{ATLAS_COLUMNS, ATLAS_TILE as TILE, TRAINING_SCENES};

/// Frames used per source sequence.
const FRAMES_PER_SOURCE: usize = 16;
/// Candidate window grid step, pixels.
const STRIDE: usize = 16;
/// Smallest fraction of a window with valid depth (HoloLens depth has holes).
const MIN_VALID_DEPTH: f64 = 0.8;
/// Largest `(p95 - p5) / median` of the depth inside a window: one surface, not an object edge.
const MAX_DEPTH_SPREAD: f32 = 0.3;
/// Accepted mean absolute grey gradient, grey levels per pixel: textured but not cluttered.
const GRADIENT_RANGE: (f64, f64) = (1.5, 14.0);
/// Largest fraction of clipped (`<= 4` or `>= 251`) grey values in a window.
const MAX_CLIPPED: f64 = 0.02;
/// JPEG quality of the atlas.
const ATLAS_QUALITY: u8 = 90;

/// Arguments of `densefeat texture-atlas`.
#[derive(Debug, Clone, Args)]
pub struct TextureAtlasArgs {
    /// Folder holding the training scenes (`hololens_000`, `tartanair_hospital`).
    #[arg(long, default_value = "../shared/data")]
    pub data: PathBuf,
    /// Output folder: writes `atlas.jpg` and `crops.txt`.
    #[arg(long, default_value = "fixtures/textures")]
    pub out: PathBuf,
}

/// One chosen window.
struct Crop {
    scene: &'static str,
    frame: String,
    x: usize,
    y: usize,
    gradient: f64,
    pixels: Array3<f32>,
}

/// The image files of a scene's `images/` folder, sorted.
fn frames(dir: &Path) -> Result<Vec<PathBuf>> {
    let images = dir.join("images");
    let mut out: Vec<PathBuf> = std::fs::read_dir(&images)
        .map_err(|e| Error::io(&images, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("png" | "jpg")))
        .collect();
    out.sort();
    Ok(out)
}

/// Mean absolute horizontal plus vertical grey difference and clipped fraction of a window.
fn texture_stats(grey: &Array2<f32>, x: usize, y: usize) -> (f64, f64) {
    let (mut g, mut clipped) = (0.0f64, 0usize);
    for j in y..y + TILE {
        for i in x..x + TILE {
            let v = grey[[j, i]];
            if v <= 4.0 || v >= 251.0 {
                clipped += 1;
            }
            if i + 1 < x + TILE && j + 1 < y + TILE {
                g += ((grey[[j, i + 1]] - v).abs() + (grey[[j + 1, i]] - v).abs()) as f64;
            }
        }
    }
    (g / ((TILE - 1) * (TILE - 1)) as f64, clipped as f64 / (TILE * TILE) as f64)
}

/// Whether the depth inside a window is valid everywhere and spans little relative to its median.
fn on_one_surface(depth: &Array2<f32>, x: usize, y: usize) -> bool {
    let mut z: Vec<f32> = depth
        .slice(s![y..y + TILE, x..x + TILE])
        .iter()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    if (z.len() as f64) < MIN_VALID_DEPTH * (TILE * TILE) as f64 {
        return false;
    }
    z.sort_by(f32::total_cmp);
    let q = |p: f64| z[((z.len() - 1) as f64 * p) as usize];
    (q(0.95) - q(0.05)) <= MAX_DEPTH_SPREAD * q(0.5)
}

/// The best window of one frame, if any passes.
fn best_window(scene: &'static str, image: &Path) -> Result<Option<Crop>> {
    let rgb = load_rgb(image)?;
    let stem = image.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
    let depth_path =
        image.parent().and_then(Path::parent).map(|d| d.join("depth").join(format!("{stem}.png")));
    let depth_path = depth_path.ok_or_else(|| Error::bad_file(image, "no parent folder"))?;
    let depth = load_depth_png(&depth_path, 1e-3, None)?;
    let grey = to_gray(&rgb);
    let (h, w) = grey.dim();
    let mut best: Option<(f64, usize, usize)> = None;
    for y in (0..h.saturating_sub(TILE) + 1).step_by(STRIDE) {
        for x in (0..w.saturating_sub(TILE) + 1).step_by(STRIDE) {
            let (g, clipped) = texture_stats(&grey, x, y);
            if !(GRADIENT_RANGE.0..=GRADIENT_RANGE.1).contains(&g) || clipped > MAX_CLIPPED {
                continue;
            }
            if best.is_some_and(|(bg, _, _)| bg >= g) || !on_one_surface(&depth, x, y) {
                continue;
            }
            best = Some((g, x, y));
        }
    }
    let file = image.file_name().and_then(|s| s.to_str()).unwrap_or_default().to_string();
    Ok(best.map(|(gradient, x, y)| Crop {
        scene,
        frame: file,
        x,
        y,
        gradient,
        pixels: rgb.slice(s![y..y + TILE, x..x + TILE, ..]).to_owned(),
    }))
}

/// Cut the atlas.
///
/// # Errors
/// [`Error::Io`] / [`Error::BadFile`] for unreadable frames; [`Error::InvalidArgument`] if too few
/// windows pass.
pub fn run(args: TextureAtlasArgs) -> Result<()> {
    let mut crops = Vec::new();
    for scene in TRAINING_SCENES {
        let list = frames(&args.data.join(scene))?;
        if list.is_empty() {
            return Err(Error::invalid_argument("--data", format!("no frames in {scene}/images")));
        }
        for k in 0..FRAMES_PER_SOURCE {
            let i = (2 * k + 1) * list.len() / (2 * FRAMES_PER_SOURCE);
            if let Some(c) = best_window(scene, &list[i])? {
                crops.push(c);
            }
        }
    }
    let rows = crops.len() / ATLAS_COLUMNS;
    if rows == 0 {
        return Err(Error::invalid_argument("--data", format!("only {} windows passed", crops.len())));
    }
    crops.truncate(rows * ATLAS_COLUMNS);
    let (aw, ah) = (ATLAS_COLUMNS * TILE, rows * TILE);
    let mut atlas = vec![0u8; aw * ah * 3];
    let mut listing = String::from("# tile scene frame x y size mean_abs_gradient\n");
    for (t, c) in crops.iter().enumerate() {
        let (ox, oy) = ((t % ATLAS_COLUMNS) * TILE, (t / ATLAS_COLUMNS) * TILE);
        for ((j, i, ch), &v) in c.pixels.indexed_iter() {
            atlas[((oy + j) * aw + ox + i) * 3 + ch] = v.round().clamp(0.0, 255.0) as u8;
        }
        let _ = writeln!(listing, "{t} {} {} {} {} {TILE} {:.2}", c.scene, c.frame, c.x, c.y, c.gradient);
    }
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, ATLAS_QUALITY)
        .encode(&atlas, aw as u32, ah as u32, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::invalid_argument("atlas", format!("JPEG encoding failed: {e}")))?;
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    write_atomic(&args.out.join("atlas.jpg"), &bytes)?;
    write_atomic(&args.out.join("crops.txt"), listing.as_bytes())?;
    eprintln!(
        "texture-atlas: {} tiles of {TILE}x{TILE} ({aw}x{ah}, {} bytes) written to {}",
        crops.len(),
        bytes.len(),
        args.out.display()
    );
    Ok(())
}
