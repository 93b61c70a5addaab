//! Normals from a depth map (SPEC.md §10.2, `--normals gt`): the plane fit recovers planes to the
//! image border, does not bridge an occlusion edge, averages a sensor's noise out, gives no normal
//! where the support is too thin, is the same for any thread count, and its fast path gives the
//! reference's bits.

use densefeat::geometry::PinholeCamera;
use densefeat::mapping::depth_normals::normals_from_depth_reference;
use densefeat::mapping::normals::{fit_radius, normals_from_depth};
use ndarray::{Array2, Array3};

use crate::common::dtam_cases::{stream, with_threads};

/// Depth of the plane `nᵀX + δ = 0` at every pixel of `cam` (`z = −δ / nᵀK⁻¹ũ`), 0 where the ray
/// misses it (behind the camera).
fn plane_depth(cam: &PinholeCamera, n: [f64; 3], delta: f64) -> Array2<f32> {
    Array2::from_shape_fn((cam.height, cam.width), |(y, x)| {
        let den = n[0] * (x as f64 - cam.cx) / cam.fx + n[1] * (y as f64 - cam.cy) / cam.fy + n[2];
        let z = -delta / den;
        if z > 0.0 {
            z as f32
        } else {
            0.0
        }
    })
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Angle in degrees between the fitted normal at `(y, x)` and `truth` oriented towards the camera.
fn angle(normals: &Array3<f32>, y: usize, x: usize, truth: [f64; 3]) -> f64 {
    let n = [normals[[y, x, 0]] as f64, normals[[y, x, 1]] as f64, normals[[y, x, 2]] as f64];
    let t = if truth[2] > 0.0 { [-truth[0], -truth[1], -truth[2]] } else { truth };
    let c: f64 = (0..3).map(|k| n[k] * t[k]).sum();
    let x = [n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0]];
    (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt().atan2(c).to_degrees()
}

#[test]
fn the_window_spans_the_same_angle_at_any_focal_length() {
    let cam = |f: f64| PinholeCamera::new(f, -f, 10.0, 10.0, 20, 20).unwrap();
    assert_eq!(fit_radius(&cam(256.0)), 3);
    assert_eq!(fit_radius(&cam(570.342)), 7);
    assert_eq!(fit_radius(&cam(128.0)), 2);
    assert_eq!(fit_radius(&cam(20.0)), 1);
}

#[test]
fn the_plane_fit_recovers_planes_to_the_image_border() {
    // Planes of several orientations (signed f_y as the renders use it), none so steep that depth
    // changes by the gate's 5 % within the window: every pixel, border included, within 1e-3° of
    // the plane's normal, oriented towards the camera.
    let cam = PinholeCamera::new(128.0, -128.0, 47.5, 35.5, 96, 72).unwrap();
    for (n, delta) in [
        ([0.0, 0.0, 1.0], -2.0),
        (unit([-0.6, 0.2, 0.77]), -2.5),
        (unit([0.3, -0.5, 0.8]), -1.0),
        (unit([0.0, 0.6, -0.8]), 1.5),
    ] {
        let depth = plane_depth(&cam, n, delta);
        assert!(depth.iter().all(|&z| z > 0.0), "the plane must fill the view");
        let normals = normals_from_depth(&depth, &cam);
        let mut worst = 0.0f64;
        for y in 0..cam.height {
            for x in 0..cam.width {
                worst = worst.max(angle(&normals, y, x, n));
                let p = [(x as f64 - cam.cx) / cam.fx, (y as f64 - cam.cy) / cam.fy, 1.0];
                let facing: f64 = (0..3).map(|k| normals[[y, x, k]] as f64 * p[k]).sum();
                assert!(facing < 0.0, "normal at ({x}, {y}) faces away from the camera");
            }
        }
        assert!(worst < 1e-3, "plane {n:?}: worst angle {worst}°");
    }
}

#[test]
fn an_occlusion_edge_is_not_bridged() {
    // A slanted plane in front (left half, 1.5-1.7 m) and a differently slanted wall behind (right
    // half, about 3 m): the pixels right beside the jump take their own surface's normal.
    let cam = PinholeCamera::new(128.0, 128.0, 47.5, 35.5, 96, 72).unwrap();
    let (front, back) = (unit([0.3, 0.1, 1.0]), unit([-0.4, 0.0, 1.0]));
    let (df, db) = (plane_depth(&cam, front, -1.6), plane_depth(&cam, back, -3.0));
    let depth = Array2::from_shape_fn(df.dim(), |(y, x)| if x < 48 { df[[y, x]] } else { db[[y, x]] });
    let normals = normals_from_depth(&depth, &cam);
    let mut worst = 0.0f64;
    for y in 0..cam.height {
        for x in 44..52 {
            worst = worst.max(angle(&normals, y, x, if x < 48 { front } else { back }));
        }
    }
    assert!(worst < 1e-3, "beside the edge: worst angle {worst}°");
}

#[test]
fn a_sensors_noise_is_averaged_out() {
    // A wall 2-3 m away seen at SUN3D's focal length with 0.5 % depth noise (a structured-light
    // sensor's order, along the rays): central differences over ±2 px (the rule before 2026-12-06)
    // are tens of degrees off; the fit is within a few (a 3D total-least-squares plane through the
    // same points tilts towards the rays: 9.7° in a prototype).
    let cam = PinholeCamera::new(570.0, 570.0, 79.5, 59.5, 160, 120).unwrap();
    let n = unit([-0.5, 0.2, 1.0]);
    let mut r = stream(11);
    let gauss = |r: &mut dyn FnMut() -> f64| {
        let (u, v) = (r().max(1e-12), r());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    };
    let clean = plane_depth(&cam, n, -2.2);
    let depth = clean.mapv(|z| (z as f64 * (1.0 + 0.005 * gauss(&mut r))) as f32);
    let normals = normals_from_depth(&depth, &cam);
    let (mut fit, mut central, mut count) = (0.0, 0.0, 0.0);
    let point = |y: usize, x: usize| {
        let z = depth[[y, x]] as f64;
        [(x as f64 - cam.cx) / cam.fx * z, (y as f64 - cam.cy) / cam.fy * z, z]
    };
    for y in 10..110 {
        for x in 10..150 {
            fit += angle(&normals, y, x, n);
            let (a, b, c, d) = (point(y, x + 2), point(y, x - 2), point(y + 2, x), point(y - 2, x));
            let tx = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
            let ty = [c[0] - d[0], c[1] - d[1], c[2] - d[2]];
            let cr = unit([
                tx[1] * ty[2] - tx[2] * ty[1],
                tx[2] * ty[0] - tx[0] * ty[2],
                tx[0] * ty[1] - tx[1] * ty[0],
            ]);
            let t = [-n[0], -n[1], -n[2]];
            central += (0..3).map(|k| cr[k] * t[k]).sum::<f64>().abs().min(1.0).acos().to_degrees();
            count += 1.0;
        }
    }
    let (fit, central) = (fit / count, central / count);
    eprintln!("mean angle: plane fit {fit:.2}°, central differences ±2 px {central:.2}°");
    assert!(fit < 4.0, "plane fit {fit}°");
    assert!(central > 5.0 * fit, "central differences {central}° against the fit's {fit}°");
}

#[test]
fn missing_depth_and_thin_support_give_no_normal() {
    let cam = PinholeCamera::new(128.0, 128.0, 15.5, 15.5, 32, 32).unwrap();
    let mut depth = Array2::from_elem((32, 32), 2.0f32);
    depth[[5, 5]] = 0.0; // no depth
    for y in 18..32 {
        for x in 0..32 {
            depth[[y, x]] = 0.0;
        }
    }
    depth[[25, 10]] = 2.0; // an island of one pixel
    for x in 0..32 {
        depth[[29, x]] = 2.0; // a line one pixel wide
    }
    let normals = normals_from_depth(&depth, &cam);
    assert!(normals[[5, 5, 0]].is_nan());
    assert!(normals[[25, 10, 0]].is_nan(), "an island has no plane");
    assert!((0..32).all(|x| normals[[29, x, 0]].is_nan()), "a line has no plane");
    assert!(normals[[2, 2, 2]] < -0.999, "the wall faces the camera: {:?}", normals[[2, 2, 2]]);
}

#[test]
fn the_fit_is_independent_of_thread_count() {
    let cam = PinholeCamera::new(300.0, 300.0, 40.0, 30.0, 81, 61).unwrap();
    let mut r = stream(3);
    let depth = Array2::from_shape_fn((61, 81), |(y, x)| {
        let z = 1.0 + 0.02 * x as f64 + 0.5 * ((y / 20) % 2) as f64 + 0.01 * r();
        if r() < 0.05 {
            0.0
        } else {
            z as f32
        }
    });
    let run = |n| {
        with_threads(n, || normals_from_depth(&depth, &cam).iter().map(|v| v.to_bits()).collect::<Vec<_>>())
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert!(run(n) == one, "threads = {n}");
    }
}

#[test]
fn the_fast_path_gives_the_reference_bits() {
    // Random scenes: two slanted planes with a step between them, holes, a noisy patch, sizes down
    // to smaller than the window, focal lengths giving r = 1..6; every value bit for bit.
    for seed in 0..40u64 {
        let mut r = stream(seed);
        let (w, h) = (1 + (r() * 60.0) as usize, 1 + (r() * 45.0) as usize);
        let f = 40.0 + r() * 480.0;
        let cam =
            PinholeCamera::new(f, if seed % 2 == 0 { f } else { -f }, w as f64 / 2.0, h as f64 / 2.0, w, h)
                .unwrap();
        let (a, b, step, hole, noise) =
            (r() - 0.5, r() - 0.5, (w as f64 * r()) as usize, 0.3 * r(), 0.02 * r());
        let depth = Array2::from_shape_fn((h, w), |(y, x)| {
            let z = 2.0 + 0.01 * (a * x as f64 + b * y as f64) + if x > step { 0.4 } else { 0.0 };
            let z = z * (1.0 + noise * (r() - 0.5));
            if r() < hole {
                0.0
            } else {
                z as f32
            }
        });
        let bits = |n: Array3<f32>| n.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let (fast, reference) =
            (normals_from_depth(&depth, &cam), normals_from_depth_reference(&depth, &cam));
        assert!(bits(fast) == bits(reference), "seed {seed}: {w}x{h}, r {}", fit_radius(&cam));
    }
}
