//! The inspection history: one SQLite file holding every inspection (part, time, product, method and knowledge-base
//! version, verdict, diagnosis and trace, where the report and pictures are, and every candidate region the rules
//! weighed with its evidence), and operators' feedback on them.
//!
//! Durability: the database runs in WAL mode with `synchronous = FULL`, and each inspection (with its candidates) or
//! feedback is one transaction, so a process killed mid-inspection loses at most the inspection it was writing and
//! never corrupts the file. The schema version is kept in `PRAGMA user_version`; a file from a newer stripe3d, or a
//! SQLite file that is not a stripe3d history, is refused rather than altered.
//!
//! Default location: `$STRIPE3D_DB` if set, else `$XDG_DATA_HOME/stripe3d/history.sqlite`, else
//! `~/.local/share/stripe3d/history.sqlite` (see [`default_path`]).

use crate::IoError;
use rusqlite::{Connection, OptionalExtension, params};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use stripe3d_core::detect::{Candidate, CandidateSource, DefectKind, Evidence};
use stripe3d_kb::learn::Mark;
use stripe3d_kb::reason::PartDefects;

/// Schema version this build writes and reads.
pub const SCHEMA_VERSION: i64 = 1;
/// How close (mm) an operator's "missed defect at x, y" must be to a candidate to label it.
pub const MISSED_RADIUS_MM: f64 = 2.0;

const SCHEMA: &str = "
CREATE TABLE inspection (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    part_id TEXT NOT NULL,
    time_utc TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%SZ', 'now')),
    product TEXT,
    process TEXT,
    method TEXT,
    kb_name TEXT,
    kb_version INTEGER,
    verdict TEXT NOT NULL,
    coverage REAL,
    diagnosis TEXT NOT NULL,
    trace TEXT NOT NULL,
    report_dir TEXT,
    origin_x_mm REAL NOT NULL,
    origin_y_mm REAL NOT NULL
);
CREATE INDEX inspection_product ON inspection(product, id);
CREATE TABLE candidate (
    inspection_id INTEGER NOT NULL REFERENCES inspection(id),
    idx INTEGER NOT NULL,
    defect_id INTEGER,
    designed TEXT,
    source TEXT NOT NULL,
    kind TEXT NOT NULL,
    confidence REAL NOT NULL,
    x_mm REAL NOT NULL,
    y_mm REAL NOT NULL,
    area_mm2 REAL NOT NULL,
    depth_mm REAL,
    volume_mm3 REAL,
    curvature REAL NOT NULL,
    direction REAL NOT NULL,
    gap REAL NOT NULL,
    similarity REAL NOT NULL,
    elongation REAL NOT NULL,
    edge_notch REAL NOT NULL,
    cells INTEGER NOT NULL,
    PRIMARY KEY (inspection_id, idx)
);
CREATE TABLE feedback (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    inspection_id INTEGER NOT NULL REFERENCES inspection(id),
    time_utc TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%SZ', 'now')),
    judgement TEXT NOT NULL CHECK (judgement IN ('confirmed', 'false-alarm', 'missed', 'reviewed')),
    defect_id INTEGER,
    kind TEXT,
    x_mm REAL,
    y_mm REAL,
    cause TEXT,
    operator TEXT,
    note TEXT
);
CREATE INDEX feedback_inspection ON feedback(inspection_id);
";

/// The default database file (see the module docs).
pub fn default_path() -> PathBuf {
    if let Some(p) = std::env::var_os("STRIPE3D_DB").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let base = std::env::var_os("XDG_DATA_HOME")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share")))
        .unwrap_or_else(|| PathBuf::from("."));
    base.join("stripe3d").join("history.sqlite")
}

/// One candidate as recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateRecord {
    /// The candidate.
    pub candidate: Candidate,
    /// Its defect number in the report (1-based), when reported.
    pub defect_id: Option<usize>,
    /// The designed feature it is, when it is one.
    pub designed: Option<String>,
    /// Depth or height of its defect, mm.
    pub depth_mm: Option<f64>,
    /// Volume of its defect, mm³.
    pub volume_mm3: Option<f64>,
}

