//! The `densefeat` command line. One file per subcommand; each parses its own arguments (clap) and
//! returns the library's [`densefeat::Error`], which `main` prints and turns into exit code 1.

use clap::{Parser, Subcommand};

use densefeat::error::Result;

pub mod backend_flag;
pub mod bench;
pub mod bench_costvolume;
pub mod bench_refine;
pub mod bench_tv;
#[cfg(feature = "gpu")]
mod bench_tv_gpu;
pub mod costcurve;
pub mod demo;
pub mod eval;
pub mod features;
pub mod init_weights;
pub mod inspect;
pub mod map;
pub mod mapping_args;
pub mod progress_bar;
pub mod reconstruct;
pub mod synth;
pub mod texture_atlas;
pub mod train;
pub mod train_normals;
pub mod validate;

/// Dense monocular reconstruction with learned good features to match.
#[derive(Debug, Parser)]
#[command(name = "densefeat", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Open a sequence folder and print what was read: frames, camera, depth, motion, warnings.
    Inspect(inspect::InspectArgs),
    /// Render a synthetic posed RGB-D sequence (DeepVideoMVS layout).
    Synth(synth::SynthArgs),
    /// Render one frame of several synthetic scenes into a PNG grid (a page of samples).
    SynthSheet(synth::SynthSheetArgs),
    /// Cut the photo-texture atlas of the realistic synthetic style from the training scenes' frames.
    TextureAtlas(texture_atlas::TextureAtlasArgs),
    /// Compute dense features of one image with the feature network (writes .npy, optional PCA PNG).
    Features(features::FeaturesArgs),
    /// Write Xavier-initialised (untrained) feature-network weights as safetensors.
    InitWeights(init_weights::InitWeightsArgs),
    /// Time the network's forward pass or the SGEMM peak.
    Bench(bench::BenchArgs),
    /// Reconstruct one keyframe's depth (cost volume, winner-take-all, optional DTAM TV).
    Reconstruct(reconstruct::ReconstructArgs),
    /// Evaluate methods over keyframes against ground truth: the paper's table.
    Eval(eval::EvalArgs),
    /// A whole sequence to a mesh: keyframes, depth, TSDF fusion, mesh, metrics against ground truth.
    Map(map::MapArgs),
    /// Reconstruct a keyframe of the shipped synthetic fixture with every method.
    Demo(demo::DemoArgs),
    /// Plot the cost curves of a few keyframe pixels (RGB vs learned) as the volume fills (PNG + CSV).
    Costcurve(costcurve::CostcurveArgs),
    /// Train the feature network with the paper's deeply supervised cost-volume loss.
    Train(train::TrainArgs),
    /// Train the built-in surface-normal predictor (`--normals learned`) on frames with depth.
    TrainNormals(train_normals::TrainNormalsArgs),
}

/// Parse the process arguments and run the subcommand.
///
/// # Errors
/// Whatever the subcommand returns.
pub fn run(cli: Cli) -> Result<()> {
    densefeat::runtime::check_cpu_level_env()?;
    match cli.command {
        Command::Inspect(args) => inspect::run(args),
        Command::Train(args) => train::run(args),
        Command::TrainNormals(args) => train_normals::run(args),
        Command::Synth(args) => synth::run(args),
        Command::SynthSheet(args) => synth::run_sheet(args),
        Command::TextureAtlas(args) => texture_atlas::run(args),
        Command::Features(args) => features::run(args),
        Command::InitWeights(args) => init_weights::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Map(args) => map::run(args),
        Command::Costcurve(args) => costcurve::run(args),
    }
}
