//! Validated shapes of the network's kernels (SPEC.md §7.1). This file is the only place where the
//! output-size formulas live; every kernel takes one of these types and trusts it.
//!
//! | op | input | output |
//! |---|---|---|
//! | conv 3x3, padding 1, stride `s ∈ {1, 2}` | `[H, W, C_in]` | `[(H + 2 - 3)/s + 1, (W + 2 - 3)/s + 1, C_out]` |
//! | transposed conv 5x5, stride 2, padding 2, output padding 1 | `[H, W, C_in]` | `[2H, 2W, C_out]` |
//! | 2x tent downsampling | `[H, W, C]` | `[ceil(H/2), ceil(W/2), C]` |

use crate::error::{Error, Result};

/// Side of the square convolution kernel.
pub const CONV_KERNEL: usize = 3;
/// Zero padding on every side of the convolution input.
pub const CONV_PADDING: usize = 1;
/// Side of the square transposed-convolution kernel.
pub const DECONV_KERNEL: usize = 5;
/// Stride of the transposed convolution.
pub const DECONV_STRIDE: usize = 2;
/// Padding of the transposed convolution (PyTorch `padding`): output `o = 2 i - 2 + k`.
pub const DECONV_PADDING: usize = 2;
/// Extra rows/columns at the bottom/right of the transposed convolution's output (PyTorch
/// `output_padding`).
pub const DECONV_OUTPUT_PADDING: usize = 1;

/// Output length of a 3x3, padding-1 convolution along one axis of length `n >= 1`.
fn conv_out_len(n: usize, stride: usize) -> usize {
    (n + 2 * CONV_PADDING - CONV_KERNEL) / stride + 1
}

/// Output length of the 5x5 stride-2 transposed convolution along one axis: PyTorch's
/// `(n - 1) s - 2 p + k + output_padding`, which is `2 n`.
fn deconv_out_len(n: usize) -> usize {
    (n - 1) * DECONV_STRIDE + DECONV_KERNEL + DECONV_OUTPUT_PADDING - 2 * DECONV_PADDING
}

/// Output length of the 2x downsampling along one axis: `ceil(n / 2)`.
fn downsample_out_len(n: usize) -> usize {
    n.div_ceil(2)
}

/// Largest size along any axis: keeps `2n + 4` and signed pixel offsets far from overflow.
const MAX_DIM: usize = (isize::MAX / 8) as usize;

/// Checks that every size is positive and at most [`MAX_DIM`], and that their product (an element
/// count) fits in `usize`.
fn check_sizes(op: &str, sizes: &[(&str, usize)]) -> Result<()> {
    let mut total: usize = 1;
    for &(name, value) in sizes {
        if value == 0 {
            return Err(Error::invalid_argument(format!("{op} {name}"), "must be at least 1"));
        }
        if value > MAX_DIM {
            return Err(Error::invalid_argument(
                format!("{op} {name}"),
                format!("{value} exceeds {MAX_DIM}"),
            ));
        }
        total = total.checked_mul(value).ok_or_else(|| {
            Error::invalid_argument(op.to_string(), format!("element count overflows with {name} = {value}"))
        })?;
    }
    Ok(())
}

/// Shape of a 3x3 convolution with zero padding 1 and stride 1 or 2 (`torch.nn.Conv2d(c_in, c_out,
/// 3, stride, padding=1)`), on a channels-last `[h, w, c_in]` input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Conv2dGeometry {
    h: usize,
    w: usize,
    c_in: usize,
    c_out: usize,
    stride: usize,
}

impl Conv2dGeometry {
    /// Validates a convolution shape.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if a size is zero, the stride is not 1 or 2, or an element count
    /// overflows `usize`.
    pub fn new(h: usize, w: usize, c_in: usize, c_out: usize, stride: usize) -> Result<Self> {
        if stride != 1 && stride != 2 {
            return Err(Error::invalid_argument("conv2d stride", format!("must be 1 or 2, got {stride}")));
        }
        check_sizes("conv2d", &[("h", h), ("w", w), ("c_in", c_in), ("c_out", c_out)])?;
        let g = Conv2dGeometry { h, w, c_in, c_out, stride };
        check_sizes("conv2d", &[("h_out", g.h_out()), ("w_out", g.w_out()), ("k", g.k()), ("c_out", c_out)])?;
        Ok(g)
    }
    /// Input height.
    pub fn h(&self) -> usize {
        self.h
    }
    /// Input width.
    pub fn w(&self) -> usize {
        self.w
    }
    /// Input channels.
    pub fn c_in(&self) -> usize {
        self.c_in
    }
    /// Output channels.
    pub fn c_out(&self) -> usize {
        self.c_out
    }
    /// Stride (1 or 2).
    pub fn stride(&self) -> usize {
        self.stride
    }
    /// Output height `(h + 2 - 3)/s + 1` (`ceil(h/2)` for stride 2).
    pub fn h_out(&self) -> usize {
        conv_out_len(self.h, self.stride)
    }
    /// Output width `(w + 2 - 3)/s + 1`.
    pub fn w_out(&self) -> usize {
        conv_out_len(self.w, self.stride)
    }
    /// Number of products per output value, `9 c_in` (the GEMM's inner dimension).
    pub fn k(&self) -> usize {
        CONV_KERNEL * CONV_KERNEL * self.c_in
    }
    /// Input shape `[h, w, c_in]`.
    pub fn input_shape(&self) -> [usize; 3] {
        [self.h, self.w, self.c_in]
    }
    /// Output shape `[h_out, w_out, c_out]`.
    pub fn output_shape(&self) -> [usize; 3] {
        [self.h_out(), self.w_out(), self.c_out]
    }
    /// PyTorch weight shape `[c_out, c_in, 3, 3]`.
    pub fn weight_shape(&self) -> [usize; 4] {
        [self.c_out, self.c_in, CONV_KERNEL, CONV_KERNEL]
    }
    /// Floating-point operations of one evaluation, `2 k h_out w_out c_out` (bias and ReLU not counted).
    pub fn flops(&self) -> f64 {
        2.0 * self.k() as f64 * self.h_out() as f64 * self.w_out() as f64 * self.c_out as f64
    }
}

