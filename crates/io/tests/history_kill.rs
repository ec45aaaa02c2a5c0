//! The history survives its writer being killed: a child process records inspections as fast as it can and says
//! which ids it committed; the parent kills it (SIGKILL, no chance to clean up) mid-stream, then checks that the
//! file is sound and that every committed inspection is there with all its candidates.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use stripe3d_core::detect::{Candidate, CandidateSource, DefectKind, Evidence};
use stripe3d_io::history::{CandidateRecord, Filter, History, InspectionRecord};

const ENV: &str = "STRIPE3D_KILL_TEST_DB";
const CANDIDATES: usize = 40;

fn record(n: usize) -> InspectionRecord {
    InspectionRecord {
        part_id: format!("P{n}"),
        product: Some("cover-plate".into()),
        verdict: "accept".into(),
        trace: vec!["accept".into()],
        candidates: (0..CANDIDATES)
            .map(|k| CandidateRecord {
                candidate: Candidate {
                    source: CandidateSource::Surface,
                    centroid_mm: [k as f64, n as f64],
                    area_mm2: 1.0,
                    evidence: Evidence::default(),
                    kind: DefectKind::Dent,
                    confidence: 0.9,
                    reported: false,
                    defect: None,
                },
                defect_id: None,
                designed: None,
                depth_mm: None,
                volume_mm3: None,
            })
            .collect(),
        ..InspectionRecord::default()
    }
}

/// The child: runs only when the parent sets the variable (ignored otherwise).
#[test]
#[ignore = "helper: run by a_killed_writer_loses_nothing_committed"]
fn writer_child() {
    let Some(path) = std::env::var_os(ENV) else {
        return;
    };
    let mut h = History::open(std::path::Path::new(&path)).expect("open");
    for n in 0.. {
        let id = h.record(&record(n)).expect("record");
        println!("committed {id}");
    }
}

#[test]
fn a_killed_writer_loses_nothing_committed() {
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("history.sqlite");
    let exe = std::env::current_exe().expect("test binary");
    let mut child = Command::new(exe)
        .args([
            "--exact",
            "writer_child",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ENV, &path)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn the writer");
    let out = child.stdout.take().expect("stdout");
    let mut committed = Vec::new();
    for line in BufReader::new(out).lines() {
        let Ok(line) = line else { break };
        if let Some(id) = line.strip_prefix("committed ") {
            committed.push(id.trim().parse::<i64>().expect("id"));
            if committed.len() >= 60 {
                break;
            }
        }
    }
    // Killed while it writes the next ones.
    child.kill().expect("kill");
    let _ = child.wait();
    assert!(
        committed.len() >= 60,
        "the writer committed {} inspections",
        committed.len()
    );
    let mut h = History::open(&path).expect("reopens after the kill");
    assert_eq!(h.integrity().expect("integrity"), "ok");
    let rows = h.list(&Filter::default()).expect("list");
    for id in &committed {
        assert!(
            rows.iter().any(|r| r.id == *id),
            "committed inspection {id} is there"
        );
    }
    // Every inspection present is whole: all its candidates came with it (one transaction).
    for r in &rows {
        assert_eq!(
            h.candidates(r.id).expect("candidates").len(),
            CANDIDATES,
            "inspection {}",
            r.id
        );
    }
    // And the history still takes new inspections.
    h.record(&record(9999)).expect("writes after the kill");
}
