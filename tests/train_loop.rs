//! The trainer (SPEC.md §13.6) on a tiny configuration: bit-identical weights for 1 and 2
//! threads, resume to exactly the uninterrupted result, checkpoint round trip and rejection, and
//! the run's outputs (CSV, plot, weights loadable by the network).

use std::path::Path;

use densefeat::backend::CpuBackend;
use densefeat::geometry::InverseDepthBins;
use densefeat::nn::{FeatureNet, NetworkConfig, NetworkWeights};
use densefeat::train::checkpoint::Checkpoint;
use densefeat::train::data::DataConfig;
use densefeat::train::loss::LossConfig;
use densefeat::train::optim::OptimConfig;
use densefeat::train::step::Supervision;
use densefeat::train::trainer::{train, TrainConfig};

fn tiny() -> TrainConfig {
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
    pool.install(|| train(cfg, out, resume, stop, false)).unwrap()
}

fn bits(w: &NetworkWeights) -> Vec<u32> {
    w.layers()
        .iter()
        .flat_map(|l| l.weight.iter().chain(l.bias.iter()).map(|v| v.to_bits()).collect::<Vec<_>>())
        .collect()
}

#[test]
fn one_and_two_threads_give_bit_identical_weights() {
    let cfg = tiny();
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let w1 = run(&cfg, a.path(), 1, None, None);
    let w2 = run(&cfg, b.path(), 2, None, None);
    assert_eq!(bits(&w1), bits(&w2));
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
fn a_checkpoint_from_another_configuration_or_a_bad_file_is_refused() {
    let cfg = tiny();
    let d = tempfile::tempdir().unwrap();
    run(&cfg, d.path(), 2, None, Some(1));
    let ck = d.path().join("checkpoint.safetensors");
    let other = TrainConfig { seed: 99, ..tiny() };
    let err = train(&other, d.path(), Some(&ck), None, false).unwrap_err().to_string();
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
    let err = pool.install(|| train(&cfg, &d.path().join("bad"), None, Some(1), false)).expect_err("refused");
    assert!(err.to_string().contains("other.safetensors"), "{err}");
}
