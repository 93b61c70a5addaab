//! The photo-texture atlas of the realistic style: square crops of the training scenes' frames
//! (`fixtures/textures/atlas.jpg`, made by `densefeat texture-atlas`, listed in
//! `fixtures/textures/crops.txt`), embedded in the binary and decoded once.
//!
//! A [`Texture::Photo`](super::Texture::Photo) samples one tile bilinearly with mirrored repeat (no
//! seams), normalised to the tile's mean colour so that brightness and tint are set by the texture,
//! not by the photograph's exposure.

use std::sync::OnceLock;

use super::{ATLAS_COLUMNS, ATLAS_TILE};
use crate::error::{Error, Result};

/// The atlas JPEG.
const ATLAS_JPEG: &[u8] = include_bytes!("../../fixtures/textures/atlas.jpg");
/// The atlas crop list (`tile scene frame x y size gradient` per line).
pub const ATLAS_CROPS: &str = include_str!("../../fixtures/textures/crops.txt");

/// The decoded atlas: tiles of `ATLAS_TILE²` RGB values in `[0, 1]`, each with its mean colour.
pub struct Atlas {
    /// Per tile, `ATLAS_TILE * ATLAS_TILE * 3` values, row-major.
    pub tiles: Vec<Vec<f32>>,
    /// Per tile, the mean of each channel.
    pub means: Vec<[f64; 3]>,
}

/// The atlas, decoded on first use, or why it could not be.
fn decoded() -> &'static std::result::Result<Atlas, String> {
    static ATLAS: OnceLock<std::result::Result<Atlas, String>> = OnceLock::new();
    ATLAS.get_or_init(|| {
        let img = image::load_from_memory_with_format(ATLAS_JPEG, image::ImageFormat::Jpeg)
            .map_err(|e| format!("embedded fixtures/textures/atlas.jpg does not decode: {e}"))?
            .to_rgb8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let raw = img.into_raw();
        let (cols, rows) = ((w / ATLAS_TILE).min(ATLAS_COLUMNS), h / ATLAS_TILE);
        let mut tiles = Vec::with_capacity(cols * rows);
        let mut means = Vec::with_capacity(cols * rows);
        for r in 0..rows {
            for c in 0..cols {
                let mut tile = Vec::with_capacity(ATLAS_TILE * ATLAS_TILE * 3);
                let mut sum = [0.0f64; 3];
                for y in 0..ATLAS_TILE {
                    let start = ((r * ATLAS_TILE + y) * w + c * ATLAS_TILE) * 3;
                    for (k, &v) in raw[start..start + ATLAS_TILE * 3].iter().enumerate() {
                        let v = v as f32 / 255.0;
                        sum[k % 3] += v as f64;
                        tile.push(v);
                    }
                }
                means.push(sum.map(|s| (s / (ATLAS_TILE * ATLAS_TILE) as f64).max(1e-3)));
                tiles.push(tile);
            }
        }
        if tiles.is_empty() {
            return Err(format!(
                "embedded fixtures/textures/atlas.jpg is {w}x{h}: no {ATLAS_TILE}-pixel tile"
            ));
        }
        Ok(Atlas { tiles, means })
    })
}

/// Check that the atlas decodes (the realistic style calls this before building a scene).
///
/// # Errors
/// [`Error::BadFile`] naming the atlas if it does not decode or holds no tile.
pub fn check() -> Result<()> {
    decoded()
        .as_ref()
        .map(|_| ())
        .map_err(|e| Error::bad_file(std::path::Path::new("fixtures/textures/atlas.jpg"), e.clone()))
}

/// A one-tile mid-grey atlas, the stand-in if the embedded one does not decode ([`check`] reports
/// that before any scene uses it).
fn fallback() -> &'static Atlas {
    static GREY: OnceLock<Atlas> = OnceLock::new();
    GREY.get_or_init(|| Atlas { tiles: vec![vec![0.5; ATLAS_TILE * ATLAS_TILE * 3]], means: vec![[0.5; 3]] })
}

/// The decoded atlas.
pub fn atlas() -> &'static Atlas {
    decoded().as_ref().unwrap_or_else(|_| fallback())
}

/// Number of tiles in the atlas.
pub fn tile_count() -> usize {
    atlas().tiles.len()
}

/// Mirrored-repeat coordinate: `x` in tile pixels folded into `[0, ATLAS_TILE - 1]`.
#[inline]
fn mirror(x: f64) -> f64 {
    let n = (ATLAS_TILE - 1) as f64;
    let period = 2.0 * n;
    let m = x - (x / period).floor() * period;
    if m > n {
        period - m
    } else {
        m
    }
}

/// Bilinear sample of tile `tile` at pixel coordinates `(x, y)` (mirrored repeat), RGB in `[0, 1]`.
#[inline]
pub fn sample(tile: usize, x: f64, y: f64) -> [f64; 3] {
    let a = atlas();
    let t = &a.tiles[tile % a.tiles.len()];
    let (x, y) = (mirror(x), mirror(y));
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(ATLAS_TILE - 1), (y0 + 1).min(ATLAS_TILE - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let at = |xx: usize, yy: usize, c: usize| t[(yy * ATLAS_TILE + xx) * 3 + c] as f64;
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let top = at(x0, y0, c) + (at(x1, y0, c) - at(x0, y0, c)) * fx;
        let bottom = at(x0, y1, c) + (at(x1, y1, c) - at(x0, y1, c)) * fx;
        *o = top + (bottom - top) * fy;
    }
    out
}

/// Mean colour of tile `tile`.
#[inline]
pub fn tile_mean(tile: usize) -> [f64; 3] {
    let a = atlas();
    a.means[tile % a.means.len()]
}
