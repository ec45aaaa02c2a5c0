//! `stripe3d kb`, `feedback`, `history` and `learn`: the knowledge base, the inspection history, operators'
//! feedback and learning from it.

use crate::inspect::{ProductContext, load_product};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use serde_json::json;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use stripe3d_core::detect::DefectKind;
use stripe3d_io::history::{Feedback, Filter, History, Judgement, default_path};
use stripe3d_io::knowledge::{read_kb, write_kb};
use stripe3d_kb::KnowledgeBase;
use stripe3d_kb::check::check_product;
use stripe3d_kb::learn::{TuneReport, label_by_position, tune_rules, update_priors};
use stripe3d_kb::model::{ProductStatistics, SourceFile};

/// Fewest parts with feedback learning works from.
pub const MIN_LABELLED_PARTS: usize = 5;

/// Output formats of the listing commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Aligned columns for people.
    Table,
    /// Comma-separated, with a header.
    Csv,
    /// JSON.
    Json,
}

/// `stripe3d kb ...`.
#[derive(Debug, Subcommand)]
pub enum KbCommand {
    /// Anticipate problems of a product before production: features and limits finer than the sensor resolves,
    /// tolerances tighter than the process holds or the measurement can tell, glossy or dark materials, features
    /// the stripes cannot light.
    Check {
        /// Product name (in --kb) or product file.
        product: String,
        /// Knowledge-base folder [default: the shipped example].
        #[arg(long, value_name = "DIR")]
        kb: Option<PathBuf>,
        /// Output format.
        #[arg(long, value_enum, default_value = "table")]
        format: Format,
        /// Exit non-zero when a problem (not only a warning) is found.
        #[arg(long)]
        strict: bool,
    },
    /// Show what changed between two knowledge-base versions (folders; `shipped` for the shipped example).
    Diff {
        /// The older version.
        old: String,
        /// The newer version.
        new: String,
    },
    /// Write the shipped worked example into a new folder to edit (it never overwrites).
    Init {
        /// The new folder.
        dir: PathBuf,
    },
    /// Validate a knowledge base and list what it holds.
    Show {
        /// Knowledge-base folder [default: the shipped example].
        #[arg(long, value_name = "DIR")]
        kb: Option<PathBuf>,
    },
}

/// Arguments of `stripe3d feedback`.
#[derive(Debug, Args)]
pub struct FeedbackArgs {
    /// The inspection (its id in `stripe3d history`).
    pub inspection: i64,
    /// A reported defect is real: its number in the report (use --kind if it is of another kind).
    #[arg(long, value_name = "N", group = "judgement")]
    pub confirm: Option<usize>,
    /// A reported defect is not a defect: its number in the report.
    #[arg(long, value_name = "N", group = "judgement")]
    pub false_alarm: Option<usize>,
    /// A defect the inspection did not report, at X,Y mm (part coordinates, as in the report); needs --kind.
    #[arg(
        long,
        value_name = "X,Y",
        group = "judgement",
        allow_hyphen_values = true
    )]
    pub missed: Option<String>,
    /// The whole part was checked: what is reported and not otherwise judged is right.
    #[arg(long, group = "judgement")]
    pub reviewed: bool,
    /// The defect's real kind: bump, dent, hole, scratch, edge-chip, anomaly.
    #[arg(long)]
    pub kind: Option<String>,
    /// The cause found (a cause name of the product's process), for the diagnosis's priors.
    #[arg(long)]
    pub cause: Option<String>,
    /// Who judges.
    #[arg(long)]
    pub operator: Option<String>,
    /// Free text.
    #[arg(long)]
    pub note: Option<String>,
    /// History database [default: $STRIPE3D_DB, else ~/.local/share/stripe3d/history.sqlite].
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
}

