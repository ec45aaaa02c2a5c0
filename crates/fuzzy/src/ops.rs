//! Norms, hedges and the tolerant comparisons fuzzylite uses.
//!
//! Comparisons treat numbers closer than [`MACHEPS`] as equal, as fuzzylite's `Op::isEq` family does; minimum and
//! maximum follow `a < b ? a : b`, so NaN propagates the way the reference implementation's does.

/// Tolerance of the comparisons (fuzzylite's default `macheps`).
pub const MACHEPS: f64 = 1e-6;

/// `a == b` within [`MACHEPS`] (NaN equals NaN).
#[inline]
pub fn is_eq(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() < MACHEPS || (a.is_nan() && b.is_nan())
}
/// `a < b` and not [`is_eq`].
#[inline]
pub fn is_lt(a: f64, b: f64) -> bool {
    !is_eq(a, b) && a < b
}
/// `a <= b` or [`is_eq`].
#[inline]
pub fn is_le(a: f64, b: f64) -> bool {
    is_eq(a, b) || a < b
}
/// `a > b` and not [`is_eq`].
#[inline]
pub fn is_gt(a: f64, b: f64) -> bool {
    !is_eq(a, b) && a > b
}
/// `a >= b` or [`is_eq`].
#[inline]
pub fn is_ge(a: f64, b: f64) -> bool {
    is_eq(a, b) || a > b
}
/// `a < b ? a : b`.
#[inline]
pub fn min(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}
/// `a > b ? a : b`.
#[inline]
pub fn max(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}
/// Clamps `x` to `[lo, hi]`, letting NaN through.
#[inline]
pub fn bound(x: f64, lo: f64, hi: f64) -> f64 {
    if x > hi {
        hi
    } else if x < lo {
        lo
    } else {
        x
    }
}

macro_rules! named_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $variant:ident),* $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum $name { $($(#[$vm])* $variant),* }
        impl $name {
            /// Every variant.
            pub const ALL: &'static [$name] = &[$($name::$variant),*];
            /// The class name used in FLL.
            pub fn name(self) -> &'static str {
                match self { $($name::$variant => stringify!($variant)),* }
            }
            /// The variant with FLL class name `s`.
            pub fn from_name(s: &str) -> Option<Self> {
                Self::ALL.iter().copied().find(|v| v.name() == s)
            }
        }
    };
}

named_enum!(
    /// Triangular norms: conjunction and implication operators.
    TNorm {
        /// min(a, b)
        Minimum,
        /// a b
        AlgebraicProduct,
        /// max(0, a + b − 1)
        BoundedDifference,
        /// min(a, b) when max(a, b) = 1, else 0
        DrasticProduct,
        /// a b / (2 − (a + b − a b))
        EinsteinProduct,
        /// a b / (a + b − a b)
        HamacherProduct,
        /// min(a, b) when a + b > 1, else 0
        NilpotentMinimum,
    }
);

named_enum!(
    /// Triangular conorms: disjunction and aggregation operators.
    SNorm {
        /// max(a, b)
        Maximum,
        /// a + b − a b
        AlgebraicSum,
        /// min(1, a + b)
        BoundedSum,
        /// max(a, b) when min(a, b) = 0, else 1
        DrasticSum,
        /// (a + b) / (1 + a b)
        EinsteinSum,
        /// (a + b − 2 a b) / (1 − a b)
        HamacherSum,
        /// max(a, b) when a + b < 1, else 1
        NilpotentMaximum,
        /// (a + b) / max(1, a + b)
        NormalizedSum,
        /// a + b
        UnboundedSum,
    }
);

impl TNorm {
    /// Applies the norm.
    #[inline]
    pub fn compute(self, a: f64, b: f64) -> f64 {
        match self {
            TNorm::Minimum => min(a, b),
            TNorm::AlgebraicProduct => a * b,
            TNorm::BoundedDifference => max(0.0, a + b - 1.0),
            TNorm::DrasticProduct => {
                if is_eq(max(a, b), 1.0) {
                    min(a, b)
                } else {
                    0.0
                }
            }
            TNorm::EinsteinProduct => (a * b) / (2.0 - (a + b - a * b)),
            TNorm::HamacherProduct => {
                if is_eq(a + b, 0.0) {
                    0.0
                } else {
                    (a * b) / (a + b - a * b)
                }
            }
            TNorm::NilpotentMinimum => {
                if is_gt(a + b, 1.0) {
                    min(a, b)
                } else {
                    0.0
                }
            }
        }
    }
}

