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

#[cfg(test)]
mod tests {
    use super::*;

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
