//! Every shipped configuration loads and validates, and every experiment matrix names configs
//! that exist.

use std::path::{Path, PathBuf};

use ctadsa_core::config::Config;
use ctadsa_core::run::experiment::Experiment;

fn tomls(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(tomls(&p));
        } else if p.extension().is_some_and(|x| x == "toml") {
            out.push(p);
        }
    }
    out
}

#[test]
fn shipped_configs_load_and_matrices_point_at_them() {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/configs"));
    let all = tomls(&root);
    assert!(all.len() >= 8, "expected the paper, quick, baseline, ablation and experiment files");
    for p in &all {
        if p.parent().is_some_and(|d| d.ends_with("experiments")) {
            let m: toml::Table = std::fs::read_to_string(p).unwrap().parse().unwrap();
            for method in m["methods"].as_array().unwrap() {
                let cfg = p.parent().unwrap().join(method["config"].as_str().unwrap());
                assert!(cfg.exists(), "{}: {} does not exist", p.display(), cfg.display());
            }
            // The whole matrix as `ctadsa experiment` reads it: every method's configuration with
            // each view subset, and its ensembles.
            Experiment::load(p, &[], Path::new("unused"), &[]).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        } else {
            Config::load(Some(p), &[]).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        }
    }
    let quick = Config::load(Some(&root.join("quick.toml")), &[]).unwrap();
    let prior_only = Config::load(Some(&root.join("baselines/prior-only.toml")), &[]).unwrap();
    assert_eq!(prior_only.init.n2, 0);
    assert!(prior_only.densify.reseed_at.is_empty(), "the prior-only baseline must not seed from the images");
    assert_eq!(prior_only.run, quick.run, "a baseline changes only what it says");
    // The CPU configuration is the quick one with a larger budget and a lower 3-view iso-level
    // (more recall), without the two-view level beside the prior, nothing else.
    let mut cpu = Config::load(Some(&root.join("cpu.toml")), &[]).unwrap();
    let cpu_iterations = cpu.run.iterations;
    assert!(cpu.run.iterations > quick.run.iterations && cpu.densify.max_gaussians > quick.densify.max_gaussians);
    cpu.run.iterations = quick.run.iterations;
    cpu.densify.until = quick.densify.until;
    cpu.densify.every = quick.densify.every;
    cpu.densify.max_gaussians = quick.densify.max_gaussians;
    // Re-seeding at the same fractions of the run.
    let scale = |at: &[usize], n: usize| at.iter().map(|&i| i as f64 / n as f64).collect::<Vec<_>>();
    assert_eq!(scale(&cpu.densify.reseed_at, cpu_iterations), scale(&quick.densify.reseed_at, quick.run.iterations));
    cpu.densify.reseed_at = quick.densify.reseed_at.clone();
    assert!(cpu.output.level_mask_threshold < cpu.init.mask_threshold);
    assert_eq!(cpu.output.level_mask_threshold_two_views, quick.output.level_mask_threshold_two_views);
    cpu.output.level_mask_threshold = quick.output.level_mask_threshold;
    // The two-view level beside the prior was measured with the quick configurations only.
    assert_eq!(cpu.output.near_prior_mask_threshold, 0.0);
    cpu.output.near_prior_mask_threshold = quick.output.near_prior_mask_threshold;
    assert_eq!(
        format!("{cpu:?}"),
        format!("{quick:?}"),
        "cpu.toml changes only the budget and the 3-view level (and has no two-view level beside the prior)"
    );
    // The 512² configuration is the quick one with 1.5 times the iterations, its schedule
    // scaled with the run, the prior's projection subtracted for the image seeds, a second
    // image-seeded member and tracks in rounds for the prior-only member (measured at 512² only), the
    // centreline's tracing, nothing else.
    let mut fine = Config::load(Some(&root.join("quick-512.toml")), &[]).unwrap();
    let scaled = |n: usize| n * 3 / 2;
    assert_eq!(fine.run.iterations, scaled(quick.run.iterations));
    assert_eq!(
        [fine.densify.from, fine.densify.until, fine.densify.every, fine.loss.pa_start],
        [quick.densify.from, quick.densify.until, quick.densify.every, quick.loss.pa_start].map(scaled)
    );
    assert_eq!(fine.densify.reseed_at, quick.densify.reseed_at.iter().map(|&i| scaled(i)).collect::<Vec<_>>());
    fine.run.iterations = quick.run.iterations;
    (fine.densify.from, fine.densify.until, fine.densify.every) =
        (quick.densify.from, quick.densify.until, quick.densify.every);
    fine.loss.pa_start = quick.loss.pa_start;
    fine.densify.reseed_at = quick.densify.reseed_at.clone();
    assert!(fine.init.subtract_prior && !quick.init.subtract_prior);
    fine.init.subtract_prior = false;
    assert!(!fine.run.member_seeds.is_empty() && quick.run.member_seeds.is_empty());
    fine.run.member_seeds.clear();
    // The prior-only member seeded along the tracks, with 2 and 3 views (measured at 512² only).
    assert_eq!((fine.run.member_tracks_max_views, quick.run.member_tracks_max_views), (3, 0));
    assert_eq!(fine.prior_only_member().unwrap().init.track_max_views, 3);
    fine.run.member_tracks_max_views = 0;
    // Its tracks in rounds: the branches of the tracked vessels (only the member tracks).
    assert!(fine.init.track_rounds > 1 && quick.init.track_rounds == 1);
    assert!(fine.init.track_max_points > quick.init.track_max_points);
    // Where arrival maps check the tracks' claims, more rounds and room for them; elsewhere four.
    assert_eq!((fine.init.track_rounds_for(true), fine.init.track_rounds_for(false)), (6, 4));
    assert!(fine.init.track_max_points_for(true) > fine.init.track_max_points_for(false));
    (fine.init.track_rounds_arrival, fine.init.track_max_points_arrival) = (None, None);
    // Where arrival maps check the seeds, densification prunes the ghosts they show.
    assert!(fine.densify.arrival_prune && !quick.densify.arrival_prune);
    fine.densify.arrival_prune = false;
    fine.init.track_rounds = quick.init.track_rounds;
    fine.init.track_max_points = quick.init.track_max_points;
    // The tracks read the prior's projection fitted to each view and not dilated; the image
    // seeds keep quick's removal of the prior.
    assert_eq!((fine.init.track_fit_prior_projection, fine.init.track_prior_dilation_px), (Some(true), Some(0)));
    assert_eq!((fine.init.fit_prior_projection, fine.init.prior_dilation_px), (false, quick.init.prior_dilation_px));
    (fine.init.track_fit_prior_projection, fine.init.track_prior_dilation_px) = (None, None);
    // Denser, spaced image seeds with three views; two-view runs keep quick's number of them,
    // spread apart.
    assert_eq!(fine.init.n2_for(2), quick.init.n2);
    assert!(fine.init.seed_spacing_mm_for(2) > 0.0 && quick.init.seed_spacing_mm_for(2) == 0.0);
    assert!(fine.init.n2_for(3) > quick.init.n2 && fine.init.seed_spacing_mm_for(3) > 0.0);
    (fine.init.n2, fine.init.seed_spacing_mm) = (quick.init.n2, quick.init.seed_spacing_mm);
    (fine.init.n2_two_views, fine.init.seed_spacing_mm_two_views) = (None, None);
    // The centreline traced on a finer grid and across beads (an output of the 512² runs only).
    assert!(fine.output.centreline_voxel_mm > 0.0 && quick.output.centreline_voxel_mm == 0.0);
    assert!(fine.output.centreline_bridge_fraction > 0.0 && quick.output.centreline_bridge_fraction == 0.0);
    // Two-view runs trace it with a wider cover and lower bridges; three-view runs do not change.
    assert_eq!(fine.output.centreline_const_mm_for(3, false), quick.output.centreline_const_mm);
    assert!(fine.output.centreline_const_mm_for(2, false) > fine.output.centreline_const_mm_for(3, false));
    // With arrival maps checking the new branches, a narrower one (still wider than three views').
    let arrival = fine.output.centreline_const_mm_for(2, true);
    assert!(
        arrival < fine.output.centreline_const_mm_for(2, false)
            && arrival > fine.output.centreline_const_mm_for(3, false)
    );
    fine.output.centreline_const_mm_arrival = None;
    // And paths along the density's ridges with two views, more so where the maps check them;
    // three-view runs along the solid's middle as before.
    let ridge_two_views = fine.output.centreline_ridge_weight_for(2, false);
    assert!(ridge_two_views > 0.0 && fine.output.centreline_ridge_weight_for(2, true) > ridge_two_views);
    assert_eq!(fine.output.centreline_ridge_weight_for(3, true), 0.0, "no change with three views");
    fine.output.centreline_ridge_weight_arrival = None;
    fine.output.centreline_ridge_weight_two_views = None;
    let bridge_two_views = fine.output.centreline_bridge_fraction_for(2);
    assert!(bridge_two_views > 0.0 && bridge_two_views < fine.output.centreline_bridge_fraction_for(3));
    fine.output.centreline_voxel_mm = quick.output.centreline_voxel_mm;
    fine.output.centreline_bridge_fraction = quick.output.centreline_bridge_fraction;
    fine.output.centreline_const_mm_two_views = None;
    fine.output.centreline_bridge_fraction_two_views = None;
    fine.output.centreline_bridge_prior_clearance_mm = quick.output.centreline_bridge_prior_clearance_mm;
    // Both cut two-view surfaces lower beside the prior, at the threshold three-view runs
    // match their masks at already (so three-view runs do not change).
    for cfg in [&quick, &fine] {
        assert!(cfg.output.near_prior_mask_threshold > 0.0);
        assert_eq!(
            cfg.output.near_prior_mask_threshold,
            cfg.output.level_mask_threshold_for(3, cfg.init.mask_threshold),
            "no change with three views"
        );
    }
    // Two-view runs on cases with arrival maps check the image seeds, the track starts and the
    // re-seeds, and trace the centreline they check with a narrower cover than other two-view runs.
    assert!(fine.init.arrival_seeds && fine.init.arrival_track_starts && fine.init.arrival_reseeds);
    assert!(!quick.init.arrival_seeds && !quick.init.arrival_track_starts && !quick.init.arrival_reseeds);
    (fine.init.arrival_seeds, fine.init.arrival_track_starts, fine.init.arrival_reseeds) = (false, false, false);
    // A view the prior hides at a point is judged where a vessel behind the prior leaves it.
    assert!(fine.init.arrival_prior_unknown && fine.init.arrival_prior_exit_px > 0);
    assert!(!quick.init.arrival_prior_unknown && quick.init.arrival_prior_exit_px == 0);
    (fine.init.arrival_prior_unknown, fine.init.arrival_prior_exit_px) = (false, 0);
    // A track's claim whose point fills at two times gives way to one that fills at once.
    assert!(fine.init.arrival_track_claims && !quick.init.arrival_track_claims);
    fine.init.arrival_track_claims = false;
    // And the prior-only member re-seeds too, where the maps check its re-seeds.
    assert!(fine.run.member_reseeds && !quick.run.member_reseeds);
    assert!(fine.prior_only_member().unwrap().densify.reseed_arrival_only);
    fine.run.member_reseeds = false;
    assert!(
        quick.output.centreline_const_mm_arrival.is_none()
            && quick.output.centreline_ridge_weight_arrival.is_none()
            && quick.output.centreline_ridge_weight_two_views.is_none()
    );
    assert_eq!(
        format!("{fine:?}"),
        format!("{quick:?}"),
        "quick-512.toml changes only the budget, the seeds' prior, count and arrival checks, the members and the centreline's tracing"
    );
    // The paper's budget (paper.toml) is quick-512's method and field with the paper's
    // iterations, one view per step, quick-512's schedule at the same fractions of the run and the
    // prior-only member stopped early, nothing else.
    let fine = Config::load(Some(&root.join("quick-512.toml")), &[]).unwrap();
    let method = Config::load(Some(&root.join("baselines/paper-method.toml")), &[]).unwrap();
    let mut budget = Config::load(Some(&root.join("paper.toml")), &[]).unwrap();
    let n = budget.run.iterations;
    assert_eq!((n, budget.run.views_per_step), (method.run.iterations, method.run.views_per_step));
    let fraction = |i: usize, of: usize| i as f64 / of as f64;
    for (at_budget, at_fine) in [
        (budget.densify.from, fine.densify.from),
        (budget.densify.until, fine.densify.until),
        (budget.densify.every, fine.densify.every),
        (budget.loss.pa_start, fine.loss.pa_start),
    ]
    .into_iter()
    .chain(budget.densify.reseed_at.iter().copied().zip(fine.densify.reseed_at.iter().copied()))
    {
        assert!((fraction(at_budget, n) - fraction(at_fine, fine.run.iterations)).abs() < 1e-9);
    }
    assert_eq!(budget.densify.reseed_at.len(), fine.densify.reseed_at.len());
    // quick-512's field and its learning rate, not the paper's (docs/RESULTS.md, "Which part of
    // the budget costs").
    assert_ne!(fine.field.encoding, method.field.encoding);
    assert_eq!(budget.field.encoding, fine.field.encoding);
    assert_eq!(budget.optim.lr_field, fine.optim.lr_field);
    assert!(budget.run.member_iterations > 0 && budget.run.member_iterations < n);
    assert_eq!(budget.prior_only_member().unwrap().run.steps_to_train(), budget.run.member_iterations);
    // The FN term stays off as in quick-512; its start is the paper's.
    assert_eq!((budget.loss.fn_weight, budget.loss.fn_start), (0.0, method.loss.fn_start));
    budget.run.iterations = fine.run.iterations;
    budget.run.views_per_step = fine.run.views_per_step;
    budget.run.checkpoint_every = fine.run.checkpoint_every;
    budget.run.member_iterations = fine.run.member_iterations;
    (budget.densify.from, budget.densify.until, budget.densify.every) =
        (fine.densify.from, fine.densify.until, fine.densify.every);
    budget.densify.reseed_at = fine.densify.reseed_at.clone();
    (budget.loss.pa_start, budget.loss.fn_start) = (fine.loss.pa_start, fine.loss.fn_start);
    assert_eq!(
        format!("{budget:?}"),
        format!("{fine:?}"),
        "paper.toml changes only quick-512's budget and the member's length"
    );
}
