//! Training data (SPEC.md §13.5): reference/live pairs chosen by baseline, rotation and view
//! overlap, from posed RGB-D sequences (a held-out tail of each for validation) and from the
//! synthetic renderer on the fly; random crops (the live crop follows the reference crop's mean
//! flow) and independent photometric augmentation of each frame.
//!
//! Every random choice of training step `t` comes from a generator seeded with
//! `hash(seed, t, i)` (`i` the pair's index in the batch), so a step's data do not depend on what
//! came before: resuming at step `t` sees exactly what an uninterrupted run would.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndarray::{s, Array2, Array3, ArrayView2};

use crate::error::{Error, Result};
use crate::geometry::{relative_pose, PinholeCamera, Pose, Warp};
use crate::image::is_valid_depth;
use crate::sequence::{open, Sequence};
use crate::synth::{Scene, SceneConfig, Style};
use crate::train::frame_cache::{Frame, FrameCache, FrameKey};
use crate::train::occlusion::mask_occluded;
use crate::train::step::{ExtraLive, TrainingPair};
use crate::util::rng::{hash64, SplitMix64};

/// Which frame pairs are used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairRule {
    /// Smallest camera-centre distance, metres.
    pub min_baseline: f64,
    /// Largest camera-centre distance, metres.
    pub max_baseline: f64,
    /// Largest relative rotation, degrees.
    pub max_rotation_deg: f64,
    /// Smallest fraction of the reference's valid-depth pixels that land inside the live image.
    pub min_overlap: f64,
}

impl Default for PairRule {
    fn default() -> Self {
        PairRule { min_baseline: 0.05, max_baseline: 0.5, max_rotation_deg: 30.0, min_overlap: 0.6 }
    }
}

/// Photometric augmentation, drawn independently for each frame (SPEC.md §13.5):
/// `clamp(g · T(I) + b + n, 0, 255)`, where `T` is the optional sensor part (a motion blur, then a
/// gamma curve; off by default) and `g`, `b`, `n` the gain, offset and noise.
#[derive(Clone, Copy, PartialEq)]
pub struct Augment {
    /// `g` uniform in `[1 - gain, 1 + gain]`.
    pub gain: f64,
    /// `b` uniform in `[-bias, bias]` (0-255 scale).
    pub bias: f64,
    /// Per-value noise, uniform in `[-noise, noise] · √3` (standard deviation `noise`).
    pub noise: f64,
    /// Longest linear motion blur, pixels: length uniform in `[0, blur]`, direction uniform; 0: off.
    pub blur: f64,
    /// Gamma curve `255 (I/255)^γ` with `ln γ` uniform in `[-gamma, gamma]`; 0: off.
    pub gamma: f64,
}

impl Default for Augment {
    fn default() -> Self {
        Augment { gain: 0.2, bias: 15.0, noise: 2.0, blur: 0.0, gamma: 0.0 }
    }
}

// Written by hand so that the sensor part appears only when it is on: the checkpoint fingerprint
// (SPEC.md §13.6) holds this text, and runs from before 2026-12-07 must stay resumable.
impl std::fmt::Debug for Augment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Augment");
        d.field("gain", &self.gain).field("bias", &self.bias).field("noise", &self.noise);
        if self.blur != 0.0 {
            d.field("blur", &self.blur);
        }
        if self.gamma != 0.0 {
            d.field("gamma", &self.gamma);
        }
        d.finish()
    }
}

