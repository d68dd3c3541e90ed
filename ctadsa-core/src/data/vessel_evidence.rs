//! What a view shows of its vessels, pooled along them where the view is noisy.
//!
//! In a view with quantum or electronic noise each pixel of a thin vessel can lie below the
//! per-pixel noise floor (3 σ) while the line of pixels it belongs to does not. Read along lines
//! of [`LINE_PX`] pixels through each pixel in [`ORIENTATIONS`] directions ([`LineReadings`]),
//! a straight vessel keeps its value and the noise shrinks by two to three: the masks find
//! vessels at under half the per-pixel floor. The lines also lose detail (vessel edges and
//! bends) and widen a vessel by the pixels beside it, so a pooled view reads along lines only
//! the pixels that do not clear 3 σ on their own, and of those only the ones that lean to vessel
//! themselves ([`POOLED_PIXEL_SIGMAS`]); the rest keep their values. With two views every pixel
//! of a noisy view is read along lines ([`Reading`]). Views whose noise is low against their
//! vessels ([`POOLED_NOISE_SHARE`], [`POOLED_NOISE_SHARE_TWO_VIEWS`]), noise-free ones
//! ([`noise_sigma`] 0) among them, are read per pixel.

use std::borrow::Cow;
use std::sync::OnceLock;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use crate::data::case::images::Image;
use crate::data::masks::{Mask, NOISE_FLOOR_SIGMAS, above, noise_sigma};
use crate::data::projector::noise::standard_normal;
use crate::stats::percentile;

/// Pixels on each line (odd: the line is centred on the pixel it scores).
pub const LINE_PX: usize = 9;
/// Directions of the lines, evenly spread over 180°.
pub const ORIENTATIONS: usize = 12;
/// The fewest pixels of a line, cut short by the image's edge, that are read.
pub const MIN_LINE_PX: usize = LINE_PX / 2 + 1;

/// The pixel offsets (column, row) of each orientation's line, nearest pixels.
fn line_offsets() -> [[(i32, i32); LINE_PX]; ORIENTATIONS] {
    let half = (LINE_PX / 2) as i32;
    std::array::from_fn(|k| {
        let angle = k as f64 * std::f64::consts::PI / ORIENTATIONS as f64;
        let (sin, cos) = angle.sin_cos();
        std::array::from_fn(|i| {
            let t = (i as i32 - half) as f64;
            ((t * cos).round() as i32, (t * sin).round() as i32)
        })
    })
}

/// A view pooled along lines through each pixel: the two readings [`VesselEvidence`] takes.
#[derive(Debug, Clone, PartialEq)]
pub struct LineReadings {
    /// Each pixel the largest over [`ORIENTATIONS`] of the smaller of the means of its line's
    /// two halves ([`MIN_LINE_PX`] pixels each, the pixel itself in both): high where a vessel
    /// runs on both sides of the pixel, so it finds thin vessels and does not lengthen their
    /// ends; the noise of the best of the directions lifts it, most beside a vessel, where one
    /// half of a crossing line reads only noise. Lines that leave the image are not read; where
    /// every one does (near two edges) the pixel keeps its own value.
    pub along: Image,
    /// Each pixel the mean of its line along which the image varies least: along a vessel, a
    /// vessel's edge or anywhere in a flat background. The choice follows the variance, not the
    /// mean, so the noise lifts no pixel and beside a vessel the line runs beside it too. Near
    /// the image's edges a line is read where it lies on the image, if that is at least
    /// [`MIN_LINE_PX`] pixels.
    pub least_varying: Image,
}

