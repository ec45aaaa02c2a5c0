//! Stripe coding: which laser stripe each extracted point belongs to (stripe 0 has the smallest x at the belt).
//!
//! Over a realistic measuring range a stripe moves across the image by more than the stripe pitch, so a point's
//! column alone does not say which stripe it is. The coder combines three kinds of evidence, and drops (and counts)
//! every point the evidence does not settle; it never guesses.
//!
//! 1. **Geometry, per scan line.** The calibrated model gives, for every row, the band of columns each stripe can
//!    occupy over the measuring range, and the height each candidate label implies. Labels along a row increase
//!    with the column (the ordering constraint), except that one sheet may be seen twice where an edge runs along
//!    the row (its upper part on the upper surface, the rest beyond the edge lower down; see `Transitions::cost`):
//!    a repeated label, the second point lower by more than a jump, costs what a false point costs. A labelling of
//!    the row is scored by the stripes it declares missing and the points it declares false: a stripe may vanish
//!    where the surface rises away from the projector (the sheet hits a wall the camera cannot see, or a belt spot
//!    hidden from the camera), or where it leaves the image at the height of its neighbours, almost for free;
//!    anywhere else a missing stripe costs [`CodingParams::skip_cost`]. Each point's label is decided from
//!    min-marginals of that score (a forward and a backward pass of dynamic programming over the row): it is kept
//!    only when the best labelling that gives it this label beats every labelling that gives it another (or none)
//!    by [`CodingParams::margin`].
//! 2. **Segments, with the paper's stripe-coding rules.** Points are linked down the image into segments by the
//!    rule base `rules/stripe_coding.fll` (rules 1 and 4: a point joins a segment when its height is not very
//!    small and not very different from its neighbour's; rules 2 and 3: a gap is bridged when it is very small, or
//!    very large with similar heights at its boundaries; rule 5: very short segments are ignored). Heights are the
//!    ones the candidate label implies. The rules are evaluated through the fuzzy crate once, when the coder is
//!    built, into tables over their inputs (the same min/max inference, sampled finely enough that the decisions
//!    match; see [`FuzzyTables`]), because one evaluation costs microseconds and a frame has thousands of points.
//! 3. **Segment vote.** A segment takes the label most of its confidently coded points agree on (at least
//!    [`CodingParams::min_vote_share`] of them); its undecided points inherit it where the geometry allows, and
//!    points that confidently disagree are dropped. Points on the belt (height very small, which rule 1 keeps out
//!    of segments) keep their per-row decision, unless it breaks the row's order with the labels the segments
//!    voted for the row's points on both sides of it (a row near a plate's edge read one stripe over as a whole).
//!
//! Fragments — points extraction marked cut ([`StripePoint::cut`]: a profile that falls to the background in one
//! pixel on one side) that are also much dimmer than their row's other points ([`CodingParams::fragment_intensity`])
//! — and points much dimmer than the light beside them in the row, cut or not ([`CodingParams::faint_intensity`])
//! — are left out of the row labelling and of the votes: the fragment a sheet's tail throws on a part's far corner
//! would otherwise pass for one more stripe and shift the reading of the whole row by one. They join the segment
//! they line up with and take its label; a fragment no segment claims is dropped as false. A cut point as bright as
//! its row's stripes (a stripe half hidden by a hole's side) is read like any other.
//!
//! Only scan lines along image rows are supported (stripes roughly vertical, the paper's set-up), because the
//! ordering constraint holds along the direction that crosses the stripes.

mod coder;
mod row;
mod tables;
mod temporal;

pub use coder::StripeCoder;
pub use tables::FuzzyTables;
pub use temporal::{TemporalParams, reconcile};

use crate::CoreError;
use crate::extract::StripePoint;
use crate::sensor::MAX_STRIPES;
use serde::{Deserialize, Serialize};

/// "No stripe": the label of a point no stripe explains (and the padding of [`Coding::near`]).
const NO_LABEL: u16 = u16::MAX;
/// "No segment".
const NO_SEGMENT: u32 = u32::MAX;

/// A stripe point of row `row` at column `x` with the tests' usual peak and width.
#[cfg(test)]
fn test_point(row: u32, x: f64) -> StripePoint {
    StripePoint {
        row,
        x,
        intensity: 100.0,
        width: 4.0,
        score: 1.0,
        cut: false,
    }
}

/// Largest [`CodingParams::max_outlier_run`]: the row passes visit every pair of points this many apart.
pub const MAX_OUTLIER_RUN: usize = 16;

