//! The parity suite (issue 11, SPEC.md §15.3): every op of the [`Backend`] op list, on every
//! backend this build has, against the CPU reference backend (`CpuBackend::reference()`: f64
//! kernels), with the budget SPEC.md states for that op; then end to end on the shipped fixture.
//!
//! A backend that is not available here (for example `gpu` in a build without it) is reported as
//! `SKIPPED (<name>: <reason>)` on stderr; with `DENSEFEAT_REQUIRE_GPU=1` (CI) in a build with the
//! `gpu` feature, a missing GPU adapter fails instead. An op a device backend does not implement
//! (`Error::Unsupported`) is reported as `SKIPPED (<name>: <op>: <reason>)`, never passed silently.
//! A failure prints the first mismatching indices, values and the budget
//! (`densefeat::testing::within_budget`).

use std::sync::Arc;

use ndarray::{Array1, Array3, Array4};

use densefeat::backend::{self, Backend, CpuBackend, LayerOp, Tensor};
use densefeat::costvolume::{NO_TRUNCATION, UNSEEN_COST};
use densefeat::dtam::DtamProblem;
use densefeat::error::Error;
use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose};
use densefeat::mapping::keyframe::{reconstruct, KeyframeConfig, Regularizer};
use densefeat::mapping::FeatureKind;
use densefeat::ops::conv2d::{winograd_budget, winograd_magnitude_reference};
use densefeat::ops::deconv2d::deconv2d_winograd_magnitude_reference;
use densefeat::ops::LayerParams;
use densefeat::ops::{Activation, Conv2dGeometry, Deconv2dGeometry, NetworkConfig};
use densefeat::sequence::open;
use densefeat::testing::within_budget;

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
const EPS: f32 = f32::EPSILON;

/// splitmix64: deterministic test inputs without a dependency.
struct TestRng(u64);

impl TestRng {
    fn seed_from_u64(s: u64) -> Self {
        Self(s)
    }
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn random_range<T: From<f32> + Into<f64> + Copy + FromF64>(&mut self, r: std::ops::Range<T>) -> T {
        let (a, b) = (r.start.into(), r.end.into());
        T::from_f64(a + (b - a) * self.next())
    }
}

trait FromF64 {
    fn from_f64(v: f64) -> Self;
}
impl FromF64 for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
}
impl FromF64 for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
}

/// Every backend under test: each name of `backend::NAMES` this build and machine have.
fn backends() -> Vec<Arc<dyn Backend>> {
    let mut out = Vec::new();
    for name in backend::NAMES {
        match backend::by_name(name) {
            Ok(b) => {
                eprintln!("backend {name}: {}", b.device());
                out.push(b);
            }
            Err(e) => {
                if *name == "gpu"
                    && cfg!(feature = "gpu")
                    && std::env::var_os("DENSEFEAT_REQUIRE_GPU").is_some()
                {
                    panic!("DENSEFEAT_REQUIRE_GPU is set but the gpu backend is unavailable: {e}");
                }
                eprintln!("SKIPPED ({name}: {e})");
            }
        }
    }
    assert!(!out.is_empty(), "the CPU backend is always available");
    out
}

/// `Ok(v)` as `Some(v)`; an [`Error::Unsupported`] from a non-CPU backend as `None` with a loud
/// `SKIPPED` line; anything else panics.
fn supported<T>(b: &dyn Backend, op: &str, r: densefeat::error::Result<T>) -> Option<T> {
    match r {
        Ok(v) => Some(v),
        Err(Error::Unsupported { what, .. }) if b.name() != "cpu" => {
            eprintln!("SKIPPED ({}: {op}: {what})", b.name());
            None
        }
        Err(e) => panic!("{} {op}: {e}", b.name()),
    }
}

/// Prints the largest `|got - want|` and its share of the elementwise budget `rel · M`.
fn report_budget(label: &str, got: &Array3<f32>, want: &Array3<f32>, mag: &Array3<f32>, rel: f32) {
    let (mut worst, mut share) = (0.0f32, 0.0f32);
    for ((g, w), m) in got.iter().zip(want).zip(mag) {
        let d = (g - w).abs();
        worst = worst.max(d);
        if *m > 0.0 {
            share = share.max(d / (rel * m));
        }
    }
    eprintln!("{label}: max |diff| {worst:e}, at most {:.2} % of its elementwise budget", 100.0 * share);
}

fn reference() -> CpuBackend {
    CpuBackend::reference()
}

fn random_map(rng: &mut TestRng, (h, w, c): (usize, usize, usize)) -> Array3<f32> {
    Array3::from_shape_fn((h, w, c), |_| rng.random_range(-1.0f32..1.0))
}

fn random_layer(rng: &mut TestRng, shape: [usize; 4], bias: usize) -> LayerParams {
    LayerParams {
        weight: Array4::from_shape_fn(shape, |_| rng.random_range(-0.3f32..0.3)),
        bias: Array1::from_shape_fn(bias, |_| rng.random_range(-0.1f32..0.1)),
    }
}

fn abs_layer(l: &LayerParams) -> LayerParams {
    LayerParams { weight: l.weight.mapv(f32::abs), bias: l.bias.mapv(f32::abs) }
}

fn host(b: &dyn Backend, t: &Tensor) -> Array3<f32> {
    b.download(t).unwrap()
}

fn bits(a: &Array3<f32>) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

/// Run `op` on `backend` with host inputs uploaded, and download the result.
/// `be.conv3x3` of `l`, prepared by `be` for this call.
fn conv_on(be: &dyn Backend, x: &Tensor, l: &LayerParams, stride: usize, act: Activation) -> Tensor {
    let p = be.prepare_layer(Arc::new(l.clone()), LayerOp::Conv3x3).unwrap();
    be.conv3x3(x, &p, stride, act).unwrap()
}

/// `be.deconv5x5s2` of `l`, prepared by `be` for this call.
fn deconv_on(be: &dyn Backend, x: &Tensor, l: &LayerParams) -> Tensor {
    let p = be.prepare_layer(Arc::new(l.clone()), LayerOp::Deconv5x5s2).unwrap();
    be.deconv5x5s2(x, &p).unwrap()
}

fn run(
    backend: &dyn Backend,
    inputs: &[&Array3<f32>],
    op: impl Fn(&dyn Backend, &[Tensor]) -> Tensor,
) -> Array3<f32> {
    let t: Vec<Tensor> = inputs.iter().map(|x| backend.upload(x.view()).unwrap()).collect();
    host(backend, &op(backend, &t))
}