/// The [`LineReadings`] of `image`.
pub fn line_readings(image: &Image) -> LineReadings {
    let (w, h) = (image.width as i32, image.height as i32);
    let lines = line_offsets();
    let centre = LINE_PX / 2;
    let pairs: Vec<(f32, f32)> = (0..image.data.len())
        .into_par_iter()
        .map(|i| {
            let (c, r) = ((i % w as usize) as i32, (i / w as usize) as i32);
            let own = image.data[i] as f64;
            let mut along = f64::NEG_INFINITY;
            let (mut least_variance, mut mean_along) = (f64::INFINITY, own);
            for line in &lines {
                let (mut n, mut sum, mut sum_sq) = (0usize, 0.0f64, 0.0f64);
                let mut halves = [0.0f64; 2];
                for (k, &(dc, dr)) in line.iter().enumerate() {
                    let (cc, rr) = (c + dc, r + dr);
                    if cc >= 0 && rr >= 0 && cc < w && rr < h {
                        let v = image.data[(rr * w + cc) as usize] as f64;
                        (n, sum, sum_sq) = (n + 1, sum + v, sum_sq + v * v);
                        if k <= centre {
                            halves[0] += v;
                        }
                        if k >= centre {
                            halves[1] += v;
                        }
                    }
                }
                if n == LINE_PX {
                    along = along.max(halves[0].min(halves[1]) / MIN_LINE_PX as f64);
                }
                if n >= MIN_LINE_PX {
                    let mean = sum / n as f64;
                    // Unbiased, so that lines cut short by the image's edge compete fairly.
                    let variance = (sum_sq - n as f64 * mean * mean) / (n - 1) as f64;
                    if variance < least_variance {
                        (least_variance, mean_along) = (variance, mean);
                    }
                }
            }
            let along = if along == f64::NEG_INFINITY { own } else { along };
            (along as f32, mean_along as f32)
        })
        .collect();
    let image_of = |data: Vec<f32>| Image { width: image.width, height: image.height, data };
    LineReadings {
        along: image_of(pairs.iter().map(|p| p.0).collect()),
        least_varying: image_of(pairs.iter().map(|p| p.1).collect()),
    }
}

/// The share of a noise-only background that the per-pixel floor
/// ([`crate::data::masks::NOISE_FLOOR_SIGMAS`] = 3 σ, a one-sided normal tail) lets through:
/// 0.135 %; each pooled floor lets through the same.
const FLOOR_TAIL: f64 = 0.001_35;

/// The floors of [`LineReadings::along`] and [`LineReadings::least_varying`] in units of the
/// view's noise σ: the quantiles of the readings of unit white Gaussian noise that
/// 0.135 % of it exceeds, from a seeded 512² field (the same numbers on every machine).
pub fn pooled_floors_sigmas() -> (f64, f64) {
    static FLOORS: OnceLock<(f64, f64)> = OnceLock::new();
    *FLOORS.get_or_init(|| {
        let n = 512u32;
        let mut rng = ChaCha8Rng::seed_from_u64(0x7e55_e15e);
        let data = (0..n * n).map(|_| standard_normal(&mut rng) as f32).collect();
        let readings = line_readings(&Image { width: n, height: n, data });
        let quantile = |image: &Image| {
            let values: Vec<f64> = image.data.iter().map(|&v| v as f64).collect();
            percentile(&values, 100.0 * (1.0 - FLOOR_TAIL))
        };
        (quantile(&readings.along), quantile(&readings.least_varying))
    })
}

/// In a run with three views or more a view is pooled when its noise σ exceeds this share of
/// its bright value (the 99.5th percentile of its pixels above 3 σ), i.e. where the per-pixel floor
/// lies more than about a quarter above the level that `mask_threshold = 0.05` asks. On the shared
/// BraVa trees the views at σ = 0.1 lie at 0.009–0.019, at σ = 0.15 at 0.012–0.026, at σ = 0.2 at
/// 0.015–0.032; pooled under 3 σ, a σ = 0.1 tree scored worse than per pixel and the σ = 0.15 trees
/// better in the mean, at the same shares: the share does not say where pooling pays between the
/// two (docs/RESULTS.md, "Noisy views"). A run with one view above it reads all its views so
/// ([`ViewReading::of_run`]).
pub const POOLED_NOISE_SHARE: f64 = 0.021;

/// In a run with two views a view is pooled (wholly along lines) when its noise σ exceeds this
/// share of its bright value: every view of the shared BraVa trees at σ = 0.1, 0.15 and 0.2 (the
/// lowest 0.009). Pooled, the 4 BG trees scored better than per pixel at σ = 0.15 and 0.2 on both
/// CD_ROI and HD95_ROI; at σ = 0.1 all 8 trees scored HD95_ROI better on 6 of 8 and CD_ROI about
/// the same (4 of 8; docs/RESULTS.md, "Noisy views"). Below it, not measured, a view is read per
/// pixel.
pub const POOLED_NOISE_SHARE_TWO_VIEWS: f64 = 0.008;

/// The 99.5th percentile of the pixels of `image` above 0 and `floor`; `None` where none is.
fn shown_bright(image: &Image, floor: f64) -> Option<f64> {
    let shown: Vec<f64> = image.data.iter().filter(|&&v| v > 0.0 && v as f64 > floor).map(|&v| v as f64).collect();
    (!shown.is_empty()).then(|| percentile(&shown, 99.5))
}

