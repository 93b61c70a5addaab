//! Training the feature network (paper §3.2, SPEC.md §13): the deeply supervised multi-view
//! cost-volume loss, backpropagation through the network, the optimiser, the data pipeline and the
//! trainer with checkpoints.

pub mod backprop;
pub mod checkpoint;
pub mod data;
pub(crate) mod frame_cache;
pub mod loss;
pub mod normals;
pub mod occlusion;
pub mod optim;
pub mod step;
pub mod trainer;
