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

use crate::CoreError;
use crate::extract::StripePoint;
use crate::rules::RuleBase;
use crate::sensor::MAX_STRIPES;
use crate::triangulate::FullModel;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use stripe3d_fuzzy::Engine;

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

/// Parameters of [`reconcile`].
#[derive(Debug, Clone, PartialEq)]
pub struct TemporalParams {
    /// Largest column change (px) between a point and the same stripe on the same row one frame later: the part
    /// moves one frame step (0.5 mm in the paper's set-up) and a smooth surface moves the stripe by a fraction of a
    /// pixel, a sheet sliding down a flank by one or two; a step of the surface (tens of pixels) ends the track.
    pub link_px: f64,
    /// Fewest coded points of a track that must agree on its label.
    pub min_votes: usize,
    /// Least share of the track's coded points that must agree.
    pub min_share: f64,
    /// Fewest agreeing points, in frames before and after (or on the one side there is, where the track starts or
    /// ends), for a track to overrule a label the point's own row settled (0: never), or to relabel a point at
    /// the track's end (or start) that only the segment vote coded. A single frame can be misread with confidence as a whole (a sheet's dim tail read as one
    /// more stripe shifts its row by one index) while the frames around it read the same stripes right.
    pub overrule_votes: usize,
    /// Fewest agreeing labels the segment vote gave the track's points (each label a row settled for the track
    /// counting two), in frames before and after or on the one side there is, for the track to overrule a label the
    /// point's own row settled when no other frame's row settled another (0: never). A band of rows can be read one
    /// stripe over with confidence in one frame while the frames around it, ambiguous row by row, were coded right by
    /// their segments.
    pub overrule_segment_votes: usize,
}

impl Default for TemporalParams {
    fn default() -> Self {
        Self {
            // Measured on the demo's 22 frames (wrong stripe indices after reconciliation): 1 px -> 1,451, 1.5 ->
            // 1,448, 2 -> 1,298, 2.5 -> 1,298, 3 -> 1,497 (a sheet sliding over the step's edge moves 1.2-1.7 px a
            // frame; at 3 px tracks start to join other points).
            link_px: 2.0,
            min_votes: 3,
            min_share: 0.9,
            // Measured on the demo's 22 frames (wrong stripe indices 4,262 without): 3, 4 and 6 -> 3,030, 10 -> 3,052.
            overrule_votes: 6,
            // Twice `overrule_votes`: a segment's label is weaker evidence than a row's. Measured on the demo's 22
            // frames (wrong stripe indices after reconciliation, 1,298 without): 6 -> 1,112, 8 -> 1,118, 12 ->
            // 1,148, 24 (more than the scan's other frames) -> 1,298; every relabelling right at each.
            overrule_segment_votes: 12,
        }
    }
}

/// The links between the points of one image row in two consecutive frames (both rows in column order): point `i`
/// of `a` and point `j` of `b` are linked when each is the other's nearest and no other point of either row is within
/// `link_px` of the other one. That is the same as each being the only point of the other row within reach (then it
/// is also the nearest), which the rows' order lets one pass find: the points within reach of a point are a run, and
/// those of the next point start no earlier. (It was three scans of the rows per point, a twentieth of a 1,000-frame
/// scan's time; unit-tested against that definition.)
fn row_links(a: &[StripePoint], b: &[StripePoint], link_px: f64) -> Vec<(usize, usize)> {
    let within = |u: f64, v: f64| (u - v).abs() <= link_px;
    let mut links = Vec::new();
    let mut j = 0;
    for (i, p) in a.iter().enumerate() {
        while j < b.len() && b[j].x < p.x && !within(b[j].x, p.x) {
            j += 1;
        }
        let Some(o) = b.get(j).filter(|o| within(o.x, p.x)) else {
            continue;
        };
        let alone_in_b = b.get(j + 1).is_none_or(|n| !within(n.x, p.x));
        let alone_in_a =
            (i == 0 || !within(a[i - 1].x, o.x)) && a.get(i + 1).is_none_or(|n| !within(n.x, o.x));
        if alone_in_a && alone_in_b {
            links.push((i, j));
        }
    }
    links
}

/// The votes of a scan's tracks, by track root (a point index): (label, count, first frame, last frame) per label,
/// few labels per track. A table by point index instead of a hash map: every coded point of a scan looks its track
/// up, and hashing them was a tenth of a 1,000-frame scan's time.
struct Votes {
    /// Per point index: where its list is in `lists`, if it is a root with votes.
    slot: Vec<u32>,
    lists: Vec<Vec<(u16, usize, usize, usize)>>,
}

impl Votes {
    fn new(points: usize) -> Self {
        Self {
            slot: vec![u32::MAX; points],
            lists: Vec::new(),
        }
    }

    /// The list of track `root` (a point index below the count given to [`Votes::new`]), made empty if new.
    fn entry(&mut self, root: usize) -> &mut Vec<(u16, usize, usize, usize)> {
        let n = self.lists.len();
        let slot = &mut self.slot[root];
        if *slot == u32::MAX {
            // Fewer lists than points, and a scan of more than 4 billion points does not fit in memory before this.
            *slot = n as u32;
            self.lists.push(Vec::new());
        }
        let k = *slot as usize;
        &mut self.lists[k]
    }

    fn get(&self, root: usize) -> Option<&Vec<(u16, usize, usize, usize)>> {
        let k = *self.slot.get(root)?;
        self.lists.get(k as usize)
    }
}

/// Temporal reconciliation of a scan's coding (frames in travel order): a point is linked to the point of the next
/// frame on the same row when each is the other's only neighbour within [`TemporalParams::link_px`] — the same stripe
/// on the same surface, 0.5 mm further along — and linked points form tracks. A point the coder dropped as ambiguous
/// takes its track's label when the points of the track their own rows settled agree on it (at least `min_votes`, at
/// least `min_share` of them, in frames before and after) and the label is one its own row could nearly take — or,
/// when as many settled points as overrule a row ([`TemporalParams::overrule_votes`]) agree in frames before and
/// after, even a label its row would not take (its row was read one over with confidence: a sheet's leading fragment
/// on a part's edge read as one more stripe; the row's points no track supports then give way). So does a
/// point only the segment vote coded (its row could not settle it) whose track reads it otherwise: a segment that runs
/// the length of a plate can carry one frame's misreading down every row. At a track's end (a sheet sliding over an
/// edge, about to vanish) there is no frame after it: such a point follows the track when at least
/// [`TemporalParams::overrule_votes`] settled points of one side agree (a dropped point is still only interpolated).
/// Even a label the point's own row settled is overruled when at least [`TemporalParams::overrule_votes`] of the
/// track's settled points agree on another, in frames before and after it (or on the one side there is where the
/// track starts or ends: a sheet sliding over an edge is read one over with confidence in its last frame); points no
/// track supports are then dropped
/// where the overruled labels break the row's order (a sheet's dim tail read as a stripe), and if two supported labels
/// conflict nothing is overruled. Labels the segment vote gave count for less: at least
/// [`TemporalParams::overrule_segment_votes`] of them (a settled label of the track's counting two), before and
/// after or from the one side there is, overrule a settled label when no other frame's row settled another (a band
/// of rows misread with confidence in one frame, ambiguous in the others). Where the row's
/// order leaves a point one label alone (its labelled neighbours are that label less and more one), a weaker agreement
/// of its track is enough: its most agreed label, coded by at least `min_votes` settled points before and after the
/// frame, whatever their share (a track cut short by a bump's flank, or sharing a frame's misreading): a dropped point
/// takes it if its row could nearly take it, and a point that would otherwise give way to an overruling track takes it
/// instead of being dropped. A dropped point the row's order leaves one label takes it even when its track settled on
/// nothing, as long as the track reads no other label from `min_votes` settled points (every row of the track
/// ambiguous: a stripe beside a hidden one, or the scan's last frames); it still takes only a label its row could
/// nearly take. The row must stay ordered (labels growing with the column) with all its changes, or only the dropped
/// points that keep it ordered by themselves are recovered. Returns how many points were recovered, relabelled or
/// dropped.
///
/// Where a stripe falls into a hole, the rows it leaves are read as well one stripe over, and the coder drops the other
/// stripes' points there; the frames before and after saw the same stripes on the same surface and coded them.
pub fn reconcile(frames: &mut [CodedFrame], params: &TemporalParams) -> usize {
    fn find(parent: &mut [usize], mut a: usize) -> usize {
        while parent[a] != a {
            parent[a] = parent[parent[a]];
            a = parent[a];
        }
        a
    }
    let offsets: Vec<usize> = frames
        .iter()
        .scan(0usize, |acc, f| {
            let o = *acc;
            *acc += f.points.len();
            Some(o)
        })
        .collect();
    let total: usize = frames.iter().map(|f| f.points.len()).sum();
    let mut parent: Vec<usize> = (0..total).collect();
    // The row runs of a frame's points: (row, start, end).
    let rows_of = |f: &CodedFrame| -> Vec<(u32, usize, usize)> {
        let mut out = Vec::new();
        let mut i = 0;
        while i < f.points.len() {
            let r = f.points[i].row;
            let mut j = i + 1;
            while j < f.points.len() && f.points[j].row == r {
                j += 1;
            }
            out.push((r, i, j));
            i = j;
        }
        out
    };
    let sorted = |f: &CodedFrame| {
        f.points.len() == f.coding.stripes.len()
            && f.points
                .windows(2)
                .all(|w| w[0].row < w[1].row || (w[0].row == w[1].row && w[0].x <= w[1].x))
    };
    if !frames.iter().all(sorted) {
        return 0;
    }
    // The links between consecutive frames, found for every pair of frames in parallel (as global point indices),
    // then joined into tracks in frame order: the same tracks as one pass makes.
    let rows: Vec<Vec<(u32, usize, usize)>> = frames.par_iter().map(rows_of).collect();
    let links: Vec<Vec<(usize, usize)>> = (0..frames.len().saturating_sub(1))
        .into_par_iter()
        .map(|k| {
            let (a, b) = (&frames[k], &frames[k + 1]);
            let (ra, rb) = (&rows[k], &rows[k + 1]);
            let mut out = Vec::new();
            let mut q = 0;
            for &(row, s, e) in ra {
                while q < rb.len() && rb[q].0 < row {
                    q += 1;
                }
                if q >= rb.len() || rb[q].0 != row {
                    continue;
                }
                let (pa, pb) = (&a.points[s..e], &b.points[rb[q].1..rb[q].2]);
                out.extend(
                    row_links(pa, pb, params.link_px)
                        .into_iter()
                        .map(|(i, j)| (offsets[k] + s + i, offsets[k + 1] + rb[q].1 + j)),
                );
            }
            out
        })
        .collect();
    for (i, j) in links.into_iter().flatten() {
        let (x, y) = (find(&mut parent, i), find(&mut parent, j));
        if x != y {
            parent[x.max(y)] = x.min(y);
        }
    }
    // Every point's track (its root), points in parallel (reading the links only: the same roots).
    let roots: Vec<usize> = {
        let parent = &parent;
        (0..total)
            .into_par_iter()
            .map(|mut a| {
                while parent[a] != a {
                    a = parent[a];
                }
                a
            })
            .collect()
    };
    // Votes per track: (label, count, first frame, last frame), few labels per track; `votes` from the labels the
    // points' own rows settled, `segment_votes` from the labels only the segment vote gave (a consistent misreading
    // can spread through those, so they count for less, see [`TemporalParams::overrule_segment_votes`]).
    let (mut votes, mut segment_votes) = (Votes::new(total), Votes::new(total));
    for (k, f) in frames.iter().enumerate() {
        for (i, l) in f.coding.stripes.iter().enumerate() {
            let Some(l) = *l else { continue };
            let settled = f.coding.row_confident.get(i).copied().unwrap_or(false);
            let root = roots[offsets[k] + i];
            let into = if settled {
                &mut votes
            } else {
                &mut segment_votes
            };
            let v = into.entry(root);
            match v.iter_mut().find(|x| x.0 == l) {
                Some(x) => {
                    x.1 += 1;
                    x.2 = x.2.min(k);
                    x.3 = x.3.max(k);
                }
                None => v.push((l, 1, k, k)),
            }
        }
    }
    let (votes, segment_votes) = (&votes, &segment_votes);
    // Each frame's rows are decided from the tracks alone: frames in parallel.
    let recovered_in = |(k, f): (usize, &mut CodedFrame)| -> usize {
        let mut recovered = 0;
        let mut proposal: Vec<Option<u16>> = Vec::new();
        for &(_, s, e) in &rows[k] {
            // The track's label for every point of the row it may change: dropped points, and points only the
            // segment vote coded (their row could not settle them) that their track reads otherwise.
            proposal.clear();
            proposal.extend_from_slice(&f.coding.stripes[s..e]);
            let mut changed = false;
            let mut overruled = false;
            // The track's winning label with its votes and whether it codes frames on both sides of this one.
            let winner = |i: usize| -> Option<(u16, usize, bool)> {
                let root = roots[offsets[k] + i];
                let v = votes.get(root)?;
                let all: usize = v.iter().map(|x| x.1).sum();
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                ((c as f64) >= params.min_share * all as f64).then_some((
                    w,
                    c,
                    first < k && last > k,
                ))
            };
            // The track's most agreed label, coded by at least `min_votes` settled points before and after this frame,
            // whatever its share.
            let majority = |i: usize| -> Option<u16> {
                let v = votes.get(roots[offsets[k] + i])?;
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                (c >= params.min_votes && first < k && last > k).then_some(w)
            };
            // The label the segment vote gave the track's points, when their weight reaches
            // `overrule_segment_votes` — each segment-given label counting one and each label a row settled for it
            // two (a settled label is worth two of its segment's: `overrule_segment_votes` is twice
            // `overrule_votes`) — 90% of its segment-given labels agree, and no other frame's row settled another
            // label; in frames before and after this one, or from the one side there is where the track starts or
            // ends (as settled labels overrule: in frame 15 of the demo, stripe 2 about to vanish over the step's
            // edge was read as 1 with confidence in its last frame, its track coded 2 by the segments and by a few
            // settled rows in the frames before).
            let segment_winner = |i: usize| -> Option<u16> {
                let root = roots[offsets[k] + i];
                let v = segment_votes.get(root)?;
                let &(w, c, first, last) = v.iter().max_by_key(|x| x.1)?;
                let all: usize = v.iter().map(|x| x.1).sum();
                let settled = |same: bool| -> usize {
                    votes.get(root).map_or(0, |sv| {
                        sv.iter().filter(|x| (x.0 == w) == same).map(|x| x.1).sum()
                    })
                };
                (params.overrule_segment_votes > 0
                    && c + 2 * settled(true) >= params.overrule_segment_votes
                    && (first < k || last > k)
                    && (c as f64) >= params.min_share * all as f64
                    && settled(false) <= 1)
                    .then_some(w)
            };
            // The one label the row's order leaves point j (between its labelled neighbours in `labels`).
            let left_by_order = |labels: &[Option<u16>], j: usize| -> Option<u16> {
                let lo = *labels[..j].iter().rev().flatten().next()?;
                let hi = *labels[j + 1..].iter().flatten().next()?;
                let w = lo.checked_add(1)?;
                (hi.checked_sub(1) == Some(w)).then_some(w)
            };
            // That label, when the track's majority (point `i`'s) is that label.
            let sandwiched = |labels: &[Option<u16>], j: usize, i: usize| -> Option<u16> {
                left_by_order(labels, j).filter(|&w| majority(i) == Some(w))
            };
            // That label, when the track reads no other (no settled points, or too few for any other label).
            let unopposed = |labels: &[Option<u16>], j: usize, i: usize| -> Option<u16> {
                left_by_order(labels, j).filter(|&w| {
                    !votes
                        .get(roots[offsets[k] + i])
                        .is_some_and(|v| v.iter().any(|x| x.0 != w && x.1 >= params.min_votes))
                })
            };
            for i in s..e {
                let current = f.coding.stripes[i];
                if current.is_some() && f.coding.row_confident.get(i).copied().unwrap_or(false) {
                    // Before and after this frame, or from the one side there is where the track starts or ends
                    // (at the scan's ends, or mid-scan where a sheet slides over an edge and vanishes): as many
                    // settled points either way. (Mid-scan it once dropped points into a false 0.8 mm² "hole"
                    // beside the demo's dent; inspection now reports gaps that small as unmeasured,
                    // `DetectParams::min_hole_travel_steps`.)
                    if params.overrule_votes > 0
                        && let Some((w, c, _around)) = winner(i)
                        && c >= params.overrule_votes
                        && current != Some(w)
                    {
                        proposal[i - s] = Some(w);
                        changed = true;
                        overruled = true;
                    } else if let Some(w) = segment_winner(i)
                        && current != Some(w)
                    {
                        proposal[i - s] = Some(w);
                        changed = true;
                        overruled = true;
                    }
                    continue;
                }
                let near = f.coding.near.get(i).copied().unwrap_or([NO_LABEL; 3]);
                if near[0] == NO_LABEL {
                    continue;
                }
                let Some((w, c, around)) = winner(i) else {
                    continue;
                };
                // Interpolation: the track codes the label before and after this frame. At a track's end (or
                // start), a label the segment vote gave gives way to as many settled points as overrule a row.
                let extends =
                    current.is_some() && params.overrule_votes > 0 && c >= params.overrule_votes;
                // A dropped point whose track settled the label in frames before and after as firmly as overrules a
                // row takes it even when its own row would not nearly take it: the row's confident reading that
                // dropped it was one over (a sheet's leading fragment on a part's edge read as one more stripe).
                // It counts as an overrule: the row's points no track supports give way where the order breaks.
                let firm = current.is_none()
                    && around
                    && params.overrule_votes > 0
                    && c >= params.overrule_votes;
                if c < params.min_votes
                    || !(near.contains(&w) || firm)
                    || !(around || extends)
                    || current == Some(w)
                {
                    continue;
                }
                proposal[i - s] = Some(w);
                changed = true;
                if !near.contains(&w) {
                    overruled = true;
                }
            }
            // A dropped point the row's order leaves one label alone (between its labelled neighbours) takes it when
            // its track agrees, by a majority too small for the rule above.
            for j in 0..e - s {
                let near = f.coding.near.get(s + j).copied().unwrap_or([NO_LABEL; 3]);
                if f.coding.stripes[s + j].is_none()
                    && proposal[j].is_none()
                    && near[0] != NO_LABEL
                    && let Some(w) =
                        sandwiched(&proposal, j, s + j).or_else(|| unopposed(&proposal, j, s + j))
                    && near.contains(&w)
                {
                    proposal[j] = Some(w);
                    changed = true;
                }
            }
            if !changed {
                continue;
            }
            // The row must stay ordered with every change made; otherwise only the dropped points whose label keeps
            // the row ordered by itself are recovered (a relabelling that breaks the order is not trusted).
            let ordered = |labels: &[Option<u16>]| {
                labels
                    .iter()
                    .flatten()
                    .zip(labels.iter().flatten().skip(1))
                    .all(|(a, b)| a < b)
            };
            if overruled && !ordered(&proposal) {
                // The proposal without the overrules.
                let plain: Vec<Option<u16>> = (s..e)
                    .map(|i| {
                        let settled = f.coding.row_confident.get(i).copied().unwrap_or(false);
                        match f.coding.stripes[i] {
                            Some(l) if settled => Some(l),
                            _ => proposal[i - s],
                        }
                    })
                    .collect();
                // Points whose label no track supports give way to the overruling tracks: dropped where they
                // break the row's order. If two supported labels conflict, nothing is overruled.
                let supported = |i: usize, l: u16| {
                    winner(i).is_some_and(|(w, c, _)| w == l && c >= params.min_votes)
                };
                loop {
                    let labelled: Vec<usize> =
                        (0..e - s).filter(|&j| proposal[j].is_some()).collect();
                    let Some(bad) = labelled
                        .windows(2)
                        .find(|w| proposal[w[0]] >= proposal[w[1]])
                    else {
                        break;
                    };
                    // An unsupported point gives way: it takes the one label the order leaves it if its track
                    // agrees, or is dropped.
                    let (a, b) = (bad[0], bad[1]);
                    if !supported(s + b, proposal[b].unwrap_or(NO_LABEL)) {
                        proposal[b] = None;
                        proposal[b] = sandwiched(&proposal, b, s + b);
                    } else if !supported(s + a, proposal[a].unwrap_or(NO_LABEL)) {
                        proposal[a] = None;
                        proposal[a] = sandwiched(&proposal, a, s + a);
                    } else {
                        // Undo the overrules and the drops; the usual rules apply.
                        proposal.copy_from_slice(&plain);
                        break;
                    }
                }
            }
            if ordered(&proposal) {
                for (i, p) in (s..e).zip(&proposal) {
                    if f.coding.stripes[i] != *p {
                        if f.coding.stripes[i].is_none() {
                            f.coding.stats.coded += 1;
                            f.coding.stats.ambiguous = f.coding.stats.ambiguous.saturating_sub(1);
                        } else if p.is_none() {
                            f.coding.stats.coded -= 1;
                            f.coding.stats.ambiguous += 1;
                        }
                        f.coding.stripes[i] = *p;
                        recovered += 1;
                    }
                }
                continue;
            }
            for i in s..e {
                let (None, Some(w)) = (f.coding.stripes[i], proposal[i - s]) else {
                    continue;
                };
                let before = f.coding.stripes[s..i].iter().rev().flatten().next();
                let after = f.coding.stripes[i + 1..e].iter().flatten().next();
                if before.is_some_and(|&b| b >= w) || after.is_some_and(|&a| a <= w) {
                    continue;
                }
                f.coding.stripes[i] = Some(w);
                f.coding.stats.coded += 1;
                f.coding.stats.ambiguous = f.coding.stats.ambiguous.saturating_sub(1);
                recovered += 1;
            }
        }
        recovered
    };
    frames.par_iter_mut().enumerate().map(recovered_in).sum()
}

