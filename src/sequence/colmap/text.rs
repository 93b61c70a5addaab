//! COLMAP's text model: `cameras.txt`, `images.txt` (two lines per image: the pose line, then the
//! 2D points line, which may be empty) and `points3D.txt`. `#` comment lines are skipped.

use std::path::Path;

use super::model::{CameraModel, Loc, RawCamera, RawImage, RawPoint, SUPPORTED_MODELS};
use crate::error::{Error, Result};
use crate::sequence::text::{data_lines, read_text, Line};

fn id<T: std::str::FromStr>(path: &Path, l: &Line, i: usize, name: &str) -> Result<T> {
    let s = l.fields.get(i).map(String::as_str).unwrap_or("");
    s.parse().map_err(|_| {
        Error::parse(path, l.number, format!("{name} (field {}) is {s:?}, not a non-negative integer", i + 1))
    })
}

/// `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]` per line.
pub(crate) fn read_cameras(path: &Path) -> Result<Vec<RawCamera>> {
    let mut out = Vec::new();
    for l in data_lines(path)? {
        l.expect_at_least(path, 4, "`CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`")?;
        let name = l.fields[1].as_str();
        let (model, n) = CameraModel::from_name(name).ok_or_else(|| {
            Error::parse(
                path,
                l.number,
                format!("unknown camera model {name:?}; supported: {SUPPORTED_MODELS}"),
            )
        })?;
        if l.fields.len() != 4 + n {
            return Err(Error::parse(
                path,
                l.number,
                format!("model {name} has {n} parameters, the line has {}", l.fields.len() - 4),
            ));
        }
        let params = (0..n).map(|k| l.float(path, 4 + k, "camera parameter")).collect::<Result<_>>()?;
        out.push(RawCamera {
            id: id(path, &l, 0, "CAMERA_ID")?,
            model,
            width: id(path, &l, 2, "WIDTH")?,
            height: id(path, &l, 3, "HEIGHT")?,
            params,
            loc: Loc::Line(l.number),
        });
    }
    Ok(out)
}

/// `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then `X Y POINT3D_ID` triples on the next line.
pub(crate) fn read_images(path: &Path) -> Result<Vec<RawImage>> {
    let text = read_text(path)?;
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let t = lines[i].trim();
        if t.is_empty() || t.starts_with('#') {
            i += 1;
            continue;
        }
        let number = i + 1;
        let fields: Vec<String> = t.split_whitespace().map(str::to_string).collect();
        let l = Line { number, fields };
        if l.fields.len() != 10 {
            return Err(Error::parse(
                path,
                number,
                format!(
                    "expected `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` (10 fields), found {} field(s) \
                     (image names with spaces are not supported)",
                    l.fields.len()
                ),
            ));
        }
        let q = l.floats::<4>(path, 1, "quaternion")?;
        let tr = l.floats::<3>(path, 5, "translation")?;
        let points = lines.get(i + 1).copied().unwrap_or("");
        let observed = read_points2d(path, i + 2, points)?;
        out.push(RawImage {
            id: id(path, &l, 0, "IMAGE_ID")?,
            q_wxyz: q,
            t: tr,
            camera_id: id(path, &l, 8, "CAMERA_ID")?,
            name: l.fields[9].clone(),
            observed,
            loc: Loc::Line(number),
        });
        i += 2;
    }
    Ok(out)
}

/// The 2D points line `(X Y POINT3D_ID)*` at 1-based line `number`: the observed point ids.
fn read_points2d(path: &Path, number: usize, text: &str) -> Result<Vec<u64>> {
    let f: Vec<&str> = text.split_whitespace().collect();
    if !f.len().is_multiple_of(3) {
        return Err(Error::parse(
            path,
            number,
            format!("2D points line has {} fields, not a multiple of 3 (`X Y POINT3D_ID` triples)", f.len()),
        ));
    }
    let mut ids = Vec::new();
    for (k, c) in f.chunks(3).enumerate() {
        for s in &c[..2] {
            if !s.parse::<f64>().is_ok_and(f64::is_finite) {
                return Err(Error::parse(
                    path,
                    number,
                    format!("2D point {k}: coordinate {s:?} is not a finite number"),
                ));
            }
        }
        match c[2].parse::<i64>() {
            Ok(-1) => {}
            Ok(v) if v >= 0 => ids.push(v as u64),
            _ => {
                return Err(Error::parse(
                    path,
                    number,
                    format!("2D point {k}: POINT3D_ID {:?} is not an integer >= -1", c[2]),
                ))
            }
        }
    }
    Ok(ids)
}

/// `POINT3D_ID X Y Z R G B ERROR TRACK[]` per line.
pub(crate) fn read_points(path: &Path) -> Result<Vec<RawPoint>> {
    let mut out = Vec::new();
    for l in data_lines(path)? {
        l.expect_at_least(path, 8, "`POINT3D_ID X Y Z R G B ERROR TRACK[]`")?;
        if !(l.fields.len() - 8).is_multiple_of(2) {
            return Err(Error::parse(
                path,
                l.number,
                "track has an odd number of fields (expected `IMAGE_ID POINT2D_IDX` pairs)",
            ));
        }
        out.push(RawPoint {
            id: id(path, &l, 0, "POINT3D_ID")?,
            xyz: l.floats::<3>(path, 1, "point coordinate")?,
        });
    }
    Ok(out)
}
