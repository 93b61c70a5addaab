//! The loss's ranking term (SPEC.md §13.1e, `--hinge-weight`, `--hinge-margin`): off by default
//! with the paper's bits and fingerprint, its value and gradient on a hand case, its gradient
//! against central differences (per pixel and through the f64 reference loss), the fast loss
//! against the reference with it on, and bad values refused naming the flag.

use densefeat::geometry::InverseDepthBins;
use densefeat::train::loss::{pixel_terms, scale_loss_reference, LossConfig, HINGE_RADIUS};
use densefeat::train::trainer::TrainConfig;
use proptest::prelude::*;

use crate::train_loop::tiny;
use crate::train_loss::{case, fast_within_budget, pixel_terms_match_fd, ref_gradient_matches_fd, rng, Case};

fn cfg12(w: f64, margin: f64) -> LossConfig {
    LossConfig { bins: InverseDepthBins::new(0.0, 2.0, 12).unwrap(), ..LossConfig::default() }
        .with_hinge(w, margin)
        .unwrap()
}

#[test]
fn the_ranking_term_is_off_by_default_and_bad_values_name_their_flag() {
    assert_eq!(LossConfig::default().with_hinge(0.0, 1.0).unwrap(), LossConfig::default());
    for bad in [-0.5, f64::NAN, f64::INFINITY] {
        let err = LossConfig::default().with_hinge(bad, 1.0).unwrap_err().to_string();
        assert!(err.contains("--hinge-weight"), "{err}");
        let err = LossConfig::default().with_hinge(1.0, bad).unwrap_err().to_string();
        assert!(err.contains("--hinge-margin"), "{err}");
    }
    // The fingerprint (SPEC.md §13.6) names the term only when it is on, so checkpoints from
    // before the flags existed stay resumable.
    let off = tiny();
    assert!(!off.fingerprint().contains("hinge") && off.fingerprint().contains("sample_seed: 0 }"));
    let on = TrainConfig { loss: off.loss.with_hinge(0.5, 2.0).unwrap(), ..tiny() };
    assert!(on.fingerprint().contains("hinge_weight: 0.5, hinge_margin: 2.0 }"), "{}", on.fingerprint());
}

/// Target bin 5: bin 6 (within the radius) is cheaper still and ignored; bin 9 is the cheapest of
/// the far bins. The term is `w (μ + E_5 − E_9)`, the gradient the paper's plus `w` at 5 and `−w`
/// at 9, every other bin's bits unchanged; with the target ahead by more than μ it is 0 and
/// changes nothing.
#[test]
fn the_ranking_term_on_a_hand_case() {
    assert_eq!(HINGE_RADIUS, 2);
    let mut e = vec![4.0; 12];
    e[5] = 2.0;
    e[6] = 1.0;
    e[9] = 1.5;
    e[11] = 1.5; // a tie: the first far bin of lowest cost is 9
    let (mut g_off, mut g_on) = (vec![0.0; 12], vec![0.0; 12]);
    let off = pixel_terms(&cfg12(0.0, 1.0), &e, 5, 0.9, &mut g_off);
    let on = pixel_terms(&cfg12(0.5, 1.0), &e, 5, 0.9, &mut g_on);
    assert_eq!(off.hinge, 0.0);
    assert!((on.hinge - 0.5 * (1.0 + 2.0 - 1.5)).abs() < 1e-15);
    assert_eq!(
        (on.ce.to_bits(), on.rho.to_bits(), on.depth.to_bits()),
        (off.ce.to_bits(), off.rho.to_bits(), off.depth.to_bits())
    );
    for l in 0..12 {
        let want = g_off[l]
            + if l == 5 {
                0.5
            } else if l == 9 {
                -0.5
            } else {
                0.0
            };
        assert_eq!(g_on[l].to_bits(), want.to_bits(), "bin {l}");
    }
    // The target ahead of every far bin by more than the margin: no term, the paper's bits.
    e[5] = 0.2;
    let (mut g_off, mut g_on) = (vec![0.0; 12], vec![0.0; 12]);
    pixel_terms(&cfg12(0.0, 1.0), &e, 5, 0.9, &mut g_off);
    let on = pixel_terms(&cfg12(0.5, 1.0), &e, 5, 0.9, &mut g_on);
    assert_eq!(on.hinge, 0.0);
    assert_eq!(
        g_on.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
        g_off.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// The per-pixel terms with the ranking term on, against a central difference in every bin
    /// (costs drawn so that the term is usually active; a case within the step of its kink or of
    /// a tie between far bins is skipped).
    #[test]
    fn pixel_terms_with_the_ranking_term_match_finite_differences(seed in 0u64..1000, target in 0usize..12) {
        let mut r = rng(seed);
        let cfg = cfg12(0.7, 1.5);
        let e: Vec<f64> = (0..12).map(|i| if i == 3 { cfg.outside_cost } else { 2.0 + 1.5 * r() }).collect();
        let far: Vec<f64> = (0..12).filter(|l: &usize| l.abs_diff(target) > HINGE_RADIUS).map(|l| e[l]).collect();
        let mut sorted = far.clone();
        sorted.sort_by(f64::total_cmp);
        prop_assume!(sorted[1] - sorted[0] > 1e-4 && (cfg.hinge_margin + e[target] - sorted[0]).abs() > 1e-4);
        let rho_star = 0.3 + 0.5 * (r() + 1.0);
        pixel_terms_match_fd(&cfg, &e, target, rho_star)?;
    }

    /// Fast f32 against the f64 reference with the ranking term on, within §13.3's budgets.
    #[test]
    fn fast_matches_reference_with_the_ranking_term(seed in 0u64..1000) {
        let mut c = case(seed, 12, 16, 8, 32);
        c.cfg = c.cfg.with_hinge(0.5, 1.0).unwrap();
        prop_assert!(fast_within_budget(&c)?.hinge > 0.0);
    }
}

/// The reference loss with the ranking term on: its sums hold the term, the paper's sums are
/// unchanged bit for bit, and its gradient with respect to the reference features matches a
/// central difference.
#[test]
fn the_reference_loss_with_the_ranking_term_matches_finite_differences() {
    let base = case(11, 6, 7, 3, 12);
    let paper =
        scale_loss_reference(&base.cfg, base.f_ref.view(), base.f_live.view(), base.depth.view(), &base.warp)
            .unwrap();
    let c = Case { cfg: base.cfg.with_hinge(0.5, 1.0).unwrap(), ..base };
    let g = scale_loss_reference(&c.cfg, c.f_ref.view(), c.f_live.view(), c.depth.view(), &c.warp).unwrap();
    assert_eq!(paper.sums.hinge, 0.0);
    assert!(g.sums.hinge > 0.0);
    assert_eq!(
        (g.sums.ce.to_bits(), g.sums.rho.to_bits()),
        (paper.sums.ce.to_bits(), paper.sums.rho.to_bits())
    );
    assert!(g.sums.mean() > paper.sums.mean());
    ref_gradient_matches_fd(&c, &g.d_ref, &[(0, 0, 0), (2, 3, 1), (5, 6, 2), (3, 1, 0), (4, 4, 2)]);
}
