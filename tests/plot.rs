//! `densefeat::plot`: a plot is written whole, is a PNG of the stated size with real content, and a
//! bad path gives an error naming it.

use densefeat::plot::{grid_of_plots_png, line_plot_png, Marker, Panel, Series, PANEL_SIZE, PLOT_SIZE};
use densefeat::Error;

fn sine() -> Series {
    Series {
        name: "sin".into(),
        points: (0..100).map(|i| (0.1 * i as f64 + 0.1, (0.1 * i as f64).sin())).collect(),
        colour: (200, 0, 0),
    }
}

fn marker() -> Marker {
    Marker { x: 3.0, colour: (0, 160, 0), label: "three".into() }
}

/// Decode and return (width, height, number of distinct colours).
fn decode(path: &std::path::Path) -> (u32, u32, usize) {
    let img = image::open(path).expect("a valid PNG").to_rgb8();
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    (img.width(), img.height(), colours.len())
}

#[test]
fn line_plot_is_a_png_of_the_stated_size_with_content() {
    let dir = tempfile::tempdir().unwrap();
    for log_x in [false, true] {
        let path = dir.path().join(format!("line_{log_x}.png"));
        line_plot_png(&path, "A sine", "x", "sin x", &[sine()], &[marker()], log_x).unwrap();
        let (w, h, colours) = decode(&path);
        assert_eq!((w, h), PLOT_SIZE);
        // White background, black text and axes, the red curve, the green marker, antialiasing.
        assert!(colours > 10, "only {colours} colours: the plot is (nearly) blank");
    }
    // Nothing but the two plots: no temporary file left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}

#[test]
fn grid_has_one_panel_size_per_cell_plus_title_band() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.png");
    let panel = Panel {
        title: "panel".into(),
        x_label: "x".into(),
        y_label: "y".into(),
        series: vec![sine()],
        markers: vec![marker()],
        log_x: false,
    };
    let rows = vec![vec![panel.clone(), panel.clone(), panel.clone()], vec![panel]];
    grid_of_plots_png(&path, "Grid", &rows).unwrap();
    let (w, h, colours) = decode(&path);
    assert_eq!(w, 3 * PANEL_SIZE.0);
    assert!(h > 2 * PANEL_SIZE.1 && h < 2 * PANEL_SIZE.1 + 100, "height {h}");
    assert!(colours > 10);
}

#[test]
fn empty_and_non_finite_data_still_plot() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gaps.png");
    let gappy = Series {
        name: "gaps".into(),
        points: vec![(0.0, 1.0), (1.0, f64::NAN), (2.0, 0.5)],
        colour: (0, 0, 0),
    };
    let empty = Series { name: "empty".into(), points: vec![], colour: (0, 0, 255) };
    line_plot_png(&path, "gaps", "x", "y", &[gappy, empty], &[], false).unwrap();
    assert_eq!(decode(&path).0, PLOT_SIZE.0);
}

#[test]
fn bad_path_is_an_io_error_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no_such_folder").join("plot.png");
    let err = line_plot_png(&path, "t", "x", "y", &[sine()], &[], false).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("no_such_folder/plot.png"), "{err}");
}

#[test]
fn log_axis_rejects_non_positive_x() {
    let dir = tempfile::tempdir().unwrap();
    let s = Series { name: "s".into(), points: vec![(0.0, 1.0), (1.0, 2.0)], colour: (0, 0, 0) };
    let err = line_plot_png(&dir.path().join("log.png"), "t", "x", "y", &[s], &[], true).unwrap_err();
    assert!(matches!(err, Error::InvalidArgument { .. }), "{err:?}");
    let err = grid_of_plots_png(&dir.path().join("g.png"), "t", &[]).unwrap_err();
    assert!(matches!(err, Error::InvalidArgument { .. }), "{err:?}");
}
