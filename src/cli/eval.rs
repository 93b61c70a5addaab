//! `densefeat eval`: every method on every keyframe, the paper's table (SPEC.md §11.5).

use std::io::Write as _;
use std::path::{Path, PathBuf};

use clap::Args;

use densefeat::error::{Error, Result};
use densefeat::io::{write_atomic_with, Staging};
use densefeat::mapping::evaluate::{evaluate, EvalOptions, EvalTable, Method};
use densefeat::mapping::figure::{write_feature_figure, FigureEntry};
use densefeat::mapping::keyframe::{KeyframeResult, Regularizer};
use densefeat::mapping::{write_outputs_with, FeatureKind};
use densefeat::plot::{line_plot_png, Series};
use densefeat::sequence::Sequence;

use super::mapping_args::{
    parse_keyframes, progress_bar, resolve_depth_range, show_stage, summary, DepthRange, MappingArgs,
};
use super::validate::{flag, mapping_preflight, positive};

/// Arguments of `densefeat eval`.
#[derive(Debug, Clone, Args)]
pub struct EvalArgs {
    /// Sequence folder with ground-truth depth.
    #[arg(long)]
    pub sequence: PathBuf,
    /// Keyframes `START:STEP:END`, END inclusive.
    #[arg(long)]
    pub keyframes: String,
    /// Comma-separated methods: FEATURES-wta or FEATURES-tv with FEATURES rgb, learned, b1 (block 1
    /// of the network alone), dsift (dense SIFT) or patch7 (affine-warped 7x7 patches), SPEC.md §9a;
    /// and rgb-normals, learned-normals (the surface-normal prior, SPEC.md §10.2, with --normals' or
    /// the built-in predictor's normals). The default is the paper's four and learned-normals, the
    /// learned features' default regulariser (SPEC.md §10.1a).
    #[arg(
        long,
        default_value = "rgb-wta,rgb-tv,learned-wta,learned-tv,learned-normals",
        value_delimiter = ','
    )]
    pub methods: Vec<Method>,
    /// Weights of the learned and block-1 features (default: the shipped ones).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// DTAM λ for the learned features (default: --lambda).
    #[arg(long)]
    pub lambda_learned: Option<f64>,
    /// Mapping flags.
    #[command(flatten)]
    pub mapping: MappingArgs,
    /// Also write every keyframe's depth files into OUT/kf_I_FEATURES/.
    #[arg(long)]
    pub save_depth: bool,
    /// Comma-separated DTAM λ values: also run every TV method (or a kind's normal-prior method when
    /// its TV method is not asked for) at each λ on the same volumes (the same λ for RGB and learned
    /// features) and write `lambda_sweep.csv`, `lambda_sweep.png` (rms
    /// against λ) and `lambda_sweep_delta.png` (δ<1.25 against λ).
    #[arg(long, value_delimiter = ',')]
    pub lambda_sweep: Vec<f64>,
    /// Comma-separated confidence thresholds: also write every method's metrics at each
    /// (`confidence_sweep.csv`: coverage and accuracy against the threshold).
    #[arg(long, value_delimiter = ',')]
    pub confidence_sweep: Vec<f32>,
    /// Also write `figure_kfNNNNN.png` per keyframe: its image, the ground truth and every method's
    /// depth on one colour scale, each captioned with its rms, δ<1.1 and δ<1.25 (the paper's Fig. 4).
    #[arg(long)]
    pub figure: bool,
    /// Output folder (table.csv, table.md, per_keyframe.csv, timings.md; normals_error.csv with
    /// `--normals learned`).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
