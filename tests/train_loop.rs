//! The trainer (SPEC.md §13.6) on a tiny configuration: bit-identical weights for 1 and 2
//! threads, resume to exactly the uninterrupted result, checkpoint round trip and rejection, and
//! the run's outputs (CSV, plot, weights loadable by the network).

use std::path::Path;

use densefeat::backend::CpuBackend;
use densefeat::geometry::InverseDepthBins;
use densefeat::nn::{FeatureNet, NetworkWeights};
use densefeat::ops::NetworkConfig;
use densefeat::train::checkpoint::Checkpoint;
use densefeat::train::data::DataConfig;
use densefeat::train::loss::LossConfig;
use densefeat::train::optim::OptimConfig;
use densefeat::train::step::Supervision;
use densefeat::train::trainer::{train, TrainConfig};

pub(crate) fn tiny() -> TrainConfig {
    TrainConfig {
        network: NetworkConfig { blocks: 2, channels: 4, b1_stride: 2, input_mean: [110.0; 3] },
        init_seed: 3,
        seed: 4,
        steps: 4,
        batch: 2,
        optim: OptimConfig { warmup: 1, ..OptimConfig::default() },
        loss: LossConfig { bins: InverseDepthBins::new(0.0, 4.0, 16).unwrap(), ..LossConfig::default() },
        supervision: Supervision::default(),
        data: DataConfig {
            crop: (48, 32),
            synthetic_scenes: 2,
            synthetic_val_scenes: 1,
            ..DataConfig::default()
        },
        val_every: 2,
        val_per_source: 1,
        ckpt_every: 2,
        frame_cache_mb: 64,
        init_weights: None,
    }
}

fn run(
    cfg: &TrainConfig,
    out: &Path,
    threads: usize,
    resume: Option<&Path>,
    stop: Option<usize>,
) -> NetworkWeights {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| train(cfg, out, resume, stop, &mut densefeat::progress::Silent)).unwrap()
}

fn bits(w: &NetworkWeights) -> Vec<u32> {
    w.layers()
        .iter()
        .flat_map(|l| l.weight.iter().chain(l.bias.iter()).map(|v| v.to_bits()).collect::<Vec<_>>())
        .collect()
}

