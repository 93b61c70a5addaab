//! The built-in normal predictor (SPEC.md §13.11): the loss's and the head's gradients against
//! central differences in f64, the fast head against the f64 reference, the whole predictor's
//! gradient against a directional difference, thread-count determinism, files, training (the loss
//! goes down, resume is exact) and the command line's error paths.

use std::path::Path;
use std::process::Command;

use densefeat::backend::CpuBackend;
use densefeat::geometry::PinholeCamera;
use densefeat::nn::NetworkWeights;
use densefeat::normals_net::head::{
    head_backward, head_backward_reference, head_forward, head_forward_reference, normal_loss,
    normal_loss_f64, orient, pixel_terms, ray, RAW_NORM_FLOOR,
};
use densefeat::normals_net::{upsample_normals, NormalNet, NormalNetWeights, HEAD_SEED};
use densefeat::ops::LayerParams;
use densefeat::ops::NetworkConfig;
use densefeat::train::data::{DataConfig, DataSet};
use densefeat::train::normals::checkpoint::NormalCheckpoint;
use densefeat::train::normals::step::{normals_batch_step, sample_step, validate_normals, NormalSample};
use densefeat::train::normals::trainer::{train_normals, NormalsTrainConfig};
use densefeat::train::optim::OptimConfig;
use densefeat::util::rng::SplitMix64;
use ndarray::{Array1, Array3, Array4};

fn rng(seed: u64) -> impl FnMut() -> f64 {
    let mut r = SplitMix64::new(seed);
    move || r.range(-1.0, 1.0)
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Random ground-truth normals facing the camera, with every 7th pixel missing (NaN).
fn gt_field(h: usize, w: usize, camera: &PinholeCamera, seed: u64) -> Array3<f32> {
    let mut r = rng(seed);
    let mut gt = Array3::from_elem((h, w, 3), f32::NAN);
    for y in 0..h {
        for x in 0..w {
            let g = unit([r(), r(), r() - 2.0]);
            let (n, _, _) = orient(g, ray(camera, x, y)).unwrap();
            if (y * w + x) % 7 != 3 {
                for k in 0..3 {
                    gt[[y, x, k]] = n[k] as f32;
                }
            }
        }
    }
    gt
}

fn camera(h: usize, w: usize) -> PinholeCamera {
    PinholeCamera::new(0.9 * w as f64, 0.9 * w as f64, 0.47 * w as f64, 0.52 * h as f64, w, h).unwrap()
}

#[test]
fn pixel_gradient_matches_central_difference() {
    let mut r = rng(1);
    let mut checked = 0;
    for i in 0..400 {
        // Half the probes below the floor of the loss's linear regime, half above (SPEC.md §13.11).
        let scale = if i % 2 == 0 { 2.0 } else { 10.0 * RAW_NORM_FLOOR };
        let raw = [scale * r(), scale * r(), scale * r()];
        let d = [0.5 * r(), 0.5 * r(), 1.0];
        let g = unit([r(), r(), -1.0]);
        // Away from the orientation's kink (rᵀd = 0).
        let cos_rd = (raw[0] * d[0] + raw[1] * d[1] + raw[2] * d[2]).abs()
            / ((raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2]).sqrt()
                * (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt());
        if cos_rd < 0.05 {
            continue;
        }
        let t = pixel_terms(raw, d, g, RAW_NORM_FLOOR).unwrap();
        let h = 1e-6;
        for k in 0..3 {
            let (mut p, mut m) = (raw, raw);
            p[k] += h;
            m[k] -= h;
            let numeric = (pixel_terms(p, d, g, RAW_NORM_FLOOR).unwrap().loss
                - pixel_terms(m, d, g, RAW_NORM_FLOOR).unwrap().loss)
                / (2.0 * h);
            assert!(
                (numeric - t.d_raw[k]).abs() <= 1e-6 * (1.0 + t.d_raw[k].abs()),
                "component {k}: numeric {numeric:e}, analytic {:e}",
                t.d_raw[k]
            );
        }
        let norm = (raw[0] * raw[0] + raw[1] * raw[1] + raw[2] * raw[2]).sqrt();
        if norm >= RAW_NORM_FLOOR {
            // The loss is 1 - cos of the angle it reports.
            assert!((t.loss - (1.0 - t.angle_deg.to_radians().cos())).abs() < 1e-12);
        } else {
            // Linear below the floor (s rᵀg / R_FLOOR = cos · ‖r‖ / R_FLOOR), the unit n's angle reported.
            let cos = t.angle_deg.to_radians().cos();
            assert!((t.loss - (1.0 - cos * norm / RAW_NORM_FLOOR)).abs() < 1e-9, "{t:?}");
            let g_norm = t.d_raw.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!((g_norm - 1.0 / RAW_NORM_FLOOR).abs() < 1e-12, "the gradient is g / R_FLOOR: {g_norm}");
        }
        checked += 1;
    }
    assert!(checked > 300, "{checked}");
    // Continuous at the floor: just below and just above give the same loss.
    let (d, g) = ([0.1, -0.2, 1.0], unit([0.3, 0.1, -1.0]));
    let dir = unit([0.2, 0.4, -1.0]);
    let at = |k: f64| pixel_terms([k * dir[0], k * dir[1], k * dir[2]], d, g, RAW_NORM_FLOOR).unwrap().loss;
    assert!((at(RAW_NORM_FLOOR * (1.0 - 1e-12)) - at(RAW_NORM_FLOOR * (1.0 + 1e-12))).abs() < 1e-9);
    // No ground truth, or a zero prediction: no term.
    assert!(pixel_terms([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [f64::NAN, 0.0, 1.0], 0.0).is_none());
    assert!(pixel_terms([0.0; 3], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], RAW_NORM_FLOOR).is_none());
}

/// A random head `[3, c, 3, 3]` and bias in f64.
fn head64(c: usize, seed: u64) -> (Array4<f64>, Array1<f64>) {
    let mut r = rng(seed);
    (Array4::from_shape_simple_fn((3, c, 3, 3), || 0.3 * r()), Array1::from_shape_simple_fn(3, || 0.2 * r()))
}

/// Orientation signs of every pixel (to keep probes off the orientation's kink).
fn signs(raw: &Array3<f64>, cam: &PinholeCamera) -> Vec<bool> {
    let (h, w, _) = raw.dim();
    let mut v = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let d = ray(cam, x, y);
            v.push(raw[[y, x, 0]] * d[0] + raw[[y, x, 1]] * d[1] + raw[[y, x, 2]] * d[2] > 0.0);
        }
    }
    v
}