/// Data settings.
#[derive(Clone, Debug, PartialEq)]
pub struct DataConfig {
    /// Crop `(width, height)`.
    pub crop: (usize, usize),
    /// Pair rule.
    pub rule: PairRule,
    /// Augmentation of training pairs (validation pairs are not augmented).
    pub augment: Augment,
    /// Posed RGB-D sequences to train on (training scenes, SPEC §3a).
    pub sequences: Vec<PathBuf>,
    /// Posed RGB-D sequences used only for validation (validation scenes, SPEC §3a): every frame
    /// gives validation pairs, none is trained on.
    pub val_sequences: Vec<PathBuf>,
    /// Synthetic training scenes (seeds `SYNTH_TRAIN_SEED0 ..`); 0 for none.
    pub synthetic_scenes: usize,
    /// Synthetic validation scenes (seeds `SYNTH_VAL_SEED0 ..`).
    pub synthetic_val_scenes: usize,
    /// Probability that a training pair is synthetic when sequences are given too.
    pub synthetic_fraction: f64,
    /// Renderer style of the synthetic scenes (SPEC.md §4b, §13.5).
    pub synthetic_style: SyntheticStyles,
    /// Fraction of each training sequence's frames, at its end, held out for validation (0 under
    /// the scene-level protocol of SPEC §3a, where validation comes from `val_sequences`).
    pub val_fraction: f64,
    /// Live frames per training reference (1: pairs, the paper; more: the multi-frame loss of
    /// SPEC.md §13.1b). Validation pairs always have one.
    pub live_frames: usize,
    /// Where each live crop is cut (SPEC.md §13.5): at the reference window shifted by the mean
    /// flow, or at the reference window itself, as the mapper sees full frames.
    pub live_crop: LiveCrop,
    /// Occlusion masking of the loss (`--occlusion-mask`, SPEC.md §13.1c): a reference pixel whose
    /// true match is hidden behind a nearer surface in any live frame, by more than this fraction
    /// of its depth, is left out of the loss. 0: off (the paper, every run before 2026-12-06).
    pub occlusion_tolerance: f64,
}

/// Where the live crops are cut (`--live-crop flow | same`, SPEC.md §13.5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LiveCrop {
    /// The reference window shifted by the mean image displacement of its valid pixels, so the
    /// live crop sees the same surfaces (every run before 2026-12-05).
    #[default]
    Flow,
    /// The reference window's own image coordinates (clamped inside the live frame), as the mapper
    /// compares full frames: a feature that encodes the position in the image (the network's zero
    /// padding makes one) then favours the same pixel, i.e. far depth, in training as at run time,
    /// and the loss can penalise it.
    Same,
}

impl std::str::FromStr for LiveCrop {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "flow" => Ok(LiveCrop::Flow),
            "same" => Ok(LiveCrop::Same),
            _ => Err(Error::invalid_argument("--live-crop", format!("{s:?}: expected flow or same"))),
        }
    }
}

/// With `LiveCrop::Same`, the reference window is redrawn (up to this many times) until at least
/// `SAME_MIN_OVERLAP` of its valid pixels match inside every live window.
const SAME_WINDOW_DRAWS: usize = 8;
/// See `SAME_WINDOW_DRAWS`.
const SAME_MIN_OVERLAP: f64 = 0.5;

/// First seed of the synthetic training scenes (the shipped fixture and the evaluation scenes
/// use seeds below 1000, so training never sees them).
pub const SYNTH_TRAIN_SEED0: u64 = 100_000;
/// First seed of the synthetic validation scenes.
pub const SYNTH_VAL_SEED0: u64 = 200_000;
/// Frames of a synthetic scene.
const SYNTH_FRAMES: usize = 60;
/// Attempts at finding a pair that passes the overlap rule before giving up on a draw.
const ATTEMPTS: usize = 16;
/// Grid step (pixels) of the overlap and flow estimates.
const GRID: usize = 4;

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig {
            crop: (256, 192),
            rule: PairRule::default(),
            augment: Augment::default(),
            sequences: Vec::new(),
            val_sequences: Vec::new(),
            synthetic_scenes: 64,
            synthetic_val_scenes: 4,
            synthetic_fraction: 0.5,
            synthetic_style: SyntheticStyles::One(Style::Classic),
            val_fraction: 0.2,
            live_frames: 1,
            live_crop: LiveCrop::Flow,
            occlusion_tolerance: 0.0,
        }
    }
}

/// The renderer styles of the synthetic scenes (`--synthetic-style classic | real | mixed`,
/// SPEC.md §13.5): one style for every scene, or both, by seed parity (even seeds classic, odd
/// seeds realistic), so a mix is a pure function of the seed and resume stays exact.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum SyntheticStyles {
    /// Every scene in this style.
    One(Style),
    /// Even seeds classic, odd seeds realistic.
    Mixed,
}

impl SyntheticStyles {
    /// The style of scene `seed`.
    pub fn of(self, seed: u64) -> Style {
        match self {
            SyntheticStyles::One(s) => s,
            SyntheticStyles::Mixed if seed.is_multiple_of(2) => Style::Classic,
            SyntheticStyles::Mixed => Style::Real,
        }
    }
}

