//! TSDF fusion, mesh extraction, PLY and mesh metrics (SPEC.md §16).

use crate::common;
use densefeat::fusion::grid::{Aabb, VoxelGrid};
use densefeat::fusion::metrics::{nearest_distances, KdTree};
use densefeat::fusion::ply::{read_mesh_ply, write_mesh_ply};
use densefeat::fusion::reference::integrate_reference;
use densefeat::fusion::{extract_mesh, mesh_metrics, remove_small_components, DepthObservation, Mesh, Tsdf};
use densefeat::geometry::{PinholeCamera, Pose};
use densefeat::runtime::thread_pool;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use ndarray::{Array2, Array3};
use proptest::prelude::*;

fn camera() -> PinholeCamera {
    PinholeCamera::new(120.0, 120.0, 63.5, 47.5, 128, 96).unwrap()
}

/// `T_wc` of a camera at `eye` looking at `target` (camera y down, roughly along `-up`).
fn look_at(eye: Vector3<f64>, target: Vector3<f64>, up: Vector3<f64>) -> Pose {
    let z = (target - eye).normalize();
    let x = z.cross(&-up).try_normalize(1e-9).unwrap_or_else(|| z.cross(&Vector3::x()).normalize());
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(Translation3::from(eye), UnitQuaternion::from_rotation_matrix(&r))
}

/// Depth map of the first ray hit `hit(origin, direction) -> t` (direction with unit camera z, so
/// `t` is the depth); 0 where nothing is hit.
fn render_depth(
    cam: &PinholeCamera,
    pose: &Pose,
    hit: impl Fn(Vector3<f64>, Vector3<f64>) -> Option<f64>,
) -> Array2<f32> {
    Array2::from_shape_fn((cam.height, cam.width), |(v, u)| {
        let d = pose.rotation * cam.ray(u as f64, v as f64);
        hit(pose.translation.vector, d).map_or(0.0, |t| t as f32)
    })
}

/// Ray against the axis-aligned box `[-h, h]^3` (slab method), entry distance.
fn hit_box(h: f64) -> impl Fn(Vector3<f64>, Vector3<f64>) -> Option<f64> {
    move |o, d| {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            let (a0, a1) = ((-h - o[a]) / d[a], (h - o[a]) / d[a]);
            t0 = t0.max(a0.min(a1));
            t1 = t1.min(a0.max(a1));
        }
        (t0 <= t1 && t0 > 0.0).then_some(t0)
    }
}

/// Distance from `p` to the surface of the box `[-h, h]^3`.
fn box_distance(p: [f32; 3], h: f64) -> f64 {
    let q = p.map(|v| (v as f64).abs() - h);
    let outside = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
    outside + q.iter().cloned().fold(f64::NEG_INFINITY, f64::max).min(0.0).abs()
}

const BOX_HALF: f64 = 0.3;
const BOX_VOXEL: f64 = 0.02;

/// Cameras on two rings around the box and one above and below it.
fn box_views() -> Vec<(Pose, Array2<f32>)> {
    let mut eyes = Vec::new();
    for ring in [-0.6f64, 0.6] {
        for i in 0..8 {
            let a = i as f64 * std::f64::consts::TAU / 8.0 + ring;
            eyes.push(Vector3::new(1.6 * a.cos(), ring * 1.5, 1.6 * a.sin()));
        }
    }
    eyes.push(Vector3::new(0.1, 1.7, 0.05));
    eyes.push(Vector3::new(-0.05, -1.7, 0.1));
    eyes.into_iter()
        .map(|e| {
            let pose = look_at(e, Vector3::zeros(), Vector3::y());
            (pose, render_depth(&camera(), &pose, hit_box(BOX_HALF)))
        })
        .collect()
}

fn fuse(
    grid: VoxelGrid,
    truncation: f64,
    views: &[(Pose, Array2<f32>)],
    colour: Option<&Array3<f32>>,
) -> Tsdf {
    let mut v = Tsdf::new(grid, truncation).unwrap();
    for (pose, depth) in views {
        let obs = DepthObservation {
            depth: depth.view(),
            weight: None,
            colour: colour.map(|c| c.view()),
            camera: camera(),
            pose: *pose,
        };
        v.integrate(&obs).unwrap();
    }
    v
}