/// Arguments of `stripe3d history`.
#[derive(Debug, Args)]
pub struct HistoryArgs {
    /// Only this product.
    #[arg(long)]
    pub product: Option<String>,
    /// Only this verdict.
    #[arg(long, value_parser = ["accept", "incomplete", "rework", "reject"])]
    pub verdict: Option<String>,
    /// Only this part.
    #[arg(long)]
    pub part: Option<String>,
    /// Only from this time on (UTC, e.g. 2026-11-23 or 2026-11-23T14:00).
    #[arg(long, value_name = "TIME")]
    pub since: Option<String>,
    /// Most inspections listed, newest first (0 = all).
    #[arg(long, default_value_t = 50)]
    pub limit: usize,
    /// Output format.
    #[arg(long, value_enum, default_value = "table")]
    pub format: Format,
    /// Also diagnose the listed inspections as one batch: causes ranked by their mean certainty.
    #[arg(long)]
    pub diagnose: bool,
    /// History database [default: $STRIPE3D_DB, else ~/.local/share/stripe3d/history.sqlite].
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
}

/// Arguments of `stripe3d learn`.
#[derive(Debug, Args)]
pub struct LearnArgs {
    /// The product whose labelled inspections are learned from (name in --kb, or product file).
    #[arg(long)]
    pub product: String,
    /// Knowledge-base folder to start from [default: the shipped example].
    #[arg(long, value_name = "DIR")]
    pub kb: Option<PathBuf>,
    /// History database [default: $STRIPE3D_DB, else ~/.local/share/stripe3d/history.sqlite].
    #[arg(long, value_name = "FILE")]
    pub db: Option<PathBuf>,
    /// Folder of the new knowledge-base version (must not exist).
    #[arg(long)]
    pub out: PathBuf,
}

fn kind_arg(k: Option<&str>) -> Result<Option<DefectKind>> {
    k.map(|k| {
        DefectKind::from_name(k).with_context(|| {
            format!(
                "--kind {k}: not a kind ({})",
                DefectKind::ALL.map(|k| k.name()).join(", ")
            )
        })
    })
    .transpose()
}

