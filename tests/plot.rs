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

#[test]
fn picture_grid_copies_every_tile_below_its_caption() {
    use densefeat::plot::{image_grid_png, Tile};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grid.png");
    // Three tiles of distinct solid colours, one smaller, in rows of two.
    let tile = |w: usize, h: usize, c: [u8; 3], caption: &str| Tile {
        width: w,
        height: h,
        rgb: std::iter::repeat_n(c, w * h).flatten().collect(),
        caption: caption.into(),
    };
    let tiles = [
        tile(30, 20, [200, 0, 0], "red"),
        tile(30, 20, [0, 200, 0], "green"),
        tile(10, 8, [0, 0, 200], "blue"),
    ];
    image_grid_png(&path, "three tiles", &tiles, 2).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    // Cells of (30 + 6) x (20 + 22 + 6) pixels, a 6 pixel margin left, a 40 pixel title band.
    assert_eq!(img.dimensions(), (2 * 36 + 6, 2 * 48 + 40));
    let at = |x: u32, y: u32| img.get_pixel(x, y).0;
    // Each tile's pixels, whole, at its cell's origin under the caption band.
    for (i, t) in tiles.iter().enumerate() {
        let (x0, y0) = (6 + 36 * (i as u32 % 2), 40 + 48 * (i as u32 / 2) + 22);
        let want = t.rgb[0..3].to_vec();
        for (x, y) in [(x0, y0), (x0 + t.width as u32 - 1, y0 + t.height as u32 - 1)] {
            assert_eq!(at(x, y).to_vec(), want, "tile {i} at ({x}, {y})");
        }
        // Just right of and below the tile: background or the next cell, never the tile's colour.
        assert_ne!(at(x0 + t.width as u32, y0).to_vec(), want);
        assert_ne!(at(x0, y0 + t.height as u32).to_vec(), want);
        // The caption band has dark text pixels.
        let dark =
            (x0..x0 + 30).flat_map(|x| (y0 - 20..y0).map(move |y| (x, y))).any(|(x, y)| at(x, y)[0] < 100);
        assert!(dark, "tile {i}: no caption text");
    }
    // Bad tiles and layouts are refused, naming the tile.
    let mut bad = tiles.clone();
    bad[1].rgb.pop();
    let e = image_grid_png(&path, "bad", &bad, 2).unwrap_err();
    assert!(e.to_string().contains("tile 1"), "{e}");
    assert!(image_grid_png(&path, "none", &[], 2).is_err());
    assert!(image_grid_png(&path, "no columns", &tiles, 0).is_err());
}