#[test]
fn reference_head_and_loss_gradients_match_central_differences() {
    let (h, w, c) = (7, 9, 5);
    let cam = camera(h, w);
    let gt = gt_field(h, w, &cam, 2);
    let mut r = rng(3);
    let features = Array3::from_shape_simple_fn((h, w, c), &mut r);
    let (wt, b) = head64(c, 4);
    let loss = |f: &Array3<f64>, wt: &Array4<f64>, b: &Array1<f64>| {
        let raw = head_forward_reference(wt.view(), b.view(), f.view()).unwrap();
        (normal_loss_f64(raw.view(), gt.view(), &cam, 1.0, 0.0).unwrap().0.mean(), signs(&raw, &cam))
    };
    let raw = head_forward_reference(wt.view(), b.view(), features.view()).unwrap();
    let (sums, d_raw) = normal_loss_f64(raw.view(), gt.view(), &cam, 1.0, 0.0).unwrap();
    assert!(sums.pixels > 40, "{}", sums.pixels);
    let (d_f, d_w, d_b) = head_backward_reference(wt.view(), features.view(), d_raw.view()).unwrap();
    let hstep = 1e-6;
    let mut dir = rng(5);
    for probe in 0..4 {
        // Features, weight, bias, each along its own random direction.
        let vf = Array3::from_shape_simple_fn((h, w, c), &mut dir);
        let vw = Array4::from_shape_simple_fn((3, c, 3, 3), &mut dir);
        let vb = Array1::from_shape_simple_fn(3, &mut dir);
        for (what, analytic) in
            [("features", (&d_f * &vf).sum()), ("weight", (&d_w * &vw).sum()), ("bias", (&d_b * &vb).sum())]
        {
            let at = |s: f64| match what {
                "features" => loss(&(&features + &(&vf * s)), &wt, &b),
                "weight" => loss(&features, &(&wt + &(&vw * s)), &b),
                _ => loss(&features, &wt, &(&b + &(&vb * s))),
            };
            let ((lp, sp), (lm, sm)) = (at(hstep), at(-hstep));
            assert_eq!(sp, sm, "probe {probe} {what} crossed an orientation kink");
            let numeric = (lp - lm) / (2.0 * hstep);
            assert!(
                (numeric - analytic).abs() <= 1e-6 * (1.0 + analytic.abs()),
                "probe {probe} {what}: numeric {numeric:e}, analytic {analytic:e}"
            );
        }
    }
}

