//! The cost-volume loss (SPEC.md §13.1): the f64 reference against central finite differences,
//! the fast f32 version against the reference within the §13.3 budget, thread-count determinism,
//! masking and the per-pixel terms.

use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose, Warp};
use densefeat::runtime::CpuFeatureLevel;
use densefeat::train::loss::{
    loss_kernels, pixel_sampled, pixel_terms, scale_loss, scale_loss_multi, scale_loss_multi_reference,
    scale_loss_reference, scale_loss_with, seen_threshold, uses_avx512, LiveView, LossConfig, LossKernels,
    LossSums, MultiCost, MultiScaleLoss, SEEN_MIN_EVIDENCE,
};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use ndarray::{Array2, Array3};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Values in [-1, 1) from SplitMix64.
pub(crate) fn rng(seed: u64) -> impl FnMut() -> f64 {
    let mut r = densefeat::util::rng::SplitMix64::new(seed);
    move || r.range(-1.0, 1.0)
}

pub(crate) struct Case {
    pub(crate) cfg: LossConfig,
    pub(crate) f_ref: Array3<f64>,
    pub(crate) f_live: Array3<f64>,
    pub(crate) depth: Array2<f32>,
    pub(crate) warp: Warp,
}

pub(crate) fn case(seed: u64, h: usize, w: usize, c: usize, k: usize) -> Case {
    let mut r = rng(seed);
    let cam =
        PinholeCamera::new(w as f64, w as f64, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h).unwrap();
    let t = Vector3::new(0.25 + 0.1 * r(), 0.1 * r(), 0.05 * r());
    let q = UnitQuaternion::from_euler_angles(0.03 * r(), 0.03 * r(), 0.03 * r());
    let pose = Pose::from_parts(Translation3::from(t), q);
    let warp = Warp::new(&cam, &cam, &pose);
    // Features of moderate size so the softmax is neither flat nor saturated.
    let f_ref = Array3::from_shape_fn((h, w, c), |_| 0.8 * r());
    let f_live = Array3::from_shape_fn((h, w, c), |_| 0.8 * r());
    let depth = Array2::from_shape_fn((h, w), |_| if r() < -0.8 { 0.0 } else { (1.9 + 1.1 * r()) as f32 });
    let cfg = LossConfig { bins: InverseDepthBins::new(0.0, 1.5, k).unwrap(), ..LossConfig::default() };
    Case { cfg, f_ref, f_live, depth, warp }
}

pub(crate) fn loss_of(c: &Case, f_ref: &Array3<f64>, f_live: &Array3<f64>) -> f64 {
    scale_loss_reference(&c.cfg, f_ref.view(), f_live.view(), c.depth.view(), &c.warp).unwrap().sums.mean()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    /// Every entry of both analytic gradients against a central difference of the f64 loss.
    #[test]
    fn reference_gradients_match_finite_differences(seed in 0u64..1000) {
        let c = case(seed, 5, 6, 3, 10);
        let out = scale_loss_reference(&c.cfg, c.f_ref.view(), c.f_live.view(), c.depth.view(), &c.warp).unwrap();
        prop_assume!(out.sums.pixels > 3);
        let eps = 1e-6;
        let mut worst: f64 = 0.0;
        for (which, grad) in [(0, &out.d_ref), (1, &out.d_live)] {
            for (idx, &g) in grad.indexed_iter() {
                let (mut a, mut b) = (c.f_ref.clone(), c.f_live.clone());
                let (mut a2, mut b2) = (c.f_ref.clone(), c.f_live.clone());
                if which == 0 { a[idx] += eps; a2[idx] -= eps; } else { b[idx] += eps; b2[idx] -= eps; }
                let fd = (loss_of(&c, &a, &b) - loss_of(&c, &a2, &b2)) / (2.0 * eps);
                let err = (fd - g).abs() / (1e-4 + g.abs().max(fd.abs()));
                worst = worst.max(err);
                prop_assert!(err < 1e-4, "grad {which} {idx:?}: analytic {g}, fd {fd}");
            }
        }
        prop_assert!(worst.is_finite());
    }

    /// The per-pixel terms' gradient with respect to the costs, including out-of-image costs.
    #[test]
    fn pixel_terms_gradient_matches_finite_differences(seed in 0u64..1000, target in 0usize..12) {
        let mut r = rng(seed);
        let cfg = LossConfig { bins: InverseDepthBins::new(0.0, 2.0, 12).unwrap(), ..LossConfig::default() };
        let e: Vec<f64> = (0..12).map(|i| if i == 3 { cfg.outside_cost } else { 2.0 + 1.5 * r() }).collect();
        let rho_star = 0.3 + 0.5 * (r() + 1.0);
        pixel_terms_match_fd(&cfg, &e, target, rho_star)?;
    }

    /// Fast f32 against the f64 reference: the loss within 1e-5 relative, each gradient entry
    /// within 1e-4 of the largest entry of its map (SPEC.md §13.3).
    #[test]
    fn fast_matches_reference_within_budget(seed in 0u64..1000, stride in 1usize..4) {
        let mut c = case(seed, 12, 16, 8, 32);
        // Pixel sampling (SPEC.md §13.1a): both implementations evaluate the same pixels.
        c.cfg.sample_stride = stride;
        c.cfg.sample_seed = seed ^ 0x5eed;
        fast_within_budget(&c)?;
    }
}

