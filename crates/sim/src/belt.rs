//! The simulator as a camera on a running belt: a stream of parts at a set gap, with the truth kept for scoring.
//!
//! Part `p` is scene `scenes[p % scenes.len()]` rendered at travel `t - T0 - p * pitch`, where the pitch is the
//! longest part's length plus the gap and `T0` puts part 0's leading edge just short of the view at travel 0; in
//! part coordinates (world x less the travel) its plate spans `x - T0 - p * pitch` for the scene's plate span `x`.
//! The simulator renders one scene at a time, so the gap must be at least the view's length along the travel
//! ([`BeltSource::new`] says so otherwise): one part is in view at a time.

use crate::SimError;
use crate::render::{RenderOptions, Simulator};
use crate::scene::{DefectTruth, Scene};
use stripe3d_core::line::{FrameSource, SourceFrame};
use stripe3d_core::{CoreError, Sensor};

/// Clearance between the view and part 0's leading edge at travel 0, mm.
pub const LEAD_IN_MM: f64 = 5.0;

/// One part on the simulated belt, as it truly is.
#[derive(Debug, Clone)]
pub struct BeltPart {
    /// Position in the stream, from 0.
    pub index: usize,
    /// The scene it was made from.
    pub scene: String,
    /// Extent of its plate along the travel, part coordinates, mm.
    pub x_mm: [f64; 2],
    /// Its seeded defects, in its scene's coordinates.
    pub defects: Vec<DefectTruth>,
}

/// The simulator as a [`FrameSource`] (see the module documentation).
pub struct BeltSource {
    sensor: Sensor,
    sims: Vec<Simulator>,
    parts: Vec<BeltPart>,
    spans: Vec<[f64; 2]>,
    lead_mm: f64,
    pitch_mm: f64,
    view_mm: [f64; 2],
    next: u64,
    frames: u64,
    name: String,
}

/// The world x the sheets of `sensor` cover on the belt and `top_mm` above it, mm.
pub fn view_of(sensor: &Sensor, top_mm: f64) -> [f64; 2] {
    let laser = &sensor.laser;
    let mut span = [f64::INFINITY, f64::NEG_INFINITY];
    for i in 0..laser.stripes {
        let x = laser.belt_x_mm(i);
        // At height z a sheet from a source at (xs, zs) meets x + (xs - x) z / zs.
        let top = x + (laser.source_x_mm - x) * top_mm / laser.source_z_mm;
        span = [span[0].min(x.min(top)), span[1].max(x.max(top))];
    }
    span
}

impl BeltSource {
    /// `parts` parts made from `scenes` in turn, `gap_mm` apart along the travel, rendered with `opts` (frame k
    /// with seed `opts.seed + k`); the stream ends once the last part has left the view.
    pub fn new(
        name: &str,
        sensor: &Sensor,
        scenes: &[Scene],
        parts: usize,
        gap_mm: f64,
        opts: RenderOptions,
    ) -> Result<Self, SimError> {
        let invalid = |field: &str, reason: String| SimError::InvalidScene {
            field: field.into(),
            reason,
        };
        if scenes.is_empty() || parts == 0 {
            return Err(invalid("parts", "a belt needs at least one part".into()));
        }
        let mut spans = Vec::new();
        let mut sims = Vec::new();
        let mut top: f64 = 0.0;
        for s in scenes {
            let plate = s
                .plate
                .as_ref()
                .ok_or_else(|| invalid("plate", format!("scene `{}` has no part", s.name)))?;
            spans.push([
                plate.center_x_mm - plate.length_mm / 2.0,
                plate.center_x_mm + plate.length_mm / 2.0,
            ]);
            top = top.max(plate.thickness_mm);
            sims.push(Simulator::new(sensor, s, opts.clone())?);
        }
        let view = view_of(sensor, top);
        let longest = spans.iter().map(|s| s[1] - s[0]).fold(0.0, f64::max);
        let view_len = view[1] - view[0];
        if !(gap_mm.is_finite() && gap_mm >= view_len) {
            return Err(invalid(
                "gap",
                format!(
                    "{gap_mm} mm: the simulator renders one part at a time, so parts must be at least the view's \
                     length along the travel apart ({view_len:.1} mm)"
                ),
            ));
        }
        let pitch = longest + gap_mm;
        let lead =
            spans.iter().map(|s| s[1]).fold(f64::NEG_INFINITY, f64::max) - view[0] + LEAD_IN_MM;
        let belt_parts: Vec<BeltPart> = (0..parts)
            .map(|p| {
                let k = p % scenes.len();
                let shift = lead + p as f64 * pitch;
                BeltPart {
                    index: p,
                    scene: scenes[k].name.clone(),
                    x_mm: [spans[k][0] - shift, spans[k][1] - shift],
                    defects: sims[k].defects().to_vec(),
                }
            })
            .collect();
        let step = sensor.conveyor.clone().unwrap_or_default().step_mm();
        // The last part's trailing edge past the view's far end, and a gap's worth more for the tracker.
        let last = &belt_parts[parts - 1];
        let end_travel = view[1] - last.x_mm[0] + gap_mm;
        let frames = (end_travel / step).ceil().max(1.0) as u64;
        Ok(Self {
            sensor: sensor.clone(),
            sims,
            parts: belt_parts,
            spans,
            lead_mm: lead,
            pitch_mm: pitch,
            view_mm: view,
            next: 0,
            frames,
            name: name.to_string(),
        })
    }

