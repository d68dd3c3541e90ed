//! The arrival maps the seed checks read: with `init.arrival_prior_unknown` the pixels of the
//! prior's projection cannot tell what fills behind the prior, and read as hidden; the maps the
//! new branches are checked against stay as the case has them; densification with
//! `densify.arrival_prune` removes the Gaussians off the prior that they call ghosts.

#![allow(deprecated)] // burn-ndarray is the CPU backend the tests use.

use burn::tensor::Device;
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::masks::prior_solid;
use ctadsa_core::data::synth::arrival::ArrivalSpec;
use ctadsa_core::data::synth::{SynthConfig, synthesize};
use ctadsa_core::data::volume::Grid;
use ctadsa_core::method::arrival::{
    HIDDEN_BY_PRIOR, ghosts_by_arrival, run_arrival_maps, run_arrival_readings, seed_arrival_maps,
};
use ctadsa_core::method::train::Trainer;

mod scratch;
use scratch::scratch;

const QUICK_TOML: &str = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/quick.toml"));

/// The small procedural case with arrival maps (7.5 frames/s, 300 mm/s), written to `name`.
fn arrival_case(name: &str) -> Case {
    arrival_case_with(name, ArrivalSpec::ideal(7.5, 300.0))
}

/// The small procedural case with the arrival maps of `spec`, written to `name`.
fn arrival_case_with(name: &str, spec: ArrivalSpec) -> Case {
    let dir = scratch(name);
    let mut synth = SynthConfig::small_procedural("arrival");
    synth.arrival = Some(spec);
    synthesize(&synth, &dir, &mut |_| {}).expect("synthesis");
    Case::load(&dir).expect("case loads")
}

#[test]
fn the_prior_projection_hides_arrival_only_when_asked() {
    let case = arrival_case("arrival-maps-case");
    let config = |unknown: bool| {
        let sets = vec!["run.views=[0,1]".to_string(), format!("init.arrival_prior_unknown={unknown}")];
        Config::from_toml_str(QUICK_TOML, "configs/quick.toml", &sets).unwrap()
    };
    let raw = seed_arrival_maps(&case, &config(false)).unwrap().expect("the case has maps");
    let masked = seed_arrival_maps(&case, &config(true)).unwrap().expect("the case has maps");
    assert_eq!(raw.len(), 2);
    assert_eq!(run_arrival_maps(&case, &config(true)).unwrap().unwrap(), raw, "the branch check reads the case's maps");
    assert!(raw.iter().flat_map(|m| &m.data).all(|&f| f != HIDDEN_BY_PRIOR));
    for (r, m) in raw.iter().zip(&masked) {
        assert_eq!(r.data.len(), m.data.len());
        let (mut hidden, mut hidden_on_vessel, mut shown) = (0usize, 0usize, 0usize);
        for (&before, &after) in r.data.iter().zip(&m.data) {
            if after == HIDDEN_BY_PRIOR {
                hidden += 1;
                hidden_on_vessel += usize::from(before >= 0.0);
            } else {
                assert_eq!(before, after, "a pixel off the prior keeps its frame");
                shown += usize::from(after >= 0.0);
            }
        }
        // The prior is a vessel: its projection is pixels that fill; the missing vessels still
        // show their own frames beside it.
        assert!(hidden > 50 && hidden_on_vessel as f64 >= 0.8 * hidden as f64, "{hidden_on_vessel} of {hidden}");
        assert!(shown > 10, "{shown} pixels keep a frame");
    }
}

