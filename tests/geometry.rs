//! Property tests of the geometric conventions (SPEC.md §2).

use approx::assert_relative_eq;
use densefeat::geometry::{
    pose_from_matrix, pose_from_tum, relative_pose, InverseDepthBins, PinholeCamera, Pose, RadTan, Warp,
};
use nalgebra::{Matrix4, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

fn camera() -> impl Strategy<Value = PinholeCamera> {
    (200.0..800.0f64, prop_oneof![Just(1.0), Just(-1.0)], 0.8..1.2f64, 100usize..700, 80usize..500).prop_map(
        |(f, sign, aspect, w, h)| {
            PinholeCamera::new(f, sign * f * aspect, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h)
                .unwrap()
        },
    )
}

fn pose() -> impl Strategy<Value = Pose> {
    (prop::array::uniform3(-0.5..0.5f64), prop::array::uniform3(-0.3..0.3f64)).prop_map(|(t, r)| {
        Pose::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(r)),
        )
    })
}

proptest! {
    #[test]
    fn project_backproject_roundtrip(k in camera(), fu in 0.0..1.0f64, fv in 0.0..1.0f64, rho in 0.05..5.0f64) {
        let (u, v) = (fu * (k.width - 1) as f64, fv * (k.height - 1) as f64);
        let p = k.backproject(u, v, rho);
        prop_assert!((p.z - 1.0 / rho).abs() <= 1e-12 * p.z, "z = 1/rho along the optical axis");
        let q = k.project(&p).unwrap();
        prop_assert!((q.x - u).abs() < 1e-9 && (q.y - v).abs() < 1e-9, "{q:?} vs ({u}, {v})");
    }

    #[test]
    fn warp_composition_matches_direct_warp(k in camera(), t_ab in pose(), t_bc in pose(),
                                            fu in 0.1..0.9f64, fv in 0.1..0.9f64, rho in 0.0..2.0f64) {
        // Warp pixel u of camera c into b, then b into a; compare with the direct c -> a warp.
        let (u, v) = (fu * k.width as f64, fv * k.height as f64);
        let t_ac = t_ab * t_bc;
        let direct = Warp::new(&k, &k, &t_ac).apply(u, v, rho);
        let first = Warp::new(&k, &k, &t_bc).apply(u, v, rho);
        prop_assume!(direct.is_some() && first.is_some());
        let (direct, first) = (direct.unwrap(), first.unwrap());
        let second = Warp::new(&k, &k, &t_ab).apply(first.uv.x, first.uv.y, first.rho).unwrap();
        // Relative to the projection's size: a point next to camera a's image plane projects millions of
        // pixels out, where f64 rounding of the two routes differs by ~1e-16 of that.
        prop_assert!((second.uv - direct.uv).norm() < 1e-7 * (1.0 + direct.uv.coords.norm()), "{:?} vs {:?}", second.uv, direct.uv);
        prop_assert!((second.rho - direct.rho).abs() < 1e-9 * (1.0 + direct.rho));
    }

    #[test]
    fn warp_matches_explicit_backproject_transform_project(k in camera(), t in pose(),
                                                            fu in 0.0..1.0f64, fv in 0.0..1.0f64, rho in 0.1..4.0f64) {
        let (u, v) = (fu * k.width as f64, fv * k.height as f64);
        let x_n = t * nalgebra::Point3::from(k.backproject(u, v, rho));
        let want = k.project(&x_n.coords);
        let got = Warp::new(&k, &k, &t).apply(u, v, rho);
        prop_assert_eq!(want.is_some(), got.is_some());
        if let (Some(w), Some(g)) = (want, got) {
            prop_assert!((w - g.uv).norm() < 1e-8 * (1.0 + w.coords.norm()));
            prop_assert!((g.rho - 1.0 / x_n.z).abs() < 1e-9 * g.rho.abs().max(1.0));
        }
    }

    #[test]
    fn volume_warp_is_the_warp_with_one_division(k in camera(), t in pose(),
                                                 fu in 0.0..1.0f64, fv in 0.0..1.0f64, rho in 0.0..4.0f64) {
        // `apply_volume` (the cost volume's projection, SPEC.md §9.1): the same point, `None` exactly
        // where `apply` is, and within an ulp-level distance of it (one rounding of 1/p_z more).
        let (u, v) = (fu * k.width as f64, fv * k.height as f64);
        let w = Warp::new(&k, &k, &t);
        let (full, one) = (w.apply(u, v, rho), w.apply_volume(u, v, rho));
        prop_assert_eq!(full.is_some(), one.is_some());
        if let (Some(a), Some(b)) = (full, one) {
            prop_assert!((a.uv - b).norm() <= 1e-12 * (1.0 + a.uv.coords.norm()), "{:?} vs {b:?}", a.uv);
            let p = w.point(u, v, rho);
            let inv = 1.0 / p.z;
            prop_assert_eq!(b.x, k.fx * p.x * inv + k.cx);
            prop_assert_eq!(b.y, k.fy * p.y * inv + k.cy);
        }
    }

    #[test]
    fn warp_at_zero_inverse_depth_is_the_limit(k in camera(), t in pose(), fu in 0.2..0.8f64, fv in 0.2..0.8f64) {
        // ρ = 0 (a point at infinity) is exact and continuous with small ρ.
        let (u, v) = (fu * k.width as f64, fv * k.height as f64);
        let w = Warp::new(&k, &k, &t);
        let at0 = w.apply(u, v, 0.0).unwrap();
        let near0 = w.apply(u, v, 1e-9).unwrap();
        prop_assert!((at0.uv - near0.uv).norm() < 1e-5);
        prop_assert_eq!(at0.rho, 0.0);
        // ... and depends on rotation only.
        let rot_only = Pose::from_parts(Translation3::identity(), t.rotation);
        let r = Warp::new(&k, &k, &rot_only).apply(u, v, 0.0).unwrap();
        prop_assert!((r.uv - at0.uv).norm() < 1e-9);
    }

    #[test]
    fn undistort_inverts_distort(x in -0.62..0.62f64, y in -0.5..0.5f64, which in 0usize..3) {
        // Over the field of view of a 640x480 TUM camera (|x| <= 320/517, |y| <= 240/516).
        let d = [
            RadTan { k1: 0.2624, k2: -0.9531, p1: -0.0054, p2: 0.0026, k3: 1.1633 }, // freiburg1
            RadTan { k1: 0.2312, k2: -0.7849, p1: -0.0033, p2: -0.0001, k3: 0.9172 }, // freiburg2
            RadTan { k1: -0.28, k2: 0.07, p1: 0.001, p2: -0.002, k3: 0.0 },
        ][which];
        let (xd, yd) = d.distort(x, y);
        let (ux, uy) = d.undistort(xd, yd).expect("Newton converges inside the field of view");
        prop_assert!((ux - x).abs() < 1e-10 && (uy - y).abs() < 1e-10, "({ux}, {uy}) vs ({x}, {y})");
    }

    #[test]
    fn level_intrinsics_scale_pixel_coordinates_by_powers_of_two(k in camera(), t in pose(), level in 1u32..5,
                                                                   fu in 0.0..1.0f64, fv in 0.0..1.0f64, rho in 0.1..3.0f64) {
        // u_l = u_0 / 2^l for every projected point: the level-l grid samples level-0 pixels 2^l j.
        let kl = k.at_level(level);
        let (u, v) = (fu * k.width as f64, fv * k.height as f64);
        let s = (1u32 << level) as f64;
        let w0 = Warp::new(&k, &k, &t).apply(u, v, rho);
        let wl = Warp::new(&kl, &kl, &t).apply(u / s, v / s, rho);
        prop_assert_eq!(w0.is_some(), wl.is_some());
        if let (Some(a), Some(b)) = (w0, wl) {
            prop_assert!((a.uv / s - b.uv).norm() < 1e-9 * (1.0 + a.uv.coords.norm()));
        }
        prop_assert_eq!(kl.width, k.width.div_ceil(1 << level));
    }
}

