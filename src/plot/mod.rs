//! Line plots as PNG files, for diagnostics (cost curves, sweeps, timings).
//!
//! A thin layer over [plotters](https://docs.rs/plotters) with its bitmap backend rendering into an
//! in-memory RGB buffer, which our own `image` crate then encodes as PNG and writes atomically
//! ([`crate::io::write_atomic_with`]): a plot appears whole or not at all. Text is drawn with
//! plotters' `ab_glyph` renderer and DejaVu Sans compiled into the binary
//! (`fixtures/fonts/DejaVuSans.ttf`, licence beside it), so no system fontconfig or freetype is
//! needed.
//!
//! - [`line_plot_png`]: one chart, [`PLOT_SIZE`] pixels.
//! - [`grid_of_plots_png`]: a grid of [`Panel`]s under one title, [`PANEL_SIZE`] pixels each.
//! - [`image_grid_png`]: a grid of pictures ([`Tile`]s), each with a caption above it, under one
//!   title (the feature figure of `eval --figure`).
//!
//! Non-finite points are skipped (a gap in the data is not an error); axis ranges cover every
//! finite point and marker. A logarithmic x axis plots `log10 x` and labels the ticks with `x`.
//!
//! # Example
//! ```no_run
//! use densefeat::plot::{line_plot_png, Marker, Series};
//! let s = Series { name: "x²".into(), points: (0..20).map(|i| (i as f64, (i * i) as f64)).collect(), colour: (0, 0, 200) };
//! let m = Marker { x: 10.0, colour: (0, 160, 0), label: "ten".into() };
//! line_plot_png("square.png".as_ref(), "A parabola", "x", "x²", &[s], &[m], false).unwrap();
//! ```

use std::io::Write;
use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::error::{Error, Result};
use crate::io::write_atomic_with;

/// DejaVu Sans 2.37 (Bitstream Vera licence, `fixtures/fonts/LICENSE-DejaVu.txt`).
const FONT: &[u8] = include_bytes!("../../fixtures/fonts/DejaVuSans.ttf");
/// The family name plotters asks for by default; we register our font under it.
const FAMILY: &str = "sans-serif";

/// Size `(width, height)` of a [`line_plot_png`] image, pixels.
pub const PLOT_SIZE: (u32, u32) = (800, 600);
/// Size of one panel of [`grid_of_plots_png`], pixels.
pub const PANEL_SIZE: (u32, u32) = (480, 360);
/// Height of the band holding a grid's title, pixels.
const TITLE_BAND: u32 = 40;
/// Most panels a grid may hold (keeps the image below ~200 megapixels of nonsense).
const MAX_PANELS: usize = 400;

/// One polyline, drawn in `colour` and named in the legend.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// `(x, y)` points, drawn in order; non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// RGB colour.
    pub colour: (u8, u8, u8),
}

/// A vertical line at `x`, across the whole chart; named in the legend unless `label` is empty.
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    /// Where.
    pub x: f64,
    /// RGB colour.
    pub colour: (u8, u8, u8),
    /// Legend text (empty: not in the legend).
    pub label: String,
}

/// One chart of a [`grid_of_plots_png`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Panel {
    /// Caption above the chart.
    pub title: String,
    /// X axis description.
    pub x_label: String,
    /// Y axis description.
    pub y_label: String,
    /// The curves.
    pub series: Vec<Series>,
    /// Vertical lines.
    pub markers: Vec<Marker>,
    /// Logarithmic x axis (every x must then be positive).
    pub log_x: bool,
}

fn font_registered() -> std::result::Result<(), String> {
    static REGISTERED: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            register_font(FAMILY, FontStyle::Normal, FONT)
                .map_err(|_| "the bundled DejaVu Sans font failed to parse".to_string())
        })
        .clone()
}

/// Write one line chart of [`PLOT_SIZE`] to `path` (PNG, atomically).
///
/// # Errors
/// [`Error::InvalidArgument`] if `log_x` and some finite x (of a point or marker) is not positive;
/// [`Error::BadFile`] naming `path` if drawing fails; [`Error::Io`] naming `path` if the file
/// cannot be written (a missing folder, no permission).
pub fn line_plot_png(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    markers: &[Marker],
    log_x: bool,
) -> Result<()> {
    let panel = Panel {
        title: title.to_string(),
        x_label: x_label.to_string(),
        y_label: y_label.to_string(),
        series: series.to_vec(),
        markers: markers.to_vec(),
        log_x,
    };
    check_panel(&panel)?;
    let (w, h) = PLOT_SIZE;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    draw(&mut buf, (w, h), |root| draw_panel(root, &panel, 22)).map_err(|e| Error::bad_file(path, e))?;
    write_png(path, &buf, (w, h))
}

