//! Training frames kept in memory once read or rendered (SPEC.md §13.5): decoding a real frame
//! and ray-tracing a synthetic one cost more than the training step that uses them. The cache is
//! transparent (a frame is a pure function of its key), so it never changes a result; it is
//! bounded by a byte budget, and frames past the budget are made again on every use.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use ndarray::{s, Array2, Array3};

use crate::error::Result;
use crate::geometry::{PinholeCamera, Pose};

/// One frame: image (0-255), depth (metres, 0 invalid), camera-to-world pose, its camera.
#[derive(Clone, Debug)]
pub(crate) struct Frame {
    rgb: Rgb,
    /// Depth `[H, W]`.
    pub depth: Array2<f32>,
    /// Camera-to-world pose.
    pub pose: Pose,
    /// The frame's camera (a sequence may have one per frame, SPEC.md §4a).
    pub camera: PinholeCamera,
}

/// The image, as bytes when that is lossless (decoded 8-bit images and the realistic renderer's
/// JPEG output), else as floats.
#[derive(Clone, Debug)]
enum Rgb {
    U8(Array3<u8>),
    F32(Array3<f32>),
}

impl Frame {
    /// A frame from an f32 image, stored as bytes if every value is an integer in 0..=255.
    pub fn new(rgb: Array3<f32>, depth: Array2<f32>, pose: Pose, camera: PinholeCamera) -> Self {
        let bytes = rgb.iter().all(|&v| (0.0..=255.0).contains(&v) && v.fract() == 0.0);
        let rgb = if bytes { Rgb::U8(rgb.mapv(|v| v as u8)) } else { Rgb::F32(rgb) };
        Frame { rgb, depth, pose, camera }
    }

    /// The image window of `h x w` pixels at `(x0, y0)`, as f32 (the exact stored values).
    pub fn rgb_window(&self, x0: usize, y0: usize, w: usize, h: usize) -> Array3<f32> {
        match &self.rgb {
            Rgb::U8(a) => a.slice(s![y0..y0 + h, x0..x0 + w, ..]).mapv(f32::from),
            Rgb::F32(a) => a.slice(s![y0..y0 + h, x0..x0 + w, ..]).to_owned(),
        }
    }

    /// Bytes held.
    fn bytes(&self) -> usize {
        let rgb = match &self.rgb {
            Rgb::U8(a) => a.len(),
            Rgb::F32(a) => 4 * a.len(),
        };
        rgb + 4 * self.depth.len()
    }
}

/// Which frame: frame `i` of training source `s`, or frame `i` of the synthetic scene `seed`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(crate) enum FrameKey {
    Sequence(usize, usize),
    Synthetic(u64, usize),
}

/// Frames by key, up to a byte budget.
#[derive(Debug)]
pub(crate) struct FrameCache {
    budget: usize,
    inner: Mutex<(usize, HashMap<FrameKey, Arc<Frame>>)>,
}

impl FrameCache {
    /// A cache holding at most `budget_bytes` of frames (0: none).
    pub fn new(budget_bytes: usize) -> Self {
        FrameCache { budget: budget_bytes, inner: Mutex::new((0, HashMap::new())) }
    }

    /// The frame `key`, from the cache or made by `make` (and kept if it fits the budget).
    ///
    /// # Errors
    /// Whatever `make` returns.
    pub fn get(&self, key: FrameKey, make: impl FnOnce() -> Result<Frame>) -> Result<Arc<Frame>> {
        if let Some(f) = self.lock().1.get(&key) {
            return Ok(Arc::clone(f));
        }
        let frame = Arc::new(make()?);
        let mut inner = self.lock();
        let size = frame.bytes();
        if inner.0 + size <= self.budget {
            inner.0 += size;
            inner.1.insert(key, Arc::clone(&frame));
        }
        Ok(frame)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (usize, HashMap<FrameKey, Arc<Frame>>)> {
        // A panic while holding the lock leaves a consistent map (inserts are single calls).
        self.inner.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}
