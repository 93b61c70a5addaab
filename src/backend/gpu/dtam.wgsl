// DTAM's Huber-TV solve (SPEC.md §10, §15.5) as six kernels over device-resident state. Every
// per-pixel value is the CPU definition's sequence of f64 operations (`dtam::solve_reference`:
// `HuberTv::step_reference`, `search_pixel`, `total_energy`, `rms_gap`, `regulariser_energy`);
// every sum runs in the definition's order (per row, x ascending, in `rows`; then rows in order,
// in `total`), one invocation per output: no atomics, no workgroup reductions.
//
// p = [pixels, h, w, k, UNSEEN_COST bits]
// c = [σ = τ, ε, 1/(1 + σε), λ, ρ_min, Δρ, K-1, 1/λ,  (global)
//      θ, 2θ, 1/(1 + τ/θ), 1/(2θ),                  (this iteration: copied in per iteration)
//      ρ_0 .. ρ_{K-1}]
// q = (qx, qy) interleaved per pixel; range = (C_min, C_max) per pixel (C_min > C_max: nothing
// seen); terms = (regulariser, coupling, data, gap²) per pixel; rows = the same sums per row;
// measure = (E_θ, rms gap).

@group(0) @binding(0) var<storage, read> p: array<u32>;
@group(0) @binding(1) var<storage, read> c: array<f64>;
@group(0) @binding(2) var<storage, read> costs: array<f32>;
@group(0) @binding(3) var<storage, read_write> range: array<f32>;
@group(0) @binding(4) var<storage, read_write> d: array<f32>;
@group(0) @binding(5) var<storage, read_write> d_bar: array<f32>;
@group(0) @binding(6) var<storage, read> g: array<f32>;
@group(0) @binding(7) var<storage, read_write> q: array<f32>;
@group(0) @binding(8) var<storage, read_write> a: array<f32>;
@group(0) @binding(9) var<storage, read_write> terms: array<f64>;
@group(0) @binding(10) var<storage, read_write> rows: array<f64>;
@group(0) @binding(11) var<storage, read_write> measure: array<f64>;

const STEP: u32 = 0u;
const EPS: u32 = 1u;
const DUAL_SCALE: u32 = 2u;
const LAMBDA: u32 = 3u;
const RHO_MIN: u32 = 4u;
const DELTA: u32 = 5u;
const LAST: u32 = 6u;
const INV_LAMBDA: u32 = 7u;
const THETA: u32 = 8u;
const TWO_THETA: u32 = 9u;
const PRIMAL_SCALE: u32 = 10u;
const INV_TWO_THETA: u32 = 11u;
const RHO0: u32 = 12u;

fn flat(gid: vec3<u32>, nwg: vec3<u32>) -> u32 { return gid.x + gid.y * nwg.x * 64u; }

fn unseen() -> f32 { return bitcast<f32>(p[4]); }

// Per pixel: the extreme seen costs (`CostRange::new`).
@compute @workgroup_size(64)
fn cost_range(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let kk = p[3];
    var lo = 1.0f;
    var hi = 0.0f;
    var found = false;
    for (var k = 0u; k < kk; k++) {
        let v = costs[i * kk + k];
        if (v < unseen()) {
            if (found) {
                lo = min(lo, v);
                hi = max(hi, v);
            } else {
                lo = v;
                hi = v;
                found = true;
            }
        }
    }
    range[2u * i] = lo;
    range[2u * i + 1u] = hi;
}

// q ← Π_{|q|<=1}((q + σ g ∇d̄) · 1/(1 + σε)), Π(n) = n · 1/max(|n|, 1).
@compute @workgroup_size(64)
fn dual(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = p[1];
    let w = p[2];
    let x = i % w;
    let y = i / w;
    let cc = f64(d_bar[i]);
    var gx = f64(0.0);
    var gy = f64(0.0);
    if (x + 1u < w) { gx = f64(d_bar[i + 1u]) - cc; }
    if (y + 1u < h) { gy = f64(d_bar[i + w]) - cc; }
    let gw = f64(g[i]);
    let s = c[STEP];
    let nx = (f64(q[2u * i]) + s * gw * gx) * c[DUAL_SCALE];
    let ny = (f64(q[2u * i + 1u]) + s * gw * gy) * c[DUAL_SCALE];
    let shrink = f64(1.0) / max(sqrt(nx * nx + ny * ny), f64(1.0));
    q[2u * i] = f32(nx * shrink);
    q[2u * i + 1u] = f32(ny * shrink);
}

