//! `densefeat costcurve` on the rendered fixture: frame order, grid pixels, curve invariants, and
//! the command's PNG and CSV.

use std::path::Path;
use std::process::Command;

use densefeat::geometry::InverseDepthBins;
use densefeat::mapping::costcurve::{
    colour_of, cost_curves, curve_colour, curve_label, frame_order, grid_pixel, normalise,
};
use densefeat::mapping::features::FeatureKind;
use densefeat::plot::PANEL_SIZE;

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

#[test]
fn frame_order_alternates_future_and_past_nearest_first() {
    assert_eq!(frame_order(2, 6), vec![3, 1, 4, 0, 5]);
    assert_eq!(frame_order(0, 3), vec![1, 2]);
    assert_eq!(frame_order(2, 3), vec![1, 0]);
    assert!(frame_order(0, 1).is_empty());
    let mut all = frame_order(7, 20);
    all.sort_unstable();
    assert_eq!(all, (0..20).filter(|&n| n != 7).collect::<Vec<_>>());
}

#[test]
fn grid_pixel_rounds_and_clamps() {
    assert_eq!(grid_pixel((100, 81), 1, (160, 120)), (50, 41));
    assert_eq!(grid_pixel((319, 239), 1, (160, 120)), (159, 119));
    assert_eq!(grid_pixel((5, 6), 0, (10, 10)), (5, 6));
    assert_eq!(grid_pixel((6, 5), 2, (10, 10)), (2, 1));
}

#[test]
fn normalise_maps_seen_costs_to_unit_interval() {
    let (k, n) = normalise(&[Some(3.0), None, Some(1.0), Some(2.0), Some(1.0)]).unwrap();
    assert_eq!(k, 2, "first argmin");
    assert_eq!(n[0], 1.0);
    assert!(n[1].is_nan());
    assert_eq!((n[2], n[3], n[4]), (0.0, 0.5, 0.0));
    assert!(normalise(&[None, None]).is_none());
    assert_eq!(normalise(&[Some(4.0), Some(4.0)]).unwrap().1, vec![0.0, 0.0]);
}

#[test]
fn every_feature_kind_has_its_own_colour() {
    let kinds = ["rgb", "learned", "b1", "dsift", "patch7"];
    for (i, a) in kinds.iter().enumerate() {
        let name = a.parse::<FeatureKind>().unwrap().name();
        assert_eq!(&name, a, "the plot is keyed by the kind's name");
        for b in &kinds[i + 1..] {
            assert_ne!(colour_of(a), colour_of(b), "{a} and {b} share a colour");
        }
    }
}

#[test]
fn repeated_kinds_get_their_own_labels_and_shades() {
    let kinds: Vec<FeatureKind> =
        ["rgb", "learned=a/x.safetensors", "learned=b/x.safetensors", "learned", "b1"]
            .iter()
            .map(|k| k.parse().unwrap())
            .collect();
    let labels: Vec<String> =
        kinds.iter().enumerate().map(|(i, k)| curve_label(&kinds, i, k.name())).collect();
    assert_eq!(labels, ["rgb", "learned=a/x", "learned=b/x", "learned=shipped", "b1"]);
    let twice: Vec<FeatureKind> =
        ["learned=w.safetensors", "learned=w.safetensors"].iter().map(|k| k.parse().unwrap()).collect();
    assert_eq!(curve_label(&twice, 0, "learned"), "learned=w");
    assert_eq!(curve_label(&twice, 1, "learned"), "learned=w#1", "a repeated label is told apart");

    // Two learned weights on the fixture: distinct labels in the curves, two shades of one colour.
    let seq = densefeat::sequence::open(FIXTURE).unwrap();
    let bins = InverseDepthBins::from_depth_range(0.4, 10.0, 8).unwrap();
    let w = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/weights/featurenet_trained_mf4sc.safetensors");
    let two = [FeatureKind::Learned(None), FeatureKind::Learned(Some(w.into()))];
    let curves =
        cost_curves(&seq, 20, &[(200, 150)], &two, &[2], bins, &densefeat::backend::default_backend())
            .unwrap();
    assert_eq!(curves.len(), 2);
    assert_eq!(curves[0].label, "learned=shipped");
    assert_eq!(curves[1].label, "learned=weights/featurenet_trained_mf4sc");
    assert_eq!(curve_colour(&curves[0], &curves), colour_of("learned"));
    let (a, b) = (curve_colour(&curves[0], &curves), curve_colour(&curves[1], &curves));
    assert_ne!(a, b, "the second learned curve is a darker shade");
    assert!(b.0 < a.0 && b.1 < a.1);
}

#[test]
fn curves_are_recorded_at_clamped_frame_counts_with_ground_truth() {
    let seq = densefeat::sequence::open(FIXTURE).unwrap();
    let bins = InverseDepthBins::from_depth_range(0.4, 10.0, 32).unwrap();
    // Keyframe 20 of 40: 39 live frames, so 100 is clamped to 39.
    let curves = cost_curves(
        &seq,
        20,
        &[(200, 150)],
        &[FeatureKind::Rgb],
        &[3, 100],
        bins,
        &densefeat::backend::default_backend(),
    )
    .unwrap();
    let counts: Vec<usize> = curves.iter().map(|c| c.frames_added).collect();
    assert_eq!(counts, vec![3, 39]);
    for c in &curves {
        assert_eq!(c.grid_pixel, (100, 75));
        assert_eq!(c.costs.len(), 32);
        assert!(c.costs.iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
        let gt = c.gt_inverse_depth.expect("the fixture has depth everywhere");
        assert!(gt > 0.1 && gt < 2.5, "gt {gt}");
    }
    // With 39 frames the textured room pins the RGB minimum within two bins of the truth.
    let last = &curves[1];
    let (k, _) = normalise(&last.costs).unwrap();
    let gt_bin = bins.bin_of(last.gt_inverse_depth.unwrap());
    assert!((k as f64 - gt_bin).abs() <= 2.0, "argmin bin {k}, ground truth bin {gt_bin}");
    let err = cost_curves(
        &seq,
        40,
        &[(0, 0)],
        &[FeatureKind::Rgb],
        &[2],
        bins,
        &densefeat::backend::default_backend(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("keyframe"), "{err}");
    let err = cost_curves(
        &seq,
        0,
        &[(320, 0)],
        &[FeatureKind::Rgb],
        &[2],
        bins,
        &densefeat::backend::default_backend(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("outside"), "{err}");
}

#[test]
fn costcurve_command_writes_png_grid_and_csv() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cost.png");
    let run = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["costcurve", "--sequence", FIXTURE, "--keyframe", "20", "--pixels", "100,80;200,150"])
        .args(["--features", "rgb,learned", "--frames", "2,4", "--bins", "16", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let img = image::open(&out).unwrap();
    assert_eq!(img.width(), 2 * PANEL_SIZE.0, "two pixels: two columns");
    assert!(img.height() > 2 * PANEL_SIZE.1, "two frame counts: two rows");
    let csv = std::fs::read_to_string(Path::new(&out).with_extension("csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    // Header, then 2 kinds x 2 counts x 2 pixels x 16 hypotheses.
    assert_eq!(lines.len(), 1 + 2 * 2 * 2 * 16);
    assert!(lines[0].starts_with("feature,frames_added,pixel_x,pixel_y"));
    assert!(lines.iter().any(|l| l.starts_with("learned,4,200,150,100,75,")));
}
