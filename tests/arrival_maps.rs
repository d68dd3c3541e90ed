//! The arrival maps the seed checks read: with `init.arrival_prior_unknown` the pixels of the
//! prior's projection cannot tell what fills behind the prior, and read as hidden; the maps the
//! new branches are checked against stay as the case has them.

use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::synth::arrival::ArrivalSpec;
use ctadsa_core::data::synth::{SynthConfig, synthesize};
use ctadsa_core::method::arrival::{HIDDEN_BY_PRIOR, run_arrival_maps, seed_arrival_maps};

mod scratch;
use scratch::scratch;

const QUICK_TOML: &str = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/quick.toml"));

#[test]
fn the_prior_projection_hides_arrival_only_when_asked() {
    let dir = scratch("arrival-maps-case");
    let mut synth = SynthConfig::small_procedural("arrival");
    synth.arrival = Some(ArrivalSpec { frames_per_s: 7.5, flow_mm_s: 300.0 });
    synthesize(&synth, &dir, &mut |_| {}).expect("synthesis");
    let case = Case::load(&dir).expect("case loads");
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
