use super::*;

#[test]
fn unknown_keys_and_bad_values_name_the_key() {
    let err = Config::load(None, &["run.iterationz=5".into()]).unwrap_err().to_string();
    assert!(err.contains("iterationz"), "{err}");
    // An unknown key from an override blames the override, not the file it was laid on.
    let err = Config::from_toml_str("[run]\niterations = 5\n", "file.toml", &["run.iterationz=5".into()])
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("override `run.iterationz=5`") && !err.contains("file.toml"), "{err}");
    let err = Config::from_toml_str("[run]\niterationz = 5\n", "file.toml", &[]).unwrap_err().to_string();
    assert!(err.contains("file.toml") && err.contains("iterationz"), "{err}");
    let err = Config::load(None, &["loss.lambda_dssim=2".into()]).unwrap_err().to_string();
    assert!(err.contains("loss.lambda_dssim"), "{err}");
    let err = Config::load(None, &["init.n2_mode=\"sideways\"".into()]).unwrap_err().to_string();
    assert!(err.contains("sideways") || err.contains("n2_mode"), "{err}");
    // The arrival checks' windows are bounded (a huge one would scan the whole image per point).
    for (key, good) in
        [("init.arrival_prior_exit_px", 6), ("output.arrival_prior_exit_px", 6), ("run.arrival_median_px", 1)]
    {
        let err = Config::load(None, &[format!("{key}=100000")]).unwrap_err().to_string();
        assert!(err.contains(key), "{err}");
        assert!(Config::load(None, &[format!("{key}={good}")]).is_ok());
    }
    for bad in ["-0.1", "1.5", "nan"] {
        let err = Config::load(None, &[format!("run.arrival_noisy_share={bad}")]).unwrap_err().to_string();
        assert!(err.contains("run.arrival_noisy_share"), "{err}");
    }
    assert!(Config::load(None, &["run.arrival_noisy_share=1".into()]).is_ok());
    // The tracking settings of runs whose claims the arrival maps check are bounded as the
    // settings they replace.
    for (key, bad, good) in [("init.track_rounds_arrival", 9, 6), ("init.track_max_points_arrival", 30_000_000, 80_000)]
    {
        let err = Config::load(None, &[format!("{key}={bad}")]).unwrap_err().to_string();
        assert!(err.contains(key), "{err}");
        assert!(Config::load(None, &[format!("{key}={good}")]).is_ok());
    }
    let ok = Config::load(None, &["run.iterations=7".into(), "init.n2_mode=uniform".into()]).unwrap();
    assert_eq!(ok.run.iterations, 7);
    assert_eq!(ok.init.n2_mode, SeedMode::Uniform);
    // Round trip through TOML.
    let text = ok.to_toml();
    let back: Config = toml::from_str(&text).unwrap();
    assert_eq!(back, ok);
}

#[test]
fn two_view_runs_match_the_level_to_their_own_mask_threshold() {
    let mut out = OutputConfig::default();
    assert_eq!(out.level_mask_threshold_for(3, 0.05), 0.05, "the seeds' threshold by default");
    assert_eq!(out.level_mask_threshold_for(2, 0.05), out.level_mask_threshold_two_views);
    out.level_mask_threshold = 0.03;
    assert_eq!(out.level_mask_threshold_for(3, 0.05), 0.03);
    out.level_mask_threshold_two_views = 0.0;
    assert_eq!(out.level_mask_threshold_for(2, 0.05), 0.03, "0 falls back to the general threshold");
}

#[test]
fn two_view_runs_trace_the_centreline_with_their_own_settings() {
    let cfg = Config::load(
        None,
        &[
            "output.centreline_const_mm=1.0".into(),
            "output.centreline_bridge_fraction=0.7".into(),
            "output.centreline_const_mm_two_views=2.0".into(),
            "output.centreline_bridge_fraction_two_views=0.5".into(),
        ],
    )
    .unwrap();
    let out = &cfg.output;
    assert_eq!((out.centreline_const_mm_for(3, false), out.centreline_bridge_fraction_for(3)), (1.0, 0.7));
    assert_eq!((out.centreline_const_mm_for(2, false), out.centreline_bridge_fraction_for(2)), (2.0, 0.5));
    assert_eq!(out.centreline_const_mm_for(2, true), 2.0, "no arrival setting: the two-view one");
    let arrival = OutputConfig { centreline_const_mm_arrival: Some(1.5), ..out.clone() };
    assert_eq!((arrival.centreline_const_mm_for(2, true), arrival.centreline_const_mm_for(2, false)), (1.5, 2.0));
    assert_eq!(arrival.centreline_const_mm_for(3, true), 1.0, "three views are not checked");
    let plain = OutputConfig { centreline_const_mm: 1.5, ..OutputConfig::default() };
    assert_eq!(plain.centreline_const_mm_for(2, false), 1.5, "absent: the general setting");
    for bad in [
        "output.centreline_bridge_fraction_two_views=1.0",
        "output.centreline_const_mm_two_views=-1",
        "output.centreline_const_mm_arrival=-1",
    ] {
        let err = Config::load(None, &[bad.into()]).unwrap_err().to_string();
        assert!(err.contains(bad.split('=').next().unwrap()), "{err}");
    }
}

