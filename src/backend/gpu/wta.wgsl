// Winner-take-all with sub-bin parabola refinement (SPEC.md §9.5, §15.5): one invocation per
// pixel scans its cost curve (k ascending, the first strict minimum among seen cells), then the
// parabola vertex in f64, exactly `costvolume::winner_take_all_costs`'s operations.
//
// p = [pixels, k, UNSEEN_COST bits]
// g = [ρ_min, Δρ, ρ_0 .. ρ_{K-1}]
// out: per pixel [valid (0 or 1), inverse depth, depth, bin], f32.

@group(0) @binding(0) var<storage, read> p: array<u32>;
@group(0) @binding(1) var<storage, read> g: array<f64>;
@group(0) @binding(2) var<storage, read> costs: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

// `costvolume::parabola_offset`: the vertex of the parabola through (-1, cm), (0, c0), (1, cp),
// clamped to ±0.5; 0 where the curvature is not positive.
fn parabola_offset(cm: f64, c0: f64, cp: f64) -> f64 {
    let curvature = cm - f64(2.0) * c0 + cp;
    if (curvature > f64(0.0)) {
        return clamp((cm - cp) / (f64(2.0) * curvature), f64(-0.5), f64(0.5));
    }
    return f64(0.0);
}

@compute @workgroup_size(64)
fn wta(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 64u;
    if (i >= p[0]) { return; }
    let kk = p[1];
    let unseen = bitcast<f32>(p[2]);
    let base = i * kk;
    var found = false;
    var best = 0u;
    var c0 = 0.0f;
    for (var k = 0u; k < kk; k++) {
        let c = costs[base + k];
        if (c < unseen && (!found || c < c0)) {
            found = true;
            best = k;
            c0 = c;
        }
    }
    if (!found) {
        out[4u * i] = 0.0;
        out[4u * i + 1u] = 0.0;
        out[4u * i + 2u] = 0.0;
        out[4u * i + 3u] = 0.0;
        return;
    }
    var offset = f64(0.0);
    if (best > 0u && best + 1u < kk) {
        let cm = costs[base + best - 1u];
        let cp = costs[base + best + 1u];
        if (cm < unseen && cp < unseen) {
            offset = parabola_offset(f64(cm), f64(c0), f64(cp));
        }
    }
    let bin = f64(best) + offset;
    var rho = g[2u + best];
    if (offset != f64(0.0)) {
        rho = g[0] + bin * g[1];
    }
    var depth = 0.0f;
    if (rho > f64(0.0)) {
        depth = f32(f64(1.0) / rho);
    }
    out[4u * i] = 1.0;
    out[4u * i + 1u] = f32(rho);
    out[4u * i + 2u] = depth;
    out[4u * i + 3u] = f32(bin);
}
