//! The fuzzy rule bases stripe3d uses, shipped as FLL files (`crates/core/rules/`) that an engineer can read and
//! edit, compiled into the binary and loaded through `stripe3d-fuzzy`.
//!
//! - [`RuleBase::SinglePeak`]: the paper's single-peak detector (rules 1-4 of section 4).
//! - [`RuleBase::StripeCoding`]: the stripe-coding rules (stripe-code rules 1-5).
//! - [`RuleBase::Surface`]: surface characterization (dent, bump, hole: surface rules 1-3; plus scratch and edge chip).

use stripe3d_fuzzy::{Engine, FuzzyError, fll};

/// One of stripe3d's rule bases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RuleBase {
    /// Does a peak continue the current stripe segment; is a segment long enough to keep.
    SinglePeak,
    /// Which points and segments belong to the same stripe.
    StripeCoding,
    /// Dent, bump or hole.
    Surface,
}

impl RuleBase {
    /// Every rule base.
    pub const ALL: [RuleBase; 3] = [
        RuleBase::SinglePeak,
        RuleBase::StripeCoding,
        RuleBase::Surface,
    ];

    /// The shipped FLL text.
    pub fn fll(self) -> &'static str {
        match self {
            RuleBase::SinglePeak => include_str!("../rules/single_peak.fll"),
            RuleBase::StripeCoding => include_str!("../rules/stripe_coding.fll"),
            RuleBase::Surface => include_str!("../rules/surface.fll"),
        }
    }

    /// The file name under `crates/core/rules/`.
    pub fn file_name(self) -> &'static str {
        match self {
            RuleBase::SinglePeak => "single_peak.fll",
            RuleBase::StripeCoding => "stripe_coding.fll",
            RuleBase::Surface => "surface.fll",
        }
    }

    /// The shipped engine, loaded.
    pub fn engine(self) -> Result<Engine, FuzzyError> {
        fll::read(self.fll())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn eval(base: RuleBase, inputs: &[(&str, f64)], output: &str) -> f64 {
        let mut e = base.engine().expect("shipped rule base loads");
        for (name, v) in inputs {
            e.set_input_by_name(name, *v).expect("input exists");
        }
        e.process().expect("process");
        e.output_by_name(output).expect("output exists")
    }

    #[test]
    fn single_peak_rules_behave_as_the_paper_says() {
        let same = |i, c, g| {
            eval(
                RuleBase::SinglePeak,
                &[("intensity", i), ("intensity_change", c), ("gap", g)],
                "same_segment",
            )
        };
        assert!(
            same(0.6, 0.02, 0.5) > 0.6,
            "rules 1 and 2: bright, similar, adjacent"
        );
        assert!(
            same(0.6, 0.5, 0.5) < 0.5,
            "rule 3: bright but very different"
        );
        assert!(same(0.01, 0.02, 0.5) < 0.5, "very small intensity");
        assert!(same(0.6, 0.02, 8.0) < 0.5, "far from the segment");
        let keep = |n| {
            eval(
                RuleBase::SinglePeak,
                &[("segment_length", n)],
                "keep_segment",
            )
        };
        assert!(
            keep(2.0) < 0.4 && keep(50.0) > 0.6,
            "rule 4: very short segments are ignored"
        );
    }

    #[test]
    fn stripe_coding_rules_behave_as_the_paper_says() {
        let e = |inputs: &[(&str, f64)], out| eval(RuleBase::StripeCoding, inputs, out);
        assert!(e(&[("height", 10.0), ("height_change", 0.1)], "same_segment") > 0.6);
        assert!(e(&[("height", 10.0), ("height_change", 8.0)], "same_segment") < 0.4);
        assert!(e(&[("gap", 1.0), ("boundary_difference", 5.0)], "bridge_gap") > 0.6);
        assert!(e(&[("gap", 60.0), ("boundary_difference", 0.1)], "bridge_gap") > 0.6);
        assert!(e(&[("gap", 60.0), ("boundary_difference", 5.0)], "bridge_gap") < 0.4);
        assert!(e(&[("segment_length", 2.0)], "keep_segment") < 0.4);
    }

    #[test]
    fn surface_rules_behave_as_the_paper_says() {
        let e = |c, d, out| {
            eval(
                RuleBase::Surface,
                &[
                    ("curvature", c),
                    ("direction", d),
                    ("gap", 0.0),
                    ("height_similarity", 10.0),
                    ("elongation", 1.0),
                    ("edge_notch", 0.0),
                ],
                out,
            )
        };
        assert!(e(0.2, -1.0, "dent") > 0.6 && e(0.2, -1.0, "bump") < 0.4);
        assert!(e(0.2, 1.0, "bump") > 0.6 && e(0.2, 1.0, "dent") < 0.4);
        assert!(
            e(4.0, -1.0, "dent") < 0.4,
            "too much curvature is not a dent"
        );
        let hole = |g, s| {
            eval(
                RuleBase::Surface,
                &[
                    ("curvature", 0.0),
                    ("direction", 0.0),
                    ("gap", g),
                    ("height_similarity", s),
                    ("elongation", 1.0),
                    ("edge_notch", 0.0),
                ],
                "hole",
            )
        };
        assert!(hole(3.0, 0.05) > 0.6);
        assert!(
            hole(3.0, 5.0) < 0.4,
            "different heights: an edge, not a hole"
        );
        assert!(hole(60.0, 0.05) < 0.4, "too large a gap");
        assert!(hole(0.5, 0.05) < 0.4, "a few empty cells are not a hole");
        // Beyond the paper: scratches and edge chips.
        let e = |inputs: &[(&str, f64)], out| {
            let mut all = vec![
                ("curvature", 3.0),
                ("direction", -1.0),
                ("gap", 0.0),
                ("height_similarity", 50.0),
                ("elongation", 1.0),
                ("edge_notch", 0.0),
            ];
            for (k, v) in inputs {
                if let Some(x) = all.iter_mut().find(|x| x.0 == *k) {
                    x.1 = *v;
                }
            }
            eval(RuleBase::Surface, &all, out)
        };
        assert!(e(&[("elongation", 10.0)], "scratch") > 0.6);
        assert!(
            e(&[("elongation", 10.0), ("curvature", 0.2)], "dent") < 0.4,
            "long: a scratch, not a dent"
        );
        assert!(e(&[("elongation", 1.2)], "scratch") < 0.4);
        assert!(e(&[("edge_notch", 2.0), ("direction", 0.0)], "edge_chip") > 0.6);
        assert!(e(&[("edge_notch", 0.2), ("direction", 0.0)], "edge_chip") < 0.4);
    }
}