/// Write a grid of charts (`rows[r][c]`, rows may have different lengths; the grid is as wide as
/// the longest) under one `title`, each panel [`PANEL_SIZE`], to `path` (PNG, atomically).
///
/// # Errors
/// [`Error::InvalidArgument`] for an empty or oversized grid or a bad log axis (as
/// [`line_plot_png`]); [`Error::BadFile`] or [`Error::Io`] naming `path` as [`line_plot_png`].
pub fn grid_of_plots_png(path: &Path, title: &str, rows: &[Vec<Panel>]) -> Result<()> {
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    if cols == 0 || rows.len() * cols > MAX_PANELS {
        return Err(Error::invalid_argument(
            "plot grid",
            format!("{} rows x {cols} columns: need 1 to {MAX_PANELS} panels", rows.len()),
        ));
    }
    rows.iter().flatten().try_for_each(check_panel)?;
    let (pw, ph) = PANEL_SIZE;
    // Invariant: at most MAX_PANELS panels, so the sizes fit in u32.
    let size = (pw * cols as u32, ph * rows.len() as u32 + TITLE_BAND);
    let mut buf = vec![255u8; (size.0 * size.1 * 3) as usize];
    draw(&mut buf, size, |root| {
        let (band, body) = root.split_vertically(TITLE_BAND);
        band.draw(&Text::new(title.to_string(), (10, 8), (FAMILY, 18).into_font().color(&BLACK)))
            .map_err(s)?;
        let areas = body.split_evenly((rows.len(), cols));
        for (r, row) in rows.iter().enumerate() {
            for (c, panel) in row.iter().enumerate() {
                draw_panel(&areas[r * cols + c], panel, 16)?;
            }
        }
        Ok(())
    })
    .map_err(|e| Error::bad_file(path, e))?;
    write_png(path, &buf, size)
}

