//! The depth filter before fusion (SPEC.md §16.10): constructed cases for the multi-view check and
//! the discontinuity rule, and thread-count determinism.

use densefeat::fusion::consistency::{confirmations, filter_depth, smooth_mask, ConsistencyRule, ViewDepth};
use densefeat::geometry::{PinholeCamera, Pose};
use nalgebra::{Translation3, UnitQuaternion};
use ndarray::Array2;

const W: usize = 64;
const H: usize = 48;

fn camera() -> PinholeCamera {
    PinholeCamera::new(60.0, 60.0, 31.5, 23.5, W, H).unwrap()
}

/// Camera-to-world pose at `x` metres along the world x axis, looking down +z.
fn pose(x: f64) -> Pose {
    Pose::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity())
}

/// Depth of the plane z = 2 m (world) seen by a camera at z = 0 looking down +z: 2 everywhere.
fn plane() -> Array2<f32> {
    Array2::from_elem((H, W), 2.0)
}

fn rule(min_views: usize) -> ConsistencyRule {
    ConsistencyRule { min_views, max_depth_error: 0.02, max_reprojection_px: 1.0 }
}

#[test]
fn a_surface_seen_consistently_is_kept() {
    let (d0, d1, d2) = (plane(), plane(), plane());
    let views = [
        ViewDepth { depth: d0.view(), camera: camera(), pose: pose(0.0) },
        ViewDepth { depth: d1.view(), camera: camera(), pose: pose(0.1) },
        ViewDepth { depth: d2.view(), camera: camera(), pose: pose(-0.1) },
    ];
    let votes = confirmations(&views[0], &views[1..], &rule(2));
    // A 0.1 m baseline at 2 m shifts pixels by 3 px: every pixel at least 4 px from the left and
    // right edges is inside both other views and confirmed by both.
    for y in 0..H {
        for x in 4..W - 4 {
            assert_eq!(votes[[y, x]], 2, "pixel ({x}, {y})");
        }
    }
    let kept = filter_depth(&views[0], &views[1..], &rule(2), 1.1);
    assert_eq!(kept.slice(ndarray::s![.., 4..W - 4]), d0.slice(ndarray::s![.., 4..W - 4]));
}

#[test]
fn a_wrong_keyframes_outlier_is_removed() {
    let mut d0 = plane();
    // A blob 30 % too near: the other views see the plane there.
    for y in 20..30 {
        for x in 25..35 {
            d0[[y, x]] = 1.4;
        }
    }
    let (d1, d2) = (plane(), plane());
    let views = [
        ViewDepth { depth: d0.view(), camera: camera(), pose: pose(0.0) },
        ViewDepth { depth: d1.view(), camera: camera(), pose: pose(0.1) },
        ViewDepth { depth: d2.view(), camera: camera(), pose: pose(-0.1) },
    ];
    // The multi-view check alone (edge rule off).
    let kept = filter_depth(&views[0], &views[1..], &rule(1), 0.0);
    for y in 20..30 {
        for x in 25..35 {
            assert_eq!(kept[[y, x]], 0.0, "outlier ({x}, {y}) kept");
        }
    }
    assert_eq!(kept[[10, 10]], 2.0);
    assert_eq!(kept[[40, 50]], 2.0);
    // Off: every valid pixel stays.
    let all = filter_depth(&views[0], &views[1..], &rule(0), 0.0);
    assert_eq!(all, d0);
}

#[test]
fn an_occlusion_edge_is_not_bridged() {
    // A box at 1 m in front of a wall at 3 m: the pixels on both sides of its outline are dropped,
    // the interiors of both surfaces kept.
    let d =
        Array2::from_shape_fn(
            (H, W),
            |(y, x)| if (16..32).contains(&y) && (20..44).contains(&x) { 1.0 } else { 3.0 },
        );
    let m = smooth_mask(d.view(), 1.1);
    assert!(!m[[16, 30]] && !m[[15, 30]], "the outline's two sides");
    assert!(!m[[24, 20]] && !m[[24, 19]]);
    assert!(m[[24, 30]], "box interior");
    assert!(m[[5, 5]], "wall interior");
    // Invalid depth is never kept, and ratio <= 1 keeps every valid pixel.
    let mut holes = d.clone();
    holes[[5, 5]] = 0.0;
    let off = smooth_mask(holes.view(), 1.0);
    assert!(!off[[5, 5]] && off[[16, 30]]);
}

#[test]
fn the_filter_is_bit_identical_for_any_thread_count() {
    let d0 = Array2::from_shape_fn((H, W), |(y, x)| 2.0 + 0.01 * ((x * 7 + y * 3) % 11) as f32);
    let (d1, d2) = (plane(), Array2::from_shape_fn((H, W), |(y, x)| 2.0 + 0.02 * ((x + y) % 5) as f32));
    let views = [
        ViewDepth { depth: d0.view(), camera: camera(), pose: pose(0.0) },
        ViewDepth { depth: d1.view(), camera: camera(), pose: pose(0.1) },
        ViewDepth { depth: d2.view(), camera: camera(), pose: pose(-0.05) },
    ];
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| filter_depth(&views[0], &views[1..], &rule(1), 1.05))
    };
    let base = run(1);
    assert!(base.iter().any(|&v| v == 0.0) && base.iter().any(|&v| v > 0.0), "a non-trivial mask");
    for n in [2, 3, 8] {
        assert!(run(n).iter().zip(&base).all(|(a, b)| a.to_bits() == b.to_bits()), "{n} threads");
    }
}

/// A keyframe without neighbours has nothing to be checked against: its depth is kept (only the
/// edge rule applies), and with fewer neighbours than `min_views` all of them must confirm.
#[test]
fn a_keyframe_without_neighbours_is_kept() {
    let d = plane();
    let v = ViewDepth { depth: d.view(), camera: camera(), pose: pose(0.0) };
    assert_eq!(filter_depth(&v, &[], &rule(2), 1.1), d);
    let d1 = plane();
    let one = [ViewDepth { depth: d1.view(), camera: camera(), pose: pose(0.1) }];
    let kept = filter_depth(&v, &one, &rule(3), 0.0);
    assert_eq!(kept[[20, 30]], 2.0, "one neighbour of the three asked for confirms");
    assert_eq!(kept[[20, 1]], 0.0, "outside the neighbour (it sees pixel 1 at -2): unconfirmed");
}