/// Parameters of [`StripeCoder`]; every cost is in units of one unexplained missing stripe. They read from TOML
/// (`stripe3d scan --coding FILE`): every field may be left out and keeps its default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CodingParams {
    /// Lowest height a surface point may have, mm (slightly below the belt, for noise).
    pub min_height_mm: f64,
    /// Highest height a surface point may have, mm: the top of the measuring range.
    pub max_height_mm: f64,
    /// Height step (mm) across a missing stripe that explains it by occlusion.
    pub rise_mm: f64,
    /// Cost of a stripe declared missing with nothing to explain it.
    pub skip_cost: f64,
    /// Cost of a gap of stripes declared missing where the surface rises away from the projector (one wall hides
    /// them all; each stripe adds [`CodingParams::edge_skip_cost`]).
    pub rise_skip_cost: f64,
    /// Cost of a stripe declared missing beyond the first or last point of a row where it would be out of view.
    pub edge_skip_cost: f64,
    /// Height difference (mm) between neighbouring stripes above which the surface is taken to jump.
    pub jump_mm: f64,
    /// Cost of a jump between neighbouring stripes: of two labellings that explain the same points, the one with
    /// the smoother surface wins.
    pub jump_cost: f64,
    /// Cost per millimetre of height change between neighbouring stripes on one surface (no jump), at most
    /// [`CodingParams::jump_cost`]: of two labellings that explain the same points, the one with the more level
    /// surface wins. The sheets fan out from the projector, so a surface read one stripe over comes out tilted
    /// (a level step read one over, 0.25 mm from stripe to stripe on the demo part) while the true reading of a
    /// level face is level.
    pub tilt_cost_per_mm: f64,
    /// Neighbouring stripes both at the belt's height (within [`CodingParams::rise_mm`] of it) whose peaks differ
    /// by more than this ratio (the dimmer below this fraction of the brighter) cost
    /// [`CodingParams::belt_unlike_cost`] more: the belt is one material, its stripes about as bright as each other,
    /// and where a tall part's edge lines its top's first stripe up with the belt's next one (the 30 mm block), the
    /// part's stripe is more than twice as bright as the belt's. Not on parts: a printed mark or a dark patch changes
    /// a part's brightness from one stripe to the next (0: no condition).
    pub belt_intensity_ratio: f64,
    /// See [`CodingParams::belt_intensity_ratio`]: a tie-breaker, well below the margin.
    pub belt_unlike_cost: f64,
    /// Cost of declaring a point false (a ghost or noise peak).
    pub outlier_cost: f64,
    /// How much cheaper the best labelling of a point must be than any other for the point to be coded.
    pub margin: f64,
    /// Most consecutive points of a row one labelling may declare false.
    pub max_outlier_run: usize,
    /// Share of a segment's confident points that must agree for the segment to take their label.
    pub min_vote_share: f64,
    /// Least share of a segment's points that must be confidently coded for the segment to vote at all: a long
    /// segment settled by a handful of its rows (typically at its ends, where the surface changes) is not trusted.
    pub min_voting_share: f64,
    /// How much more a row labelling may cost with the segment's label than with the row's own best for the
    /// segment's label to be taken (a stripe missing in a hole makes the row cheaper to read one stripe over).
    pub segment_override_cost: f64,
    /// Largest column change (pixels) between linked points of consecutive rows of a segment.
    pub link_px: f64,
    /// Largest number of empty rows a segment may bridge.
    pub max_gap_rows: u32,
    /// A point whose peak is dimmer than this fraction of the peak of a segment's last point, or brighter than
    /// its inverse times it, does not continue the segment (0: no brightness condition). A stripe keeps its
    /// brightness down one surface, while where a plate's height moves the stripes by one pitch, the belt beside
    /// its edge, lit by the neighbouring sheet on nearly the same column, is half as bright as the plate.
    pub link_intensity_ratio: f64,
    /// A point extraction marked cut ([`StripePoint::cut`]) whose peak is dimmer than this fraction of the median
    /// peak of its row's other points is a fragment (the tail of a sheet lighting a corner): it does not take part
    /// in reading the row, and takes the label of the segment it continues, if any.
    pub fragment_intensity: f64,
    /// Any point whose peak is dimmer than this fraction of the brighter of its two neighbours along the row is a
    /// fragment too, cut or not (0: none): a sheet's tail on a corner or a glint lies beside the stripe whose light
    /// it is. The reference is the light beside the point, not the row's: a row crosses the belt and the part, and
    /// a black belt's stripes are a tenth as bright as a white part's and still stripes (with the row's median
    /// instead, every belt stripe of a dark belt beside a bright part would be one).
    pub faint_intensity: f64,
}

