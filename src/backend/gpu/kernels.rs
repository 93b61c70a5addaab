//! The WGSL compute kernels of the GPU backend (SPEC.md §15.5). One invocation per output element,
//! each output written by exactly one invocation, sums in a fixed loop order, no atomics: the result
//! is the same bits run after run on one device.
//!
//! Every kernel sees binding 0 as `p: array<u32>` (its parameters, `p[0]` = number of outputs),
//! then its inputs, then its output; workgroups are 64 wide and laid out on a 2D grid
//! ([`super::GpuBackend`] splits large dispatches), so the flat output index is
//! `gid.x + gid.y * nwg.x * 64`.

/// The part every kernel shares: the parameter binding and the entry point's flat index.
const HEADER: &str = r"
@group(0) @binding(0) var<storage, read> p: array<u32>;
fn flat(gid: vec3<u32>, nwg: vec3<u32>) -> u32 { return gid.x + gid.y * nwg.x * 64u; }
";

/// `o = a + b`, elementwise (one f32 addition: exact like the CPU's).
pub(super) const ADD: &str = r"
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> o: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    o[i] = a[i] + b[i];
}
";

/// Channel concatenation; `p = [n, ca, cb]`.
pub(super) const CONCAT: &str = r"
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> o: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let ca = p[1];
    let cb = p[2];
    let c = ca + cb;
    let pix = i / c;
    let ch = i % c;
    if (ch < ca) {
        o[i] = a[pix * ca + ch];
    } else {
        o[i] = b[pix * cb + ch - ca];
    }
}
";

/// The top-left window; `p = [n, w_in, w, c]`.
pub(super) const CROP: &str = r"
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read_write> o: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let w_in = p[1];
    let w = p[2];
    let c = p[3];
    let ch = i % c;
    let pix = i / c;
    let x = pix % w;
    let y = pix / w;
    o[i] = a[(y * w_in + x) * c + ch];
}
";

/// The 2x tent of SPEC.md §7.4 in f64, the CPU's loop order and one rounding (bit-identical to
/// `nn::downsample2x`); `p = [n, h, w, c, w_out]`. Needs `Features::SHADER_F64`.
pub(super) const DOWNSAMPLE_F64: &str = r"
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read_write> o: array<f32>;
fn tap(j: u32, t: u32, n: u32) -> u32 {
    let v = 2u * j + t;
    if (v == 0u) { return 0u; }
    return min(v - 1u, n - 1u);
}
fn tent(t: u32) -> f64 {
    if (t == 1u) { return f64(0.5); }
    return f64(0.25);
}
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = p[1];
    let w = p[2];
    let c = p[3];
    let w_out = p[4];
    let ch = i % c;
    let pix = i / c;
    let ox = pix % w_out;
    let oy = pix / w_out;
    var acc = f64(0.0);
    for (var ta = 0u; ta < 3u; ta++) {
        let y = tap(oy, ta, h);
        for (var tb = 0u; tb < 3u; tb++) {
            let x = tap(ox, tb, w);
            acc += tent(ta) * tent(tb) * f64(a[(y * w + x) * c + ch]);
        }
    }
    o[i] = f32(acc);
}
";

/// 3x3 convolution, padding 1, stride 1/2, bias, optional ReLU (SPEC.md §7.2);
/// `p = [n, h, w, c_in, w_out, c_out, stride, relu, bias_offset]`; weights repacked to
/// `[c_out, ky, kx, c_in]` followed by the bias. Sum order: taps `(ky, kx)` row-major, channels
/// inside, bias last.
pub(super) const CONV3X3: &str = r"
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> wt: array<f32>;
@group(0) @binding(3) var<storage, read_write> o: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = i32(p[1]);
    let w = i32(p[2]);
    let cin = p[3];
    let w_out = p[4];
    let cout = p[5];
    let stride = p[6];
    let co = i % cout;
    let pix = i / cout;
    let ox = pix % w_out;
    let oy = pix / w_out;
    var acc = 0.0;
    for (var ky = 0u; ky < 3u; ky++) {
        let iy = i32(oy * stride + ky) - 1;
        if (iy < 0 || iy >= h) { continue; }
        for (var kx = 0u; kx < 3u; kx++) {
            let ix = i32(ox * stride + kx) - 1;
            if (ix < 0 || ix >= w) { continue; }
            let xb = u32(iy * w + ix) * cin;
            let wb = ((co * 3u + ky) * 3u + kx) * cin;
            for (var c = 0u; c < cin; c++) {
                acc += wt[wb + c] * x[xb + c];
            }
        }
    }
    acc += wt[p[8] + co];
    if (p[7] != 0u) { acc = max(acc, 0.0); }
    o[i] = acc;
}
";

/// 5x5 stride-2 transposed convolution (padding 2, output padding 1; SPEC.md §7.3) as a gather:
/// output `o` takes input `i` through tap `k = o + 2 - 2i`; `p = [n, h, w, c_in, c_out, bias_offset]`;
/// weights repacked to `[c_out, ky, kx, c_in]` followed by the bias. Sum order: taps row-major,
/// channels inside, bias last.
pub(super) const DECONV5X5S2: &str = r"
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read> wt: array<f32>;
@group(0) @binding(3) var<storage, read_write> o: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = i32(p[1]);
    let w = i32(p[2]);
    let cin = p[3];
    let cout = p[4];
    let w_out = 2u * p[2];
    let co = i % cout;
    let pix = i / cout;
    let ox = i32(pix % w_out);
    let oy = i32(pix / w_out);
    var acc = 0.0;
    for (var ky = 0; ky < 5; ky++) {
        let ty = oy + 2 - ky;
        if (ty < 0 || (ty & 1) != 0 || ty / 2 >= h) { continue; }
        let iy = ty / 2;
        for (var kx = 0; kx < 5; kx++) {
            let tx = ox + 2 - kx;
            if (tx < 0 || (tx & 1) != 0 || tx / 2 >= w) { continue; }
            let ix = tx / 2;
            let xb = u32(iy * w + ix) * cin;
            let wb = ((co * 5u + u32(ky)) * 5u + u32(kx)) * cin;
            for (var c = 0u; c < cin; c++) {
                acc += wt[wb + c] * x[xb + c];
            }
        }
    }
    o[i] = acc + wt[p[5] + co];
}
";

/// A kernel's full WGSL source: the shared header, then its body.
pub(super) fn source(body: &str) -> String {
    format!("{HEADER}{body}")
}
