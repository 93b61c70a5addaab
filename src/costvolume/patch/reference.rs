//! The patch-volume oracle (SPEC.md §9a.5): for every cell, the patch warp, 49 bilinear samples in
//! f64, the mean-removed L1 in f64, f64 running sums. One thread. Keep it naive.

use super::{clamped_axis, patch_warp, Problem, PATCH_RADIUS, PATCH_SAMPLES};

/// Patch offsets `(dx, dy)`, rows of `dy` from -3 to 3, `dx` from -3 to 3 within a row.
pub(super) fn offsets() -> impl Iterator<Item = (i64, i64)> {
    (-PATCH_RADIUS..=PATCH_RADIUS).flat_map(|dy| (-PATCH_RADIUS..=PATCH_RADIUS).map(move |dx| (dx, dy)))
}

/// Add one live frame into `sums` / `counts` (`[H, W, K]`, hypothesis fastest).
pub(super) fn add_frame(p: &Problem, sums: &mut [f64], counts: &mut [u16]) {
    let (h, w) = p.key.dim();
    let (lh, lw) = p.live.dim();
    let k_count = p.rhos.len();
    for y in 0..h {
        for x in 0..w {
            let mut r = [0.0f64; PATCH_SAMPLES];
            for (ri, (dx, dy)) in r.iter_mut().zip(offsets()) {
                let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                let xx = (x as i64 + dx).clamp(0, w as i64 - 1) as usize;
                *ri = f64::from(p.key[[yy, xx]]);
            }
            let r_mean = r.iter().sum::<f64>() / PATCH_SAMPLES as f64;
            'hypotheses: for (k, &rho) in p.rhos.iter().enumerate() {
                let Some(pw) = patch_warp(p.warp, x as f64, y as f64, rho) else {
                    continue;
                };
                let mut l = [0.0f64; PATCH_SAMPLES];
                for (li, (dx, dy)) in l.iter_mut().zip(offsets()) {
                    let (sx, sy) = pw.position(dx, dy);
                    let (Some((x0, x1, a)), Some((y0, y1, b))) = (clamped_axis(sx, lw), clamped_axis(sy, lh))
                    else {
                        continue 'hypotheses;
                    };
                    let at = |yy: usize, xx: usize| f64::from(p.live[[yy, xx]]);
                    *li = (1.0 - a) * (1.0 - b) * at(y0, x0)
                        + a * (1.0 - b) * at(y0, x1)
                        + (1.0 - a) * b * at(y1, x0)
                        + a * b * at(y1, x1);
                }
                let l_mean = l.iter().sum::<f64>() / PATCH_SAMPLES as f64;
                let e: f64 = r.iter().zip(&l).map(|(ri, li)| ((ri - r_mean) - (li - l_mean)).abs()).sum();
                let i = (y * w + x) * k_count + k;
                sums[i] += e.min(f64::from(p.truncation));
                counts[i] += 1;
            }
        }
    }
}
