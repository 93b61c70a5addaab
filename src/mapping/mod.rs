//! Keyframe mapping: the features that fill the cost volume, the keyframe reconstruction (cost
//! volume of [`crate::costvolume`], regulariser of [`crate::dtam`]), its output files, and the
//! evaluation table over keyframes and methods (SPEC.md §11); the cost-curve diagnostic (§12.1);
//! keyframe selection and the whole-sequence map (§16.8).

pub mod costcurve;
pub mod depth_normals;
pub mod evaluate;
pub mod feature_cache;
pub mod features;
pub mod figure;
pub mod keyframe;
pub mod keyframe_select;
pub mod normals;
pub mod output;
pub mod parallax;
pub mod photometric;
pub mod refine;
pub mod resample;
pub mod sequence_map;

pub use evaluate::{evaluate, EvalOptions, EvalTable, Method};
pub use features::{FeatureExtractor, FeatureKind, FeatureMap};
pub use keyframe::{
    memory_estimate, reconstruct, reconstruct_cached, reconstruct_with, DepthEstimate, KeyframeConfig,
    KeyframeResult, Regularizer, Stage, StageTimings, Truncation, DEFAULT_TRUNCATION_B1,
    DEFAULT_TRUNCATION_DSIFT, DEFAULT_TRUNCATION_LEARNED, DEFAULT_TRUNCATION_PATCH7, DEFAULT_TRUNCATION_RGB,
};
pub use output::{write_outputs, write_outputs_with};
