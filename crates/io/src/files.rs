//! Safe file writing: to a temporary name in the destination folder, then renamed into place.

use crate::IoError;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically: a reader never sees a partly written file under that name.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let tmp = dir.join(format!(".{name}.tmp-{}", std::process::id()));
    let err = |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    std::fs::write(&tmp, bytes).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        err(e)
    })
}

/// Creates `dir` (and its parents) and checks that a file can be written in it.
pub fn prepare_dir(dir: &Path) -> Result<(), IoError> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let probe = dir.join(format!(".stripe3d-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"").map_err(|source| IoError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &Path) -> Result<String, IoError> {
    std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// The entries of a folder, sorted by path.
pub fn read_dir(path: &Path) -> Result<Vec<PathBuf>, IoError> {
    let mut out = Vec::new();
    let entries = std::fs::read_dir(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    for e in entries {
        let e = e.map_err(|source| IoError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        out.push(e.path());
    }
    out.sort();
    Ok(out)
}

/// Orders names the way a person reads numbered files: runs of digits compare by their value (`frame_2` before
/// `frame_10`, as a camera that does not pad its counter writes them), everything else character by character;
/// names equal so (`frame_02`, `frame_2`) fall back to plain order. Zero-padded names keep their plain order.
pub fn natural_order(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(p), Some(q)) if p.is_ascii_digit() && q.is_ascii_digit() => {
                let run = |s: &[u8]| s.iter().take_while(|c| c.is_ascii_digit()).count();
                let (m, n) = (run(x), run(y));
                // Value order: without leading zeros, the longer run is the larger; of equal length, plain order.
                let strip = |s: &[u8]| {
                    let z = s.iter().take_while(|&&c| c == b'0').count();
                    s[z.min(s.len().saturating_sub(1))..].to_vec()
                };
                let (u, v) = (strip(&x[..m]), strip(&y[..n]));
                let by_value = u.len().cmp(&v.len()).then_with(|| u.cmp(&v));
                if by_value != Ordering::Equal {
                    return by_value;
                }
                (x, y) = (&x[m..], &y[n..]);
            }
            (Some(p), Some(q)) => {
                if p != q {
                    return p.cmp(q);
                }
                (x, y) = (&x[1..], &y[1..]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn numbered_names_go_by_their_numbers() {
        let mut names = vec![
            "frame_10.png",
            "frame_2.png",
            "frame_1.png",
            "frame_0100.png",
            "a.png",
        ];
        names.sort_by(|a, b| natural_order(a, b));
        assert_eq!(
            names,
            [
                "a.png",
                "frame_1.png",
                "frame_2.png",
                "frame_10.png",
                "frame_0100.png"
            ]
        );
    }

    proptest! {
        /// Zero-padded counters keep their plain order; unpadded ones sort by value; the order is total.
        #[test]
        fn padded_names_keep_their_order_and_unpadded_sort_by_value(a in 0u32..100_000, b in 0u32..100_000, p in "[a-z_]{0,6}") {
            let (pa, pb) = (format!("{p}{a:06}.png"), format!("{p}{b:06}.png"));
            prop_assert_eq!(natural_order(&pa, &pb), pa.cmp(&pb));
            let (ua, ub) = (format!("{p}{a}.png"), format!("{p}{b}.png"));
            prop_assert_eq!(natural_order(&ua, &ub), a.cmp(&b));
            prop_assert_eq!(natural_order(&ua, &ub), natural_order(&ub, &ua).reverse());
        }
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"one").expect("write");
        write_atomic(&p, b"two").expect("write");
        assert_eq!(std::fs::read(&p).expect("read"), b"two");
        assert_eq!(std::fs::read_dir(dir.path()).expect("ls").count(), 1);
        let missing = dir.path().join("no/such/dir/a.txt");
        assert!(matches!(
            write_atomic(&missing, b"x"),
            Err(IoError::Write { .. })
        ));
    }
}
