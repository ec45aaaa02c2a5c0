//! Encoder files: the conveyor position of each frame, one number in mm per line (`#` comments and blank lines
//! allowed), never decreasing. `stripe3d scan --encoder` and `stripe3d simulate --encoder` read them.

use crate::error::IoError;
use crate::files::read_text;
use std::path::Path;

/// Most positions an encoder file may hold (the most frames one scan or simulation takes).
pub const MAX_POSITIONS: usize = 100_000;

/// Reads an encoder file of at most `max_positions` positions; returns the travel since the first position, mm.
pub fn read_encoder(path: &Path, max_positions: usize) -> Result<Vec<f64>, IoError> {
    let text = read_text(path)?;
    let err = |line: Option<usize>, message: String| IoError::Encoder {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut out: Vec<f64> = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let t = line.split('#').next().unwrap_or("").trim();
        if t.is_empty() {
            continue;
        }
        let v: f64 = t
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| {
                err(
                    Some(n + 1),
                    format!("{t:?} is not a position in mm (one finite number per line)"),
                )
            })?;
        if let Some(&last) = out.last()
            && v < last
        {
            return Err(err(
                Some(n + 1),
                format!(
                    "position {v} mm is behind the previous {last} mm; encoder positions must not decrease"
                ),
            ));
        }
        out.push(v);
    }
    if out.is_empty() {
        return Err(err(
            None,
            "no positions; write one position in mm per frame, one per line".to_string(),
        ));
    }
    if out.len() > max_positions {
        return Err(err(
            None,
            format!(
                "{} positions is more than the {max_positions} frames one run takes",
                out.len()
            ),
        ));
    }
    let first = out[0];
    Ok(out.into_iter().map(|v| v - first).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]

        /// Any text: positions that are finite, non-decreasing and within the limit, or an error that names the
        /// file.
        #[test]
        fn encoder_files_are_read_or_refused_by_name(
            text in "([-+0-9.eE#a-z ]{0,12}\\n){0,20}|\\PC{0,100}",
        ) {
            let dir = tempfile::tempdir().expect("tmp");
            let p = dir.path().join("enc.txt");
            std::fs::write(&p, &text).expect("write");
            match read_encoder(&p, 15) {
                Ok(v) => {
                    proptest::prop_assert!(!v.is_empty() && v.len() <= 15);
                    proptest::prop_assert!(v.iter().all(|x| x.is_finite()));
                    proptest::prop_assert!(v.windows(2).all(|w| w[0] <= w[1]));
                    proptest::prop_assert_eq!(v[0], 0.0);
                }
                Err(e) => proptest::prop_assert!(e.to_string().contains("enc.txt"), "{}", e),
            }
        }
    }

    #[test]
    fn a_bad_line_is_named() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("enc.txt");
        std::fs::write(&p, "# mm\n10.0\n10.5\n10.2\n").expect("write");
        let e = read_encoder(&p, 10).expect_err("backwards");
        assert!(
            e.to_string().ends_with(
                "enc.txt:4: position 10.2 mm is behind the previous 10.5 mm; encoder \
                                         positions must not decrease"
            ),
            "{e}"
        );
        std::fs::write(&p, "1\n2\n3\n").expect("write");
        assert_eq!(read_encoder(&p, 10).expect("read"), [0.0, 1.0, 2.0]);
        assert!(
            read_encoder(&p, 2)
                .expect_err("too many")
                .to_string()
                .contains("more than the 2")
        );
    }
}
