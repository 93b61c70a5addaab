//! What densefeat's criterion benches (`cargo bench -p densefeat-benches --bench NAME`) and speed
//! examples share; the package is kept out of the root so that `cargo test` does not build criterion.

/// The convolution shapes timed: (h, w, c_in, c_out, stride). B1's first layer is 3 -> 32; the
/// 35-channel inputs are a coarser block's 32 features concatenated with the downsampled RGB image.
pub const CONV_SHAPES: [(usize, usize, usize, usize, usize); 5] = [
    (240, 320, 32, 32, 1),
    (120, 160, 35, 32, 2),
    (240, 320, 35, 32, 2),
    (240, 320, 3, 32, 1),
    (480, 640, 32, 32, 1),
];