// Written as `Classic`, `Real` or `Mixed`: the checkpoint fingerprint (SPEC.md §13.6) holds the data
// settings' Debug text, and runs made when this field was a plain `Style` must stay resumable.
impl std::fmt::Debug for SyntheticStyles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SyntheticStyles::One(s) => write!(f, "{s:?}"),
            SyntheticStyles::Mixed => f.write_str("Mixed"),
        }
    }
}

impl std::fmt::Display for SyntheticStyles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SyntheticStyles::One(s) => write!(f, "{s}"),
            SyntheticStyles::Mixed => f.write_str("mixed: even seeds classic, odd seeds real"),
        }
    }
}

impl std::str::FromStr for SyntheticStyles {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "mixed" => Ok(SyntheticStyles::Mixed),
            _ => s.parse::<Style>().map(SyntheticStyles::One).map_err(|_| {
                Error::invalid_argument(
                    "--synthetic-style",
                    format!("{s:?}: expected classic, real or mixed"),
                )
            }),
        }
    }
}

/// A sequence with its train and validation pairs.
struct SequenceSource {
    name: String,
    seq: Sequence,
    /// First validation frame.
    split: usize,
    train: Vec<(usize, usize)>,
    val: Vec<(usize, usize)>,
}

/// A reference frame, its live frames and their camera.
type FrameTuple = (Arc<Frame>, Vec<Arc<Frame>>);

/// `count` distinct entries of `candidates` that pass `accept`, drawn uniformly in turn (each draw
/// removes its entry); `None` when the candidates run out first.
fn draw_distinct(
    candidates: &[usize],
    count: usize,
    rng: &mut SplitMix64,
    accept: impl Fn(usize) -> bool,
) -> Option<Vec<usize>> {
    let mut left = candidates.to_vec();
    let mut picked = Vec::with_capacity(count);
    while picked.len() < count {
        if left.is_empty() {
            return None;
        }
        let c = left.swap_remove(rng.below(left.len()));
        if accept(c) {
            picked.push(c);
        }
    }
    Some(picked)
}

/// The training and validation data.
pub struct DataSet {
    cfg: DataConfig,
    /// The synthetic scenes' frames and size; each scene sets its own seed and style
    /// ([`SyntheticStyles::of`]) when it is generated.
    synth: SceneConfig,
    sequences: Vec<SequenceSource>,
    cache: FrameCache,
}

/// Default byte budget of the frame cache ([`DataSet::with_cache_mb`]).
pub const DEFAULT_CACHE_MB: usize = 4096;

/// Relative rotation angle of two poses, degrees, and their camera-centre distance.
fn motion(a: &Pose, b: &Pose) -> (f64, f64) {
    let rel = relative_pose(a, b);
    (rel.rotation.angle().to_degrees(), (a.translation.vector - b.translation.vector).norm())
}

fn passes_pose_rule(rule: &PairRule, a: &Pose, b: &Pose) -> bool {
    let (rot, base) = motion(a, b);
    rot <= rule.max_rotation_deg && base >= rule.min_baseline && base <= rule.max_baseline
}

/// Fraction of valid-depth grid pixels of the reference (within `window` = `(x0, y0, w, h)`) that
/// land inside the live camera, and their mean displacement.
fn overlap_and_flow(
    depth: &Array2<f32>,
    (cam, live): (&PinholeCamera, &PinholeCamera),
    t_lr: &Pose,
    window: (usize, usize, usize, usize),
) -> (f64, f64, f64) {
    overlap_and_flow_in(depth, (cam, live), t_lr, window, (0, 0, live.width, live.height))
}

