//! `densefeat costcurve`: parses the flags, checks them up front, calls
//! [`densefeat::mapping::costcurve::cost_curves`] and writes the plot and the CSV (SPEC.md §12.1).

use std::path::{Path, PathBuf};

use clap::Args;

use densefeat::error::{Error, Result};
use densefeat::geometry::InverseDepthBins;
use densefeat::io::{write_atomic, Staging};
use densefeat::mapping::costcurve::{cost_curves, curves_csv, panels};
use densefeat::mapping::features::{FeatureExtractor, FeatureKind};
use densefeat::memory;
use densefeat::plot::grid_of_plots_png;
use densefeat::sequence::Sequence;

use super::validate::{flag, frames_big_enough, MemoryLimit};
use densefeat::mapping::features::feature_memory;

/// Arguments of `densefeat costcurve`.
#[derive(Debug, Clone, Args)]
pub struct CostcurveArgs {
    /// The sequence folder (any format `densefeat inspect` reads).
    #[arg(long)]
    pub sequence: PathBuf,
    /// Index of the keyframe (the reference frame of the volume).
    #[arg(long)]
    pub keyframe: usize,
    /// Level-0 keyframe pixels "x,y;x,y;..." (column, row).
    #[arg(long)]
    pub pixels: String,
    /// Feature kinds, comma-separated: rgb, learned, learned=WEIGHTS, b1, b1=WEIGHTS, dsift, patch7.
    #[arg(long, default_value = "rgb,learned")]
    pub features: String,
    /// Numbers of added frames at which curves are recorded (clamped to the frames that exist).
    #[arg(long, default_value = "2,15,30")]
    pub frames: String,
    /// Depth range NEAR,FAR in metres (hypotheses uniform in inverse depth).
    #[arg(long, default_value = "0.4,10")]
    pub depth_range: String,
    /// Number of inverse-depth hypotheses K.
    #[arg(long, default_value_t = 64)]
    pub bins: usize,
    /// Metres per unit of the sequence's poses: required for sequences without a metric scale
    /// (COLMAP); `--scale 1` keeps their units.
    #[arg(long)]
    pub scale: Option<f64>,
    /// Output PNG; the raw curves go to the same path with extension `.csv`.
    #[arg(long)]
    pub out: PathBuf,
    /// Memory limit.
    #[command(flatten)]
    pub memory: MemoryLimit,
    /// Where the volumes are built.
    #[command(flatten)]
    pub backend: super::backend_flag::BackendFlag,
}

/// Parse `"x,y;x,y"`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--pixels`.
pub fn parse_pixels(text: &str) -> Result<Vec<(usize, usize)>> {
    let bad = |what: String| Error::invalid_argument("--pixels", format!("{text:?}: {what}"));
    let pixels = text
        .split(';')
        .filter(|p| !p.trim().is_empty())
        .map(|p| {
            let (x, y) = p.split_once(',').ok_or_else(|| bad(format!("{p:?} is not x,y")))?;
            let num =
                |v: &str| v.trim().parse::<usize>().map_err(|_| bad(format!("{v:?} is not a pixel index")));
            Ok((num(x)?, num(y)?))
        })
        .collect::<Result<Vec<_>>>()?;
    if pixels.is_empty() {
        return Err(bad("no pixel".into()));
    }
    Ok(pixels)
}

fn parse_list(name: &str, text: &str) -> Result<Vec<usize>> {
    let list = text
        .split(',')
        .map(|v| v.trim().parse::<usize>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| Error::invalid_argument(name, format!("{text:?}: expected N,N,...")))?;
    if list.is_empty() || list.contains(&0) {
        return Err(Error::invalid_argument(name, format!("{text:?}: need counts >= 1")));
    }
    Ok(list)
}

fn parse_range(text: &str) -> Result<(f64, f64)> {
    let bad = || Error::invalid_argument("--depth-range", format!("{text:?}: expected NEAR,FAR in metres"));
    let (a, b) = text.split_once(',').ok_or_else(bad)?;
    Ok((a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?))
}