fn box_grid() -> VoxelGrid {
    let b = Aabb { min: [-0.45; 3], max: [0.45; 3] };
    VoxelGrid::covering(&b, BOX_VOXEL).unwrap()
}

fn box_volume() -> Tsdf {
    fuse(box_grid(), 4.0 * BOX_VOXEL, &box_views(), None)
}

/// A closed box seen from all sides is recovered as a closed mesh within the stated error
/// (SPEC.md §16.7).
#[test]
fn fused_box_is_closed_and_within_error() {
    let mesh = extract_mesh(&box_volume());
    assert!(mesh.triangles.len() > 1000, "{} triangles", mesh.triangles.len());
    let e = mesh.edge_report();
    assert_eq!(e.boundary, 0, "{e:?}");
    let mut d: Vec<f64> = mesh.vertices.iter().map(|&p| box_distance(p, BOX_HALF)).collect();
    let (max, mean) = (d.iter().cloned().fold(0.0, f64::max), d.iter().sum::<f64>() / d.len() as f64);
    d.sort_by(f64::total_cmp);
    let q = |f: f64| d[((d.len() - 1) as f64 * f) as usize];
    println!(
        "box: {} vertices, median {:.5} p90 {:.5} p95 {:.5} p99 {:.5} max {max:.5} m, mean {mean:.5} m, {e:?}",
        d.len(), q(0.5), q(0.9), q(0.95), q(0.99)
    );
    // Away from the box's edges (no two coordinates within 2 voxels of the faces).
    let interior: Vec<f64> = mesh
        .vertices
        .iter()
        .filter(|p| p.iter().filter(|v| (v.abs() as f64) > BOX_HALF - 2.0 * BOX_VOXEL).count() <= 1)
        .map(|&p| box_distance(p, BOX_HALF))
        .collect();
    let imax = interior.iter().cloned().fold(0.0, f64::max);
    let imean = interior.iter().sum::<f64>() / interior.len() as f64;
    println!("box faces: {} vertices, max {imax:.5} m, mean {imean:.5} m", interior.len());
    // Budgets (SPEC.md §16.7): on the faces, nearest-pixel depth at grazing views; near the edges,
    // surface nets round the corner and projective distances of occluded voxels ("shadows") reach
    // at most the truncation.
    assert!(imean <= 0.15 * BOX_VOXEL && imax <= BOX_VOXEL, "faces: mean {imean}, max {imax}");
    assert!(q(0.5) <= 0.15 * BOX_VOXEL, "median {}", q(0.5));
    assert!(mean <= 0.5 * BOX_VOXEL, "mean {mean}");
    assert!(max <= 4.0 * BOX_VOXEL, "max {max}");
    // Normals point out of the box (toward free space and the cameras): 13411 of 13650 measured.
    let outward = (0..mesh.triangles.len())
        .filter(|&t| {
            let n = mesh.triangle_normal(t);
            let c = mesh.triangles[t].map(|i| mesh.vertices[i as usize]);
            let centre: Vec<f64> = (0..3).map(|a| c.iter().map(|p| p[a] as f64).sum::<f64>() / 3.0).collect();
            n[0] * centre[0] + n[1] * centre[1] + n[2] * centre[2] > 0.0
        })
        .count();
    // All but the folds of the edge artefacts.
    assert!(outward as f64 >= 0.97 * mesh.triangles.len() as f64, "{outward} of {}", mesh.triangles.len());
}

