//! Native 7-Scenes (`frame-XXXXXX.{color,depth}.png`, `.pose.txt`).

use std::path::Path;

use densefeat::geometry::PinholeCamera;
use densefeat::sequence::inspect::Summary;
use densefeat::sequence::sevenscenes_write::SevenScenesWriter;
use densefeat::sequence::{open, Format};

use crate::render::{
    assert_error, assert_same_geometry, assert_warp_matches_renderer, render, reprojection_difference,
    Rendered,
};

/// The 7-Scenes colour camera the reader assumes, and the depth camera, at 640x480.
fn cameras() -> (PinholeCamera, PinholeCamera) {
    (
        PinholeCamera::new(525.0, 525.0, 320.0, 240.0, 640, 480).unwrap(),
        PinholeCamera::new(585.0, 585.0, 320.0, 240.0, 640, 480).unwrap(),
    )
}

fn write(dir: &Path, colour: &Rendered, depth: &Rendered) {
    let mut w = SevenScenesWriter::create(dir).unwrap();
    for (c, d) in colour.frames.iter().zip(&depth.frames) {
        w.push(&c.0, &d.1, &c.2).unwrap();
    }
}

#[test]
fn seven_scenes_round_trip_colour_and_poses_depth_refused() {
    let (kc, kd) = cameras();
    let colour = render(640, 480, 3, Some(kc));
    let depth = render(640, 480, 3, Some(kd));
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &colour, &depth);
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::SevenScenes);
    assert!(seq.metric);
    assert_same_geometry(&seq, &colour);
    assert!(
        seq.frames.iter().all(|f| f.depth.is_none()),
        "depth is not registered to colour: none is exposed"
    );
    assert!(reprojection_difference(&seq, &colour, 0, 2) < crate::render::REPROJECTION_TOLERANCE_PX);
    assert_warp_matches_renderer(&seq, &colour, 0, 1, Some(&colour.frames[0].1));
    let text = Summary::new(&seq).unwrap().to_string();
    eprintln!("{text}");
    for part in [
        "format       7-Scenes (native layout)",
        "camera       fx 525 fy 525 cx 320 cy 240",
        "not registered",
    ] {
        assert!(text.contains(part), "inspect output lacks {part:?}");
    }
}

#[test]
fn seven_scenes_malformed_pose_files_name_file_and_line() {
    let (kc, _) = cameras();
    let small = PinholeCamera::new(kc.fx / 8.0, kc.fy / 8.0, 40.0, 30.0, 80, 60).unwrap();
    let r = render(80, 60, 2, Some(small));
    let fresh = || {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), &r, &r);
        d
    };
    let pose = |d: &Path| d.join("frame-000001.pose.txt");
    let d = fresh();
    let p = pose(d.path());
    let text = std::fs::read_to_string(&p).unwrap();
    std::fs::write(&p, text.replacen('\t', "\tabc", 1)).unwrap();
    assert_error(open(d.path()), &["frame-000001.pose.txt:1:", "\"abc"]);
    let d = fresh();
    let p = pose(d.path());
    let lines: Vec<&str> = text.lines().collect();
    std::fs::write(&p, lines[..3].join("\n")).unwrap();
    assert_error(open(d.path()), &["frame-000001.pose.txt", "found 3 lines"]);
    let d = fresh();
    let p = pose(d.path());
    std::fs::write(&p, format!("{}\n{}\n{}\n1 1 1 1\n", lines[0], lines[1], lines[2])).unwrap();
    assert_error(open(d.path()), &["frame-000001.pose.txt:1:", "last row"]);
    let d = fresh();
    std::fs::remove_file(pose(d.path())).unwrap();
    assert_error(open(d.path()), &["frame-000001.color.png has no pose file"]);
}
