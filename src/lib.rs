//! # densefeat
//!
//! Dense monocular reconstruction with learned "good features to match" (Weerasekera, Garg, Latif
//! and Reid, ACCV 2018), CPU first.
//!
//! This crate is the numerical oracle for every other backend, so it keeps one set of conventions
//! (SPEC.md): pixel centres at integer coordinates, channels-last `[H, W, C]` `f32` tensors,
//! camera-to-world poses in metres, inverse depth `ρ = 1/z`.
//!
//! - [`backend`]: the one seam for compute backends: the op list and the CPU backend.
//! - [`costvolume`]: the multi-view feature cost volume (paper eq. 4) and winner-take-all depth.
//! - [`dsift`]: dense SIFT, a hand-crafted per-pixel descriptor baseline for the cost volume.
//! - [`dtam`]: Huber-TV regularisation of inverse depth (DTAM's primal-dual optimiser).
//! - [`mapping`]: keyframe reconstruction with RGB, learned, block-1 or dense-SIFT features, outputs
//!   and evaluation.
//! - [`fusion`]: TSDF fusion of keyframe depth maps, its mesh, mesh-to-mesh metrics and pictures.
//! - [`geometry`]: pinhole cameras, distortion, SE(3), the inverse-depth warp.
//! - [`image`]: image types, PNG I/O, bilinear sampling, undistortion.
//! - [`sequence`]: posed RGB-D sequences (TUM, ICL-NUIM, DeepVideoMVS / 7-Scenes, stereo pairs).
//! - [`eval`]: depth metrics and the photometric warp check.
//! - [`nn`]: the feature network (the paper's CNN), its kernels and PyTorch-compatible weights.
//! - [`normals_net`]: the built-in surface-normal predictor (trunk + head) for the normal prior.
//! - [`runtime`]: the CPU-feature probe, thread pools and the median every command shares.
//! - [`perf`]: benchmark inputs, the SGEMM peak and CPU time for `densefeat bench` and `benches/`.
//! - [`plot`]: line plots and grids of them as PNG (diagnostics such as cost curves).
//! - [`testing`]: error-budget comparisons shared by the test suites.
//! - [`train`]: the paper's deeply supervised cost-volume loss, backpropagation and the trainer.
//! - [`synth`]: a deterministic renderer of textured rooms with exact depth.
//!
//! ```
//! use densefeat::geometry::{PinholeCamera, Pose, Warp};
//! let k = PinholeCamera::new(500.0, 500.0, 319.5, 239.5, 640, 480).unwrap();
//! // The identity pose maps every pixel to itself at any inverse depth, including ρ = 0.
//! let w = Warp::new(&k, &k, &Pose::identity()).apply(100.0, 50.0, 0.0).unwrap();
//! assert_eq!((w.uv.x, w.uv.y), (100.0, 50.0));
//! ```
//!
//! Determinism: every parallel kernel splits work over independent outputs, so results are
//! bit-identical for any thread count on a given build and target.
#![deny(missing_docs)]
#![deny(rustdoc::broken_intra_doc_links)]

pub mod backend;
pub mod costvolume;
pub mod dsift;
pub mod dtam;
pub mod error;
pub mod eval;
pub mod fusion;
pub mod geometry;
pub mod image;
pub mod io;
pub mod mapping;
pub mod memory;
pub mod nn;
pub mod normals_net;
pub mod ops;
pub mod perf;
pub mod plot;
pub mod progress;
pub mod runtime;
pub mod sequence;
pub mod synth;
pub mod testing;
pub mod train;
pub mod util;

pub use error::{Error, Result};
