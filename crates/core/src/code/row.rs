//! The row labelling's pieces: each stripe's band of columns per row, the costs of the stripes a row may declare
//! missing at its ends, the transition costs between neighbouring points, and the items and states of the passes
//! ([`super::StripeCoder`] runs them).

use super::*;

/// Per row and stripe: the band of columns the stripe can occupy and its heights at the image's side edges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Band {
    /// Smallest and largest column over the measuring range.
    pub(super) u_min: f32,
    pub(super) u_max: f32,
    /// Height the stripe shows at the first and the last column (NaN where the ray misses the plane).
    pub(super) z_left: f32,
    pub(super) z_right: f32,
    /// True when the stripe moves towards smaller columns as the height grows (the projector is on the −x side).
    pub(super) leftward: bool,
}

/// The cost of the stripes missing beyond a row's first or last labelled point, the quick way where the row
/// allows it. Where every stripe of a row moves towards smaller columns as the height grows and the heights the
/// stripes show at the image's side edges grow with the stripe index (the paper's set-up), a stripe out of view
/// at a height is so for every stripe before it (left edge) or after it (right edge): the missing stripes' cost
/// is then one count over the row's thresholds and one look-up of the same `f32` sum the general path adds up.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct EdgeSkips {
    pub(super) stripes: usize,
    /// Per row: whether the quick way holds.
    pub(super) ordered: Vec<bool>,
    /// Per row and stripe: the height at or above which the stripe is out of view left of column 0
    /// (`z_left − rise_mm`), and the one above which it is still in view right of the last column
    /// (`z_right + rise_mm`).
    pub(super) left_at: Vec<f32>,
    pub(super) right_at: Vec<f32>,
    /// `left_sum[gone * (stripes + 1) + label]`: the sum over stripes `0 .. label` of the edge cost for the first
    /// `gone` and the full cost for the rest; `right_sum[kept * (stripes + 1) + n]`: over `n` stripes, the full
    /// cost for the first `kept` and the edge cost for the rest.
    pub(super) left_sum: Vec<f32>,
    pub(super) right_sum: Vec<f32>,
}

impl EdgeSkips {
    pub(super) fn new(bands: &[Band], stripes: usize, params: &CodingParams) -> Self {
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
    pub(super) fn costs(
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
pub(super) struct EdgeCursor {
    pub(super) z: f32,
    pub(super) left: usize,
    pub(super) right: usize,
}

impl EdgeCursor {
    pub(super) const START: Self = Self {
        z: f32::NEG_INFINITY,
        left: 0,
        right: 0,
    };
}

/// One candidate (point, label) of a row.
#[derive(Debug, Clone, Copy)]
pub(super) struct Item {
    /// Point's position in the row (0-based, in column order).
    pub(super) j: u16,
    pub(super) label: u16,
    pub(super) z: f32,
    /// +1 when the label's stripe moves towards smaller columns as the height grows on this row, −1 otherwise.
    pub(super) sign: f32,
    /// The point's peak intensity.
    pub(super) level: f32,
    pub(super) forward: f32,
    pub(super) backward: f32,
    /// Cost of the stripes missing before this item when it is the row's first labelled point.
    pub(super) start: f32,
    /// Cost of the stripes missing after it when it is the last.
    pub(super) end: f32,
}

/// An item with a finite backward cost, as the backward pass reads it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Back {
    pub(super) label: u16,
    pub(super) z: f32,
    pub(super) sign: f32,
    pub(super) level: f32,
    pub(super) backward: f32,
}

/// Per-point working state of one frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct PointState {
    /// Best label of the row labelling (even when not confident); `u16::MAX` for a declared-false point.
    pub(super) best: u16,
    pub(super) confident: bool,
    /// The runner-up labels and how much more their best row labelling costs than the best label's.
    pub(super) alternatives: [(u16, f32); 2],
    pub(super) z: f32,
    pub(super) segment: u32,
}

#[derive(Debug, Clone, Default)]
pub(super) struct SegmentState {
    pub(super) last_row: u32,
    pub(super) last_u: f64,
    /// Peak intensity of the segment's last point.
    pub(super) last_intensity: f32,
    pub(super) last_label: u16,
    pub(super) last_z: f32,
    pub(super) length: u32,
    /// Confident votes: up to four distinct labels with counts, plus the total.
    pub(super) votes: [(u16, u32); 4],
    pub(super) total_votes: u32,
    pub(super) taken_row: u32,
}

/// One step of the row passes: `best` becomes `base + transition()` where that is smaller. The transition is not
/// computed when `base` alone already reaches `best` (transition costs are never negative, and adding one to `base`
/// cannot round below it).
#[inline(always)]
pub(super) fn relax(best: &mut f32, base: f32, transition: impl FnOnce() -> f32) {
    if base < *best {
        let c = base + transition();
        if c < *best {
            *best = c;
        }
    }
}

/// The neighbouring `f32` above (`up`) or below `t` (`f32::next_up` and `next_down` are newer than this crate's
/// minimum Rust).
pub(super) fn next_f32(t: f32, up: bool) -> f32 {
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
pub(super) struct Transitions {
    /// Largest `f32` at most [`CodingParams::jump_mm`]: for an `f32` difference `d`, `d > jump_at` exactly when
    /// `f64::from(d) > jump_mm`.
    pub(super) jump_at: f32,
    /// Smallest `f32` at least [`CodingParams::rise_mm`]: `r >= rise_at` exactly when `f64::from(r) >= rise_mm`.
    pub(super) rise_at: f32,
    pub(super) jump_cost: f32,
    /// [`CodingParams::tilt_cost_per_mm`], [`CodingParams::belt_intensity_ratio`] (compared in `f64`: the
    /// comparison is the parameter's) and [`CodingParams::belt_unlike_cost`].
    pub(super) tilt: f32,
    pub(super) belt_ratio: f64,
    pub(super) belt_unlike_cost: f32,
    /// One sheet seen twice in a row ([`CodingParams::outlier_cost`]).
    pub(super) split_cost: f32,
    /// Per number of stripes missing between the two points: the cost without a rise, and with one.
    pub(super) skip: [f32; MAX_STRIPES],
    pub(super) rise_skip: [f32; MAX_STRIPES],
}

impl Transitions {
    pub(super) fn new(params: &CodingParams) -> Self {
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
    pub(super) fn cost(
        &self,
        from: u16,
        to: u16,
        za: f32,
        zb: f32,
        rise_sign: f32,
        ia: f32,
        ib: f32,
    ) -> f32 {
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