#[test]
fn conv3x3_matches_reference_within_its_budget() {
    let mut rng = TestRng::seed_from_u64(11);
    for b in backends() {
        for &(h, w, c_in, c_out, stride, act) in &[
            (9, 13, 3, 32, 1, Activation::Relu),
            (10, 7, 35, 32, 2, Activation::Relu),
            (6, 6, 32, 32, 1, Activation::None),
            (5, 11, 8, 5, 2, Activation::None),
        ] {
            let x = random_map(&mut rng, (h, w, c_in));
            let l = random_layer(&mut rng, [c_out, c_in, 3, 3], c_out);
            let got = run(b.as_ref(), &[&x], |be, t| conv_on(be, &t[0], &l, stride, act));
            let want = run(&reference(), &[&x], |be, t| conv_on(be, &t[0], &l, stride, act));
            let mut mag = run(&reference(), &[&x.mapv(f32::abs)], |be, t| {
                conv_on(be, &t[0], &abs_layer(&l), stride, Activation::None)
            });
            let k = 9 * c_in + 1;
            let mut rel = 2.0 * k as f32 * EPS;
            // The CPU backend runs Winograd on wide stride-1 layers: its own budget against its own
            // magnitude (SPEC.md §7.11).
            let g = Conv2dGeometry::new(h, w, c_in, c_out, stride).unwrap();
            let tile = CpuBackend::default().conv_impl_for(&g).winograd_tile();
            if let (Some(tile), "cpu") = (tile, b.name()) {
                let f = |v: &f32| f64::from(*v);
                let (al, ax) = (abs_layer(&l), x.mapv(f32::abs));
                let (aw, ab) = (al.weight.map(f), al.bias.map(f));
                let mw =
                    winograd_magnitude_reference(tile, &g, ax.map(f).view(), aw.view(), ab.view()).unwrap();
                mag = mw.mapv(|v| v as f32);
                rel = winograd_budget(tile, c_in);
            }
            let label = format!("{} conv3x3 {h}x{w}x{c_in} -> {c_out} s{stride}", b.name());
            report_budget(&label, &got, &want, &mag, rel);
            if let Err(e) = within_budget(got.view(), want.view(), mag.view(), rel) {
                panic!("{} conv3x3 {h}x{w}x{c_in} -> {c_out} s{stride}: {e}", b.name());
            }
        }
    }
}

#[test]
fn deconv5x5s2_matches_reference_within_its_budget() {
    let mut rng = TestRng::seed_from_u64(12);
    for b in backends() {
        for &(h, w, c_in, c_out) in &[(4, 5, 32, 32), (7, 3, 5, 9), (1, 1, 32, 32)] {
            let x = random_map(&mut rng, (h, w, c_in));
            let l = random_layer(&mut rng, [c_in, c_out, 5, 5], c_out);
            let got = run(b.as_ref(), &[&x], |be, t| deconv_on(be, &t[0], &l));
            let want = run(&reference(), &[&x], |be, t| deconv_on(be, &t[0], &l));
            let mut mag =
                run(&reference(), &[&x.mapv(f32::abs)], |be, t| deconv_on(be, &t[0], &abs_layer(&l)));
            // §7.5: at most 9 taps per output pixel and input channel, plus the bias.
            let k = 9 * c_in + 1;
            let mut rel = 2.0 * k as f32 * EPS;
            // The CPU backend runs Winograd on wide transposed convolutions: its own budget against
            // its own magnitude (SPEC.md §7.3, §7.11).
            let g = Deconv2dGeometry::new(h, w, c_in, c_out).unwrap();
            let tile = CpuBackend::default().deconv_impl_for(&g).winograd_tile();
            if let (Some(tile), "cpu") = (tile, b.name()) {
                let f = |v: &f32| f64::from(*v);
                let (al, ax) = (abs_layer(&l), x.mapv(f32::abs));
                let (aw, ab) = (al.weight.map(f), al.bias.map(f));
                let mw =
                    deconv2d_winograd_magnitude_reference(tile, &g, ax.map(f).view(), aw.view(), ab.view())
                        .unwrap();
                mag = mw.mapv(|v| v as f32);
                rel = winograd_budget(tile, c_in);
            }
            let label = format!("{} deconv5x5s2 {h}x{w}x{c_in} -> {c_out}", b.name());
            report_budget(&label, &got, &want, &mag, rel);
            if let Err(e) = within_budget(got.view(), want.view(), mag.view(), rel) {
                panic!("{} deconv5x5s2 {h}x{w}x{c_in} -> {c_out}: {e}", b.name());
            }
        }
    }
}

#[test]
fn exact_ops_are_bit_identical_to_reference() {
    let mut rng = TestRng::seed_from_u64(13);
    let a = random_map(&mut rng, (7, 9, 32));
    let c = random_map(&mut rng, (7, 9, 32));
    let img = random_map(&mut rng, (7, 9, 3)).mapv(|v| 128.0 + 127.0 * v);
    for b in backends() {
        let name = b.name();
        let cases: [(&str, Array3<f32>, Array3<f32>); 4] = [
            (
                "downsample2x",
                run(b.as_ref(), &[&img], |be, t| be.downsample2x(&t[0]).unwrap()),
                run(&reference(), &[&img], |be, t| be.downsample2x(&t[0]).unwrap()),
            ),
            (
                "concat",
                run(b.as_ref(), &[&a, &img], |be, t| be.concat(&t[0], &t[1]).unwrap()),
                run(&reference(), &[&a, &img], |be, t| be.concat(&t[0], &t[1]).unwrap()),
            ),
            (
                "add",
                run(b.as_ref(), &[&a, &c], |be, t| be.add(&t[0], &t[1]).unwrap()),
                run(&reference(), &[&a, &c], |be, t| be.add(&t[0], &t[1]).unwrap()),
            ),
            (
                "crop",
                run(b.as_ref(), &[&a], |be, t| be.crop(t[0].clone(), 5, 4).unwrap()),
                run(&reference(), &[&a], |be, t| be.crop(t[0].clone(), 5, 4).unwrap()),
            ),
        ];
        for (op, got, want) in cases {
            assert_eq!(got.dim(), want.dim(), "{name} {op}: shape");
            assert_eq!(bits(&got), bits(&want), "{name} {op}: not bit-identical to the reference");
        }
        let config = NetworkConfig::default();
        let got = b.image_pyramid(&config, img.view(), 2).unwrap();
        let want = reference().image_pyramid(&config, img.view(), 2).unwrap();
        for (l, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(bits(&host(b.as_ref(), g)), bits(&host(&reference(), w)), "{name} pyramid level {l}");
        }
        assert!(b.crop(b.upload(a.view()).unwrap(), 8, 4).is_err(), "{name}: crop larger than the map");
    }
}