/// `pixel_terms`' gradient with respect to every cost against a central difference of its total
/// (every term, the ranking term's included).
pub(crate) fn pixel_terms_match_fd(
    cfg: &LossConfig,
    e: &[f64],
    target: usize,
    rho_star: f64,
) -> Result<(), TestCaseError> {
    let k = e.len();
    let mut g = vec![0.0; k];
    pixel_terms(cfg, e, target, rho_star, &mut g);
    let total = |e: &[f64]| {
        let mut s = vec![0.0; k];
        let t = pixel_terms(cfg, e, target, rho_star, &mut s);
        t.ce + t.rho + t.depth + t.hinge
    };
    for l in 0..k {
        let (mut a, mut b) = (e.to_vec(), e.to_vec());
        a[l] += 1e-6;
        b[l] -= 1e-6;
        let fd = (total(&a) - total(&b)) / 2e-6;
        prop_assert!((fd - g[l]).abs() < 1e-6 + 1e-5 * fd.abs(), "bin {l}: analytic {}, fd {fd}", g[l]);
    }
    Ok(())
}

/// Fast f32 against the f64 reference on the f32-rounded inputs (so only the arithmetic differs):
/// the same pixels and WTA counts, the loss within 1e-5 relative, each gradient entry within 1e-4
/// of the largest entry of its map (SPEC.md §13.3). Returns the reference's sums.
pub(crate) fn fast_within_budget(c: &Case) -> Result<LossSums, TestCaseError> {
    let fr = c.f_ref.mapv(|v| v as f32);
    let fl = c.f_live.mapv(|v| v as f32);
    let want = scale_loss_reference(
        &c.cfg,
        fr.mapv(f64::from).view(),
        fl.mapv(f64::from).view(),
        c.depth.view(),
        &c.warp,
    )
    .unwrap();
    let got = scale_loss(&c.cfg, fr.view(), fl.view(), c.depth.view(), &c.warp).unwrap();
    prop_assert_eq!(got.sums.pixels, want.sums.pixels);
    prop_assert_eq!(got.sums.delta125_wta, want.sums.delta125_wta);
    let (lg, lw) = (got.sums.mean(), want.sums.mean());
    prop_assert!((lg - lw).abs() <= 1e-5 * lw.abs().max(1.0), "loss {lg} vs {lw}");
    for (g, w) in [(&got.d_ref, &want.d_ref), (&got.d_live, &want.d_live)] {
        let scale = w.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        prop_assert!(scale > 0.0 || want.sums.pixels == 0);
        for (a, b) in g.iter().zip(w.iter()) {
            prop_assert!((f64::from(*a) - b).abs() <= 1e-4 * scale + 1e-12, "{a} vs {b} (max {scale})");
        }
    }
    Ok(want.sums)
}

#[test]
fn fast_loss_is_bit_identical_for_any_thread_count() {
    for stride in [1, 3] {
        let mut c = case(7, 24, 20, 8, 48);
        c.cfg.sample_stride = stride;
        c.cfg.sample_seed = 11;
        loss_bits_independent_of_threads(&c);
    }
}

