//! Keyframe mapping: the features that fill the cost volume, and (with the cost volume of
//! [`crate::costvolume`] and the regulariser of [`crate::dtam`]) the keyframe reconstruction.

pub mod features;

pub use features::{FeatureExtractor, FeatureKind, FeatureMap};