/// A tilted plane seen by a few cameras: vertices within the stated error of the plane, normals
/// toward the cameras, an open mesh whose boundary edges are reported.
#[test]
fn fused_plane_is_within_error_and_open() {
    let n = Vector3::new(0.0, -0.5, -1.0).normalize(); // tilted ~27 degrees, facing the cameras
    let p0 = Vector3::new(0.0, 0.0, 2.0);
    let hit = move |o: Vector3<f64>, d: Vector3<f64>| {
        let t = (p0 - o).dot(&n) / d.dot(&n);
        (t > 0.0).then_some(t)
    };
    let views: Vec<(Pose, Array2<f32>)> = [-0.2, 0.0, 0.2]
        .iter()
        .map(|&x| {
            let pose = look_at(Vector3::new(x, 0.0, 0.0), Vector3::new(x, 0.0, 1.0), -Vector3::y());
            (pose, render_depth(&camera(), &pose, hit))
        })
        .collect();
    let voxel = 0.02;
    let grid = VoxelGrid::covering(&Aabb { min: [-0.8, -0.6, 1.2], max: [0.8, 0.6, 2.8] }, voxel).unwrap();
    let mesh = extract_mesh(&fuse(grid, 4.0 * voxel, &views, None));
    assert!(mesh.triangles.len() > 1000);
    let d: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|v| (Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64) - p0).dot(&n).abs())
        .collect();
    let (max, mean) = (d.iter().cloned().fold(0.0, f64::max), d.iter().sum::<f64>() / d.len() as f64);
    let e = mesh.edge_report();
    println!("plane: {} vertices, max {max:.5} m, mean {mean:.5} m, {e:?}", d.len());
    // Nearest-pixel depth on a plane tilted by θ errs by up to half a pixel footprint times tan θ:
    // 0.5 · (2.6 m / 120 px) · 0.5 = 5.4 mm at the far edge (SPEC.md §16.7).
    assert!(max <= 0.27 * voxel, "max {max}");
    assert!(mean <= 0.1 * voxel, "mean {mean}");
    assert!(e.boundary > 0, "an open plane has a boundary");
    for t in 0..mesh.triangles.len() {
        let tn = mesh.triangle_normal(t);
        assert!(tn[0] * n.x + tn[1] * n.y + tn[2] * n.z > 0.9, "triangle {t} normal {tn:?}");
    }
}

fn bits(v: &Tsdf) -> (Vec<u32>, Vec<u32>, Vec<[u32; 3]>) {
    (
        v.tsdf.iter().map(|x| x.to_bits()).collect(),
        v.weight.iter().map(|x| x.to_bits()).collect(),
        v.colour.iter().map(|c| c.map(f32::to_bits)).collect(),
    )
}

#[test]
fn tsdf_output_independent_of_thread_count() {
    let views = box_views();
    let colour = Array3::from_shape_fn((96, 128, 3), |(y, x, c)| ((x * 7 + y * 3 + c * 50) % 256) as f32);
    let run = |n: usize| {
        thread_pool(n).unwrap().install(|| {
            let v = fuse(box_grid(), 4.0 * BOX_VOXEL, &views, Some(&colour));
            let m = extract_mesh(&v);
            (bits(&v), m)
        })
    };
    let one = run(1);
    for n in [2, 3, 8] {
        let other = run(n);
        assert!(other.0 == one.0, "volume differs at {n} threads");
        assert!(other.1 == one.1, "mesh differs at {n} threads");
    }
}

/// A random scene for the oracle test: a few cameras looking at a random plane, random
/// confidence weights and colours.
#[derive(Debug, Clone)]
struct Scene {
    seed: u64,
    views: usize,
    voxel: f64,
    truncation_voxels: f64,
}

