//! Seed files of the pose-format targets (issue 34): COLMAP text and binary, `transforms.json`,
//! native 7-Scenes, Record3D `metadata.json` and its EXR depth, ScanNet's intrinsics and poses, and PLY
//! meshes. Each is a valid file
//! written by our writers (or by hand, for Record3D) from the same 16x12 synthetic frames.

use std::path::Path;

use densefeat::fusion::ply::{read_mesh_ply, write_mesh_ply};
use densefeat::fusion::Mesh;
use densefeat::geometry::{Camera, RadTan};
use densefeat::image::load_rgb;
use densefeat::sequence::colmap::{write_model, CameraModel, ColmapExport};
use densefeat::sequence::nerfstudio_write::NerfstudioWriter;
use densefeat::sequence::sevenscenes_write::SevenScenesWriter;
use densefeat::sequence::{open, Sequence};
use nalgebra::Point3;

use super::setup::{copy_dir, target};
use super::Target;

/// The new targets whose name `want` accepts, built from the DeepVideoMVS sequence in `base`.
pub fn targets(dir: &Path, base: &Path, want: &dyn Fn(&str) -> bool) -> Vec<Target> {
    let seq = open(base).unwrap();
    let mut out = Vec::new();
    for binary in [false, true] {
        let ext = if binary { "bin" } else { "txt" };
        for file in ["cameras", "images", "points3D"] {
            let name = colmap_name(file, binary);
            if !want(name) {
                continue;
            }
            let root = dir.join(name);
            write_colmap(&seq, base, &root, binary);
            let s = root.clone();
            out.push(target(name, &root.join(format!("sparse/0/{file}.{ext}")), !binary, move || {
                open(&s).map(drop)
            }));
        }
    }
    if want("transforms_json") {
        let root = dir.join("transforms_json");
        let mut w = NerfstudioWriter::create(&root, seq.raw_camera, false).unwrap();
        for i in 0..seq.len() {
            let f = seq.load_frame(i).unwrap();
            w.push(&f.rgb, f.depth.as_ref(), &f.pose).unwrap();
        }
        w.finish().unwrap();
        let s = root.clone();
        out.push(target("transforms_json", &root.join("transforms.json"), true, move || open(&s).map(drop)));
    }
    if want("sevenscenes_pose") {
        let root = dir.join("sevenscenes");
        let mut w = SevenScenesWriter::create(&root).unwrap();
        for i in 0..seq.len() {
            let f = seq.load_frame(i).unwrap();
            w.push(&f.rgb, f.depth.as_ref().unwrap(), &f.pose).unwrap();
        }
        let s = root.clone();
        out.push(target("sevenscenes_pose", &root.join("frame-000001.pose.txt"), true, move || {
            open(&s).map(drop)
        }));
    }
    if want("record3d_metadata") {
        let root = dir.join("record3d_metadata");
        crate::common::record3d::write(&root, 16, 12, 3, 2);
        let s = root.clone();
        out.push(target("record3d_metadata", &root.join("metadata.json"), true, move || open(&s).map(drop)));
    }
    for (name, file) in
        [("scannet_intrinsic", "intrinsic/intrinsic_color.txt"), ("scannet_pose", "pose/1.txt")]
    {
        if want(name) {
            // Through the whole reader and a frame's load (the depth registered with the fuzzed
            // camera or pose).
            let root = dir.join(name);
            crate::common::scannet::write(&root, 16, 12, 3);
            let s = root.clone();
            out.push(target(name, &root.join(file), true, move || {
                open(&s).and_then(|q: Sequence| q.load_frame(0)).map(drop)
            }));
        }
    }
    if want("exr_depth") {
        // The EXR through the whole reader: the header checked when the sequence opens, the pixels
        // decoded and upsampled when the frame loads.
        let root = dir.join("record3d_exr");
        crate::common::record3d::write(&root, 16, 12, 3, 2);
        let s = root.clone();
        out.push(target("exr_depth", &root.join("depth/1.exr"), false, move || {
            open(&s).and_then(|q: Sequence| q.load_frame(1)).map(drop)
        }));
    }
    if want("ply_mesh") {
        let p = dir.join("mesh.ply");
        let mesh = Mesh {
            vertices: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            colours: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        };
        write_mesh_ply(&p, &mesh, "fuzz seed").unwrap();
        let q = p.clone();
        out.push(target("ply_mesh", &p, false, move || read_mesh_ply(&q).map(drop)));
    }
    out
}

/// Target names of the COLMAP files.
fn colmap_name(file: &str, binary: bool) -> &'static str {
    match (file, binary) {
        ("cameras", false) => "colmap_cameras_txt",
        ("images", false) => "colmap_images_txt",
        ("points3D", false) => "colmap_points3d_txt",
        ("cameras", true) => "colmap_cameras_bin",
        ("images", true) => "colmap_images_bin",
        _ => "colmap_points3d_bin",
    }
}

/// `root/images/*.png` (the base frames) and an `OPENCV` model in `root/sparse/0`: a point every 4th
/// pixel of each frame's depth, observed by that frame.
fn write_colmap(seq: &Sequence, base: &Path, root: &Path, binary: bool) {
    copy_dir(&base.join("images"), &root.join("images"));
    let (mut points, mut observations, mut images) = (Vec::new(), Vec::new(), Vec::new());
    for (i, info) in seq.frames.iter().enumerate() {
        let f = seq.load_frame(i).unwrap();
        let mut obs = Vec::new();
        for ((y, x), &z) in f.depth.as_ref().unwrap().indexed_iter() {
            if z > 0.0 && x % 4 == 0 && y % 4 == 0 {
                let c = seq.camera.backproject(x as f64, y as f64, 1.0 / f64::from(z));
                let w = f.pose * Point3::from(c);
                obs.push((x as f64, y as f64, points.len()));
                points.push([w.x, w.y, w.z]);
            }
        }
        observations.push(obs);
        let name = info.rgb.file_name().unwrap().to_string_lossy().into_owned();
        assert!(load_rgb(&root.join("images").join(&name)).is_ok());
        images.push((name, info.pose));
    }
    let distortion = RadTan { k1: 0.01, k2: -0.002, p1: 0.001, p2: 0.0005, k3: 0.0 };
    let camera = Camera { pinhole: seq.camera, distortion: Some(distortion) };
    let export = ColmapExport { model: CameraModel::Opencv, camera, images, points, observations };
    write_model(&root.join("sparse/0"), &export, binary).unwrap();
}