/// The camera of a live map: the case's when the sizes match, else one of the map's own size with
/// other intrinsics (SPEC.md §9.1: each live frame in its own camera).
fn live_camera(case: &VolumeCase, x: &Array3<f32>) -> PinholeCamera {
    let (h, w, _) = x.dim();
    if (h, w) == (case.camera.height, case.camera.width) {
        return case.camera;
    }
    PinholeCamera::new(14.0, 13.0, (w as f64 - 1.0) / 2.0 + 0.3, (h as f64 - 1.0) / 2.0 - 0.2, w, h).unwrap()
}

/// A small random scene for the volume: reference and live features, camera, bins, poses.
#[derive(Clone)]
struct VolumeCase {
    reference: Array3<f32>,
    live: Vec<(Array3<f32>, Pose)>,
    camera: PinholeCamera,
    bins: InverseDepthBins,
    /// Per-frame truncation `τ` (SPEC.md §9.13).
    truncation: f32,
}

/// `h x w` maps with `c` channels, `k` hypotheses over `[0.1, 2]` 1/m, three live frames up to
/// 0.3 m and 0.05 rad away (some hypotheses fall behind a live camera or outside its image).
fn volume_case_sized(seed: u64, (h, w): (usize, usize), c: usize, k: usize) -> VolumeCase {
    let mut rng = TestRng::seed_from_u64(seed);
    let camera =
        PinholeCamera::new(12.0, 12.0, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h).unwrap();
    let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
    // The third live frame has a camera of its own, 2 rows and 3 columns larger (`live_camera`).
    let live = (0..3)
        .map(|i| {
            let (h, w) = if i == 2 { (h + 2, w + 3) } else { (h, w) };
            let t = nalgebra::Vector3::new(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.3..0.3),
            );
            let r = nalgebra::UnitQuaternion::from_euler_angles(
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
            );
            (random_map(&mut rng, (h, w, c)), Pose::from_parts(nalgebra::Translation3::from(t), r))
        })
        .collect();
    VolumeCase { reference: random_map(&mut rng, (h, w, c)), live, camera, bins, truncation: NO_TRUNCATION }
}

/// The case's volume on `b`, every live frame added, not yet finished.
fn try_builder(
    b: &dyn Backend,
    case: &VolumeCase,
    abs: bool,
) -> densefeat::error::Result<Box<dyn densefeat::backend::VolumeBuilder>> {
    let f = |x: &Array3<f32>, sign: f32| if abs { x.mapv(|v| sign * v.abs()) } else { x.clone() };
    let r = b.upload_owned(f(&case.reference, 1.0))?;
    // The magnitude run (§9.6's M̄) bounds the untruncated terms; `min(·, τ)` is 1-Lipschitz, so the
    // same budget holds for the truncated costs (§9.13).
    let tau = if abs { NO_TRUNCATION } else { case.truncation };
    let mut v = b.cost_volume(&r, case.camera, case.bins, tau)?;
    for (x, pose) in &case.live {
        v.add_frame_seen_by(&b.upload_owned(f(x, -1.0))?, &live_camera(case, x), pose)?;
    }
    assert_eq!(v.frames(), case.live.len());
    Ok(v)
}

fn try_build(
    b: &dyn Backend,
    case: &VolumeCase,
    abs: bool,
) -> densefeat::error::Result<densefeat::costvolume::CostVolume> {
    try_builder(b, case, abs)?.finish()
}

fn build(b: &dyn Backend, case: &VolumeCase, abs: bool) -> densefeat::costvolume::CostVolume {
    try_build(b, case, abs).unwrap()
}

/// Counts equal cell for cell; a failure names the first differing cells.
#[track_caller]
fn assert_same_counts(label: &str, got: &Array3<u16>, want: &Array3<u16>) {
    assert_eq!(got.dim(), want.dim(), "{label}: count shapes");
    let diff: Vec<_> = got.indexed_iter().filter(|(i, g)| **g != want[*i]).take(5).collect();
    let total = got.iter().zip(want).filter(|(g, w)| g != w).count();
    assert!(
        diff.is_empty(),
        "{label}: {total} counts differ (budget: exact); first (y, x, k): got, want: {:?}",
        diff.iter().map(|(i, g)| (*i, **g, want[*i])).collect::<Vec<_>>()
    );
}

/// Costs within `rel · M̄` (unseen cells compared as 0; the counts already matched); prints the
/// largest difference and its share of the budget.
#[track_caller]
fn assert_costs_within(label: &str, got: &Array3<f32>, want: &Array3<f32>, mag: &Array3<f32>, rel: f32) {
    let seen = |a: &Array3<f32>| a.mapv(|v| if v == UNSEEN_COST { 0.0 } else { v });
    let (g, w, m) = (seen(got), seen(want), seen(mag));
    report_budget(label, &g, &w, &m, rel);
    if let Err(e) = within_budget(g.view(), w.view(), m.view(), rel) {
        panic!("{label}: {e}");
    }
}

/// The same bits, with the first differing elements named.
#[track_caller]
fn assert_same_bits<D: ndarray::Dimension>(
    label: &str,
    got: &ndarray::Array<f32, D>,
    want: &ndarray::Array<f32, D>,
) {
    assert_eq!(got.shape(), want.shape(), "{label}: shapes");
    let diff: Vec<_> = got
        .indexed_iter()
        .zip(want.iter())
        .filter(|((_, g), w)| g.to_bits() != w.to_bits())
        .take(5)
        .map(|((i, g), w)| (format!("{i:?}"), *g, *w))
        .collect();
    assert!(
        diff.is_empty(),
        "{label}: not bit-identical (budget: exact); first (index, got, want): {diff:?}"
    );
}

