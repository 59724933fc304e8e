//! What to look for ([`DetectOptions`]) and what is found ([`Disk`]).

use crate::error::{Error, Result};

/// Whether the disks are brighter or darker than what surrounds them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Polarity {
    Bright,
    Dark,
    Either,
}

impl Polarity {
    /// The name reported in the run summary and `image-frame.json`.
    pub fn name(self) -> &'static str {
        match self {
            Polarity::Bright => "bright",
            Polarity::Dark => "dark",
            Polarity::Either => "either",
        }
    }
}

#[derive(Debug, Clone)]
pub struct DetectOptions {
    /// Radius range [px] of the disks to find.
    pub radius_min: f64,
    pub radius_max: f64,
    pub polarity: Polarity,
    /// Gaussian smoothing before the voting gradients [px]; `None` picks it
    /// from the radius (texture and noise must not outvote the boundary).
    pub smoothing_px: Option<f64>,
    /// Gaussian smoothing of the image the edges are located in [px]; `None`
    /// picks it from the noise: 1 px on clean images (so the narrow gaps at
    /// contacts keep their edges), more on noisy ones.
    pub edge_smoothing_px: Option<f64>,
    /// Fraction of a disk's visible rays whose edge must lie on the fitted circle.
    pub min_support: f64,
    /// Candidates with less support, down to this, are kept only when the
    /// final model fit confirms an edge as sharp and as strong as the
    /// confident disks' (small disks with many contacts show little rim).
    pub min_support_confirmed: f64,
    /// Fraction of the circumference that must lie inside the image.
    pub min_visible: f64,
    /// Candidate centres: accumulator maxima above this fraction of the largest.
    pub vote_threshold: f64,
    /// Smallest intensity step across the edge: two grey levels of an 8-bit
    /// image. Fainter "disks" are echoes of edges in another colour channel
    /// (JPEG's subsampled chroma) or quantisation, not disks.
    pub min_contrast: f64,
    /// Several size classes ([min, max] px each), e.g. a bidisperse packing:
    /// each is searched on its own, so sizes between them are not found.
    /// Empty: the one range `radius_min..radius_max`.
    pub classes: Vec<[f64; 2]>,
    /// Also look for disks outlined by a dark rim, whatever their interior
    /// (dim photoelastic disks darker than the background); bright polarity only.
    pub find_by_rims: bool,
    /// Two circles may cross by this fraction of the smaller radius (at least
    /// 3 px) before the less supported one is dropped: fitted outlines of
    /// real, loaded disks overlap where the disks press into each other.
    pub overlap: f64,
    /// Smallest median intensity (signed by the polarity) over the inner
    /// 0.8 R of a disk: in a colour distance a disk is a region that differs
    /// from the background, and a circle whose inside is background (fitted
    /// to a wall's or a piston's edges) is none. 0: not checked.
    pub min_fill: f64,
    /// Off by default (measured worse on some real photographs; see
    /// docs/photoelastic.md, round 8): the narrow edge passes repeat until
    /// the circle settles instead of stopping after two, so a circle left on
    /// a fringe edge beside a dim stretch of outline creeps out to it.
    pub settle_edges: bool,
    /// The photograph's own pixel in the searched picture's pixels: 1, or
    /// the factor of an up-sampled search (small disks). The support's
    /// tolerance is one such pixel plus 0.02 R: up-sampling adds no detail,
    /// and a tolerance of half a photograph's pixel lost most disks of a
    /// dense packing whose outlines merge (docs/image.md, round 13).
    pub sensor_pixel: f64,
    /// On by default (docs/image.md, rounds 15 and 16: it mends circles
    /// found inside loaded disks on rendered photographs; its cost on the
    /// real photographs' fringe fits was the box walls'): in the searches
    /// of distances from the background (the colour distance, a gray
    /// picture's distance), where a disk's outline is its last drop, each
    /// disk found is refined once more from its own circle with the
    /// outermost edge of each ray as its outline, and that reading kept
    /// when it is better supported and encloses the first.
    pub outermost_outline: bool,
}

impl DetectOptions {
    pub fn new(radius_min: f64, radius_max: f64) -> Self {
        DetectOptions {
            radius_min,
            radius_max,
            polarity: Polarity::Bright,
            smoothing_px: None,
            edge_smoothing_px: None,
            min_support: 0.45,
            min_support_confirmed: 0.3,
            min_visible: 0.3,
            vote_threshold: 0.04,
            min_contrast: 2.0 / 255.0,
            classes: Vec::new(),
            find_by_rims: true,
            overlap: 0.15,
            min_fill: 0.0,
            settle_edges: false,
            sensor_pixel: 1.0,
            outermost_outline: true,
        }
    }

    /// Options for several radius classes; `radius_min..radius_max` spans them.
    pub fn with_classes(classes: &[[f64; 2]]) -> Result<Self> {
        let bad = |why: &str| {
            let list: Vec<String> = classes
                .iter()
                .map(|c| format!("{}..{}", c[0], c[1]))
                .collect();
            Error::Invalid(format!("radius classes {}: {why}", list.join(",")))
        };
        if classes.is_empty() {
            return Err(bad("none given"));
        }
        let mut sorted = classes.to_vec();
        sorted.sort_by(|a, b| a[0].total_cmp(&b[0]));
        for c in &sorted {
            if !(c[0].is_finite() && c[1].is_finite() && c[0] >= 2.0 && c[1] >= c[0]) {
                return Err(bad("each must satisfy 2 ≤ MIN ≤ MAX pixels"));
            }
        }
        if sorted.windows(2).any(|p| p[1][0] <= p[0][1]) {
            return Err(bad("classes must not overlap"));
        }
        let mut o = DetectOptions::new(sorted[0][0], sorted[sorted.len() - 1][1]);
        if sorted.len() > 1 {
            o.classes = sorted;
        }
        Ok(o)
    }

    /// The smoothing actually used.
    pub fn smoothing(&self) -> f64 {
        self.smoothing_px
            .unwrap_or_else(|| (self.radius_min / 5.0).clamp(1.5, 5.0))
    }
}

/// A disk found in an image, in pixel coordinates (see the module docs of
/// [`crate::image`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disk {
    pub x: f64,
    pub y: f64,
    pub r: f64,
    /// Fraction of the visible rays whose edge lies on the fitted circle.
    pub support: f64,
    /// Fraction of the circumference inside the image.
    pub visible: f64,
    /// Intensity step across the edge (positive: as the polarity asked).
    pub contrast: f64,
    /// RMS distance of the inlying edge points from the circle [px].
    pub rms: f64,
}

impl Disk {
    /// Whether part of the disk lies outside the image.
    pub fn cut_by_border(&self) -> bool {
        self.visible < 0.999
    }
}