fn lcg(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]
    /// The fast integration against the naive f64 reference (SPEC.md §16.2): the observed voxels
    /// are the same (the gathers are bit-exact); T, W and colour within `4 n ε`, `n ε W` and
    /// `4 n ε 255` for `n` observations.
    #[test]
    fn tsdf_matches_reference(scene in (any::<u64>(), 1usize..5, 0.03f64..0.1, 1.5f64..6.0)
        .prop_map(|(seed, views, voxel, truncation_voxels)| Scene { seed, views, voxel, truncation_voxels })) {
        let mut s = scene.seed;
        let n = Vector3::new(lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, -1.0).normalize();
        let p0 = Vector3::new(0.0, 0.0, 1.5 + lcg(&mut s));
        let hit = move |o: Vector3<f64>, d: Vector3<f64>| {
            let t = (p0 - o).dot(&n) / d.dot(&n);
            (t > 0.0).then_some(t)
        };
        let cam = camera();
        let mut maps = Vec::new();
        for _ in 0..scene.views {
            let eye = Vector3::new(lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) * 0.3);
            let pose = look_at(eye, p0, -Vector3::y());
            let depth = render_depth(&cam, &pose, hit);
            let weight = Array2::from_shape_fn(depth.dim(), |_| lcg(&mut s) as f32);
            let colour = Array3::from_shape_fn((cam.height, cam.width, 3), |_| (lcg(&mut s) * 255.0) as f32);
            maps.push((pose, depth, weight, colour));
        }
        let obs: Vec<DepthObservation> = maps
            .iter()
            .map(|(pose, d, w, c)| DepthObservation {
                depth: d.view(), weight: Some(w.view()), colour: Some(c.view()), camera: cam, pose: *pose,
            })
            .collect();
        let grid = VoxelGrid::covering(&Aabb { min: [-0.7, -0.7, 1.0], max: [0.7, 0.7, 3.0] }, scene.voxel).unwrap();
        let mu = scene.truncation_voxels * scene.voxel;
        let mut fast = Tsdf::new(grid, mu).unwrap();
        for o in &obs {
            fast.integrate(o).unwrap();
        }
        let oracle = integrate_reference(&grid, mu, &obs).unwrap();
        let eps = f32::EPSILON as f64 * obs.len() as f64;
        let mut observed = 0;
        for i in 0..grid.len() {
            prop_assert_eq!(fast.weight[i] > 0.0, oracle.weight[i] > 0.0, "voxel {} observed differently", i);
            if oracle.weight[i] == 0.0 {
                continue;
            }
            observed += 1;
            let dt = (fast.tsdf[i] as f64 - oracle.tsdf[i]).abs();
            prop_assert!(dt <= 4.0 * eps, "T at {}: {} vs {} (budget {})", i, fast.tsdf[i], oracle.tsdf[i], 4.0 * eps);
            let dw = (fast.weight[i] as f64 - oracle.weight[i]).abs();
            prop_assert!(dw <= eps * oracle.weight[i], "W at {}: {} vs {}", i, fast.weight[i], oracle.weight[i]);
            for a in 0..3 {
                let dc = (fast.colour[i][a] as f64 - oracle.colour[i][a]).abs();
                prop_assert!(dc <= 4.0 * eps * 255.0, "colour at {}: {} vs {}", i, fast.colour[i][a], oracle.colour[i][a]);
            }
        }
        prop_assert!(observed > 0);
    }
}

#[test]
fn mesh_ply_round_trip_and_boundary_edges() {
    let mesh = extract_mesh(&box_volume());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("box.ply");
    write_mesh_ply(&path, &mesh, "densefeat test box").unwrap();
    let back = read_mesh_ply(&path).unwrap();
    assert_eq!(back, mesh);
    assert_eq!(back.edge_report().boundary, 0, "watertight");
    // Drop one triangle: its three edges become boundary edges.
    let mut open = back.clone();
    open.triangles.pop();
    assert_eq!(open.edge_report().boundary, 3);
    // The header a viewer reads.
    let bytes = std::fs::read(&path).unwrap();
    let header = String::from_utf8_lossy(&bytes[..400]);
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(header.contains(&format!("element face {}", mesh.triangles.len())));
    // Truncated or foreign files are errors naming the file.
    std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
    let err = read_mesh_ply(&path).unwrap_err().to_string();
    assert!(err.contains("box.ply"), "{err}");
}

#[test]
fn kd_tree_matches_brute_force() {
    let mut s = 3u64;
    let pts: Vec<[f64; 3]> = (0..2000).map(|_| [lcg(&mut s), lcg(&mut s), lcg(&mut s) * 0.1]).collect();
    let queries: Vec<[f64; 3]> =
        (0..300).map(|_| [lcg(&mut s) * 2.0 - 0.5, lcg(&mut s), lcg(&mut s)]).collect();
    let fast = nearest_distances(&queries, &pts);
    for (q, d) in queries.iter().zip(&fast) {
        let brute = pts
            .iter()
            .map(|p| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt())
            .fold(f64::INFINITY, f64::min);
        assert_eq!(*d, brute);
    }
    assert_eq!(KdTree::new(&[]).nearest_distance([0.0; 3]), f64::INFINITY);
}