impl SNorm {
    /// Applies the conorm.
    #[inline]
    pub fn compute(self, a: f64, b: f64) -> f64 {
        match self {
            SNorm::Maximum => max(a, b),
            SNorm::AlgebraicSum => a + b - a * b,
            SNorm::BoundedSum => min(1.0, a + b),
            SNorm::DrasticSum => {
                if is_eq(min(a, b), 0.0) {
                    max(a, b)
                } else {
                    1.0
                }
            }
            SNorm::EinsteinSum => (a + b) / (1.0 + a * b),
            SNorm::HamacherSum => {
                if is_eq(a * b, 1.0) {
                    1.0
                } else {
                    (a + b - 2.0 * a * b) / (1.0 - a * b)
                }
            }
            SNorm::NilpotentMaximum => {
                if is_lt(a + b, 1.0) {
                    max(a, b)
                } else {
                    1.0
                }
            }
            SNorm::NormalizedSum => (a + b) / max(1.0, a + b),
            SNorm::UnboundedSum => a + b,
        }
    }
}

named_enum!(
    /// Linguistic hedges.
    Hedge {
        /// 1 − x
        Not,
        /// x²
        Very,
        /// √x
        Somewhat,
        /// √(x/2) up to 0.5, then 1 − √((1 − x)/2)
        Seldom,
        /// 2x² up to 0.5, then 1 − 2(1 − x)²
        Extremely,
        /// always 1 (the proposition holds whatever the value)
        Any,
    }
);

impl Hedge {
    /// The keyword in rules.
    pub fn keyword(self) -> &'static str {
        match self {
            Hedge::Not => "not",
            Hedge::Very => "very",
            Hedge::Somewhat => "somewhat",
            Hedge::Seldom => "seldom",
            Hedge::Extremely => "extremely",
            Hedge::Any => "any",
        }
    }

    /// The hedge with rule keyword `s`.
    pub fn from_keyword(s: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|h| h.keyword() == s)
    }

    /// Applies the hedge.
    #[inline]
    pub fn apply(self, x: f64) -> f64 {
        match self {
            Hedge::Not => 1.0 - x,
            Hedge::Very => x * x,
            Hedge::Somewhat => x.sqrt(),
            Hedge::Seldom => {
                if is_le(x, 0.5) {
                    (0.5 * x).sqrt()
                } else {
                    1.0 - (0.5 * (1.0 - x)).sqrt()
                }
            }
            Hedge::Extremely => {
                if is_le(x, 0.5) {
                    2.0 * x * x
                } else {
                    1.0 - 2.0 * (1.0 - x) * (1.0 - x)
                }
            }
            Hedge::Any => 1.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn norms_are_bounded_by_min_and_max_at_the_corners() {
        for t in TNorm::ALL {
            assert!(is_eq(t.compute(1.0, 0.3), 0.3), "{t:?}");
            assert!(is_eq(t.compute(0.0, 0.7), 0.0), "{t:?}");
            assert_eq!(TNorm::from_name(t.name()), Some(*t));
        }
        for s in SNorm::ALL {
            assert!(is_eq(s.compute(0.0, 0.3), 0.3), "{s:?}");
            assert_eq!(SNorm::from_name(s.name()), Some(*s));
        }
        assert!(is_eq(SNorm::AlgebraicSum.compute(0.5, 0.5), 0.75));
        assert!(is_eq(TNorm::EinsteinProduct.compute(0.5, 0.5), 0.2));
        assert!(is_eq(SNorm::NormalizedSum.compute(0.8, 0.6), 1.0));
    }

    #[test]
    fn hedges_match_their_definitions() {
        assert!(is_eq(Hedge::Very.apply(0.5), 0.25));
        assert!(is_eq(Hedge::Extremely.apply(0.25), 0.125));
        assert!(is_eq(Hedge::Extremely.apply(0.75), 0.875));
        assert!(is_eq(Hedge::Seldom.apply(0.5), 0.5));
        assert_eq!(Hedge::from_keyword("somewhat"), Some(Hedge::Somewhat));
        assert!(
            min(f64::NAN, 1.0) == 1.0 && min(1.0, f64::NAN).is_nan(),
            "fuzzylite's NaN order"
        );
    }
}