impl Default for CodingParams {
    fn default() -> Self {
        Self {
            min_height_mm: -1.0,
            max_height_mm: 40.0,
            // Steps lower than this do not hide a whole stripe in the paper's geometry (a 0.5 mm wall is about
            // two pixels wide in the image).
            rise_mm: 0.5,
            skip_cost: 1.0,
            // Above the margin: a rise that explains missing stripes must not be as cheap as seeing them all,
            // or a flat surface would be read as a tilted one one stripe over (measured on flat plates).
            rise_skip_cost: 0.4,
            edge_skip_cost: 0.02,
            // 1 mm over a stripe pitch of 10 mm is a 6 degree slope: gentler surfaces never pay it.
            jump_mm: 1.0,
            // Above the margin, so that a flat plate beats the same points read one stripe over as a tilted plate
            // with a narrow wall (measured on the raised-plate test).
            jump_cost: 0.35,
            // Measured on the simulated scans (`stripe3d bench coding`, wrong stripe indices after reconciliation /
            // points coded; demo, block): without the tilt and belt conditions 1,054 / 100,793, 0 / 69,369. Tilt
            // alone at 0.4, 0.8, 1.2 per mm (uncapped): demo 419, 307, 288 wrong; capped at the jump cost, 0.8, 1.2,
            // 1.6: demo 304, 134, 84, but the block 218, 208, 172 wrong (its belt read on into the column where its
            // top's first stripe lies). With a jump's cost for unlike neighbours anywhere (ratio 0.55): 1.2 -> demo
            // 134, block 0; 1.6 -> 74, 0; 2.4 -> 71, 0 — but the demo's dark patch (albedo 0.2 in 0.6) went
            // unmeasured, its stripes read more cheaply with a neighbour missing, and the inspection reported a
            // false 4.9 mm² anomaly at its edge (also at 0.1 and 0.05 of a jump). On the belt only, 0.1: demo 74 /
            // 104,939, block 0 / 86,739; renders 2 and 3: 78 and 84 wrong, the block 0. Plates on the belt and
            // defect plates 19, 7, 12, 42: 0 wrong throughout.
            tilt_cost_per_mm: 1.6,
            belt_intensity_ratio: 0.55,
            // 0.35 (a jump): the block 42 wrong; 0.02: 368 wrong; 0.05 and 0.1: 0.
            belt_unlike_cost: 0.1,
            outlier_cost: 0.8,
            margin: 0.3,
            max_outlier_run: 2,
            min_vote_share: 0.75,
            // Measured on the demo part: the step whose stripes are ambiguous in every row but its first few was
            // coded one stripe over by those few rows.
            min_voting_share: 0.25,
            // One unexplained missing stripe (skip_cost) minus one jump (jump_cost) is 0.65: the hole case.
            segment_override_cost: 0.7,
            link_px: 3.0,
            max_gap_rows: 40,
            // Measured on the simulated scans (wrong stripe indices after reconciliation, 22 frames; plate on the
            // belt, demo, block, defect plate 19; without the condition 54, 1,148, 0, 52): 0.45 -> 52, 1,133, 0,
            // 49; 0.5 -> 37, 1,134, 0, 31; 0.55 -> 2, 1,133, 0, 0; 0.6 -> 0, 1,128, 5, 0 (the block's top stripes
            // dim towards its edge). The plate's chamfer rows are 1.9 times dimmer than its top: a narrow margin,
            // set on the simulator's lighting. Dimmer points only (not brighter): 22, 1,138, 0, 22.
            link_intensity_ratio: 0.55,
            // Tail fragments on the demo peak at 0.1-0.5 of the stripes beside them; a stripe half hidden by a
            // hole's side keeps most of its peak. Measured on the demo's 22 frames (wrong stripe indices after
            // temporal reconciliation, 9,445 without marking; before segments kept their settled label): 0.4 ->
            // 6,210, 0.6 -> 4,554, 1.0 -> 3,068, every cut point -> 2,945; on the defect benchmark every cut point
            // made holes look larger (area within 15% 98.2% -> 95.5%: through a hole the belt shows as a dim cut
            // stripe), 0.6 costs 1% (97.2%).
            fragment_intensity: 0.6,
            // Measured with the brighter row neighbour as the reference (against the row's median): the demo's scan
            // 89 points over 0.5 mm off (87); the validation scans' gross errors 0.07 / 0.06 / 0.72 % (0.07 / 0.07 /
            // 0.91 %), texture_defects' coverage 0.951 (0.922); 50 random scans' 95th percentile of gross errors 17.2 %
            // (18.8 %), and none of them warns of unexplained light (two did, their dark belts dropped as faint).
            faint_intensity: 0.15,
        }
    }
}