fn loss_bits_independent_of_threads(c: &Case) {
    let fr = c.f_ref.mapv(|v| v as f32);
    let fl = c.f_live.mapv(|v| v as f32);
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| scale_loss(&c.cfg, fr.view(), fl.view(), c.depth.view(), &c.warp).unwrap())
    };
    let base = run(1);
    assert!(base.sums.pixels > 0);
    for n in [2, 3, 8] {
        let o = run(n);
        assert_eq!(o.sums, base.sums, "{n} threads");
        assert!(
            o.d_ref.iter().zip(base.d_ref.iter()).all(|(a, b)| a.to_bits() == b.to_bits()),
            "{n} threads d_ref"
        );
        assert!(
            o.d_live.iter().zip(base.d_live.iter()).all(|(a, b)| a.to_bits() == b.to_bits()),
            "{n} threads d_live"
        );
    }
}

#[test]
fn masked_pixels_contribute_nothing() {
    let c = case(3, 8, 10, 4, 16);
    let all_invalid = Array2::<f32>::zeros(c.depth.dim());
    let o =
        scale_loss_reference(&c.cfg, c.f_ref.view(), c.f_live.view(), all_invalid.view(), &c.warp).unwrap();
    assert_eq!(o.sums.pixels, 0);
    assert_eq!(o.sums.mean(), 0.0);
    assert!(o.d_ref.iter().chain(o.d_live.iter()).all(|&v| v == 0.0));
    // A depth beyond the bins (rho* < rho_min) is masked as well.
    let cfg = LossConfig { bins: InverseDepthBins::new(0.5, 1.5, 16).unwrap(), ..c.cfg };
    let far = Array2::<f32>::from_elem(c.depth.dim(), 4.0);
    let o = scale_loss_reference(&cfg, c.f_ref.view(), c.f_live.view(), far.view(), &c.warp).unwrap();
    assert_eq!(o.sums.pixels, 0);
}

#[test]
fn matching_features_at_the_true_depth_give_a_low_loss() {
    // Live features are the reference features warped: the true bin has zero cost, so WTA is exact.
    let (h, w, c_n) = (10, 12, 4);
    let cam = PinholeCamera::new(12.0, 12.0, 5.5, 4.5, w, h).unwrap();
    let pose = Pose::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity());
    let warp = Warp::new(&cam, &cam, &pose);
    let mut r = rng(11);
    let f = Array3::from_shape_fn((h, w, c_n), |_| 2.0 * r());
    let cfg = LossConfig { bins: InverseDepthBins::new(0.0, 1.0, 8).unwrap(), ..LossConfig::default() };
    // Identity pose: every hypothesis samples u itself, so the curve is flat (ambiguous).
    let depth = Array2::<f32>::from_elem((h, w), 2.0);
    let flat = scale_loss_reference(&cfg, f.view(), f.view(), depth.view(), &warp).unwrap();
    assert_eq!(flat.sums.pixels, h * w);
    // CE of a uniform P over K bins: ln K + (K-1) ln(K/(K-1)).
    let k = 8.0f64;
    let ce = k.ln() + (k - 1.0) * (k / (k - 1.0)).ln();
    assert!((flat.sums.ce / (h * w) as f64 - ce).abs() < 1e-9);
}