#[test]
fn two_view_and_arrival_checked_runs_follow_the_ridges_with_their_own_weights() {
    let plain = OutputConfig::default();
    assert!(!plain.centreline_follows_ridges(), "off by default");
    assert_eq!(plain.centreline_ridge_weight_for(2, true), 0.0);
    let output =
        |sets: &[&str]| Config::load(None, &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap().output;
    let arrival = "output.centreline_ridge_weight_arrival=0.5";
    let two_views = "output.centreline_ridge_weight_two_views=0.25";
    // (views, arrival-checked) -> weight: the arrival weight for checked two-view runs, then
    // the two-view weight for runs of two views or fewer, then the general one (0 here).
    for (sets, expected) in [
        (vec![arrival], [0.5, 0.0, 0.0, 0.0]),
        (vec![two_views], [0.25, 0.25, 0.25, 0.0]),
        (vec![two_views, arrival], [0.5, 0.25, 0.25, 0.0]),
    ] {
        let out = output(&sets);
        assert!(out.centreline_follows_ridges(), "{sets:?}");
        let weights =
            [(2, true), (2, false), (1, false), (3, true)].map(|(v, a)| out.centreline_ridge_weight_for(v, a));
        assert_eq!(weights, expected, "{sets:?}: 2 views checked, 2 unchecked, 1, 3 views");
    }
    for bad in [
        "output.centreline_ridge_weight=1.5",
        "output.centreline_ridge_weight_two_views=2",
        "output.centreline_ridge_weight_arrival=-0.1",
    ] {
        let err = Config::load(None, &[bad.into()]).unwrap_err().to_string();
        assert!(err.contains(bad.split('=').next().unwrap()), "{err}");
    }
}

#[test]
fn two_view_runs_take_their_own_seed_count_and_spacing() {
    let mut init = InitConfig { n2: 10_000, seed_spacing_mm: 0.7, ..InitConfig::default() };
    assert_eq!((init.n2_for(2), init.seed_spacing_mm_for(2)), (10_000, 0.7), "absent: the general values");
    init.n2_two_views = Some(3_000);
    init.seed_spacing_mm_two_views = Some(0.0);
    assert_eq!((init.n2_for(2), init.seed_spacing_mm_for(2)), (3_000, 0.0));
    assert_eq!((init.n2_for(1), init.seed_spacing_mm_for(1)), (3_000, 0.0));
    assert_eq!((init.n2_for(3), init.seed_spacing_mm_for(3)), (10_000, 0.7));
    let cfg =
        Config::load(None, &["init.n2_two_views=500".into(), "init.seed_spacing_mm_two_views=1.5".into()]).unwrap();
    assert_eq!((cfg.init.n2_two_views, cfg.init.seed_spacing_mm_two_views), (Some(500), Some(1.5)));
    let back: Config = toml::from_str(&cfg.to_toml()).unwrap();
    assert_eq!(back, cfg, "round trip through TOML");
    let err = Config::load(None, &["init.seed_spacing_mm_two_views=-1".into()]).unwrap_err().to_string();
    assert!(err.contains("init.seed_spacing_mm_two_views"), "{err}");
}

#[test]
fn the_prior_only_member_is_the_run_without_image_seeds() {
    let off = Config::load(None, &[]).unwrap();
    assert!(off.prior_only_member().is_none(), "off by default");
    let on = Config::load(None, &["run.prior_only_member=true".into()]).unwrap();
    let member = on.prior_only_member().expect("a member");
    assert_eq!((member.init.n2, member.init.n2_mode), (0, SeedMode::None));
    assert!(!member.run.prior_only_member, "a member has no member");
    let mut same = member.clone();
    same.init = on.init.clone();
    same.run.prior_only_member = true;
    assert_eq!(same, on, "only the seeds differ");
    let tracked = Config::load(None, &["run.prior_only_member=true".into(), "run.member_tracks_max_views=2".into()])
        .unwrap()
        .prior_only_member()
        .expect("a member");
    assert_eq!((tracked.init.n2_for(2), tracked.init.n2_for(3), tracked.init.n2_mode), (0, 0, on.init.n2_mode));
    assert_eq!(tracked.init.track_max_views, 2, "its seeds are the tracks of runs of up to 2 views");
    assert!(tracked.densify.reseed_at.is_empty() && tracked.run.member_tracks_max_views == 0);
    let reseeding = ["run.prior_only_member=true", "densify.reseed_at=[5, 9]"].map(String::from);
    let reseeds = |extra: &str| {
        let overrides: Vec<String> = reseeding.iter().cloned().chain([extra.to_string()]).collect();
        Config::load(None, &overrides).unwrap().prior_only_member().expect("a member").densify.reseed_at
    };
    assert!(reseeds("run.member_reseeds=false").is_empty(), "the member does not re-seed by default");
    assert_eq!(reseeds("run.member_reseeds=true"), [5, 9], "run.member_reseeds keeps the run's re-seeds");
    let member = Config::load(None, &["run.prior_only_member=true".into(), "run.member_reseeds=true".into()]).unwrap();
    let member = member.prior_only_member().expect("a member");
    assert!(member.densify.reseed_arrival_only && !member.run.member_reseeds, "where the arrival maps check them");
    assert_eq!((tracked.run.stop_after, tracked.run.steps_to_train()), (None, tracked.run.iterations));
    let short = Config::load(
        None,
        &["run.prior_only_member=true".into(), "run.iterations=300".into(), "run.member_iterations=120".into()],
    )
    .unwrap();
    let short_member = short.prior_only_member().expect("a member");
    assert_eq!((short.run.steps_to_train(), short_member.run.steps_to_train()), (300, 120));
    assert_eq!(short_member.run.iterations, 300, "the member keeps the run's schedule");
    let mut long = short.clone();
    long.run.member_iterations = 500;
    assert_eq!(long.prior_only_member().unwrap().run.steps_to_train(), 300, "never past the run's end");
    let err = Config::load(None, &["run.member_iterations=20000000".into()]).unwrap_err().to_string();
    assert!(err.contains("run.member_iterations"), "{err}");
    let unseeded = Config::load(None, &["run.prior_only_member=true".into(), "init.n2=0".into()]).unwrap();
    assert!(unseeded.prior_only_member().is_none(), "without image seeds the member would be the run");
    let no_prior = Config::load(None, &["run.prior_only_member=true".into(), "init.n1=0".into()]).unwrap();
    assert!(no_prior.prior_only_member().is_none(), "without prior Gaussians the member would be empty");
}

#[test]
fn seed_members_differ_from_the_run_only_in_their_seed() {
    assert!(Config::load(None, &[]).unwrap().seed_members().is_empty(), "none by default");
    let sets = ["run.member_seeds=[7, 8]".into(), "run.prior_only_member=true".into()];
    let on = Config::load(None, &sets).unwrap();
    let members = on.seed_members();
    assert_eq!(members.iter().map(|m| m.run.seed).collect::<Vec<_>>(), [7, 8]);
    for member in &members {
        assert!(member.seed_members().is_empty() && member.prior_only_member().is_none());
        let mut same = member.clone();
        same.run.seed = on.run.seed;
        same.run.member_seeds = on.run.member_seeds.clone();
        same.run.prior_only_member = true;
        assert_eq!(same, on, "only the seed differs");
    }
    assert!(on.prior_only_member().unwrap().seed_members().is_empty(), "the prior-only member has none");
    for bad in ["run.member_seeds=[42]", "run.member_seeds=[7, 7]", "run.member_seeds=[1,2,3,4,5,6,7,8,9]"] {
        let err = Config::load(None, &[bad.into()]).unwrap_err().to_string();
        assert!(err.contains("run.member_seeds"), "{bad}: {err}");
    }
}

#[test]
fn a_config_can_start_from_a_base_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    std::fs::write(dir.join("base.toml"), "[run]\niterations = 77\nseed = 3\n[loss]\nfn_weight = 0.5\n").unwrap();
    std::fs::write(dir.join("sub/child.toml"), "base = \"../base.toml\"\n[run]\nseed = 9\n").unwrap();
    let c = Config::load(Some(&dir.join("sub/child.toml")), &["loss.pa_k=3".into()]).unwrap();
    assert_eq!((c.run.iterations, c.run.seed, c.loss.fn_weight, c.loss.pa_k), (77, 9, 0.5, 3));
    std::fs::write(dir.join("loop.toml"), "base = \"loop.toml\"\n").unwrap();
    let err = Config::load(Some(&dir.join("loop.toml")), &[]).unwrap_err().to_string();
    assert!(err.contains("loop.toml") && err.contains("base"), "{err}");
    std::fs::write(dir.join("typo.toml"), "base = \"base.toml\"\n[run]\niteratons = 5\n").unwrap();
    let err = Config::load(Some(&dir.join("typo.toml")), &[]).unwrap_err().to_string();
    assert!(err.contains("iteratons"), "{err}");
}