/// With `densify.arrival_prune` a densification removes exactly the Gaussians off the prior whose
/// centres fill at two times (the image seeds unchecked, so that there are some); without it
/// they stay.
/// A map whose frames were detected a frame off here and there is read through the 1-pixel
/// median on its own (`run.arrival_noisy_share`); an ideal one as it is; a median set by hand
/// holds for both, and `run.arrival_noisy_share = 1` turns the choice off.
#[test]
fn noisy_arrival_maps_are_read_through_a_median_ideal_ones_as_they_are() {
    let ideal = arrival_case("arrival-maps-ideal");
    let noisy = arrival_case_with(
        "arrival-maps-noisy",
        ArrivalSpec { frame_noise: 0.5, seed: 1, ..ArrivalSpec::ideal(7.5, 300.0) },
    );
    let config = |sets: &[&str]| {
        let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        sets.push("run.views=[0,1]".into());
        Config::from_toml_str(QUICK_TOML, "configs/quick.toml", &sets).unwrap()
    };
    let maps = |case: &Case, sets: &[&str]| run_arrival_maps(case, &config(sets)).unwrap().expect("the case has maps");
    let readings = |case: &Case, sets: &[&str]| run_arrival_readings(case, &config(sets)).unwrap().unwrap();

    let (ideal_read, noisy_read) = (readings(&ideal, &[]), readings(&noisy, &[]));
    assert_eq!(ideal_read.len(), 2);
    for (i, n) in ideal_read.iter().zip(&noisy_read) {
        assert_eq!(i.view, n.view);
        assert!(i.noise < 0.1 && n.noise > 0.2, "{i:?} {n:?}");
        assert_eq!((i.median_px, n.median_px), (0, 1), "{i:?} {n:?}");
    }
    assert_eq!(maps(&ideal, &[]), maps(&ideal, &["run.arrival_noisy_share=1"]), "an ideal map is read as it is");
    assert_eq!(maps(&noisy, &[]), maps(&noisy, &["run.arrival_median_px=1"]), "a noisy one through the median");
    assert_ne!(maps(&noisy, &[]), maps(&noisy, &["run.arrival_noisy_share=1"]));
    for case in [&ideal, &noisy] {
        let by_hand = readings(case, &["run.arrival_median_px=2"]);
        assert!(by_hand.iter().all(|r| r.median_px == 2), "{by_hand:?}");
    }
}

#[test]
fn densification_prunes_the_gaussians_that_arrival_calls_ghosts() {
    let case = arrival_case("arrival-prune-case");
    let config = |prune: bool| {
        let sets = [
            "run.views=[0,1]",
            "init.arrival_seeds=false",
            "init.arrival_reseeds=true",
            "densify.enabled=true",
            "densify.from=0",
            "densify.grad_threshold=1e9",
        ]
        .map(String::from)
        .into_iter()
        .chain([format!("densify.arrival_prune={prune}")])
        .collect::<Vec<_>>();
        Config::from_toml_str(QUICK_TOML, "configs/quick.toml", &sets).unwrap()
    };
    let maps = seed_arrival_maps(&case, &config(true)).unwrap().expect("the case has maps");
    let prior = case.prior_mesh().unwrap().expect("the case has a prior");
    let trained = |prune: bool| {
        let mut t = Trainer::new(&case, config(prune), Device::ndarray().autodiff()).unwrap();
        let before = t.model().len();
        let plan = t.densify().unwrap();
        let solid = prior_solid(&prior, Grid::covering(t.working_box(), t.voxel_mm()).unwrap());
        let means: Vec<glam::DVec3> = t
            .host_gaussians()
            .0
            .chunks_exact(3)
            .map(|m| glam::DVec3::new(f64::from(m[0]), f64::from(m[1]), f64::from(m[2])))
            .collect();
        let init = &t.cfg().init;
        let (tolerance, exit) = (init.arrival_tolerance_frames as f32, init.arrival_prior_exit_px);
        let ghosts = ghosts_by_arrival(t.views().views(), &maps, Some(&solid), &means, tolerance, exit);
        (before, plan.pruned, t.model().len(), ghosts.iter().filter(|&&g| g).count())
    };
    let (before, pruned_off, left_off, ghosts_off) = trained(false);
    let (before_on, pruned_on, left_on, ghosts_on) = trained(true);
    eprintln!(
        "{before} Gaussians; without the prune {pruned_off} pruned, {ghosts_off} ghosts left; with it {pruned_on}, {ghosts_on}"
    );
    assert_eq!(before, before_on, "the same start");
    assert!(ghosts_off >= 10, "unchecked image seeds leave ghosts to prune: {ghosts_off}");
    assert_eq!(ghosts_on, 0, "no ghost left after the prune");
    assert_eq!(pruned_on, pruned_off + ghosts_off, "exactly the ghosts pruned");
    assert_eq!(left_off - left_on, ghosts_off);
}