/// How a view's pixels are read for its vessels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reading {
    /// Each pixel its own value, above 3 σ ([`NOISE_FLOOR_SIGMAS`]): noise-free views, and the
    /// views of a run none of whose views' noise is high against its vessels
    /// ([`POOLED_NOISE_SHARE`], [`POOLED_NOISE_SHARE_TWO_VIEWS`]).
    PerPixel,
    /// Each pixel its line reading ([`LineReadings::along`]), counted as vessel where its least
    /// varying line stands above its floor too: a noisy view of a run with two views, which needs every
    /// pixel of a thin vessel (two views have no third to place a vessel whose mask breaks up).
    AlongLines,
    /// The pixels under 3 σ their line readings, the others their own values ([`pooled_evidence`]):
    /// a noisy view of a run with three views or more, which keeps the vessels' edges and bends.
    UnderFloorAlongLines,
}

impl Reading {
    /// How a view whose noise is `noise_sigma` and bright value `bright` (image units) is read in
    /// a run with `views` views.
    pub fn of(noise_sigma: f64, bright: Option<f64>, views: usize) -> Self {
        let share = if views <= 2 { POOLED_NOISE_SHARE_TWO_VIEWS } else { POOLED_NOISE_SHARE };
        let noisy = noise_sigma > 0.0 && bright.is_some_and(|b| noise_sigma > share * b);
        match (noisy, views) {
            (false, _) => Self::PerPixel,
            (true, 0..=2) => Self::AlongLines,
            (true, _) => Self::UnderFloorAlongLines,
        }
    }
}

/// How a view is read for its vessels, as a run reports it (`summary.json` → `view_readings`):
/// its noise, its bright value and its [`Reading`] ([`ViewReading::of_run`] decides by these
/// numbers, the run's view count and its other views).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewReading {
    /// The view's name in the case.
    pub view: String,
    /// The view's noise standard deviation ([`noise_sigma`]; image units, 0 for a noise-free view).
    pub noise_sigma: f64,
    /// Its bright value: the 99.5th percentile of its pixels above 0 and 3 σ (image units);
    /// `None` where no pixel is.
    pub bright: Option<f64>,
    /// How its pixels are read.
    pub reading: Reading,
}

impl ViewReading {
    /// The reading of `image`, the view named `view`, on its own in a run with `views` views.
    pub fn of(image: &Image, view: &str, views: usize) -> Self {
        let noise_sigma = noise_sigma(image);
        let bright = shown_bright(image, NOISE_FLOOR_SIGMAS * noise_sigma);
        Self { view: view.to_string(), noise_sigma, bright, reading: Reading::of(noise_sigma, bright, views) }
    }

    /// The readings of a run's views (`images`, named `names`): a run reads its views one way.
    /// Where any view is noisy ([`Reading::of`]) every view with noise is read as the view count
    /// says; views read differently (one per pixel beside pooled ones) scored worse than all
    /// pooled on every tree measured (docs/RESULTS.md, "Noisy views").
    pub fn of_run(images: &[Image], names: &[&str]) -> Vec<Self> {
        let views = images.len();
        let mut readings: Vec<Self> = images
            .iter()
            .enumerate()
            .map(|(i, image)| Self::of(image, names.get(i).copied().unwrap_or(""), views))
            .collect();
        if let Some(pooled) = readings.iter().map(|r| r.reading).find(|&r| r != Reading::PerPixel) {
            for reading in readings.iter_mut().filter(|r| r.noise_sigma > 0.0) {
                reading.reading = pooled;
            }
        }
        readings
    }
}

/// How many noise σ a pixel of a pooled view must itself stand above 0 for its line's reading to
/// count: beside a vessel the best of the lines through a background pixel reads the vessel's
/// edge, and such a pixel passes this in 6.7 % of cases; a pixel of a vessel of 2 σ in 69 %, of
/// 3 σ in 93 %. It keeps the pooled masks from widening the vessels and from lowering the
/// iso-level matched to them (docs/RESULTS.md, "Noisy views").
pub const POOLED_PIXEL_SIGMAS: f64 = 1.5;

