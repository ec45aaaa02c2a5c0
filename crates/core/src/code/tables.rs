//! The paper's stripe-coding rule base (`rules/stripe_coding.fll`) evaluated once into tables over its inputs.

use super::*;
use crate::rules::RuleBase;
use stripe3d_fuzzy::Engine;

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