#[test]
fn one_two_three_and_eight_threads_give_bit_identical_weights() {
    let cfg = tiny();
    let a = tempfile::tempdir().unwrap();
    let w1 = run(&cfg, a.path(), 1, None, None);
    // The pairs of a batch, the images of a pair and each kernel all run at once (SPEC.md §13.6).
    for threads in [2, 3, 8] {
        let b = tempfile::tempdir().unwrap();
        let wn = run(&cfg, b.path(), threads, None, None);
        assert_eq!(bits(&w1), bits(&wn), "{threads} threads");
    }
    // Training moved the weights away from the initialisation.
    let init = densefeat::train::trainer::training_init(&cfg.network, cfg.init_seed).unwrap();
    assert_ne!(bits(&w1), bits(&init));
    // The outputs exist and the weights file loads into the network.
    for f in ["checkpoint.safetensors", "weights.safetensors", "log.csv", "curves.png"] {
        assert!(a.path().join(f).is_file(), "{f} missing");
    }
    let csv = std::fs::read_to_string(a.path().join("log.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + cfg.steps, "{csv}");
    assert!(
        csv.lines().nth(2).unwrap().split(',').nth(11).is_some_and(|v| v.parse::<f64>().is_ok()),
        "validation at step 2"
    );
    let loaded = NetworkWeights::load(&a.path().join("weights.safetensors")).unwrap();
    assert_eq!(bits(&loaded), bits(&w1));
    let img = ndarray::Array3::<f32>::from_elem((32, 48, 3), 100.0);
    FeatureNet::new(loaded).unwrap().forward(img.view(), &CpuBackend::default()).unwrap();
}

#[test]
fn resuming_gives_exactly_the_uninterrupted_run() {
    let cfg = tiny();
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let straight = run(&cfg, a.path(), 2, None, None);
    run(&cfg, b.path(), 2, None, Some(2));
    let ck = Checkpoint::load(&b.path().join("checkpoint.safetensors")).unwrap();
    assert_eq!((ck.step, ck.adam.step), (2, 2));
    let resumed = run(&cfg, b.path(), 1, Some(&b.path().join("checkpoint.safetensors")), None);
    assert_eq!(bits(&straight), bits(&resumed));
    let (ca, cb) = (
        Checkpoint::load(&a.path().join("checkpoint.safetensors")).unwrap(),
        Checkpoint::load(&b.path().join("checkpoint.safetensors")).unwrap(),
    );
    assert_eq!(ca, cb, "weights, optimiser state and step all equal");
    // The CSV has one row per step, no duplicates after the resume.
    let csv = std::fs::read_to_string(b.path().join("log.csv")).unwrap();
    let steps: Vec<usize> =
        csv.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect();
    assert_eq!(steps, vec![1, 2, 3, 4]);
}

#[test]
fn a_checkpoint_is_written_to_the_same_bytes_every_time() {
    // Sorted metadata (SPEC.md §8.4's layout): two saves of one checkpoint, in one process or in
    // two runs, are byte-identical (a HashMap's order differs between maps and processes).
    let d = tempfile::tempdir().unwrap();
    run(&tiny(), d.path(), 1, None, Some(2));
    let ck = Checkpoint::load(&d.path().join("checkpoint.safetensors")).unwrap();
    let (a, b) = (d.path().join("a.safetensors"), d.path().join("b.safetensors"));
    for _ in 0..3 {
        ck.save(&a).unwrap();
        ck.save(&b).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    }
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(d.path().join("checkpoint.safetensors")).unwrap());
    assert_eq!(Checkpoint::load(&a).unwrap(), ck);
}

/// What the trainer tells its [`densefeat::progress::Progress`] (the CLI draws its bar from this).
#[derive(Default)]
struct Recorded {
    start: Option<(u64, u64)>,
    positions: Vec<u64>,
    lines: Vec<String>,
    finished: bool,
}

impl densefeat::progress::Progress for Recorded {
    fn start(&mut self, total: u64, position: u64) {
        self.start = Some((total, position));
    }
    fn update(&mut self, position: u64, message: &str) {
        assert!(message.starts_with("loss "), "{message}");
        self.positions.push(position);
    }
    fn line(&mut self, line: &str) {
        self.lines.push(line.to_string());
    }
    fn finish(&mut self) {
        self.finished = true;
    }
}

#[test]
fn progress_hears_every_step_and_each_validation() {
    let cfg = tiny();
    let d = tempfile::tempdir().unwrap();
    run(&cfg, d.path(), 1, None, Some(2));
    let mut p = Recorded::default();
    let ck = d.path().join("checkpoint.safetensors");
    train(&cfg, d.path(), Some(&ck), None, &mut p).unwrap();
    // Resumed at step 2 of 4: validation every 2 steps, so one line (step 4).
    assert_eq!(p.start, Some((4, 2)));
    assert_eq!(p.positions, vec![3, 4]);
    assert_eq!(p.lines.len(), 1, "{:?}", p.lines);
    assert!(p.lines[0].starts_with("step 4: train "), "{:?}", p.lines);
    assert!(p.finished);
}

#[test]
fn a_checkpoint_from_another_configuration_or_a_bad_file_is_refused() {
    let cfg = tiny();
    let d = tempfile::tempdir().unwrap();
    run(&cfg, d.path(), 2, None, Some(1));
    let ck = d.path().join("checkpoint.safetensors");
    let other = TrainConfig { seed: 99, ..tiny() };
    let err =
        train(&other, d.path(), Some(&ck), None, &mut densefeat::progress::Silent).unwrap_err().to_string();
    assert!(err.contains("checkpoint.safetensors") && err.contains("different configuration"), "{err}");
    // A weights file is not a checkpoint.
    let err = Checkpoint::load(&d.path().join("weights.safetensors")).unwrap_err().to_string();
    assert!(err.contains("weights.safetensors") && err.contains("format"), "{err}");
    // A truncated checkpoint.
    let bytes = std::fs::read(&ck).unwrap();
    let cut = d.path().join("cut.safetensors");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let err = Checkpoint::load(&cut).unwrap_err().to_string();
    assert!(err.contains("cut.safetensors"), "{err}");
    // Missing file.
    assert!(Checkpoint::load(&d.path().join("nope.safetensors"))
        .unwrap_err()
        .to_string()
        .contains("nope.safetensors"));
}

#[test]
fn validation_scenes_give_only_validation_pairs_and_never_train() {
    use densefeat::train::data::DataSet;
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synthetic/room_s1");
    let cfg = DataConfig {
        crop: (64, 48),
        val_sequences: vec![fixture.clone()],
        synthetic_scenes: 1,
        synthetic_val_scenes: 0,
        val_fraction: 0.0,
        ..DataConfig::default()
    };
    let data = DataSet::open(cfg.clone()).unwrap();
    let text = data.describe().join("\n");
    // Every frame of the validation scene is validation: "train frames 0..0 (0 pairs)".
    assert!(
        text.contains("room_s1: 40 frames, train frames 0..0 (0 pairs), validation frames 0..40"),
        "{text}"
    );
    let val = data.val_pairs(3).unwrap();
    assert_eq!(val.iter().filter(|(name, _)| name == "room_s1").count(), 3);
    // A scene given both as training and as validation data is refused, naming the flag.
    let both = DataConfig { sequences: vec![fixture.clone()], ..cfg };
    let err = DataSet::open(both).err().expect("refused").to_string();
    assert!(err.contains("--val-data") && err.contains("room_s1"), "{err}");
}

/// The multi-frame loss in the loop (SPEC.md §13.1b): every training reference gets its further
/// live frames (consistent shapes and cameras), and the run is bit-identical for 1 and 2 threads
/// and differs from the pair run.
#[test]
fn three_live_frames_train_bit_identically_for_any_thread_count() {
    let cfg = TrainConfig { data: DataConfig { live_frames: 3, ..tiny().data }, ..tiny() };
    // The fingerprint names the live frames only when there is more than one, so pair runs keep
    // the fingerprints (and resumable checkpoints) they had before the flag existed.
    assert!(cfg.fingerprint().contains("live_frames: 3"));
    assert!(!tiny().fingerprint().contains("live_frames") && tiny().fingerprint().ends_with(" }"));
    let data = densefeat::train::data::DataSet::open(cfg.data.clone()).unwrap();
    for step in 1..4 {
        let p = data.train_pair(cfg.seed, step, 0).unwrap();
        p.validate().unwrap();
        assert_eq!(p.more_lives.len(), 2, "step {step}");
        for e in &p.more_lives {
            assert_eq!(e.rgb.dim(), p.live_rgb.dim());
            assert!(e.t_lr.translation.vector.norm() >= cfg.data.rule.min_baseline);
        }
    }
    // Validation pairs keep one live frame.
    assert!(data.val_pairs(1).unwrap().iter().all(|(_, p)| p.more_lives.is_empty()));
    let (a, b, c) =
        (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let w1 = run(&cfg, a.path(), 1, None, None);
    let w2 = run(&cfg, b.path(), 2, None, None);
    assert_eq!(bits(&w1), bits(&w2));
    let pairs = run(&tiny(), c.path(), 2, None, None);
    assert_ne!(bits(&w1), bits(&pairs));
    // More than 8 live frames is refused, naming the flag.
    let bad = DataConfig { live_frames: 9, ..tiny().data };
    let err = densefeat::train::data::DataSet::open(bad).err().expect("refused").to_string();
    assert!(err.contains("--live-frames"), "{err}");
}

/// `--init-weights` (SPEC.md §13.6): a run starts from the given weights (fine-tuning), its
/// fingerprint names them, and weights of another network are refused naming the file.
#[test]
fn init_weights_start_the_run_and_a_mismatch_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let start = densefeat::train::trainer::training_init(&tiny().network, 99).unwrap();
    let path = d.path().join("start.safetensors");
    start.save(&path).unwrap();
    let cfg = TrainConfig { init_weights: Some(path.clone()), ..tiny() };
    assert!(cfg.fingerprint().contains("init_weights="));
    assert!(!tiny().fingerprint().contains("init_weights"), "unchanged without it");
    let out = d.path().join("run");
    let fine = run(&cfg, &out, 2, None, Some(1));
    let scratch = run(&tiny(), &d.path().join("scratch"), 2, None, Some(1));
    assert_ne!(bits(&fine), bits(&scratch), "one step from other weights");
    // One step moves every weight only a little from where it started.
    let moved = fine.layers().iter().zip(start.layers()).all(|(a, b)| {
        a.weight.iter().zip(b.weight.iter()).all(|(x, y)| (x - y).abs() <= 2.0 * cfg.optim.lr as f32 + 1e-6)
    });
    assert!(moved, "the run started from the given weights");
    let other = densefeat::train::trainer::training_init(&NetworkConfig { channels: 8, ..tiny().network }, 0)
        .unwrap();
    let bad = d.path().join("other.safetensors");
    other.save(&bad).unwrap();
    let cfg = TrainConfig { init_weights: Some(bad.clone()), ..tiny() };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let err = pool
        .install(|| train(&cfg, &d.path().join("bad"), None, Some(1), &mut densefeat::progress::Silent))
        .expect_err("refused");
    assert!(err.to_string().contains("other.safetensors"), "{err}");
}

/// Training data from a sequence whose frames have cameras of their own (SPEC.md §4a, §13.5): a
/// hand-written `transforms.json` with depth, frames rendered through a 96x72 and an 80x60 camera.
/// Every crop carries its own frame's intrinsics, the live window stays inside the live frame, and
/// the cropped pair is geometrically right: the reference crop's depth warps it onto the live crop
/// (the warp check with the two crop cameras, after its affine fit) far better than the identity.
#[test]
fn frames_with_their_own_cameras_give_consistent_training_crops() {
    use densefeat::geometry::PinholeCamera;
    use densefeat::image::{save_depth_png_mm, save_rgb_png};
    use densefeat::sequence::Frame;
    use densefeat::synth::{PhotometricConfig, Scene, SceneConfig};
    let cams = [
        PinholeCamera::new(80.0, 80.0, 47.5, 35.5, 96, 72).unwrap(),
        PinholeCamera::new(62.0, 63.0, 39.0, 29.0, 80, 60).unwrap(),
    ];
    let n = 12;
    let cfg = SceneConfig {
        seed: 5,
        width: 96,
        height: 72,
        frames: n,
        photometric: PhotometricConfig::none(),
        ..SceneConfig::default()
    };
    let scene = Scene::generate(&cfg).unwrap();
    let d = tempfile::tempdir().unwrap();
    for sub in ["images", "depth"] {
        std::fs::create_dir_all(d.path().join(sub)).unwrap();
    }
    let mut frames = Vec::new();
    for i in 0..n {
        let k = cams[i % 2];
        let pose = scene.pose(i).unwrap();
        let (rgb, depth) = scene.clone().with_camera(k).render_pose(&pose, i).unwrap();
        save_rgb_png(&d.path().join(format!("images/{i:03}.png")), &rgb).unwrap();
        save_depth_png_mm(&d.path().join(format!("depth/{i:03}.png")), &depth).unwrap();
        // OpenGL axes: flip the camera's y and z columns.
        let m = pose.to_homogeneous();
        let rows: Vec<Vec<f64>> = (0..4)
            .map(|r| (0..4).map(|c| if c == 1 || c == 2 { -m[(r, c)] } else { m[(r, c)] }).collect())
            .collect();
        frames.push(serde_json::json!({
            "file_path": format!("images/{i:03}.png"), "depth_file_path": format!("depth/{i:03}.png"),
            "transform_matrix": rows, "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx + 0.5, "cy": k.cy + 0.5,
            "w": k.width, "h": k.height,
        }));
    }
    let json = serde_json::json!({ "camera_model": "OPENCV", "frames": frames });
    std::fs::write(d.path().join("transforms.json"), serde_json::to_string_pretty(&json).unwrap()).unwrap();
    let seq = densefeat::sequence::open(d.path()).unwrap();
    assert_eq!(seq.raw_cameras.len(), 2);
    let data_cfg = DataConfig {
        crop: (64, 48),
        sequences: vec![d.path().to_path_buf()],
        synthetic_scenes: 0,
        synthetic_val_scenes: 0,
        val_fraction: 0.0,
        ..DataConfig::default()
    };
    let data = densefeat::train::data::DataSet::open(data_cfg).unwrap();
    let mut mixed = 0;
    for step in 1..40 {
        let p = data.train_pair(3, step, 0).unwrap();
        p.validate().unwrap();
        let (rc, lc) = (p.ref_camera, p.live_camera);
        assert_eq!((rc.width, rc.height, lc.width, lc.height), (64, 48, 64, 48));
        // Each crop keeps its frame's focal length: one of the two cameras'.
        let focal = |c: &PinholeCamera| {
            cams.iter().position(|k| k.fx == c.fx && k.fy == c.fy).expect("a frame's focal")
        };
        let (fr, fl) = (focal(&rc), focal(&lc));
        if fr != fl {
            mixed += 1;
            let r = Frame {
                index: 0,
                rgb: p.ref_rgb.clone(),
                depth: Some(p.ref_depth.clone()),
                pose: densefeat::geometry::Pose::identity(),
                camera: rc,
            };
            let l =
                Frame { index: 1, rgb: p.live_rgb.clone(), depth: None, pose: p.t_lr.inverse(), camera: lc };
            let c = densefeat::eval::photometric_warp_check(&r, &l).unwrap();
            // The crops are augmented (gain, bias, noise per image): the affine error removes that.
            assert!(c.identity_error > 3.0 * c.affine_error, "step {step}: {c:?}");
        }
    }
    assert!(mixed >= 5, "only {mixed} pairs across the two cameras");
}

/// `--synthetic-style mixed` (SPEC.md §13.5): scenes alternate between the two renderer styles by
/// seed parity, the flag's text parses and a bad one is refused naming it, the single-style
/// fingerprints keep their pre-mixed text (so older checkpoints stay resumable), and a mixed run
/// draws valid pairs from scenes of both styles.
#[test]
fn mixed_synthetic_styles_alternate_by_seed_and_keep_old_fingerprints() {
    use densefeat::synth::Style;
    use densefeat::train::data::{DataSet, SyntheticStyles};
    let mixed: SyntheticStyles = "mixed".parse().unwrap();
    assert_eq!(mixed, SyntheticStyles::Mixed);
    assert_eq!(mixed.of(100_000), Style::Classic);
    assert_eq!(mixed.of(100_001), Style::Real);
    assert_eq!("real".parse::<SyntheticStyles>().unwrap().of(100_000), Style::Real);
    let err = "photo".parse::<SyntheticStyles>().expect_err("refused").to_string();
    assert!(err.contains("--synthetic-style") && err.contains("mixed"), "{err}");
    assert!(tiny().fingerprint().contains("synthetic_style: Classic,"), "{}", tiny().fingerprint());
    let cfg = TrainConfig { data: DataConfig { synthetic_style: mixed, ..tiny().data }, ..tiny() };
    assert!(cfg.fingerprint().contains("synthetic_style: Mixed,"));
    let data = DataSet::open(cfg.data.clone()).unwrap();
    assert!(data.describe().join("\n").contains("mixed"));
    // Two scenes (seeds 100000 classic, 100001 real): draws from both give valid pairs, and the
    // realistic scene's frames differ from what the classic style renders for that seed.
    let classic = DataSet::open(tiny().data).unwrap();
    let mut differ = 0;
    for step in 0..8 {
        let p = data.train_pair(cfg.seed, step, 0).unwrap();
        p.validate().unwrap();
        let q = classic.train_pair(cfg.seed, step, 0).unwrap();
        differ += usize::from(p.ref_rgb != q.ref_rgb);
    }
    assert!(differ > 0 && differ < 8, "{differ} of 8 draws differ from the classic-only run");
}

/// `--live-crop same` (SPEC.md §13.5): every live crop is cut at the reference window's own image
/// coordinates (one camera, so the crop cameras are equal), while `flow` shifts it by the mean
/// flow (the crop cameras differ on some draws); the flag parses and a bad one is refused naming
/// it; `flow` leaves the fingerprint's text as it was and `same` enters it; the crops still give
/// valid tuples whose matches mostly land inside the live crop.
#[test]
fn live_crops_cut_at_the_reference_window_keep_its_coordinates() {
    use densefeat::geometry::Warp;
    use densefeat::train::data::{DataSet, LiveCrop};
    assert_eq!("same".parse::<LiveCrop>().unwrap(), LiveCrop::Same);
    assert_eq!("flow".parse::<LiveCrop>().unwrap(), LiveCrop::Flow);
    let err = "shift".parse::<LiveCrop>().expect_err("refused").to_string();
    assert!(err.contains("--live-crop") && err.contains("same"), "{err}");
    assert!(!tiny().fingerprint().contains("live_crop"), "{}", tiny().fingerprint());
    // `--multi-cost` (SPEC.md §13.1d) likewise: `all` leaves the loss's text as it was.
    let f = tiny().fingerprint();
    assert!(!f.contains("multi_cost") && f.contains("sample_seed: 0 } supervision="), "{f}");
    let seen = TrainConfig {
        loss: densefeat::train::loss::LossConfig {
            multi_cost: densefeat::train::loss::MultiCost::Seen,
            ..tiny().loss
        },
        ..tiny()
    };
    assert!(seen.fingerprint().contains("multi_cost: Seen }"), "{}", seen.fingerprint());
    let data = |live_crop| DataConfig { crop: (128, 96), live_frames: 3, live_crop, ..tiny().data };
    let same_cfg = TrainConfig { data: data(LiveCrop::Same), ..tiny() };
    assert!(same_cfg.fingerprint().contains("live_crop: Same"), "{}", same_cfg.fingerprint());
    let (same, flow) =
        (DataSet::open(data(LiveCrop::Same)).unwrap(), DataSet::open(data(LiveCrop::Flow)).unwrap());
    let mut shifted = 0;
    let (mut inside, mut valid) = (0usize, 0usize);
    for step in 1..9 {
        let p = same.train_pair(5, step, 0).unwrap();
        p.validate().unwrap();
        assert_eq!(p.more_lives.len(), 2);
        assert_eq!(p.live_camera, p.ref_camera, "step {step}");
        for e in &p.more_lives {
            assert_eq!(e.camera, p.ref_camera, "step {step}");
        }
        let warp = Warp::new(&p.ref_camera, &p.live_camera, &p.t_lr);
        for ((y, x), &z) in p.ref_depth.indexed_iter() {
            if z > 0.0 && z.is_finite() {
                valid += 1;
                let q = warp.apply(x as f64, y as f64, 1.0 / f64::from(z));
                inside += usize::from(q.is_some_and(|q| p.live_camera.contains(q.uv.x, q.uv.y)));
            }
        }
        let q = flow.train_pair(5, step, 0).unwrap();
        shifted += usize::from(q.live_camera != q.ref_camera);
    }
    assert!(shifted > 0, "the flow crops never moved");
    assert!(inside * 2 > valid, "{inside} of {valid} matches inside the live crop");
}

/// Runs `cfg` on 1, 2, 3 and 8 threads (the same bits) and the paper's configuration (`tiny()`,
/// other weights), and checks that `cfg` refuses the paper's checkpoint; returns the output folders
/// of the 1-thread run and of the paper's.
pub(crate) fn same_bits_and_not_the_papers(cfg: &TrainConfig) -> (tempfile::TempDir, tempfile::TempDir) {
    let a = tempfile::tempdir().unwrap();
    let w1 = run(cfg, a.path(), 1, None, None);
    for threads in [2, 3, 8] {
        let b = tempfile::tempdir().unwrap();
        assert_eq!(bits(&w1), bits(&run(cfg, b.path(), threads, None, None)), "{threads} threads");
    }
    let deep_dir = tempfile::tempdir().unwrap();
    let deep = run(&tiny(), deep_dir.path(), 2, None, None);
    assert_ne!(bits(&w1), bits(&deep), "the objective differs, so do the weights");
    // Each is its own configuration: the paper's checkpoint is refused.
    let ck = deep_dir.path().join("checkpoint.safetensors");
    let err = train(cfg, deep_dir.path(), Some(&ck), None, &mut densefeat::progress::Silent)
        .unwrap_err()
        .to_string();
    assert!(err.contains("different configuration"), "{err}");
    (a, deep_dir)
}

#[test]
fn final_supervision_trains_the_aggregated_features_alone_and_is_its_own_configuration() {
    // `--supervision final` (SPEC.md §13.2): the objective is L alone; the block columns of the
    // log stay empty; the run is deterministic for any thread count; a deep run's checkpoint is
    // refused; bad values are refused naming the flag.
    let fin: Supervision = "final".parse().unwrap();
    assert_eq!(fin, Supervision::FINAL);
    assert_eq!("deep".parse::<Supervision>().unwrap(), Supervision::default());
    let err = "blocks".parse::<Supervision>().unwrap_err().to_string();
    assert!(err.contains("--supervision") && err.contains("blocks"), "{err}");

    let cfg = TrainConfig { supervision: fin, ..tiny() };
    let (a, deep_dir) = same_bits_and_not_the_papers(&cfg);
    let csv = std::fs::read_to_string(a.path().join("log.csv")).unwrap();
    for row in csv.lines().skip(1) {
        let cols: Vec<&str> = row.split(',').collect();
        // The objective is the aggregated scale's loss, and no block scale was computed.
        let (loss, loss_l): (f64, f64) = (cols[2].parse().unwrap(), cols[3].parse().unwrap());
        assert!(loss > 0.0 && (loss - loss_l).abs() <= 1e-6 * loss, "{row}");
        assert!(cols[4..9].iter().all(|c| c.is_empty()), "{row}");
    }
    let deep_csv = std::fs::read_to_string(deep_dir.path().join("log.csv")).unwrap();
    let first = deep_csv.lines().nth(1).unwrap().split(',').collect::<Vec<_>>();
    assert!(first[4].parse::<f64>().is_ok(), "a deep run logs its block scales: {first:?}");
    // The same pairs at step 1 from the same initialisation: the deep objective adds the blocks'.
    let fin_first = csv.lines().nth(1).unwrap().split(',').collect::<Vec<_>>();
    assert_eq!(fin_first[3], first[3], "L at step 1 is the same scale on the same pairs");
    assert!(first[2].parse::<f64>().unwrap() > fin_first[2].parse::<f64>().unwrap());
}
