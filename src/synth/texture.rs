//! Procedural albedo textures: analytic functions of a surface's `(u, v)` coordinates in metres,
//! returning linear RGB albedo in `[0, 1]`. No texture images, no state: a texture evaluated at the
//! same point always returns the same bits.
//!
//! The kinds span the range a matcher meets indoors, from rich to nearly textureless. Edges are
//! soft (a smoothstep a few millimetres to centimetres wide) so that the supersampled renderer does
//! not alias at typical viewing distances.

use super::noise::{fbm, smoothstep, value_noise};
use crate::util::rng::{hash_unit, SplitMix64};

/// Linear RGB albedo, each channel in `[0, 1]`.
pub type Albedo = [f64; 3];

/// Largest number of colours in a [`Texture::Collage`] palette.
pub const PALETTE_LEN: usize = 4;

/// Probability of the near-uniform kind where it is allowed.
const PLAIN_SHARE: f64 = 0.2;

/// Lowest albedo of a [`Texture::near_uniform`] colour: painted surfaces are light.
const PAINT_FLOOR: f64 = 0.45;

/// Half-width of soft stripe and checker edges, as a fraction of the period.
const EDGE_SOFTNESS: f64 = 0.15;

/// Half-width of collage shape edges, as a fraction of the cell.
const COLLAGE_EDGE: f64 = 0.02;

/// A procedural texture.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum Texture {
    /// Nearly textureless: a base colour, a faint linear gradient and very faint noise.
    Uniform {
        /// Colour at `(0, 0)`.
        colour: Albedo,
        /// Relative brightness change per metre along `u` and `v`.
        gradient: [f64; 2],
        /// Amplitude of the faint noise (relative brightness).
        grain: f64,
        /// Noise key.
        key: u64,
    },
    /// Fractal value noise blending two colours.
    Noise {
        /// Colour at noise value 0.
        a: Albedo,
        /// Colour at noise value 1.
        b: Albedo,
        /// Lattice spacing of the coarsest octave, metres.
        scale: f64,
        /// Number of octaves.
        octaves: u32,
        /// Noise key.
        key: u64,
    },
    /// Soft parallel stripes.
    Stripes {
        /// First colour.
        a: Albedo,
        /// Second colour.
        b: Albedo,
        /// Stripe period, metres.
        period: f64,
        /// Unit direction across the stripes, in `(u, v)`.
        direction: [f64; 2],
    },
    /// A soft checkerboard.
    Checker {
        /// First colour.
        a: Albedo,
        /// Second colour.
        b: Albedo,
        /// Square size, metres.
        period: f64,
    },
    /// An "image patch" collage: discs and rectangles of palette colours on a mottled background,
    /// placed per square cell by hashing the cell index.
    Collage {
        /// Background colour.
        background: Albedo,
        /// Shape colours.
        palette: [Albedo; PALETTE_LEN],
        /// Cell size, metres.
        cell: f64,
        /// Hash key.
        key: u64,
    },
    /// Painted plaster (realistic style): a colour with a faint linear gradient, a faint blotchy
    /// low-frequency variation (metre scale) and a fine grain (centimetre scale).
    Paint {
        /// Colour at `(0, 0)`.
        colour: Albedo,
        /// Relative brightness change per metre along `u` and `v`.
        gradient: [f64; 2],
        /// Amplitude of the blotchy variation (relative brightness).
        blotch: f64,
        /// Amplitude of the fine grain (relative brightness).
        grain: f64,
        /// Noise key.
        key: u64,
    },
    /// A crop of a real photograph from the embedded atlas (`fixtures/textures/atlas.jpg`),
    /// repeated (mirrored, or as floor tiles), with its mean colour replaced by `colour` and its
    /// contrast scaled, plus a faint blotchy variation that hides the repetition.
    Photo {
        /// Atlas tile.
        tile: usize,
        /// Side of one tile on the surface, metres.
        size: f64,
        /// Offset into the tile, tile pixels.
        offset: [f64; 2],
        /// Swap the tile's axes (a 90-degree turn and a mirror).
        swap: bool,
        /// Lay the tile as floor tiles: each tile-sized cell gets its own hashed flips and a
        /// slight brightness change (instead of one mirrored repeat).
        cells: bool,
        /// Mean colour.
        colour: Albedo,
        /// Contrast factor applied to the tile's deviation from its mean.
        contrast: f64,
        /// Noise key of the blotchy variation.
        key: u64,
    },
}