/// One inspection as recorded.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct InspectionRecord {
    /// Part identifier (serial number, or one made up from the time).
    pub part_id: String,
    /// Product, when inspected with one.
    pub product: Option<String>,
    /// Its process.
    pub process: Option<String>,
    /// Its method.
    pub method: Option<String>,
    /// Knowledge base name.
    pub kb_name: Option<String>,
    /// Knowledge base version.
    pub kb_version: Option<u32>,
    /// Verdict.
    pub verdict: String,
    /// Share of the outline with data.
    pub coverage: f64,
    /// Ranked causes.
    pub diagnosis: Vec<(String, f64)>,
    /// The trace.
    pub trace: Vec<String>,
    /// Folder of report.json and the pictures.
    pub report_dir: Option<String>,
    /// Product frame origin in part coordinates, mm.
    pub frame_origin_mm: [f64; 2],
    /// Every candidate.
    pub candidates: Vec<CandidateRecord>,
}

/// An operator's judgement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Judgement {
    /// A reported defect is real (optionally of another kind).
    Confirmed,
    /// A reported defect is not a defect.
    FalseAlarm,
    /// A defect the inspection did not report.
    Missed,
    /// The operator checked the whole part: reported defects without other feedback are right, and nothing else
    /// is wrong.
    Reviewed,
}

impl Judgement {
    /// Name in the database.
    pub fn name(self) -> &'static str {
        match self {
            Judgement::Confirmed => "confirmed",
            Judgement::FalseAlarm => "false-alarm",
            Judgement::Missed => "missed",
            Judgement::Reviewed => "reviewed",
        }
    }

    fn from_name(s: &str) -> Option<Self> {
        [
            Judgement::Confirmed,
            Judgement::FalseAlarm,
            Judgement::Missed,
            Judgement::Reviewed,
        ]
        .into_iter()
        .find(|j| j.name() == s)
    }
}

/// One piece of feedback.
#[derive(Debug, Clone, PartialEq)]
pub struct Feedback {
    /// The inspection.
    pub inspection: i64,
    /// What the operator says.
    pub judgement: Judgement,
    /// The defect number in the report (confirmed, false alarm).
    pub defect_id: Option<usize>,
    /// The kind it really is (confirmed: a correction; missed: required).
    pub kind: Option<DefectKind>,
    /// Where (missed), part coordinates, mm.
    pub at_mm: Option<[f64; 2]>,
    /// The cause the operator found.
    pub cause: Option<String>,
    /// Who.
    pub operator: Option<String>,
    /// Free text.
    pub note: Option<String>,
}

/// A row of `stripe3d history`.
#[derive(Debug, Clone, PartialEq)]
pub struct InspectionRow {
    /// Inspection id.
    pub id: i64,
    /// Part.
    pub part_id: String,
    /// When (UTC, RFC 3339).
    pub time_utc: String,
    /// Product.
    pub product: Option<String>,
    /// Method.
    pub method: Option<String>,
    /// Knowledge-base version.
    pub kb_version: Option<u32>,
    /// Verdict.
    pub verdict: String,
    /// Reported defects that are not designed features.
    pub defects: usize,
    /// Ranked causes.
    pub diagnosis: Vec<(String, f64)>,
    /// Feedback entries.
    pub feedback: usize,
    /// Report folder.
    pub report_dir: Option<String>,
}

/// Which inspections `stripe3d history` lists.
#[derive(Debug, Clone, Default)]
pub struct Filter {
    /// Only this product.
    pub product: Option<String>,
    /// Only this verdict.
    pub verdict: Option<String>,
    /// Only this part.
    pub part_id: Option<String>,
    /// Only from this time on (RFC 3339 prefix, e.g. `2026-11-23`).
    pub since: Option<String>,
    /// Most rows (newest first).
    pub limit: usize,
}

/// A part with operator feedback, ready for learning.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelledPart {
    /// Inspection id.
    pub inspection: i64,
    /// Candidates (designed features left out).
    pub candidates: Vec<Candidate>,
    /// The judgements as marks.
    pub marks: Vec<Mark>,
}

/// An open history database.
pub struct History {
    conn: Connection,
    path: PathBuf,
}

impl std::fmt::Debug for History {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("History").field("path", &self.path).finish()
    }
}

fn to_i64(v: usize) -> i64 {
    i64::try_from(v).unwrap_or(i64::MAX)
}

impl History {
    fn err(&self, e: impl std::fmt::Display) -> IoError {
        db_error(&self.path, e)
    }