#[test]
fn cost_volume_counts_exact_costs_within_the_9_6_budget_and_wta_exact() {
    // (seed, (H, W), C, K, τ): 1-pixel-wide and -high maps alias the bilinear corners; K = 2 has no
    // inner hypothesis for the parabola; the τ cases truncate about half the per-frame costs (the
    // features are uniform in [-1, 1], so a channel's |difference| averages about 2/3).
    let cases = [
        (21, (11, 14), 3, 9, NO_TRUNCATION),
        (22, (11, 14), 32, 9, NO_TRUNCATION),
        (23, (11, 14), 5, 9, NO_TRUNCATION),
        (24, (1, 9), 3, 5, NO_TRUNCATION),
        (25, (8, 1), 4, 2, NO_TRUNCATION),
        (26, (7, 10), 35, 17, NO_TRUNCATION),
        (28, (11, 14), 3, 9, 2.0),
        (29, (11, 14), 32, 9, 20.0),
    ];
    for b in backends() {
        for &(seed, hw, c, k, tau) in &cases {
            let case = VolumeCase { truncation: tau, ..volume_case_sized(seed, hw, c, k) };
            let tau_text = if tau == NO_TRUNCATION { "none".to_string() } else { tau.to_string() };
            let label = format!("{} volume {}x{}, C = {c}, K = {k}, τ = {tau_text}", b.name(), hw.0, hw.1);
            let want = build(&reference(), &case, false);
            // WTA on one cost array is exact on every backend (argmin and parabola in f64).
            let wts = want.costs();
            if let Some(wg) =
                supported(b.as_ref(), "winner_take_all", b.winner_take_all(wts.view(), &case.bins))
            {
                let wr = reference().winner_take_all(wts.view(), &case.bins).unwrap();
                assert_eq!(wg.valid, wr.valid, "{label}: WTA validity");
                assert_same_bits(
                    &format!("{label}: WTA inverse depth"),
                    &wg.inverse_depth,
                    &wr.inverse_depth,
                );
                assert_same_bits(&format!("{label}: WTA depth"), &wg.depth, &wr.depth);
                assert_same_bits(&format!("{label}: WTA bin"), &wg.bin, &wr.bin);
            }
            let Some(got) = supported(b.as_ref(), "cost_volume", try_build(b.as_ref(), &case, false)) else {
                continue;
            };
            let mag = build(&reference(), &case, true);
            assert_same_counts(&label, &got.counts(), &want.counts());
            let n = case.live.len();
            let rel = (c + n + 8) as f32 * EPS; // (C + N + 8) ε M̄ (SPEC.md §9.6)
            assert_costs_within(&label, &got.costs(), &want.costs(), &mag.costs(), rel);
        }
    }
}

/// WTA on hand-made cost arrays: exact ties (the first minimum wins), unseen cells next to the
/// minimum (no parabola), a pixel with nothing seen (invalid), minima at both ends, a flat curve
/// (no positive curvature) and `ρ_min = 0` (depth 0 at infinity).
#[test]
fn winner_take_all_is_exact_on_ties_unseen_cells_and_ends() {
    const U: f32 = UNSEEN_COST;
    let curves: [[f32; 6]; 8] = [
        [5.0, 3.0, 1.0, 1.0, 3.0, 5.0],
        [U, U, U, U, U, U],
        [4.0, U, 1.0, 2.0, 6.0, 7.0],
        [0.5, 1.0, 2.0, 3.0, 4.0, 5.0],
        [5.0, 4.0, 3.0, 2.0, 1.5, 0.25],
        [2.0, 2.0, 2.0, 2.0, 2.0, 2.0],
        [3.0, 1.0, 2.0, 9.0, U, 0.0],
        [1e-7, 2e-7, 1.5e-7, 3e-7, 1e-6, 8e-8],
    ];
    let costs = Array3::from_shape_fn((2, 4, 6), |(y, x, k)| curves[y * 4 + x][k]);
    for bins in [InverseDepthBins::new(0.0, 2.5, 6).unwrap(), InverseDepthBins::new(0.3, 1.7, 6).unwrap()] {
        let want = reference().winner_take_all(costs.view(), &bins).unwrap();
        for b in backends() {
            let Some(got) = supported(b.as_ref(), "winner_take_all", b.winner_take_all(costs.view(), &bins))
            else {
                continue;
            };
            let label = format!("{} WTA ρ_min = {}", b.name(), bins.rho_min);
            assert_eq!(got.valid, want.valid, "{label}: validity");
            assert_same_bits(&format!("{label}: inverse depth"), &got.inverse_depth, &want.inverse_depth);
            assert_same_bits(&format!("{label}: depth"), &got.depth, &want.depth);
            assert_same_bits(&format!("{label}: bin"), &got.bin, &want.bin);
        }
    }
}

/// A snapshot taken while the volume fills equals the reference after as many frames, `finish`
/// equals the last snapshot, and two runs give the same bits (fixed order, no atomics).
#[test]
fn volume_snapshots_match_and_runs_repeat_bit_for_bit() {
    let case = volume_case_sized(27, (9, 12), 16, 7);
    for b in backends() {
        let run = || -> densefeat::error::Result<(Vec<densefeat::costvolume::CostVolume>, densefeat::costvolume::CostVolume)> {
            let mut v = b.cost_volume(&b.upload(case.reference.view())?, case.camera, case.bins, NO_TRUNCATION)?;
            let mut snaps = Vec::new();
            for (x, pose) in &case.live {
                v.add_frame_seen_by(&b.upload(x.view())?, &live_camera(&case, x), pose)?;
                snaps.push(v.snapshot()?);
            }
            Ok((snaps, v.finish()?))
        };
        let Some((snaps, last)) = supported(b.as_ref(), "cost_volume", run()) else { continue };
        let (snaps2, last2) = run().unwrap();
        let label = b.name();
        assert_same_bits(&format!("{label}: two runs"), &last.costs(), &last2.costs());
        assert_same_bits(&format!("{label}: finish vs last snapshot"), &last.costs(), &snaps[2].costs());
        assert_eq!(last.counts(), last2.counts(), "{label}: two runs' counts");
        for (n, (s, s2)) in snaps.iter().zip(&snaps2).enumerate() {
            assert_eq!(s.frames(), n + 1, "{label}: snapshot frames");
            assert_same_bits(&format!("{label}: snapshot {n} twice"), &s.costs(), &s2.costs());
            let partial = VolumeCase { live: case.live[..=n].to_vec(), ..case.clone() };
            let want = build(&reference(), &partial, false);
            assert_same_counts(&format!("{label}: snapshot {n}"), &s.counts(), &want.counts());
            let mag = build(&reference(), &partial, true);
            let rel = (16 + n + 1 + 8) as f32 * EPS;
            assert_costs_within(
                &format!("{label} snapshot {n}"),
                &s.costs(),
                &want.costs(),
                &mag.costs(),
                rel,
            );
        }
    }
}