/// A function of one or two inputs sampled on a regular grid, read back with (bi)linear interpolation and the
/// inputs clamped to the grid: the fuzzy rule base's decisions, tabulated.
#[derive(Debug, Clone, PartialEq)]
struct Table2 {
    x0: f64,
    dx: f64,
    nx: usize,
    y0: f64,
    dy: f64,
    ny: usize,
    values: Vec<f32>,
}

impl Table2 {
    fn build(
        (x0, x1, nx): (f64, f64, usize),
        (y0, y1, ny): (f64, f64, usize),
        mut f: impl FnMut(f64, f64) -> Result<f64, CoreError>,
    ) -> Result<Self, CoreError> {
        let dx = if nx > 1 {
            (x1 - x0) / (nx - 1) as f64
        } else {
            1.0
        };
        let dy = if ny > 1 {
            (y1 - y0) / (ny - 1) as f64
        } else {
            1.0
        };
        let mut values = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                values.push(f(x0 + dx * i as f64, y0 + dy * j as f64)? as f32);
            }
        }
        Ok(Self {
            x0,
            dx,
            nx,
            y0,
            dy,
            ny,
            values,
        })
    }

    #[inline]
    fn axis(v: f64, v0: f64, dv: f64, n: usize) -> (usize, f32) {
        let t = ((v - v0) / dv).clamp(0.0, (n - 1) as f64);
        let i = (t as usize).min(n.saturating_sub(2));
        (i, (t - i as f64) as f32)
    }

    #[inline]
    fn get(&self, x: f64, y: f64) -> f32 {
        let (i, fx) = Self::axis(x, self.x0, self.dx, self.nx);
        let (j, fy) = Self::axis(y, self.y0, self.dy, self.ny);
        let at =
            |i: usize, j: usize| self.values[j.min(self.ny - 1) * self.nx + i.min(self.nx - 1)];
        let top = at(i, j) * (1.0 - fx) + at(i + 1, j) * fx;
        let bottom = at(i, j + 1) * (1.0 - fx) + at(i + 1, j + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// The stripe-coding rule base (`rules/stripe_coding.fll`), evaluated once into tables.
#[derive(Debug, Clone, PartialEq)]
pub struct FuzzyTables {
    /// `same_segment` over (height mm, height change mm).
    same_segment: Table2,
    /// `bridge_gap` over (gap rows, boundary difference mm).
    bridge_gap: Table2,
    /// `keep_segment` over (segment length points).
    keep_segment: Table2,
}

fn rule_error(e: impl ToString) -> CoreError {
    CoreError::RuleBase {
        file: RuleBase::StripeCoding.file_name(),
        message: e.to_string(),
    }
}

fn evaluate(engine: &mut Engine, inputs: &[(usize, f64)], output: usize) -> Result<f64, CoreError> {
    for &(i, v) in inputs {
        engine.set_input(i, v);
    }
    engine.process().map_err(rule_error)?;
    Ok(engine.output_value(output))
}

impl FuzzyTables {
    /// Tabulates the shipped rule base.
    pub fn shipped() -> Result<Self, CoreError> {
        let engine = RuleBase::StripeCoding.engine().map_err(rule_error)?;
        Self::from_engine(engine)
    }

    /// Tabulates a stripe-coding engine (inputs `height`, `height_change`, `gap`, `boundary_difference`,
    /// `segment_length`; outputs `same_segment`, `bridge_gap`, `keep_segment`).
    pub fn from_engine(mut e: Engine) -> Result<Self, CoreError> {
        let input = |e: &Engine, name: &str| {
            e.input_index(name)
                .ok_or_else(|| rule_error(format!("no input variable `{name}`")))
        };
        let output = |e: &Engine, name: &str| {
            e.output_index(name)
                .ok_or_else(|| rule_error(format!("no output variable `{name}`")))
        };
        let (height, change, gap, boundary, length) = (
            input(&e, "height")?,
            input(&e, "height_change")?,
            input(&e, "gap")?,
            input(&e, "boundary_difference")?,
            input(&e, "segment_length")?,
        );
        let (same, bridge, keep) = (
            output(&e, "same_segment")?,
            output(&e, "bridge_gap")?,
            output(&e, "keep_segment")?,
        );
        // Neutral values for the inputs a table does not vary: they only feed rules of other outputs.
        let neutral = [(gap, 0.0), (boundary, 0.0), (length, 100.0)];
        for &(i, v) in &neutral {
            e.set_input(i, v);
        }
        // Sampling: 0.02 mm of height below 1 mm (the "very small" terms live there) and 0.05 mm of height change
        // up to 6 mm, rows of gap up to 60 and 0.05 mm of boundary difference, one point of length up to 40; the
        // shipped terms are flat beyond those ends.
        let same_segment = Table2::build((0.0, 1.0, 51), (0.0, 6.0, 121), |h, c| {
            evaluate(&mut e, &[(height, h), (change, c)], same)
        })?;
        let bridge_gap = Table2::build((0.0, 60.0, 61), (0.0, 6.0, 121), |g, b| {
            evaluate(&mut e, &[(gap, g), (boundary, b)], bridge)
        })?;
        let keep_segment = Table2::build((0.0, 40.0, 41), (0.0, 0.0, 1), |n, _| {
            evaluate(&mut e, &[(length, n)], keep)
        })?;
        Ok(Self {
            same_segment,
            bridge_gap,
            keep_segment,
        })
    }

    /// Rules 1 and 4: does a point of height `height_mm` continue a segment whose last point differs by
    /// `change_mm`?
    pub fn same_segment(&self, height_mm: f64, change_mm: f64) -> bool {
        self.same_segment.get(height_mm.abs(), change_mm.abs()) > 0.5
    }

    /// Rules 2 and 3: is a gap of `gap_rows` empty rows bridged when the heights at its ends differ by
    /// `boundary_mm`?
    pub fn bridge_gap(&self, gap_rows: u32, boundary_mm: f64) -> bool {
        self.bridge_gap.get(f64::from(gap_rows), boundary_mm.abs()) > 0.5
    }

    /// Rule 5: is a segment of `points` points kept?
    pub fn keep_segment(&self, points: usize) -> bool {
        self.keep_segment.get(points as f64, 0.0) > 0.5
    }
}

/// Per row and stripe: the band of columns the stripe can occupy and its heights at the image's side edges.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Band {
    /// Smallest and largest column over the measuring range.
    u_min: f32,
    u_max: f32,
    /// Height the stripe shows at the first and the last column (NaN where the ray misses the plane).
    z_left: f32,
    z_right: f32,
    /// True when the stripe moves towards smaller columns as the height grows (the projector is on the −x side).
    leftward: bool,
}

/// The cost of the stripes missing beyond a row's first or last labelled point, the quick way where the row
/// allows it. Where every stripe of a row moves towards smaller columns as the height grows and the heights the
/// stripes show at the image's side edges grow with the stripe index (the paper's set-up), a stripe out of view
/// at a height is so for every stripe before it (left edge) or after it (right edge): the missing stripes' cost
/// is then one count over the row's thresholds and one look-up of the same `f32` sum the general path adds up.
#[derive(Debug, Clone, PartialEq)]
struct EdgeSkips {
    stripes: usize,
    /// Per row: whether the quick way holds.
    ordered: Vec<bool>,
    /// Per row and stripe: the height at or above which the stripe is out of view left of column 0
    /// (`z_left − rise_mm`), and the one above which it is still in view right of the last column
    /// (`z_right + rise_mm`).
    left_at: Vec<f32>,
    right_at: Vec<f32>,
    /// `left_sum[gone * (stripes + 1) + label]`: the sum over stripes `0 .. label` of the edge cost for the first
    /// `gone` and the full cost for the rest; `right_sum[kept * (stripes + 1) + n]`: over `n` stripes, the full
    /// cost for the first `kept` and the edge cost for the rest.
    left_sum: Vec<f32>,
    right_sum: Vec<f32>,
}

impl EdgeSkips {
    fn new(bands: &[Band], stripes: usize, params: &CodingParams) -> Self {
        let rise = params.rise_mm as f32;
        let (edge, full) = (params.edge_skip_cost as f32, params.skip_cost as f32);
        // A stripe whose ray at the edge misses its plane (NaN) is out of view at every height.
        let left_at: Vec<f32> = bands
            .iter()
            .map(|b| {
                if b.z_left.is_nan() {
                    f32::NEG_INFINITY
                } else {
                    b.z_left - rise
                }
            })
            .collect();
        let right_at: Vec<f32> = bands
            .iter()
            .map(|b| {
                if b.z_right.is_nan() {
                    f32::INFINITY
                } else {
                    b.z_right + rise
                }
            })
            .collect();
        // The last stripe is never left of a point, the first never right of one.
        let ordered = bands
            .chunks(stripes)
            .zip(left_at.chunks(stripes).zip(right_at.chunks(stripes)))
            .map(|(row, (l, r))| {
                row.iter().all(|b| b.leftward)
                    && l[..stripes - 1].windows(2).all(|w| w[0] <= w[1])
                    && r[1..].windows(2).all(|w| w[0] <= w[1])
            })
            .collect();
        let n = stripes + 1;
        let mut left_sum = vec![f32::NAN; n * n];
        let mut right_sum = vec![f32::NAN; n * n];
        for a in 0..n {
            for b in 0..n {
                left_sum[a * n + b] = (0..b).map(|k| if k < a { edge } else { full }).sum();
                right_sum[a * n + b] = (0..b).map(|k| if k < a { full } else { edge }).sum();
            }
        }
        Self {
            stripes,
            ordered,
            left_at,
            right_at,
            left_sum,
            right_sum,
        }
    }

    /// The costs of the stripes missing before and after a point at height `z` labelled `label`, if the row is
    /// ordered (for [`StripeCoder::left_skip`] and [`StripeCoder::right_skip`], the same values). `cursor` carries
    /// the counts from the point's previous label: in an ordered row the height grows with the label, so each
    /// count only moves on.
    #[inline]
    fn costs(
        &self,
        tr: &Transitions,
        row: u32,
        label: u16,
        z: f32,
        cursor: &mut EdgeCursor,
    ) -> Option<(f32, f32)> {
        let r = row as usize;
        if !self.ordered[r] || z.is_nan() {
            return None;
        }
        if z < cursor.z {
            *cursor = EdgeCursor::START;
        }
        cursor.z = z;
        let n = self.stripes;
        // Sorted thresholds: the stripes out of view left are the ones whose threshold is at most z; the ones
        // still in view right (stripes 1..) the ones whose threshold is below z.
        let left_at = &self.left_at[r * n..][..n - 1];
        while cursor.left < left_at.len() && left_at[cursor.left] <= z {
            cursor.left += 1;
        }
        let right_at = &self.right_at[r * n + 1..][..n - 1];
        while cursor.right < right_at.len() && right_at[cursor.right] < z {
            cursor.right += 1;
        }
        let l = usize::from(label);
        let mut left = self.left_sum[cursor.left.min(l) * (n + 1) + l];
        // The projector is on the left in an ordered row: a rise from the belt to the point may hide every
        // stripe before it.
        if l > 0 && z >= tr.rise_at {
            left = left.min(tr.rise_skip[l]);
        }
        let right = self.right_sum[cursor.right.saturating_sub(l) * (n + 1) + (n - 1 - l)];
        Some((left, right))
    }
}

/// Where [`EdgeSkips::costs`] left its counts for the point's previous label.
#[derive(Debug, Clone, Copy)]
struct EdgeCursor {
    z: f32,
    left: usize,
    right: usize,
}

impl EdgeCursor {
    const START: Self = Self {
        z: f32::NEG_INFINITY,
        left: 0,
        right: 0,
    };
}

/// One candidate (point, label) of a row.
#[derive(Debug, Clone, Copy)]
struct Item {
    /// Point's position in the row (0-based, in column order).
    j: u16,
    label: u16,
    z: f32,
    /// +1 when the label's stripe moves towards smaller columns as the height grows on this row, −1 otherwise.
    sign: f32,
    /// The point's peak intensity.
    level: f32,
    forward: f32,
    backward: f32,
    /// Cost of the stripes missing before this item when it is the row's first labelled point.
    start: f32,
    /// Cost of the stripes missing after it when it is the last.
    end: f32,
}

/// An item with a finite backward cost, as the backward pass reads it.
#[derive(Debug, Clone, Copy)]
struct Back {
    label: u16,
    z: f32,
    sign: f32,
    level: f32,
    backward: f32,
}

/// Per-point working state of one frame.
#[derive(Debug, Clone, Copy)]
struct PointState {
    /// Best label of the row labelling (even when not confident); `u16::MAX` for a declared-false point.
    best: u16,
    confident: bool,
    /// The runner-up labels and how much more their best row labelling costs than the best label's.
    alternatives: [(u16, f32); 2],
    z: f32,
    segment: u32,
}

const NO_LABEL: u16 = u16::MAX;
const NO_SEGMENT: u32 = u32::MAX;

#[derive(Debug, Clone, Default)]
struct SegmentState {
    last_row: u32,
    last_u: f64,
    /// Peak intensity of the segment's last point.
    last_intensity: f32,
    last_label: u16,
    last_z: f32,
    length: u32,
    /// Confident votes: up to four distinct labels with counts, plus the total.
    votes: [(u16, u32); 4],
    total_votes: u32,
    taken_row: u32,
}

/// One step of the row passes: `best` becomes `base + transition()` where that is smaller. The transition is not
/// computed when `base` alone already reaches `best` (transition costs are never negative, and adding one to `base`
/// cannot round below it).
#[inline(always)]
fn relax(best: &mut f32, base: f32, transition: impl FnOnce() -> f32) {
    if base < *best {
        let c = base + transition();
        if c < *best {
            *best = c;
        }
    }
}

/// The neighbouring `f32` above (`up`) or below `t` (`f32::next_up` and `next_down` are newer than this crate's
/// minimum Rust).
fn next_f32(t: f32, up: bool) -> f32 {
    if t.is_nan() || t == if up { f32::INFINITY } else { f32::NEG_INFINITY } {
        return t;
    }
    if t == 0.0 {
        let tiny = f32::from_bits(1);
        return if up { tiny } else { -tiny };
    }
    let bits = t.to_bits();
    f32::from_bits(if (t > 0.0) == up { bits + 1 } else { bits - 1 })
}

/// The costs of transitions between labelled points of a row, in the `f32` the row passes add them in, tabulated
/// once per coder: the same values [`CodingParams`] defines, without `f64` conversions or branches per pair.
#[derive(Debug, Clone, PartialEq)]
struct Transitions {
    /// Largest `f32` at most [`CodingParams::jump_mm`]: for an `f32` difference `d`, `d > jump_at` exactly when
    /// `f64::from(d) > jump_mm`.
    jump_at: f32,
    /// Smallest `f32` at least [`CodingParams::rise_mm`]: `r >= rise_at` exactly when `f64::from(r) >= rise_mm`.
    rise_at: f32,
    jump_cost: f32,
    /// [`CodingParams::tilt_cost_per_mm`], [`CodingParams::belt_intensity_ratio`] (compared in `f64`: the
    /// comparison is the parameter's) and [`CodingParams::belt_unlike_cost`].
    tilt: f32,
    belt_ratio: f64,
    belt_unlike_cost: f32,
    /// One sheet seen twice in a row ([`CodingParams::outlier_cost`]).
    split_cost: f32,
    /// Per number of stripes missing between the two points: the cost without a rise, and with one.
    skip: [f32; MAX_STRIPES],
    rise_skip: [f32; MAX_STRIPES],
}

impl Transitions {
    fn new(params: &CodingParams) -> Self {
        // Round towards the side that keeps the comparison exact (the parameters are finite, checked).
        let below = |v: f64| {
            let t = v as f32;
            if f64::from(t) > v {
                next_f32(t, false)
            } else {
                t
            }
        };
        let above = |v: f64| {
            let t = v as f32;
            if f64::from(t) < v {
                next_f32(t, true)
            } else {
                t
            }
        };
        let skip_cost = params.skip_cost as f32;
        Self {
            jump_at: below(params.jump_mm),
            rise_at: above(params.rise_mm),
            jump_cost: params.jump_cost as f32,
            tilt: params.tilt_cost_per_mm as f32,
            belt_ratio: params.belt_intensity_ratio,
            belt_unlike_cost: params.belt_unlike_cost as f32,
            split_cost: params.outlier_cost as f32,
            skip: std::array::from_fn(|n| n as f32 * skip_cost),
            rise_skip: std::array::from_fn(|n| {
                (params.rise_skip_cost + n as f64 * params.edge_skip_cost) as f32
            }),
        }
    }

    /// Cost of the transition from a point labelled `from` at height `za` (peak intensity `ia`) to one labelled
    /// `to` at height `zb` (peak `ib`): stripes `from + 1 .. to` missing (one wall hides all it hides when the
    /// surface rises away from the projector: one event, plus a little per stripe), or between neighbouring
    /// stripes the surface jumping (a height step beyond [`CodingParams::jump_mm`]) or tilting (a cost per
    /// millimetre, at most a jump's; on the belt, more for peaks too unlike for it, still at most a jump's).
    /// `rise_sign` is +1 when stripe `to` moves towards smaller columns as the height grows, −1 otherwise.
    ///
    /// `from == to` is one sheet seen twice: where an edge runs along the row, the sheet's upper part lies on the
    /// upper surface and the rest beyond the edge on the lower one, two points of one stripe in one row (a plate's
    /// top and the belt past its side; the two levels of a step). The second must lie lower by more than a jump;
    /// it costs what a false point costs, so it wins only where the row runs on from it on the lower surface
    /// without the jump the false point would leave (a stray point on a smooth surface stays cheaper as false).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn cost(&self, from: u16, to: u16, za: f32, zb: f32, rise_sign: f32, ia: f32, ib: f32) -> f32 {
        let d = zb - za;
        if from == to {
            return if -rise_sign * d > self.jump_at {
                self.split_cost
            } else {
                f32::INFINITY
            };
        }
        // Fewer than MAX_STRIPES (a power of two) stripes: the mask only spares the bounds check.
        let n = usize::from(to - from - 1) & (MAX_STRIPES - 1);
        if n == 0 {
            if d.abs() > self.jump_at {
                self.jump_cost
            } else {
                let tilt = (self.tilt * d.abs()).min(self.jump_cost);
                let belt = za.abs() < self.rise_at && zb.abs() < self.rise_at;
                let (a, b) = (f64::from(ia), f64::from(ib));
                if belt && (a < self.belt_ratio * b || self.belt_ratio * a > b) {
                    (tilt + self.belt_unlike_cost).min(self.jump_cost)
                } else {
                    tilt
                }
            }
        } else if rise_sign * d >= self.rise_at {
            self.rise_skip[n]
        } else {
            self.skip[n]
        }
    }
}