fn to32<D: ndarray::Dimension>(a: &ndarray::Array<f64, D>) -> ndarray::Array<f32, D> {
    a.mapv(|v| v as f32)
}
fn to64<D: ndarray::Dimension>(a: &ndarray::Array<f32, D>) -> ndarray::Array<f64, D> {
    a.mapv(f64::from)
}

#[test]
fn fast_head_and_loss_match_the_f64_reference() {
    // 32 channels: the network's width, so the SIMD kernels run where the CPU has them.
    for (h, w, c, seed) in [(13, 11, 32, 6), (1, 5, 32, 7), (9, 1, 4, 8), (17, 23, 32, 9)] {
        let cam = camera(h, w);
        let gt = gt_field(h, w, &cam, seed);
        let mut r = rng(seed + 100);
        let features = Array3::from_shape_simple_fn((h, w, c), || r() as f32);
        let (wt, b) = head64(c, seed + 200);
        let head = LayerParams { weight: to32(&wt), bias: to32(&b) };
        let (wt, b) = (to64(&head.weight), to64(&head.bias));
        let f64s = to64(&features);
        // Forward: within 2 K ε Σ|x||w| (K = 9 c), SPEC.md §7.5.
        let fast = head_forward(&head, features.view()).unwrap();
        let reference = head_forward_reference(wt.view(), b.view(), f64s.view()).unwrap();
        let magnitude = head_forward_reference(
            wt.mapv(f64::abs).view(),
            b.mapv(f64::abs).view(),
            f64s.mapv(f64::abs).view(),
        )
        .unwrap();
        let k = (9 * c) as f32;
        densefeat::testing::within_budget(
            fast.view(),
            to32(&reference).view(),
            to32(&magnitude).view(),
            2.0 * k * f32::EPSILON,
        )
        .unwrap_or_else(|e| panic!("forward {h}x{w}x{c}: {e}"));
        // Loss on the same raw values: the same per-pixel maths, the gradient rounded once.
        let (s32, d32) = normal_loss(fast.view(), gt.view(), &cam, 0.5, 0.0).unwrap();
        let (s64, d64) = normal_loss_f64(to64(&fast).view(), gt.view(), &cam, 0.5, 0.0).unwrap();
        assert_eq!(s32, s64);
        assert_eq!(d32, to32(&d64));
        // Backward on the same d_raw: within 2 K ε of the magnitudes (K = 27 for the input
        // gradient, the pixel count for the weight gradient).
        let (d_f, d_head) = head_backward(&head, features.view(), d32.view()).unwrap();
        let (rf, rw, rb) = head_backward_reference(wt.view(), f64s.view(), to64(&d32).view()).unwrap();
        let (mf, mw, mb) = head_backward_reference(
            wt.mapv(f64::abs).view(),
            f64s.mapv(f64::abs).view(),
            to64(&d32).mapv(f64::abs).view(),
        )
        .unwrap();
        densefeat::testing::within_budget(
            d_f.view(),
            to32(&rf).view(),
            to32(&mf).view(),
            2.0 * 27.0 * f32::EPSILON,
        )
        .unwrap_or_else(|e| panic!("d_features {h}x{w}x{c}: {e}"));
        let kp = (h * w) as f32;
        densefeat::testing::within_budget(
            d_head.weight.view(),
            to32(&rw).view(),
            to32(&mw).view(),
            2.0 * kp * f32::EPSILON,
        )
        .unwrap_or_else(|e| panic!("d_weight {h}x{w}x{c}: {e}"));
        densefeat::testing::within_budget(
            d_head.bias.view(),
            to32(&rb).view(),
            to32(&mb).view(),
            2.0 * kp * f32::EPSILON,
        )
        .unwrap_or_else(|e| panic!("d_bias {h}x{w}x{c}: {e}"));
    }
}