///
/// # Errors
/// Bad arguments, missing ground truth, reading or writing errors.
pub fn run(args: EvalArgs) -> Result<()> {
    let seq = args.mapping.open_sequence(&args.sequence)?;
    let keyframes = parse_keyframes(&args.keyframes)?;
    preflight(&seq, &args, &keyframes)?;
    let mut lambdas = args.lambda_sweep.clone();
    lambdas.sort_by(f64::total_cmp);
    let mut staging = Staging::new();
    let out = staging.dir(&args.out)?;
    let table = run_eval(
        &seq,
        &args.mapping,
        &keyframes,
        &args.methods,
        &out,
        (args.save_depth, args.figure),
        || EvalOptions {
            weights: args.weights.clone(),
            lambda_learned: args.lambda_learned,
            lambda_per_kind: args.mapping.lambda.is_none(),
            lambda_sweep: lambdas.clone(),
            min_confidence: args.mapping.min_confidence,
            confidence_sweep: args.confidence_sweep.clone(),
            ..EvalOptions::default()
        },
    )?;
    let mut sweep_csv = None;
    if !table.confidence_sweep.is_empty() {
        let mut csv = String::from("method,min_confidence,rms,delta_1.25,abs_rel,coverage\n");
        for (m, c, d) in &table.confidence_sweep {
            csv += &format!("{m},{c},{},{},{},{}\n", d.rms, d.delta_1_25, d.abs_rel, d.coverage);
        }
        write_text(&out.join("confidence_sweep.csv"), &csv)?;
        sweep_csv = Some(csv);
    }
    if !lambdas.is_empty() {
        write_sweep(&table, &out)?;
    }
    staging.commit()?;
    print_table(&table, &args.out);
    if let Some(csv) = sweep_csv {
        println!("\nconfidence sweep:\n{csv}");
    }
    Ok(())
}

/// Every check of `eval`'s flags and inputs that runs before the evaluation (SPEC.md §14.1).
fn preflight(seq: &Sequence, args: &EvalArgs, keyframes: &[usize]) -> Result<()> {
    if args.methods.is_empty() {
        return Err(flag("methods", "empty: name at least one method"));
    }
    if let Some(l) = args.lambda_learned {
        positive("lambda-learned", l)?;
    }
    if !args.lambda_sweep.is_empty() {
        if !args.methods.iter().any(|m| m.tv() || m.normals()) {
            return Err(flag("lambda-sweep", "needs at least one TV or normal-prior method in --methods"));
        }
        if let Some(bad) = args.lambda_sweep.iter().find(|l| !(**l > 0.0 && l.is_finite())) {
            return Err(flag("lambda-sweep", format!("λ = {bad}: must be positive")));
        }
    }
    let mut kinds: Vec<FeatureKind> = Vec::new();
    for m in &args.methods {
        let kind = m.features(args.weights.as_deref());
        if !kinds.contains(&kind) {
            kinds.push(kind);
        }
    }
    let regularizer =
        if args.methods.iter().any(|m| m.normals()) { Regularizer::TvAndNormals } else { Regularizer::Tv };
    let cfg = args.mapping.config(seq, keyframes[0], FeatureKind::Rgb, regularizer)?;
    mapping_preflight(seq, &cfg, keyframes, &kinds, "eval")
}

/// `lambda_sweep.csv` and the plots `lambda_sweep.png` (rms) and `lambda_sweep_delta.png`
/// (δ<1.25) against λ, from the volumes of the main evaluation (the paper's λ-sensitivity figure).
fn write_sweep(table: &EvalTable, out: &Path) -> Result<()> {
    let mut methods: Vec<Method> = Vec::new();
    for (m, _, _) in &table.sweep {
        if !methods.contains(m) {
            methods.push(*m);
        }
    }
    let mut csv = String::from("method,lambda,rms,delta_1.25,abs_rel,coverage\n");
    for (m, l, d) in &table.sweep {
        csv += &format!("{m},{l},{},{},{},{}\n", d.rms, d.delta_1_25, d.abs_rel, d.coverage);
    }
    write_text(&out.join("lambda_sweep.csv"), &csv)?;
    const COLOURS: [(u8, u8, u8); 4] = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189)];
    for (file, ylabel, pick) in [
        ("lambda_sweep.png", "rms (m)", (|d: &densefeat::eval::DepthMetrics| d.rms) as fn(&_) -> f64),
        ("lambda_sweep_delta.png", "δ<1.25", |d: &densefeat::eval::DepthMetrics| d.delta_1_25),
    ] {
        let series: Vec<Series> = methods
            .iter()
            .enumerate()
            .map(|(i, m)| Series {
                name: m.name().to_string(),
                points: table
                    .sweep
                    .iter()
                    .filter(|(pm, _, _)| pm == m)
                    .map(|(_, l, d)| (*l, pick(d)))
                    .collect(),
                colour: COLOURS[i % COLOURS.len()],
            })
            .collect();
        line_plot_png(
            &out.join(file),
            &format!("Keyframe {ylabel} against regularisation strength"),
            "λ (normalised data term weighted by 1/λ)",
            ylabel,
            &series,
            &[],
            true,
        )?;
    }
    println!("\nλ sweep:\n{csv}wrote lambda_sweep.csv, lambda_sweep.png, lambda_sweep_delta.png");
    Ok(())
}

