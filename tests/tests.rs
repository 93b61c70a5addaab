//! The integration tests, one binary (issue 33 item 5): one module per area, the shared furniture
//! in `common`. The parity suite (`tests/parity.rs`: every backend this build has against the f64
//! reference) is a module here in a build without `gpu`, and its own target, built only with
//! `--features gpu` (`cargo test --features gpu --test parity`, CI on lavapipe).

mod common;

mod cli;
mod cli_defaults;
mod costcurve;
mod costvolume;
mod depth_normals;
mod dsift;
mod dtam;
mod dtam_normals;
mod dtam_tgv;
mod feature_baselines;
mod features_cli;
mod fusion;
mod fusion_consistency;
mod fuzz;
mod geometry;
mod image_ops;
mod layering;
mod malformed;
mod mapping;
mod mapping_level0;
mod network;
mod nn_backward;
mod nn_kernels;
mod nn_winograd;
mod nn_winograd_deconv;
mod normals_net;
#[cfg(not(feature = "gpu"))]
mod parallax;
mod parity;
mod patch_volume;
mod photometric;
mod plot;
mod readers;
mod refine;
mod reliability;
mod synth;
mod synth_real;
mod train_augment;
mod train_backprop;
mod train_deep_weight;
mod train_hinge;
mod train_loop;
mod train_loss;
mod train_occlusion;
mod warp;
mod weights;