/// Amplitude of the blotchy variation laid over photo textures (relative brightness).
const PHOTO_BLOTCH: f64 = 0.12;
/// Relative brightness spread between the cells of a tiled photo texture.
const CELL_BRIGHTNESS: f64 = 0.12;
/// Lattice spacing of the blotchy variations, metres.
const BLOTCH_SCALE: f64 = 0.9;
/// Lattice spacing of the paint grain, metres.
const GRAIN_SCALE: f64 = 0.02;

#[inline]
fn mix(a: &Albedo, b: &Albedo, t: f64) -> Albedo {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

#[inline]
fn scale(a: &Albedo, s: f64) -> Albedo {
    [(a[0] * s).clamp(0.0, 1.0), (a[1] * s).clamp(0.0, 1.0), (a[2] * s).clamp(0.0, 1.0)]
}

/// A soft square wave in `[0, 1]` with period 1: 0 on `[0, ½)`, 1 on `[½, 1)`, with smooth edges of
/// half-width [`EDGE_SOFTNESS`] centred on `½` and on the integers.
#[inline]
fn soft_square(x: f64) -> f64 {
    let f = x - x.floor();
    let e = EDGE_SOFTNESS;
    smoothstep(0.5 - e, 0.5 + e, f) * (1.0 - smoothstep(1.0 - e, 1.0 + e, f)) + (1.0 - smoothstep(-e, e, f))
}

impl Texture {
    /// Albedo at surface coordinates `(u, v)`, metres.
    pub fn eval(&self, u: f64, v: f64) -> Albedo {
        match self {
            Texture::Uniform { colour, gradient, grain, key } => {
                let g = 1.0 + gradient[0] * u + gradient[1] * v;
                let n = grain * (value_noise(*key, u * 4.0, v * 4.0) - 0.5);
                scale(colour, g + n)
            }
            Texture::Noise { a, b, scale: s, octaves, key } => {
                let t = fbm(*key, u / s, v / s, *octaves);
                // Stretch the (centre-heavy) fbm distribution to use the whole colour range.
                mix(a, b, smoothstep(0.2, 0.8, t))
            }
            Texture::Stripes { a, b, period, direction } => {
                let x = (u * direction[0] + v * direction[1]) / period;
                mix(a, b, soft_square(x))
            }
            Texture::Checker { a, b, period } => {
                let (sx, sy) = (soft_square(u / period), soft_square(v / period));
                mix(a, b, sx + sy - 2.0 * sx * sy)
            }
            Texture::Collage { background, palette, cell, key } => {
                collage(background, palette, *cell, *key, u, v)
            }
            Texture::Paint { colour, gradient, blotch, grain, key } => {
                let g = 1.0 + gradient[0] * u + gradient[1] * v;
                let b = blotch * (fbm(*key, u / BLOTCH_SCALE, v / BLOTCH_SCALE, 2) - 0.5);
                let n = grain * (value_noise(*key ^ 0x6EA1, u / GRAIN_SCALE, v / GRAIN_SCALE) - 0.5);
                scale(colour, g + b + n)
            }
            Texture::Photo { tile, size, offset, swap, cells, colour, contrast, key } => {
                let t = super::ATLAS_TILE as f64;
                let px = t / size;
                let (mut x, mut y) = (u * px + offset[0], v * px + offset[1]);
                let mut b = 1.0 + PHOTO_BLOTCH * (fbm(*key, u / BLOTCH_SCALE, v / BLOTCH_SCALE, 2) - 0.5);
                if *cells {
                    let (ci, cj) = ((x / t).floor(), (y / t).floor());
                    let h = crate::util::rng::hash64(*key, ci as i64 as u64, cj as i64 as u64, 7);
                    (x, y) = (x - ci * t, y - cj * t);
                    if h & 1 == 1 {
                        x = t - 1.0 - x;
                    }
                    if h & 2 == 2 {
                        y = t - 1.0 - y;
                    }
                    b *= 1.0 + CELL_BRIGHTNESS * (((h >> 11) as f64 / (1u64 << 53) as f64) - 0.5);
                }
                let (x, y) = if *swap { (y, x) } else { (x, y) };
                let s = super::atlas::sample(*tile, x, y);
                let mean = super::atlas::tile_mean(*tile);
                [0, 1, 2].map(|c| (colour[c] * b * (1.0 + contrast * (s[c] / mean[c] - 1.0))).clamp(0.0, 1.0))
            }
        }
    }

    /// A random near-uniform texture in a light colour (a painted wall or ceiling).
    pub fn near_uniform(rng: &mut SplitMix64) -> Self {
        let key = rng.next_u64();
        let base = random_colour(rng).map(|c| PAINT_FLOOR + (1.0 - PAINT_FLOOR) * c);
        Self::near_uniform_with(rng, base, key)
    }

    fn near_uniform_with(rng: &mut SplitMix64, colour: Albedo, key: u64) -> Self {
        let gradient = [rng.range(-0.08, 0.08), rng.range(-0.08, 0.08)];
        Texture::Uniform { colour, gradient, grain: rng.range(0.005, 0.02), key }
    }

    /// A random texture. The kind is drawn with weights favouring textured surfaces;
    /// `allow_plain` = `false` excludes the near-uniform kind. `size` scales every spatial period
    /// (1 for objects; larger for walls, which are seen from further away).
    pub fn random(rng: &mut SplitMix64, allow_plain: bool, size: f64) -> Self {
        let key = rng.next_u64();
        let base = random_colour(rng);
        let other = contrasting(rng, &base);
        // Kinds by cumulative probability: near-uniform, noise, collage, stripes, checker.
        let lo = if allow_plain { 0.0 } else { PLAIN_SHARE };
        let roll = lo + (1.0 - lo) * rng.unit();
        if roll < PLAIN_SHARE {
            Self::near_uniform_with(rng, base, key)
        } else if roll < 0.5 {
            Texture::Noise { a: base, b: other, scale: size * rng.range(0.08, 0.35), octaves: 3, key }
        } else if roll < 0.7 {
            Texture::Collage {
                background: base,
                palette: [(); PALETTE_LEN].map(|_| random_colour(rng)),
                cell: size * rng.range(0.15, 0.35),
                key,
            }
        } else if roll < 0.85 {
            let angle = rng.range(0.0, std::f64::consts::PI);
            Texture::Stripes {
                a: base,
                b: other,
                period: size * rng.range(0.06, 0.25),
                direction: [super::detmath::cos(angle), super::detmath::sin(angle)],
            }
        } else {
            Texture::Checker { a: base, b: other, period: size * rng.range(0.08, 0.3) }
        }
    }
}

/// A random painted surface of brightness `lo..hi` with a faint tint (walls, ceilings, doors).
pub fn paint(rng: &mut SplitMix64, lo: f64, hi: f64) -> Texture {
    let key = rng.next_u64();
    let grey = rng.range(lo, hi);
    let tint = rng.range(0.0, 0.08);
    let colour = [0; 3].map(|_| (grey * (1.0 + tint * rng.range(-1.0, 1.0))).clamp(0.0, 1.0));
    Texture::Paint {
        colour,
        gradient: [rng.range(-0.05, 0.05), rng.range(-0.05, 0.05)],
        blotch: rng.range(0.02, 0.06),
        grain: rng.range(0.01, 0.03),
        key,
    }
}

/// A random photo texture with tiles `size_lo..size_hi` metres wide: a random atlas tile, its own
/// colour jittered in brightness (x0.7-1.3) and per channel (±12 %), contrast x0.7-1.2. `cells`:
/// laid as floor tiles; otherwise offset by at most a quarter tile, so that surfaces up to ¾ of
/// the tile size show no mirrored repeat.
pub fn photo(rng: &mut SplitMix64, size_lo: f64, size_hi: f64, cells: bool) -> Texture {
    let key = rng.next_u64();
    let tile = rng.below(super::atlas::tile_count());
    let mean = super::atlas::tile_mean(tile);
    let brightness = rng.range(0.7, 1.3);
    let colour = [0, 1, 2].map(|c| (mean[c] * brightness * rng.range(0.88, 1.12)).clamp(0.03, 0.95));
    let t = super::ATLAS_TILE as f64;
    Texture::Photo {
        tile,
        size: rng.range(size_lo, size_hi),
        offset: [rng.range(0.0, 0.25 * t), rng.range(0.0, 0.25 * t)],
        swap: rng.chance(0.5),
        cells,
        colour,
        contrast: rng.range(0.7, 1.2),
        key,
    }
}

/// A random albedo: a grey level with a random tint, every channel in `[0.08, 0.92]`.
pub fn random_colour(rng: &mut SplitMix64) -> Albedo {
    let grey = rng.range(0.2, 0.8);
    let tint = rng.range(0.0, 0.3);
    [0; 3].map(|_| (grey + tint * rng.range(-1.0, 1.0)).clamp(0.08, 0.92))
}

/// A random colour at least 0.25 away from `base` in mean brightness.
fn contrasting(rng: &mut SplitMix64, base: &Albedo) -> Albedo {
    let c = random_colour(rng);
    let (mb, mc) = ((base[0] + base[1] + base[2]) / 3.0, (c[0] + c[1] + c[2]) / 3.0);
    if (mb - mc).abs() >= 0.25 {
        return c;
    }
    let shift = if mb > 0.5 { -0.35 } else { 0.35 };
    c.map(|x| (x + shift).clamp(0.05, 0.95))
}

/// [`Texture::Collage`]: two shapes per cell, fully inside the cell so only the own cell is read.
fn collage(
    background: &Albedo,
    palette: &[Albedo; PALETTE_LEN],
    cell: f64,
    key: u64,
    u: f64,
    v: f64,
) -> Albedo {
    let (x, y) = (u / cell, v / cell);
    let (fx, fy) = (x.floor(), y.floor());
    let (i, j) = (fx as i64 as u64, fy as i64 as u64);
    let (lx, ly) = (x - fx, y - fy);
    let mottle = 0.85 + 0.3 * value_noise(key ^ 0xC011, u * 3.0, v * 3.0);
    let mut colour = scale(background, mottle);
    for shape in 0..2u64 {
        let h = |k: u64| hash_unit(key, i, j, shape * 8 + k);
        let (cx, cy) = (0.3 + 0.4 * h(0), 0.3 + 0.4 * h(1));
        let (rx, ry) = (0.08 + 0.2 * h(2), 0.08 + 0.2 * h(3));
        let c = &palette[(h(4) * PALETTE_LEN as f64) as usize % PALETTE_LEN];
        let inside = if h(5) < 0.5 {
            // Disc (an ellipse in cell units); the edge is soft over COLLAGE_EDGE.
            let (ex, ey) = ((lx - cx) / rx, (ly - cy) / ry);
            let r = (ex * ex + ey * ey).sqrt();
            1.0 - smoothstep(1.0 - COLLAGE_EDGE / rx.min(ry), 1.0, r)
        } else {
            let dx = rx - (lx - cx).abs();
            let dy = ry - (ly - cy).abs();
            smoothstep(-COLLAGE_EDGE, COLLAGE_EDGE, dx.min(dy))
        };
        colour = mix(&colour, c, inside);
    }
    colour
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_stays_in_unit_range() {
        let mut rng = SplitMix64::new(3);
        for _ in 0..200 {
            let t = Texture::random(&mut rng, true, 1.0);
            for k in 0..50 {
                let (u, v) = (k as f64 * 0.173 - 4.0, k as f64 * -0.091 + 2.0);
                for c in t.eval(u, v) {
                    assert!((0.0..=1.0).contains(&c), "{t:?} at ({u}, {v}) gave {c}");
                }
            }
        }
    }
}