/// One picture of an [`image_grid_png`]: `width x height` RGB pixels, row-major, and its caption.
#[derive(Clone, Debug, PartialEq)]
pub struct Tile {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width · height · 3` bytes, RGB, row-major.
    pub rgb: Vec<u8>,
    /// Text above the picture (one line).
    pub caption: String,
}

/// Height of a tile's caption band, pixels.
const CAPTION_BAND: u32 = 22;
/// Gap between tiles, pixels.
const TILE_GAP: u32 = 6;

/// Write `tiles` in rows of `cols` (the last row may be shorter), each under its caption, the whole
/// under `title`, to `path` (PNG, atomically). Each cell is as large as the largest tile.
///
/// # Errors
/// [`Error::InvalidArgument`] for no tile, `cols == 0`, a tile whose bytes do not match its size,
/// more than 400 tiles or a picture above 2¹⁴ pixels a side; write errors name `path`.
pub fn image_grid_png(path: &Path, title: &str, tiles: &[Tile], cols: usize) -> Result<()> {
    if tiles.is_empty() || cols == 0 || tiles.len() > MAX_PANELS {
        return Err(Error::invalid_argument(
            "picture grid",
            format!("{} tiles in {cols} columns: need 1 to {MAX_PANELS} tiles and a column", tiles.len()),
        ));
    }
    const MAX_SIDE: usize = 1 << 14;
    for (i, t) in tiles.iter().enumerate() {
        if t.rgb.len() != t.width * t.height * 3
            || t.width == 0
            || t.height == 0
            || t.width > MAX_SIDE
            || t.height > MAX_SIDE
        {
            return Err(Error::invalid_argument(
                "picture grid",
                format!(
                    "tile {i} ({:?}): {} bytes for {}x{} pixels",
                    t.caption,
                    t.rgb.len(),
                    t.width,
                    t.height
                ),
            ));
        }
    }
    let cols = cols.min(tiles.len());
    let rows = tiles.len().div_ceil(cols);
    // Invariant: at most 400 tiles of at most 2^14 pixels a side, so the sizes fit in u32.
    let cell_w = tiles.iter().map(|t| t.width).max().unwrap_or(1) as u32 + TILE_GAP;
    let cell_h = tiles.iter().map(|t| t.height).max().unwrap_or(1) as u32 + CAPTION_BAND + TILE_GAP;
    let size = (cell_w * cols as u32 + TILE_GAP, cell_h * rows as u32 + TITLE_BAND);
    let mut buf = vec![255u8; (size.0 as usize) * (size.1 as usize) * 3];
    let origin = |i: usize| {
        let (r, c) = ((i / cols) as u32, (i % cols) as u32);
        (TILE_GAP + c * cell_w, TITLE_BAND + r * cell_h)
    };
    draw(&mut buf, size, |root| {
        root.draw(&Text::new(title.to_string(), (10, 8), (FAMILY, 18).into_font().color(&BLACK)))
            .map_err(s)?;
        for (i, t) in tiles.iter().enumerate() {
            let (x, y) = origin(i);
            let font = (FAMILY, 14).into_font().color(&BLACK);
            root.draw(&Text::new(t.caption.clone(), (x as i32, y as i32 + 3), font)).map_err(s)?;
        }
        Ok(())
    })
    .map_err(|e| Error::bad_file(path, e))?;
    let stride = size.0 as usize * 3;
    for (i, t) in tiles.iter().enumerate() {
        let (x, y) = origin(i);
        let (x, y) = (x as usize, (y + CAPTION_BAND) as usize);
        for (row, src) in t.rgb.chunks_exact(t.width * 3).enumerate() {
            let start = (y + row) * stride + x * 3;
            buf[start..start + src.len()].copy_from_slice(src);
        }
    }
    write_png(path, &buf, size)
}

fn s<E: std::fmt::Display>(e: E) -> String {
    format!("drawing the plot: {e}")
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Render into `buf` (`w·h·3` bytes, RGB) with `f`.
fn draw(
    buf: &mut [u8],
    size: (u32, u32),
    f: impl FnOnce(&Area<'_>) -> std::result::Result<(), String>,
) -> std::result::Result<(), String> {
    font_registered()?;
    let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
    root.fill(&WHITE).map_err(s)?;
    f(&root)?;
    root.present().map_err(s)
}

fn check_panel(panel: &Panel) -> Result<()> {
    if !panel.log_x {
        return Ok(());
    }
    let xs = panel.series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    match xs.chain(panel.markers.iter().map(|m| m.x)).find(|x| x.is_finite() && *x <= 0.0) {
        Some(x) => Err(Error::invalid_argument(
            "log x axis",
            format!("panel {:?} has x = {x}: a log axis needs x > 0", panel.title),
        )),
        None => Ok(()),
    }
}

/// `[lo, hi]` of the finite values, padded by `pad` of the span (or ±0.5 if the span is 0); `[0, 1]`
/// when there is none.
fn range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return (0.0, 1.0);
    }
    let span = hi - lo;
    if span == 0.0 || !span.is_finite() {
        (lo - 0.5, hi + 0.5)
    } else {
        (lo - pad * span, hi + pad * span)
    }
}

/// A tick value with at most 3 decimals and no trailing zeros (`0.5`, `2`, `0.125`).
fn tick_text(x: f64) -> String {
    let t = format!("{x:.3}");
    let t = if t.contains('.') { t.trim_end_matches('0').trim_end_matches('.') } else { &t };
    if t == "-0" {
        "0".to_string()
    } else {
        t.to_string()
    }
}

fn rgb((r, g, b): (u8, u8, u8)) -> RGBColor {
    RGBColor(r, g, b)
}

fn draw_panel(area: &Area<'_>, panel: &Panel, caption_px: u32) -> std::result::Result<(), String> {
    let tx = |x: f64| if panel.log_x { x.log10() } else { x };
    let xs = panel.series.iter().flat_map(|s| s.points.iter().map(|p| tx(p.0)));
    let (x0, x1) = range(xs.chain(panel.markers.iter().map(|m| tx(m.x))), 0.0);
    let (y0, y1) = range(panel.series.iter().flat_map(|s| s.points.iter().map(|p| p.1)), 0.05);
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FAMILY, caption_px))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(s)?;
    let x_desc = if panel.log_x { format!("{} (log scale)", panel.x_label) } else { panel.x_label.clone() };
    let log_x = panel.log_x;
    let x_fmt = move |v: &f64| {
        let x = if log_x { 10f64.powf(*v) } else { *v };
        tick_text(x)
    };
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(panel.y_label.as_str())
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&x_fmt)
        .label_style((FAMILY, 13))
        .axis_desc_style((FAMILY, 14))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(s)?;
    let mut legend = false;
    for series in &panel.series {
        let colour = rgb(series.colour);
        // Split at non-finite points so a gap is drawn as a gap.
        let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
        for &(x, y) in &series.points {
            let p = (tx(x), y);
            if p.0.is_finite() && p.1.is_finite() {
                runs.last_mut().expect("never empty").push(p);
            } else if !runs.last().expect("never empty").is_empty() {
                runs.push(Vec::new());
            }
        }
        let mut first = true;
        for run in runs.into_iter().filter(|r| !r.is_empty()) {
            let drawn = chart.draw_series(LineSeries::new(run, colour.stroke_width(2))).map_err(s)?;
            if first && !series.name.is_empty() {
                legend = true;
                drawn.label(series.name.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            }
            first = false;
        }
    }
    for marker in panel.markers.iter().filter(|m| m.x.is_finite()) {
        let colour = rgb(marker.colour);
        let x = tx(marker.x);
        let drawn =
            chart.draw_series(LineSeries::new([(x, y0), (x, y1)], colour.stroke_width(1))).map_err(s)?;
        if !marker.label.is_empty() {
            legend = true;
            drawn
                .label(marker.label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x + 9, y - 6), (x + 9, y + 6)], colour));
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .label_font((FAMILY, 12))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.5))
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(s)?;
    }
    Ok(())
}

fn write_png(path: &Path, buf: &[u8], (w, h): (u32, u32)) -> Result<()> {
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(buf, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::bad_file(path, format!("encoding PNG: {e}")))?;
    write_atomic_with(path, |f| f.write_all(&bytes))
}
