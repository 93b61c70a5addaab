//! Fresh activation maps (SPEC.md §8.9): zeroed `f32` storage whose large allocations are advised
//! onto transparent huge pages.
//!
//! A 640x480x32 map is 39 MB. The allocator hands such a block out as fresh pages from the OS
//! (`calloc` of an `mmap`ed block, no memset), and the kernel then zero-fills it on first touch one
//! 4 KB page at a time: about 9600 page faults per map, 30 000 per 640x480 forward pass, which
//! `bench forward --profile` charged to whichever op first wrote the map (10-15 ms on a 39 MB map).
//! With `madvise(MADV_HUGEPAGE)` on the block before it is touched the kernel backs it with 2 MB
//! pages where the system allows it (`/sys/kernel/mm/transparent_hugepage/enabled` set to `always`
//! or `madvise`): 20 faults per map, and fewer TLB misses for the kernels that stream it. The advice
//! changes how memory is backed, never its contents; where it is refused or unavailable nothing
//! changes.

use ndarray::{Array1, Array3};

/// Allocations at least this large are advised (smaller ones rarely span a whole huge page).
const MIN_ADVISED_BYTES: usize = 4 << 20;

/// The transparent huge page size on x86-64 and most aarch64 kernels.
const HUGE_PAGE_BYTES: usize = 2 << 20;

/// `n` zeros, the allocation advised onto huge pages when it is large.
pub fn zeroed_vec(n: usize) -> Vec<f32> {
    zeroed(n)
}

/// A zeroed `shape` map on [`zeroed_vec`] storage (standard layout).
pub fn zeroed_map(shape: [usize; 3]) -> Array3<f32> {
    let v = zeroed_vec(shape.iter().product());
    let Ok(a) = Array3::from_shape_vec(shape, v) else { unreachable!("length is the shape's product") };
    a
}

/// The cache line size the aligned allocations start on.
const LINE_BYTES: usize = 64;

/// A zeroed `shape` map like [`zeroed_map`] whose first value starts a 64-byte cache line (an
/// owned array with an offset into its storage, [`zeroed_aligned`]; its values and layout are
/// [`zeroed_map`]'s). Kernels that load whole 64-byte chunks (the cost volume's block kernel, SPEC.md
/// §9.4) then read it without an aligned copy.
pub fn zeroed_map_aligned(shape: [usize; 3]) -> Array3<f32> {
    let line = zeroed_aligned::<f32>(shape.iter().product());
    let Ok(a) = line.into_shape_with_order(shape) else { unreachable!("length is the shape's product") };
    a
}

/// `n` zeros of a plain number type (`f32`, `f64`, `u16`, ...) whose first value starts a 64-byte
/// cache line, on huge pages when large (as [`zeroed`]): the storage is up to 63 bytes longer and the
/// array starts at its first line boundary. A kernel whose 64-byte (or 32-byte) accesses lie at
/// multiples of their size from the start then never splits one across two lines (a large `malloc`
/// block starts 16 bytes past a page boundary, which split every other one).
pub fn zeroed_aligned<T: Clone + Default>(n: usize) -> Array1<T> {
    let size = std::mem::size_of::<T>();
    assert!(size > 0 && LINE_BYTES.is_multiple_of(size), "a plain number type");
    let v = zeroed::<T>(n + LINE_BYTES / size - 1);
    // `T`'s storage is aligned to its size (plain number types), so a line boundary is a whole
    // number of values in, fewer than `LINE_BYTES / size`.
    let skip = (v.as_ptr() as usize).next_multiple_of(LINE_BYTES).wrapping_sub(v.as_ptr() as usize) / size;
    Array1::from_vec(v).slice_move(ndarray::s![skip..skip + n])
}

/// `n` zeros of a plain number type (`f32`, `f64`, `u16`, ...), the allocation advised onto huge
/// pages when it is large (as [`zeroed_vec`]).
pub fn zeroed<T: Clone + Default>(n: usize) -> Vec<T> {
    let v = vec![T::default(); n];
    advise_huge_pages(&v);
    v
}

/// Asks the kernel to back the whole 2 MB pages inside `v` with huge pages (best effort).
#[cfg(target_os = "linux")]
fn advise_huge_pages<T>(v: &[T]) {
    let bytes = std::mem::size_of_val(v);
    if bytes < MIN_ADVISED_BYTES {
        return;
    }
    let start = v.as_ptr() as usize;
    let lo = start.next_multiple_of(HUGE_PAGE_BYTES);
    let hi = (start + bytes) / HUGE_PAGE_BYTES * HUGE_PAGE_BYTES;
    if hi > lo {
        // SAFETY: `lo .. hi` lies inside `v`'s allocation and is page-aligned; MADV_HUGEPAGE only
        // changes how the kernel backs those pages, never their contents or validity. The result
        // is ignored: the advice is optional (THP may be disabled).
        unsafe {
            libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages<T>(_: &[T]) {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zeroed_maps_are_zero_and_standard_layout_at_advised_sizes() {
        for shape in [[1, 1, 1], [480, 640, 32], [17, 13, 35]] {
            let m = zeroed_map(shape);
            assert_eq!(m.shape(), &shape);
            assert!(m.is_standard_layout());
            assert!(m.iter().all(|v| v.to_bits() == 0));
            let a = zeroed_map_aligned(shape);
            assert_eq!(a.shape(), &shape);
            assert!(a.is_standard_layout() && a.as_slice().is_some());
            assert!((a.as_ptr() as usize).is_multiple_of(64), "{shape:?}");
            assert!(a.iter().all(|v| v.to_bits() == 0));
        }
    }

    #[test]
    fn aligned_zeros_start_a_cache_line() {
        fn check<T: Clone + Default>(n: usize, is_zero: fn(&T) -> bool) {
            let a = zeroed_aligned::<T>(n);
            assert_eq!(a.len(), n);
            // (An empty array has nothing to align.)
            assert!(a.as_slice().is_some() && (n == 0 || (a.as_ptr() as usize).is_multiple_of(64)), "{n}");
            assert!(a.iter().all(is_zero));
        }
        for n in [0, 1, 17, 3 << 20] {
            check::<u16>(n, |&v| v == 0);
            check::<f64>(n, |v| v.to_bits() == 0);
        }
    }
}

thread_local! {
    /// This thread's reusable buffer for [`with_scratch`].
    static SCRATCH: std::cell::Cell<Vec<f32>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Runs `f` on a buffer of `len` f32 that **`f` must overwrite entirely before reading** (im2col
/// columns, GEMM outputs with β = 0): its initial contents are whatever a previous user left (NaN
/// in debug builds, so a read before a write shows in the tests). The buffer is this thread's,
/// kept between calls, so the large column buffers of the backward pass cost no allocation, page
/// faults or zeroing per call. Re-entrant: a nested call on the same thread (rayon may run another
/// job while `f` waits) gets a fresh buffer.
pub fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [f32]) -> R) -> R {
    let mut buf = SCRATCH.with(std::cell::Cell::take);
    if buf.len() < len {
        buf.resize(len, 0.0);
    }
    if cfg!(debug_assertions) {
        buf[..len].fill(f32::NAN);
    }
    let r = f(&mut buf[..len]);
    // Keep the larger of this buffer and one a nested call may have left.
    SCRATCH.with(|c| {
        let other = c.take();
        c.set(if other.capacity() > buf.capacity() { other } else { buf });
    });
    r
}