    /// Opens (creating when absent) the history at `path`.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|source| IoError::Write {
                path: parent.to_path_buf(),
                source,
            })?;
        }
        if path.is_dir() {
            return Err(db_error(path, "is a folder: give a database file"));
        }
        let conn = Connection::open(path).map_err(|e| db_error(path, e))?;
        let h = History {
            conn,
            path: path.to_path_buf(),
        };
        h.conn
            .busy_timeout(std::time::Duration::from_secs(10))
            .map_err(|e| h.err(e))?;
        let version: i64 = h
            .conn
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(|e| h.err(e))?;
        if version > SCHEMA_VERSION {
            return Err(h.err(format!(
                "written by a newer stripe3d (history schema {version}; this build reads up to {SCHEMA_VERSION}): \
                 use that stripe3d, or give another --db"
            )));
        }
        let tables: Vec<String> = {
            let mut st = h
                .conn
                .prepare("SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite_%'")
                .map_err(|e| h.err(e))?;
            st.query_map([], |r| r.get(0))
                .map_err(|e| h.err(e))?
                .collect::<Result<_, _>>()
                .map_err(|e| h.err(e))?
        };
        let mode: String = h
            .conn
            .query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))
            .map_err(|e| h.err(e))?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(h.err(format!(
                "cannot switch to WAL journaling (got `{mode}`): put the database on a local disk"
            )));
        }
        h.conn
            .execute_batch("PRAGMA synchronous = FULL; PRAGMA foreign_keys = ON;")
            .map_err(|e| h.err(e))?;
        if version == 0 {
            if !tables.is_empty() {
                return Err(h.err(format!(
                    "a SQLite database but not a stripe3d history (it has tables {}): give another --db",
                    tables.join(", ")
                )));
            }
            h.conn
                .execute_batch(&format!(
                    "BEGIN; {SCHEMA} PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;"
                ))
                .map_err(|e| h.err(e))?;
        } else {
            for t in ["inspection", "candidate", "feedback"] {
                if !tables.iter().any(|x| x == t) {
                    return Err(h.err(format!(
                        "schema {version} without its `{t}` table: the file is damaged; restore a backup"
                    )));
                }
            }
        }
        Ok(h)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Stores one inspection with its candidates in one transaction; returns its id.
    pub fn record(&mut self, r: &InspectionRecord) -> Result<i64, IoError> {
        let diagnosis = serde_json::to_string(&r.diagnosis).map_err(|e| self.err(e))?;
        let trace = serde_json::to_string(&r.trace).map_err(|e| self.err(e))?;
        let path = self.path.clone();
        let tx = self.conn.transaction().map_err(|e| db_error(&path, e))?;
        tx.execute(
            "INSERT INTO inspection (part_id, product, process, method, kb_name, kb_version, verdict, coverage, \
             diagnosis, trace, report_dir, origin_x_mm, origin_y_mm) \
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13)",
            params![
                r.part_id,
                r.product,
                r.process,
                r.method,
                r.kb_name,
                r.kb_version,
                r.verdict,
                r.coverage,
                diagnosis,
                trace,
                r.report_dir,
                r.frame_origin_mm[0],
                r.frame_origin_mm[1]
            ],
        )
        .map_err(|e| db_error(&path, e))?;
        let id = tx.last_insert_rowid();
        {
            let mut st = tx
                .prepare(
                    "INSERT INTO candidate (inspection_id, idx, defect_id, designed, source, kind, confidence, x_mm, \
                     y_mm, area_mm2, depth_mm, volume_mm3, curvature, direction, gap, similarity, elongation, \
                     edge_notch, cells) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, \
                     ?16, ?17, ?18, ?19)",
                )
                .map_err(|e| db_error(&path, e))?;
            for (k, c) in r.candidates.iter().enumerate() {
                let d = &c.candidate;
                let e = &d.evidence;
                st.execute(params![
                    id,
                    to_i64(k),
                    c.defect_id.map(to_i64),
                    c.designed,
                    d.source.name(),
                    d.kind.name(),
                    d.confidence,
                    d.centroid_mm[0],
                    d.centroid_mm[1],
                    d.area_mm2,
                    c.depth_mm,
                    c.volume_mm3,
                    e.curvature_per_mm,
                    e.direction,
                    e.gap_mm,
                    e.height_similarity_mm,
                    e.elongation,
                    e.edge_notch_mm,
                    to_i64(e.cells)
                ])
                .map_err(|e| db_error(&path, e))?;
            }
        }
        tx.commit().map_err(|e| db_error(&path, e))?;
        Ok(id)
    }

    /// Records feedback after checking that it refers to something that exists; returns its id.
    pub fn add_feedback(&mut self, f: &Feedback) -> Result<i64, IoError> {
        let exists: Option<i64> = self
            .conn
            .query_row(
                "SELECT id FROM inspection WHERE id = ?1",
                [f.inspection],
                |r| r.get(0),
            )
            .optional()
            .map_err(|e| self.err(e))?;
        if exists.is_none() {
            return Err(self.err(format!(
                "no inspection {} (see `stripe3d history`)",
                f.inspection
            )));
        }
        match f.judgement {
            Judgement::Confirmed | Judgement::FalseAlarm => {
                let Some(n) = f.defect_id else {
                    return Err(self.err("name the defect by its number in the report"));
                };
                let found: Option<i64> = self
                    .conn
                    .query_row(
                        "SELECT idx FROM candidate WHERE inspection_id = ?1 AND defect_id = ?2",
                        params![f.inspection, to_i64(n)],
                        |r| r.get(0),
                    )
                    .optional()
                    .map_err(|e| self.err(e))?;
                if found.is_none() {
                    return Err(self.err(format!(
                        "inspection {} has no defect {n} (see its report.json)",
                        f.inspection
                    )));
                }
            }
            Judgement::Missed => {
                if f.kind.is_none()
                    || f.at_mm
                        .is_none_or(|p| !(p[0].is_finite() && p[1].is_finite()))
                {
                    return Err(self.err("a missed defect needs its kind and its place x, y in mm"));
                }
            }
            Judgement::Reviewed => {}
        }
        self.conn
            .execute(
                "INSERT INTO feedback (inspection_id, judgement, defect_id, kind, x_mm, y_mm, cause, operator, note) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
                params![
                    f.inspection,
                    f.judgement.name(),
                    f.defect_id.map(to_i64),
                    f.kind.map(|k| k.name()),
                    f.at_mm.map(|p| p[0]),
                    f.at_mm.map(|p| p[1]),
                    f.cause,
                    f.operator,
                    f.note
                ],
            )
            .map_err(|e| self.err(e))?;
        Ok(self.conn.last_insert_rowid())
    }

    /// Inspections matching `filter`, newest first.
    pub fn list(&self, filter: &Filter) -> Result<Vec<InspectionRow>, IoError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT i.id, i.part_id, i.time_utc, i.product, i.method, i.kb_version, i.verdict, i.diagnosis, \
                 i.report_dir, \
                 (SELECT COUNT(*) FROM candidate c WHERE c.inspection_id = i.id AND c.defect_id IS NOT NULL \
                  AND c.designed IS NULL), \
                 (SELECT COUNT(*) FROM feedback f WHERE f.inspection_id = i.id) \
                 FROM inspection i \
                 WHERE (?1 IS NULL OR i.product = ?1) AND (?2 IS NULL OR i.verdict = ?2) \
                 AND (?3 IS NULL OR i.part_id = ?3) AND (?4 IS NULL OR i.time_utc >= ?4) \
                 ORDER BY i.id DESC LIMIT ?5",
            )
            .map_err(|e| self.err(e))?;
        let limit = if filter.limit == 0 {
            i64::MAX
        } else {
            to_i64(filter.limit)
        };
        let rows = st
            .query_map(
                params![
                    filter.product,
                    filter.verdict,
                    filter.part_id,
                    filter.since,
                    limit
                ],
                |r| {
                    let diagnosis: String = r.get(7)?;
                    Ok(InspectionRow {
                        id: r.get(0)?,
                        part_id: r.get(1)?,
                        time_utc: r.get(2)?,
                        product: r.get(3)?,
                        method: r.get(4)?,
                        kb_version: r.get(5)?,
                        verdict: r.get(6)?,
                        diagnosis: serde_json::from_str(&diagnosis).unwrap_or_default(),
                        report_dir: r.get(8)?,
                        defects: r.get::<_, i64>(9)?.max(0) as usize,
                        feedback: r.get::<_, i64>(10)?.max(0) as usize,
                    })
                },
            )
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// The defects (kind, product-frame centre) of the product's last `parts` inspections, newest first (for
    /// recurrence).
    pub fn recent_defects(&self, product: &str, parts: usize) -> Result<Vec<PartDefects>, IoError> {
        let mut st = self
            .conn
            .prepare("SELECT id, origin_x_mm, origin_y_mm FROM inspection WHERE product = ?1 ORDER BY id DESC LIMIT ?2")
            .map_err(|e| self.err(e))?;
        let ids: Vec<(i64, f64, f64)> = st
            .query_map(params![product, to_i64(parts)], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?))
            })
            .map_err(|e| self.err(e))?
            .collect::<Result<_, _>>()
            .map_err(|e| self.err(e))?;
        let mut out = Vec::new();
        let mut st = self
            .conn
            .prepare(
                "SELECT kind, x_mm, y_mm FROM candidate WHERE inspection_id = ?1 AND defect_id IS NOT NULL \
                 AND designed IS NULL",
            )
            .map_err(|e| self.err(e))?;
        for (id, ox, oy) in ids {
            let defects: Vec<(String, f64, f64)> = st
                .query_map([id], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
                .map_err(|e| self.err(e))?
                .collect::<Result<_, _>>()
                .map_err(|e| self.err(e))?;
            out.push(
                defects
                    .into_iter()
                    .filter_map(|(k, x, y)| Some((DefectKind::from_name(&k)?, [x - ox, y - oy])))
                    .collect(),
            );
        }
        Ok(out)
    }

    fn feedback_of(&self, inspection: i64) -> Result<Vec<Feedback>, IoError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT judgement, defect_id, kind, x_mm, y_mm, cause, operator, note FROM feedback \
                 WHERE inspection_id = ?1 ORDER BY id",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([inspection], |r| {
                let j: String = r.get(0)?;
                let kind: Option<String> = r.get(2)?;
                let (x, y): (Option<f64>, Option<f64>) = (r.get(3)?, r.get(4)?);
                Ok(Feedback {
                    inspection,
                    judgement: Judgement::from_name(&j).unwrap_or(Judgement::Reviewed),
                    defect_id: r.get::<_, Option<i64>>(1)?.map(|v| v.max(0) as usize),
                    kind: kind.as_deref().and_then(DefectKind::from_name),
                    at_mm: x.zip(y).map(|(x, y)| [x, y]),
                    cause: r.get(5)?,
                    operator: r.get(6)?,
                    note: r.get(7)?,
                })
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    fn candidates_of(
        &self,
        inspection: i64,
    ) -> Result<Vec<(Candidate, Option<usize>, bool)>, IoError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT source, kind, confidence, x_mm, y_mm, area_mm2, curvature, direction, gap, similarity, \
                 elongation, edge_notch, cells, defect_id, designed FROM candidate WHERE inspection_id = ?1 \
                 ORDER BY idx",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([inspection], |r| {
                let source: String = r.get(0)?;
                let kind: String = r.get(1)?;
                let defect: Option<i64> = r.get(13)?;
                let designed: Option<String> = r.get(14)?;
                Ok((
                    Candidate {
                        source: CandidateSource::from_name(&source)
                            .unwrap_or(CandidateSource::Surface),
                        centroid_mm: [r.get(3)?, r.get(4)?],
                        area_mm2: r.get(5)?,
                        evidence: Evidence {
                            curvature_per_mm: r.get(6)?,
                            direction: r.get(7)?,
                            gap_mm: r.get(8)?,
                            height_similarity_mm: r.get(9)?,
                            elongation: r.get(10)?,
                            edge_notch_mm: r.get(11)?,
                            cells: r.get::<_, i64>(12)?.max(0) as usize,
                        },
                        kind: DefectKind::from_name(&kind).unwrap_or(DefectKind::Anomaly),
                        confidence: r.get(2)?,
                        reported: defect.is_some(),
                        defect: defect.map(|d| (d.max(1) - 1) as usize),
                    },
                    defect.map(|d| d.max(0) as usize),
                    designed.is_some(),
                ))
            })
            .map_err(|e| self.err(e))?;
        rows.collect::<Result<Vec<_>, _>>().map_err(|e| self.err(e))
    }

    /// The candidates recorded with an inspection, in their order.
    pub fn candidates(&self, inspection: i64) -> Result<Vec<Candidate>, IoError> {
        Ok(self
            .candidates_of(inspection)?
            .into_iter()
            .map(|c| c.0)
            .collect())
    }

    /// Every inspection of `product` with feedback, as candidates and marks (see [`Judgement::Reviewed`]: reported
    /// defects without feedback count as confirmed, unreported candidates as nothing).
    pub fn labelled(&self, product: &str) -> Result<Vec<LabelledPart>, IoError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT DISTINCT i.id FROM inspection i JOIN feedback f ON f.inspection_id = i.id \
                 WHERE i.product = ?1 ORDER BY i.id",
            )
            .map_err(|e| self.err(e))?;
        let ids: Vec<i64> = st
            .query_map([product], |r| r.get(0))
            .map_err(|e| self.err(e))?
            .collect::<Result<_, _>>()
            .map_err(|e| self.err(e))?;
        let mut out = Vec::new();
        for id in ids {
            let fb = self.feedback_of(id)?;
            let all = self.candidates_of(id)?;
            let mut marks = Vec::new();
            let mut candidates = Vec::new();
            for (c, defect_id, designed) in all {
                if designed {
                    continue;
                }
                if let Some(n) = defect_id {
                    let about = fb.iter().rev().find(|f| {
                        f.defect_id == Some(n)
                            && matches!(f.judgement, Judgement::Confirmed | Judgement::FalseAlarm)
                    });
                    let kind = match about {
                        Some(f) if f.judgement == Judgement::FalseAlarm => None,
                        Some(f) => Some(f.kind.unwrap_or(c.kind)),
                        None => Some(c.kind),
                    };
                    marks.push(Mark {
                        kind,
                        at_mm: c.centroid_mm,
                        radius_mm: 1e-6,
                    });
                }
                candidates.push(c);
            }
            for f in fb.iter().filter(|f| f.judgement == Judgement::Missed) {
                if let Some(at) = f.at_mm {
                    marks.push(Mark {
                        kind: f.kind,
                        at_mm: at,
                        radius_mm: MISSED_RADIUS_MM,
                    });
                }
            }
            out.push(LabelledPart {
                inspection: id,
                candidates,
                marks,
            });
        }
        Ok(out)
    }

    /// Operator-confirmed causes per product: `counts[product][cause]`.
    pub fn confirmed_causes(&self) -> Result<BTreeMap<String, BTreeMap<String, u64>>, IoError> {
        let mut st = self
            .conn
            .prepare(
                "SELECT i.product, f.cause, COUNT(*) FROM feedback f JOIN inspection i ON i.id = f.inspection_id \
                 WHERE f.cause IS NOT NULL AND i.product IS NOT NULL AND f.judgement IN ('confirmed', 'missed') \
                 GROUP BY i.product, f.cause",
            )
            .map_err(|e| self.err(e))?;
        let rows = st
            .query_map([], |r| {
                Ok((
                    r.get::<_, String>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, i64>(2)?,
                ))
            })
            .map_err(|e| self.err(e))?;
        let mut out: BTreeMap<String, BTreeMap<String, u64>> = BTreeMap::new();
        for row in rows {
            let (p, c, n) = row.map_err(|e| self.err(e))?;
            out.entry(p).or_default().insert(c, n.max(0) as u64);
        }
        Ok(out)
    }

    /// `PRAGMA integrity_check`'s answer (`ok` for a sound file).
    pub fn integrity(&self) -> Result<String, IoError> {
        self.conn
            .query_row("PRAGMA integrity_check", [], |r| r.get(0))
            .map_err(|e| self.err(e))
    }
}

