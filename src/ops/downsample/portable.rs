//! The portable column loop of the 2x tent downsampling (SPEC.md §7.4).

use super::TENT;

/// The tent's nine weights `t_a t_b`, `a` (rows) outer: each is a power of two.
const TENT2: [[f64; 3]; 3] = {
    let mut t = [[0.0; 3]; 3];
    let mut a = 0;
    while a < 3 {
        let mut b = 0;
        while b < 3 {
            t[a][b] = TENT[a] * TENT[b];
            b += 1;
        }
        a += 1;
    }
    t
};

/// The nine-term sum per output column, `acc = 0`, then `acc += t_a t_b x` for `a`, then `b`
/// ascending, as the reference (no contraction to FMA: Rust does not contract).
#[inline(always)]
pub(super) fn combine(even: [&[f64]; 3], odd: [&[f64]; 3], plane: &mut [f32]) {
    let n = plane.len();
    let (e, o) = (even.map(|v| &v[..n + 1]), odd.map(|v| &v[..n]));
    for (i, out) in plane.iter_mut().enumerate() {
        let mut acc = 0.0f64;
        for a in 0..3 {
            acc += TENT2[a][0] * e[a][i];
            acc += TENT2[a][1] * o[a][i];
            acc += TENT2[a][2] * e[a][i + 1];
        }
        *out = acc as f32;
    }
}