/// A reusable stripe coder for one calibrated sensor: bands, rule tables and buffers persist across frames.
#[derive(Debug, Clone)]
pub struct StripeCoder {
    model: FullModel,
    params: CodingParams,
    width: u32,
    height: u32,
    stripes: usize,
    bands: Vec<Band>,
    edges: EdgeSkips,
    tables: FuzzyTables,
    order: Vec<u32>,
    items: Vec<Item>,
    row_start: Vec<usize>,
    outlier_marginal: Vec<f32>,
    /// Transition costs, tabulated.
    transitions: Transitions,
    /// How far above the row's best labelling a min-marginal can still change a decision
    /// ([`CodingParams::margin`] + [`CodingParams::segment_override_cost`], and a little for rounding).
    window: f32,
    /// Per row: the items whose forward cost is within the window (`alive`), and of those the ones whose
    /// min-marginal is (`live`), with each point's range.
    alive: Vec<u32>,
    alive_start: Vec<usize>,
    live: Vec<u32>,
    live_start: Vec<usize>,
    /// Per row, the items with a finite backward cost, point by point (`back_range`), as the backward pass needs
    /// them.
    back: Vec<Back>,
    back_range: Vec<(usize, usize)>,
    state: Vec<PointState>,
    segments: Vec<SegmentState>,
    open: Vec<u32>,
    /// Undistorted normalised coordinates of every point of the frame (computed once, used for every label).
    normalized: Vec<(f64, f64)>,
    /// The points of the row being read (fragments left out), in column order.
    row_points: Vec<u32>,
    /// Per point of the frame: a fragment (see [`CodingParams::fragment_intensity`]).
    fragment: Vec<bool>,
    /// Peak intensities of the row's uncut points (for the fragment test).
    levels: Vec<f32>,
    /// Per point of the frame: the label its segment voted for where the point's own row reads another by more
    /// than the override cost (the point is dropped), [`NO_LABEL`] elsewhere. It still orders the row's points only
    /// their row labelled (see [`StripeCoder::order_by_overruled`]).
    overruled: Vec<u16>,
    /// Per point of the row being checked against overruled points (reused).
    scratch_labels: Vec<u16>,
}

