//! Occlusion masking of the training loss (SPEC.md §13.1c): the rule on a scene whose occlusions
//! are known in closed form, and the data pipeline with the mask on.

use densefeat::geometry::{PinholeCamera, Pose, Warp};
use densefeat::train::data::{DataConfig, DataSet};
use densefeat::train::occlusion::{mask_occluded, occluded};
use ndarray::Array2;

const F: f64 = 100.0;
const CX: f64 = 64.0;
/// The live camera's centre is `(B, 0, 0)` in the reference frame.
const B: f64 = 0.6;
/// A box face at depth 2 m spans `X ∈ [X0, X1]` (any height) in front of a wall at 4 m.
const X0: f64 = -0.2;
const X1: f64 = 0.2;

fn camera() -> PinholeCamera {
    PinholeCamera::new(F, F, CX, 16.0, 128, 32).unwrap()
}

/// The depth seen at column `u` by a camera centred at `(c, 0, 0)` looking down `z`.
fn seen(c: f64, u: f64) -> f32 {
    let x_at_box = c + 2.0 * (u - CX) / F;
    if (X0..=X1).contains(&x_at_box) {
        2.0
    } else {
        4.0
    }
}

fn depth_map(c: f64) -> Array2<f32> {
    Array2::from_shape_fn((32, 128), |(_, x)| seen(c, x as f64))
}

fn warp() -> Warp {
    // T_lr: X_l = X_r − (B, 0, 0).
    let t_lr = Pose::translation(-B, 0.0, 0.0);
    Warp::new(&camera(), &camera(), &t_lr)
}

#[test]
fn wall_pixels_behind_the_box_are_occluded_and_no_other() {
    let (reference, live) = (depth_map(0.0), depth_map(B));
    let w = warp();
    // The live image's box columns.
    let (lo, hi) = (CX + F * (X0 - B) / 2.0, CX + F * (X1 - B) / 2.0);
    let (mut hidden, mut checked) = (0, 0);
    for u in 0..128 {
        let z = reference[[16, u]];
        let got = occluded(&w, live.view(), u as f64, 16.0, z, 0.05);
        if z == 2.0 {
            assert!(!got, "a box pixel has nothing in front of it (u {u})");
            continue;
        }
        // A wall point at 4 m moves by f B / 4 pixels.
        let u_live = u as f64 - F * B / 4.0;
        if !(0.0..=127.0).contains(&u_live) {
            assert!(!got, "outside the live image: left to the loss's own mask (u {u})");
            continue;
        }
        // Sub-pixel matches within 1.5 px of the box's edges have taps on both sides.
        if (u_live - lo).abs() < 1.5 || (u_live - hi).abs() < 1.5 {
            continue;
        }
        let want = u_live > lo && u_live < hi;
        assert_eq!(got, want, "u {u}: live column {u_live}, box columns {lo}..{hi}");
        hidden += usize::from(want);
        checked += 1;
    }
    assert!(hidden >= 10 && checked > hidden + 40, "hidden {hidden} of {checked}");
}