fn bits_equal(a: &Array3<f32>, b: &Array3<f32>) -> bool {
    a.iter().zip(b.iter()).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// 32 channels (the network's): the AVX-512 or AVX2 kernels where the CPU has them. Budget against
/// the reference, the portable kernels' bits (and each vector build the CPU has), and thread-count
/// determinism.
#[test]
fn fast_loss_with_32_channels_matches_reference_portable_and_threads() {
    let c = case(11, 14, 18, 32, 40);
    eprintln!("loss kernels: {:?}", loss_kernels(CpuFeatureLevel::get(), 32));
    assert!(!uses_avx512(CpuFeatureLevel::Portable, 32) && !uses_avx512(CpuFeatureLevel::get(), 8));
    assert_eq!(loss_kernels(CpuFeatureLevel::Portable, 32), LossKernels::Portable);
    assert_eq!(loss_kernels(CpuFeatureLevel::get(), 8), LossKernels::Portable);
    if CpuFeatureLevel::detected() >= CpuFeatureLevel::Avx2 {
        assert_eq!(loss_kernels(CpuFeatureLevel::Avx2, 32), LossKernels::Avx2);
    }
    let fr = c.f_ref.mapv(|v| v as f32);
    let fl = c.f_live.mapv(|v| v as f32);
    let run = |n: usize, k: CpuFeatureLevel| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| scale_loss_with(k, &c.cfg, fr.view(), fl.view(), c.depth.view(), &c.warp).unwrap())
    };
    let got = run(1, CpuFeatureLevel::get());
    assert!(got.sums.pixels > 10);
    // The dispatched kernels within the budget of the f64 reference.
    fast_within_budget(&c).unwrap();
    for (n, k) in [
        (1, CpuFeatureLevel::Portable),
        (2, CpuFeatureLevel::get()),
        (3, CpuFeatureLevel::Portable),
        (8, CpuFeatureLevel::get()),
        (1, CpuFeatureLevel::Avx2),
        (3, CpuFeatureLevel::Avx2),
        (2, CpuFeatureLevel::Avx512),
    ] {
        let o = run(n, k);
        assert_eq!(o.sums, got.sums, "{n} threads, {k:?}");
        assert!(bits_equal(&o.d_ref, &got.d_ref), "{n} threads, {k:?}: d_ref");
        assert!(bits_equal(&o.d_live, &got.d_live), "{n} threads, {k:?}: d_live");
    }
}

/// The cross-entropy's Σ ln(1 − P) taken over runs of products stays exact for a tiny floor.
#[test]
fn pixel_terms_cross_entropy_is_the_sum_of_logs_for_any_floor() {
    let k = 200;
    let energies: Vec<f64> = (0..k).map(|l| 0.05 * ((l * 37) % 23) as f64).collect();
    for floor in [1e-6, 1e-30, 1e-300] {
        let cfg = LossConfig {
            bins: InverseDepthBins::new(0.0, 2.0, k).unwrap(),
            prob_floor: floor,
            ..LossConfig::default()
        };
        let mut grad = vec![0.0; k];
        let t = pixel_terms(&cfg, &energies, 17, 0.5, &mut grad);
        let e_min = energies.iter().cloned().fold(f64::INFINITY, f64::min);
        let z: f64 = energies.iter().map(|e| (e_min - e).exp()).sum();
        let p = |l: usize| (e_min - energies[l]).exp() / z;
        let want =
            -p(17).ln() - (0..k).filter(|&l| l != 17).map(|l| (1.0 - p(l)).max(floor).ln()).sum::<f64>();
        assert!((t.ce - want).abs() <= 1e-12 * want.abs(), "floor {floor}: {} vs {want}", t.ce);
    }
}

/// SPEC.md §13.1a: over the seed every pixel (partial edge blocks included) is evaluated with
/// probability 1/s², and exactly one pixel of each full block is evaluated for any seed.
#[test]
fn sampling_evaluates_each_pixel_with_probability_one_over_s_squared() {
    let (w, h, s) = (7usize, 5usize, 3usize);
    let seeds = 9000u64;
    let mut hits = vec![0u64; w * h];
    for seed in 0..seeds {
        let cfg = LossConfig { sample_stride: s, sample_seed: seed, ..LossConfig::default() };
        for y in 0..h {
            for x in 0..w {
                hits[y * w + x] += u64::from(pixel_sampled(&cfg, x, y));
            }
        }
        // The two full 3x3 blocks hold exactly one evaluated pixel each.
        for bx in 0..2 {
            let n = (0..3)
                .flat_map(|y| (0..3).map(move |x| (x + 3 * bx, y)))
                .filter(|&(x, y)| pixel_sampled(&cfg, x, y))
                .count();
            assert_eq!(n, 1, "seed {seed} block {bx}");
        }
    }
    let p = 1.0 / (s * s) as f64;
    let se = (p * (1.0 - p) / seeds as f64).sqrt();
    for (i, &k) in hits.iter().enumerate() {
        let f = k as f64 / seeds as f64;
        assert!((f - p).abs() < 5.0 * se, "pixel {i}: {f} vs {p}");
    }
    let all = LossConfig::default();
    assert!((0..h).all(|y| (0..w).all(|x| pixel_sampled(&all, x, y))));
}