/// Runs `stripe3d feedback`.
pub fn run_feedback(a: &FeedbackArgs) -> Result<()> {
    let kind = kind_arg(a.kind.as_deref())?;
    let (judgement, defect_id, at_mm) = match (a.confirm, a.false_alarm, &a.missed, a.reviewed) {
        (Some(n), None, None, false) => (Judgement::Confirmed, Some(n), None),
        (None, Some(n), None, false) => {
            if kind.is_some() || a.cause.is_some() {
                bail!("--false-alarm {n}: a false alarm has no --kind or --cause");
            }
            (Judgement::FalseAlarm, Some(n), None)
        }
        (None, None, Some(xy), false) => {
            let parsed: Option<[f64; 2]> = xy
                .split_once(',')
                .and_then(|(x, y)| Some([x.trim().parse().ok()?, y.trim().parse().ok()?]))
                .filter(|p: &[f64; 2]| p.iter().all(|v| v.is_finite()));
            let Some(p) = parsed else {
                bail!("--missed {xy}: give the place as X,Y in mm, e.g. --missed 12.5,-3");
            };
            if kind.is_none() {
                bail!(
                    "--missed {xy}: say what was missed with --kind (bump, dent, hole, scratch, edge-chip)"
                );
            }
            (Judgement::Missed, None, Some(p))
        }
        (None, None, None, true) => (Judgement::Reviewed, None, None),
        _ => bail!("give one of --confirm N, --false-alarm N, --missed X,Y or --reviewed"),
    };
    let path = a.db.clone().unwrap_or_else(default_path);
    if !path.is_file() {
        bail!(
            "{}: no history there (inspections are recorded by `stripe3d inspect`; give --db FILE for another one)",
            path.display()
        );
    }
    let mut h = History::open(&path)?;
    let id = h.add_feedback(&Feedback {
        inspection: a.inspection,
        judgement,
        defect_id,
        kind,
        at_mm,
        cause: a.cause.clone(),
        operator: a.operator.clone(),
        note: a.note.clone(),
    })?;
    say!(
        "recorded feedback {id} on inspection {}: {}{}{} in {}",
        a.inspection,
        judgement.name(),
        defect_id
            .map(|n| format!(" defect {n}"))
            .unwrap_or_default(),
        kind.map(|k| format!(" ({})", k.name())).unwrap_or_default(),
        path.display()
    );
    Ok(())
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Runs `stripe3d history`.
pub fn run_history(a: &HistoryArgs) -> Result<()> {
    let path = a.db.clone().unwrap_or_else(default_path);
    if !path.exists() {
        bail!(
            "{}: no history yet (inspections are recorded by `stripe3d inspect`; give --db FILE for another one)",
            path.display()
        );
    }
    if let Some(t) = &a.since {
        // UTC times are stored as 2026-11-23T14:05:00Z and compared as text: accept a prefix of that form only.
        let pattern = "dddd-dd-ddTdd:dd:ddZ";
        let ok = t.len() >= 4
            && t.len() <= pattern.len()
            && t.chars().zip(pattern.chars()).all(|(c, p)| match p {
                'd' => c.is_ascii_digit(),
                _ => c == p,
            });
        if !ok {
            bail!("--since {t}: give a UTC time as 2026-11-23, 2026-11-23T14 or 2026-11-23T14:05");
        }
    }
    let h = History::open(&path)?;
    let rows = h.list(&Filter {
        product: a.product.clone(),
        verdict: a.verdict.clone(),
        part_id: a.part.clone(),
        since: a.since.clone(),
        limit: a.limit,
    })?;
    let top = |r: &stripe3d_io::history::InspectionRow| {
        r.diagnosis
            .first()
            .map(|(c, v)| format!("{c} ({v:.2})"))
            .unwrap_or_default()
    };
    // Buffered, and every write checked: a history can be long, and a reader that stops early (`| head`) ends
    // the listing quietly (main) instead of a panic in `println!`.
    let stdout = std::io::stdout();
    let mut w = std::io::BufWriter::new(stdout.lock());
    match a.format {
        Format::Table => {
            writeln!(
                w,
                "{:>5}  {:<20}  {:<22}  {:<14}  {:<10}  {:>7}  {:<28}  {:>8}",
                "id",
                "time (UTC)",
                "part",
                "product",
                "verdict",
                "defects",
                "probable cause",
                "feedback"
            )?;
            for r in &rows {
                writeln!(
                    w,
                    "{:>5}  {:<20}  {:<22}  {:<14}  {:<10}  {:>7}  {:<28}  {:>8}",
                    r.id,
                    r.time_utc,
                    r.part_id,
                    r.product.as_deref().unwrap_or("-"),
                    r.verdict,
                    r.defects,
                    top(r),
                    r.feedback
                )?;
            }
            writeln!(w, "{} inspection(s) in {}", rows.len(), path.display())?;
        }
        Format::Csv => {
            writeln!(
                w,
                "id,time_utc,part_id,product,method,kb_version,verdict,defects,top_cause,top_certainty,feedback,report_dir"
            )?;
            for r in &rows {
                let (c, v) = r.diagnosis.first().cloned().unwrap_or_default();
                writeln!(
                    w,
                    "{},{},{},{},{},{},{},{},{},{},{},{}",
                    r.id,
                    r.time_utc,
                    csv_field(&r.part_id),
                    csv_field(r.product.as_deref().unwrap_or("")),
                    csv_field(r.method.as_deref().unwrap_or("")),
                    r.kb_version.map(|v| v.to_string()).unwrap_or_default(),
                    r.verdict,
                    r.defects,
                    csv_field(&c),
                    if c.is_empty() {
                        String::new()
                    } else {
                        format!("{v:.3}")
                    },
                    r.feedback,
                    csv_field(r.report_dir.as_deref().unwrap_or(""))
                )?;
            }
        }
        Format::Json => {
            let v: Vec<_> = rows
                .iter()
                .map(|r| {
                    json!({
                        "id": r.id, "time_utc": r.time_utc, "part_id": r.part_id, "product": r.product,
                        "method": r.method, "kb_version": r.kb_version, "verdict": r.verdict, "defects": r.defects,
                        "diagnosis": r.diagnosis.iter().map(|(c, v)| json!({"cause": c, "certainty": v})).collect::<Vec<_>>(),
                        "feedback": r.feedback, "report_dir": r.report_dir,
                    })
                })
                .collect();
            writeln!(w, "{}", serde_json::to_string_pretty(&v)?)?;
        }
    }
    w.flush()?;
    drop(w);
    if a.diagnose {
        let parts: Vec<Vec<stripe3d_kb::CauseCertainty>> = rows
            .iter()
            .filter(|r| r.product.is_some())
            .map(|r| {
                r.diagnosis
                    .iter()
                    .map(|(c, v)| stripe3d_kb::CauseCertainty {
                        cause: c.clone(),
                        process: String::new(),
                        certainty: *v,
                        remedy: String::new(),
                    })
                    .collect()
            })
            .collect();
        let ranked = stripe3d_kb::reason::diagnose_batch(&parts);
        eprintln!("batch diagnosis over {} inspection(s):", parts.len());
        if ranked.is_empty() {
            eprintln!("  no cause: no defects with a known cause");
        }
        for (c, top_share) in ranked {
            eprintln!(
                "  {:<24} mean certainty {:.2}, the most probable cause on {:.0}% of the parts",
                c.cause,
                c.certainty,
                100.0 * top_share
            );
        }
    }
    Ok(())
}

/// What learning produced.
pub struct Learned {
    /// The new version.
    pub kb: KnowledgeBase,
    /// The rule tuning.
    pub tuning: TuneReport,
    /// Parts learned from.
    pub parts: usize,
    /// Readable changes.
    pub changes: Vec<String>,
}

/// Learns a new knowledge-base version for `ctx`'s product from the labelled inspections in `history`.
pub fn learn_from_history(ctx: &ProductContext, history: &History) -> Result<Learned> {
    let (_, _, method) = ctx.kb.product_context(&ctx.name)?;
    let method = method.clone();
    let parts = history.labelled(&ctx.name)?;
    if parts.len() < MIN_LABELLED_PARTS {
        bail!(
            "product `{}` has {} inspection(s) with feedback in {}; learning needs at least {MIN_LABELLED_PARTS} \
             (record judgements with `stripe3d feedback`)",
            ctx.name,
            parts.len(),
            history.path().display()
        );
    }
    let (mut data, mut missed) = (Vec::new(), 0);
    let mut kinds: BTreeMap<String, u64> = BTreeMap::new();
    for p in &parts {
        let (l, m) = label_by_position(&p.candidates, &p.marks);
        data.extend(l);
        missed += m;
        for k in p.marks.iter().filter_map(|m| m.kind) {
            *kinds.entry(k.name().to_string()).or_default() += 1;
        }
    }
    let rules = ctx.kb.surface_rules(&method)?;
    let (engine, tuning) = tune_rules(&rules, &method.surface.detect_params(), &data, missed)?;
    let mut kb = ctx.kb.clone();
    let old = kb.manifest.version;
    kb.manifest.parent = Some(old);
    kb.manifest.version = old + 1;
    let mut changes = Vec::new();
    if !tuning.changes.is_empty() {
        // Rules learned from this product's parts change this product's inspection only: a method other products
        // share is copied for it.
        let shared = kb
            .products
            .values()
            .any(|p| p.name != ctx.name && p.method == method.name);
        let target = if shared {
            format!("{}-{}", method.name, ctx.name)
        } else {
            method.name.clone()
        };
        let path = format!("rules/{target}-v{}.fll", old + 1);
        kb.rules
            .insert(path.clone(), stripe3d_fuzzy::fll::write(&engine));
        let mut m = kb
            .methods
            .get(&target)
            .cloned()
            .unwrap_or_else(|| method.clone());
        if shared && m.name != target {
            m.name = target.clone();
            m.description = format!("{} (rules learned for {})", method.description, ctx.name);
            changes.push(format!(
                "product `{}`: method `{}` (shared with other products) copied as `{target}`",
                ctx.name, method.name
            ));
        }
        m.surface.rules = Some(path.clone());
        kb.methods.insert(target.clone(), m);
        if let Some(p) = kb.products.get_mut(&ctx.name) {
            p.method = target.clone();
        }
        changes.push(format!(
            "method `{}`: surface rules tuned on {} labelled parts ({} candidates): F1 {:.3} -> {:.3}; now {path}",
            target,
            parts.len(),
            data.len(),
            tuning.before.f1(),
            tuning.after.f1()
        ));
        for c in &tuning.changes {
            changes.push(format!(
                "  {} parameter {}: {:.4} -> {:.4}",
                c.term, c.index, c.before, c.after
            ));
        }
    }
    let causes = history.confirmed_causes()?;
    changes.extend(update_priors(&mut kb, &causes));
    kb.statistics.product.insert(
        ctx.name.clone(),
        ProductStatistics {
            labelled_parts: parts.len() as u64,
            kinds,
            causes: causes.get(&ctx.name).cloned().unwrap_or_default(),
        },
    );
    kb.manifest.changes = changes.clone();
    kb.validate()?;
    Ok(Learned {
        kb,
        tuning,
        parts: parts.len(),
        changes,
    })
}

/// Runs `stripe3d learn`.
pub fn run_learn(a: &LearnArgs) -> Result<()> {
    if a.out.exists() {
        bail!(
            "--out {}: exists already; a knowledge-base version is never overwritten, choose a new folder",
            a.out.display()
        );
    }
    let Some(ctx) = load_product(Some(&a.product), a.kb.as_deref())? else {
        bail!("--product is required");
    };
    let path = a.db.clone().unwrap_or_else(default_path);
    if !path.exists() {
        bail!(
            "{}: no history to learn from (give --db FILE)",
            path.display()
        );
    }
    let history = History::open(&path)?;
    let learned = learn_from_history(&ctx, &history)?;
    let t = &learned.tuning;
    say!(
        "learned from {} labelled part(s) of `{}`: defect F1 on them {:.3} -> {:.3} (true {} -> {}, false {} -> {}, \
         missed {} -> {}; {} evaluations)",
        learned.parts,
        ctx.name,
        t.before.f1(),
        t.after.f1(),
        t.before.true_positive,
        t.after.true_positive,
        t.before.false_positive,
        t.after.false_positive,
        t.before.false_negative,
        t.after.false_negative,
        t.evaluations
    );
    if learned.changes.is_empty() {
        say!("nothing to change: no new version written");
        return Ok(());
    }
    for c in &learned.changes {
        say!("  {c}");
    }
    write_kb(&a.out, &learned.kb)?;
    say!(
        "wrote knowledge base v{} to {} (v{} untouched); inspect with --kb {}; `stripe3d kb diff` shows the changes",
        learned.kb.manifest.version,
        a.out.display(),
        ctx.kb.manifest.version,
        a.out.display()
    );
    Ok(())
}

fn kb_arg(v: &str) -> Result<KnowledgeBase> {
    if v == "shipped" {
        Ok(stripe3d_kb::shipped()?)
    } else {
        Ok(read_kb(Path::new(v))?)
    }
}

/// Runs `stripe3d kb ...`.
pub fn run_kb(cmd: &KbCommand) -> Result<()> {
    match cmd {
        KbCommand::Check {
            product,
            kb,
            format,
            strict,
        } => {
            let Some(ctx) = load_product(Some(product), kb.as_deref())? else {
                bail!("give a product");
            };
            let (fig, findings) = check_product(&ctx.kb, &ctx.name)?;
            if *format == Format::Json {
                say!(
                    "{}",
                    serde_json::to_string_pretty(
                        &json!({"product": ctx.name, "sensor": fig, "findings": findings})
                    )?
                );
            } else {
                say!(
                    "product `{}`: sensor resolves {:.3} mm across x {:.3} mm along; {:.3} mm of height per pixel, \
                     height noise {:.4} mm; view {:.1} mm across",
                    ctx.name,
                    fig.lateral_across_mm,
                    fig.lateral_along_mm,
                    fig.depth_per_px_mm,
                    fig.depth_noise_mm,
                    fig.view_width_mm
                );
                if findings.is_empty() {
                    say!("no problems anticipated");
                }
                for f in &findings {
                    say!("{:<8} {}: {}", f.severity.name(), f.subject, f.message);
                }
            }
            if *strict
                && findings
                    .iter()
                    .any(|f| f.severity == stripe3d_kb::check::Severity::Problem)
            {
                bail!("problems found (--strict)");
            }
            Ok(())
        }
        KbCommand::Diff { old, new } => {
            let a = kb_arg(old).with_context(|| format!("reading {old}"))?;
            let b = kb_arg(new).with_context(|| format!("reading {new}"))?;
            let lines = stripe3d_kb::diff::diff(&a, &b);
            if lines.is_empty() {
                say!("no differences");
            }
            for l in lines {
                say!("{l}");
            }
            Ok(())
        }
        KbCommand::Init { dir } => {
            if dir.exists() {
                bail!("{}: exists already; give a new folder", dir.display());
            }
            let files: Vec<SourceFile> = stripe3d_kb::SHIPPED_FILES
                .iter()
                .map(|(p, t)| SourceFile {
                    path: (*p).into(),
                    text: (*t).into(),
                })
                .collect();
            for f in &files {
                let p = dir.join(&f.path);
                if let Some(parent) = p.parent() {
                    std::fs::create_dir_all(parent)
                        .with_context(|| format!("{}: cannot create", parent.display()))?;
                }
                stripe3d_io::write_atomic(&p, f.text.as_bytes())?;
            }
            read_kb(dir)?;
            say!(
                "wrote the worked example ({} files) to {}; edit it, check it with `stripe3d kb show --kb {}`",
                files.len(),
                dir.display(),
                dir.display()
            );
            Ok(())
        }
        KbCommand::Show { kb } => {
            let k = match kb {
                Some(d) => read_kb(d)?,
                None => stripe3d_kb::shipped()?,
            };
            say!(
                "knowledge base `{}` version {}{}: valid",
                k.manifest.name,
                k.manifest.version,
                k.manifest
                    .parent
                    .map(|p| format!(" (learned from v{p})"))
                    .unwrap_or_default()
            );
            for (n, p) in &k.products {
                say!(
                    "  product {n}: {} — process {}, method {}, {} designed feature(s), {} zone(s)",
                    p.description,
                    p.process,
                    p.method,
                    p.features.len(),
                    p.zones.len()
                );
            }
            for (n, p) in &k.processes {
                say!(
                    "  process {n}: {} cause(s): {}",
                    p.causes.len(),
                    p.causes
                        .iter()
                        .map(|c| format!("{} ({})", c.name, c.prior))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
            for (n, m) in &k.methods {
                say!(
                    "  method {n}: {:?} reference, {} estimator, threshold {} mm, rules {}, {} standard(s)",
                    m.surface.reference,
                    m.scan.extraction,
                    m.surface.threshold_mm,
                    m.surface.rules.as_deref().unwrap_or("shipped"),
                    m.standards.len()
                );
            }
            for c in &k.manifest.changes {
                say!("  change: {c}");
            }
            Ok(())
        }
    }
}
