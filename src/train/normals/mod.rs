//! Training the built-in normal predictor (SPEC.md §13.11, `densefeat train-normals`): single
//! frames (the reference crops of §13.5's training pairs), ground-truth normals from their depth,
//! the angular loss of [`crate::normals_net::head`], backpropagation through the head and the
//! trunk ([`crate::train::backprop`]), AdamW ([`crate::train::optim::adam_step_layers`]), a log,
//! checkpoints and exact resume.

pub mod checkpoint;
pub mod step;
pub mod trainer;