fn tiny_trunk() -> NetworkWeights {
    let cfg = NetworkConfig { blocks: 2, channels: 4, b1_stride: 2, input_mean: [110.0; 3] };
    densefeat::train::trainer::training_init(&cfg, 5).unwrap()
}

fn data_cfg() -> DataConfig {
    DataConfig { crop: (48, 32), synthetic_scenes: 2, synthetic_val_scenes: 1, ..DataConfig::default() }
}

fn samples(n: usize) -> Vec<NormalSample> {
    let data = DataSet::open(data_cfg()).unwrap().with_cache_mb(64);
    (0..n).map(|i| data.train_pair(9, 1, i).unwrap().into()).collect()
}

#[test]
fn predictor_gradient_matches_a_directional_difference() {
    let mut weights = NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap();
    let sample = samples(1).remove(0);
    let cpu = CpuBackend::reference();
    // Keep every prediction far from r = 0, where the normalisation's curvature is unbounded: a
    // head bias along -z three times the largest raw output.
    let f = densefeat::nn::FeatureNet::new(weights.trunk.clone())
        .unwrap()
        .features(sample.rgb.view(), &cpu)
        .unwrap();
    let raw = head_forward(&weights.head, f.view()).unwrap();
    let peak = raw.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    weights.head.bias[2] = -3.0 * peak;
    let mut grads = weights.zeros_like();
    let sums = sample_step(&weights, &sample, &cpu, Some((&mut grads, 1.0)), 0.0).unwrap();
    assert!(sums.pixels > 100, "{}", sums.pixels);
    let mut r = rng(11);
    let mut dir = weights.zeros_like();
    for l in dir.layers_mut() {
        l.weight.mapv_inplace(|_| r() as f32);
        l.bias.mapv_inplace(|_| r() as f32);
    }
    let analytic: f64 = grads
        .layers()
        .iter()
        .zip(dir.layers())
        .map(|(g, v)| {
            g.weight
                .iter()
                .zip(&v.weight)
                .chain(g.bias.iter().zip(&v.bias))
                .map(|(a, b)| f64::from(*a) * f64::from(*b))
                .sum::<f64>()
        })
        .sum();
    let at = |s: f64, head_only: Option<bool>| {
        let mut w = weights.clone();
        let n = w.layers().len();
        for (i, (l, v)) in w.layers_mut().into_iter().zip(dir.layers()).enumerate() {
            if head_only.is_some_and(|h| h != (i == n - 1)) {
                continue;
            }
            l.weight.zip_mut_with(&v.weight, |a, b| *a += (s * f64::from(*b)) as f32);
            l.bias.zip_mut_with(&v.bias, |a, b| *a += (s * f64::from(*b)) as f32);
        }
        sample_step(&w, &sample, &cpu, None, 0.0).unwrap().mean()
    };
    let part = |head: bool| -> f64 {
        let n = grads.layers().len();
        grads
            .layers()
            .iter()
            .zip(dir.layers())
            .enumerate()
            .filter(|(i, _)| (*i == n - 1) == head)
            .map(|(_, (g, v))| {
                g.weight
                    .iter()
                    .zip(&v.weight)
                    .chain(g.bias.iter().zip(&v.bias))
                    .map(|(a, b)| f64::from(*a) * f64::from(*b))
                    .sum::<f64>()
            })
            .sum()
    };
    // The forward is f32: the difference carries its rounding over 2h (measured: 0.2 % at
    // h = 1e-4, converging from 1e-2; 0.1 % for the head alone).
    let h = 1e-4;
    for (what, only, analytic) in
        [("all", None, analytic), ("head", Some(true), part(true)), ("trunk", Some(false), part(false))]
    {
        let numeric = (at(h, only) - at(-h, only)) / (2.0 * h);
        assert!(
            (numeric - analytic).abs() <= 5e-3 * analytic.abs(),
            "{what}: numeric {numeric:e}, analytic {analytic:e}"
        );
    }
}

fn bits(w: &NormalNetWeights) -> Vec<u32> {
    w.layers()
        .iter()
        .flat_map(|l| l.weight.iter().chain(l.bias.iter()).map(|v| v.to_bits()).collect::<Vec<_>>())
        .collect()
}