/// A DTAM test problem: the reference volume of `volume_case`, a patterned grey image, WTA start.
fn dtam_case(seed: u64) -> (Array3<f32>, InverseDepthBins, ndarray::Array2<f32>, ndarray::Array2<f32>) {
    let case = volume_case_sized(seed, (13, 17), 3, 16);
    let costs = build(&reference(), &case, false).costs();
    let (h, w, _) = costs.dim();
    let grey = ndarray::Array2::from_shape_fn((h, w), |(y, x)| ((y * 13 + x * 7) % 255) as f32);
    let init = reference().winner_take_all(costs.view(), &case.bins).unwrap().inverse_depth;
    (costs, case.bins, grey, init)
}

/// One DTAM iteration (SPEC.md §15.3): `d` within `4 ε max |d|` elementwise, `a` the same except at
/// most 1 % of pixels (a near-tie in the a-search may resolve the other way), energy and gap within
/// a relative `1e-6`. The CPU backend is bit-identical.
#[test]
fn dtam_one_iteration_matches_within_budget() {
    let (costs, bins, grey, init) = dtam_case(31);
    let params = densefeat::dtam::DtamParams {
        iterations: 1,
        max_iterations: 1,
        steps_per_search: 2,
        ..Default::default()
    };
    let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
    let (want, wr) = reference().dtam_solve(&problem).unwrap();
    for b in backends() {
        let Some((got, report)) = supported(b.as_ref(), "dtam_solve", b.dtam_solve(&problem)) else {
            continue;
        };
        let label = format!("{} DTAM one iteration", b.name());
        assert_eq!(report.iterations, 1, "{label}: iterations");
        if b.name() == "cpu" {
            assert_same_bits(&label, &got.inverse_depth, &want.inverse_depth);
            continue;
        }
        let scale = want.inverse_depth.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let d_budget = 4.0 * EPS * scale;
        let worst = max_abs_diff(&got.inverse_depth, &want.inverse_depth);
        let a_off = count_beyond(&got.auxiliary, &want.auxiliary, d_budget);
        let e_rel = rel_diff(report.energy[0], wr.energy[0]);
        let g_rel = rel_diff(report.gap[0], wr.gap[0]);
        eprintln!(
            "{label}: max |Δd| {worst:e} (budget {d_budget:e}), a differs in {a_off} of {} pixels, \
             energy rel diff {e_rel:e}, gap rel diff {g_rel:e} (budget 1e-6); d bit-identical: {}",
            init.len(),
            bits2(&got.inverse_depth) == bits2(&want.inverse_depth)
        );
        assert!(
            worst <= d_budget,
            "{label}: max |Δd| {worst:e} > {d_budget:e}; {}",
            first_diffs(&got.inverse_depth, &want.inverse_depth, d_budget)
        );
        assert!(a_off * 100 <= init.len(), "{label}: a differs in {a_off} pixels (budget 1 %)");
        assert!(
            e_rel <= 1e-6 && g_rel <= 1e-6,
            "{label}: energy / gap rel diff {e_rel:e} / {g_rel:e} > 1e-6"
        );
    }
}

/// A whole DTAM solve on one cost array (SPEC.md §15.3): at most 1 % of pixels' `d` more than one
/// bin step from the reference, and the energies of the iterations both ran within a relative 1e-3
/// (the stopping rule's own tolerance). The CPU backend is bit-identical.
#[test]
fn dtam_solve_matches_within_budget_on_one_cost_array() {
    let (costs, bins, grey, init) = dtam_case(32);
    // The mapping default's primal-dual steps per a-search (SPEC §10.1), so the schedule the product
    // runs is the one compared.
    let params = densefeat::dtam::DtamParams {
        iterations: 20,
        max_iterations: 40,
        steps_per_search: densefeat::dtam::MAPPING_DEFAULTS.steps_per_search,
        ..Default::default()
    };
    let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
    let (want, wr) = reference().dtam_solve(&problem).unwrap();
    let step = bins.step() as f32;
    for b in backends() {
        let Some((got, report)) = supported(b.as_ref(), "dtam_solve", b.dtam_solve(&problem)) else {
            continue;
        };
        let label = format!("{} DTAM solve", b.name());
        assert!(report.iterations >= 20, "{label}: {} iterations", report.iterations);
        let (again, report2) = b.dtam_solve(&problem).unwrap();
        assert_same_bits(&format!("{label}: two runs"), &again.inverse_depth, &got.inverse_depth);
        assert_eq!(report2.energy, report.energy, "{label}: two runs' energies");
        if b.name() == "cpu" {
            assert_same_bits(&label, &got.inverse_depth, &want.inverse_depth);
            continue;
        }
        let far = count_beyond(&got.inverse_depth, &want.inverse_depth, step);
        let e_rel = report.energy.iter().zip(&wr.energy).map(|(g, w)| rel_diff(*g, *w)).fold(0.0, f64::max);
        eprintln!(
            "{label}: {} iterations (reference {}), {far} of {} pixels more than a bin off, max |Δd| {:e}, \
             max energy rel diff {e_rel:e} (budget 1e-3); d bit-identical: {}, energies bit-identical: {}",
            report.iterations,
            wr.iterations,
            init.len(),
            max_abs_diff(&got.inverse_depth, &want.inverse_depth),
            bits2(&got.inverse_depth) == bits2(&want.inverse_depth),
            report.energy == wr.energy
        );
        assert!(
            far * 100 <= init.len(),
            "{label}: {far} pixels more than a bin off (budget 1 %); {}",
            first_diffs(&got.inverse_depth, &want.inverse_depth, step)
        );
        assert!(e_rel <= 1e-3, "{label}: energy rel diff {e_rel:e} > 1e-3");
        assert!(report.converged == wr.converged || report.iterations == params.max_iterations);
    }
}