    /// The parts on the belt, as they truly are.
    pub fn parts(&self) -> &[BeltPart] {
        &self.parts
    }

    /// Frames in the stream.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The part nearest to the view at travel `t` and the travel its scene is rendered at.
    fn part_at(&self, t: f64) -> (usize, f64) {
        let centre = 0.5 * (self.view_mm[0] + self.view_mm[1]);
        let n = self.parts.len();
        let best = (0..n)
            .min_by(|&a, &b| {
                let d = |p: usize| {
                    let x = &self.parts[p].x_mm;
                    (0.5 * (x[0] + x[1]) + t - centre).abs()
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0);
        (best, t - self.lead_mm - best as f64 * self.pitch_mm)
    }
}

impl FrameSource for BeltSource {
    fn next_frame(&mut self) -> Result<Option<SourceFrame>, CoreError> {
        if self.next >= self.frames {
            return Ok(None);
        }
        let k = self.next;
        self.next += 1;
        let conveyor = self.sensor.conveyor.clone().unwrap_or_default();
        let t = conveyor.travel_mm(k as usize);
        let (p, local) = self.part_at(t);
        let scene = p % self.spans.len();
        let frame = self.sims[scene].render(k as usize, local);
        Ok(Some(SourceFrame {
            index: k,
            timestamp_s: k as f64 / conveyor.fps,
            encoder_mm: Some(t),
            image: frame.image,
        }))
    }

    fn live_rate_hz(&self) -> Option<f64> {
        None
    }

    fn describe(&self) -> String {
        format!(
            "{} ({} parts {:.0} mm apart, {} frames)",
            self.name,
            self.parts.len(),
            self.pitch_mm,
            self.frames
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_follow_each_other_at_the_pitch_and_a_short_gap_is_refused() {
        let sensor = Sensor::default();
        let scenes = [Scene::builtin("plate").expect("plate")];
        let view = view_of(&sensor, 10.0);
        let gap = view[1] - view[0] + 10.0;
        let src = BeltSource::new(
            "sim:plate",
            &sensor,
            &scenes,
            3,
            gap,
            RenderOptions::default(),
        )
        .expect("belt");
        let p = src.parts();
        assert_eq!(p.len(), 3);
        let pitch = (p[0].x_mm[1] - p[0].x_mm[0]) + gap;
        for w in p.windows(2) {
            assert!((w[0].x_mm[0] - w[1].x_mm[0] - pitch).abs() < 1e-9);
        }
        // At travel 0 part 0's leading edge is just short of the view; the stream ends after the last has left.
        assert!((p[0].x_mm[1] - (view[0] - LEAD_IN_MM)).abs() < 1e-9);
        let step = sensor.conveyor.clone().unwrap_or_default().step_mm();
        assert!(src.frames() as f64 * step > view[1] - p[2].x_mm[0]);
        // In view, the part nearest to the view is the one rendered.
        let t_mid = 0.5 * (view[0] + view[1]) - 0.5 * (p[1].x_mm[0] + p[1].x_mm[1]);
        assert_eq!(src.part_at(t_mid).0, 1);
        let short = BeltSource::new(
            "sim:plate",
            &sensor,
            &scenes,
            2,
            20.0,
            RenderOptions::default(),
        );
        assert!(matches!(short, Err(SimError::InvalidScene { .. })));
    }
}