#[test]
fn batch_gradient_is_independent_of_thread_count() {
    let weights = NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap();
    let frames = samples(3);
    let cpu = CpuBackend::default();
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| normals_batch_step(&weights, 3, |b| Ok(frames[b].clone()), &cpu, RAW_NORM_FLOOR))
            .unwrap()
    };
    let (l1, g1) = run(1);
    for n in [2, 3, 8] {
        let (l, g) = run(n);
        assert_eq!(l, l1, "threads = {n}");
        assert_eq!(bits(&g), bits(&g1), "threads = {n}");
    }
}

#[test]
fn upsampling_keeps_coarse_normals_and_gives_unit_vectors() {
    let cam = camera(9, 11);
    let coarse_cam = cam.at_level(1);
    let gt = gt_field(coarse_cam.height, coarse_cam.width, &coarse_cam, 12);
    let up = upsample_normals(gt.view(), 1, &cam);
    assert_eq!(up.dim(), (9, 11, 3));
    for y in 0..9 {
        for x in 0..11 {
            let n: Vec<f32> = (0..3).map(|k| up[[y, x, k]]).collect();
            if n[0].is_nan() {
                continue;
            }
            let norm = n.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-6, "({x}, {y}): {norm}");
            let d = ray(&cam, x, y);
            assert!(f64::from(n[0]) * d[0] + f64::from(n[1]) * d[1] + f64::from(n[2]) * d[2] <= 0.0);
            if x % 2 == 0 && y % 2 == 0 && !gt[[y / 2, x / 2, 0]].is_nan() {
                // Level-1 pixel j sits on level-0 pixel 2j: bilinear weight 1 (re-orientation
                // keeps it: the two rays are the same).
                for k in 0..3 {
                    assert!((up[[y, x, k]] - gt[[y / 2, x / 2, k]]).abs() < 1e-6);
                }
            }
        }
    }
    // The whole predictor: level-0 unit normals of the image's size.
    let sample = samples(1).remove(0);
    let net = NormalNet::new(NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap()).unwrap();
    let n = net.predict(sample.rgb.view(), &sample.camera).unwrap();
    assert_eq!(n.dim(), (32, 48, 3));
}

#[test]
fn files_round_trip_byte_for_byte_and_bad_files_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let w = NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap();
    let p = d.path().join("normalnet.safetensors");
    w.save(&p).unwrap();
    let back = NormalNetWeights::load(&p).unwrap();
    assert_eq!(back, w);
    assert_eq!(back.to_safetensors_bytes().unwrap(), std::fs::read(&p).unwrap());
    // A feature-network file is not a normal predictor.
    let f = d.path().join("featurenet.safetensors");
    w.trunk.save(&f).unwrap();
    let e = NormalNetWeights::load(&f).unwrap_err().to_string();
    assert!(e.contains("densefeat-normalnet-v1") && e.contains("featurenet.safetensors"), "{e}");
    // Truncated.
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() - 4]).unwrap();
    assert!(NormalNetWeights::load(&f).is_err());
    std::fs::write(&f, &bytes[..5]).unwrap();
    assert!(NormalNetWeights::load(&f).unwrap_err().to_string().contains("truncated"));
    // A weights file is not a checkpoint.
    let e = NormalCheckpoint::load(&p).unwrap_err().to_string();
    assert!(e.contains("densefeat-normalnet-checkpoint-v1"), "{e}");
}

fn tiny_cfg(steps: usize) -> NormalsTrainConfig {
    NormalsTrainConfig {
        init_trunk: "test trunk".into(),
        head_seed: HEAD_SEED,
        seed: 4,
        steps,
        batch: 2,
        optim: OptimConfig { lr: 3e-3, warmup: 1, ..OptimConfig::default() },
        data: data_cfg(),
        val_every: 2,
        val_per_source: 2,
        ckpt_every: 2,
        // The tiny trunk's outputs are far below the shipped one's scale: no floor.
        raw_norm_floor: 0.0,
        frame_cache_mb: 64,
    }
}

fn run(
    cfg: &NormalsTrainConfig,
    out: &Path,
    threads: usize,
    resume: Option<&Path>,
    stop: Option<usize>,
) -> NormalNetWeights {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| train_normals(cfg, &tiny_trunk(), out, resume, stop, &mut densefeat::progress::Silent))
        .unwrap()
}

