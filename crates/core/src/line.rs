//! On the line: frames from a source, and every part on a running belt found in the stream of profiles.
//!
//! A production belt never stops; parts pass the sensor one after another. [`FrameSource`] is what a camera, a
//! recording or the simulator offers: frames in order, each with its timestamp and, where there is one, the
//! encoder's conveyor position. The chain codes and triangulates each frame as it arrives ([`crate::scan::Scanner`]);
//! [`PartTracker`] finds the parts in the profiles.
//!
//! **Parts in belt coordinates.** A profile's points are in part coordinates (belt coordinates: world x less the
//! travel since frame 0), so a point of a part keeps its x however far the belt has run. The tracker counts, in bins
//! of [`PartParams::bin_mm`] along x, the points higher than [`PartParams::min_height_mm`] above the belt; a bin
//! holding at least [`PartParams::min_points`] of them is part of a part, and bins closer than
//! [`PartParams::gap_mm`] belong to the same one. The belt moves +x: a part's leading edge (its largest x) meets
//! the sheets first, its trailing edge (its smallest x) leaves them last. A frame at travel `t` sees part x from
//! `view.0 - t` to `view.1 - t`, where `view` is the sheets' extent in world x over the measuring range
//! ([`view_span_mm`]); a part is *complete* once its trailing edge, less the gap, is below `view.1 - t`: every
//! sheet has swept all of it and nothing joins it any more. Parts closer than the gap are one part (reported so, by
//! their length); a part still in view when the stream ends is handed on as incomplete; an empty belt gives none.

use crate::accumulate::{Profile, RangeImage};
use crate::calibrate::Calibration;
use crate::error::CoreError;
use crate::image::Image;
use std::collections::BTreeMap;

/// One frame from a [`FrameSource`].
#[derive(Debug, Clone)]
pub struct SourceFrame {
    /// Index in the stream, from 0.
    pub index: u64,
    /// When it was taken, seconds since the stream began.
    pub timestamp_s: f64,
    /// Conveyor position from the encoder, mm (`None`: the source has no encoder; the nominal speed applies).
    pub encoder_mm: Option<f64>,
    /// The pixels (8-bit frames are held as 16-bit values unchanged).
    pub image: Image<u16>,
}

/// A stream of frames: a camera, a recording, the simulator.
pub trait FrameSource: Send {
    /// The next frame, `Ok(None)` at the end of the stream.
    fn next_frame(&mut self) -> Result<Option<SourceFrame>, CoreError>;
    /// The rate at which the source delivers frames whether or not they are taken, frames/s (a camera); `None`
    /// when it waits for the chain (a recording read as fast as possible, the simulator).
    fn live_rate_hz(&self) -> Option<f64>;
    /// What the source is, for messages.
    fn describe(&self) -> String;
}

/// Parameters of [`PartTracker`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PartParams {
    /// Least height above the belt of a point that belongs to a part, mm: well above the belt's noise and its
    /// flatness, below any part's thickness.
    pub min_height_mm: f64,
    /// Bin size along the travel, mm.
    pub bin_mm: f64,
    /// Fewest such points in a bin for the bin to be part of a part (a stray wrong reading is not a part).
    pub min_points: u32,
    /// Shortest gap between two parts along the travel, mm: closer bins are one part.
    pub gap_mm: f64,
    /// Shortest part along the travel, mm: shorter runs are debris, counted and not inspected.
    pub min_length_mm: f64,
}

impl Default for PartParams {
    fn default() -> Self {
        Self {
            min_height_mm: 1.0,
            bin_mm: 0.5,
            min_points: 10,
            gap_mm: 3.0,
            min_length_mm: 5.0,
        }
    }
}

/// A part found in the stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoundPart {
    /// Its extent along the travel in part coordinates, mm.
    pub x_mm: [f64; 2],
    /// First and last frame index that saw it.
    pub frames: [u64; 2],
    /// Every sheet swept all of it (false: the stream ended while it was in view).
    pub complete: bool,
}

impl FoundPart {
    /// Length along the travel, mm.
    pub fn length_mm(&self) -> f64 {
        self.x_mm[1] - self.x_mm[0]
    }
}

#[derive(Debug, Clone, Copy)]
struct Bin {
    count: u32,
    first: u64,
    last: u64,
}

/// Finds parts in a stream of profiles (see the module documentation).
#[derive(Debug, Clone)]
pub struct PartTracker {
    params: PartParams,
    view_mm: [f64; 2],
    bins: BTreeMap<i64, Bin>,
    /// Runs shorter than [`PartParams::min_length_mm`] dropped so far.
    pub debris: usize,
}

/// The extent in world x of the calibrated sheets between the heights `z_mm` at y = 0, mm: what one frame sees of
/// the belt along the travel.
pub fn view_span_mm(cal: &Calibration, z_mm: [f64; 2]) -> [f64; 2] {
    let mut span = [f64::INFINITY, f64::NEG_INFINITY];
    for p in &cal.full.planes {
        let (n, d) = (p.normal, p.offset);
        if n.x.abs() < 1e-12 {
            continue;
        }
        for z in z_mm {
            let x = (d - n.z * z) / n.x;
            span = [span[0].min(x), span[1].max(x)];
        }
    }
    span
}

