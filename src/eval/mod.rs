//! Evaluation: the depth metrics of Eigen et al. (the paper's Table 1) and the photometric warp
//! check that proves the geometric conventions on real data.

mod metrics;
mod photometric;

pub use metrics::{depth_metrics, DepthMetrics};
pub use photometric::{photometric_warp_check, WarpCheck};
