//! The block scales' weight in the objective (SPEC.md §13.2, `--deep-weight`): 1 is the paper's
//! deep supervision with its bits and fingerprint; another weight scales the block scales' share
//! of the objective and of the gradient, and nothing else; the run is bit-identical for any
//! thread count; bad values are refused naming the flag.

use densefeat::backend::CpuBackend;
use densefeat::nn::NetworkWeights;
use densefeat::train::data::DataSet;
use densefeat::train::step::{batch_step, Supervision};
use densefeat::train::trainer::{training_init, TrainConfig};

use crate::train_loop::{same_bits_and_not_the_papers, tiny};

#[test]
fn bad_deep_weights_name_the_flag_and_one_is_the_paper() {
    let deep = Supervision::default();
    assert_eq!(deep.with_deep_weight(1.0).unwrap(), deep);
    assert_eq!(Supervision::FINAL.with_deep_weight(1.0).unwrap(), Supervision::FINAL);
    for bad in [0.0, -0.5, 1.5, f64::NAN, f64::INFINITY] {
        let err = deep.with_deep_weight(bad).unwrap_err().to_string();
        assert!(err.contains("--deep-weight"), "{bad}: {err}");
    }
    let err = Supervision::FINAL.with_deep_weight(0.5).unwrap_err().to_string();
    assert!(err.contains("--deep-weight") && err.contains("final"), "{err}");
    // The fingerprint (SPEC.md §13.6) names the weight only when it is not 1, so the paper's
    // checkpoints from before the flag stay resumable.
    assert!(tiny().fingerprint().contains("supervision=Supervision { deep: true, aggregated: true }"));
    let w = TrainConfig { supervision: deep.with_deep_weight(0.25).unwrap(), ..tiny() };
    assert!(w.fingerprint().contains("Supervision { deep: true, aggregated: true, deep_weight: 0.25 }"));
}

/// One batch's gradients under a supervision.
fn grads(cfg: &TrainConfig, sup: Supervision) -> (f64, NetworkWeights) {
    let data = DataSet::open(cfg.data.clone()).unwrap();
    let weights = training_init(&cfg.network, cfg.init_seed).unwrap();
    let cpu = CpuBackend::default();
    let (losses, g) =
        batch_step(&weights, 2, |b| data.train_pair(cfg.seed, 1, b), &cfg.loss, &sup, &cpu).unwrap();
    (losses.iter().map(|l| l.total(&sup)).sum(), g)
}

fn flat(w: &NetworkWeights) -> Vec<f64> {
    w.layers().iter().flat_map(|l| l.weight.iter().chain(l.bias.iter()).map(|&v| f64::from(v))).collect()
}

#[test]
fn the_deep_weight_scales_the_block_scales_share_of_objective_and_gradient() {
    let cfg = tiny();
    let w = 0.25;
    let (l_deep, g_deep) = grads(&cfg, Supervision::default());
    let (l_fin, g_fin) = grads(&cfg, Supervision::FINAL);
    let (l_w, g_w) = grads(&cfg, Supervision::default().with_deep_weight(w).unwrap());
    // The objective and the gradient are linear in the block scales' weight: L alone plus w times
    // the blocks' share (the same pairs and sampled pixels in all three runs).
    assert!(l_deep > l_fin && l_fin > 0.0);
    let want = l_fin + w * (l_deep - l_fin);
    assert!((l_w - want).abs() <= 1e-9 * want, "{l_w} vs {want}");
    let (gd, gf, gw) = (flat(&g_deep), flat(&g_fin), flat(&g_w));
    let scale = gd.iter().chain(&gf).fold(0.0f64, |m, v| m.max(v.abs()));
    let mut moved = 0;
    for ((d, f), got) in gd.iter().zip(&gf).zip(&gw) {
        let want = f + w * (d - f);
        // f32 sums of up to a few thousand terms at the gradients' scale.
        assert!((got - want).abs() <= 1e-4 * scale, "{got} vs {want} (scale {scale})");
        moved += usize::from((got - f).abs() > 1e-3 * scale);
    }
    assert!(moved > gw.len() / 10, "the blocks' share reached only {moved} of {} parameters", gw.len());
}

#[test]
fn a_deep_weight_run_is_the_same_bits_for_any_thread_count_and_its_own_configuration() {
    let cfg = TrainConfig { supervision: Supervision::default().with_deep_weight(0.2).unwrap(), ..tiny() };
    let (a, _) = same_bits_and_not_the_papers(&cfg);
    // The log's objective is L plus 0.2 times the block scales' columns.
    let csv = std::fs::read_to_string(a.path().join("log.csv")).unwrap();
    for row in csv.lines().skip(1) {
        // Columns: step, lr, loss, L, L1, L2 (the tiny network's two blocks).
        let cols: Vec<f64> = row.split(',').take(6).map(|c| c.parse().unwrap()).collect();
        let want = cols[3] + 0.2 * (cols[4] + cols[5]);
        assert!((cols[2] - want).abs() <= 1e-5 * want, "{row}");
    }
}
