//! The seeds' arrival-time checks: which candidates fill at once in both views of a two-view run
//! (`init.arrival_seeds`, `init.arrival_track_starts`, `init.arrival_reseeds`).

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;

use super::Scored;
use crate::config::InitConfig;
use crate::data::case::images::Image;
use crate::method::arrival::arrives_together;

/// The `candidates` whose points fill at once in both `views` ([`arrives_together`] with the
/// two views' arrival `maps`, within `init.arrival_tolerance_frames`).
pub(crate) fn arriving(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    maps: &[Image],
    candidates: impl IntoParallelIterator<Item = Scored>,
) -> Vec<Scored> {
    let together = fills_at_once(cfg, views, maps);
    candidates.into_par_iter().filter(|(_, c, _)| together(*c)).collect()
}

/// Whether a point fills at once in both `views` ([`arrives_together`] with the two views'
/// arrival `maps`, within `init.arrival_tolerance_frames`, the prior's exit window
/// `init.arrival_prior_exit_px`).
pub(super) fn fills_at_once<'a>(
    cfg: &InitConfig,
    views: &'a [ConeBeamView],
    maps: &'a [Image],
) -> impl Fn(DVec3) -> bool + Sync + 'a {
    let tolerance = cfg.arrival_tolerance_frames as f32;
    // Maps without the prior hidden (`arrival_prior_unknown` off) never open the window.
    let exit = cfg.arrival_prior_exit_px;
    move |p| arrives_together(views, maps, p, tolerance, exit)
}

/// The two views' arrival maps, where a run of two views has them and checks seeds with them
/// (`init.arrival_seeds`, `init.arrival_track_starts`, `init.arrival_reseeds`).
pub(crate) fn arrival_pair<'m>(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    arrival: Option<&'m [Image]>,
) -> Option<&'m [Image]> {
    arrival.filter(|m| cfg.checks_arrival() && views.len() == 2 && m.len() == 2)
}