impl CodingParams {
    /// Checks the parameters; the error names the field.
    pub fn validate(&self) -> Result<(), CoreError> {
        let bad = |field: &'static str, value: f64, reason: &str| {
            Err(CoreError::InvalidParameter {
                field,
                value: value.to_string(),
                reason: reason.to_string(),
            })
        };
        for (field, v) in [
            ("min_height_mm", self.min_height_mm),
            ("max_height_mm", self.max_height_mm),
            ("rise_mm", self.rise_mm),
            ("skip_cost", self.skip_cost),
            ("rise_skip_cost", self.rise_skip_cost),
            ("edge_skip_cost", self.edge_skip_cost),
            ("jump_mm", self.jump_mm),
            ("jump_cost", self.jump_cost),
            ("tilt_cost_per_mm", self.tilt_cost_per_mm),
            ("belt_intensity_ratio", self.belt_intensity_ratio),
            ("belt_unlike_cost", self.belt_unlike_cost),
            ("outlier_cost", self.outlier_cost),
            ("margin", self.margin),
            ("segment_override_cost", self.segment_override_cost),
            ("min_vote_share", self.min_vote_share),
            ("min_voting_share", self.min_voting_share),
            ("link_px", self.link_px),
            ("link_intensity_ratio", self.link_intensity_ratio),
            ("fragment_intensity", self.fragment_intensity),
            ("faint_intensity", self.faint_intensity),
        ] {
            if !v.is_finite() {
                return bad(field, v, "must be a finite number");
            }
        }
        // Costs, heights and distances that the row passes take to be at least zero (a transition cost is never
        // negative: the passes stop at a candidate whose cost before its transition reaches the best found).
        for (field, v) in [
            ("rise_mm", self.rise_mm),
            ("skip_cost", self.skip_cost),
            ("rise_skip_cost", self.rise_skip_cost),
            ("edge_skip_cost", self.edge_skip_cost),
            ("jump_mm", self.jump_mm),
            ("jump_cost", self.jump_cost),
            ("outlier_cost", self.outlier_cost),
            ("margin", self.margin),
            ("segment_override_cost", self.segment_override_cost),
            ("tilt_cost_per_mm", self.tilt_cost_per_mm),
            ("belt_unlike_cost", self.belt_unlike_cost),
            ("faint_intensity", self.faint_intensity),
            ("fragment_intensity", self.fragment_intensity),
        ] {
            if v < 0.0 {
                return bad(field, v, "must be 0 or more");
            }
        }
        // Shares and ratios.
        for (field, v) in [
            ("min_vote_share", self.min_vote_share),
            ("min_voting_share", self.min_voting_share),
            ("link_intensity_ratio", self.link_intensity_ratio),
            ("belt_intensity_ratio", self.belt_intensity_ratio),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return bad(field, v, "must be 0 to 1");
            }
        }
        if self.max_outlier_run > MAX_OUTLIER_RUN {
            return bad(
                "max_outlier_run",
                self.max_outlier_run as f64,
                &format!("must be 0 to {MAX_OUTLIER_RUN}"),
            );
        }
        if self.max_height_mm <= self.min_height_mm {
            return bad(
                "max_height_mm",
                self.max_height_mm,
                "must be above min_height_mm",
            );
        }
        if self.link_px <= 0.0 {
            return bad("link_px", self.link_px, "must be greater than zero");
        }
        Ok(())
    }
}

/// Counts of what coding did with the points of a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CodingStats {
    /// Points handed to the coder.
    pub points: usize,
    /// Points given a stripe index.
    pub coded: usize,
    /// Points dropped because the evidence did not settle their stripe.
    pub ambiguous: usize,
    /// Points dropped as false (outside every band, declared false by the row labelling, in a very short
    /// segment, or cut fragments no segment claimed).
    pub noise: usize,
}

impl CodingStats {
    /// Adds another frame's counts.
    pub fn add(&mut self, other: &CodingStats) {
        self.points += other.points;
        self.coded += other.coded;
        self.ambiguous += other.ambiguous;
        self.noise += other.noise;
    }
}

/// The stripe index of every point of a frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Coding {
    /// One entry per input point, in the input's order: the stripe, or `None` when the point was dropped.
    pub stripes: Vec<Option<u16>>,
    /// Per point, the labels its row could take nearly as cheaply as the best (the best first, then the
    /// alternatives within [`CodingParams::segment_override_cost`]; `u16::MAX` pads): what [`reconcile`] may choose
    /// from for a dropped point.
    pub near: Vec<[u16; 3]>,
    /// Per point, whether its own row settled its label by the margin (before segments voted).
    pub row_confident: Vec<bool>,
    /// What happened to the points.
    pub stats: CodingStats,
}

/// One frame's extracted points and their coding, kept for [`reconcile`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CodedFrame {
    /// The stripe points, sorted by row then column (as extraction gives them).
    pub points: Vec<StripePoint>,
    /// Their coding.
    pub coding: Coding,
}
