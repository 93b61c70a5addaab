// The cost volume's `add_frame` (SPEC.md §9.1, §15.5): one invocation per cell (y, x, k) of the
// [H, W, K] volume (hypothesis fastest), so every cell's running sum and count are updated by
// exactly one invocation per frame, frames in submission order: no atomics, the same bits run
// after run.
//
// p = [cells, h', w, c, k, w'] (w the reference width, h' x w' the live map's size: the live frame
// has its own camera, SPEC.md §9.1)
// g = [R K⁻¹ row-major (9), t_nr (3), fx, fy, cx, cy, x_max, y_max, x_cap, y_cap, τ, ρ_0 .. ρ_{K-1}]
// (x_max = W-1, x_cap = max(W-2, 0), likewise for y; τ the per-frame truncation, SPEC.md §9.13,
// f32::MAX for none).

@group(0) @binding(0) var<storage, read> p: array<u32>;
@group(0) @binding(1) var<storage, read> g: array<f64>;
@group(0) @binding(2) var<storage, read> reference: array<f32>;
@group(0) @binding(3) var<storage, read> live: array<f32>;
@group(0) @binding(4) var<storage, read_write> sums: array<f32>;
@group(0) @binding(5) var<storage, read_write> counts: array<u32>;

const TAU: u32 = 20u;
const RHO0: u32 = 21u;

@compute @workgroup_size(64)
fn add_frame(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if (i >= p[0]) { return; }
    let lh = p[1];
    let w = p[2];
    let c = p[3];
    let kk = p[4];
    let lw = p[5];
    let k = i % kk;
    let pix = i / kk;
    let x = pix % w;
    let y = pix / w;
    let u = f64(x);
    let v = f64(y);
    // p = R K⁻¹ u̇ + ρ t with R K⁻¹ u̇ in nalgebra's order (`Warp::point`): (r0 u + r1 v) + r2.
    let rho = g[RHO0 + k];
    let px = ((g[0] * u + g[1] * v) + g[2]) + g[9] * rho;
    let py = ((g[3] * u + g[4] * v) + g[5]) + g[10] * rho;
    let pz = ((g[6] * u + g[7] * v) + g[8]) + g[11] * rho;
    // `Warp::apply_volume` (one division) and `image::sample`'s bounds (SPEC.md §2.1, §9.1). `p_z`
    // is finite: every input is.
    let inv = f64(1.0) / pz;
    let uu = g[12] * px * inv + g[14];
    let vv = g[13] * py * inv + g[15];
    if (!(pz > f64(0.0) && uu >= f64(0.0) && uu <= g[16] && vv >= f64(0.0) && vv <= g[17])) {
        return;
    }
    let x0 = min(floor(uu), g[18]);
    let y0 = min(floor(vv), g[19]);
    let fa = uu - x0;
    let fb = vv - y0;
    // The bilinear weights in f64, rounded to f32 (as the CPU's fast kernel).
    let w00 = f32((f64(1.0) - fa) * (f64(1.0) - fb));
    let w10 = f32(fa * (f64(1.0) - fb));
    let w01 = f32((f64(1.0) - fa) * fb);
    let w11 = f32(fa * fb);
    let o = (u32(y0) * lw + u32(x0)) * c;
    // On a 1-pixel-wide (-high) map the right (lower) corner aliases the left (upper) one.
    let dx = select(0u, c, lw > 1u);
    let dy = select(0u, lw * c, lh > 1u);
    let r = pix * c;
    var l1 = 0.0f;
    for (var ch = 0u; ch < c; ch++) {
        let s = w00 * live[o + ch] + w10 * live[o + dx + ch] + w01 * live[o + dy + ch]
            + w11 * live[o + dy + dx + ch];
        l1 += abs(reference[r + ch] - s);
    }
    sums[i] += min(l1, f32(g[TAU]));
    counts[i] += 1u;
}