impl PartTracker {
    /// A tracker for frames that see part x from `view_mm[0] - t` to `view_mm[1] - t` at travel `t`.
    pub fn new(params: PartParams, view_mm: [f64; 2]) -> Self {
        Self {
            params,
            view_mm,
            bins: BTreeMap::new(),
            debris: 0,
        }
    }

    fn bin_of(&self, x: f64) -> i64 {
        (x / self.params.bin_mm).floor() as i64
    }

    /// Adds frame `index`'s profile, taken at travel `travel_mm`; returns the parts it completed, in belt order.
    pub fn add(&mut self, index: u64, travel_mm: f64, profile: &Profile) -> Vec<FoundPart> {
        for p in &profile.points {
            if p.z_mm >= self.params.min_height_mm && p.x_mm.is_finite() {
                let b = self.bin_of(p.x_mm);
                let bin = self.bins.entry(b).or_insert(Bin {
                    count: 0,
                    first: index,
                    last: index,
                });
                bin.count += 1;
                bin.first = bin.first.min(index);
                bin.last = bin.last.max(index);
            }
        }
        // Every x above this has left the view (every sheet swept it).
        let swept_above = self.view_mm[1] - travel_mm;
        let mut done = Vec::new();
        for run in self.runs() {
            if run.part.x_mm[0] - self.params.gap_mm > swept_above {
                done.push(run);
            }
        }
        // Bins too sparse for a part that have left the view are stray readings.
        let gap = self.params.gap_mm;
        let min_points = self.params.min_points;
        let bin_mm = self.params.bin_mm;
        self.bins
            .retain(|&b, bin| bin.count >= min_points || (b as f64) * bin_mm - gap <= swept_above);
        self.take(done)
    }

    /// The parts still open when the stream ends, handed on as incomplete.
    pub fn finish(&mut self) -> Vec<FoundPart> {
        let runs = self.runs();
        let mut parts = self.take(runs);
        for p in &mut parts {
            p.complete = false;
        }
        parts
    }

    /// Oldest frame any open part was seen in (`None`: nothing open, no frame is needed any more).
    pub fn oldest_open_frame(&self) -> Option<u64> {
        self.bins
            .values()
            .filter(|b| b.count >= self.params.min_points)
            .map(|b| b.first)
            .min()
    }

    /// Removes the runs' bins and returns the runs long enough to be parts (largest x first: the order they met
    /// the sheets), counting the others as debris.
    fn take(&mut self, runs: Vec<Run>) -> Vec<FoundPart> {
        let mut parts = Vec::new();
        for run in runs.into_iter().rev() {
            let keys: Vec<i64> = self
                .bins
                .range(run.bins[0]..=run.bins[1])
                .map(|(&k, _)| k)
                .collect();
            for k in keys {
                self.bins.remove(&k);
            }
            if run.part.length_mm() >= self.params.min_length_mm {
                parts.push(run.part);
            } else {
                self.debris += 1;
            }
        }
        parts
    }

    /// The occupied runs of bins, smallest x first.
    fn runs(&self) -> Vec<Run> {
        let p = &self.params;
        let gap_bins = (p.gap_mm / p.bin_mm).ceil() as i64;
        let mut runs: Vec<Run> = Vec::new();
        for (&b, bin) in self
            .bins
            .iter()
            .filter(|(_, bin)| bin.count >= p.min_points)
        {
            let x = [b as f64 * p.bin_mm, (b + 1) as f64 * p.bin_mm];
            match runs.last_mut() {
                Some(r) if b - r.bins[1] <= gap_bins => {
                    r.bins[1] = b;
                    r.part.x_mm[1] = x[1];
                    r.part.frames = [
                        r.part.frames[0].min(bin.first),
                        r.part.frames[1].max(bin.last),
                    ];
                }
                _ => runs.push(Run {
                    bins: [b, b],
                    part: FoundPart {
                        x_mm: x,
                        frames: [bin.first, bin.last],
                        complete: true,
                    },
                }),
            }
        }
        runs
    }
}

#[derive(Debug, Clone, Copy)]
struct Run {
    bins: [i64; 2],
    part: FoundPart,
}