#[test]
fn training_is_thread_independent_and_resumes_exactly() {
    let d = tempfile::tempdir().unwrap();
    let cfg = tiny_cfg(4);
    let one = run(&cfg, &d.path().join("one"), 1, None, None);
    let three = run(&cfg, &d.path().join("three"), 3, None, None);
    assert_eq!(bits(&one), bits(&three));
    // Two steps, then resume from that checkpoint: the same files as the uninterrupted run.
    let split = d.path().join("split");
    run(&cfg, &split, 2, None, Some(2));
    let ckpt = d.path().join("ckpt2.safetensors");
    std::fs::copy(split.join("checkpoint.safetensors"), &ckpt).unwrap();
    run(&cfg, &split, 2, Some(&ckpt), None);
    for f in ["checkpoint.safetensors", "normalnet.safetensors"] {
        assert_eq!(
            std::fs::read(split.join(f)).unwrap(),
            std::fs::read(d.path().join("one").join(f)).unwrap(),
            "{f}"
        );
    }
    let log = std::fs::read_to_string(split.join("log.csv")).unwrap();
    assert_eq!(log.lines().count(), 5, "{log}");
    // Another configuration is refused, naming the file.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let e = pool
        .install(|| {
            train_normals(
                &tiny_cfg(5),
                &tiny_trunk(),
                &split,
                Some(&ckpt),
                None,
                &mut densefeat::progress::Silent,
            )
        })
        .unwrap_err()
        .to_string();
    assert!(e.contains("different configuration") && e.contains("ckpt2"), "{e}");
}

#[test]
fn a_few_steps_lower_the_loss_on_a_tiny_synthetic_scene() {
    let d = tempfile::tempdir().unwrap();
    let cfg = NormalsTrainConfig { steps: 40, val_every: 40, ckpt_every: 40, ..tiny_cfg(40) };
    let data = DataSet::open(cfg.data.clone()).unwrap();
    let val: Vec<NormalSample> = data.val_pairs(4).unwrap().into_iter().map(|(_, p)| p.into()).collect();
    let start = NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap();
    let before = validate_normals(&start, &val).unwrap();
    let trained = run(&cfg, d.path(), 2, None, None);
    let after = validate_normals(&trained, &val).unwrap();
    eprintln!(
        "validation loss {:.4} -> {:.4}, mean angle {:.2} -> {:.2} degrees",
        before.0, after.0, before.1, after.1
    );
    assert!(after.0 < 0.8 * before.0, "loss {} -> {}", before.0, after.0);
    assert!(after.1 < before.1, "angle {} -> {}", before.1, after.1);
}

fn densefeat(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn bad_flags_are_refused_naming_the_flag() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o");
    let out = out.to_str().unwrap();
    for (extra, flag) in [
        (vec!["--steps", "0"], "--steps"),
        (vec!["--batch", "0"], "--batch"),
        (vec!["--lr=-1"], "--lr"),
        (vec!["--crop", "12"], "--crop"),
        (vec!["--resume", "/no/such/checkpoint.safetensors"], "--resume"),
        (vec!["--synthetic-style", "cartoon"], "style"),
        (vec!["--raw-norm-floor=-1"], "--raw-norm-floor"),
    ] {
        let mut args = vec!["train-normals", "--out", out, "--synthetic-scenes", "1"];
        args.extend(extra);
        let (ok, err) = densefeat(&args);
        assert!(!ok, "{args:?}");
        assert!(err.starts_with("error: ") && err.contains(flag), "{args:?}: {err}");
    }
    assert!(!Path::new(out).exists(), "nothing is written on a bad flag");
    // --normal-weights needs --normals learned and a file.
    let seq = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    let base =
        ["reconstruct", "--sequence", seq, "--keyframe", "10", "--regularizer", "normals", "--out", out];
    let (ok, err) =
        densefeat(&[&base[..], &["--normals", "gt", "--normal-weights", "x.safetensors"]].concat());
    assert!(!ok && err.contains("--normal-weights"), "{err}");
    let (ok, err) = densefeat(
        &[&base[..], &["--normals", "learned", "--normal-weights", "/no/such.safetensors"]].concat(),
    );
    assert!(!ok && err.contains("--normal-weights"), "{err}");
    // A feature-network file given as the predictor: refused naming it, before any work.
    let fw = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/weights/featurenet_init_seed0.safetensors");
    let (ok, err) = densefeat(&[&base[..], &["--normals", "learned", "--normal-weights", fw]].concat());
    assert!(!ok && err.contains("featurenet_init_seed0") && err.contains("normalnet"), "{err}");
    assert!(!Path::new(out).exists());
}

