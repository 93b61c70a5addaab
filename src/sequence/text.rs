//! Shared helpers for the readers' text files and image folders: every error names the file and,
//! for text, the 1-based line.

use std::path::{Path, PathBuf};

use image::{ColorType, ImageDecoder, ImageReader};

use crate::error::{Error, Result};

/// One meaningful line of a text file: blank lines and `#` comments are skipped.
#[derive(Clone, Debug)]
pub(crate) struct Line {
    /// 1-based line number in the file.
    pub number: usize,
    /// The line's whitespace-separated fields.
    pub fields: Vec<String>,
}

/// Read a whole text file.
pub(crate) fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        Error::bad_file(
            path,
            format!("not UTF-8 text (first bad byte at offset {})", e.utf8_error().valid_up_to()),
        )
    })
}

/// The non-blank, non-comment lines of `path`, split on whitespace (commas count as whitespace, so
/// `1,2,3` and `1 2 3` read the same).
pub(crate) fn data_lines(path: &Path) -> Result<Vec<Line>> {
    Ok(comment_and_data_lines(path)?.1)
}

/// Like [`data_lines`], also returning the comment lines' text (without `#`).
pub(crate) fn comment_and_data_lines(path: &Path) -> Result<(Vec<String>, Vec<Line>)> {
    let text = read_text(path)?;
    let mut comments = Vec::new();
    let mut lines = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let t = raw.trim();
        if t.is_empty() {
            continue;
        }
        if let Some(c) = t.strip_prefix('#') {
            comments.push(c.trim().to_string());
            continue;
        }
        let fields = t.split(|c: char| c.is_whitespace() || c == ',').filter(|s| !s.is_empty());
        lines.push(Line { number: i + 1, fields: fields.map(str::to_string).collect() });
    }
    Ok((comments, lines))
}

impl Line {
    /// Require at least `n` fields; `what` describes the expected layout for the message.
    pub fn expect_at_least(&self, path: &Path, n: usize, what: &str) -> Result<()> {
        if self.fields.len() < n {
            return Err(Error::parse(
                path,
                self.number,
                format!("expected {what} ({n} fields), found {} field(s)", self.fields.len()),
            ));
        }
        Ok(())
    }

    /// Field `i` as a finite `f64`; `name` says what it is.
    pub fn float(&self, path: &Path, i: usize, name: &str) -> Result<f64> {
        let s = self.fields.get(i).map(String::as_str).unwrap_or("");
        let v: f64 = s.parse().map_err(|_| {
            Error::parse(path, self.number, format!("{name} (field {}) is {s:?}, not a number", i + 1))
        })?;
        if !v.is_finite() {
            return Err(Error::parse(
                path,
                self.number,
                format!("{name} (field {}) is {s}, must be finite", i + 1),
            ));
        }
        Ok(v)
    }

    /// Fields `start..start + N` as finite numbers.
    pub fn floats<const N: usize>(&self, path: &Path, start: usize, name: &str) -> Result<[f64; N]> {
        let mut out = [0.0; N];
        for (k, o) in out.iter_mut().enumerate() {
            *o = self.float(path, start + k, name)?;
        }
        Ok(out)
    }
}

/// `root/relative`, with an error naming `list:line` when the file does not exist.
pub(crate) fn existing_file(root: &Path, relative: &str, list: &Path, line: usize) -> Result<PathBuf> {
    let p = root.join(relative);
    if !p.is_file() {
        return Err(Error::parse(
            list,
            line,
            format!("references {relative}, but {} does not exist", p.display()),
        ));
    }
    Ok(p)
}

/// File extensions accepted for colour images (case-insensitive): PNG and JPEG.
pub const COLOUR_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The files directly in `dir` whose extension is one of `extensions` (case-insensitive), sorted by
/// file name.
pub(crate) fn list_files_with(dir: &Path, extensions: &[&str]) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut out = Vec::new();
    for entry in entries {
        let p = entry.map_err(|e| Error::io(dir, e))?.path();
        if !p.extension().is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x))) {
            continue;
        }
        // Follow links; a loop or a dangling link is an error naming it, not a silently missing frame.
        match std::fs::metadata(&p) {
            Ok(m) if m.is_file() => out.push(p),
            Ok(_) => {}
            Err(e) => return Err(Error::io(&p, e)),
        }
    }
    out.sort();
    Ok(out)
}

