//! The built-in surface-normal predictor (SPEC.md §13.11, `--normals learned`): a feature network
//! of its own (the architecture of §8.1, its own weights, so retraining the matching features
//! never invalidates it) with a 3x3 convolution head `C -> 3` on the aggregated features, whose
//! output is normalised per pixel and oriented towards the camera.
//!
//! - [`weights`]: the parameters, their initialisation and the file `normalnet.safetensors`.
//! - [`head`]: the head, the angular loss and their backward passes (fast f32 and f64 reference).
//! - [`predict`]: inference and upsampling to the input resolution; angular-error statistics.
//! - [`file`](mod@file): the f32 safetensors writer and checked reader the files share.
//!
//! Training is [`crate::train::normals`].

pub mod file;
pub mod head;
pub mod predict;
pub mod weights;

pub use head::{NormalLossSums, PixelTerms};
pub use predict::{upsample_normals, NormalNet};
pub use weights::{NormalNetWeights, HEAD_SEED, NORMALNET_FORMAT};

/// The shipped trained predictor's bytes (`fixtures/weights/normalnet.safetensors`, compiled in;
/// its model card is `fixtures/weights/MODEL_CARD_normalnet.md`). `Option` so that a build without
/// a trained predictor stays expressible: every caller handles `None` with an error naming
/// `--normal-weights`.
pub const SHIPPED_NORMAL_WEIGHTS: Option<&[u8]> =
    Some(include_bytes!("../../fixtures/weights/normalnet.safetensors"));

/// The name [`SHIPPED_NORMAL_WEIGHTS`] is reported under.
pub const SHIPPED_NORMAL_WEIGHTS_NAME: &str = "fixtures/weights/normalnet.safetensors (built in)";