/// SPEC.md §13.1a: the sampled loss and its gradient are unbiased estimates of the full ones
/// (mean over seeds within 5 standard errors; the gradient through its projection on the full
/// gradient).
#[test]
fn sampled_loss_and_gradient_are_unbiased() {
    let c = case(3, 12, 16, 8, 32);
    let fr = c.f_ref.mapv(|v| v as f32);
    let fl = c.f_live.mapv(|v| v as f32);
    let full = scale_loss(&c.cfg, fr.view(), fl.view(), c.depth.view(), &c.warp).unwrap();
    assert!(full.sums.pixels > 50);
    let dot = |a: &Array3<f32>, b: &Array3<f32>| {
        a.iter().zip(b).map(|(x, y)| f64::from(*x) * f64::from(*y)).sum::<f64>()
    };
    let g2 = dot(&full.d_ref, &full.d_ref) + dot(&full.d_live, &full.d_live);
    for stride in [2, 3] {
        let (mut losses, mut projections) = (Vec::new(), Vec::new());
        for seed in 0..400 {
            let cfg = LossConfig { sample_stride: stride, sample_seed: seed, ..c.cfg };
            let o = scale_loss(&cfg, fr.view(), fl.view(), c.depth.view(), &c.warp).unwrap();
            assert_eq!(o.sums.pixels, full.sums.pixels, "N counts every unmasked pixel");
            losses.push(o.sums.mean());
            projections.push((dot(&o.d_ref, &full.d_ref) + dot(&o.d_live, &full.d_live)) / g2);
        }
        for (name, v, want) in [("loss", &losses, full.sums.mean()), ("gradient", &projections, 1.0)] {
            let n = v.len() as f64;
            let mean = v.iter().sum::<f64>() / n;
            let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
            let se = (var / n).sqrt();
            assert!(se > 0.0, "{name}: the samples differ");
            assert!(
                (mean - want).abs() < 5.0 * se,
                "stride {stride} {name}: mean {mean} vs {want} (se {se})"
            );
        }
    }
}

/// Further live frames for a case: features and warps of other poses of the same camera.
fn more_lives(seed: u64, c: &Case, n: usize) -> Vec<(Array3<f64>, Warp)> {
    let mut r = rng(seed ^ 0xabc);
    let (h, w, ch) = c.f_ref.dim();
    let cam = *c.warp.reference();
    (0..n)
        .map(|_| {
            let t = Vector3::new(-0.2 + 0.1 * r(), 0.15 * r(), 0.05 * r());
            let q = UnitQuaternion::from_euler_angles(0.03 * r(), 0.03 * r(), 0.03 * r());
            let warp = Warp::new(&cam, &cam, &Pose::from_parts(Translation3::from(t), q));
            (Array3::from_shape_fn((h, w, ch), |_| 0.8 * r()), warp)
        })
        .collect()
}

fn views<'a>(c: &'a Case, extra: &'a [(Array3<f64>, Warp)]) -> Vec<LiveView<'a, f64>> {
    std::iter::once(LiveView { features: c.f_live.view(), warp: &c.warp })
        .chain(extra.iter().map(|(f, w)| LiveView { features: f.view(), warp: w }))
        .collect()
}

/// SPEC.md §13.1b: the multi-frame reference's gradients against central differences, for the
/// reference map and every live map.
#[test]
fn multi_frame_reference_gradients_match_finite_differences() {
    let c = case(5, 5, 6, 3, 10);
    let extra = more_lives(5, &c, 2);
    let out = assert_multi_gradients_match_fd(&c, &views(&c, &extra));
    assert_eq!(out.d_lives.len(), 3);
}

