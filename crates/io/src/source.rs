//! Frame sources on disk: a recorded folder replayed (`replay:DIR`), and a folder read as new files appear
//! (`folder:DIR`), as [`stripe3d_core::line::FrameSource`]s.
//!
//! Frames are the folder's PNG, JPEG, PGM and TIFF files in name order, numbers by value (`frame_2` before
//! `frame_10`). Their timestamps are their index over the frame rate given; they carry no encoder position (the
//! conveyor's nominal speed applies). A file that cannot be read ends the stream with an error naming it.

use crate::files::natural_order;
use crate::images::read_frame;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use stripe3d_core::CoreError;
use stripe3d_core::line::{FrameSource, SourceFrame};

/// Whether `p` names an image a frame can be read from (by its extension).
pub fn is_image(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["png", "jpg", "jpeg", "pgm", "pnm", "tif", "tiff"]
            .contains(&e.to_ascii_lowercase().as_str())
    })
}

/// The images of `dir` in name order (numbers by value).
pub fn images_in(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|f| f.is_file() && is_image(f))
        .collect();
    let name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    files.sort_by(|a, b| natural_order(&name(a), &name(b)));
    Ok(files)
}

/// A folder of frames (see the module documentation).
pub struct FolderSource {
    dir: PathBuf,
    name: String,
    queue: Vec<PathBuf>,
    seen: BTreeSet<PathBuf>,
    next: u64,
    fps: f64,
    /// `Some(idle)`: wait for new files, ending after `idle` without one; `None`: the files there at the start.
    watch: Option<Duration>,
}

impl FolderSource {
    /// The frames in `dir` now (`watch` None), or as they appear until none has for `watch`; `fps` dates them.
    pub fn new(
        name: &str,
        dir: &Path,
        fps: f64,
        watch: Option<Duration>,
    ) -> Result<Self, CoreError> {
        let source_err = |message: String| CoreError::Source {
            source_name: name.to_string(),
            message,
        };
        if !dir.is_dir() {
            return Err(source_err(format!(
                "{}: no such folder (give a folder of frames)",
                dir.display()
            )));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(source_err(format!(
                "frame rate {fps}: give a positive rate"
            )));
        }
        let mut s = Self {
            dir: dir.to_path_buf(),
            name: name.to_string(),
            queue: Vec::new(),
            seen: BTreeSet::new(),
            next: 0,
            fps,
            watch,
        };
        s.refresh()?;
        if s.queue.is_empty() && watch.is_none() {
            return Err(source_err(format!(
                "{}: the folder holds no PNG, JPEG, PGM or TIFF frames",
                dir.display()
            )));
        }
        Ok(s)
    }

    fn refresh(&mut self) -> Result<(), CoreError> {
        let files = images_in(&self.dir).map_err(|e| CoreError::Source {
            source_name: self.name.clone(),
            message: format!("{}: cannot list the folder: {e}", self.dir.display()),
        })?;
        let fresh: Vec<PathBuf> = files
            .into_iter()
            .filter(|f| !self.seen.contains(f))
            .collect();
        for f in &fresh {
            self.seen.insert(f.clone());
        }
        // Taken from the end: the queue holds the files still to read in reverse order.
        let mut rest = std::mem::take(&mut self.queue);
        rest.reverse();
        rest.extend(fresh);
        rest.reverse();
        self.queue = rest;
        Ok(())
    }
}

impl FrameSource for FolderSource {
    fn next_frame(&mut self) -> Result<Option<SourceFrame>, CoreError> {
        if self.queue.is_empty() {
            let Some(idle) = self.watch else {
                return Ok(None);
            };
            let since = Instant::now();
            while self.queue.is_empty() {
                if since.elapsed() >= idle {
                    return Ok(None);
                }
                std::thread::sleep(Duration::from_millis(50));
                self.refresh()?;
            }
        }
        let Some(path) = self.queue.pop() else {
            return Ok(None);
        };
        let frame = read_frame(&path).map_err(|e| CoreError::Source {
            source_name: self.name.clone(),
            message: e.to_string(),
        })?;
        let index = self.next;
        self.next += 1;
        Ok(Some(SourceFrame {
            index,
            timestamp_s: index as f64 / self.fps,
            encoder_mm: None,
            image: frame.image,
        }))
    }

    fn live_rate_hz(&self) -> Option<f64> {
        // A folder waits for the chain: nothing is lost by reading slowly.
        None
    }

    fn describe(&self) -> String {
        format!("{} ({})", self.name, self.dir.display())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::images::write_grey_png;
    use stripe3d_core::Image;

    #[test]
    fn frames_come_in_name_order_and_a_bad_file_is_named() {
        let dir = std::env::temp_dir().join(format!("stripe3d-source-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for k in [10u16, 2, 1] {
            let mut img = Image::<u16>::new(4, 3);
            img.data_mut()[0] = k;
            write_grey_png(&dir.join(format!("frame_{k}.png")), &img, 8).unwrap();
        }
        let mut src = FolderSource::new("replay:test", &dir, 20.0, None).unwrap();
        let mut firsts = Vec::new();
        while let Some(f) = src.next_frame().unwrap() {
            firsts.push((f.index, f.image.data()[0], f.timestamp_s));
        }
        assert_eq!(firsts, vec![(0, 1, 0.0), (1, 2, 0.05), (2, 10, 0.1)]);
        std::fs::write(dir.join("frame_11.png"), b"not a png").unwrap();
        let mut src = FolderSource::new("replay:test", &dir, 20.0, None).unwrap();
        let err = loop {
            match src.next_frame() {
                Ok(Some(_)) => continue,
                Ok(None) => panic!("the bad file was not reported"),
                Err(e) => break e.to_string(),
            }
        };
        assert!(err.contains("frame_11.png"), "{err}");
        let empty = dir.join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        assert!(FolderSource::new("replay:x", &empty, 20.0, None).is_err());
        assert!(FolderSource::new("replay:x", &dir.join("none"), 20.0, None).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
