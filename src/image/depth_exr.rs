//! Single-channel OpenEXR depth maps (Record3D exports, SPEC.md §4a), read with the maintained `exr`
//! crate: half (`f16`) or float (`f32`) samples, metres. The header is checked before any pixel is
//! decoded, so a file whose header claims a huge image is refused without allocating for it.

use std::path::Path;

use exr::meta::MetaData;
use exr::prelude::{read, FlatSamples, ReadChannels, ReadLayers};
use ndarray::Array2;

use super::DepthMap;
use crate::error::{Error, Result};

/// Channel names taken as depth when a file has several channels, in order of preference.
pub const DEPTH_CHANNELS: [&str; 4] = ["R", "Y", "Z", "depth"];

/// Width and height of the first layer of an EXR file, from its header alone.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::BadFile`] if it is not an EXR file.
pub fn read_exr_dimensions(path: &Path) -> Result<(usize, usize)> {
    let meta = read_meta(path)?;
    let h = &meta.headers[0];
    Ok((h.layer_size.width(), h.layer_size.height()))
}

fn read_meta(path: &Path) -> Result<MetaData> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let meta = MetaData::read_from_unbuffered(file, false)
        .map_err(|e| Error::bad_file(path, format!("cannot read EXR header: {e}")))?;
    if meta.headers.is_empty() {
        return Err(Error::bad_file(path, "EXR file has no layer"));
    }
    Ok(meta)
}

/// Load a depth map from the first layer of an EXR file: its only channel, or else the first of
/// [`DEPTH_CHANNELS`] it has; `f16` or `f32` samples in metres. Values that are not finite or not
/// `> 0` become `0` (no depth). Every layer must be at most `max_width x max_height`, checked on the
/// header before decoding.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read; [`Error::BadFile`] naming the file for an undecodable
/// file, a layer larger than the limit, no usable channel, `u32` samples or subsampled channels.
pub fn load_depth_exr(path: &Path, max_width: usize, max_height: usize) -> Result<DepthMap> {
    let meta = read_meta(path)?;
    for h in &meta.headers {
        let (w, hh) = (h.layer_size.width(), h.layer_size.height());
        if w > max_width || hh > max_height || w == 0 || hh == 0 {
            return Err(Error::bad_file(
                path,
                format!("EXR layer is {w}x{hh}: expected at least 1x1 and at most {max_width}x{max_height}"),
            ));
        }
    }
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .non_parallel()
        .from_file(path)
        .map_err(|e| Error::bad_file(path, format!("cannot decode EXR: {e}")))?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
    let index = if channels.len() == 1 {
        0
    } else {
        DEPTH_CHANNELS
            .iter()
            .find_map(|want| names.iter().position(|n| n.eq_ignore_ascii_case(want)))
            .ok_or_else(|| {
                Error::bad_file(
                    path,
                    format!(
                        "EXR has channels [{}] and none is depth: expected one channel, or one named {}",
                        names.join(", "),
                        DEPTH_CHANNELS.join("/")
                    ),
                )
            })?
    };
    let samples = &channels[index].sample_data;
    let values: Vec<f32> = match samples {
        FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(_) => {
            return Err(Error::bad_file(
                path,
                format!("EXR channel {} holds u32 samples; depth must be half or float", names[index]),
            ))
        }
    };
    if values.len() != w * h {
        return Err(Error::bad_file(
            path,
            format!(
                "EXR channel {} has {} samples for a {w}x{h} layer (subsampled channels are not read)",
                names[index],
                values.len()
            ),
        ));
    }
    let values = values.into_iter().map(|z| if z.is_finite() && z > 0.0 { z } else { 0.0 }).collect();
    Array2::from_shape_vec((h, w), values).map_err(|e| Error::bad_file(path, format!("bad EXR shape: {e}")))
}