/// A view read [`Reading::UnderFloorAlongLines`] at noise `sigma` (image units): each pixel above
/// the per-pixel floor (3 σ) its own value; a pixel above [`POOLED_PIXEL_SIGMAS`] whose least
/// varying line stands above its floor too its [`LineReadings::along`]; any other pixel 0 (it
/// shows nothing the noise could not).
pub fn pooled_evidence(image: &Image, sigma: f64) -> Image {
    let readings = line_readings(image);
    let (_, least_varying_floor) = pooled_floors_sigmas();
    let (own_floor, pixel_floor, settled_floor) =
        (NOISE_FLOOR_SIGMAS * sigma, POOLED_PIXEL_SIGMAS * sigma, least_varying_floor * sigma);
    let data = (image.data.iter().zip(&readings.along.data).zip(&readings.least_varying.data))
        .map(|((&own, &along), &least_varying)| {
            if own as f64 > own_floor {
                own
            } else if own as f64 > pixel_floor && least_varying as f64 > settled_floor {
                along
            } else {
                0.0
            }
        })
        .collect();
    Image { width: image.width, height: image.height, data }
}

/// What a view shows of its vessels, read as its [`Reading`] says: per pixel, every pixel along
/// lines, or the pixels under 3 σ along lines ([`pooled_evidence`]) with their floor at 1.2 σ
/// ([`pooled_floors_sigmas`]); 0 for a noise-free view.
#[derive(Debug, Clone)]
pub struct VesselEvidence<'a> {
    /// The values a vessel is read from (image units).
    pub image: Cow<'a, Image>,
    /// The level below which no pixel of `image` counts as vessel whatever the threshold asks
    /// (image units; 3 σ per pixel, the line reading's floor pooled, 0 for a noise-free view).
    pub noise_floor: f64,
    /// How the view is read.
    pub reading: Reading,
    /// The view's noise σ (image units).
    sigma: f64,
    /// The bright value of `image` ([`Self::bright`]).
    bright: Option<f64>,
    /// Read [`Reading::AlongLines`]: the pixels whose least varying line stands above its floor.
    settled: Option<Mask>,
}

impl<'a> VesselEvidence<'a> {
    /// The evidence of `image`, on its own a view of a run with `views` views (the tests' view
    /// by view; a run reads its views through [`Self::of_views`]).
    #[cfg(test)]
    pub(crate) fn of(image: &'a Image, views: usize) -> Self {
        let ViewReading { noise_sigma, reading, .. } = ViewReading::of(image, "", views);
        Self::read_as(image, noise_sigma, reading)
    }

    /// The evidence of `image`, whose noise is `sigma`, read as `reading` says.
    fn read_as(image: &'a Image, sigma: f64, reading: Reading) -> Self {
        let (along_floor, least_varying_floor) = pooled_floors_sigmas();
        match reading {
            Reading::PerPixel => Self::per_pixel(image, sigma),
            Reading::AlongLines => {
                let readings = line_readings(image);
                let noise_floor = along_floor * sigma;
                Self {
                    bright: shown_bright(&readings.along, noise_floor),
                    settled: Some(above(&readings.least_varying, least_varying_floor * sigma)),
                    image: Cow::Owned(readings.along),
                    noise_floor,
                    reading,
                    sigma,
                }
            }
            Reading::UnderFloorAlongLines => Self {
                image: Cow::Owned(pooled_evidence(image, sigma)),
                noise_floor: along_floor * sigma,
                reading,
                sigma,
                bright: shown_bright(image, 0.0),
                settled: None,
            },
        }
    }

    /// The evidence of `image`, whose noise is `sigma`, read per pixel: its pixels above the
    /// level and 3 σ ([`NOISE_FLOOR_SIGMAS`]).
    fn per_pixel(image: &'a Image, sigma: f64) -> Self {
        Self {
            image: Cow::Borrowed(image),
            noise_floor: NOISE_FLOOR_SIGMAS * sigma,
            reading: Reading::PerPixel,
            sigma,
            bright: shown_bright(image, 0.0),
            settled: None,
        }
    }

    /// The evidence of each of a run's views, read as [`ViewReading::of_run`] says.
    pub fn of_views(images: &'a [Image]) -> Vec<Self> {
        let readings = ViewReading::of_run(images, &[]);
        images.iter().zip(readings).map(|(image, r)| Self::read_as(image, r.noise_sigma, r.reading)).collect()
    }

    /// Whether the view was pooled (read along lines, wholly or under 3 σ).
    pub fn pooled(&self) -> bool {
        self.reading != Reading::PerPixel
    }

