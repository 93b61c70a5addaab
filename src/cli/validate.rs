//! Up-front checks shared by the subcommands (SPEC.md §14.1): the one way to say "flag X: problem",
//! the size and range parsers that name their flag, the frame-size check, and the memory-limit flag.
//! Every subcommand runs these before any heavy work or any write.

use clap::Args;

use densefeat::error::{Error, Result};
use densefeat::memory::DEFAULT_MAX_MEMORY_MB;
use densefeat::sequence::Sequence;

/// Largest image or crop side any command accepts (the renderer's limit), pixels.
pub const MAX_SIDE: usize = 8192;

/// Smallest frame side (level-0 pixels) a reconstruction accepts: below it the level-1 grid has
/// fewer than 8x8 cells and no depth metric means anything.
pub const MIN_FRAME_SIDE: usize = 16;

/// The one `A,B` parser (window, depth range, baseline, ...).
///
/// # Errors
/// A message naming the text, for clap or for [`flag`].
pub fn pair<T: std::str::FromStr>(s: &str) -> std::result::Result<(T, T), String> {
    let (a, b) = s.split_once(',').ok_or_else(|| format!("{s:?}: expected two values A,B"))?;
    let p = |v: &str| v.trim().parse::<T>().map_err(|_| format!("{v:?} is not a number"));
    Ok((p(a)?, p(b)?))
}

/// The one "flag X: problem" error: `name` with or without its leading `--`.
pub fn flag(name: &str, what: impl Into<String>) -> Error {
    let name = if name.starts_with("--") { name.to_string() } else { format!("--{name}") };
    Error::invalid_argument(name, what)
}

/// `Ok` if `v` is finite and `> 0`, else an error naming `name`.
///
/// # Errors
/// [`flag`] error.
pub fn positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(flag(name, format!("{v}: must be a finite number > 0")))
    }
}

/// Parse `WIDTHxHEIGHT` for flag `name`, each side in `1..=`[`MAX_SIDE`].
///
/// # Errors
/// [`flag`] error naming `name`.
pub fn size(name: &str, text: &str) -> Result<(usize, usize)> {
    let bad = |what: &str| flag(name, format!("{text:?}: {what}"));
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(|| bad("expected WIDTHxHEIGHT, e.g. 320x240"))?;
    let side = |v: &str, which: &str| -> Result<usize> {
        let n: usize =
            v.trim().parse().map_err(|_| bad(&format!("{which} is not a non-negative integer")))?;
        if n == 0 || n > MAX_SIDE {
            return Err(bad(&format!("{which} {n} must be in 1..={MAX_SIDE}")));
        }
        Ok(n)
    };
    Ok((side(w, "width")?, side(h, "height")?))
}

/// Refuse a sequence whose frames are smaller than [`MIN_FRAME_SIDE`], naming its first frame.
///
/// # Errors
/// [`Error::BadFile`] naming the first colour image.
pub fn frames_big_enough(seq: &Sequence, command: &str) -> Result<()> {
    // Every frame's own camera; the first too-small frame is named.
    let Some(i) = (0..seq.len()).find(|&i| {
        let c = seq.frame_camera(i);
        c.width < MIN_FRAME_SIDE || c.height < MIN_FRAME_SIDE
    }) else {
        return Ok(());
    };
    let (w, h) = (seq.frame_camera(i).width, seq.frame_camera(i).height);
    let file = seq.frames[i].rgb.clone();
    Err(Error::bad_file(
        file,
        format!("frames are {w}x{h} pixels; {command} needs at least {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE}"),
    ))
}

/// The memory-limit flag of every command that allocates in proportion to its arguments.
#[derive(Debug, Clone, Copy, Args)]
pub struct MemoryLimit {
    /// Refuse to run when the estimated memory exceeds this many MiB.
    #[arg(long, default_value_t = DEFAULT_MAX_MEMORY_MB)]
    pub max_memory_mb: usize,
}

impl Default for MemoryLimit {
    fn default() -> Self {
        Self { max_memory_mb: DEFAULT_MAX_MEMORY_MB }
    }
}

