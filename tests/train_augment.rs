//! The sensor part of the training augmentation (SPEC.md §13.5): the motion blur against a naive
//! reference, its invariants, the fingerprint left as it was when it is off, and a training run with
//! it bit-identical for any thread count.

use approx::assert_abs_diff_eq;
use ndarray::Array3;
use proptest::prelude::*;

use densefeat::train::data::{motion_blur, Augment, DataConfig, DataSet};
use densefeat::util::rng::SplitMix64;

/// The definition, pixel by pixel in f64: the mean of `n = ⌈length⌉ + 1` bilinear samples along the
/// line, the image extended by its edge values.
fn blur_reference(img: &Array3<f32>, length: f64, angle: f64) -> Array3<f64> {
    let (h, w, c) = img.dim();
    let n = length.ceil() as usize + 1;
    let at = |y: f64, x: f64, ch: usize| {
        let yi = (y as isize).clamp(0, h as isize - 1) as usize;
        let xi = (x as isize).clamp(0, w as isize - 1) as usize;
        f64::from(img[[yi, xi, ch]])
    };
    Array3::from_shape_fn((h, w, c), |(y, x, ch)| {
        let mut sum = 0.0;
        for i in 0..n {
            let t = i as f64 / (n - 1) as f64 - 0.5;
            let (sx, sy) = (x as f64 + t * length * angle.cos(), y as f64 + t * length * angle.sin());
            let (x0, y0) = (sx.floor(), sy.floor());
            let (fx, fy) = (sx - x0, sy - y0);
            let top = (1.0 - fx) * at(y0, x0, ch) + fx * at(y0, x0 + 1.0, ch);
            let bottom = (1.0 - fx) * at(y0 + 1.0, x0, ch) + fx * at(y0 + 1.0, x0 + 1.0, ch);
            sum += (1.0 - fy) * top + fy * bottom;
        }
        sum / n as f64
    })
}

fn random_image(h: usize, w: usize, c: usize, seed: u64) -> Array3<f32> {
    let mut rng = SplitMix64::new(seed);
    Array3::from_shape_fn((h, w, c), |_| (255.0 * rng.unit()) as f32)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn motion_blur_matches_its_definition(
        h in 1usize..12, w in 1usize..12, c in 1usize..4, seed in any::<u64>(),
        length in 0.5f64..7.0, angle in 0.0f64..std::f64::consts::PI,
    ) {
        let img = random_image(h, w, c, seed);
        let mut fast = img.clone();
        motion_blur(&mut fast, length, angle);
        let reference = blur_reference(&img, length, angle);
        for (f, r) in fast.iter().zip(reference.iter()) {
            prop_assert!((f64::from(*f) - r).abs() < 1e-3, "{f} vs {r}");
        }
    }
}

#[test]
fn motion_blur_keeps_a_constant_image_and_below_half_a_pixel_does_nothing() {
    let mut flat = Array3::from_elem((9, 13, 3), 87.25f32);
    motion_blur(&mut flat, 5.3, 0.7);
    for v in &flat {
        assert_abs_diff_eq!(*v, 87.25, epsilon = 1e-4);
    }
    let img = random_image(7, 8, 3, 5);
    let mut same = img.clone();
    motion_blur(&mut same, 0.49, 1.0);
    assert_eq!(same, img);
}

#[test]
fn a_horizontal_blur_of_two_pixels_is_a_three_tap_box() {
    let img = random_image(5, 10, 2, 9);
    let mut out = img.clone();
    motion_blur(&mut out, 2.0, 0.0);
    for y in 0..5 {
        for x in 1..9 {
            for ch in 0..2 {
                let mean = (img[[y, x - 1, ch]] + img[[y, x, ch]] + img[[y, x + 1, ch]]) as f64 / 3.0;
                assert_abs_diff_eq!(f64::from(out[[y, x, ch]]), mean, epsilon = 1e-3);
            }
        }
    }
}

#[test]
fn the_fingerprint_names_the_sensor_augmentation_only_when_it_is_on() {
    // Checkpoints from before the flags existed must stay resumable (SPEC.md §13.6).
    assert_eq!(format!("{:?}", Augment::default()), "Augment { gain: 0.2, bias: 15.0, noise: 2.0 }");
    let on = Augment { blur: 3.0, gamma: 0.2, ..Augment::default() };
    assert_eq!(format!("{on:?}"), "Augment { gain: 0.2, bias: 15.0, noise: 2.0, blur: 3.0, gamma: 0.2 }");
}

fn tiny_data(augment: Augment) -> DataConfig {
    DataConfig {
        crop: (48, 32),
        synthetic_scenes: 2,
        synthetic_val_scenes: 1,
        augment,
        ..DataConfig::default()
    }
}

#[test]
fn blurred_training_pairs_are_the_same_for_any_thread_count_and_differ_from_sharp_ones() {
    let sensor = Augment { blur: 4.0, gamma: 0.3, ..Augment::default() };
    let data = DataSet::open(tiny_data(sensor)).unwrap();
    let sharp = DataSet::open(tiny_data(Augment::default())).unwrap();
    let draw = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            (1..4)
                .map(|step| {
                    let p = data.train_pair(7, step, 0).unwrap();
                    p.validate().unwrap();
                    p.ref_rgb.iter().chain(p.live_rgb.iter()).map(|v| v.to_bits()).collect::<Vec<_>>()
                })
                .collect::<Vec<_>>()
        })
    };
    let one = draw(1);
    for t in [2, 3, 8] {
        assert_eq!(draw(t), one, "{t} threads");
    }
    let p = sharp.train_pair(7, 1, 0).unwrap();
    let q = data.train_pair(7, 1, 0).unwrap();
    // The same pair and crops (drawn before any augmentation), so the same depth; other pixels, all
    // within 0..=255.
    assert_eq!(p.ref_depth, q.ref_depth);
    assert_ne!(p.ref_rgb, q.ref_rgb);
    assert!(q.ref_rgb.iter().chain(q.live_rgb.iter()).all(|v| (0.0..=255.0).contains(v)));
}
