//! The plane-fitting experiment of paper §III-C (Fig. 2) must show what the paper shows: the
//! weighted fit stays flat over α while the unweighted error grows.

use mlod::uncertainty::plane::{plane_fit_experiment, PlaneCase, PlaneFitConfig};

#[test]
fn weighted_fit_is_flat_and_far_below_unweighted() {
    let cfg = PlaneFitConfig {
        trials: 40,
        seed: 11,
        alphas: vec![0.0, 0.02, 0.05, 0.1],
        ..Default::default()
    };
    let rows = plane_fit_experiment(&cfg, &PlaneCase::paper_cases()).unwrap();
    for case in ["ground", "wall"] {
        let rs: Vec<_> = rows.iter().filter(|r| r.case == case).collect();
        assert_eq!(rs.len(), 4);
        for r in &rs {
            println!(
                "{case} α={:.2}: weighted {:.3e}, unweighted {:.3e}",
                r.alpha, r.weighted_error, r.unweighted_error
            );
        }
        let (a0, a02, a05, a1) = (rs[0], rs[1], rs[2], rs[3]);
        // At α = 0 both fits see the same data with equal weights.
        assert!((a0.weighted_error - a0.unweighted_error).abs() < 1e-9 * a0.unweighted_error.max(1e-12));
        // Weighted: flat over α > 0 (α = 0.1 within 1.5× of α = 0.02).
        let ratio = a1.weighted_error / a02.weighted_error;
        assert!(
            (1.0 / 1.5..=1.5).contains(&ratio),
            "{case}: weighted 0.1/0.02 ratio {ratio}"
        );
        // At α = 0.1 at least 10× below the unweighted error ...
        assert!(
            a1.unweighted_error >= 10.0 * a1.weighted_error,
            "{case}: {} vs {}",
            a1.unweighted_error,
            a1.weighted_error
        );
        // ... which grows with α.
        assert!(a02.unweighted_error < a05.unweighted_error && a05.unweighted_error < a1.unweighted_error);
        assert!(a02.unweighted_error > 2.0 * a0.unweighted_error);
    }
}

#[test]
fn experiment_is_deterministic_and_rejects_bad_config() {
    let cfg = PlaneFitConfig {
        trials: 3,
        points: 500,
        alphas: vec![0.05],
        ..Default::default()
    };
    let a = plane_fit_experiment(&cfg, &PlaneCase::paper_cases()).unwrap();
    let b = plane_fit_experiment(&cfg, &PlaneCase::paper_cases()).unwrap();
    assert_eq!(a[0].weighted_error, b[0].weighted_error);
    let bad = PlaneFitConfig {
        alphas: vec![-0.1],
        ..cfg.clone()
    };
    assert!(plane_fit_experiment(&bad, &PlaneCase::paper_cases()).is_err());
    let bad = PlaneFitConfig { trials: 0, ..cfg };
    assert!(plane_fit_experiment(&bad, &PlaneCase::paper_cases()).is_err());
}