#[test]
fn eval_reports_the_predictors_angular_error_per_keyframe() {
    let d = tempfile::tempdir().unwrap();
    let weights = d.path().join("normalnet.safetensors");
    NormalNetWeights::from_trunk(tiny_trunk(), HEAD_SEED).unwrap().save(&weights).unwrap();
    let out = d.path().join("eval");
    let seq = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    let (ok, err) = densefeat(&[
        "eval",
        "--sequence",
        seq,
        "--keyframes",
        "10:5:15",
        "--methods",
        "rgb-normals",
        "--normals",
        "learned",
        "--normal-weights",
        weights.to_str().unwrap(),
        "--window",
        "2,2",
        "--level",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    assert!(table.contains("Built-in normal predictor") && table.contains("| 15 |"), "{table}");
    let csv = std::fs::read_to_string(out.join("normals_error.csv")).unwrap();
    let rows: Vec<Vec<f64>> =
        csv.lines().skip(1).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
    assert_eq!(rows.iter().map(|r| r[0]).collect::<Vec<_>>(), [10.0, 15.0], "{csv}");
    for r in &rows {
        // Mean and median angles in [0, 180]; every pixel of the 320x240 fixture has depth.
        assert!((0.0..=180.0).contains(&r[1]) && (0.0..=180.0).contains(&r[2]) && r[3] > 50_000.0, "{csv}");
    }
}

#[test]
fn the_shipped_predictor_is_the_normal_priors_default() {
    // The compiled-in file loads as a predictor of the shipped features' shape.
    let w = densefeat::mapping::normals::load_predictor(None).unwrap();
    assert_eq!(w.trunk.config, densefeat::mapping::features::load_weights(None).unwrap().config);
    // `reconstruct --regularizer normals` without --normals runs with it and reports its error.
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o");
    let seq = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    let o = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["reconstruct", "--sequence", seq, "--keyframe", "10", "--window", "2,2", "--level", "1"])
        .args(["--bins", "32", "--regularizer", "normals", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line =
        stdout.lines().find(|l| l.contains("predicted normals (--normals learned)")).unwrap_or_else(|| {
            panic!("{stdout}");
        });
    let mean: f64 = line.split("mean ").nth(1).and_then(|s| s.split('°').next()).unwrap().parse().unwrap();
    assert!((0.0..90.0).contains(&mean), "{line}");
    assert!(stdout.contains("  normals: "), "the prior's metrics: {stdout}");
}

#[test]
fn the_learned_features_default_to_the_normal_prior_and_the_others_to_tv() {
    use densefeat::mapping::keyframe::Regularizer;
    use densefeat::mapping::FeatureKind;
    // SPEC.md §10.1b: chosen per feature type on validation; without a normal source, TV.
    assert_eq!(Regularizer::default_for(&FeatureKind::Learned(None), true), Regularizer::Normals);
    let custom = FeatureKind::Learned(Some("w.safetensors".into()));
    assert_eq!(Regularizer::default_for(&custom, true), Regularizer::Normals);
    assert_eq!(Regularizer::default_for(&FeatureKind::Learned(None), false), Regularizer::Tv);
    for k in [FeatureKind::Rgb, FeatureKind::B1(None), FeatureKind::Dsift, FeatureKind::Patch7] {
        assert_eq!(Regularizer::default_for(&k, true), Regularizer::Tv, "{k:?}");
    }
    // `reconstruct` without --regularizer: the learned features write the prior's depth, RGB TV's.
    let d = tempfile::tempdir().unwrap();
    let seq = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    for (features, depth, other) in
        [("learned", "depth_normals.pfm", "depth_tv.pfm"), ("rgb", "depth_tv.pfm", "depth_normals.pfm")]
    {
        let out = d.path().join(features);
        let o = Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["reconstruct", "--sequence", seq, "--keyframe", "10", "--window", "2,2", "--level", "1"])
            .args(["--bins", "32", "--features", features, "--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(out.join(depth).is_file() && !out.join(other).exists(), "{features}: {stdout}");
    }
}
