//! The triangulation-angle report of `map` (SPEC.md §16.11): constructed cases with known angles,
//! pure rotation, missing depth, and thread counts.

use crate::common;
use densefeat::geometry::{PinholeCamera, Pose};
use densefeat::mapping::parallax::{median_over_keyframes, median_triangulation_angle};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use ndarray::Array2;

fn camera(w: usize, h: usize) -> PinholeCamera {
    PinholeCamera::new(100.0, 100.0, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h).unwrap()
}

#[test]
fn the_principal_point_on_a_plane_sees_the_known_angle() {
    // One pixel at the principal point, 2 m ahead; live cameras 10 cm and 30 cm to the side: the
    // largest angle is atan(0.3 / 2), wherever the keyframe stands and however it is turned.
    let cam = camera(1, 1);
    let pose = Pose::from_parts(
        Translation3::new(1.0, -2.0, 0.5),
        UnitQuaternion::from_euler_angles(0.2, -0.4, 0.1),
    );
    let side = pose.rotation * Vector3::x();
    let c = pose.translation.vector;
    let centres = [c + 0.1 * side, c - 0.3 * side, c];
    let got = median_triangulation_angle(&Array2::from_elem((1, 1), 2.0f32), &cam, &pose, &centres).unwrap();
    let want = (0.3f64 / 2.0).atan().to_degrees();
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
}

#[test]
fn pure_rotation_sees_nothing_and_missing_depth_has_no_angle() {
    let cam = camera(8, 6);
    let pose = Pose::identity();
    let depth = Array2::from_shape_fn((6, 8), |(y, x)| 1.0 + 0.1 * (x + y) as f32);
    // Live cameras at the keyframe's centre (turned, but a pose's centre is all that counts).
    let same = [Vector3::zeros(), Vector3::zeros()];
    assert_eq!(median_triangulation_angle(&depth, &cam, &pose, &same), Some(0.0));
    assert_eq!(median_triangulation_angle(&depth, &cam, &pose, &[]), None);
    let none = Array2::from_elem((6, 8), 0.0f32);
    assert_eq!(median_triangulation_angle(&none, &cam, &pose, &[Vector3::x()]), None);
    // A farther surface is seen under a smaller angle.
    let near = median_triangulation_angle(&depth, &cam, &pose, &[0.1 * Vector3::x()]).unwrap();
    let far =
        median_triangulation_angle(&depth.mapv(|z| 4.0 * z), &cam, &pose, &[0.1 * Vector3::x()]).unwrap();
    assert!(near > 3.0 * far && far > 0.0, "near {near}, far {far}");
    assert_eq!(median_over_keyframes(&[Some(3.0), None, Some(1.0), Some(2.0)]), Some(2.0));
    assert_eq!(median_over_keyframes(&[Some(3.0), Some(1.0)]), Some(1.0));
    assert_eq!(median_over_keyframes(&[None]), None);
}

#[test]
fn the_angle_is_independent_of_thread_count() {
    let cam = camera(64, 48);
    let mut next = common::lcg(5);
    let depth = Array2::from_shape_fn((48, 64), |_| {
        let v = 0.5 * (next() + 1.0);
        if v < 0.1 {
            0.0
        } else {
            0.5 + 5.0 * v
        }
    });
    let centres: Vec<Vector3<f64>> =
        (0..9).map(|i| Vector3::new(0.02 * i as f64, -0.01 * i as f64, 0.005)).collect();
    let pose = Pose::identity();
    let run = |n| {
        common::thread_pool(n).install(|| median_triangulation_angle(&depth, &cam, &pose, &centres).unwrap())
    };
    let one = run(1).to_bits();
    for n in [2, 3, 8] {
        assert_eq!(one, run(n).to_bits(), "{n} threads");
    }
}
