//! Knowledge-base folders: reading one (the layout of [`stripe3d_kb::model`]) and writing a new version.

use crate::IoError;
use std::path::{Path, PathBuf};
use stripe3d_kb::model::{MAX_FILE_BYTES, MAX_FILES};
use stripe3d_kb::{KnowledgeBase, SourceFile};

fn kb_error(dir: &Path, e: stripe3d_kb::KbError) -> IoError {
    IoError::Knowledge {
        dir: dir.to_path_buf(),
        message: e.to_string(),
    }
}

fn rel(dir: &Path, p: &Path) -> String {
    p.strip_prefix(dir)
        .unwrap_or(p)
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("/")
}

/// Reads the knowledge base in `dir`: `kb.toml`, `statistics.toml`, everything in `products/`, `processes/` and
/// `methods/`, and every `.fll` file within two folder levels. Other top-level files (a README) are left alone.
pub fn read_kb(dir: &Path) -> Result<KnowledgeBase, IoError> {
    if !dir.join("kb.toml").is_file() {
        return Err(IoError::Knowledge {
            dir: dir.to_path_buf(),
            message: "no kb.toml here: give the folder of a knowledge base (see crates/kb/knowledge for the \
                      shipped example)"
                .into(),
        });
    }
    let mut paths: Vec<PathBuf> = Vec::new();
    for name in ["kb.toml", "statistics.toml"] {
        if dir.join(name).is_file() {
            paths.push(dir.join(name));
        }
    }
    for sub in ["products", "processes", "methods"] {
        let d = dir.join(sub);
        if d.is_dir() {
            paths.extend(crate::files::read_dir(&d)?.into_iter().filter(|p| {
                !p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            }));
        }
    }
    // Rule bases: .fll within two levels (rules/surface.fll).
    let mut stack = vec![(dir.to_path_buf(), 0)];
    while let Some((d, depth)) = stack.pop() {
        for p in crate::files::read_dir(&d)? {
            if p.is_dir() && depth < 2 {
                stack.push((p, depth + 1));
            } else if p.extension().is_some_and(|e| e == "fll") {
                paths.push(p);
            }
        }
    }
    if paths.len() > MAX_FILES {
        return Err(IoError::Knowledge {
            dir: dir.to_path_buf(),
            message: format!("{} files: at most {MAX_FILES}", paths.len()),
        });
    }
    let mut files = Vec::new();
    for p in paths {
        let size = std::fs::metadata(&p)
            .map_err(|source| IoError::Read {
                path: p.clone(),
                source,
            })?
            .len();
        if size > MAX_FILE_BYTES as u64 {
            return Err(IoError::Invalid {
                path: p,
                line: None,
                field: "file".into(),
                message: format!("{size} bytes: knowledge files are at most {MAX_FILE_BYTES}"),
            });
        }
        let text = crate::files::read_text(&p)?;
        files.push(SourceFile {
            path: rel(dir, &p),
            text,
        });
    }
    KnowledgeBase::from_files(&files).map_err(|e| kb_error(dir, e))
}

/// The knowledge base holding `product_file` (a `products/NAME.toml`): the nearest folder above it with a
/// `kb.toml`.
pub fn kb_root_of(product_file: &Path) -> Option<PathBuf> {
    let abs = product_file
        .canonicalize()
        .unwrap_or_else(|_| product_file.to_path_buf());
    abs.ancestors()
        .skip(1)
        .take(3)
        .find(|d| d.join("kb.toml").is_file())
        .map(Path::to_path_buf)
}

/// Writes `kb` as a new folder `dir`, which must not exist: a learned version never replaces another. The files
/// go to a temporary folder beside it, renamed into place once complete.
pub fn write_kb(dir: &Path, kb: &KnowledgeBase) -> Result<(), IoError> {
    if dir.exists() {
        return Err(IoError::Invalid {
            path: dir.to_path_buf(),
            line: None,
            field: "folder".into(),
            message:
                "exists already: a knowledge-base version is never overwritten; choose a new folder"
                    .into(),
        });
    }
    let files = kb.to_files().map_err(|e| kb_error(dir, e))?;
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "kb".into());
    let tmp = dir.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    let write_err = |path: &Path, source| IoError::Write {
        path: path.to_path_buf(),
        source,
    };
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| write_err(&tmp, e))?;
    }
    for f in &files {
        let p = tmp.join(&f.path);
        if let Some(parent) = p.parent() {
            std::fs::create_dir_all(parent).map_err(|e| write_err(parent, e))?;
        }
        std::fs::write(&p, &f.text).map_err(|e| write_err(&p, e))?;
    }
    std::fs::rename(&tmp, dir).map_err(|e| {
        let _ = std::fs::remove_dir_all(&tmp);
        write_err(dir, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_version_reads_back_and_is_never_overwritten() {
        let kb = stripe3d_kb::shipped().expect("shipped");
        let dir = tempfile::tempdir().expect("tmp");
        let v = dir.path().join("v1");
        write_kb(&v, &kb).expect("write");
        let back = read_kb(&v).expect("read");
        assert!(stripe3d_kb::diff::diff(&kb, &back).is_empty());
        assert!(write_kb(&v, &kb).is_err(), "never over an existing folder");
        assert_eq!(
            kb_root_of(&v.join("products/cover-plate.toml")).as_deref(),
            v.canonicalize().ok().as_deref()
        );
        // A broken entry names the folder, the file and the entry.
        let p = v.join("products/cover-plate.toml");
        let t = std::fs::read_to_string(&p).expect("text");
        std::fs::write(
            &p,
            t.replace("process = \"stamping\"", "process = \"forging\""),
        )
        .expect("edit");
        let e = read_kb(&v).expect_err("refused").to_string();
        assert!(
            e.contains("products/cover-plate.toml") && e.contains("forging"),
            "{e}"
        );
        assert!(
            read_kb(dir.path())
                .expect_err("no kb.toml")
                .to_string()
                .contains("kb.toml")
        );
    }
}
