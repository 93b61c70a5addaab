//! Features of frames already extracted, kept for the next keyframes of a `map` run (SPEC.md
//! §16.12). Keyframe windows overlap (a frame is a live frame of several keyframes) and slide
//! forward, so the cache keeps the frames with the highest indices that fit its byte budget. A frame's
//! features depend on its image alone, so a hit gives the same bits as extracting again; frames whose
//! photometric correction is not the identity belong to one keyframe and are never cached.

use std::collections::BTreeMap;

use ndarray::Array3;

/// Default budget of `map`'s cache, MiB (`--feature-cache-mb`); it also stays under the headroom
/// that `--max-memory-mb` leaves beside each keyframe.
pub const DEFAULT_FEATURE_CACHE_MB: usize = 512;

/// The cache (module docs).
#[derive(Debug, Default)]
pub struct FeatureCache {
    budget: u64,
    capacity: usize,
    frames: BTreeMap<usize, Array3<f32>>,
    hits: usize,
    misses: usize,
}

impl FeatureCache {
    /// An empty cache of at most `budget_bytes` (0: caches nothing).
    pub fn new(budget_bytes: u64) -> Self {
        FeatureCache { budget: budget_bytes, ..Default::default() }
    }

    /// Size the cache for frames of `frame_bytes` each, within its budget and `headroom` bytes (what
    /// the memory limit leaves beside the keyframe's own work); frames beyond the new capacity go,
    /// lowest indices first. Returns the capacity in frames.
    pub fn fit(&mut self, frame_bytes: u64, headroom: u64) -> usize {
        self.capacity = self.budget.min(headroom).checked_div(frame_bytes).map_or(0, |n| n as usize);
        while self.frames.len() > self.capacity {
            self.frames.pop_first();
        }
        self.capacity
    }

    /// The features of frame `index`, if cached (counted as a hit or a miss).
    pub fn get(&mut self, index: usize) -> Option<&Array3<f32>> {
        let found = self.frames.get(&index);
        if found.is_some() {
            self.hits += 1;
        } else {
            self.misses += 1;
        }
        found
    }

    /// Offer frame `index`'s features: kept (a copy) while there is room, or in place of the
    /// lowest-indexed frame when `index` is higher; otherwise not.
    pub fn offer(&mut self, index: usize, features: &Array3<f32>) {
        if self.capacity == 0 || self.frames.contains_key(&index) {
            return;
        }
        if self.frames.len() >= self.capacity {
            match self.frames.first_key_value() {
                Some((&lowest, _)) if lowest < index => {
                    self.frames.pop_first();
                }
                _ => return,
            }
        }
        self.frames.insert(index, features.clone());
    }

    /// Frames held now.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is held.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Lookups that found their frame, and those that did not.
    pub fn hits_and_misses(&self) -> (usize, usize) {
        (self.hits, self.misses)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(v: f32) -> Array3<f32> {
        Array3::from_elem((2, 2, 2), v)
    }

    #[test]
    fn keeps_the_highest_frames_within_its_budget() {
        let bytes = 4 * 8;
        let mut c = FeatureCache::new(3 * bytes + 5);
        assert_eq!(c.fit(bytes, u64::MAX), 3);
        for i in [4, 2, 7] {
            c.offer(i, &frame(i as f32));
        }
        // Full: a lower frame is not taken, a higher one replaces the lowest.
        c.offer(1, &frame(1.0));
        assert!(c.get(1).is_none());
        c.offer(9, &frame(9.0));
        assert!(c.get(2).is_none());
        assert_eq!(c.get(9).unwrap()[[0, 0, 0]], 9.0);
        assert_eq!(c.get(4).unwrap()[[1, 1, 1]], 4.0);
        assert_eq!(c.len(), 3);
        // A frame already held is not copied again.
        c.offer(9, &frame(-1.0));
        assert_eq!(c.get(9).unwrap()[[0, 0, 0]], 9.0);
        assert_eq!(c.hits_and_misses(), (3, 2));
        // Less headroom: the lowest frames go.
        assert_eq!(c.fit(bytes, bytes), 1);
        assert_eq!(c.len(), 1);
        assert!(c.get(9).is_some() && c.get(7).is_none());
    }

    #[test]
    fn a_zero_budget_holds_nothing() {
        let mut c = FeatureCache::new(0);
        assert_eq!(c.fit(32, u64::MAX), 0);
        c.offer(3, &frame(3.0));
        assert!(c.is_empty() && c.get(3).is_none());
        let mut c = FeatureCache::new(1 << 20);
        assert_eq!(c.fit(0, u64::MAX), 0, "empty features are not cached");
    }
}