/// The resident volume (SPEC.md §15.6) against the host path on the same backend's volume: the
/// volume built twice (its runs repeat bit for bit), one copy downloaded and filtered, scored,
/// WTA'd, tapered and solved on the host arrays with the backend's WTA and DTAM, the other kept
/// where the backend built it. Confidence, cost scale, WTA, the tapered costs and DTAM's result
/// and energies are bit-identical (budget: exact), for evidence fractions that filter nothing,
/// some and most cells, tapers off and wider than the map, one hypothesis per pixel pair (K = 2)
/// and truncated costs.
#[test]
fn resident_volume_matches_the_host_path_bit_for_bit() {
    use densefeat::costvolume::{confidence_and_scale, filter_evidence, taper_border};
    // (seed, (H, W), C, K, τ, evidence fraction, taper radius)
    let cases = [
        (41, (11, 14), 3, 9, NO_TRUNCATION, 0.0, 0.0),
        (42, (11, 14), 5, 9, NO_TRUNCATION, 0.25, 3.5),
        (43, (9, 12), 4, 2, NO_TRUNCATION, 0.7, 40.0),
        (44, (13, 17), 3, 16, 2.0, 1.0, 2.0),
    ];
    let params = densefeat::dtam::DtamParams {
        iterations: 8,
        max_iterations: 16,
        steps_per_search: densefeat::dtam::MAPPING_DEFAULTS.steps_per_search,
        ..Default::default()
    };
    for b in backends() {
        for &(seed, hw, c, k, tau, fraction, radius) in &cases {
            let case = VolumeCase { truncation: tau, ..volume_case_sized(seed, hw, c, k) };
            let label = format!(
                "{} resident volume {}x{}, K = {k}, evidence {fraction}, taper {radius}",
                b.name(),
                hw.0,
                hw.1
            );
            let Some(host_volume) = supported(b.as_ref(), "cost_volume", try_build(b.as_ref(), &case, false))
            else {
                continue;
            };
            let frames = host_volume.frames();
            let (mut costs, counts) = host_volume.into_costs();
            filter_evidence(&mut costs, counts.view(), fraction);
            let (conf, scale) = confidence_and_scale(costs.view(), counts.view(), frames);
            let Some(wta) =
                supported(b.as_ref(), "winner_take_all", b.winner_take_all(costs.view(), &case.bins))
            else {
                continue;
            };
            taper_border(&mut costs, radius);
            let (h, w, _) = costs.dim();
            let grey = ndarray::Array2::from_shape_fn((h, w), |(y, x)| ((y * 13 + x * 7) % 255) as f32);
            let problem =
                DtamProblem::new(costs.view(), &case.bins, grey.view(), wta.inverse_depth.view(), &params);
            let Some((want, wr)) = supported(b.as_ref(), "dtam_solve", b.dtam_solve(&problem)) else {
                continue;
            };

            let mut volume = try_builder(b.as_ref(), &case, false).unwrap().finish_resident().unwrap();
            assert_eq!((volume.dim(), volume.frames()), (costs.dim(), frames), "{label}: shape, frames");
            volume.filter_evidence(fraction).unwrap();
            let (got_conf, got_scale) = volume.confidence_and_scale().unwrap();
            assert_same_bits(&format!("{label}: confidence"), &got_conf, &conf);
            assert_eq!(got_scale.to_bits(), scale.to_bits(), "{label}: cost scale {got_scale} vs {scale}");
            let got_wta = volume.winner_take_all(&case.bins).unwrap();
            assert_eq!(got_wta.valid, wta.valid, "{label}: WTA validity");
            assert_same_bits(
                &format!("{label}: WTA inverse depth"),
                &got_wta.inverse_depth,
                &wta.inverse_depth,
            );
            assert_same_bits(&format!("{label}: WTA bin"), &got_wta.bin, &wta.bin);
            volume.taper_border(radius).unwrap();
            assert_same_bits(&format!("{label}: tapered costs"), &volume.costs().unwrap(), &costs);
            let resident = DtamProblem::resident(&case.bins, grey.view(), wta.inverse_depth.view(), &params);
            let (got, report) = volume.dtam_solve(&resident).unwrap();
            assert_same_bits(&format!("{label}: DTAM d"), &got.inverse_depth, &want.inverse_depth);
            assert_same_bits(&format!("{label}: DTAM a"), &got.auxiliary, &want.auxiliary);
            assert_eq!(report.energy, wr.energy, "{label}: DTAM energies");
            eprintln!("{label}: bit-identical (scale {scale}, {} DTAM iterations)", report.iterations);
        }
    }
}

/// The resident volume checks its inputs before touching the device: an evidence fraction outside
/// `[0, 1]`, a non-finite taper, hypotheses of another count and a DTAM problem of another size are
/// errors naming what is wrong.
#[test]
fn resident_volume_refuses_bad_inputs() {
    let case = volume_case_sized(45, (6, 7), 3, 5);
    for b in backends() {
        let r = b.upload_owned(case.reference.clone()).unwrap();
        let Some(mut builder) =
            supported(b.as_ref(), "cost_volume", b.cost_volume(&r, case.camera, case.bins, NO_TRUNCATION))
        else {
            continue;
        };
        let (x, pose) = &case.live[0];
        builder.add_frame_seen_by(&b.upload_owned(x.clone()).unwrap(), &live_camera(&case, x), pose).unwrap();
        let mut v = builder.finish_resident().unwrap();
        let name = b.name();
        let err = |e: Error| e.to_string();
        assert!(err(v.filter_evidence(1.5).unwrap_err()).contains("min-evidence"), "{name}");
        assert!(err(v.taper_border(f64::NAN).unwrap_err()).contains("border-taper"), "{name}");
        let other = InverseDepthBins::new(0.1, 2.0, 4).unwrap();
        assert!(err(v.winner_take_all(&other).unwrap_err()).contains("hypotheses"), "{name}");
        let grey = ndarray::Array2::<f32>::zeros((6, 8));
        let init = ndarray::Array2::<f32>::zeros((6, 8));
        let params = densefeat::dtam::DtamParams::default();
        let p = DtamProblem::resident(&case.bins, grey.view(), init.view(), &params);
        assert!(err(v.dtam_solve(&p).unwrap_err()).contains("sizes must agree"), "{name}");
    }
}