/// `overlap_and_flow` with the live side restricted to the pixel rectangle `live_window`
/// `(x0, y0, w, h)` (inside the live frame): a match counts as inside when it lies in
/// `[x0, x0 + w - 1] x [y0, y0 + h - 1]`; for the whole frame that is `PinholeCamera::contains`.
fn overlap_and_flow_in(
    depth: &Array2<f32>,
    (cam, live): (&PinholeCamera, &PinholeCamera),
    t_lr: &Pose,
    window: (usize, usize, usize, usize),
    live_window: (usize, usize, usize, usize),
) -> (f64, f64, f64) {
    let warp = Warp::new(cam, live, t_lr);
    let (x0, y0, w, h) = window;
    let (lx0, ly0, lw, lh) = live_window;
    let (lx0, ly0) = (lx0 as f64, ly0 as f64);
    let (lx1, ly1) = (lx0 + lw as f64 - 1.0, ly0 + lh as f64 - 1.0);
    let (mut n, mut inside, mut du, mut dv) = (0usize, 0usize, 0.0, 0.0);
    for y in (y0..y0 + h).step_by(GRID) {
        for x in (x0..x0 + w).step_by(GRID) {
            let z = depth[[y, x]];
            if !is_valid_depth(z) {
                continue;
            }
            n += 1;
            if let Some(p) = warp.apply(x as f64, y as f64, 1.0 / f64::from(z)) {
                let (u, v) = (p.uv.x, p.uv.y);
                if (lx0..=lx1).contains(&u) && (ly0..=ly1).contains(&v) {
                    inside += 1;
                    du += p.uv.x - x as f64;
                    dv += p.uv.y - y as f64;
                }
            }
        }
    }
    if inside == 0 {
        return (0.0, 0.0, 0.0);
    }
    (inside as f64 / n as f64, du / inside as f64, dv / inside as f64)
}

/// Frame `i` of a synthetic scene.
fn render(scene: &Scene, i: usize) -> Result<Frame> {
    let f = scene.render(i)?;
    Ok(Frame::new(f.rgb, f.depth, f.pose, scene.camera()))
}

/// `clamp(g T(I) + b + n, 0, 255)` with `g`, `b` drawn once and `n` per value; `T` the motion blur
/// and the gamma curve when they are on (each drawn first, only when on: with both off the draws
/// are the same as before they existed).
fn augment(img: &mut Array3<f32>, a: &Augment, rng: &mut SplitMix64) {
    if a.blur > 0.0 {
        let length = rng.range(0.0, a.blur);
        let angle = rng.range(0.0, std::f64::consts::PI);
        motion_blur(img, length, angle);
    }
    if a.gamma > 0.0 {
        let gamma = rng.range(-a.gamma, a.gamma).exp();
        for v in img.iter_mut() {
            *v = (255.0 * (f64::from(v.clamp(0.0, 255.0)) / 255.0).powf(gamma)) as f32;
        }
    }
    let g = rng.range(1.0 - a.gain, 1.0 + a.gain) as f32;
    let b = rng.range(-a.bias, a.bias) as f32;
    let amp = (a.noise * 3f64.sqrt()) as f32;
    for v in img.iter_mut() {
        let n = if amp > 0.0 { amp * (2.0 * rng.unit() as f32 - 1.0) } else { 0.0 };
        *v = (g * *v + b + n).clamp(0.0, 255.0);
    }
}

/// A linear motion blur of `length` pixels at `angle` (radians from the x axis), centred on each
/// pixel: the mean of `n = ⌈length⌉ + 1` bilinear samples at offsets `(i/(n-1) - 1/2) · length ·
/// (cos, sin)`, `i = 0..n`, the image extended by its edge values (SPEC.md §13.5). Below 0.5 pixel
/// it does nothing.
pub fn motion_blur(img: &mut Array3<f32>, length: f64, angle: f64) {
    if length < 0.5 {
        return;
    }
    let (h, w, c) = img.dim();
    let n = length.ceil() as usize + 1;
    let (dx, dy) = (angle.cos() * length, angle.sin() * length);
    let src = img.as_standard_layout().into_owned();
    let src = src.as_slice().expect("standard layout is contiguous");
    // Every sample of the line is the same bilinear blend of four shifted copies of the image, so
    // the blur is a sum of 4n shifted copies, each added whole (the order: offsets ascending, then
    // the corners top-left, top-right, bottom-left, bottom-right).
    let mut acc = vec![0.0f64; h * w * c];
    let clamp = |v: isize, len: usize| v.clamp(0, len as isize - 1) as usize;
    for i in 0..n {
        let t = i as f64 / (n - 1) as f64 - 0.5;
        let (ox, oy) = (t * dx, t * dy);
        let (x0, y0) = (ox.floor(), oy.floor());
        let (fx, fy) = (ox - x0, oy - y0);
        let (x0, y0) = (x0 as isize, y0 as isize);
        // The source columns of the two column shifts, made once per sample.
        let cols = [x0, x0 + 1].map(|sx| (0..w).map(|x| clamp(x as isize + sx, w)).collect::<Vec<_>>());
        for (sy, wy) in [(y0, 1.0 - fy), (y0 + 1, fy)] {
            for (cols, wx) in cols.iter().zip([1.0 - fx, fx]) {
                let weight = wy * wx / n as f64;
                if weight == 0.0 {
                    continue;
                }
                for y in 0..h {
                    let row = &src[clamp(y as isize + sy, h) * w * c..][..w * c];
                    let out = &mut acc[y * w * c..][..w * c];
                    for (x, &col) in cols.iter().enumerate() {
                        for ch in 0..c {
                            out[x * c + ch] += weight * f64::from(row[col * c + ch]);
                        }
                    }
                }
            }
        }
    }
    for (v, a) in img.iter_mut().zip(acc) {
        *v = a as f32;
    }
}