    /// `other` (an image of the same view, e.g. a residual) read as this view is, at the view's
    /// noise.
    pub fn read(&self, other: Image) -> Image {
        match self.reading {
            Reading::PerPixel => other,
            Reading::AlongLines => line_readings(&other).along,
            Reading::UnderFloorAlongLines => pooled_evidence(&other, self.sigma),
        }
    }

    /// The view's bright value: the 99.5th percentile of the positive pixels of the view itself
    /// (read per pixel or under 3 σ along lines, so that those readings move no level), or of its
    /// line readings above the noise floor (read wholly along lines: there the best of the lines
    /// lifts most of the background above 0); `None` where no pixel counts.
    pub fn bright(&self) -> Option<f64> {
        self.bright
    }

    /// The image value that defines "vessel": `threshold ×` [`Self::bright`], and at least the
    /// noise floor (0 where no pixel shows anything).
    pub fn level(&self, threshold: f64) -> f64 {
        self.bright().map_or(0.0, |bright| (threshold * bright).max(self.noise_floor))
    }

    /// Whether pixel `i` (row-major) may count as vessel beside its value: always, except in a
    /// view read wholly along lines, where its least varying line must stand above its floor.
    pub fn settled_at(&self, i: usize) -> bool {
        self.settled.as_ref().is_none_or(|m| m.data[i])
    }