/// The `*.png` files directly in `dir`, sorted by file name.
pub(crate) fn list_pngs(dir: &Path) -> Result<Vec<PathBuf>> {
    list_files_with(dir, &["png"])
}

/// The colour images (`*.png`, `*.jpg`, `*.jpeg`) directly in `dir`, sorted by file name. Two files
/// with the same stem (`00001.png` and `00001.jpg`) make the frame order ambiguous and are refused,
/// naming both.
pub(crate) fn list_colour_images(dir: &Path) -> Result<Vec<PathBuf>> {
    let files = list_files_with(dir, &COLOUR_EXTENSIONS)?;
    let mut stems: Vec<(String, &PathBuf)> = files.iter().map(|p| (stem(p), p)).collect();
    stems.sort();
    for w in stems.windows(2) {
        if w[0].0 == w[1].0 {
            return Err(Error::bad_sequence(
                dir,
                format!(
                    "{} and {} are the same frame in two formats; keep one",
                    w[0].1.display(),
                    w[1].1.display()
                ),
            ));
        }
    }
    Ok(files)
}

/// `dir/STEM.png`, `dir/STEM.jpg` or `dir/STEM.jpeg`, the first that is a file.
pub(crate) fn find_colour_image(dir: &Path, stem: &str) -> Option<PathBuf> {
    COLOUR_EXTENSIONS.iter().map(|e| dir.join(format!("{stem}.{e}"))).find(|p| p.is_file())
}

/// The image format of `path` from its extension, for reports: `"PNG"`, `"JPEG"` or the extension.
pub fn image_format_name(path: &Path) -> String {
    match path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).as_deref() {
        Some("png") => "PNG".into(),
        Some("jpg" | "jpeg") => "JPEG".into(),
        Some(other) => other.to_uppercase(),
        None => "unknown".into(),
    }
}

/// Check from the header alone that `path` is a 16-bit single-channel image, so an 8-bit export
/// is reported when the sequence is opened rather than on the first load.
pub(crate) fn check_depth_png16(path: &Path) -> Result<()> {
    let reader = ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    let decoder =
        reader.into_decoder().map_err(|e| Error::bad_file(path, format!("cannot read image header: {e}")))?;
    match decoder.color_type() {
        ColorType::L16 => Ok(()),
        other => Err(Error::bad_file(path, format!("depth image must be 16-bit grey, got {other:?}"))),
    }
}

/// The file name of `p` as text, for messages and frame names.
pub(crate) fn stem(p: &Path) -> String {
    p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// A 4x4 matrix stored as four lines of four numbers (7-Scenes and ScanNet poses, ScanNet's
/// intrinsics), row-major; `Ok(None)` when some entry is not finite (ScanNet marks lost frames with
/// `-inf`). Errors name the file and line.
pub(crate) fn read_matrix4(path: &Path) -> Result<Option<nalgebra::Matrix4<f64>>> {
    let lines = data_lines(path)?;
    if lines.len() != 4 {
        return Err(Error::bad_file(
            path,
            format!("expected 4 lines of 4 numbers (a 4x4 matrix), found {} lines", lines.len()),
        ));
    }
    let mut v = [0.0f64; 16];
    for (r, l) in lines.iter().enumerate() {
        if l.fields.len() != 4 {
            return Err(Error::parse(
                path,
                l.number,
                format!("expected 4 numbers, found {}", l.fields.len()),
            ));
        }
        for (c, s) in l.fields.iter().enumerate() {
            v[4 * r + c] = s.parse().map_err(|_| {
                Error::parse(path, l.number, format!("matrix entry (field {}) is {s:?}, not a number", c + 1))
            })?;
        }
    }
    Ok(v.iter().all(|x: &f64| x.is_finite()).then(|| nalgebra::Matrix4::from_row_slice(&v)))
}
