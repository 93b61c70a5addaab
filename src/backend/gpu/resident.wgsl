// The resident volume's steps between the cost volume and DTAM (SPEC.md §15.6): the `[H, W, K]`
// mean costs stay in `costs` (the volume's running sums, turned into means in place) and every
// step is the host function's operations on the same values, so the results are the CPU's bit for
// bit (the divisions are f64 rounded once to f32, which equals the correctly rounded f32 quotient:
// SPEC.md §15.6). Each invocation owns its cell or pixel: no atomics except the non-finite count.
//
// p = [n (cells or pixels: this dispatch's size), k, UNSEEN_COST bits, frames]
// table: evidence threshold per largest count `N_u` (0 ..= frames), `costvolume::evidence_threshold`
// weights: the border taper's weight per pixel (`costvolume::border_weight`)
// out: per pixel [confidence, spread (median - minimum; -1 where fewer than 2 cells are seen)]

@group(0) @binding(0) var<storage, read> p: array<u32>;
@group(0) @binding(1) var<storage, read_write> costs: array<f32>;
@group(0) @binding(2) var<storage, read> counts: array<u32>;
@group(0) @binding(3) var<storage, read> table: array<u32>;
@group(0) @binding(4) var<storage, read> weights: array<f32>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;
@group(0) @binding(6) var<storage, read_write> bad: array<atomic<u32>>;

fn index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * 64u;
}

// Per cell: `CostVolume::into_costs`: the sum over the count, UNSEEN_COST where no frame saw it.
// A non-finite sum is counted (WGSL may assume finite values; the host refuses the volume).
@compute @workgroup_size(64)
fn mean(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= p[0]) { return; }
    let s = costs[i];
    if ((bitcast<u32>(s) & 0x7f800000u) == 0x7f800000u) {
        atomicAdd(&bad[0], 1u);
    }
    let n = counts[i];
    if (n == 0u) {
        costs[i] = bitcast<f32>(p[2]);
    } else {
        costs[i] = f32(f64(s) / f64(n));
    }
}

// Per pixel: `costvolume::filter_evidence`: cells seen by fewer than the threshold of the pixel's
// largest count become unseen.
@compute @workgroup_size(64)
fn evidence(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= p[0]) { return; }
    let kk = p[1];
    let base = i * kk;
    var most = 0u;
    for (var k = 0u; k < kk; k++) {
        most = max(most, counts[base + k]);
    }
    let t = table[most];
    for (var k = 0u; k < kk; k++) {
        if (counts[base + k] < t) {
            costs[base + k] = bitcast<f32>(p[2]);
        }
    }
}

// Per pixel: `costvolume::confidence_and_scale`'s per-pixel part: the minimum and the median (the
// order statistic (n-1)/2 of the n seen costs, found by counting: the seen cost with fewer than
// (n-1)/2 + 1 seen costs below it and more than (n-1)/2 at or below it), the spread, and the
// confidence `clamp(1 - min/median, 0, 1) · min(N_{u,k*} / N, 1)` in f64 (k* the first minimum).
@compute @workgroup_size(64)
fn confidence(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= p[0]) { return; }
    let kk = p[1];
    let unseen = bitcast<f32>(p[2]);
    let base = i * kk;
    var n = 0u;
    var lo = 0.0f;
    var first = 0u;
    for (var k = 0u; k < kk; k++) {
        let c = costs[base + k];
        if (c < unseen) {
            if (n == 0u || c < lo) {
                lo = c;
                first = k;
            }
            n += 1u;
        }
    }
    if (n < 2u) {
        out[2u * i] = 0.0;
        out[2u * i + 1u] = -1.0;
        return;
    }
    let m = (n - 1u) / 2u;
    var med = 0.0f;
    for (var k = 0u; k < kk; k++) {
        let c = costs[base + k];
        if (c < unseen) {
            var below = 0u;
            var at_most = 0u;
            for (var j = 0u; j < kk; j++) {
                let d = costs[base + j];
                if (d < unseen) {
                    below += select(0u, 1u, d < c);
                    at_most += select(0u, 1u, d <= c);
                }
            }
            if (below <= m && m < at_most) {
                med = c;
                break;
            }
        }
    }
    var sharp = f64(0.0);
    if (med > 0.0) {
        sharp = f64(1.0) - f64(lo) / f64(med);
    }
    let seen_by = f64(counts[base + first]) / f64(max(p[3], 1u));
    out[2u * i] = f32(clamp(sharp, f64(0.0), f64(1.0)) * min(seen_by, f64(1.0)));
    out[2u * i + 1u] = med - lo;
}

// Per cell: `costvolume::taper_border`: every seen cost of a pixel with weight below 1 is
// multiplied by it; unseen cells stay unseen.
@compute @workgroup_size(64)
fn taper(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= p[0]) { return; }
    let w = weights[i / p[1]];
    let c = costs[i];
    if (w < 1.0 && c < bitcast<f32>(p[2])) {
        costs[i] = c * w;
    }
}