// d' ← (d - τ ∇ᵀ(g q) + τ a / θ) · 1/(1 + τ/θ), d̄ ← 2d' - d; `g q` in f32.
@compute @workgroup_size(64)
fn primal(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = p[1];
    let w = p[2];
    let x = i % w;
    let y = i / w;
    var div = f64(0.0);
    if (x + 1u < w) { div += f64(q[2u * i] * g[i]); }
    if (x > 0u) { div -= f64(q[2u * (i - 1u)] * g[i - 1u]); }
    if (y + 1u < h) { div += f64(q[2u * i + 1u] * g[i]); }
    if (y > 0u) { div -= f64(q[2u * (i - w) + 1u] * g[i - w]); }
    let kt = -div;
    let s = c[STEP];
    let old = d[i];
    let fresh = f32((f64(old) - s * kt + s * f64(a[i]) / c[THETA]) * c[PRIMAL_SCALE]);
    d[i] = fresh;
    d_bar[i] = 2.0 * fresh - old;
}

fn rho(k: u32) -> f64 { return c[RHO0 + k]; }

// `search::energy`.
fn energy(dv: f64, r: f64, cost: f32) -> f64 {
    let diff = dv - r;
    return diff * diff * c[INV_TWO_THETA] + f64(cost) * c[INV_LAMBDA];
}

// `costvolume::parabola_offset`.
fn parabola_offset(cm: f64, c0: f64, cp: f64) -> f64 {
    let curvature = cm - f64(2.0) * c0 + cp;
    if (curvature > f64(0.0)) {
        return clamp((cm - cp) / (f64(2.0) * curvature), f64(-0.5), f64(0.5));
    }
    return f64(0.0);
}

// Rust's `f64::round`: half away from zero (WGSL's `round` rounds half to even). `x - trunc(x)`
// is exact.
fn round_away(x: f64) -> f64 {
    let t = trunc(x);
    if (abs(x - t) >= f64(0.5)) {
        return t + sign(x);
    }
    return t;
}

struct Found {
    ok: bool,
    a: f64,
}

// `search_range`: the first strict minimum of the energy over the seen hypotheses `lo..=hi`, then
// the parabola refinement.
fn search_range(base: u32, dv: f64, lo: u32, hi: u32) -> Found {
    let kk = p[3];
    var found = false;
    var bk = 0u;
    var be = f64(0.0);
    for (var k = lo; k <= hi; k++) {
        let cost = costs[base + k];
        if (cost >= unseen()) { continue; }
        let e = energy(dv, rho(k), cost);
        if (!found || e < be) {
            found = true;
            bk = k;
            be = e;
        }
    }
    if (!found) { return Found(false, f64(0.0)); }
    var delta = f64(0.0);
    if (bk > 0u && bk + 1u < kk && costs[base + bk - 1u] < unseen() && costs[base + bk + 1u] < unseen()) {
        let em = energy(dv, rho(bk - 1u), costs[base + bk - 1u]);
        let ep = energy(dv, rho(bk + 1u), costs[base + bk + 1u]);
        delta = parabola_offset(em, be, ep);
    }
    if (delta == f64(0.0)) { return Found(true, rho(bk)); }
    return Found(true, c[RHO_MIN] + (f64(bk) + delta) * c[DELTA]);
}