#[test]
fn relative_pose_maps_reference_points_into_frame_n() {
    let t_wr =
        Pose::from_parts(Translation3::new(1.0, 2.0, 3.0), UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3));
    let t_wn = Pose::from_parts(
        Translation3::new(-1.0, 0.5, 0.0),
        UnitQuaternion::from_euler_angles(-0.3, 0.1, 0.0),
    );
    let x_r = nalgebra::Point3::new(0.3, -0.2, 2.0);
    let x_w = t_wr * x_r;
    let x_n = relative_pose(&t_wr, &t_wn) * x_r;
    assert_relative_eq!(t_wn * x_n, x_w, epsilon = 1e-12);
}

#[test]
fn tum_quaternion_is_xyzw_hamilton() {
    // 90 degrees about z: q = (x, y, z, w) = (0, 0, sin 45, cos 45) maps the x axis to the y axis.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let p = pose_from_tum([1.0, 2.0, 3.0], [0.0, 0.0, h, h]).unwrap();
    let y = p.rotation * Vector3::x();
    assert_relative_eq!(y, Vector3::y(), epsilon = 1e-12);
    assert_eq!(p.translation.vector, Vector3::new(1.0, 2.0, 3.0));
    assert!(pose_from_tum([0.0; 3], [0.0, 0.0, 0.0, 0.0]).unwrap_err().contains("norm"));
    assert!(pose_from_tum([f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).unwrap_err().contains("non-finite"));
}

#[test]
fn pose_from_matrix_checks_rotation_and_last_row() {
    let mut m = Matrix4::identity();
    m[(0, 3)] = 1.5;
    let p = pose_from_matrix(&m).unwrap();
    assert_eq!(p.translation.vector.x, 1.5);
    let mut scaled = m;
    scaled[(0, 0)] = 1.1;
    assert!(pose_from_matrix(&scaled).unwrap_err().contains("orthonormal"));
    let mut reflect = m;
    reflect[(2, 2)] = -1.0;
    assert!(pose_from_matrix(&reflect).unwrap_err().contains("det"));
    let mut row = m;
    row[(3, 0)] = 0.5;
    assert!(pose_from_matrix(&row).unwrap_err().contains("last row"));
}

#[test]
fn negative_fy_flips_the_image_y_axis() {
    // ICL-NUIM: fy = -480. A point above the optical axis in camera y (negative y) projects below cy.
    let k = PinholeCamera::new(481.2, -480.0, 319.5, 239.5, 640, 480).unwrap();
    let uv = k.project(&Vector3::new(0.0, -0.5, 1.0)).unwrap();
    assert_eq!(uv.y, 239.5 + 240.0);
    let ray = k.ray(uv.x, uv.y);
    assert_relative_eq!(ray, Vector3::new(0.0, -0.5, 1.0), epsilon = 1e-12);
}

#[test]
fn inverse_depth_bins_are_uniform_and_inclusive() {
    let b = InverseDepthBins::paper();
    let v = b.values();
    assert_eq!(v.len(), 256);
    assert_eq!(v[0], 0.0);
    assert_eq!(v[255], 4.0);
    for w in v.windows(2) {
        assert!((w[1] - w[0] - 4.0 / 255.0).abs() < 1e-12);
    }
    let r = InverseDepthBins::from_depth_range(0.5, f64::INFINITY, 64).unwrap();
    assert_eq!((r.rho_min, r.rho_max), (0.0, 2.0));
    assert_relative_eq!(r.bin_of(r.rho(17)), 17.0, epsilon = 1e-9);
    assert!(InverseDepthBins::new(0.0, 1.0, 1).is_err());
    assert!(InverseDepthBins::from_depth_range(2.0, 1.0, 8).is_err());
    assert!(InverseDepthBins::from_depth_range(0.0, 1.0, 8).is_err());
}

#[test]
fn camera_rejects_bad_intrinsics() {
    assert!(PinholeCamera::new(f64::NAN, 1.0, 0.0, 0.0, 1, 1).is_err());
    assert!(PinholeCamera::new(0.0, 1.0, 0.0, 0.0, 1, 1).is_err());
    assert!(PinholeCamera::new(1.0, 1.0, 0.0, 0.0, 0, 1).is_err());
}