/// The columns of `range` whose x lies within `x_mm` (widened by one cell), as a range image of its own; `None` when
/// none does.
pub fn crop_x(range: &RangeImage, x_mm: [f64; 2]) -> Option<RangeImage> {
    let sx = range.spacing_mm[0];
    let col = |x: f64| ((x - range.origin_mm[0]) / sx).round();
    let c0 = (col(x_mm[0]) - 1.0).max(0.0) as usize;
    let c1 = ((col(x_mm[1]) + 1.0).max(0.0) as usize).min(range.width.checked_sub(1)?);
    if c0 > c1 || range.width == 0 {
        return None;
    }
    let w = c1 - c0 + 1;
    let pick = |v: &[f32]| -> Vec<f32> {
        (0..range.height)
            .flat_map(|r| {
                v[r * range.width + c0..r * range.width + c0 + w]
                    .iter()
                    .copied()
            })
            .collect()
    };
    Some(RangeImage {
        origin_mm: [range.origin_mm[0] + c0 as f64 * sx, range.origin_mm[1]],
        spacing_mm: range.spacing_mm,
        width: w,
        height: range.height,
        z: pick(&range.z),
        intensity: range.intensity.as_deref().map(pick),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accumulate::ProfilePoint;

    /// A profile of frame `k` at travel `t` of a belt carrying parts 10 mm high over the part-x ranges `parts`,
    /// seen through a window of world x 0-100 mm: one point every 0.25 mm of the window.
    fn profile(k: usize, t: f64, parts: &[[f64; 2]]) -> Profile {
        let mut points = Vec::new();
        for i in 0..400 {
            let x_world = 0.25 * i as f64;
            let x = x_world - t;
            let z = if parts.iter().any(|p| x >= p[0] && x < p[1]) {
                10.0
            } else {
                0.0
            };
            for row in 0..4 {
                points.push(ProfilePoint {
                    stripe: 0,
                    row,
                    u: 0.0,
                    x_mm: x,
                    y_mm: f64::from(row),
                    z_mm: z,
                    intensity: 100.0,
                    spacetime: false,
                });
            }
        }
        Profile {
            frame: k,
            travel_mm: t,
            points,
        }
    }

    #[test]
    fn parts_are_handed_on_once_every_sheet_has_swept_them_and_the_last_one_at_the_end() {
        // Parts at part x -60..-20, -100..-70 (10 mm apart) and -130..-128 (debris, 2 mm): they meet the window
        // (world x 0-100) as the belt runs 2 mm a frame.
        let parts = [[-60.0, -20.0], [-100.0, -70.0], [-130.0, -128.0]];
        let mut tracker = PartTracker::new(PartParams::default(), [0.0, 100.0]);
        let mut found = Vec::new();
        for k in 0..110 {
            let t = 2.0 * k as f64;
            for p in tracker.add(k as u64, t, &profile(k, t, &parts)) {
                found.push((k, p));
            }
        }
        assert_eq!(found.len(), 2, "{found:?}");
        let (k0, p0) = found[0];
        assert!(
            (p0.x_mm[0] + 60.0).abs() <= 0.5 && (p0.x_mm[1] + 20.0).abs() <= 0.5,
            "{p0:?}"
        );
        // Complete when its trailing edge less the gap has left the window: 100 - t < -63, t > 163.
        assert_eq!(k0, 82);
        assert!(p0.complete);
        // Frames 11..=79 saw it: its points' world x x + t within the window's samples, 0 to 99.75 mm.
        assert_eq!(p0.frames, [11, 79]);
        let (_, p1) = found[1];
        assert!(
            (p1.x_mm[0] + 100.0).abs() <= 0.5 && (p1.x_mm[1] + 70.0).abs() <= 0.5,
            "{p1:?}"
        );
        // The debris is in view at the end: finishing drops it as debris, nothing else is open.
        assert!(tracker.finish().is_empty());
        assert_eq!(tracker.debris, 1);
    }

    #[test]
    fn parts_closer_than_the_gap_are_one_and_a_part_in_view_at_the_end_is_incomplete() {
        let parts = [[-60.0, -40.0], [-41.0, -20.0]];
        let mut tracker = PartTracker::new(PartParams::default(), [0.0, 100.0]);
        let mut found = Vec::new();
        for k in 0..60 {
            let t = 2.0 * k as f64;
            found.extend(tracker.add(k as u64, t, &profile(k, t, &parts)));
        }
        assert!(found.is_empty());
        assert!(tracker.oldest_open_frame().is_some());
        let open = tracker.finish();
        assert_eq!(open.len(), 1);
        assert!(!open[0].complete);
        assert!((open[0].length_mm() - 40.0).abs() <= 1.0, "{open:?}");
        assert_eq!(tracker.oldest_open_frame(), None);
    }

    #[test]
    fn an_empty_belt_gives_no_part() {
        let mut tracker = PartTracker::new(PartParams::default(), [0.0, 100.0]);
        for k in 0..50 {
            let t = 2.0 * k as f64;
            assert!(tracker.add(k as u64, t, &profile(k, t, &[])).is_empty());
        }
        assert!(tracker.finish().is_empty());
        assert_eq!(tracker.debris, 0);
    }

    #[test]
    fn a_crop_keeps_the_columns_of_its_x_range() {
        let range = RangeImage {
            origin_mm: [-10.0, 0.0],
            spacing_mm: [1.0, 1.0],
            width: 20,
            height: 2,
            z: (0..40).map(|v| v as f32).collect(),
            intensity: None,
        };
        let c = crop_x(&range, [0.0, 4.0]).expect("inside");
        assert_eq!((c.width, c.origin_mm[0]), (7, -1.0));
        assert_eq!(c.z[..7], [9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0]);
        assert_eq!(c.z[7], 29.0);
        assert!(crop_x(&range, [100.0, 120.0]).is_none());
    }
}