/// The multi-frame f64 reference under `c.cfg`, with every entry of its gradients (the reference
/// map's and each live map's) checked against a central difference of its loss.
fn assert_multi_gradients_match_fd(c: &Case, lives: &[LiveView<'_, f64>]) -> MultiScaleLoss<f64> {
    let out = scale_loss_multi_reference(&c.cfg, c.f_ref.view(), lives, c.depth.view()).unwrap();
    assert!(out.sums.pixels > 2, "a case with unmasked pixels");
    let loss = |f_ref: &Array3<f64>, lives: &[LiveView<'_, f64>]| {
        scale_loss_multi_reference(&c.cfg, f_ref.view(), lives, c.depth.view()).unwrap().sums.mean()
    };
    let eps = 1e-6;
    let check = |g: f64, fd: f64, what: &str| {
        let err = (fd - g).abs() / (1e-4 + g.abs().max(fd.abs()));
        assert!(err < 1e-4, "{what}: analytic {g}, fd {fd}");
    };
    for (idx, &g) in out.d_ref.indexed_iter() {
        let (mut a, mut b) = (c.f_ref.clone(), c.f_ref.clone());
        a[idx] += eps;
        b[idx] -= eps;
        check(g, (loss(&a, lives) - loss(&b, lives)) / (2.0 * eps), &format!("d_ref {idx:?}"));
    }
    let live_maps: Vec<Array3<f64>> = lives.iter().map(|l| l.features.to_owned()).collect();
    for (n, d) in out.d_lives.iter().enumerate() {
        for (idx, &g) in d.indexed_iter() {
            let bumped = |delta: f64| {
                let mut maps = live_maps.clone();
                maps[n][idx] += delta;
                let v: Vec<LiveView<'_, f64>> = maps
                    .iter()
                    .zip(lives)
                    .map(|(f, l)| LiveView { features: f.view(), warp: l.warp })
                    .collect();
                loss(&c.f_ref, &v)
            };
            check(g, (bumped(eps) - bumped(-eps)) / (2.0 * eps), &format!("d_live{n} {idx:?}"));
        }
    }
    out
}

/// The fast multi-frame loss under `cfg` on `fr` / `v32` (f32 copies of `c.f_ref` and `lives`) with
/// `threads` threads.
fn fast_multi(
    cfg: &LossConfig,
    c: &Case,
    fr: &Array3<f32>,
    v32: &[LiveView<'_, f32>],
    threads: usize,
) -> MultiScaleLoss<f32> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| scale_loss_multi(cfg, fr.view(), v32, c.depth.view()).unwrap())
}