// `search_pixel`: the pruned search, the full search where the pruning does not apply, `d` where
// nothing was seen.
fn search_pixel(i: u32, dv: f64) -> f64 {
    let kk = p[3];
    let base = i * kk;
    let c_min = range[2u * i];
    let c_max = range[2u * i + 1u];
    if (c_min > c_max) { return dv; }
    let last = c[LAST];
    let nearest = u32(clamp(round_away((dv - c[RHO_MIN]) / c[DELTA]), f64(0.0), last));
    if (costs[base + nearest] < unseen()) {
        let dn = dv - rho(nearest);
        let r = sqrt(c[TWO_THETA] * f64(c_max - c_min) / c[LAMBDA] + dn * dn);
        let lo = u32(clamp(floor((dv - r - c[RHO_MIN]) / c[DELTA]), f64(0.0), last));
        let hi = u32(clamp(ceil((dv + r - c[RHO_MIN]) / c[DELTA]), f64(0.0), last));
        let pruned = search_range(base, dv, min(lo, nearest), max(hi, nearest));
        if (pruned.ok) { return pruned.a; }
    }
    let full = search_range(base, dv, 0u, kk - 1u);
    if (full.ok) { return full.a; }
    return dv;
}

// `huber_tv::huber`.
fn huber(zx: f64, zy: f64, eps: f64) -> f64 {
    let n = sqrt(zx * zx + zy * zy);
    if (n <= eps) { return n * n / (f64(2.0) * eps); }
    return n - eps / f64(2.0);
}

// The a-search, then this pixel's terms of E_θ(d, a) and of the gap.
@compute @workgroup_size(64)
fn search(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = flat(gid, nwg);
    if (i >= p[0]) { return; }
    let h = p[1];
    let w = p[2];
    let kk = p[3];
    let x = i % w;
    let y = i / w;
    let dv = f64(d[i]);
    let av = f32(search_pixel(i, dv));
    a[i] = av;
    // `total_energy`'s coupling and data terms (C linearly interpolated at a; unseen: no term).
    let diff = dv - f64(av);
    let coupling = diff * diff / c[TWO_THETA];
    let b = clamp((f64(av) - c[RHO_MIN]) / c[DELTA], f64(0.0), c[LAST]);
    let k0 = min(u32(floor(b)), kk - 2u);
    let t = b - f64(k0);
    let c0 = costs[i * kk + k0];
    let c1 = costs[i * kk + min(k0 + 1u, kk - 1u)];
    var data = f64(0.0);
    if (c0 < unseen() && c1 < unseen()) {
        data = ((f64(1.0) - t) * f64(c0) + t * f64(c1)) / c[LAMBDA];
    }
    // `regulariser_energy`'s term: ‖g ∇d‖_ε with the zero difference across the last column / row.
    var gx = f64(0.0);
    var gy = f64(0.0);
    if (x + 1u < w) { gx = f64(d[i + 1u]) - dv; }
    if (y + 1u < h) { gy = f64(d[i + w]) - dv; }
    let gw = f64(g[i]);
    terms[4u * i] = huber(gw * gx, gw * gy, c[EPS]);
    terms[4u * i + 1u] = coupling;
    terms[4u * i + 2u] = data;
    terms[4u * i + 3u] = diff * diff;
}

// Per row: the four sums, x ascending.
@compute @workgroup_size(64)
fn row_sums(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let y = flat(gid, nwg);
    if (y >= p[1]) { return; }
    let w = p[2];
    var s = vec4<f64>(f64(0.0), f64(0.0), f64(0.0), f64(0.0));
    for (var x = 0u; x < w; x++) {
        let j = 4u * (y * w + x);
        s = vec4<f64>(s.x + terms[j], s.y + terms[j + 1u], s.z + terms[j + 2u], s.w + terms[j + 3u]);
    }
    rows[4u * y] = s.x;
    rows[4u * y + 1u] = s.y;
    rows[4u * y + 2u] = s.z;
    rows[4u * y + 3u] = s.w;
}

// One invocation: the rows in order, then E_θ = regulariser + coupling + data and the rms gap.
@compute @workgroup_size(64)
fn total(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    if (flat(gid, nwg) != 0u) { return; }
    let h = p[1];
    var s = vec4<f64>(f64(0.0), f64(0.0), f64(0.0), f64(0.0));
    for (var y = 0u; y < h; y++) {
        let j = 4u * y;
        s = vec4<f64>(s.x + rows[j], s.y + rows[j + 1u], s.z + rows[j + 2u], s.w + rows[j + 3u]);
    }
    measure[0] = s.x + s.y + s.z;
    measure[1] = sqrt(s.w / f64(max(p[0], 1u)));
}