impl DataSet {
    /// Opens every sequence, splits it and lists its pairs.
    ///
    /// # Errors
    /// A sequence that cannot be read, one without depth, a crop larger than a frame, or no
    /// training data at all.
    pub fn open(cfg: DataConfig) -> Result<Self> {
        let (cw, ch) = cfg.crop;
        if cw < 8 || ch < 8 {
            return Err(Error::invalid_argument("--crop", format!("{cw}x{ch}: at least 8x8")));
        }
        if !(1..=8).contains(&cfg.live_frames) {
            return Err(Error::invalid_argument(
                "--live-frames",
                format!("{}: must be between 1 and 8", cfg.live_frames),
            ));
        }
        if !(0.0..1.0).contains(&cfg.occlusion_tolerance) {
            return Err(Error::invalid_argument(
                "--occlusion-mask",
                format!("{}: must be a fraction in [0, 1) (0: off)", cfg.occlusion_tolerance),
            ));
        }
        if !(0.0..1.0).contains(&cfg.val_fraction) || !(0.0..=1.0).contains(&cfg.synthetic_fraction) {
            return Err(Error::invalid_argument(
                "data",
                "val_fraction must be in [0, 1), synthetic_fraction in [0, 1]",
            ));
        }
        let synth = SceneConfig {
            frames: SYNTH_FRAMES,
            width: cw.max(320),
            height: ch.max(240),
            ..SceneConfig::default()
        };
        let mut sequences = Vec::new();
        for path in &cfg.sequences {
            sequences.push(Self::open_sequence(path, &cfg, cfg.val_fraction)?);
        }
        for path in &cfg.val_sequences {
            if cfg.sequences.contains(path) {
                return Err(Error::invalid_argument(
                    "--val-data",
                    format!(
                        "{} is also given as --data: a scene is training or validation, never both",
                        path.display()
                    ),
                ));
            }
            sequences.push(Self::open_sequence(path, &cfg, 1.0)?);
        }
        if sequences.iter().all(|s| s.train.is_empty()) && cfg.synthetic_scenes == 0 {
            return Err(Error::invalid_argument(
                "data",
                "no training pairs: give sequences with pairs, or synthetic scenes",
            ));
        }
        Ok(DataSet { cfg, synth, sequences, cache: FrameCache::new(DEFAULT_CACHE_MB << 20) })
    }

    /// The same data with a frame cache of `mb` MiB (0: none). The cache never changes a
    /// result, only how often a frame is decoded or rendered.
    pub fn with_cache_mb(mut self, mb: usize) -> Self {
        self.cache = FrameCache::new(mb.saturating_mul(1 << 20));
        self
    }