impl StripeCoder {
    /// A coder for frames of `width` x `height` pixels seen through `model`, with the shipped rule base.
    pub fn new(
        model: &FullModel,
        width: u32,
        height: u32,
        params: CodingParams,
    ) -> Result<Self, CoreError> {
        Self::with_tables(model, width, height, params, FuzzyTables::shipped()?)
    }

    /// A coder with the stripe-coding rules of an edited rule base.
    pub fn with_tables(
        model: &FullModel,
        width: u32,
        height: u32,
        params: CodingParams,
        tables: FuzzyTables,
    ) -> Result<Self, CoreError> {
        params.validate()?;
        let stripes = model.planes.len();
        if stripes == 0 || stripes > MAX_STRIPES {
            return Err(CoreError::InvalidParameter {
                field: "stripes",
                value: stripes.to_string(),
                reason: format!("the model must have 1 to {MAX_STRIPES} stripe planes"),
            });
        }
        if width == 0 || height == 0 {
            return Err(CoreError::InvalidParameter {
                field: "image size",
                value: format!("{width}x{height}"),
                reason: "must not be empty".into(),
            });
        }
        let mut bands = Vec::with_capacity(height as usize * stripes);
        let (u_first, u_last) = (0.0, f64::from(width) - 1.0);
        // Where a stripe cannot show one end of the range, its band runs this far beyond the image.
        let (search_lo, search_hi) = (-f64::from(width), 2.0 * f64::from(width));
        for v in 0..height {
            let v = f64::from(v);
            for k in 0..stripes {
                let z_left = model.height(k, u_first, v).unwrap_or(f64::NAN);
                let z_right = model.height(k, u_last, v).unwrap_or(f64::NAN);
                // NaN heights (a ray missing the plane) count as leftward, the paper's geometry.
                let leftward = z_right.partial_cmp(&z_left) != Some(std::cmp::Ordering::Greater);
                let at = |z: f64| model.column_at_height(k, v, z);
                let (a, b) = (at(params.min_height_mm), at(params.max_height_mm));
                let (u_min, u_max) = match (a, b) {
                    (Some(a), Some(b)) => (
                        a.min(b).clamp(search_lo, search_hi),
                        a.max(b).clamp(search_lo, search_hi),
                    ),
                    // The stripe reaches only one end of the range inside the searched columns: the band runs to
                    // the searched edge on the side the other end lies.
                    (Some(a), None) => {
                        if leftward {
                            (search_lo, a)
                        } else {
                            (a, search_hi)
                        }
                    }
                    (None, Some(b)) => {
                        if leftward {
                            (b, search_hi)
                        } else {
                            (search_lo, b)
                        }
                    }
                    (None, None) => (f64::INFINITY, f64::NEG_INFINITY),
                };
                bands.push(Band {
                    u_min: u_min as f32,
                    u_max: u_max as f32,
                    z_left: z_left as f32,
                    z_right: z_right as f32,
                    leftward,
                });
            }
        }
        let transitions = Transitions::new(&params);
        let edges = EdgeSkips::new(&bands, stripes, &params);
        // Sums of row costs are rounded differently along different passes: a hundredth of a stripe's cost covers
        // that many times over.
        let window = (params.margin.abs() + params.segment_override_cost.abs()) as f32 + 0.01;
        Ok(Self {
            model: model.clone(),
            params,
            width,
            height,
            stripes,
            bands,
            edges,
            tables,
            order: Vec::new(),
            items: Vec::new(),
            row_start: Vec::new(),
            outlier_marginal: Vec::new(),
            transitions,
            window,
            alive: Vec::new(),
            alive_start: Vec::new(),
            live: Vec::new(),
            live_start: Vec::new(),
            back: Vec::new(),
            back_range: Vec::new(),
            state: Vec::new(),
            segments: Vec::new(),
            open: Vec::new(),
            normalized: Vec::new(),
            row_points: Vec::new(),
            fragment: Vec::new(),
            levels: Vec::new(),
            overruled: Vec::new(),
            scratch_labels: Vec::new(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &CodingParams {
        &self.params
    }

    /// The frame size the coder was built for, (width, height) in pixels.
    pub fn image_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The column band of stripe `stripe` on row `row` over the measuring range, `(min, max)`.
    pub fn band(&self, row: u32, stripe: usize) -> Option<(f64, f64)> {
        if row >= self.height || stripe >= self.stripes {
            return None;
        }
        let b = self.bands[row as usize * self.stripes + stripe];
        Some((f64::from(b.u_min), f64::from(b.u_max)))
    }

    /// Codes the points of one frame (extracted along rows, any order) into `out`.
    pub fn code_into(&mut self, points: &[StripePoint], out: &mut Coding) {
        out.stripes.clear();
        out.stripes.resize(points.len(), None);
        out.near.clear();
        out.near.resize(points.len(), [NO_LABEL; 3]);
        out.row_confident.clear();
        out.row_confident.resize(points.len(), false);
        out.stats = CodingStats {
            points: points.len(),
            ..CodingStats::default()
        };
        // Column order within rows; points on rows outside the image are dropped as noise.
        self.order.clear();
        self.order
            .extend((0..points.len() as u32).filter(|&i| points[i as usize].row < self.height));
        self.order.sort_by(|&a, &b| {
            let (pa, pb) = (&points[a as usize], &points[b as usize]);
            pa.row.cmp(&pb.row).then(pa.x.total_cmp(&pb.x))
        });
        self.state.clear();
        self.state.resize(
            points.len(),
            PointState {
                best: NO_LABEL,
                confident: false,
                alternatives: [(NO_LABEL, f32::INFINITY); 2],
                z: f32::NAN,
                segment: NO_SEGMENT,
            },
        );
        let camera = &self.model.camera;
        self.normalized.clear();
        self.normalized.extend(
            points
                .iter()
                .map(|p| camera.normalized(p.x, f64::from(p.row))),
        );
        self.fragment.clear();
        self.fragment.resize(points.len(), false);
        self.overruled.clear();
        self.overruled.resize(points.len(), NO_LABEL);
        // Pass 1: each row on its own.
        let mut start = 0;
        while start < self.order.len() {
            let row = points[self.order[start] as usize].row;
            let mut end = start + 1;
            while end < self.order.len() && points[self.order[end] as usize].row == row {
                end += 1;
            }
            // Fragments (cut points much dimmer than the row's stripes, and points much dimmer than the light beside
            // them: a sheet's tail on a corner, a glint) take no part in reading the row: they follow the segment they continue (pass 3). A cut point as bright as the
            // stripes is a stripe half hidden by an edge and is read with the others.
            self.row_points.clear();
            self.row_points.extend(
                self.order[start..end]
                    .iter()
                    .copied()
                    .filter(|&i| !points[i as usize].cut),
            );
            if self.row_points.len() < end - start || self.params.faint_intensity > 0.0 {
                self.levels.clear();
                self.levels.extend(
                    self.row_points
                        .iter()
                        .map(|&i| points[i as usize].intensity),
                );
                let reference = if self.levels.is_empty() {
                    0.0
                } else {
                    let mid = self.levels.len() / 2;
                    *self.levels.select_nth_unstable_by(mid, f32::total_cmp).1
                };
                let dim = self.params.fragment_intensity as f32 * reference;
                let faint = self.params.faint_intensity as f32;
                self.row_points.clear();
                let row = &self.order[start..end];
                for (n, &i) in row.iter().enumerate() {
                    let p = &points[i as usize];
                    let level = |m: Option<&u32>| m.map_or(0.0, |&j| points[j as usize].intensity);
                    let beside =
                        level(n.checked_sub(1).and_then(|m| row.get(m))).max(level(row.get(n + 1)));
                    let fragment = (p.cut && p.intensity < dim) || p.intensity < faint * beside;
                    self.fragment[i as usize] = fragment;
                    if !fragment {
                        self.row_points.push(i);
                    }
                }
            }
            if !self.row_points.is_empty() {
                self.label_row(points, row);
            }
            start = end;
        }
        // Pass 2: segments down the image.
        self.link_segments(points);
        // Pass 3: votes, then the final ordering check per row.
        self.decide(points, out);
    }

    #[inline]
    fn band_of(&self, row: u32, k: usize) -> &Band {
        &self.bands[row as usize * self.stripes + k]
    }

    /// Cost of stripes hidden beyond the end of a row on the projector's side by a rise from the belt to the
    /// first point there (height `z`): `None` when the point is too low for that.
    fn belt_rise_skip(&self, n: usize, z: f32) -> Option<f32> {
        (n > 0 && f64::from(z) >= self.params.rise_mm)
            .then_some((self.params.rise_skip_cost + n as f64 * self.params.edge_skip_cost) as f32)
    }

    /// Cost of stripes `0 .. label` missing left of the first labelled point (height `z`): each out of view at
    /// that height, or (projector on the left) all hidden by the rise from the belt to the point.
    fn left_skip(&self, row: u32, label: u16, z: f32) -> f32 {
        let rise = self.params.rise_mm as f32;
        let each: f32 = (0..usize::from(label))
            .map(|k| {
                let b = self.band_of(row, k);
                // Out of view at this height: the stripe shows heights above z_left only left of column 0.
                let gone = b.z_left.is_nan()
                    || if b.leftward {
                        z >= b.z_left - rise
                    } else {
                        z <= b.z_left + rise
                    };
                if gone {
                    self.params.edge_skip_cost as f32
                } else {
                    self.params.skip_cost as f32
                }
            })
            .sum();
        let projector_left = self.band_of(row, usize::from(label)).leftward;
        match self.belt_rise_skip(usize::from(label), z) {
            Some(c) if projector_left => each.min(c),
            _ => each,
        }
    }

    /// Cost of stripes after `label` missing right of the last labelled point (height `z`).
    fn right_skip(&self, row: u32, label: u16, z: f32) -> f32 {
        let rise = self.params.rise_mm as f32;
        let each: f32 = (usize::from(label) + 1..self.stripes)
            .map(|k| {
                let b = self.band_of(row, k);
                let gone = b.z_right.is_nan()
                    || if b.leftward {
                        z <= b.z_right + rise
                    } else {
                        z >= b.z_right - rise
                    };
                if gone {
                    self.params.edge_skip_cost as f32
                } else {
                    self.params.skip_cost as f32
                }
            })
            .sum();
        let projector_left = self.band_of(row, usize::from(label)).leftward;
        match self.belt_rise_skip(self.stripes - 1 - usize::from(label), z) {
            Some(c) if !projector_left => each.min(c),
            _ => each,
        }
    }

    /// Pass 1 over the points `row_points` of one row.
    ///
    /// Forward and backward passes of dynamic programming give each (point, label) item the cost of the best row
    /// labelling through it (its min-marginal). Only costs within [`StripeCoder::window`] of the row's best
    /// labelling ever change a decision (a label is kept by a margin, alternatives are offered within
    /// [`CodingParams::segment_override_cost`]), so the backward pass and the false-point pass visit only the
    /// items whose forward cost is within that window: every labelling through another item costs more, so the
    /// min-marginals within the window are exactly what the full passes give, and the ones beyond stay beyond.
    fn label_row(&mut self, points: &[StripePoint], row: u32) {
        let m = self.row_points.len();
        let q = self.params.outlier_cost as f32;
        let run = self.params.max_outlier_run;
        self.items.clear();
        self.row_start.clear();
        for j in 0..m {
            self.row_start.push(self.items.len());
            let idx = self.row_points[j] as usize;
            let u = points[idx].x;
            let (xn, yn) = self.normalized[idx];
            let mut cursor = EdgeCursor::START;
            for k in 0..self.stripes {
                let b = self.band_of(row, k);
                let uf = u as f32;
                if !(uf >= b.u_min && uf <= b.u_max) {
                    continue;
                }
                let sign = if b.leftward { 1.0 } else { -1.0 };
                if let Some(z) = self.model.height_normalized(k, xn, yn) {
                    let z = z as f32;
                    let (left, right) = self
                        .edges
                        .costs(&self.transitions, row, k as u16, z, &mut cursor)
                        .unwrap_or_else(|| {
                            (
                                self.left_skip(row, k as u16, z),
                                self.right_skip(row, k as u16, z),
                            )
                        });
                    self.items.push(Item {
                        j: j as u16,
                        label: k as u16,
                        z,
                        sign,
                        level: points[idx].intensity,
                        forward: f32::INFINITY,
                        backward: f32::INFINITY,
                        start: q * j as f32 + left,
                        end: q * (m - 1 - j) as f32 + right,
                    });
                }
            }
        }
        self.row_start.push(self.items.len());
        // The passes below visit pairs of items at most `run + 1` points apart with growing labels (items of one
        // point are in label order). A candidate whose cost before its transition already reaches the best found
        // cannot improve it (transition costs are never negative): its transition is not computed.
        let tr = &self.transitions;
        let (items, row_start) = (&mut self.items, &self.row_start);
        // Forward: best cost of the row's left part ending with this item labelled (nearest points first, whose
        // transitions skip no point and usually win).
        for bi in 0..items.len() {
            let b = items[bi];
            let jb = usize::from(b.j);
            let mut best = b.start;
            for ja in (jb.saturating_sub(run + 1)..jb).rev() {
                let gap = q * (jb - ja - 1) as f32;
                for a in &items[row_start[ja]..row_start[ja + 1]] {
                    if a.label > b.label {
                        break;
                    }
                    relax(&mut best, a.forward + gap, || {
                        tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                    });
                }
            }
            items[bi].forward = best;
        }
        // The row's best labelling (no point labelled at all: every stripe missing), and the items within the
        // window of it.
        let nothing = q * m as f32 + self.stripes as f32 * self.params.skip_cost as f32;
        let limit = items
            .iter()
            .fold(nothing, |g, it| g.min(it.forward + it.end))
            + self.window;
        self.alive.clear();
        self.alive_start.clear();
        for j in 0..m {
            self.alive_start.push(self.alive.len());
            self.alive.extend(
                (row_start[j]..row_start[j + 1])
                    .filter(|&i| items[i].forward <= limit)
                    .map(|i| i as u32),
            );
        }
        self.alive_start.push(self.alive.len());
        let (alive, alive_start) = (&self.alive, &self.alive_start);
        // Backward: best cost of the right part given this item labelled, where it keeps the item within the
        // window; beyond that only "beyond" matters (infinity), so candidates that cannot come below it are not
        // computed either. Points right to left; each point's items with a finite cost are then copied together
        // (`back`), the only ones the points before it need.
        self.back.clear();
        self.back_range.clear();
        self.back_range.resize(m, (0, 0));
        for ja in (0..m).rev() {
            let first = self.back.len();
            for &ai in alive[alive_start[ja]..alive_start[ja + 1]].iter() {
                let a = items[ai as usize];
                let cap = limit - a.forward;
                let mut best = a.end.min(cap);
                for jb in ja + 1..(ja + run + 2).min(m) {
                    let gap = q * (jb - ja - 1) as f32;
                    let (s, e) = self.back_range[jb];
                    for b in &self.back[s..e] {
                        if b.label < a.label {
                            continue;
                        }
                        relax(&mut best, b.backward + gap, || {
                            tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                        });
                    }
                }
                if best < cap {
                    items[ai as usize].backward = best;
                    self.back.push(Back {
                        label: a.label,
                        z: a.z,
                        sign: a.sign,
                        level: a.level,
                        backward: best,
                    });
                }
            }
            self.back_range[ja] = (first, self.back.len());
        }
        // Min-marginals of "point j is false".
        self.outlier_marginal.clear();
        self.outlier_marginal.resize(m, nothing);
        let mut prefix = f32::INFINITY; // best cost ending the labelling at a point left of j
        for j in 0..m {
            if j > 0 {
                for a in &items[row_start[j - 1]..row_start[j]] {
                    prefix = prefix.min(a.forward + a.end);
                }
            }
            self.outlier_marginal[j] = self.outlier_marginal[j].min(prefix);
        }
        let mut suffix = f32::INFINITY; // best cost starting the labelling at a point right of j
        for j in (0..m).rev() {
            if j + 1 < m {
                for b in &items[row_start[j + 1]..row_start[j + 2]] {
                    suffix = suffix.min(b.start + b.backward);
                }
            }
            self.outlier_marginal[j] = self.outlier_marginal[j].min(suffix);
        }
        // Labellings that declare the points strictly between two labelled ones false: only items whose own
        // min-marginal is within the window can be on such a labelling within it.
        self.live.clear();
        self.live_start.clear();
        for j in 0..m {
            self.live_start.push(self.live.len());
            self.live.extend(
                alive[alive_start[j]..alive_start[j + 1]]
                    .iter()
                    .copied()
                    .filter(|&i| {
                        let it = &items[i as usize];
                        it.forward + it.backward <= limit
                    }),
            );
        }
        self.live_start.push(self.live.len());
        let (live, live_start) = (&self.live, &self.live_start);
        for ja in 0..m {
            let before = &live[live_start[ja]..live_start[ja + 1]];
            if before.is_empty() {
                continue;
            }
            for jb in ja + 2..(ja + run + 2).min(m) {
                let gap = q * (jb - ja - 1) as f32;
                let after = &live[live_start[jb]..live_start[jb + 1]];
                // Only a labelling within the window counts; one whose cost without its transition already
                // reaches the best is not computed.
                let mut best = limit;
                for &ai in before {
                    let a = &items[ai as usize];
                    let base = a.forward + gap;
                    for &bi in after {
                        let b = &items[bi as usize];
                        if b.label < a.label || base + b.backward >= best {
                            continue;
                        }
                        let c = base
                            + tr.cost(a.label, b.label, a.z, b.z, b.sign, a.level, b.level)
                            + b.backward;
                        if c < best {
                            best = c;
                        }
                    }
                }
                if best < limit {
                    for o in &mut self.outlier_marginal[ja + 1..jb] {
                        *o = o.min(best);
                    }
                }
            }
        }
        // Decisions.
        let margin = self.params.margin as f32;
        for j in 0..m {
            let idx = self.row_points[j] as usize;
            let (mut best, mut best_label, mut best_z) = (f32::INFINITY, NO_LABEL, f32::NAN);
            // Runner-up (cost, label) pairs, cheapest first.
            let mut alt = [(f32::INFINITY, NO_LABEL); 2];
            for it in &self.items[self.row_start[j]..self.row_start[j + 1]] {
                let c = it.forward + it.backward;
                if c < best {
                    alt[1] = alt[0];
                    alt[0] = (best, best_label);
                    best = c;
                    best_label = it.label;
                    best_z = it.z;
                } else if c < alt[0].0 {
                    alt[1] = alt[0];
                    alt[0] = (c, it.label);
                } else if c < alt[1].0 {
                    alt[1] = (c, it.label);
                }
            }
            let second = alt[0].0;
            let outlier = self.outlier_marginal[j];
            let st = &mut self.state[idx];
            if best_label == NO_LABEL || outlier + margin <= best {
                st.best = NO_LABEL;
                st.confident = true;
            } else {
                st.best = best_label;
                st.z = best_z;
                st.confident = best + margin <= second.min(outlier);
                st.alternatives = alt.map(|(c, l)| (l, c - best));
            }
        }
    }

    /// Pass 2: links points of consecutive rows into segments with the fuzzy rules.
    fn link_segments(&mut self, points: &[StripePoint]) {
        self.segments.clear();
        self.open.clear();
        let max_gap = self.params.max_gap_rows;
        let mut i = 0;
        while i < self.order.len() {
            let row = points[self.order[i] as usize].row;
            // Close segments that can no longer be continued.
            self.open.retain(|&s| {
                let seg = &self.segments[s as usize];
                row - seg.last_row - 1 <= max_gap
            });
            while i < self.order.len() && points[self.order[i] as usize].row == row {
                let idx = self.order[i] as usize;
                i += 1;
                let st = self.state[idx];
                let p = &points[idx];
                let fragment = self.fragment[idx];
                if st.best == NO_LABEL && !fragment {
                    continue;
                }
                // The closest open segment that the rules let this point continue, and the point's height under
                // the segment's label.
                let mut chosen: Option<(u32, f64, f64)> = None;
                for &s in &self.open {
                    let seg = &self.segments[s as usize];
                    if seg.taken_row == row {
                        continue;
                    }
                    let gap = row - seg.last_row - 1;
                    let du = (p.x - seg.last_u).abs();
                    if du > self.params.link_px * (1.0 + f64::from(gap)) {
                        continue;
                    }
                    // Brightness: a stripe keeps it down one surface.
                    let (a, b) = (f64::from(p.intensity), f64::from(seg.last_intensity));
                    let ratio = self.params.link_intensity_ratio;
                    if a < ratio * b || ratio * a > b {
                        continue;
                    }
                    // Heights compared under the segment's label.
                    let (xn, yn) = self.normalized[idx];
                    let z = self
                        .model
                        .height_normalized(usize::from(seg.last_label), xn, yn)
                        .unwrap_or(f64::NAN);
                    let change = (z - f64::from(seg.last_z)).abs();
                    let ok = if gap == 0 {
                        self.tables.same_segment(z, change)
                    } else {
                        self.tables.same_segment(z, 0.0) && self.tables.bridge_gap(gap, change)
                    };
                    if ok && chosen.is_none_or(|(_, d, _)| du < d) {
                        chosen = Some((s, du, z));
                    }
                }
                if fragment {
                    // A fragment never starts a segment nor votes; it continues the one it lines up with.
                    if let Some((s, _, z)) = chosen {
                        let seg = &mut self.segments[s as usize];
                        seg.last_row = row;
                        seg.taken_row = row;
                        seg.last_u = p.x;
                        seg.last_intensity = p.intensity;
                        seg.last_z = z as f32;
                        self.state[idx].segment = s;
                    }
                    continue;
                }
                let (s, z_under_segment) = match chosen {
                    Some((s, _, z)) => (s, Some(z)),
                    None => {
                        // Rule 1: only points that are not very low start segments.
                        if !self.tables.same_segment(f64::from(st.z), 0.0) {
                            continue;
                        }
                        let s = self.segments.len() as u32;
                        self.segments.push(SegmentState::default());
                        self.open.push(s);
                        (s, None)
                    }
                };
                let seg = &mut self.segments[s as usize];
                seg.last_row = row;
                seg.taken_row = row;
                seg.last_u = p.x;
                seg.last_intensity = p.intensity;
                // Heights down the segment are compared under the label its last settled point had: a row read one
                // stripe over without confidence (a near tie) would otherwise carry that reading on, and under it a
                // 10 mm plate can look like a 3 mm one, low enough for rule 1 to end the segment there.
                match z_under_segment {
                    Some(z) if !st.confident => seg.last_z = z as f32,
                    _ => {
                        seg.last_label = st.best;
                        seg.last_z = st.z;
                    }
                }
                seg.length += 1;
                if st.confident {
                    seg.total_votes += 1;
                    if let Some(v) = seg.votes.iter_mut().find(|v| v.1 > 0 && v.0 == st.best) {
                        v.1 += 1;
                    } else if let Some(v) = seg.votes.iter_mut().find(|v| v.1 == 0) {
                        *v = (st.best, 1);
                    }
                }
                self.state[idx].segment = s;
            }
        }
    }

    /// Whether points `a` and `b` (left to right in `row`) are one sheet `label` seen twice by their row's own
    /// reading: both read as `label`, the right one lower by more than a jump.
    fn split(&self, row: u32, a: usize, b: usize, label: u16) -> bool {
        let (sa, sb) = (&self.state[a], &self.state[b]);
        let sign = if self.band_of(row, usize::from(label)).leftward {
            1.0
        } else {
            -1.0
        };
        sa.best == label
            && sb.best == label
            && self
                .transitions
                // One sheet twice: the peaks are not compared.
                .cost(label, label, sa.z, sb.z, sign, 0.0, 0.0)
                .is_finite()
    }

    /// The ordering check against overruled points (`self.order[start..end]`, one row): a point only its row
    /// labelled (on the belt, in no segment) that lies between overruled points of its row is dropped where its
    /// label breaks the order with the labels their segments voted for. Where a plate's height moves its stripes by
    /// one pitch, a row near the plate's edge can read the whole plate one stripe over with confidence: the
    /// segments running down the plate drop those readings, but the stripe that lands on its neighbour's belt
    /// column reads as belt, out of every segment, and kept its row's label. Only between overruled points: beyond
    /// the last of them the belt past a tall part may show the part's last sheets a second time.
    fn order_by_overruled(&mut self, start: usize, end: usize, out: &mut Coding) {
        let row = &self.order[start..end];
        if row
            .iter()
            .all(|&idx| self.overruled[idx as usize] == NO_LABEL)
        {
            return;
        }
        // Smallest overruled label to the right of each point (NO_LABEL: none).
        let mut right_min = std::mem::take(&mut self.scratch_labels);
        right_min.clear();
        right_min.resize(row.len(), NO_LABEL);
        let mut right = NO_LABEL;
        for (k, &idx) in row.iter().enumerate().rev() {
            right_min[k] = right;
            right = right.min(self.overruled[idx as usize]);
        }
        // Largest overruled label to the left.
        let mut left: Option<u16> = None;
        for (k, &idx) in row.iter().enumerate() {
            let idx = idx as usize;
            if let (Some(l), Some(lm)) = (out.stripes[idx], left)
                && self.state[idx].segment == NO_SEGMENT
                && right_min[k] != NO_LABEL
                && (lm >= l || right_min[k] <= l)
            {
                out.stripes[idx] = None;
            }
            let o = self.overruled[idx];
            if o != NO_LABEL {
                left = Some(left.map_or(o, |lm| lm.max(o)));
            }
        }
        self.scratch_labels = right_min;
    }

    /// Pass 3: segment votes, per-point decisions and the ordering check.
    fn decide(&mut self, points: &[StripePoint], out: &mut Coding) {
        let share = self.params.min_vote_share;
        for &idx in &self.order {
            let idx = idx as usize;
            let st = self.state[idx];
            let p = &points[idx];
            let fragment = self.fragment[idx];
            let label = if st.best == NO_LABEL && !(fragment && st.segment != NO_SEGMENT) {
                None
            } else if st.segment == NO_SEGMENT {
                // Belt points: their row's decision.
                st.confident.then_some(st.best)
            } else {
                let seg = &self.segments[st.segment as usize];
                if !self.tables.keep_segment(seg.length as usize) {
                    None
                } else {
                    let winner = seg.votes.iter().max_by_key(|v| v.1).copied();
                    match winner {
                        Some((w, c))
                            if c > 0
                                && f64::from(c) >= share * f64::from(seg.total_votes)
                                && f64::from(seg.total_votes)
                                    >= self.params.min_voting_share * f64::from(seg.length) =>
                        {
                            // A point the row labelling would label otherwise (even without confidence) is
                            // not relabelled: where a stripe on one surface lines up with its neighbour on
                            // another, segments link across the jump.
                            // Unless the winner is nearly as good for this row: a stripe missing from the
                            // middle of a row (it fell into a hole) lets the row be read one stripe over with a
                            // single height jump, cheaper than the missing stripe; the segment, running on
                            // above and below the hole, settles it.
                            let near = st.alternatives.iter().any(|&(l, d)| {
                                l == w && d <= self.params.segment_override_cost as f32
                            });
                            if !fragment && st.best != w && !near {
                                self.overruled[idx] = w;
                                None
                            } else {
                                let b = self.band_of(p.row, usize::from(w));
                                let uf = p.x as f32;
                                (uf >= b.u_min && uf <= b.u_max).then_some(w)
                            }
                        }
                        _ => None,
                    }
                }
            };
            out.stripes[idx] = label;
            let mut near = [NO_LABEL; 3];
            if st.best != NO_LABEL {
                near[0] = st.best;
                let mut n = 1;
                for &(l, d) in &st.alternatives {
                    if l != NO_LABEL && d <= self.params.segment_override_cost as f32 {
                        near[n] = l;
                        n += 1;
                    }
                }
            }
            out.near[idx] = near;
            out.row_confident[idx] = st.confident && st.best != NO_LABEL;
        }
        // Ordering: labels must grow with the column along every row (or repeat where the row's reading saw one
        // sheet twice, see `Transitions::cost`); drop both sides of a violation.
        let mut i = 0;
        while i < self.order.len() {
            let row = points[self.order[i] as usize].row;
            let mut end = i;
            while end < self.order.len() && points[self.order[end] as usize].row == row {
                end += 1;
            }
            let mut last: Option<(usize, u16)> = None;
            for &idx in &self.order[i..end] {
                let idx = idx as usize;
                if let Some(l) = out.stripes[idx] {
                    if let Some((prev, pl)) = last
                        && (pl > l || (pl == l && !self.split(row, prev, idx, l)))
                    {
                        out.stripes[prev] = None;
                        out.stripes[idx] = None;
                        last = None;
                        continue;
                    }
                    last = Some((idx, l));
                }
            }
            self.order_by_overruled(i, end, out);
            i = end;
        }
        for (idx, l) in out.stripes.iter().enumerate() {
            let st = &self.state[idx];
            match l {
                Some(_) => out.stats.coded += 1,
                None if st.best == NO_LABEL => out.stats.noise += 1,
                None if st.segment != NO_SEGMENT
                    && !self
                        .tables
                        .keep_segment(self.segments[st.segment as usize].length as usize) =>
                {
                    out.stats.noise += 1
                }
                None => out.stats.ambiguous += 1,
            }
        }
    }
}

#[cfg(test)]
mod temporal_tests {
    use super::*;

    /// Frames of one row with stripes 0, 1, 2 at columns 100, 150, 200 (shifted by `drift` px per frame), every
    /// point coded and row-confident.
    fn frames(n: usize, drift: f64) -> Vec<CodedFrame> {
        (0..n)
            .map(|k| {
                let points: Vec<StripePoint> = [100.0, 150.0, 200.0]
                    .iter()
                    .map(|&x| StripePoint {
                        row: 7,
                        x: x + drift * k as f64,
                        intensity: 200.0,
                        width: 6.0,
                        score: 0.8,
                        cut: false,
                    })
                    .collect();
                CodedFrame {
                    coding: Coding {
                        stripes: vec![Some(0), Some(1), Some(2)],
                        near: vec![
                            [0, NO_LABEL, NO_LABEL],
                            [1, NO_LABEL, NO_LABEL],
                            [2, NO_LABEL, NO_LABEL],
                        ],
                        row_confident: vec![true; 3],
                        stats: CodingStats {
                            points: 3,
                            coded: 3,
                            ..CodingStats::default()
                        },
                    },
                    points,
                }
            })
            .collect()
    }

    fn drop(f: &mut CodedFrame, i: usize, near: [u16; 3]) {
        f.coding.stripes[i] = None;
        f.coding.near[i] = near;
        f.coding.row_confident[i] = false;
        f.coding.stats.coded -= 1;
        f.coding.stats.ambiguous += 1;
    }

    proptest::proptest! {
        #[test]
        fn row_links_are_the_mutual_unique_nearest_pairs(
            mut xa in proptest::collection::vec(0.0f64..40.0, 0..12),
            mut xb in proptest::collection::vec(0.0f64..40.0, 0..12),
            link in 0.5f64..6.0,
        ) {
            // Coarse columns make ties and points exactly at the link distance common.
            for x in xa.iter_mut().chain(xb.iter_mut()) {
                *x = (*x * 4.0).round() / 4.0;
            }
            xa.sort_by(f64::total_cmp);
            xb.sort_by(f64::total_cmp);
            let pts = |xs: &[f64]| -> Vec<StripePoint> { xs.iter().map(|&x| super::tests::point(0, x)).collect() };
            let (a, b) = (pts(&xa), pts(&xb));
            // The definition, by brute force: nearest both ways, within reach, no other point within reach.
            let nearest = |ps: &[StripePoint], x: f64| {
                ps.iter()
                    .enumerate()
                    .map(|(k, p)| (k, (p.x - x).abs()))
                    .min_by(|u, v| u.1.total_cmp(&v.1))
            };
            let mut expected = Vec::new();
            for (i, p) in a.iter().enumerate() {
                let Some((j, d)) = nearest(&b, p.x) else { continue };
                let mutual = nearest(&a, b[j].x).is_some_and(|(ii, _)| ii == i);
                let others_a = a.iter().enumerate().any(|(ii, o)| ii != i && (o.x - b[j].x).abs() <= link);
                let others_b = b.iter().enumerate().any(|(jj, o)| jj != j && (o.x - p.x).abs() <= link);
                if d <= link && mutual && !others_a && !others_b {
                    expected.push((i, j));
                }
            }
            proptest::prop_assert_eq!(row_links(&a, &b, link), expected);
        }
    }

    #[test]
    fn a_dropped_point_between_agreeing_frames_takes_its_tracks_label() {
        let mut f = frames(9, 0.3);
        // The middle stripe is dropped in frames 3 and 4; its row could read it as 2 (cheapest) or 1.
        drop(&mut f[3], 1, [2, 1, NO_LABEL]);
        drop(&mut f[4], 1, [2, 1, NO_LABEL]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
        assert_eq!(f[3].coding.stripes[1], Some(1));
        assert_eq!(f[4].coding.stats.coded, 3);
        assert_eq!(f[4].coding.stats.ambiguous, 0);
    }

    #[test]
    fn a_frame_misread_with_confidence_among_frames_its_segments_coded_follows_them() {
        // 16 frames whose rows were all ambiguous and coded (right) by their segments, but for frame 6, whose row
        // read every stripe one over with confidence.
        let setup = |also_settled: Option<usize>| {
            let mut f = frames(16, 0.2);
            for (k, frame) in f.iter_mut().enumerate() {
                frame.coding.row_confident = vec![k == 6 || Some(k) == also_settled; 3];
                if k == 6 || Some(k) == also_settled {
                    frame.coding.stripes = vec![Some(1), Some(2), Some(3)];
                }
            }
            f
        };
        let mut f = setup(None);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
        assert_eq!(f[6].coding.stripes, vec![Some(0), Some(1), Some(2)]);
        // Off: the confident reading stands.
        let mut f = setup(None);
        let off = TemporalParams {
            overrule_segment_votes: 0,
            ..TemporalParams::default()
        };
        assert_eq!(reconcile(&mut f, &off), 0);
        // A second frame whose row settled the same reading: the segments' labels no longer decide.
        let mut f = setup(Some(11));
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        assert_eq!(f[6].coding.stripes, vec![Some(1), Some(2), Some(3)]);
    }

    #[test]
    fn segment_coded_and_settled_frames_together_overrule_a_tracks_last_frame() {
        // n frames whose rows were ambiguous and coded (right) by their segments, `settled` of them (the frames
        // before the last) settled right by their rows, and the last frame's row read every stripe one over with
        // confidence (a sheet about to vanish over an edge): no frame after it.
        let setup = |n: usize, settled: usize| {
            let mut f = frames(n, 0.2);
            let last = n - 1;
            for (k, frame) in f.iter_mut().enumerate() {
                frame.coding.row_confident = vec![k == last || k + 1 + settled > last; 3];
                if k == last {
                    frame.coding.stripes = vec![Some(1), Some(2), Some(3)];
                }
            }
            f
        };
        // 12 segment-coded frames before it: overruled from the one side there is.
        let mut f = setup(13, 0);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
        assert_eq!(f[12].coding.stripes, vec![Some(0), Some(1), Some(2)]);
        // 9 segment-coded and 2 settled frames (9 + 2 x 2 = 13): overruled; 11 segment-coded alone are not enough.
        let mut f = setup(12, 2);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 3);
        assert_eq!(f[11].coding.stripes, vec![Some(0), Some(1), Some(2)]);
        let mut f = setup(12, 0);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        assert_eq!(f[11].coding.stripes, vec![Some(1), Some(2), Some(3)]);
    }

    #[test]
    fn a_point_only_the_segment_vote_coded_at_its_tracks_end_follows_the_track() {
        // The last frame's middle stripe, sliding 1.5 px a frame, coded 0 by its segment (its row not settled):
        // its track's settled points before it read 1.
        let misread = |n: usize| {
            let mut f = frames(n, 1.5);
            let last = f.len() - 1;
            f[last].coding.stripes[1] = Some(0);
            f[last].coding.near[1] = [0, 1, NO_LABEL];
            f[last].coding.row_confident[1] = false;
            // Its left neighbour dropped, so that the row stays ordered either way.
            drop(&mut f[last], 0, [0, NO_LABEL, NO_LABEL]);
            f
        };
        let mut f = misread(7);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 1);
        assert_eq!(f[6].coding.stripes[1], Some(1));
        // Fewer settled points than it takes to overrule a row (5 of 6): left alone.
        let mut f = misread(6);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        assert_eq!(f[5].coding.stripes[1], Some(0));
        // A dropped point at the track's end is not extrapolated (the row's last, which its order does not pin
        // down either).
        let mut f = frames(7, 1.5);
        drop(&mut f[6], 2, [2, 1, NO_LABEL]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    }

    #[test]
    fn a_row_only_the_segment_vote_coded_follows_its_tracks_as_a_whole() {
        let mut f = frames(12, 0.2);
        // Frame 4's row read one stripe over, its own labelling not settled (the segment vote coded it).
        for i in 0..3 {
            f[4].coding.stripes[i] = Some(i as u16 + 1);
            f[4].coding.near[i] = [i as u16 + 1, i as u16, NO_LABEL];
            f[4].coding.row_confident[i] = false;
        }
        // Frame 5 the same, but its first point was settled by its row: without overruling it keeps its label,
        // and relabelling the others alone would break the row's order, so none is changed.
        for i in 0..3 {
            f[5].coding.stripes[i] = Some(i as u16 + 1);
            f[5].coding.near[i] = [i as u16 + 1, i as u16, NO_LABEL];
            f[5].coding.row_confident[i] = i == 0;
        }
        let mut overruled = f.clone();
        let params = TemporalParams {
            overrule_votes: 0,
            ..TemporalParams::default()
        };
        assert_eq!(reconcile(&mut f, &params), 3);
        assert_eq!(f[4].coding.stripes, vec![Some(0), Some(1), Some(2)]);
        assert_eq!(f[4].coding.stats.coded, 3);
        assert_eq!(f[5].coding.stripes, vec![Some(1), Some(2), Some(3)]);
        // With overruling (the default), the settled point follows its track too, and the row with it.
        assert_eq!(reconcile(&mut overruled, &TemporalParams::default()), 6);
        assert_eq!(overruled[5].coding.stripes, vec![Some(0), Some(1), Some(2)]);
    }

    /// Frame `k` of [`frames`] misread with confidence: a ghost at column 175 read as stripe 2, so that the
    /// stripe at 200 reads as 3.
    fn misread(f: &mut CodedFrame) {
        f.points.insert(
            2,
            StripePoint {
                x: 175.0 + (f.points[2].x - 200.0),
                intensity: 40.0,
                ..f.points[2]
            },
        );
        f.coding.stripes = vec![Some(0), Some(1), Some(2), Some(3)];
        f.coding.near = vec![
            [0, NO_LABEL, NO_LABEL],
            [1, NO_LABEL, NO_LABEL],
            [2, NO_LABEL, NO_LABEL],
            [3, NO_LABEL, NO_LABEL],
        ];
        f.coding.row_confident = vec![true; 4];
        f.coding.stats.points = 4;
        f.coding.stats.coded = 4;
    }

    #[test]
    fn tracks_overrule_a_frame_misread_with_confidence() {
        let mut f = frames(16, 0.2);
        misread(&mut f[6]);
        // Overruling off: a confident reading stands.
        let mut off = f.clone();
        let params = TemporalParams {
            overrule_votes: 0,
            ..TemporalParams::default()
        };
        assert_eq!(reconcile(&mut off, &params), 0);
        assert_eq!(off[6].coding.stripes[3], Some(3));
        // On: the stripe at 200 takes its track's label, and the ghost, which no track supports and which now
        // breaks the row's order, is dropped.
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
        assert_eq!(f[6].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
        assert_eq!(f[6].coding.stats.coded, 3);
        assert_eq!(f[6].coding.stats.ambiguous, 1);
        // The same misreading in the scan's first frame: its track reaches it from the one side there is, with as
        // many settled points, and overrules it the same way.
        let mut g = frames(16, 0.2);
        misread(&mut g[0]);
        assert_eq!(reconcile(&mut g, &TemporalParams::default()), 2);
        assert_eq!(g[0].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
        // With fewer settled points after it than it takes (5 of 6), it stands.
        let mut g = frames(6, 0.2);
        misread(&mut g[0]);
        assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
        assert_eq!(g[0].coding.stripes[3], Some(3));
        // Mid-scan, where the stripe's track ends (the sheet slid over an edge and vanished after frame 12): the
        // misreading of its last frame is overruled from the one side there is, as at the scan's ends.
        let mut h = frames(16, 0.2);
        for f in &mut h[13..] {
            f.points.truncate(2);
            f.coding.stripes.truncate(2);
            f.coding.near.truncate(2);
            f.coding.row_confident.truncate(2);
            f.coding.stats.points = 2;
            f.coding.stats.coded = 2;
        }
        misread(&mut h[12]);
        assert_eq!(reconcile(&mut h, &TemporalParams::default()), 2);
        assert_eq!(h[12].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
    }

    /// 16 frames of three stripes whose middle track's settled points read 1 in all but two frames (9 there: a
    /// share of 0.86, too little for a track to decide alone).
    fn frames_with_a_weak_middle_track() -> Vec<CodedFrame> {
        let mut f = frames(16, 0.2);
        for k in [2, 12] {
            f[k].coding.stripes[1] = Some(9);
        }
        f
    }

    #[test]
    fn a_point_the_rows_order_leaves_one_label_takes_its_tracks_majority() {
        // Dropped between 0 and 2 in frame 6: its track's 13 of 15 votes for 1 do not reach the share, but the row
        // leaves it 1 alone.
        let mut f = frames_with_a_weak_middle_track();
        drop(&mut f[6], 1, [1, 0, 2]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 1);
        assert_eq!(f[6].coding.stripes[1], Some(1));
        // Not where its own row could not take that label.
        let mut g = frames_with_a_weak_middle_track();
        drop(&mut g[6], 1, [0, 2, NO_LABEL]);
        assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
        // A track that never settled (every row of it ambiguous, or the scan's last frames): the row's order alone
        // gives the point its label, unless its track reads another label.
        let mut u = frames(6, 0.0);
        for fr in u.iter_mut() {
            fr.coding.row_confident[1] = false;
        }
        drop(&mut u[5], 1, [0, 1, 2]);
        assert_eq!(reconcile(&mut u, &TemporalParams::default()), 1);
        assert_eq!(u[5].coding.stripes[1], Some(1));
        let mut o = frames(6, 0.0);
        for fr in o.iter_mut().take(4) {
            fr.coding.stripes[1] = Some(7);
        }
        drop(&mut o[5], 1, [0, 1, 2]);
        reconcile(&mut o, &TemporalParams::default());
        assert_eq!(o[5].coding.stripes[1], None);
        // A frame misread with confidence from the middle stripe on (a ghost at 175 read as 3, the last stripe as
        // 4): the last stripe's track overrules it to 2, the ghost is dropped, and the middle stripe, which its
        // weak track cannot overrule, takes the one label left between 0 and 2 instead of being dropped.
        let mut h = frames_with_a_weak_middle_track();
        misread(&mut h[6]);
        h[6].coding.stripes = vec![Some(0), Some(2), Some(3), Some(4)];
        reconcile(&mut h, &TemporalParams::default());
        assert_eq!(h[6].coding.stripes, vec![Some(0), Some(1), None, Some(2)]);
    }

    #[test]
    fn a_point_dropped_by_a_frame_read_one_over_takes_its_firm_tracks_label() {
        // Frame 6: a dim fragment right of the last stripe (a sheet's leading edge on a part's corner) is read
        // with confidence as stripe 2, and the stripe at 200 was dropped: its row would only read it as 1.
        let setup = |n: usize| {
            let mut f = frames(n, 0.2);
            let fr = &mut f[n / 2];
            fr.points.push(StripePoint {
                x: 225.0,
                intensity: 15.0,
                ..fr.points[2]
            });
            fr.coding.stripes.push(Some(2));
            fr.coding.near.push([2, NO_LABEL, NO_LABEL]);
            fr.coding.row_confident.push(true);
            fr.coding.stats.points += 1;
            drop(fr, 2, [1, NO_LABEL, NO_LABEL]);
            f
        };
        // Its track settled 2 in 8 frames before and 7 after: the point takes 2 though its row would not, and the
        // fragment, which no track supports and which now breaks the row's order, gives way.
        let mut f = setup(16);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 2);
        assert_eq!(f[8].coding.stripes, vec![Some(0), Some(1), Some(2), None]);
        // With 5 settled frames around it (3 before, 2 after), fewer than overrule a row: the row's reading stands.
        let mut g = setup(6);
        assert_eq!(reconcile(&mut g, &TemporalParams::default()), 0);
        assert_eq!(g[3].coding.stripes[2], None);
        // Nor with overruling off.
        let mut h = setup(16);
        let off = TemporalParams {
            overrule_votes: 0,
            ..TemporalParams::default()
        };
        assert_eq!(reconcile(&mut h, &off), 0);
    }

    #[test]
    fn two_supported_labels_in_conflict_overrule_nothing() {
        let mut f = frames(16, 0.2);
        // The ghost's column is lit in every frame and read as 2 there: its track supports it as much as the
        // stripe's track supports 2 at column 200 (the other frames' rows are not ordered, which the coder would
        // not give, but only their votes matter here).
        for fr in f.iter_mut() {
            misread(fr);
            fr.coding.stripes[3] = Some(2);
        }
        f[6].coding.stripes[3] = Some(3);
        let before = f[6].coding.stripes.clone();
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        assert_eq!(f[6].coding.stripes, before);
    }

    #[test]
    fn reconciliation_never_extrapolates_jumps_or_guesses() {
        // Dropped in the last frame: no coded point after it (the row's last point, which the row's order does not
        // pin down either).
        let mut f = frames(6, 0.0);
        drop(&mut f[5], 2, [2, 1, NO_LABEL]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        // (The row's last point from here on: a point between two labelled neighbours that leave it one label can
        // take it by the row's order alone, which is not what these cases test.)
        // A jump of 5 px between frames ends the track.
        let mut f = frames(7, 5.0);
        drop(&mut f[3], 2, [2, 1, NO_LABEL]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        // The track's label is not one the row could take, and the track (5 settled points) is not firm enough to
        // overrule the row (`a_point_dropped_by_a_frame_read_one_over_takes_its_firm_tracks_label`).
        let mut f = frames(6, 0.0);
        drop(&mut f[3], 2, [1, NO_LABEL, NO_LABEL]);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        // The label would break the row's order (its right neighbour was coded 1).
        let mut f = frames(7, 0.0);
        drop(&mut f[3], 1, [1, 2, NO_LABEL]);
        f[3].coding.stripes[2] = Some(1);
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        // Two candidates within the link distance: no link.
        let mut f = frames(7, 0.0);
        drop(&mut f[3], 2, [2, 1, NO_LABEL]);
        f[3].points[1].x = 199.5;
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
        // Frames whose points and coding disagree in length are left alone.
        let mut f = frames(7, 0.0);
        drop(&mut f[3], 1, [1, 2, NO_LABEL]);
        f[2].coding.stripes.pop();
        assert_eq!(reconcile(&mut f, &TemporalParams::default()), 0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensor::Sensor;

    pub(super) fn point(row: u32, x: f64) -> StripePoint {
        StripePoint {
            row,
            x,
            intensity: 100.0,
            width: 4.0,
            score: 1.0,
            cut: false,
        }
    }

    /// Points of a flat surface at height `z` for all stripes whose column is in view, rows `rows`.
    fn flat(
        model: &FullModel,
        sensor: &Sensor,
        z: f64,
        rows: std::ops::Range<u32>,
    ) -> Vec<(StripePoint, u16)> {
        let mut out = Vec::new();
        for row in rows {
            for k in 0..sensor.laser.stripes {
                let u = model
                    .column_at_height(k, f64::from(row), z)
                    .expect("column");
                if u >= 0.0 && u <= f64::from(sensor.camera.width) - 1.0 {
                    out.push((point(row, u), k as u16));
                }
            }
        }
        out
    }

    fn code(coder: &mut StripeCoder, pts: &[(StripePoint, u16)]) -> (Coding, usize) {
        let points: Vec<StripePoint> = pts.iter().map(|p| p.0).collect();
        let mut out = Coding::default();
        coder.code_into(&points, &mut out);
        let wrong = out
            .stripes
            .iter()
            .zip(pts)
            .filter(|(l, p)| l.is_some_and(|l| l != p.1))
            .count();
        (out, wrong)
    }

    #[test]
    fn the_fuzzy_tables_follow_the_rules() {
        let t = FuzzyTables::shipped().expect("tables");
        assert!(t.same_segment(5.0, 0.05));
        assert!(!t.same_segment(5.0, 5.0));
        assert!(
            !t.same_segment(0.0, 0.0),
            "rule 1: belt points are not segments"
        );
        assert!(t.bridge_gap(1, 3.0), "rule 2: a very small gap is bridged");
        assert!(t.bridge_gap(50, 0.1), "rule 3");
        assert!(!t.bridge_gap(20, 3.0));
        assert!(!t.keep_segment(2), "rule 5");
        assert!(t.keep_segment(30));
    }

    #[test]
    fn bands_contain_the_flat_surfaces_of_the_range() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        for (p, k) in flat(&model, &sensor, 12.0, 0..480) {
            let (lo, hi) = coder.band(p.row, usize::from(k)).expect("band");
            assert!(p.x >= lo && p.x <= hi, "{p:?} stripe {k} band {lo}..{hi}");
        }
        assert!(coder.band(480, 0).is_none());
    }

    #[test]
    fn a_flat_plate_at_any_height_is_coded_without_a_wrong_index() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        for z in [0.0, 3.0, 7.5, 15.0, 30.0] {
            let pts = flat(&model, &sensor, z, 0..480);
            let (out, wrong) = code(&mut coder, &pts);
            assert_eq!(wrong, 0, "z = {z}");
            assert!(
                out.stats.coded as f64 > 0.99 * pts.len() as f64,
                "z = {z}: {:?}",
                out.stats
            );
        }
    }

    #[test]
    fn a_raised_plate_with_a_hidden_stripe_is_coded_by_the_occlusion_rule() {
        // Rows 0..100 see the belt; rows 100..480 a plate 10 mm high whose left edge hides one stripe.
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let mut pts = flat(&model, &sensor, 0.0, 0..100);
        for (p, k) in flat(&model, &sensor, 0.0, 100..480) {
            if k == 0 || k == 10 {
                pts.push((p, k));
            }
        }
        for (p, k) in flat(&model, &sensor, 10.0, 100..480) {
            if (2..=9).contains(&k) {
                pts.push((p, k));
            }
        }
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0);
        assert!(
            out.stats.coded as f64 > 0.99 * pts.len() as f64,
            "{:?}",
            out.stats
        );
    }

    #[test]
    fn one_sheet_seen_on_both_sides_of_an_edge_is_one_stripe_twice() {
        // A plate 5 mm high under stripes 2-5 whose right edge runs along the rows between where sheet 5 meets its
        // top and where it meets the belt: sheet 5 lights both, so every row holds stripe 5 twice, then 6-10 on
        // the belt (stripes 0 and 1 on the belt left of the plate). Read one stripe over, the plate would lie below
        // the belt: the only readings are the right one and the one that calls the second point false.
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut pts = Vec::new();
        for (p, k) in flat(&model, &sensor, 0.0, 100..480) {
            if k <= 1 || k >= 5 {
                pts.push((p, k));
            }
        }
        for (p, k) in flat(&model, &sensor, 5.0, 100..480) {
            if (2..=5).contains(&k) {
                pts.push((p, k));
            }
        }
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        let fives = pts
            .iter()
            .zip(&out.stripes)
            .filter(|((_, k), l)| *k == 5 && **l == Some(5))
            .count();
        assert_eq!(fives, 2 * 380, "both points of sheet 5 coded in every row");
        assert_eq!(out.stats.coded, pts.len(), "{:?}", out.stats);
        // A stray point halfway between two stripes of a flat belt is not a split: it stays false.
        let mut stray = flat(&model, &sensor, 0.0, 100..480);
        let extra: Vec<(StripePoint, u16)> = stray
            .windows(2)
            .filter(|w| w[0].0.row == w[1].0.row && w[0].1 == 4)
            .map(|w| (point(w[0].0.row, 0.5 * (w[0].0.x + w[1].0.x)), NO_LABEL))
            .collect();
        stray.extend(extra);
        stray.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        let (out, wrong) = code(&mut coder, &stray);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        for ((p, k), l) in stray.iter().zip(&out.stripes) {
            if *k == NO_LABEL {
                assert_eq!(*l, None, "the stray point stays false: {p:?}");
            }
        }
    }

    /// The demo's far edge: a plate 10 mm high (stripes 2-9) whose last stripe's sheet passes over the edge to the
    /// belt; its tail lights the corner (a dim fragment halfway between stripes 9 and 10). Stripe 5 runs along a
    /// hole's side in rows 250-270, cut there but as bright as ever.
    fn far_edge(sensor: &Sensor, model: &FullModel, mark: bool) -> Vec<(StripePoint, u16)> {
        let mut pts = Vec::new();
        for (p, k) in flat(model, sensor, 0.0, 100..480) {
            if k == 0 || k == 10 {
                pts.push((p, k));
            }
        }
        for (p, k) in flat(model, sensor, 10.0, 100..480) {
            if (2..=9).contains(&k) {
                let cut = mark && k == 5 && (250..270).contains(&p.row);
                pts.push((StripePoint { cut, ..p }, k));
            }
            if k == 9 {
                let belt = model
                    .column_at_height(10, f64::from(p.row), 0.0)
                    .expect("column");
                let x = p.x + 0.5 * (belt - p.x);
                let intensity = 40.0;
                pts.push((
                    StripePoint {
                        x,
                        intensity,
                        cut: mark,
                        ..p
                    },
                    NO_LABEL,
                ));
            }
        }
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        pts
    }

    /// Rows 100..300 of the demo part's step, as the simulator shows them: stripes 2-4 on a level step 14 mm high,
    /// 5-7 on the plate at 10 mm, 8 hidden by a boss whose top (18 mm) holds 9, and 10 on the belt beyond; all as
    /// bright as each other. Read one stripe over, the step and the plate come out tilted.
    fn step_rows(sensor: &Sensor, model: &FullModel) -> Vec<(StripePoint, u16)> {
        let mut pts = Vec::new();
        for (z, stripes) in [(14.0, 2..=4), (10.0, 5..=7), (18.0, 9..=9), (0.0, 10..=10)] {
            for (p, k) in flat(model, sensor, z, 100..300) {
                if stripes.contains(&k) {
                    pts.push((p, k));
                }
            }
        }
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        pts
    }

    #[test]
    fn a_level_surface_is_read_level_rather_than_tilted_one_stripe_over() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let pts = step_rows(&sensor, &model);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        assert_eq!(out.stats.coded, pts.len(), "{:?}", out.stats);
        let level_blind = CodingParams {
            tilt_cost_per_mm: 0.0,
            ..CodingParams::default()
        };
        let mut coder = StripeCoder::new(&model, 648, 480, level_blind).expect("coder");
        let (out, wrong) = code(&mut coder, &pts);
        let right = out.stats.coded - wrong;
        assert!(
            right < pts.len() / 2,
            "without the tilt cost the step and the plate are not read right: {right} of {}",
            pts.len()
        );
    }

    #[test]
    fn a_bright_top_does_not_continue_the_dim_belt_beside_it() {
        // A 30 mm block: its top's first stripe (7) lies on the column of the belt's next stripe (3) to within a
        // tenth of a pixel, and the block hides stripes 3-6. Read as belt stripe 3, the row costs what the truth
        // costs; the top is three times as bright as the belt. The belt's brightness condition is a tie-breaker
        // (below the margin): the rows' best reading of stripe 7 becomes the truth, which segments and tracks then
        // settle (on the simulated block, `crates/sim/tests/coding.rs`).
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut pts = Vec::new();
        for (z, stripes, intensity) in [(0.0, 0..=2, 50.0), (30.0, 7..=10, 140.0)] {
            for (p, k) in flat(&model, &sensor, z, 100..400) {
                if stripes.contains(&k) {
                    pts.push((StripePoint { intensity, ..p }, k));
                }
            }
        }
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        // Rows whose best reading of stripe 7 is stripe 7.
        let read_right = |params: CodingParams| {
            let mut coder = StripeCoder::new(&model, 648, 480, params).expect("coder");
            let (out, wrong) = code(&mut coder, &pts);
            assert_eq!(wrong, 0, "{:?}", out.stats);
            pts.iter()
                .zip(&out.near)
                .filter(|((_, k), near)| *k == 7 && near[0] == 7)
                .count()
        };
        assert_eq!(read_right(CodingParams::default()), 300);
        let blind = CodingParams {
            belt_intensity_ratio: 0.0,
            ..CodingParams::default()
        };
        assert!(read_right(blind) < 300);
    }

    #[test]
    fn cut_fragments_neither_shift_a_row_nor_go_unlabelled_on_a_stripe() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        // Without the marking it is the tilt cost of the row transitions that keeps the fragment from shifting the
        // rows (read one over, the plate comes out tilted); with neither, it shifts them.
        let neither = CodingParams {
            tilt_cost_per_mm: 0.0,
            ..CodingParams::default()
        };
        let mut coder = StripeCoder::new(&model, 648, 480, neither).expect("coder");
        let pts = far_edge(&sensor, &model, false);
        let (_, wrong_unmarked) = code(&mut coder, &pts);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let (_, wrong_unmarked_bright) = code(&mut coder, &pts);
        assert_eq!(wrong_unmarked_bright, 0);
        let pts = far_edge(&sensor, &model, true);
        let (out, wrong) = code(&mut coder, &pts);
        assert!(
            wrong_unmarked > 1000,
            "the fragment shifts the rows when not marked: {wrong_unmarked}"
        );
        assert_eq!(wrong, 0, "{:?}", out.stats);
        for ((p, k), l) in pts.iter().zip(&out.stripes) {
            if *k == NO_LABEL {
                assert_eq!(*l, None, "the corner fragment stays uncoded: {p:?}");
            }
            if *k == 5 && p.cut {
                assert_eq!(
                    *l,
                    Some(5),
                    "the hole-side points follow their stripe: {p:?}"
                );
            }
        }
    }

    #[test]
    fn faint_points_are_fragments_even_when_not_marked_cut() {
        // The corner fragment at a tenth of the stripes' peak and not marked cut (its cut too shallow to see): with
        // the faint rule it takes no part in reading the rows; without it, it shifts them.
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let pts: Vec<(StripePoint, u16)> = far_edge(&sensor, &model, false)
            .into_iter()
            .map(|(p, k)| {
                let intensity = if k == NO_LABEL { 10.0 } else { p.intensity };
                (StripePoint { intensity, ..p }, k)
            })
            .collect();
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        for ((p, k), l) in pts.iter().zip(&out.stripes) {
            if *k == NO_LABEL {
                assert_eq!(*l, None, "the faint fragment stays uncoded: {p:?}");
            }
        }
        // Without the faint rule (and without the row transitions' tilt cost, which would keep this fragment from
        // shifting the rows too).
        let off = CodingParams {
            faint_intensity: 0.0,
            tilt_cost_per_mm: 0.0,
            ..CodingParams::default()
        };
        let mut coder = StripeCoder::new(&model, 648, 480, off).expect("coder");
        let (_, wrong_off) = code(&mut coder, &pts);
        assert!(
            wrong_off > 1000,
            "the faint point shifts the rows without the rule: {wrong_off}"
        );
    }

    /// The transition cost as [`CodingParams`] defines it, in `f64` comparisons.
    #[allow(clippy::too_many_arguments)]
    fn defined_cost(
        p: &CodingParams,
        from: u16,
        to: u16,
        za: f32,
        zb: f32,
        leftward: bool,
        ia: f32,
        ib: f32,
    ) -> f32 {
        let n = u32::from(to) - u32::from(from) - 1;
        if n == 0 {
            let d = zb - za;
            if f64::from(d.abs()) > p.jump_mm {
                return p.jump_cost as f32;
            }
            // The tilt (and the belt's cost) in single precision, as the rows are read.
            let tilt = (p.tilt_cost_per_mm as f32 * d.abs()).min(p.jump_cost as f32);
            let belt = f64::from(za.abs()) < p.rise_mm && f64::from(zb.abs()) < p.rise_mm;
            let (dim, bright) = (f64::from(ia.min(ib)), f64::from(ia.max(ib)));
            return if belt && dim < p.belt_intensity_ratio * bright {
                (tilt + p.belt_unlike_cost as f32).min(p.jump_cost as f32)
            } else {
                tilt
            };
        }
        let rise = if leftward { zb - za } else { za - zb };
        if f64::from(rise) >= p.rise_mm {
            (p.rise_skip_cost + f64::from(n) * p.edge_skip_cost) as f32
        } else {
            n as f32 * p.skip_cost as f32
        }
    }

    #[test]
    fn tabulated_transition_costs_are_the_defined_ones_up_to_the_thresholds() {
        assert_eq!(next_f32(1.0, true), 1.0 + f32::EPSILON);
        assert_eq!(next_f32(1.0, false), 1.0 - f32::EPSILON / 2.0);
        assert_eq!(next_f32(-1.0, true), -1.0 + f32::EPSILON / 2.0);
        assert!(next_f32(0.0, false) < 0.0 && next_f32(0.0, true) > 0.0);
        assert_eq!(next_f32(f32::MAX, true), f32::INFINITY);
        let mut rng = crate::test_rng(0x7ab1e);
        // Thresholds that are not f32 numbers, so that rounding them the wrong way shows.
        for params in [
            CodingParams::default(),
            CodingParams {
                jump_mm: 0.3,
                rise_mm: 0.7,
                rise_skip_cost: 0.33,
                edge_skip_cost: 0.013,
                skip_cost: 1.1,
                tilt_cost_per_mm: 0.7,
                belt_intensity_ratio: 0.3,
                belt_unlike_cost: 0.2,
                ..CodingParams::default()
            },
        ] {
            let tr = Transitions::new(&params);
            for _ in 0..20_000 {
                let from = (rng() % 10) as u16;
                let to = from + 1 + (rng() % 4) as u16;
                // Heights anywhere, or on the belt (within a rise of it, and at that bound).
                let za = match rng() % 4 {
                    0 => (rng() % 200) as f32 * 0.01 - 1.0,
                    1 => next_f32(params.rise_mm as f32, rng() % 2 == 0),
                    _ => (rng() % 4000) as f32 * 0.01,
                };
                // Differences right at, just below and just above either threshold, and anywhere.
                let at = [params.jump_mm as f32, params.rise_mm as f32][(rng() % 2) as usize];
                let d = match rng() % 4 {
                    0 => at,
                    1 => next_f32(at, true),
                    2 => next_f32(at, false),
                    _ => (rng() % 400) as f32 * 0.01 - 2.0,
                };
                let d = if rng() % 2 == 0 { d } else { -d };
                // zb chosen so that zb - za is d wherever f32 allows it.
                let zb = za + d;
                let leftward = rng() % 3 != 0;
                let sign = if leftward { 1.0 } else { -1.0 };
                // Peaks: alike, at the ratio, just either side of it, or anything.
                let ia = (1 + rng() % 4000) as f32;
                let at = (f64::from(ia) * params.belt_intensity_ratio) as f32;
                let ib = match rng() % 4 {
                    0 => ia,
                    1 => at,
                    2 => next_f32(at, rng() % 2 == 0),
                    _ => (rng() % 4000) as f32,
                };
                let (ia, ib) = if rng() % 2 == 0 { (ia, ib) } else { (ib, ia) };
                assert_eq!(
                    tr.cost(from, to, za, zb, sign, ia, ib),
                    defined_cost(&params, from, to, za, zb, leftward, ia, ib),
                    "{from}->{to} za {za} zb {zb} leftward {leftward} peaks {ia} {ib} ({params:?})"
                );
            }
        }
    }

    #[test]
    fn quick_edge_costs_are_the_general_ones() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let e = &coder.edges;
        // The paper's set-up is ordered on every row, so the quick way is the one taken.
        assert!(e.ordered.iter().all(|&o| o));
        let mut rng = crate::test_rng(0xed9e);
        for row in (0..480).step_by(7) {
            let r = row as usize * coder.stripes;
            // Heights at and around every threshold of the row, and anywhere in the range.
            let mut zs: Vec<f32> = e.left_at[r..r + coder.stripes]
                .iter()
                .chain(&e.right_at[r..r + coder.stripes])
                .filter(|t| t.is_finite())
                .flat_map(|&t| [t, next_f32(t, true), next_f32(t, false)])
                .collect();
            zs.extend((0..40).map(|_| (rng() % 5000) as f32 * 0.01 - 5.0));
            zs.extend([0.5f32, next_f32(0.5f32, false), f32::NAN]);
            for &z in &zs {
                for label in 0..coder.stripes as u16 {
                    let general = (
                        coder.left_skip(row, label, z),
                        coder.right_skip(row, label, z),
                    );
                    let mut fresh = EdgeCursor::START;
                    let quick = e.costs(&coder.transitions, row, label, z, &mut fresh);
                    if z.is_nan() {
                        assert!(quick.is_none());
                        continue;
                    }
                    assert_eq!(quick, Some(general), "row {row} label {label} z {z}");
                }
            }
            // A cursor carried along growing heights, and back to a lower one, counts the same.
            zs.retain(|z| !z.is_nan());
            let mut cursor = EdgeCursor::START;
            for (i, &z) in zs.iter().enumerate() {
                let label = (i % coder.stripes) as u16;
                let general = (
                    coder.left_skip(row, label, z),
                    coder.right_skip(row, label, z),
                );
                let quick = e.costs(&coder.transitions, row, label, z, &mut cursor);
                assert_eq!(
                    quick,
                    Some(general),
                    "row {row} label {label} z {z} (carried)"
                );
            }
        }
    }

    #[test]
    fn the_pruned_row_passes_decide_what_the_full_passes_decide() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut pruned =
            StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let mut full = pruned.clone();
        full.window = f32::INFINITY;
        let mut narrow = pruned.clone();
        narrow.window = 0.05;
        let mut rng = crate::test_rng(0x9a55);
        let mut narrow_differs = false;
        for case in 0..12 {
            // Two surfaces (a step somewhere along the row), ghosts between stripes, points lost.
            let (z0, z1) = ((rng() % 300) as f64 * 0.1, (rng() % 300) as f64 * 0.1);
            let cut = 100.0 + (rng() % 400) as f64;
            let mut pts: Vec<StripePoint> = Vec::new();
            for row in (0..480).step_by(3) {
                for k in 0..sensor.laser.stripes {
                    let at = |z| model.column_at_height(k, f64::from(row), z);
                    let Some(u) = at(z0)
                        .filter(|&u| u < cut)
                        .or_else(|| at(z1).filter(|&u| u >= cut))
                    else {
                        continue;
                    };
                    if (0.0..647.0).contains(&u) && rng() % 10 != 0 {
                        pts.push(point(row, u));
                    }
                }
                for _ in 0..rng() % 3 {
                    pts.push(point(row, (rng() % 640) as f64 + 0.5));
                }
            }
            pts.sort_by(|a, b| a.row.cmp(&b.row).then(a.x.total_cmp(&b.x)));
            let (mut a, mut b, mut c) = (Coding::default(), Coding::default(), Coding::default());
            pruned.code_into(&pts, &mut a);
            full.code_into(&pts, &mut b);
            narrow.code_into(&pts, &mut c);
            assert_eq!(a, b, "case {case}: z {z0} / {z1} from column {cut}");
            narrow_differs |= c != b;
        }
        // The comparison can tell: a window narrower than the decisions need changes them.
        assert!(narrow_differs);
    }

    #[test]
    fn a_ghost_point_is_dropped_not_coded() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let mut pts = flat(&model, &sensor, 5.0, 0..480);
        // A short ghost segment between two stripes.
        let ghost: Vec<(StripePoint, u16)> = (200..203)
            .map(|r| {
                let a = pts
                    .iter()
                    .find(|p| p.0.row == r && p.1 == 4)
                    .expect("p")
                    .0
                    .x;
                let b = pts
                    .iter()
                    .find(|p| p.0.row == r && p.1 == 5)
                    .expect("p")
                    .0
                    .x;
                (point(r, 0.5 * (a + b)), NO_LABEL)
            })
            .collect();
        pts.extend(ghost);
        pts.sort_by(|a, b| a.0.row.cmp(&b.0.row).then(a.0.x.total_cmp(&b.0.x)));
        let (out, wrong) = code(&mut coder, &pts);
        assert_eq!(wrong, 0, "{:?}", out.stats);
        assert!(out.stats.noise + out.stats.ambiguous >= 3);
    }

    #[test]
    fn points_outside_the_image_and_bad_parameters_are_handled() {
        let sensor = Sensor::default();
        let model = FullModel::nominal(&sensor);
        let mut coder = StripeCoder::new(&model, 648, 480, CodingParams::default()).expect("coder");
        let (out, _) = code(
            &mut coder,
            &[(point(900, 10.0), 0), (point(3, f64::NAN), 0)],
        );
        assert_eq!(out.stats.coded, 0);
        assert_eq!(out.stripes, vec![None, None]);
        let d = CodingParams::default;
        for bad in [
            CodingParams {
                max_height_mm: -5.0,
                ..d()
            },
            CodingParams {
                margin: f64::NAN,
                ..d()
            },
            // A negative cost would let the row passes stop before the best labelling; a huge run would overflow
            // them.
            CodingParams {
                outlier_cost: -0.1,
                ..d()
            },
            CodingParams {
                max_outlier_run: usize::MAX,
                ..d()
            },
        ] {
            assert!(
                StripeCoder::new(&model, 648, 480, bad.clone()).is_err(),
                "{bad:?}"
            );
        }
        let ratio = CodingParams {
            link_intensity_ratio: 1.5,
            ..CodingParams::default()
        };
        let err = StripeCoder::new(&model, 648, 480, ratio)
            .expect_err("a ratio above 1")
            .to_string();
        assert!(err.contains("link_intensity_ratio"), "{err}");
    }
}