/// The fast multi-frame loss under `c.cfg` against the f64 reference on the same f32-rounded
/// inputs (so only the arithmetic differs) within §13.3's budgets, and bit-identical for 1, 2, 3
/// and 8 threads. Returns the one-thread result.
fn assert_fast_multi_matches_reference(
    c: &Case,
    lives: &[LiveView<'_, f64>],
    fr: &Array3<f32>,
    v32: &[LiveView<'_, f32>],
) -> MultiScaleLoss<f32> {
    let rounded: Vec<Array3<f64>> = v32.iter().map(|l| l.features.mapv(f64::from)).collect();
    let rv: Vec<LiveView<'_, f64>> =
        rounded.iter().zip(lives).map(|(f, l)| LiveView { features: f.view(), warp: l.warp }).collect();
    let want = scale_loss_multi_reference(&c.cfg, fr.mapv(f64::from).view(), &rv, c.depth.view()).unwrap();
    let got = fast_multi(&c.cfg, c, fr, v32, 1);
    assert!(got.sums.pixels > 0);
    assert_eq!(got.sums.pixels, want.sums.pixels);
    assert_eq!(got.sums.delta125_wta, want.sums.delta125_wta);
    let (lg, lw) = (got.sums.mean(), want.sums.mean());
    assert!((lg - lw).abs() <= 1e-5 * lw.abs().max(1.0), "loss {lg} vs {lw}");
    for (g, w) in std::iter::once((&got.d_ref, &want.d_ref)).chain(got.d_lives.iter().zip(&want.d_lives)) {
        let scale = w.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 0.0);
        for (a, b) in g.iter().zip(w.iter()) {
            assert!((f64::from(*a) - b).abs() <= 1e-4 * scale + 1e-12, "{a} vs {b} (max {scale})");
        }
    }
    for n in [2, 3, 8] {
        let o = fast_multi(&c.cfg, c, fr, v32, n);
        assert_eq!(o.sums, got.sums, "{n} threads");
        assert!(bits_equal(&o.d_ref, &got.d_ref), "{n} threads d_ref");
        for (a, b) in o.d_lives.iter().zip(&got.d_lives) {
            assert!(bits_equal(a, b), "{n} threads d_live");
        }
    }
    got
}

/// SPEC.md §13.1b: the fast multi-frame loss against the reference (3 live frames, with and
/// without sampling), one live frame bit-identical to the pair loss, and bit-identical for 1, 2,
/// 3 and 8 threads.
#[test]
fn multi_frame_fast_matches_reference_and_pair_loss() {
    for stride in [1, 2] {
        let mut c = case(9, 12, 16, 8, 32);
        c.cfg.sample_stride = stride;
        c.cfg.sample_seed = 4;
        let extra = more_lives(9, &c, 2);
        let lives = views(&c, &extra);
        let fr = c.f_ref.mapv(|v| v as f32);
        let fls: Vec<Array3<f32>> = lives.iter().map(|l| l.features.mapv(|v| v as f32)).collect();
        let v32: Vec<LiveView<'_, f32>> =
            fls.iter().zip(&lives).map(|(f, l)| LiveView { features: f.view(), warp: l.warp }).collect();
        assert_fast_multi_matches_reference(&c, &lives, &fr, &v32);
        // One live frame: exactly the pair loss.
        let one = scale_loss_multi(&c.cfg, fr.view(), &v32[..1], c.depth.view()).unwrap();
        let pair = scale_loss(&c.cfg, fr.view(), fls[0].view(), c.depth.view(), &c.warp).unwrap();
        assert_eq!(one.sums, pair.sums);
        assert!(bits_equal(&one.d_ref, &pair.d_ref) && bits_equal(&one.d_lives[0], &pair.d_live));
    }
}

/// `--regression-weight W` (SPEC.md §13.1 step 5): `λ_ρ = 5 W`, `λ_d = W`. W = 1 is the paper's
/// configuration field for field (so its fingerprint is unchanged); W = 0 leaves the cross-entropy
/// sums bit for bit and makes the regression sums 0, and the gradient of that loss still matches
/// finite differences; W = 2 doubles the regression sums; a bad W is refused naming the flag.
#[test]
fn the_regression_weight_scales_the_regression_term_only() {
    assert_eq!(LossConfig::default().with_regression_weight(1.0).unwrap(), LossConfig::default());
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let err = LossConfig::default().with_regression_weight(bad).unwrap_err().to_string();
        assert!(err.contains("--regression-weight"), "{err}");
    }
    let base = case(11, 6, 7, 3, 12);
    let sums = |w: f64| {
        let cfg = base.cfg.with_regression_weight(w).unwrap();
        scale_loss_reference(&cfg, base.f_ref.view(), base.f_live.view(), base.depth.view(), &base.warp)
            .unwrap()
            .sums
    };
    let (paper, ce_only, double) = (sums(1.0), sums(0.0), sums(2.0));
    assert!(paper.pixels > 0 && paper.rho > 0.0 && paper.depth > 0.0);
    assert_eq!(ce_only.ce.to_bits(), paper.ce.to_bits());
    assert_eq!((ce_only.rho, ce_only.depth), (0.0, 0.0));
    assert!((double.rho - 2.0 * paper.rho).abs() <= 1e-12 * paper.rho);
    assert!((double.depth - 2.0 * paper.depth).abs() <= 1e-12 * paper.depth);
    // The cross-entropy-only loss's analytic gradient against a central difference.
    let c = Case { cfg: base.cfg.with_regression_weight(0.0).unwrap(), ..base };
    let g = scale_loss_reference(&c.cfg, c.f_ref.view(), c.f_live.view(), c.depth.view(), &c.warp).unwrap();
    ref_gradient_matches_fd(&c, &g.d_ref, &[(0, 0, 0), (2, 3, 1), (5, 6, 2), (3, 1, 0)]);
}

/// The reference loss's gradient `d_ref` with respect to the reference features at `at`, against
/// a central difference of [`loss_of`].
pub(crate) fn ref_gradient_matches_fd(c: &Case, d_ref: &Array3<f64>, at: &[(usize, usize, usize)]) {
    let h = 1e-6;
    for &idx in at {
        let (mut plus, mut minus) = (c.f_ref.clone(), c.f_ref.clone());
        plus[idx] += h;
        minus[idx] -= h;
        let fd = (loss_of(c, &plus, &c.f_live) - loss_of(c, &minus, &c.f_live)) / (2.0 * h);
        let an = d_ref[idx];
        let err = (fd - an).abs() / (1e-4 + an.abs().max(fd.abs()));
        assert!(err < 1e-4, "{idx:?}: analytic {an}, fd {fd}");
    }
}