/// Shape of the 5x5 transposed convolution with stride 2, padding 2, output padding 1
/// (`torch.nn.ConvTranspose2d(c_in, c_out, 5, stride=2, padding=2, output_padding=1)`), on a
/// channels-last `[h, w, c_in]` input. The output is `[2h, 2w, c_out]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Deconv2dGeometry {
    h: usize,
    w: usize,
    c_in: usize,
    c_out: usize,
}

impl Deconv2dGeometry {
    /// Validates a transposed-convolution shape.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if a size is zero or an element count overflows `usize`.
    pub fn new(h: usize, w: usize, c_in: usize, c_out: usize) -> Result<Self> {
        check_sizes("deconv2d", &[("h", h), ("w", w), ("c_in", c_in), ("c_out", c_out)])?;
        let g = Deconv2dGeometry { h, w, c_in, c_out };
        check_sizes(
            "deconv2d",
            &[("h_out", g.h_out()), ("w_out", g.w_out()), ("k", g.k()), ("c_out", c_out)],
        )?;
        check_sizes(
            "deconv2d",
            &[("c_in", c_in), ("c_out", c_out), ("kernel", DECONV_KERNEL * DECONV_KERNEL)],
        )?;
        Ok(g)
    }
    /// Input height.
    pub fn h(&self) -> usize {
        self.h
    }
    /// Input width.
    pub fn w(&self) -> usize {
        self.w
    }
    /// Input channels.
    pub fn c_in(&self) -> usize {
        self.c_in
    }
    /// Output channels.
    pub fn c_out(&self) -> usize {
        self.c_out
    }
    /// Output height `2 h`.
    pub fn h_out(&self) -> usize {
        deconv_out_len(self.h)
    }
    /// Output width `2 w`.
    pub fn w_out(&self) -> usize {
        deconv_out_len(self.w)
    }
    /// Largest number of products in one output value, `9 c_in` (outputs of even row and column
    /// parity receive 3x3 taps, the others 3x2, 2x3 or 2x2).
    pub fn k(&self) -> usize {
        9 * self.c_in
    }
    /// Input shape `[h, w, c_in]`.
    pub fn input_shape(&self) -> [usize; 3] {
        [self.h, self.w, self.c_in]
    }
    /// Output shape `[2h, 2w, c_out]`.
    pub fn output_shape(&self) -> [usize; 3] {
        [self.h_out(), self.w_out(), self.c_out]
    }
    /// PyTorch weight shape `[c_in, c_out, 5, 5]`.
    pub fn weight_shape(&self) -> [usize; 4] {
        [self.c_in, self.c_out, DECONV_KERNEL, DECONV_KERNEL]
    }
}

/// Shape of the 2x tent downsampling of a channels-last `[h, w, c]` image (SPEC.md §2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DownsampleGeometry {
    h: usize,
    w: usize,
    c: usize,
}

impl DownsampleGeometry {
    /// Validates a downsampling shape.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if a size is zero or the element count overflows `usize`.
    pub fn new(h: usize, w: usize, c: usize) -> Result<Self> {
        check_sizes("downsample", &[("h", h), ("w", w), ("c", c)])?;
        Ok(DownsampleGeometry { h, w, c })
    }
    /// Input shape `[h, w, c]`.
    pub fn input_shape(&self) -> [usize; 3] {
        [self.h, self.w, self.c]
    }
    /// Output shape `[ceil(h/2), ceil(w/2), c]`.
    pub fn output_shape(&self) -> [usize; 3] {
        [downsample_out_len(self.h), downsample_out_len(self.w), self.c]
    }
}