impl MemoryLimit {
    /// [`densefeat::memory::check`] against this limit.
    ///
    /// # Errors
    /// As [`densefeat::memory::check`].
    pub fn check(&self, what: &str, bytes: u64, shrink: &str) -> Result<()> {
        densefeat::memory::check(self.max_memory_mb, what, bytes, shrink)
    }
}

/// Everything a keyframe reconstruction can check before it starts (SPEC.md §14.1): frame size,
/// bins, depth range, DTAM parameters, every keyframe and its window, every weights file, and the
/// memory estimate of the largest feature kind against `max_memory_mb`.
///
/// # Errors
/// The first problem, naming the flag or file.
pub fn mapping_preflight(
    seq: &Sequence,
    cfg: &densefeat::mapping::keyframe::KeyframeConfig,
    keyframes: &[usize],
    kinds: &[densefeat::mapping::FeatureKind],
    command: &str,
) -> Result<()> {
    use densefeat::geometry::InverseDepthBins;
    use densefeat::mapping::keyframe::Regularizer;
    frames_big_enough(seq, command)?;
    if cfg.bins < 2 {
        return Err(flag("bins", format!("{}: need at least 2", cfg.bins)));
    }
    InverseDepthBins::from_depth_range(cfg.near, cfg.far, cfg.bins)
        .map_err(|e| flag("depth-range", format!("{},{}: {e}", cfg.near, cfg.far)))?;
    if cfg.regularizer != Regularizer::None {
        cfg.dtam.validate()?;
    }
    if cfg.regularizer.normals() {
        normals_preflight(seq, cfg, keyframes)?;
    }
    for &k in keyframes {
        let mut c = cfg.clone();
        c.keyframe = k;
        c.live_frames(seq.len()).map_err(|e| flag("keyframe", e.to_string()))?;
    }
    // The largest keyframe camera bounds every volume.
    let key_camera = keyframes
        .iter()
        .map(|&k| seq.frame_camera(k))
        .max_by_key(|c| c.width * c.height)
        .unwrap_or(seq.camera);
    // The volume lives on the output grid, level `--level` (SPEC.md §11.1).
    let grid = key_camera.at_level(cfg.level);
    for kind in kinds {
        let (channels, extraction) =
            densefeat::mapping::features::feature_memory(kind, key_camera.height, key_camera.width)?;
        let bytes = densefeat::memory::cost_volume_bytes(grid.height, grid.width, cfg.bins, channels)
            .saturating_add(extraction);
        let what = format!(
            "the {}x{}x{} cost volume with {channels} feature channels ({})",
            grid.height,
            grid.width,
            cfg.bins,
            kind.name()
        );
        densefeat::memory::check(cfg.max_memory_mb, &what, bytes, "use fewer --bins or a coarser --level")?;
    }
    Ok(())
}

/// Before any heavy work: the normal prior has a source (`--normals`), runs on the CPU, and every
/// keyframe has its normals (a ground-truth depth for `gt`, a file in `DIR`; SPEC.md §10.2).
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--normals` / `--backend`.
fn normals_preflight(
    seq: &Sequence,
    cfg: &densefeat::mapping::KeyframeConfig,
    keyframes: &[usize],
) -> Result<()> {
    use densefeat::mapping::normals::{load_predictor, normals_file, NormalsSource};
    let Some(source) = &cfg.normals else {
        return Err(flag(
            "normals",
            "missing: the normal prior needs --normals learned (the built-in predictor), --normals gt or \
             --normals DIR",
        ));
    };
    if let NormalsSource::Learned(weights) = source {
        // The weights are read and checked before any heavy work.
        load_predictor(weights.as_deref())?;
    }
    if cfg.backend.name() != "cpu" {
        return Err(flag("backend", "the surface-normal prior runs on the CPU only: use --backend cpu"));
    }
    for &k in keyframes {
        match source {
            NormalsSource::GroundTruth => {
                if seq.frames.get(k).is_some_and(|f| f.depth.is_none()) {
                    return Err(flag("normals", format!("gt: keyframe {k} has no ground-truth depth")));
                }
            }
            NormalsSource::Dir(dir) => {
                normals_file(dir, seq, k)?;
            }
            // Loaded once below.
            NormalsSource::Learned(_) => {}
        }
    }
    Ok(())
}