#[test]
fn the_tolerance_and_missing_depth_decide_at_the_margin() {
    let (reference, live) = (depth_map(0.0), depth_map(B));
    let w = warp();
    // A wall pixel whose match lies well inside the live box (box at 2 m, point at 4 m): the live
    // box spans columns 24..44, and wall column 46 moves by 15 px to 31.
    let u = 46.0;
    assert_eq!(reference[[16, u as usize]], 4.0);
    assert!(occluded(&w, live.view(), u, 16.0, 4.0, 0.05));
    // 2 < (1 − τ) 4 holds for τ < 0.5 only.
    assert!(occluded(&w, live.view(), u, 16.0, 4.0, 0.49));
    assert!(!occluded(&w, live.view(), u, 16.0, 4.0, 0.5));
    // No valid tap: no evidence, kept.
    let mut holes = live.clone();
    holes.fill(0.0);
    assert!(!occluded(&w, holes.view(), u, 16.0, 4.0, 0.05));
    // One valid tap behind the point keeps it even when the others are in front.
    let x = (u - F * B / 4.0).floor() as usize;
    let mut edge = live.clone();
    edge[[16, x + 1]] = 4.5;
    assert!(!occluded(&w, edge.view(), u, 16.0, 4.0, 0.05));
    // `mask_occluded` zeroes exactly the occluded pixels of a window, and τ = 0 nothing.
    let window = reference.slice(ndarray::s![4..12, 20..100]).to_owned();
    let mut masked = window.clone();
    let lives = [(w, live.view())];
    let n = mask_occluded(&mut masked, (20, 4), &lives, 0.05);
    let mut zeroed = 0;
    for ((y, x), &z) in masked.indexed_iter() {
        let hid = occluded(&w, live.view(), (x + 20) as f64, (y + 4) as f64, window[[y, x]], 0.05);
        assert_eq!(z, if hid { 0.0 } else { window[[y, x]] }, "({x}, {y})");
        zeroed += usize::from(hid);
    }
    assert_eq!(n, zeroed);
    assert!(n > 0);
    let mut off = window.clone();
    assert_eq!(mask_occluded(&mut off, (20, 4), &lives, 0.0), 0);
    assert_eq!(off, window);
}

/// With the mask on, a training tuple is the same draw with some reference depths zeroed (the
/// images, cameras and poses unchanged); the flag enters the fingerprint only when set, and a bad
/// value is refused naming it.
#[test]
fn the_data_pipeline_masks_only_depth() {
    let base = DataConfig {
        crop: (96, 64),
        synthetic_scenes: 3,
        synthetic_val_scenes: 1,
        live_frames: 3,
        ..DataConfig::default()
    };
    let plain = DataSet::open(base.clone()).unwrap();
    let masked = DataSet::open(DataConfig { occlusion_tolerance: 0.05, ..base.clone() }).unwrap();
    let mut zeroed = 0;
    for step in 1..=6 {
        let (a, b) = (plain.train_pair(7, step, 0).unwrap(), masked.train_pair(7, step, 0).unwrap());
        assert_eq!(a.ref_rgb, b.ref_rgb);
        assert_eq!(a.live_rgb, b.live_rgb);
        assert_eq!(a.t_lr, b.t_lr);
        assert_eq!(a.more_lives.len(), b.more_lives.len());
        for (za, zb) in a.ref_depth.iter().zip(&b.ref_depth) {
            assert!(zb == za || *zb == 0.0, "{za} -> {zb}");
            zeroed += usize::from(zb != za);
        }
    }
    assert!(zeroed > 0, "six tuples of rendered rooms with boxes hide something");
    let bad = DataConfig { occlusion_tolerance: 1.0, ..base.clone() };
    let err = DataSet::open(bad).err().expect("refused").to_string();
    assert!(err.contains("--occlusion-mask"), "{err}");
    let bad = DataConfig { occlusion_tolerance: f64::NAN, ..base };
    assert!(DataSet::open(bad).is_err());
}

#[test]
fn the_fingerprint_names_the_mask_only_when_it_is_on() {
    use densefeat::nn::NetworkConfig;
    use densefeat::train::loss::LossConfig;
    use densefeat::train::optim::OptimConfig;
    use densefeat::train::step::Supervision;
    use densefeat::train::trainer::TrainConfig;
    let cfg = |tau: f64| TrainConfig {
        network: NetworkConfig { blocks: 2, channels: 4, b1_stride: 2, input_mean: [110.0; 3] },
        init_seed: 3,
        seed: 4,
        steps: 4,
        batch: 2,
        optim: OptimConfig::default(),
        loss: LossConfig::default(),
        supervision: Supervision::default(),
        data: DataConfig { occlusion_tolerance: tau, ..DataConfig::default() },
        val_every: 2,
        val_per_source: 1,
        ckpt_every: 2,
        frame_cache_mb: 64,
        init_weights: None,
    };
    let (off, on) = (cfg(0.0).fingerprint(), cfg(0.05).fingerprint());
    assert!(!off.contains("occlusion") && off.ends_with(" }"), "{off}");
    assert!(on.contains("occlusion_tolerance: 0.05 }"), "{on}");
}