    /// Reads `path` and its pairs; the last `val_fraction` of its frames (all of them at 1.0) give
    /// validation pairs, the rest training pairs.
    fn open_sequence(path: &Path, cfg: &DataConfig, val_fraction: f64) -> Result<SequenceSource> {
        let seq = open(path)?;
        let (cw, ch) = cfg.crop;
        // Every camera of the sequence must hold the crop (frames may have their own, SPEC.md §4a).
        if let Some(c) = seq.raw_cameras.iter().map(|c| c.pinhole).find(|c| c.width < cw || c.height < ch) {
            return Err(Error::invalid_argument(
                "--crop",
                format!("{cw}x{ch} is larger than {}'s {}x{} frames", path.display(), c.width, c.height),
            ));
        }
        let n = seq.len();
        let split = n - ((n as f64 * val_fraction).round() as usize).min(n);
        // Depth of every frame, for the overlap rule.
        let mut depths = Vec::with_capacity(n);
        for i in 0..n {
            let f = seq.load_frame(i)?;
            let Some(d) = f.depth else {
                return Err(Error::bad_sequence(
                    path,
                    format!("frame {i} has no depth; training needs depth"),
                ));
            };
            depths.push(d);
        }

        let pairs = |range: std::ops::Range<usize>| {
            let mut v = Vec::new();
            for i in range.clone() {
                for j in range.clone() {
                    let (a, b) = (&seq.frames[i].pose, &seq.frames[j].pose);
                    if i == j || !passes_pose_rule(&cfg.rule, a, b) {
                        continue;
                    }
                    let (ci, cj) = (seq.frame_camera(i), seq.frame_camera(j));
                    let full = (0, 0, ci.width, ci.height);
                    let (ov, _, _) = overlap_and_flow(&depths[i], (&ci, &cj), &relative_pose(a, b), full);
                    if ov >= cfg.rule.min_overlap {
                        v.push((i, j));
                    }
                }
            }
            v
        };
        let train = pairs(0..split);
        let val = pairs(split..n);
        let name =
            path.file_name().map_or_else(|| path.display().to_string(), |s| s.to_string_lossy().into_owned());
        Ok(SequenceSource { name, seq, split, train, val })
    }

    /// One line per source: frames, split and pair counts.
    pub fn describe(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .sequences
            .iter()
            .map(|s| {
                format!(
                    "{}: {} frames, train frames 0..{} ({} pairs), validation frames {}..{} ({} pairs)",
                    s.name,
                    s.seq.len(),
                    s.split,
                    s.train.len(),
                    s.split,
                    s.seq.len(),
                    s.val.len()
                )
            })
            .collect();
        if self.cfg.synthetic_scenes > 0 {
            v.push(format!(
                "synthetic ({} style): {} training scenes (seeds {}..{}), {} validation scenes (seeds {}..), {}x{}, {} frames each, rendered on the fly",
                self.cfg.synthetic_style,
                self.cfg.synthetic_scenes,
                SYNTH_TRAIN_SEED0,
                SYNTH_TRAIN_SEED0 + self.cfg.synthetic_scenes as u64,
                self.cfg.synthetic_val_scenes,
                SYNTH_VAL_SEED0,
                self.synth.width,
                self.synth.height,
                SYNTH_FRAMES
            ));
        }
        v
    }

    fn load(&self, source: usize, i: usize) -> Result<Arc<Frame>> {
        let s = &self.sequences[source];
        self.cache.get(FrameKey::Sequence(source, i), || {
            let f = s.seq.load_frame(i)?;
            let depth = f
                .depth
                .ok_or_else(|| Error::bad_sequence(s.seq.root.clone(), format!("frame {i} has no depth")))?;
            Ok(Frame::new(f.rgb, depth, f.pose, f.camera))
        })
    }

    /// A synthetic pair from scene `seed`: a random reference frame and a live frame passing the
    /// pair rule, plus `extra` further live frames that pass it too (drawn only when `extra > 0`).
    fn synthetic_pair(&self, seed: u64, rng: &mut SplitMix64, extra: usize) -> Result<Option<FrameTuple>> {
        let style = self.cfg.synthetic_style.of(seed);
        let scene = Scene::generate(&SceneConfig { seed, style, ..self.synth })?;
        let poses: Vec<Pose> = (0..scene.frames()).map(|i| scene.pose(i)).collect::<Result<_>>()?;
        let cam = scene.camera();
        let frame = |i: usize| self.cache.get(FrameKey::Synthetic(seed, i), || render(&scene, i));
        for _ in 0..ATTEMPTS {
            let i = rng.below(poses.len());
            let js: Vec<usize> = (0..poses.len())
                .filter(|&j| j != i && passes_pose_rule(&self.cfg.rule, &poses[i], &poses[j]))
                .collect();
            if js.is_empty() {
                continue;
            }
            let j = js[rng.below(js.len())];
            let r = frame(i)?;
            let overlaps = |j: usize| {
                overlap_and_flow(
                    &r.depth,
                    (&cam, &cam),
                    &relative_pose(&r.pose, &poses[j]),
                    (0, 0, cam.width, cam.height),
                )
                .0 >= self.cfg.rule.min_overlap
            };
            if overlaps(j) {
                let mut lives = vec![frame(j)?];
                if extra > 0 {
                    let others: Vec<usize> = js.iter().copied().filter(|&o| o != j).collect();
                    let Some(picked) = draw_distinct(&others, extra, rng, overlaps) else { continue };
                    for o in picked {
                        lives.push(frame(o)?);
                    }
                }
                return Ok(Some((r, lives)));
            }
        }
        Ok(None)
    }