/// A warp that sees nothing of the reference: the live camera turned 180° about its y axis, so
/// every hypothesis lies behind it.
fn blind_warp(c: &Case) -> Warp {
    let cam = *c.warp.reference();
    let q = UnitQuaternion::from_euler_angles(0.0, std::f64::consts::PI, 0.0);
    Warp::new(&cam, &cam, &Pose::from_parts(Translation3::from(Vector3::zeros()), q))
}

/// SPEC.md §13.1d (`--multi-cost seen`): the rule's threshold; the flag parses and a bad value is
/// refused naming it; the reference's gradients against central differences for the reference
/// map and every live map, on a case where some true matches leave some frames (so the rule
/// uses pixels that §13.1b masks).
#[test]
fn seen_rule_reference_gradients_match_finite_differences() {
    assert_eq!((seen_threshold(0), seen_threshold(1), seen_threshold(4), seen_threshold(5)), (1, 1, 1, 2));
    assert_eq!(SEEN_MIN_EVIDENCE, densefeat::mapping::keyframe::DEFAULT_MIN_EVIDENCE, "the mapper's default");
    assert_eq!("seen".parse::<MultiCost>().unwrap(), MultiCost::Seen);
    assert_eq!("all".parse::<MultiCost>().unwrap(), MultiCost::All);
    let err = "some".parse::<MultiCost>().expect_err("refused").to_string();
    assert!(err.contains("--multi-cost") && err.contains("seen"), "{err}");
    let mut c = case(5, 5, 6, 3, 10);
    let extra = more_lives(5, &c, 2);
    let all = scale_loss_multi_reference(&c.cfg, c.f_ref.view(), &views(&c, &extra), c.depth.view()).unwrap();
    c.cfg.multi_cost = MultiCost::Seen;
    let out = assert_multi_gradients_match_fd(&c, &views(&c, &extra));
    assert!(out.sums.pixels > all.sums.pixels, "seen {} vs all {}", out.sums.pixels, all.sums.pixels);
    for (n, d) in out.d_lives.iter().enumerate() {
        assert!(d.iter().any(|v| *v != 0.0), "frame {n} has gradient");
    }
}

/// SPEC.md §13.1d: the fast loss under `seen` against the f64 reference (3 live frames, with and
/// without sampling) within §13.3's budgets, bit-identical for 1, 2, 3 and 8 threads; a live frame
/// that sees nothing changes nothing under `seen` (the same sums and reference gradient bits, a
/// zero gradient of its own), where under `all` it masks every pixel.
#[test]
fn seen_rule_fast_matches_reference_and_ignores_a_frame_that_sees_nothing() {
    for stride in [1, 2] {
        let mut c = case(9, 12, 16, 8, 32);
        c.cfg.sample_stride = stride;
        c.cfg.sample_seed = 4;
        c.cfg.multi_cost = MultiCost::Seen;
        let extra = more_lives(9, &c, 2);
        let lives = views(&c, &extra);
        let fr = c.f_ref.mapv(|v| v as f32);
        let fls: Vec<Array3<f32>> = lives.iter().map(|l| l.features.mapv(|v| v as f32)).collect();
        let v32: Vec<LiveView<'_, f32>> =
            fls.iter().zip(&lives).map(|(f, l)| LiveView { features: f.view(), warp: l.warp }).collect();
        let got = assert_fast_multi_matches_reference(&c, &lives, &fr, &v32);
        let all_cfg = LossConfig { multi_cost: MultiCost::All, ..c.cfg };
        let all = fast_multi(&all_cfg, &c, &fr, &v32, 1);
        assert!(got.sums.pixels > all.sums.pixels, "seen {} vs all {}", got.sums.pixels, all.sums.pixels);
        // A fourth frame that sees nothing.
        let blind = blind_warp(&c);
        let mut with_blind = v32.clone();
        with_blind.push(LiveView { features: fls[0].view(), warp: &blind });
        let b = fast_multi(&c.cfg, &c, &fr, &with_blind, 2);
        assert_eq!(b.sums, got.sums);
        assert!(bits_equal(&b.d_ref, &got.d_ref));
        assert!(b.d_lives[3].iter().all(|v| *v == 0.0));
        assert_eq!(fast_multi(&all_cfg, &c, &fr, &with_blind, 2).sums.pixels, 0);
    }
}