/// A device backend refuses host tensors in its volume (no silent copy, no CPU fallback), and
/// non-finite costs in WTA and DTAM (WGSL does not define comparisons with NaN or infinity), with
/// [`Error::Unsupported`]; the CPU backend takes them.
#[test]
fn device_mapping_ops_refuse_host_tensors_and_non_finite_costs() {
    let case = volume_case_sized(41, (5, 6), 3, 4);
    let mut costs = Array3::from_elem((5, 6, 4), 1.0f32);
    costs[[2, 3, 1]] = f32::NAN;
    let init = ndarray::Array2::from_elem((5, 6), 1.0f32);
    let grey = ndarray::Array2::from_elem((5, 6), 100.0f32);
    let params = densefeat::dtam::DtamParams { iterations: 2, max_iterations: 2, ..Default::default() };
    for b in backends() {
        let host = Tensor::host(case.reference.clone());
        let wta = b.winner_take_all(costs.view(), &case.bins);
        let dtam =
            b.dtam_solve(&DtamProblem::new(costs.view(), &case.bins, grey.view(), init.view(), &params));
        if b.name() == "cpu" {
            assert!(b.cost_volume(&host, case.camera, case.bins, NO_TRUNCATION).is_ok());
            assert!(wta.is_ok() && dtam.is_ok(), "cpu takes NaN costs");
            continue;
        }
        let unsupported = |r: densefeat::error::Result<()>, what: &str| match r {
            Err(Error::Unsupported { what: w, .. }) => eprintln!("{} {what}: refused ({w})", b.name()),
            other => panic!("{} {what}: expected Unsupported, got {other:?}", b.name()),
        };
        unsupported(
            b.cost_volume(&host, case.camera, case.bins, NO_TRUNCATION).map(|_| ()),
            "host reference",
        );
        if let Ok(mut v) =
            b.cost_volume(&b.upload(case.reference.view()).unwrap(), case.camera, case.bins, NO_TRUNCATION)
        {
            unsupported(
                v.add_frame(&Tensor::host(case.live[0].0.clone()), &case.live[0].1),
                "host live frame",
            );
            assert_eq!(v.frames(), 0);
        }
        unsupported(wta.map(|_| ()), "NaN cost in WTA");
        unsupported(dtam.map(|_| ()), "NaN cost in DTAM");
        // The surface-normal prior is not ported (SPEC.md §10.2): a problem with a slope field is
        // refused, even with finite costs.
        let finite = Array3::from_elem((5, 6, 4), 1.0f32);
        let slope = densefeat::dtam::SlopeField::zeros(5, 6);
        let problem =
            DtamProblem::new(finite.view(), &case.bins, grey.view(), init.view(), &params).with_slope(&slope);
        unsupported(b.dtam_solve(&problem).map(|_| ()), "the normal prior in DTAM");
    }
}

fn bits2(a: &ndarray::Array2<f32>) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

