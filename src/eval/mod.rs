//! Evaluation: the depth metrics of Eigen et al. (the paper's Table 1), and (re-exported from
//! [`crate::sequence`], where `inspect` uses it) the photometric warp check that proves the
//! geometric conventions on real data.

mod metrics;

pub use crate::sequence::warp_check::{photometric_warp_check, WarpCheck};
pub use metrics::{depth_metrics, DepthMetrics};