#[test]
fn mesh_metrics_of_shifted_meshes() {
    let mesh = extract_mesh(&box_volume());
    let same = mesh_metrics(&mesh, &mesh, 0.05);
    assert_eq!((same.accuracy, same.completeness, same.fscore), (0.0, 0.0, 1.0));
    let shift = |m: &Mesh, dz: f32| Mesh {
        vertices: m.vertices.iter().map(|v| [v[0], v[1], v[2] + dz]).collect(),
        ..m.clone()
    };
    let near = mesh_metrics(&shift(&mesh, 0.01), &mesh, 0.05);
    assert!(near.accuracy <= 0.0101 && near.fscore == 1.0, "{near:?}");
    let far = mesh_metrics(&shift(&mesh, 2.0), &mesh, 0.05);
    assert_eq!((far.precision, far.recall, far.fscore), (0.0, 0.0, 0.0));
    let empty = mesh_metrics(&Mesh::default(), &mesh, 0.05);
    assert_eq!((empty.precision, empty.recall, empty.fscore), (0.0, 0.0, 0.0));
    // The 2 / 5 / 10 cm scores: a 3 cm vertical shift moves the box's top and bottom out of 2 cm
    // (its sides stay within it) and everything within 5 and 10 cm; the 5 cm entry is the main
    // threshold's when that is 5 cm.
    let mid = mesh_metrics(&shift(&mesh, 0.03), &mesh, 0.05);
    let th: Vec<f64> = mid.standard.iter().map(|t| t.threshold).collect();
    assert_eq!(th, vec![0.02, 0.05, 0.10]);
    assert!(mid.standard[0].fscore > 0.1 && mid.standard[0].fscore < 0.9, "{mid:?}");
    assert_eq!((mid.standard[1].fscore, mid.standard[2].fscore), (1.0, 1.0), "{mid:?}");
    assert_eq!((mid.standard[1].precision, mid.standard[1].recall), (mid.precision, mid.recall));
    let other = mesh_metrics(&shift(&mesh, 0.03), &mesh, 0.02);
    assert_eq!((other.fscore, other.standard), (mid.standard[0].fscore, mid.standard));
}

#[test]
fn small_components_are_removed_and_the_rest_kept_in_order() {
    let boxm = extract_mesh(&box_volume());
    // The box, then a floating blob of two triangles (4 vertices) far from it, then a single
    // triangle sharing no vertex with either.
    let mut m = boxm.clone();
    let base = m.vertices.len() as u32;
    m.vertices.extend([[5.0, 5.0, 5.0], [5.1, 5.0, 5.0], [5.0, 5.1, 5.0], [5.1, 5.1, 5.0]]);
    m.colours.extend([[1, 2, 3]; 4]);
    m.triangles.extend([[base, base + 1, base + 2], [base + 1, base + 3, base + 2]]);
    m.vertices.extend([[-5.0, 0.0, 0.0], [-5.1, 0.0, 0.0], [-5.0, 0.1, 0.0]]);
    m.colours.extend([[9, 9, 9]; 3]);
    m.triangles.push([base + 4, base + 5, base + 6]);
    let box_triangles = boxm.triangles.len();
    assert!(box_triangles > 100);
    // Off (0 or 1), and a threshold no piece is below: unchanged.
    for min in [0, 1] {
        let (same, r) = remove_small_components(&m, min);
        assert_eq!(
            (same.vertices.len(), same.triangles.len(), r.removed_triangles),
            (m.vertices.len(), m.triangles.len(), 0)
        );
    }
    // Below 2 triangles: only the single triangle goes.
    let (two, r) = remove_small_components(&m, 2);
    assert_eq!((r.removed_components, r.removed_triangles), (1, 1));
    assert_eq!(two.triangles.len(), box_triangles + 2);
    // Below 3: both pieces go, and what is left is the box exactly (vertices, colours, triangles).
    let (only_box, r) = remove_small_components(&m, 3);
    assert_eq!((r.removed_components, r.removed_triangles), (2, 3));
    assert_eq!(r.components, remove_small_components(&boxm, 0).1.components + 2);
    assert_eq!(only_box.vertices, boxm.vertices);
    assert_eq!(only_box.colours, boxm.colours);
    assert_eq!(only_box.triangles, boxm.triangles);
}

