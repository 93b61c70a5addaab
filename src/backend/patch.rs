//! The patch volume of `--features patch7` (SPEC.md §9a.5) as a [`VolumeBuilder`]: CPU only, on
//! host images.

use crate::backend::{Tensor, VolumeBuilder};
use crate::costvolume::patch::PatchVolume;
use crate::costvolume::CostVolume;
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};

impl VolumeBuilder for PatchVolume {
    fn add_frame_seen_by(&mut self, live: &Tensor, camera: &PinholeCamera, t_nr: &Pose) -> Result<()> {
        let Some(live) = live.as_host() else {
            return Err(Error::Unsupported {
                backend: live.location().into(),
                what: "the patch7 cost volume runs on the CPU only: pass host images".into(),
            });
        };
        PatchVolume::add_frame_seen_by(self, live, camera, t_nr)
    }
    fn camera(&self) -> &PinholeCamera {
        PatchVolume::camera(self)
    }
    fn frames(&self) -> usize {
        PatchVolume::frames(self)
    }
    fn snapshot(&self) -> Result<CostVolume> {
        self.clone().into_cost_volume()
    }
    fn finish(self: Box<Self>) -> Result<CostVolume> {
        self.into_cost_volume()
    }
}
