//! The fuzz targets' valid seed files, built in a temporary folder.

use std::path::Path;

use densefeat::image::{load_depth_png, load_rgb};
use densefeat::nn::NetworkWeights;
use densefeat::ops::NetworkConfig;
use densefeat::sequence::disparity::read_pfm;
use densefeat::sequence::{open, read_camera_file};
use densefeat::synth::{write_sequence, SceneConfig};

use super::Target;

pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

pub fn target(
    name: &'static str,
    file: &Path,
    text: bool,
    read: impl Fn() -> densefeat::error::Result<()> + 'static,
) -> Target {
    let seed = std::fs::read(file).unwrap();
    Target { name, file: file.to_path_buf(), seed, text, read: Box::new(read) }
}

/// The targets whose name `want` accepts, their files under `dir`.
pub fn targets(dir: &Path, want: &dyn Fn(&str) -> bool) -> Vec<Target> {
    let base = dir.join("base");
    let cfg = SceneConfig { seed: 3, width: 16, height: 12, frames: 3, ..SceneConfig::default() };
    write_sequence(&cfg, &base).unwrap();
    let mut out = Vec::new();

    let png = dir.join("colour.png");
    std::fs::copy(base.join("images/00000.png"), &png).unwrap();
    let p = png.clone();
    if want("png_colour") {
        out.push(target("png_colour", &png, false, move || load_rgb(&p).map(drop)));
    }

    let depth = dir.join("depth.png");
    std::fs::copy(base.join("depth/00000.png"), &depth).unwrap();
    let p = depth.clone();
    if want("png_depth") {
        out.push(target("png_depth", &depth, false, move || {
            load_depth_png(&p, 0.001, Some(65535)).map(drop)
        }));
    }

    let jpg = dir.join("colour.jpg");
    let rgb = image::open(&png).unwrap().to_rgb8();
    rgb.save_with_format(&jpg, image::ImageFormat::Jpeg).unwrap();
    let p = jpg.clone();
    if want("jpeg") {
        out.push(target("jpeg", &jpg, false, move || load_rgb(&p).map(drop)));
    }

    for (name, file) in [("dvmvs_poses", "poses.txt"), ("dvmvs_k", "K.txt")] {
        if !want(name) {
            continue;
        }
        let seq = dir.join(name);
        copy_dir(&base, &seq);
        let s = seq.clone();
        out.push(target(name, &seq.join(file), true, move || open(&s).map(drop)));
    }

    // A TUM folder from the same frames: rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt.
    let tum = dir.join("tum");
    copy_dir(&base.join("images"), &tum.join("rgb"));
    copy_dir(&base.join("depth"), &tum.join("depth"));
    let mut rgb_txt = String::from("# timestamp filename\n");
    let mut depth_txt = String::from("# timestamp filename\n");
    for i in 0..3 {
        rgb_txt += &format!("{}.000000 rgb/{i:05}.png\n", 100 + i);
        depth_txt += &format!("{}.000000 depth/{i:05}.png\n", 100 + i);
    }
    let mut gt = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for k in 0..9 {
        gt += &format!(
            "{:.4} {:.4} 0.0000 1.0000 0.0000 0.0000 {:.4} 1.0000\n",
            99.5 + 0.5 * k as f64,
            0.01 * k as f64,
            0.001 * k as f64
        );
    }
    std::fs::write(tum.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(tum.join("depth.txt"), depth_txt).unwrap();
    std::fs::write(tum.join("groundtruth.txt"), gt).unwrap();
    let tum2 = dir.join("tum2");
    copy_dir(&tum, &tum2);
    let s = tum.clone();
    if want("tum_groundtruth") {
        out.push(target("tum_groundtruth", &tum.join("groundtruth.txt"), true, move || open(&s).map(drop)));
    }
    let s = tum2.clone();
    if want("tum_rgb_list") {
        out.push(target("tum_rgb_list", &tum2.join("rgb.txt"), true, move || open(&s).map(drop)));
    }

    let cam = dir.join("camera.txt");
    std::fs::write(
        &cam,
        "# fx fy cx cy k1 k2 p1 p2 k3\n517.3 516.5 318.6 255.3 0.2624 -0.9531 -0.0054 0.0026 1.1633\n16 12\n",
    )
    .unwrap();
    let p = cam.clone();
    if want("camera_file") {
        out.push(target("camera_file", &cam, true, move || read_camera_file(&p, (16, 12)).map(drop)));
    }

    let stereo = dir.join("stereo");
    std::fs::create_dir_all(&stereo).unwrap();
    std::fs::copy(base.join("images/00000.png"), stereo.join("im0.png")).unwrap();
    std::fs::copy(base.join("images/00001.png"), stereo.join("im1.png")).unwrap();
    std::fs::write(
        stereo.join("calib.txt"),
        "cam0=[16 0 8; 0 16 6; 0 0 1]\ncam1=[16 0 8; 0 16 6; 0 0 1]\ndoffs=0\nbaseline=100\nwidth=16\nheight=12\nndisp=8\n",
    )
    .unwrap();
    let s = stereo.clone();
    if want("stereo_calib") {
        out.push(target("stereo_calib", &stereo.join("calib.txt"), true, move || open(&s).map(drop)));
    }

    let pfm = dir.join("disp.pfm");
    let d = ndarray::Array2::from_shape_fn((6, 8), |(y, x)| (x + 2 * y) as f32 + 0.5);
    densefeat::mapping::output::write_pfm(&pfm, d.view()).unwrap();
    let p = pfm.clone();
    if want("pfm") {
        out.push(target("pfm", &pfm, false, move || read_pfm(&p).map(drop)));
    }

    let st = dir.join("w.safetensors");
    let config = NetworkConfig { blocks: 2, channels: 4, b1_stride: 2, input_mean: [110.0; 3] };
    NetworkWeights::xavier_uniform(&config, 0).unwrap().save(&st).unwrap();
    let p = st.clone();
    if want("safetensors") {
        out.push(target("safetensors", &st, false, move || NetworkWeights::load(&p).map(drop)));
    }
    out.extend(super::setup_formats::targets(dir, &base, want));
    out
}