// ---------------------------------------------------------------------------------------------
// `densefeat map` on a tiny slice of the shipped fixture (RGB features, few bins, level 1).

fn map_cmd(out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    let mut args = vec![
        "map",
        "--sequence",
        fixture,
        "--frames",
        "0:11",
        "--features",
        "rgb",
        "--bins",
        "16",
        "--level",
        "1",
        "--window",
        "3,3",
        "--iterations",
        "30",
        "--max-iterations",
        "30",
        "--kf-baseline",
        "0.05",
        "--voxel-size",
        "0.1",
    ];
    args.extend_from_slice(extra);
    std::process::Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(&args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn map_feature_cache_changes_no_bits() {
    // SPEC.md §16.12: the cache only saves extractions; depth, pictures and meshes are the same bytes.
    let dir = tempfile::tempdir().unwrap();
    let (cached, fresh) = (dir.path().join("cached"), dir.path().join("fresh"));
    let a = map_cmd(&cached, &[]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let b = map_cmd(&fresh, &["--feature-cache-mb", "0"]);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let doc = |d: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("map.json")).unwrap()).unwrap()
    };
    let (da, db) = (doc(&cached), doc(&fresh));
    assert!(da["feature_cache"]["hits"].as_u64().unwrap() > 0, "{}", da["feature_cache"]);
    assert_eq!(db["feature_cache"]["hits"].as_u64(), Some(0), "{}", db["feature_cache"]);
    // The same frames are looked at either way.
    let total = |d: &serde_json::Value| {
        d["feature_cache"]["hits"].as_u64().unwrap() + d["feature_cache"]["misses"].as_u64().unwrap()
    };
    assert_eq!(total(&da), total(&db));
    assert_eq!(da["metrics"], db["metrics"]);
    // Every file but the JSON reports (which hold timings).
    let output_files = |d: &std::path::Path| {
        let mut f = common::files(d);
        f.retain(|name, _| !name.ends_with(".json"));
        f
    };
    let (fa, fb) = (output_files(&cached), output_files(&fresh));
    assert!(fa.len() > 10, "{:?}", fa.keys());
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (name, bytes) in &fa {
        assert!(bytes == &fb[name], "{name} differs");
    }
}