    /// Crops a pair: the reference window at `(x0, y0)` (random when `rng` is given, else
    /// centred), the live window shifted by the mean flow.
    fn crop(&self, r: &Frame, lives: &[Arc<Frame>], rng: Option<&mut SplitMix64>) -> Result<TrainingPair> {
        let Some((l, extra)) = lives.split_first() else {
            return Err(Error::invalid_argument("data", "a training tuple needs a live frame"));
        };
        let (cw, ch) = self.cfg.crop;
        let cam = &r.camera;
        let (w, h) = (cam.width, cam.height);
        // With `LiveCrop::Same`, the live window of a reference window `(x, y)` in a live frame.
        let same = |l: &Frame, x: usize, y: usize| (x.min(l.camera.width - cw), y.min(l.camera.height - ch));
        let (x0, y0) = match (rng, self.cfg.live_crop) {
            (Some(rng), LiveCrop::Flow) => (rng.below(w - cw + 1), rng.below(h - ch + 1)),
            (Some(rng), LiveCrop::Same) => {
                // Redraw until every live window holds enough of the reference window's matches
                // (else keep the best draw): a window whose matches all fall outside the live
                // crop would train on nothing.
                let poses: Vec<Pose> = lives.iter().map(|l| relative_pose(&r.pose, &l.pose)).collect();
                let mut best = (0, 0, -1.0);
                for _ in 0..SAME_WINDOW_DRAWS {
                    let (x, y) = (rng.below(w - cw + 1), rng.below(h - ch + 1));
                    let worst = lives
                        .iter()
                        .zip(&poses)
                        .map(|(l, t_lr)| {
                            let (lx, ly) = same(l, x, y);
                            overlap_and_flow_in(
                                &r.depth,
                                (cam, &l.camera),
                                t_lr,
                                (x, y, cw, ch),
                                (lx, ly, cw, ch),
                            )
                            .0
                        })
                        .fold(f64::INFINITY, f64::min);
                    if worst > best.2 {
                        best = (x, y, worst);
                    }
                    if worst >= SAME_MIN_OVERLAP {
                        break;
                    }
                }
                (best.0, best.1)
            }
            (None, _) => ((w - cw) / 2, (h - ch) / 2),
        };
        // Each live window, in the live frame's own camera (its size bounds the window): the
        // reference window shifted by the mean flow, or the reference window itself.
        let window = |l: &Frame| {
            let t_lr = relative_pose(&r.pose, &l.pose);
            let (lw, lh) = (l.camera.width, l.camera.height);
            match self.cfg.live_crop {
                LiveCrop::Flow => {
                    let (_, du, dv) = overlap_and_flow(&r.depth, (cam, &l.camera), &t_lr, (x0, y0, cw, ch));
                    let shift =
                        |o: usize, d: f64, max: usize| ((o as f64 + d).round().max(0.0) as usize).min(max);
                    (t_lr, shift(x0, du, lw - cw), shift(y0, dv, lh - ch))
                }
                LiveCrop::Same => {
                    let (lx, ly) = same(l, x0, y0);
                    (t_lr, lx, ly)
                }
            }
        };
        let (t_lr, lx, ly) = window(l);
        let crop_cam = |c: &PinholeCamera, x: usize, y: usize| {
            PinholeCamera::new(c.fx, c.fy, c.cx - x as f64, c.cy - y as f64, cw, ch)
        };
        let more_lives = extra
            .iter()
            .map(|e| {
                let (t_lr, ex, ey) = window(e);
                Ok(ExtraLive {
                    rgb: e.rgb_window(ex, ey, cw, ch),
                    camera: crop_cam(&e.camera, ex, ey)?,
                    t_lr,
                })
            })
            .collect::<Result<_>>()?;
        let mut ref_depth = r.depth.slice(s![y0..y0 + ch, x0..x0 + cw]).to_owned();
        if self.cfg.occlusion_tolerance > 0.0 {
            let lives: Vec<(Warp, ArrayView2<'_, f32>)> = lives
                .iter()
                .map(|f| (Warp::new(cam, &f.camera, &relative_pose(&r.pose, &f.pose)), f.depth.view()))
                .collect();
            mask_occluded(&mut ref_depth, (x0, y0), &lives, self.cfg.occlusion_tolerance);
        }
        Ok(TrainingPair {
            ref_rgb: r.rgb_window(x0, y0, cw, ch),
            live_rgb: l.rgb_window(lx, ly, cw, ch),
            ref_depth,
            ref_camera: crop_cam(cam, x0, y0)?,
            live_camera: crop_cam(&l.camera, lx, ly)?,
            t_lr,
            sample_seed: 0,
            more_lives,
        })
    }

    /// Training pair `index` of step `step` (1-based), deterministic in `(seed, step, index)`.
    ///
    /// # Errors
    /// A frame that cannot be read, or no pair found after repeated draws.
    pub fn train_pair(&self, seed: u64, step: usize, index: usize) -> Result<TrainingPair> {
        let mut rng = SplitMix64::new(hash64(seed, step as u64, index as u64, 0x0074_7261_696e));
        let real: Vec<usize> =
            (0..self.sequences.len()).filter(|&s| !self.sequences[s].train.is_empty()).collect();
        for _ in 0..ATTEMPTS {
            let synthetic = self.cfg.synthetic_scenes > 0
                && (real.is_empty() || rng.unit() < self.cfg.synthetic_fraction);
            let extra = self.cfg.live_frames - 1;
            let (r, lives) = if synthetic {
                let seed = SYNTH_TRAIN_SEED0 + rng.below(self.cfg.synthetic_scenes) as u64;
                match self.synthetic_pair(seed, &mut rng, extra)? {
                    Some(x) => x,
                    None => continue,
                }
            } else {
                let s = real[rng.below(real.len())];
                let src = &self.sequences[s];
                let (i, j) = src.train[rng.below(src.train.len())];
                let mut lives = vec![self.load(s, i)?, self.load(s, j)?];
                if extra > 0 {
                    // Further live frames: other partners of the same reference in the pair list.
                    let others: Vec<usize> =
                        src.train.iter().filter(|&&(a, b)| a == i && b != j).map(|&(_, b)| b).collect();
                    let Some(picked) = draw_distinct(&others, extra, &mut rng, |_| true) else { continue };
                    for o in picked {
                        lives.push(self.load(s, o)?);
                    }
                }
                let r = lives.remove(0);
                (r, lives)
            };
            // Crop first, then augment the crops (SPEC.md §13.5).
            let mut pair = self.crop(&r, &lives, Some(&mut rng))?;
            augment(&mut pair.ref_rgb, &self.cfg.augment, &mut rng);
            augment(&mut pair.live_rgb, &self.cfg.augment, &mut rng);
            for e in &mut pair.more_lives {
                augment(&mut e.rgb, &self.cfg.augment, &mut rng);
            }
            pair.sample_seed = rng.next_u64();
            return Ok(pair);
        }
        Err(Error::invalid_argument("data", format!("no pair passed the pair rule in {ATTEMPTS} draws")))
    }

    /// The fixed validation pairs: `per_source` pairs spread evenly over each sequence's held-out
    /// pairs and `per_source` from each synthetic validation scene; centred crops, no
    /// augmentation. Returns `(source name, pair)`.
    ///
    /// # Errors
    /// A frame that cannot be read.
    pub fn val_pairs(&self, per_source: usize) -> Result<Vec<(String, TrainingPair)>> {
        let mut v = Vec::new();
        for (k, s) in self.sequences.iter().enumerate() {
            let n = s.val.len();
            for q in 0..per_source.min(n) {
                let (i, j) = s.val[q * n / per_source.min(n)];
                v.push((s.name.clone(), self.crop(&*self.load(k, i)?, &[self.load(k, j)?], None)?));
            }
        }
        for k in 0..self.cfg.synthetic_val_scenes {
            let seed = SYNTH_VAL_SEED0 + k as u64;
            let mut rng = SplitMix64::new(seed);
            for _ in 0..per_source {
                if let Some((r, lives)) = self.synthetic_pair(seed, &mut rng, 0)? {
                    v.push((format!("synthetic-{seed}"), self.crop(&r, &lives, None)?));
                }
            }
        }
        Ok(v)
    }
}