fn max_abs_diff(a: &ndarray::Array2<f32>, b: &ndarray::Array2<f32>) -> f32 {
    a.iter().zip(b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
}

fn count_beyond(a: &ndarray::Array2<f32>, b: &ndarray::Array2<f32>, tol: f32) -> usize {
    a.iter().zip(b).filter(|(x, y)| beyond(**x - **y, tol)).count()
}

/// `|diff| > tol`, or NaN.
fn beyond(diff: f32, tol: f32) -> bool {
    diff.abs() > tol || diff.is_nan()
}

fn rel_diff(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
}

/// The first five elements further apart than `tol`, for failure messages.
fn first_diffs(got: &ndarray::Array2<f32>, want: &ndarray::Array2<f32>, tol: f32) -> String {
    let v: Vec<_> = got
        .indexed_iter()
        .filter(|(i, g)| beyond(**g - want[*i], tol))
        .take(5)
        .map(|(i, g)| format!("{i:?}: got {g:e}, want {:e}", want[i]))
        .collect();
    format!("first beyond {tol:e}: [{}]", v.join(", "))
}

/// Every device op twice on the same inputs: the same bits (fixed summation order, no atomics).
#[test]
fn every_network_op_is_deterministic_run_after_run() {
    let mut rng = TestRng::seed_from_u64(14);
    let x = random_map(&mut rng, (9, 11, 35));
    let y = random_map(&mut rng, (9, 11, 35));
    let conv = random_layer(&mut rng, [32, 35, 3, 3], 32);
    let deconv = random_layer(&mut rng, [35, 16, 5, 5], 16);
    for b in backends() {
        type Op<'a> = Box<dyn Fn(&dyn Backend, &[Tensor]) -> Tensor + 'a>;
        let ops: Vec<(&str, Op)> = vec![
            (
                "conv3x3 s1",
                Box::new(|be: &dyn Backend, t: &[Tensor]| conv_on(be, &t[0], &conv, 1, Activation::Relu)),
            ),
            (
                "conv3x3 s2",
                Box::new(|be: &dyn Backend, t: &[Tensor]| conv_on(be, &t[0], &conv, 2, Activation::None)),
            ),
            ("deconv5x5s2", Box::new(|be: &dyn Backend, t: &[Tensor]| deconv_on(be, &t[0], &deconv))),
            ("downsample2x", Box::new(|be: &dyn Backend, t: &[Tensor]| be.downsample2x(&t[0]).unwrap())),
            ("concat", Box::new(|be: &dyn Backend, t: &[Tensor]| be.concat(&t[0], &t[1]).unwrap())),
            ("add", Box::new(|be: &dyn Backend, t: &[Tensor]| be.add(&t[0], &t[1]).unwrap())),
            ("crop", Box::new(|be: &dyn Backend, t: &[Tensor]| be.crop(t[0].clone(), 4, 7).unwrap())),
        ];
        for (op, f) in &ops {
            let first = run(b.as_ref(), &[&x, &y], f);
            let second = run(b.as_ref(), &[&x, &y], f);
            assert_eq!(bits(&first), bits(&second), "{} {op}: two runs differ", b.name());
        }
    }
}

/// End to end on the fixture: a whole RGB cost volume (keyframe 10, six live frames, K = 32 over
/// 0.4..10 m) on the top-left 96x72 window of the 320x240 frames (the same intrinsics: a top-left
/// window keeps `cx, cy`), counts exact and costs within SPEC.md §9.6's budget, then WTA exact.
#[test]
fn fixture_cost_volume_and_wta_match_reference() {
    let seq = open(std::path::Path::new(FIXTURE)).unwrap();
    let (w, h) = (96, 72);
    let cam = seq.camera;
    let camera = PinholeCamera::new(cam.fx, cam.fy, cam.cx, cam.cy, w, h).unwrap();
    let bins = InverseDepthBins::from_depth_range(0.4, 10.0, 32).unwrap();
    let crop = |i: usize| {
        let f = seq.load_frame(i).unwrap();
        (f.rgb.slice(ndarray::s![..h, ..w, ..]).to_owned(), f.pose)
    };
    let (key, key_pose) = crop(10);
    let live: Vec<(Array3<f32>, Pose)> = [7, 8, 9, 11, 12, 13]
        .iter()
        .map(|&i| {
            let (f, pose) = crop(i);
            (f, densefeat::geometry::relative_pose(&key_pose, &pose))
        })
        .collect();
    let case = VolumeCase {
        reference: key,
        live,
        camera,
        bins,
        // A truncation that cuts the fixture's occlusion outliers (SPEC.md §9.13's example value).
        truncation: 100.0,
    };
    let want = build(&reference(), &case, false);
    // RGB is non-negative, so the magnitude run is the reference on `f_r` and `-f_n` (§9.6).
    let mag = build(&reference(), &case, true);
    let seen = want.counts().iter().filter(|&&n| n > 0).count();
    assert!(seen * 2 > want.counts().len(), "the window sees most cells ({seen})");
    for b in backends() {
        let Some(got) = supported(b.as_ref(), "cost_volume", try_build(b.as_ref(), &case, false)) else {
            continue;
        };
        let label = format!("{} fixture volume 96x72x32, 6 frames", b.name());
        assert_same_counts(&label, &got.counts(), &want.counts());
        assert_costs_within(&label, &got.costs(), &want.costs(), &mag.costs(), (3 + 6 + 8) as f32 * EPS);
        let costs = want.costs();
        let wg = b.winner_take_all(costs.view(), &bins).unwrap();
        let wr = reference().winner_take_all(costs.view(), &bins).unwrap();
        assert_eq!(wg.valid, wr.valid, "{label}: WTA validity");
        assert_same_bits(&format!("{label}: WTA inverse depth"), &wg.inverse_depth, &wr.inverse_depth);
    }
}

/// End to end on the fixture: the network's features within the §8.7 network budget, then a
/// whole keyframe (RGB, level 1) against the reference volume: counts-driven validity equal and the
/// DTAM depth map within SPEC.md §15.3's end-to-end budget.
#[test]
fn end_to_end_on_the_fixture() {
    let seq = open(std::path::Path::new(FIXTURE)).unwrap();
    let frame = seq.load_frame(10).unwrap();
    let weights = densefeat::nn::NetworkWeights::from_safetensors_bytes(
        densefeat::mapping::features::SHIPPED_WEIGHTS,
        std::path::Path::new("shipped"),
    )
    .unwrap();
    let net = densefeat::nn::FeatureNet::new(weights).unwrap();
    let rel = densefeat::nn::budget::relative_budget(net.config());
    // A 64x48 crop keeps the f64 reference network fast.
    let img = frame.rgb.slice(ndarray::s![..48, ..64, ..]).to_owned();
    let want = net.forward(img.view(), &reference()).unwrap();
    let scale = want.features().iter().fold(0.0f64, |m, v| m.max(f64::from(v.abs())));
    for b in backends() {
        let got = net.forward(img.view(), b.as_ref()).unwrap();
        let worst = got
            .features()
            .iter()
            .zip(want.features())
            .fold(0.0f64, |m, (g, w)| m.max(f64::from((g - w).abs())));
        eprintln!("{} features: max |diff| {worst:e}, budget {:e}", b.name(), rel * scale);
        assert!(worst <= rel * scale, "{} features: max |diff| {worst:e} > {:e}", b.name(), rel * scale);
    }

    let mut cfg = KeyframeConfig::new(10, 0.4, 10.0);
    (cfg.past, cfg.future, cfg.bins, cfg.level) = (3, 3, 32, 1);
    cfg.features = FeatureKind::Rgb;
    cfg.regularizer = Regularizer::Tv;
    cfg.backend = Arc::new(reference());
    let want = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    let step = want.bins.step() as f32;
    for b in backends() {
        cfg.backend = b.clone();
        let before = b.traffic();
        let Some(got) = supported(b.as_ref(), "reconstruct", reconstruct(&seq, &cfg, |_, _, _| {})) else {
            continue;
        };
        // The volume stays where it was built (SPEC.md §15.6): a device backend downloads per-pixel
        // maps only, less than one f32 volume of the keyframe.
        let after = b.traffic();
        let (h, w) = got.valid.dim();
        let volume_bytes = (h * w * cfg.bins * 4) as u64;
        let down = after.downloaded - before.downloaded;
        eprintln!(
            "{}: keyframe traffic {} B up, {down} B down (one volume: {volume_bytes} B)",
            b.name(),
            after.uploaded - before.uploaded
        );
        assert!(
            down < volume_bytes,
            "{}: downloaded {down} B, at least one volume ({volume_bytes} B)",
            b.name()
        );
        assert_eq!(got.valid, want.valid, "{} validity", b.name());
        let (g, w) = (&got.tv.as_ref().unwrap().inverse_depth, &want.tv.as_ref().unwrap().inverse_depth);
        let far = g.iter().zip(w).filter(|(a, b)| (*a - *b).abs() > step).count();
        let frac = far as f64 / g.len() as f64;
        eprintln!(
            "{}: DTAM pixels more than one bin from the reference: {far} of {} ({:.3} %)",
            b.name(),
            g.len(),
            100.0 * frac
        );
        assert!(
            frac <= 0.01,
            "{} DTAM depth: {:.3} % of pixels more than one bin off (budget 1 %)",
            b.name(),
            100.0 * frac
        );
        let (mg, mw) = (
            got.metrics(got.tv.as_ref().unwrap()).unwrap(),
            want.metrics(want.tv.as_ref().unwrap()).unwrap(),
        );
        assert!(
            (mg.delta_1_25 - mw.delta_1_25).abs() <= 0.01,
            "{} δ<1.25 {} vs {}",
            b.name(),
            mg.delta_1_25,
            mw.delta_1_25
        );
    }
}

/// `--backend` is resolved before any work: an unknown or unavailable backend is refused with a
/// message naming the flag, and nothing is written.
#[test]
fn unavailable_backends_are_refused_up_front() {
    let dir = tempfile::tempdir().unwrap();
    for (name, want) in [("gpu", "--backend cpu"), ("tpu", "--backend")] {
        if backend::by_name(name).is_ok() {
            continue; // gpu in a build and on a machine that has it
        }
        let out = dir.path().join(name);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["reconstruct", "--sequence", FIXTURE, "--keyframe", "5", "--backend", name, "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{name}: accepted");
        assert!(err.contains(want), "{name}: {err}");
        assert!(!out.exists(), "{name}: wrote {}", out.display());
    }
}