fn db_error(path: &Path, e: impl std::fmt::Display) -> IoError {
    let m = e.to_string();
    let message = if m.contains("not a database") || m.contains("malformed") {
        format!("not a stripe3d history database ({m}): give another --db, or move this file away")
    } else {
        m
    };
    IoError::Database {
        path: path.to_path_buf(),
        message,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(kind: DefectKind, x: f64, defect: Option<usize>) -> CandidateRecord {
        CandidateRecord {
            candidate: Candidate {
                source: CandidateSource::Surface,
                centroid_mm: [x, 1.0],
                area_mm2: 5.0,
                evidence: Evidence {
                    elongation: 1.2,
                    ..Evidence::default()
                },
                kind,
                confidence: 0.8,
                reported: defect.is_some(),
                defect: defect.map(|d| d - 1),
            },
            defect_id: defect,
            designed: None,
            depth_mm: Some(0.2),
            volume_mm3: Some(1.0),
        }
    }

    fn record(part: &str) -> InspectionRecord {
        InspectionRecord {
            part_id: part.into(),
            product: Some("cover-plate".into()),
            verdict: "rework".into(),
            diagnosis: vec![("die-debris".into(), 0.8)],
            trace: vec!["rework: 1 defect(s)".into()],
            frame_origin_mm: [1.0, 0.0],
            candidates: vec![
                candidate(DefectKind::Dent, 11.0, Some(1)),
                candidate(DefectKind::Anomaly, 20.0, None),
            ],
            ..InspectionRecord::default()
        }
    }

    #[test]
    fn inspections_and_feedback_round_trip_into_labels() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("h.sqlite");
        let mut h = History::open(&path).expect("open");
        let a = h.record(&record("A1")).expect("record");
        let b = h.record(&record("A2")).expect("record");
        let rows = h.list(&Filter::default()).expect("list");
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].id, b, "newest first");
        assert_eq!(rows[0].defects, 1);
        assert_eq!(rows[0].diagnosis[0].0, "die-debris");
        let only = h
            .list(&Filter {
                part_id: Some("A1".into()),
                ..Filter::default()
            })
            .expect("list");
        assert_eq!(only.len(), 1);
        // Feedback: defect 1 of A1 is a bump, and a scratch was missed where the anomaly is.
        let fb = |judgement, defect_id, kind, at_mm, cause: Option<&str>| Feedback {
            inspection: a,
            judgement,
            defect_id,
            kind,
            at_mm,
            cause: cause.map(String::from),
            operator: Some("ana".into()),
            note: None,
        };
        h.add_feedback(&fb(
            Judgement::Confirmed,
            Some(1),
            Some(DefectKind::Bump),
            None,
            Some("die-debris"),
        ))
        .expect("feedback");
        h.add_feedback(&fb(
            Judgement::Missed,
            None,
            Some(DefectKind::Scratch),
            Some([20.5, 1.0]),
            None,
        ))
        .expect("feedback");
        assert!(
            h.add_feedback(&fb(Judgement::Confirmed, Some(7), None, None, None))
                .is_err(),
            "no defect 7"
        );
        assert!(
            h.add_feedback(&fb(Judgement::Missed, None, None, Some([0.0, 0.0]), None))
                .is_err(),
            "kind needed"
        );
        let mut bad = fb(Judgement::Reviewed, None, None, None, None);
        bad.inspection = 99;
        assert!(h.add_feedback(&bad).is_err(), "no inspection 99");
        let parts = h.labelled("cover-plate").expect("labelled");
        assert_eq!(parts.len(), 1, "only A1 has feedback");
        let (l, missed) =
            stripe3d_kb::learn::label_by_position(&parts[0].candidates, &parts[0].marks);
        assert_eq!(missed, 0);
        assert_eq!(l[0].truth, Some(DefectKind::Bump));
        assert_eq!(l[1].truth, Some(DefectKind::Scratch));
        assert_eq!(
            h.confirmed_causes().expect("causes")["cover-plate"]["die-debris"],
            1
        );
        let recent = h.recent_defects("cover-plate", 10).expect("recent");
        assert_eq!(recent.len(), 2);
        assert_eq!(
            recent[0],
            vec![(DefectKind::Dent, [10.0, 1.0])],
            "product frame"
        );
        assert_eq!(h.integrity().expect("check"), "ok");
        drop(h);
        // Reopening finds everything.
        let h = History::open(&path).expect("reopen");
        assert_eq!(h.list(&Filter::default()).expect("list").len(), 2);
    }

    #[test]
    fn foreign_damaged_and_newer_files_are_refused() {
        let dir = tempfile::tempdir().expect("tmp");
        let junk = dir.path().join("junk.sqlite");
        std::fs::write(
            &junk,
            b"this is not a database at all, but a text file of some length.....",
        )
        .expect("w");
        let e = History::open(&junk).expect_err("refused").to_string();
        assert!(
            e.contains("junk.sqlite") && e.contains("not a stripe3d history"),
            "{e}"
        );
        let other = dir.path().join("other.sqlite");
        {
            let c = Connection::open(&other).expect("open");
            c.execute_batch("CREATE TABLE customers (name TEXT);")
                .expect("create");
        }
        let e = History::open(&other).expect_err("refused").to_string();
        assert!(e.contains("customers"), "{e}");
        let newer = dir.path().join("newer.sqlite");
        {
            let c = Connection::open(&newer).expect("open");
            c.execute_batch("PRAGMA user_version = 7;")
                .expect("version");
        }
        let e = History::open(&newer).expect_err("refused").to_string();
        assert!(e.contains("newer stripe3d") && e.contains('7'), "{e}");
        assert!(History::open(dir.path()).is_err(), "a folder");
    }
}