#[test]
fn map_writes_mesh_metrics_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map");
    let first = map_cmd(&out, &[]);
    let text = String::from_utf8_lossy(&first.stdout).to_string();
    assert!(first.status.success(), "{text}\n{}", String::from_utf8_lossy(&first.stderr));
    assert!(text.contains("F-score"), "{text}");
    assert!(text.contains("confident keyframe pixels kept"), "the filter's share is reported: {text}");
    let mesh = read_mesh_ply(&out.join("mesh.ply")).unwrap();
    assert!(!mesh.triangles.is_empty());
    let gt = read_mesh_ply(&out.join("mesh_gt.ply")).unwrap();
    assert!(!gt.triangles.is_empty());
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
    let f = doc["metrics"]["fscore"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&f), "{f}");
    // RGB keeps its depth λ in `map` (SPEC.md §16.9); map.json records it.
    assert_eq!(doc["mapping"]["lambda"].as_f64(), Some(densefeat::mapping::features::LAMBDA_RGB), "{doc}");
    assert_eq!(doc["mesh"]["edges"]["boundary"].as_u64().unwrap() as usize, mesh.edge_report().boundary);
    let keys: Vec<u64> =
        doc["keyframes"].as_array().unwrap().iter().map(|k| k["index"].as_u64().unwrap()).collect();
    assert!(keys.len() >= 2, "{keys:?}");
    assert!(out.join("mesh.png").is_file());
    // The fusion's upper bound: the ground-truth depth through the estimate's fusion (SPEC.md §16.5).
    let bound = doc["metrics_gt_depth"]["fscore"].as_f64().unwrap();
    assert!(bound > f && bound <= 1.0, "bound {bound}, estimate {f}");
    // The parallax report (SPEC.md §16.11): one angle per keyframe and their median (this test's
    // ±3-frame windows see the room under less than a degree; `map`'s ±30 see it under 1.4-6.8°).
    let mut angles: Vec<f64> = doc["triangulation_deg"]["per_keyframe"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_f64().unwrap())
        .collect();
    assert_eq!(angles.len(), keys.len(), "{doc}");
    assert!(angles.iter().all(|&a| a > 0.1 && a < 10.0), "{angles:?}");
    angles.sort_by(f64::total_cmp);
    assert_eq!(doc["triangulation_deg"]["median"].as_f64(), Some(angles[(angles.len() - 1) / 2]), "{doc}");
    // `map` refines its keyframes photometrically by default (SPEC.md §10.3, §16.9) and says so.
    assert_eq!(doc["mapping"]["refine"]["samples"].as_u64(), Some(17), "{doc}");
    let kf = out.join(format!("keyframes/kf_{:05}/keyframe.json", keys[1]));
    let kdoc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&kf).unwrap()).unwrap();
    let refined = &kdoc["refined"];
    assert!(refined["candidates"].as_u64().unwrap() > 0, "{kdoc}");
    assert!(refined["refined"].as_u64().unwrap() <= refined["candidates"].as_u64().unwrap(), "{kdoc}");
    let stamp = std::fs::metadata(&kf).unwrap().modified().unwrap();

    // A re-run reuses every keyframe and reproduces the mesh bit for bit.
    let second = map_cmd(&out, &[]);
    let text = String::from_utf8_lossy(&second.stdout).to_string();
    assert!(second.status.success(), "{text}");
    assert!(text.contains("0 computed") && text.contains(&format!("{} reused", keys.len())), "{text}");
    assert_eq!(std::fs::metadata(&kf).unwrap().modified().unwrap(), stamp);
    assert_eq!(read_mesh_ply(&out.join("mesh.ply")).unwrap(), mesh);
    // The estimate's truncation defaults to 8 voxels; the ground truth keeps 4 whatever
    // `--truncation` says (SPEC.md §16.5, §16.9). With a truncation of at most 4 voxels the grid is
    // the same, so the ground-truth mesh is the same bit for bit while the estimate's changes.
    let voxel = doc["fusion"]["voxel_m"].as_f64().unwrap();
    assert_eq!(doc["fusion"]["truncation_m"].as_f64(), Some(8.0 * voxel), "{doc}");
    assert_eq!(doc["fusion"]["gt_truncation_m"].as_f64(), Some(4.0 * voxel), "{doc}");
    let narrow = [format!("{}", 4.0 * voxel), format!("{}", 2.0 * voxel)];
    let mut gts = Vec::new();
    let mut ests = Vec::new();
    for t in &narrow {
        let run = map_cmd(&out, &["--truncation", t]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        gts.push(read_mesh_ply(&out.join("mesh_gt.ply")).unwrap());
        ests.push(read_mesh_ply(&out.join("mesh.ply")).unwrap());
    }
    assert_eq!(gts[0], gts[1], "the ground truth does not move with --truncation");
    assert_ne!(ests[0], ests[1], "the estimate does");

    // A changed mapping setting recomputes the keyframes.
    let third = map_cmd(&out, &["--min-evidence", "0.3"]);
    let text = String::from_utf8_lossy(&third.stdout).to_string();
    assert!(third.status.success() && text.contains(&format!("{} computed", keys.len())), "{text}");
    // So does turning the refinement off; map.json then records none.
    let fourth = map_cmd(&out, &["--min-evidence", "0.3", "--refine", "off"]);
    let text = String::from_utf8_lossy(&fourth.stdout).to_string();
    assert!(fourth.status.success() && text.contains(&format!("{} computed", keys.len())), "{text}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
    assert!(doc["mapping"]["refine"].is_null(), "{doc}");
    let bad = map_cmd(&out, &["--refine", "maybe"]);
    assert!(!bad.status.success());
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("--refine"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    // The refinement's variance floor is recorded, is part of the keyframes' fingerprint, and
    // needs the refinement on; a negative floor is refused naming the flag.
    let fifth = map_cmd(&out, &["--min-evidence", "0.3", "--refine-min-variance", "2.5"]);
    let text = String::from_utf8_lossy(&fifth.stdout).to_string();
    assert!(fifth.status.success() && text.contains(&format!("{} computed", keys.len())), "{text}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
    assert_eq!(doc["mapping"]["refine"]["min_variance"], 2.5, "{doc}");
    for (flags, says) in [
        (&["--refine-min-variance=-1"][..], "expected a number >= 0"),
        (&["--refine-min-variance", "NaN"][..], "expected a number >= 0"),
        (&["--refine-min-variance", "4", "--refine", "off"][..], "needs --refine on"),
    ] {
        let bad = map_cmd(&out, flags);
        let err = String::from_utf8_lossy(&bad.stderr).to_string();
        assert!(
            !bad.status.success() && err.contains("--refine-min-variance") && err.contains(says),
            "{err}"
        );
    }
    // TGV (SPEC.md §10.4): its β is recorded and part of the fingerprint; each keyframe's estimate
    // is `depth_tgv.pfm`.
    for (beta, computed) in [("4", true), ("4", false), ("8", true)] {
        let run = map_cmd(&out, &["--min-evidence", "0.3", "--regularizer", "tgv", "--tgv-beta", beta]);
        let text = String::from_utf8_lossy(&run.stdout).to_string();
        let all = format!("{} computed", keys.len());
        assert!(run.status.success() && text.contains(&all) == computed, "β {beta}: {text}");
        let doc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
        assert_eq!(doc["mapping"]["tgv_beta"], beta.parse::<f64>().unwrap(), "{doc}");
    }
    assert!(std::fs::read_dir(out.join("keyframes")).unwrap().all(|k| k
        .unwrap()
        .path()
        .join("depth_tgv.pfm")
        .exists()));
}

#[test]
fn map_smooths_the_learned_features_less_than_the_depth_commands() {
    // SPEC.md §16.9: λ 10 for the learned features by default, chosen by mesh F-score on
    // validation; `--lambda` still sets it.
    let dir = tempfile::tempdir().unwrap();
    for (extra, lambda) in
        [(&[][..], densefeat::mapping::sequence_map::MAP_LAMBDA_LEARNED), (&["--lambda", "30"][..], 30.0)]
    {
        let out = dir.path().join(format!("map_{lambda}"));
        let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["map", "--sequence", fixture, "--frames", "0:5", "--bins", "16", "--window", "2,2"])
            .args([
                "--iterations",
                "10",
                "--max-iterations",
                "10",
                "--kf-baseline",
                "0.05",
                "--voxel-size",
                "0.1",
            ])
            .args(extra)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let doc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
        assert_eq!(doc["mapping"]["lambda"].as_f64(), Some(lambda), "{extra:?}");
    }
}

#[test]
fn map_rejects_bad_flags_before_writing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map");
    for (extra, flag) in [
        (&["--voxel-size", "0"][..], "--voxel-size"),
        (&["--truncation", "0.01"][..], "--truncation"),
        (&["--frames", "5:3"][..], "--frames"),
        (&["--frames", "0:999"][..], "--frames"),
        (&["--kf-overlap", "1.5"][..], "--kf-overlap"),
        (&["--max-memory-mb", "1"][..], "--max-memory-mb"),
    ] {
        let o = map_cmd(&out, extra);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(err.contains(flag), "{extra:?}: {err}");
        assert!(!out.exists(), "{extra:?} wrote {}", out.display());
    }
}