/// Evaluate and write the tables into `out`; shared with `demo`.
///
/// # Errors
/// As [`evaluate`], and write errors.
pub fn run_eval(
    seq: &Sequence,
    mapping: &MappingArgs,
    keyframes: &[usize],
    methods: &[Method],
    out: &Path,
    (save_depth, figure): (bool, bool),
    options: impl FnOnce() -> EvalOptions,
) -> Result<EvalTable> {
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let base = mapping.config(seq, keyframes[0], FeatureKind::Rgb, Regularizer::Tv)?;
    let mut options = options();
    if mapping.depth_range == DepthRange::Auto {
        // One estimate per keyframe, all made before any heavy work (a keyframe without sparse
        // points or depth fails here, naming itself).
        options.depth_ranges = keyframes
            .iter()
            .map(|&k| resolve_depth_range(mapping.depth_range, seq, k))
            .collect::<Result<_>>()?;
    }
    let bar = progress_bar();
    // With `figure`: per keyframe, its first reconstruction (image, ground truth, colour range) and
    // every method's entry.
    let mut figures: Vec<(KeyframeResult, Vec<FigureEntry>)> = Vec::new();
    let result = evaluate(
        seq,
        &base,
        keyframes,
        methods,
        &options,
        |r| {
            bar.println(summary(r));
            if save_depth {
                let dir = out.join(format!("kf_{:05}_{}", r.keyframe, r.features));
                write_outputs_with(r, &dir, mapping.min_confidence)?;
            }
            if figure {
                let entries = methods
                    .iter()
                    .filter(|m| m.feature_name() == r.features)
                    .filter_map(|&m| FigureEntry::of(m, r));
                match figures.iter_mut().find(|(f, _)| f.keyframe == r.keyframe) {
                    Some((_, e)) => e.extend(entries),
                    None => figures.push((r.clone(), entries.collect())),
                }
            }
            Ok(())
        },
        |k, s, d, t| show_stage(&bar, &format!("keyframe {k}: "), s, d, t),
    );
    bar.finish_and_clear();
    let table = result?;
    for (r, mut entries) in figures {
        entries.sort_by_key(|e| methods.iter().position(|&m| m == e.method));
        let path = out.join(format!("figure_kf{:05}.png", r.keyframe));
        let title =
            format!("{}: keyframe {}, {} live frames", seq.root.display(), r.keyframe, r.live_frames.len());
        write_feature_figure(&path, &title, &r, &entries)?;
    }
    write_text(&out.join("table.md"), &table.markdown())?;
    write_text(&out.join("table.csv"), &table.csv())?;
    write_text(&out.join("timings.md"), &table.timings_markdown())?;
    let mut per = String::from("keyframe,method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,delta_1.25^2,delta_1.25^3,coverage\n");
    for (k, m, d) in &table.per_keyframe {
        per += &format!(
            "{k},{m},{},{},{},{},{},{},{},{},{}\n",
            d.rms,
            d.log_rms,
            d.abs_rel,
            d.sq_rel,
            d.delta_1_1,
            d.delta_1_25,
            d.delta_1_25_2,
            d.delta_1_25_3,
            d.coverage
        );
    }
    write_text(&out.join("per_keyframe.csv"), &per)?;
    if !table.normals_error.is_empty() {
        let mut csv = String::from("keyframe,normals_mean_angle_deg,normals_median_angle_deg,pixels\n");
        for (k, e) in &table.normals_error {
            csv += &format!("{k},{},{},{}\n", e.mean_deg, e.median_deg, e.pixels);
        }
        write_text(&out.join("normals_error.csv"), &csv)?;
    }
    Ok(table)
}

/// Print the table and timings.
pub fn print_table(table: &EvalTable, out: &Path) {
    println!("\n{}", table.markdown());
    println!("mean wall time per keyframe:\n{}", table.timings_markdown());
    println!("wrote table.md, table.csv, per_keyframe.csv, timings.md to {}", out.display());
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(text.as_bytes()))
}