    /// The vessel pixels: the evidence above [`Self::level`] (and settled).
    pub fn mask(&self, threshold: f64) -> Mask {
        let above_level = above(&self.image, self.level(threshold));
        match &self.settled {
            Some(settled) => above_level.and(settled),
            None => above_level,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 256² flat background with a straight band `width_px` wide of `value` (a vessel) at 30°,
    /// plus Gaussian noise of `sigma`; the band's pixels as a mask.
    fn faint_vessel(value: f64, width_px: f64, sigma: f64) -> (Image, Vec<bool>) {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let n = 256usize;
        let (sin, cos) = (30f64.to_radians()).sin_cos();
        let on: Vec<bool> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f64 - 128.0, (i / n) as f64 - 128.0);
                (-x * sin + y * cos).abs() < width_px / 2.0
            })
            .collect();
        let data =
            on.iter().map(|&v| (if v { value } else { 0.0 } + sigma * standard_normal(&mut rng)) as f32).collect();
        (Image { width: n as u32, height: n as u32, data }, on)
    }

    #[test]
    fn a_noise_free_view_is_read_as_it_is() {
        let (image, _) = faint_vessel(1.0, 2.0, 0.0);
        for views in [2, 3] {
            let evidence = VesselEvidence::of(&image, views);
            assert!(!evidence.pooled());
            assert_eq!(evidence.noise_floor, 0.0);
            assert_eq!(*evidence.image, image);
            let masks = crate::data::masks::vessel_masks(&vec![image.clone(); views], 0.5);
            assert_eq!(evidence.mask(0.5), masks[0]);
        }
    }

    #[test]
    fn a_view_with_little_noise_against_its_vessels_is_read_per_pixel() {
        // σ 0.005 against vessels of 1: the per-pixel floor (0.015) lies far under the level the
        // threshold asks (0.05), and the view is read as it is.
        let (image, _) = faint_vessel(1.0, 3.0, 0.005);
        let evidence = VesselEvidence::of(&image, 3);
        assert!(!evidence.pooled());
        assert_eq!(*evidence.image, image);
        assert!((evidence.noise_floor / (NOISE_FLOOR_SIGMAS * 0.005) - 1.0).abs() < 0.2, "{}", evidence.noise_floor);
        // The same vessels under σ 0.2 are pooled: wholly along lines with two views, under 3 σ
        // with three.
        let (noisy, _) = faint_vessel(1.0, 3.0, 0.2);
        assert_eq!(VesselEvidence::of(&noisy, 2).reading, Reading::AlongLines);
        assert_eq!(VesselEvidence::of(&noisy, 3).reading, Reading::UnderFloorAlongLines);
        // The run's report of each view says the same, with the numbers it was decided by.
        let (quiet, loud) = (ViewReading::of(&image, "ap", 3), ViewReading::of(&noisy, "lat", 3));
        assert_eq!(
            (quiet.view.as_str(), quiet.reading, loud.reading),
            ("ap", Reading::PerPixel, Reading::UnderFloorAlongLines)
        );
        assert_eq!(ViewReading::of(&noisy, "lat", 2).reading, Reading::AlongLines);
        assert!((quiet.noise_sigma / 0.005 - 1.0).abs() < 0.2 && (loud.noise_sigma / 0.2 - 1.0).abs() < 0.2);
        for reading in [&quiet, &loud] {
            let bright = reading.bright.expect("the vessel shows");
            assert_eq!(reading.reading != Reading::PerPixel, reading.noise_sigma > POOLED_NOISE_SHARE * bright);
            let two_views = Reading::of(reading.noise_sigma, reading.bright, 2);
            assert_eq!(two_views != Reading::PerPixel, reading.noise_sigma > POOLED_NOISE_SHARE_TWO_VIEWS * bright);
        }
        let (noise_free, _) = faint_vessel(1.0, 3.0, 0.0);
        let clean = ViewReading::of(&noise_free, "oblique", 2);
        assert_eq!((clean.noise_sigma, clean.bright, clean.reading), (0.0, Some(1.0), Reading::PerPixel));
    }

    #[test]
    fn a_run_reads_its_views_one_way() {
        // One quiet view (σ 0.005, per pixel on its own) beside two noisy ones: with the noisy
        // views in the run, the quiet one is read as they are; a noise-free view stays as it is.
        let (quiet, _) = faint_vessel(1.0, 3.0, 0.005);
        let (noisy, _) = faint_vessel(1.0, 3.0, 0.2);
        let (noise_free, _) = faint_vessel(1.0, 3.0, 0.0);
        assert_eq!(ViewReading::of(&quiet, "ap", 3).reading, Reading::PerPixel);
        let images = [quiet.clone(), noisy.clone(), noisy.clone()];
        let run = ViewReading::of_run(&images, &["ap", "lat", "oblique"]);
        assert_eq!(run.iter().map(|r| r.view.as_str()).collect::<Vec<_>>(), ["ap", "lat", "oblique"]);
        assert!(run.iter().all(|r| r.reading == Reading::UnderFloorAlongLines), "{run:?}");
        let evidence = VesselEvidence::of_views(&images);
        assert!(evidence.iter().all(|e| e.reading == Reading::UnderFloorAlongLines));
        assert_eq!(*evidence[0].image, pooled_evidence(&quiet, run[0].noise_sigma));
        // Two views: the quiet one wholly along lines.
        let pair = ViewReading::of_run(&images[..2], &["ap", "lat"]);
        assert!(pair.iter().all(|r| r.reading == Reading::AlongLines), "{pair:?}");
        // A noise-free view in a noisy run, and a run with no noisy view.
        let mixed = ViewReading::of_run(&[noise_free.clone(), noisy.clone(), noisy], &[]);
        assert_eq!(mixed.iter().map(|r| r.reading).collect::<Vec<_>>()[0], Reading::PerPixel);
        let calm = ViewReading::of_run(&[quiet.clone(), noise_free, quiet], &[]);
        assert!(calm.iter().all(|r| r.reading == Reading::PerPixel), "{calm:?}");
    }

    #[test]
    fn the_pooled_floors_let_through_as_much_noise_as_three_sigma_per_pixel() {
        let (along, least_varying) = pooled_floors_sigmas();
        // Well below the per-pixel floor: a line's mean shrinks the noise by 2 to 3, the choice of
        // the line lifts it a little.
        for floor in [along, least_varying] {
            assert!(floor > 0.8 && floor < 0.5 * NOISE_FLOOR_SIGMAS, "{floor}");
        }
        // An independent noise field: about the same share above the floor.
        let (noise, _) = faint_vessel(0.0, 0.0, 0.2);
        for views in [2, 3] {
            let evidence = VesselEvidence::of(&noise, views);
            assert!(evidence.pooled());
            let share = evidence.mask(0.0).count() as f64 / noise.data.len() as f64;
            assert!(share < 2.0 * FLOOR_TAIL, "{views} views: {share}");
        }
    }

    #[test]
    fn a_vessel_under_the_per_pixel_floor_stands_out_along_its_line_without_widening() {
        // 2 px wide at 2 σ: per pixel the 3 σ floor takes a sixth of it.
        let sigma = 0.2;
        let (image, on) = faint_vessel(2.0 * sigma, 2.0, sigma);
        let per_pixel = above(&image, NOISE_FLOOR_SIGMAS * sigma);
        let count = |m: &Mask, vessel: bool| m.data.iter().zip(&on).filter(|&(&s, &v)| s && v == vessel).count();
        let vessel_px = on.iter().filter(|&&v| v).count();
        assert!(count(&per_pixel, true) * 5 < vessel_px, "per pixel {} of {vessel_px}", count(&per_pixel, true));
        // Wholly along lines (two views) and under 3 σ (three).
        for views in [2, 3] {
            let evidence = VesselEvidence::of(&image, views);
            assert!(evidence.pooled());
            let pooled = evidence.mask(0.0);
            eprintln!("{views} views: pooled {} of {vessel_px}, {} off", count(&pooled, true), count(&pooled, false));
            assert!(
                count(&pooled, true) * 10 > 3 * vessel_px,
                "{views} views: pooled {} of {vessel_px}",
                count(&pooled, true)
            );
            assert!(count(&pooled, true) > 2 * count(&per_pixel, true));
            // Off the vessel: about the background's share, and a few pixels along its edges.
            let off_px = on.len() - vessel_px;
            assert!((count(&pooled, false) as f64) < 2.0 * FLOOR_TAIL * off_px as f64 + 0.05 * vessel_px as f64);
        }
    }

    #[test]
    fn a_bright_vessel_keeps_its_pixels_and_its_width_in_a_pooled_view() {
        // A 6 px vessel of 1 under σ 0.05: pooled (σ over 2.1 % of the bright value), yet every
        // pixel above 3 σ keeps its own value, and the mask is as wide as the per-pixel one.
        let sigma = 0.05;
        let (image, on) = faint_vessel(1.0, 6.0, sigma);
        let evidence = VesselEvidence::of(&image, 3);
        assert_eq!(evidence.reading, Reading::UnderFloorAlongLines);
        let estimated = noise_sigma(&image);
        for (i, (&own, &read)) in image.data.iter().zip(&evidence.image.data).enumerate() {
            if own as f64 > NOISE_FLOOR_SIGMAS * estimated {
                assert_eq!(read, own, "pixel {i}");
            }
        }
        let beside = |m: &Mask| m.data.iter().zip(&on).filter(|&(&s, &v)| s && !v).count();
        let (pooled, per_pixel) = (evidence.mask(0.05), VesselEvidence::per_pixel(&image, estimated).mask(0.05));
        let vessel_px = on.iter().filter(|&&v| v).count();
        // The line readings alone put a pixel or more beside the vessel into the mask along both
        // its edges (350 pixels against 100 of the noise per pixel); the pooled evidence few more
        // than the per-pixel one (130).
        let along_only = above(&line_readings(&image).along, evidence.level(0.05));
        assert!(beside(&along_only) * 20 > vessel_px, "the line readings widen: {}", beside(&along_only));
        let (pooled_beside, per_pixel_beside, along_beside) =
            (beside(&pooled), beside(&per_pixel), beside(&along_only));
        eprintln!("beside the vessel: pooled {pooled_beside}, per pixel {per_pixel_beside}, along only {along_beside}");
        assert!(
            (pooled_beside - per_pixel_beside.min(pooled_beside)) * 5 < along_beside - per_pixel_beside,
            "pooled {pooled_beside}, per pixel {per_pixel_beside}, along only {along_beside}"
        );
        // The bright value and so the level are the view's own.
        assert_eq!(evidence.bright(), VesselEvidence::per_pixel(&image, estimated).bright());
    }

    #[test]
    fn both_readings_keep_a_clean_band_and_nothing_beside_it() {
        let (image, _) = faint_vessel(1.0, 3.0, 0.0);
        let readings = line_readings(&image);
        let n = image.width as usize;
        let (sin, cos) = (30f64.to_radians()).sin_cos();
        for reading in [&readings.along, &readings.least_varying] {
            for (i, &v) in reading.data.iter().enumerate() {
                let (x, y) = ((i % n) as f64 - 128.0, (i / n) as f64 - 128.0);
                let from_axis = (-x * sin + y * cos).abs();
                // (Lines that would leave the image are not read: the border is left out.)
                let inside = x.abs() < 124.0 && y.abs() < 124.0;
                if from_axis >= 2.5 && inside {
                    assert_eq!(v, 0.0, "pixel {i} a pixel or more beside the band");
                } else if from_axis < 0.5 && inside {
                    assert_eq!(v, 1.0, "pixel {i} on the band's axis");
                }
            }
        }
    }
}