/// The CSV path for a PNG path.
pub fn csv_path(png: &Path) -> PathBuf {
    png.with_extension("csv")
}

/// The checks that run before any curve is computed (SPEC.md §14.1): frame size, keyframe, pixels,
/// weights files and the memory of the largest volume.
fn preflight(
    args: &CostcurveArgs,
    seq: &Sequence,
    kinds: &[FeatureKind],
    pixels: &[(usize, usize)],
) -> Result<()> {
    frames_big_enough(seq, "costcurve")?;
    if args.keyframe >= seq.len() {
        return Err(flag("keyframe", format!("{}: the sequence has {} frames", args.keyframe, seq.len())));
    }
    let camera = seq.the_camera("--sequence")?;
    let (w0, h0) = (camera.width, camera.height);
    if let Some(p) = pixels.iter().find(|(x, y)| *x >= w0 || *y >= h0) {
        return Err(flag("pixels", format!("{p:?} is outside the {w0}x{h0} image")));
    }
    if csv_path(&args.out) == args.out {
        return Err(flag(
            "out",
            format!("{}: give the PNG a .png name (the CSV goes beside it)", args.out.display()),
        ));
    }
    let level = FeatureExtractor::network_level()?;
    for kind in kinds {
        let (channels, extraction) = feature_memory(kind, h0, w0)?;
        let grid = seq.camera.at_level(level);
        let bytes = memory::cost_volume_bytes(grid.height, grid.width, args.bins, channels)
            .saturating_add(extraction);
        let what =
            format!("the {}x{}x{} cost volume with {channels} channels", grid.height, grid.width, args.bins);
        args.memory.check(&what, bytes, "use fewer --bins")?;
    }
    Ok(())
}

/// Runs the command.
///
/// # Errors
/// Argument errors naming the flag; reading and writing errors naming the file.
pub fn run(args: CostcurveArgs) -> Result<()> {
    let pixels = parse_pixels(&args.pixels)?;
    let kinds = args.features.split(',').map(|k| k.trim().parse()).collect::<Result<Vec<FeatureKind>>>()?;
    let counts = parse_list("--frames", &args.frames)?;
    let (near, far) = parse_range(&args.depth_range)?;
    let bins = InverseDepthBins::from_depth_range(near, far, args.bins)
        .map_err(|e| flag(if args.bins < 2 { "bins" } else { "depth-range" }, e.to_string()))?;
    let backend = args.backend.resolve()?;
    let seq = super::mapping_args::open_metric(&args.sequence, args.scale)?;
    preflight(&args, &seq, &kinds, &pixels)?;
    let mut staging = Staging::new();
    let png = staging.file(&args.out)?;
    let csv_staged = staging.file(&csv_path(&args.out))?;
    let start = std::time::Instant::now();
    let curves = cost_curves(&seq, args.keyframe, &pixels, &kinds, &counts, bins, &backend)?;
    let title = format!(
        "Keyframe {}: cost vs inverse depth, each curve normalised to [0, 1]; lines: minima, green: ground truth",
        args.keyframe
    );
    grid_of_plots_png(&png, &title, &panels(&curves, &bins))?;
    write_atomic(&csv_staged, curves_csv(&curves, &bins).as_bytes())?;
    staging.commit()?;
    let csv = csv_path(&args.out);
    eprintln!(
        "costcurve: {} curves -> {} and {} in {:.2} s",
        curves.len(),
        args.out.display(),
        csv.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_pixels;

    #[test]
    fn pixels_parse_as_x_comma_y_separated_by_semicolons() {
        assert_eq!(parse_pixels("1,2; 3,4;").unwrap(), vec![(1, 2), (3, 4)]);
        assert!(parse_pixels("1;2").is_err());
        assert!(parse_pixels("").is_err());
    }
}
