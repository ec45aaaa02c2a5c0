//! The knowledge files: what they hold, how they are read from TOML text, and every check that keeps a
//! contradictory or incomplete knowledge base from producing a silently wrong verdict.
//!
//! A knowledge base is a folder (the reading itself is `stripe3d-io`'s job; this module takes the texts):
//!
//! ```text
//! kb.toml                 name, version (1, 2, ... : learning writes a new folder, never over an old one), parent
//! products/NAME.toml      a product: geometry, designed features, material, tolerances, zones, process, method
//! processes/NAME.toml     a manufacturing process: capability, the defects it produces, their causes
//! methods/NAME.toml       an inspection method: sensor, scan, surface rules and parameters, decision standards
//! rules/NAME.fll          surface rule bases a method names (the fuzzy crate's FLL)
//! statistics.toml         what learning counted (optional)
//! ```

use crate::KbError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use stripe3d_core::Sensor;
use stripe3d_core::detect::{DefectKind, DetectParams, SurfaceRules};
use stripe3d_core::extract::Method as Estimator;

/// Largest knowledge file accepted, bytes (a guard against a mistaken path to a huge file).
pub const MAX_FILE_BYTES: usize = 1 << 20;
/// Most files in one knowledge base.
pub const MAX_FILES: usize = 1000;

/// One file of a knowledge base: its path relative to the knowledge base's folder and its text.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceFile {
    /// Relative path with `/` separators (`products/cover-plate.toml`).
    pub path: String,
    /// Contents.
    pub text: String,
}

/// `kb.toml`: the knowledge base's identity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Name shown in reports.
    pub name: String,
    /// Version, from 1; learning writes version n + 1 into a new folder.
    pub version: u32,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// The version this one was learned from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<u32>,
    /// What changed from the parent (written by learning).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub changes: Vec<String>,
}

/// Reflectance and gloss of a product's surface (for exposure and design checks).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Name.
    pub name: String,
    /// Diffuse reflectance, 0 to 1.
    pub reflectance: f64,
    /// Specular share, 0 (matte) to 1 (mirror).
    #[serde(default)]
    pub gloss: f64,
}

/// Nominal outline and thickness of a plate-like product.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// Extent along x (conveyor travel), mm.
    pub length_mm: f64,
    /// Extent along y, mm.
    pub width_mm: f64,
    /// Thickness (height of the top surface above the belt), mm.
    pub thickness_mm: f64,
}

/// Kinds of designed feature.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeatureKind {
    /// A through-hole the product is meant to have.
    Hole,
    /// A cylindrical boss standing on the surface.
    Boss,
}

/// A feature the product is designed to have (never a defect). Positions are in the product frame: x along travel,
/// y across, origin at the centre of the part's outline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignedFeature {
    /// Name in reports.
    pub name: String,
    /// Kind.
    pub kind: FeatureKind,
    /// Centre x, mm.
    pub x_mm: f64,
    /// Centre y, mm.
    pub y_mm: f64,
    /// Diameter, mm.
    pub diameter_mm: f64,
    /// Height (boss) or depth (hole; default: through the part), mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height_mm: Option<f64>,
    /// Allowed deviation of the measured diameter, mm (unchecked when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diameter_tolerance_mm: Option<f64>,
}

/// Tolerances of the whole part.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tolerances {
    /// Allowed ± deviation of the thickness, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness_mm: Option<f64>,
    /// Allowed flatness (peak to valley of the top surface about its plane), mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flatness_mm: Option<f64>,
}

/// A rectangular zone of the product with its own limits (product frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Zone {
    /// Name used by standards and reports.
    pub name: String,
    /// Corner x, mm.
    pub x0_mm: f64,
    /// Corner y, mm.
    pub y0_mm: f64,
    /// Opposite corner x, mm.
    pub x1_mm: f64,
    /// Opposite corner y, mm.
    pub y1_mm: f64,
    /// Any defect deeper (or higher) than this in the zone rejects the part, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_depth_mm: Option<f64>,
    /// Any defect larger than this in the zone rejects the part, mm².
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_area_mm2: Option<f64>,
}

impl Zone {
    /// Whether (x, y) lies in the zone.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0_mm && x <= self.x1_mm && y >= self.y0_mm && y <= self.y1_mm
    }
}

/// A product.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Product {
    /// Name (also the file's stem).
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// The process that makes it (a name in `processes/`).
    pub process: String,
    /// The inspection method (a name in `methods/`).
    pub method: String,
    /// Material.
    pub material: Material,
    /// Nominal geometry.
    pub geometry: Geometry,
    /// Tolerances.
    #[serde(default)]
    pub tolerances: Tolerances,
    /// Designed features.
    #[serde(default, rename = "feature", skip_serializing_if = "Vec::is_empty")]
    pub features: Vec<DesignedFeature>,
    /// Zones with their own limits; they must not overlap.
    #[serde(default, rename = "zone", skip_serializing_if = "Vec::is_empty")]
    pub zones: Vec<Zone>,
}

/// What a process can hold (3 sigma).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Capability {
    /// Thickness, ± mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thickness_mm: Option<f64>,
    /// Flatness, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flatness_mm: Option<f64>,
    /// Smallest feature it makes reliably, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smallest_feature_mm: Option<f64>,
}

/// A defect kind a process tends to produce, with its typical size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessDefect {
    /// Kind (`dent`, `hole`, ...).
    pub kind: String,
    /// Typical diameter range, mm.
    pub typical_diameter_mm: [f64; 2],
    /// Typical depth (or height) range, mm.
    pub typical_depth_mm: [f64; 2],
}

/// Numbers known about one defect of a part (what cause evidence and standards test).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Measure {
    /// Equivalent diameter (of the footprint area), mm.
    DiameterMm,
    /// Depth or height, mm.
    DepthMm,
    /// Footprint area, mm².
    AreaMm2,
    /// Volume, mm³.
    VolumeMm3,
    /// Length over width.
    Elongation,
    /// Distance from the defect's centre to the part's outline, mm.
    EdgeDistanceMm,
    /// Defects of the same kind on the part.
    Count,
    /// Share of the product's recent parts with a defect of the same kind within 2 mm of this one (history).
    Recurrence,
    /// The rules' certainty of the kind.
    Confidence,
}

impl Measure {
    /// Name in knowledge files and traces.
    pub fn name(self) -> &'static str {
        match self {
            Measure::DiameterMm => "diameter_mm",
            Measure::DepthMm => "depth_mm",
            Measure::AreaMm2 => "area_mm2",
            Measure::VolumeMm3 => "volume_mm3",
            Measure::Elongation => "elongation",
            Measure::EdgeDistanceMm => "edge_distance_mm",
            Measure::Count => "count",
            Measure::Recurrence => "recurrence",
            Measure::Confidence => "confidence",
        }
    }
}

/// One piece of evidence for (positive `cf`) or against (negative) a cause: it fires when the measure lies within
/// [`at_least`, `at_most`] (either may be absent).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CauseEvidence {
    /// What is measured.
    pub measure: Measure,
    /// Lower bound (inclusive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_least: Option<f64>,
    /// Upper bound (inclusive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_most: Option<f64>,
    /// Certainty factor it adds, −1 to 1 (MYCIN combination).
    pub cf: f64,
}

impl CauseEvidence {
    /// Whether it fires for `value`.
    pub fn fires(&self, value: f64) -> bool {
        value.is_finite()
            && self.at_least.is_none_or(|a| value >= a)
            && self.at_most.is_none_or(|b| value <= b)
    }
}

/// A probable cause of defects of a process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cause {
    /// Name (`die-debris`).
    pub name: String,
    /// What happens.
    #[serde(default)]
    pub description: String,
    /// What to do about it.
    #[serde(default)]
    pub remedy: String,
    /// Defect kinds it produces.
    pub kinds: Vec<String>,
    /// Certainty before any evidence, 0 to 1 (learning updates it from confirmed causes).
    pub prior: f64,
    /// Evidence rules.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub evidence: Vec<CauseEvidence>,
}

/// A manufacturing process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Process {
    /// Name (also the file's stem).
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// What it holds.
    #[serde(default)]
    pub capability: Capability,
    /// Defect kinds it produces.
    #[serde(default, rename = "defect", skip_serializing_if = "Vec::is_empty")]
    pub defects: Vec<ProcessDefect>,
    /// Their probable causes.
    #[serde(default, rename = "cause", skip_serializing_if = "Vec::is_empty")]
    pub causes: Vec<Cause>,
}

/// Scan parameters of a method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanSettings {
    /// Stripe-centre estimator (`stripe3d extract --method` names).
    #[serde(default = "default_extraction")]
    pub extraction: String,
    /// Range-image cell size, mm (default: one pixel on the belt).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid_mm: Option<f64>,
}

fn default_extraction() -> String {
    "steger".into()
}

impl Default for ScanSettings {
    fn default() -> Self {
        Self {
            extraction: default_extraction(),
            grid_mm: None,
        }
    }
}

/// How the reference surface is obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ReferenceKind {
    /// A plane fitted to the part's top surface.
    Plane,
    /// A quadratic fitted to it.
    Quadratic,
    /// A golden scan (`inspect --reference`).
    Golden,
}

/// Surface characterization and detection settings of a method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceSettings {
    /// Reference surface.
    #[serde(default = "default_reference")]
    pub reference: ReferenceKind,
    /// Surface rule base, relative to the knowledge base (default: the shipped `rules/surface.fll` of stripe3d).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rules: Option<String>,
    /// Deviation that starts a defect, mm.
    #[serde(default = "default_threshold")]
    pub threshold_mm: f64,
    /// Certainty below which a candidate is an anomaly.
    #[serde(default = "default_min_confidence")]
    pub min_confidence: f64,
    /// Least share of the outline that must hold data for a verdict other than `incomplete`.
    #[serde(default = "default_min_coverage")]
    pub min_coverage: f64,
}

fn default_reference() -> ReferenceKind {
    ReferenceKind::Plane
}
fn default_threshold() -> f64 {
    DetectParams::default().seed_mm
}
fn default_min_confidence() -> f64 {
    DetectParams::default().min_confidence
}
fn default_min_coverage() -> f64 {
    0.9
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            reference: default_reference(),
            rules: None,
            threshold_mm: default_threshold(),
            min_confidence: default_min_confidence(),
            min_coverage: default_min_coverage(),
        }
    }
}

impl SurfaceSettings {
    /// The fitted reference's shape (None: a golden scan is needed).
    pub fn fitted_shape(&self) -> Option<stripe3d_core::characterize::ReferenceShape> {
        use stripe3d_core::characterize::ReferenceShape;
        match self.reference {
            ReferenceKind::Plane => Some(ReferenceShape::Plane),
            ReferenceKind::Quadratic => Some(ReferenceShape::Quadratic),
            ReferenceKind::Golden => None,
        }
    }

    /// Detection parameters of these settings.
    pub fn detect_params(&self) -> DetectParams {
        DetectParams {
            seed_mm: self.threshold_mm,
            // Growth at 40% of the seed, as `stripe3d inspect --threshold-mm`.
            grow_mm: 0.4 * self.threshold_mm,
            min_confidence: self.min_confidence,
            ..DetectParams::default()
        }
    }
}

/// What a part's inspection can conclude, from best to worst.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Decision {
    /// Good.
    Accept,
    /// No defect that matters found, but the scan did not see enough of the part.
    Incomplete,
    /// Repairable.
    Rework,
    /// Scrap.
    Reject,
}

impl Decision {
    /// Name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Decision::Accept => "accept",
            Decision::Incomplete => "incomplete",
            Decision::Rework => "rework",
            Decision::Reject => "reject",
        }
    }
}

/// A decision standard: a defect of `kind` (or `any`), in `zone` (or anywhere), whose `measure` exceeds `above`
/// (or any such defect, without a measure) leads to `decision`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Standard {
    /// Defect kind or `any`.
    pub kind: String,
    /// Zone name of the product (anywhere when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zone: Option<String>,
    /// What is compared.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measure: Option<Measure>,
    /// Limit: the standard fires when the measure is greater.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub above: Option<f64>,
    /// What follows (`accept` documents that such defects are tolerated).
    pub decision: Decision,
}

/// An inspection method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Method {
    /// Name (also the file's stem).
    pub name: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// The sensor set-up (the fields of `sensor.toml`; default: the paper's set-up).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor: Option<Sensor>,
    /// Scan parameters.
    #[serde(default)]
    pub scan: ScanSettings,
    /// Surface and detection parameters.
    #[serde(default)]
    pub surface: SurfaceSettings,
    /// Decision standards, all evaluated; the worst decision wins.
    #[serde(default, rename = "standard", skip_serializing_if = "Vec::is_empty")]
    pub standards: Vec<Standard>,
}

impl Method {
    /// The sensor set-up (the paper's when the method names none).
    pub fn sensor(&self) -> Sensor {
        self.sensor.clone().unwrap_or_default()
    }
}

/// Defect counts learning found per product (`statistics.toml`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Statistics {
    /// Per product: inspected parts, and confirmed defects per kind and causes.
    #[serde(default)]
    pub product: BTreeMap<String, ProductStatistics>,
}

/// Counts for one product.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProductStatistics {
    /// Parts with operator feedback.
    pub labelled_parts: u64,
    /// Confirmed defects per kind.
    #[serde(default)]
    pub kinds: BTreeMap<String, u64>,
    /// Confirmed causes.
    #[serde(default)]
    pub causes: BTreeMap<String, u64>,
}

/// A whole knowledge base, validated.
#[derive(Debug, Clone)]
pub struct KnowledgeBase {
    /// Identity.
    pub manifest: Manifest,
    /// Products by name.
    pub products: BTreeMap<String, Product>,
    /// Processes by name.
    pub processes: BTreeMap<String, Process>,
    /// Methods by name.
    pub methods: BTreeMap<String, Method>,
    /// Rule bases by relative path.
    pub rules: BTreeMap<String, String>,
    /// Learned statistics.
    pub statistics: Statistics,
    /// Which file each entry came from (`product:NAME` etc.), for messages.
    pub origin: BTreeMap<String, String>,
}

fn parse<T: for<'de> Deserialize<'de>>(file: &SourceFile) -> Result<T, KbError> {
    toml::from_str(&file.text).map_err(|e| KbError::Parse {
        file: file.path.clone(),
        message: e.to_string().trim_end().to_string(),
    })
}

fn invalid(file: &str, entry: impl Into<String>, message: impl Into<String>) -> KbError {
    KbError::Invalid {
        file: file.to_string(),
        entry: entry.into(),
        message: message.into(),
    }
}

/// Checks that `v` is finite and `ok`.
fn need(file: &str, entry: &str, v: f64, ok: bool, what: &str) -> Result<(), KbError> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(invalid(file, entry, format!("{v}: {what}")))
    }
}

fn known_kind(kind: &str) -> bool {
    DefectKind::from_name(kind).is_some()
}

fn kinds_list() -> String {
    DefectKind::ALL
        .iter()
        .map(|k| k.name())
        .collect::<Vec<_>>()
        .join(", ")
}

impl KnowledgeBase {
    /// Reads and validates a knowledge base from its files (see the module docs for the layout). Files outside the
    /// layout are refused, so a misplaced file is not silently ignored.
    pub fn from_files(files: &[SourceFile]) -> Result<Self, KbError> {
        if files.len() > MAX_FILES {
            return Err(invalid(
                "kb.toml",
                "files",
                format!("{} files: at most {MAX_FILES}", files.len()),
            ));
        }
        let mut manifest = None;
        let mut kb = KnowledgeBase {
            manifest: Manifest {
                name: String::new(),
                version: 0,
                description: String::new(),
                parent: None,
                changes: vec![],
            },
            products: BTreeMap::new(),
            processes: BTreeMap::new(),
            methods: BTreeMap::new(),
            rules: BTreeMap::new(),
            statistics: Statistics::default(),
            origin: BTreeMap::new(),
        };
        for f in files {
            if f.text.len() > MAX_FILE_BYTES {
                return Err(invalid(
                    &f.path,
                    "file",
                    format!(
                        "{} bytes: knowledge files are at most {MAX_FILE_BYTES}",
                        f.text.len()
                    ),
                ));
            }
            let p = f.path.as_str();
            let stem = |dir: &str, ext: &str| -> Option<&str> {
                p.strip_prefix(dir)?
                    .strip_suffix(ext)
                    .filter(|s| !s.contains('/'))
            };
            if p == "kb.toml" {
                manifest = Some(parse::<Manifest>(f)?);
            } else if p == "statistics.toml" {
                kb.statistics = parse(f)?;
            } else if let Some(s) = stem("products/", ".toml") {
                let v: Product = parse(f)?;
                kb.add_named("product", s, &v.name.clone(), p)?;
                kb.products.insert(v.name.clone(), v);
            } else if let Some(s) = stem("processes/", ".toml") {
                let v: Process = parse(f)?;
                kb.add_named("process", s, &v.name.clone(), p)?;
                kb.processes.insert(v.name.clone(), v);
            } else if let Some(s) = stem("methods/", ".toml") {
                let v: Method = parse(f)?;
                kb.add_named("method", s, &v.name.clone(), p)?;
                kb.methods.insert(v.name.clone(), v);
            } else if p.ends_with(".fll") {
                kb.rules.insert(p.to_string(), f.text.clone());
            } else {
                return Err(invalid(
                    p,
                    "file",
                    "not part of a knowledge base (kb.toml, statistics.toml, products/*.toml, processes/*.toml, \
                     methods/*.toml, *.fll): move or remove it",
                ));
            }
        }
        kb.manifest = manifest.ok_or_else(|| {
            invalid(
                "kb.toml",
                "file",
                "missing: every knowledge base has a kb.toml",
            )
        })?;
        kb.validate()?;
        Ok(kb)
    }

    fn add_named(&mut self, what: &str, stem: &str, name: &str, path: &str) -> Result<(), KbError> {
        if name != stem {
            return Err(invalid(
                path,
                "name",
                format!(
                    "`{name}` differs from the file name `{stem}`: name the file after the {what}"
                ),
            ));
        }
        let key = format!("{what}:{name}");
        if let Some(first) = self.origin.get(&key) {
            return Err(invalid(
                path,
                "name",
                format!("{what} `{name}` is also defined in {first}"),
            ));
        }
        self.origin.insert(key, path.to_string());
        Ok(())
    }

    /// The file an entry came from.
    pub fn file_of(&self, what: &str, name: &str) -> String {
        self.origin
            .get(&format!("{what}:{name}"))
            .cloned()
            .unwrap_or_else(|| format!("{what}s/{name}.toml"))
    }

    /// A product by name, with a message listing the known ones.
    pub fn product(&self, name: &str) -> Result<&Product, KbError> {
        self.products.get(name).ok_or_else(|| KbError::Unknown {
            what: "product",
            name: name.to_string(),
            known: self.products.keys().cloned().collect::<Vec<_>>().join(", "),
        })
    }

    /// The process and method of a product (validated to exist).
    pub fn product_context(&self, name: &str) -> Result<(&Product, &Process, &Method), KbError> {
        let p = self.product(name)?;
        let process = self
            .processes
            .get(&p.process)
            .ok_or_else(|| KbError::Unknown {
                what: "process",
                name: p.process.clone(),
                known: self
                    .processes
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        let method = self
            .methods
            .get(&p.method)
            .ok_or_else(|| KbError::Unknown {
                what: "method",
                name: p.method.clone(),
                known: self.methods.keys().cloned().collect::<Vec<_>>().join(", "),
            })?;
        Ok((p, process, method))
    }

    /// The surface rules a method uses.
    pub fn surface_rules(&self, method: &Method) -> Result<SurfaceRules, KbError> {
        let file = self.file_of("method", &method.name);
        match &method.surface.rules {
            None => {
                SurfaceRules::shipped().map_err(|e| invalid(&file, "surface.rules", e.to_string()))
            }
            Some(path) => {
                let text = self.rules.get(path).ok_or_else(|| {
                    invalid(
                        &file,
                        "surface.rules",
                        format!("`{path}` is not in the knowledge base (give a path relative to its folder)"),
                    )
                })?;
                let engine = stripe3d_fuzzy::fll::read(text)
                    .map_err(|e| invalid(path, "rule base", e.to_string()))?;
                SurfaceRules::from_engine(engine)
                    .map_err(|e| invalid(path, "rule base", e.to_string()))
            }
        }
    }

    /// Every check of the module docs; the first problem found is returned.
    pub fn validate(&self) -> Result<(), KbError> {
        let m = &self.manifest;
        if m.name.trim().is_empty() {
            return Err(invalid(
                "kb.toml",
                "name",
                "empty: give the knowledge base a name",
            ));
        }
        if m.version == 0 {
            return Err(invalid("kb.toml", "version", "0: versions start at 1"));
        }
        if m.parent.is_some_and(|p| p >= m.version) {
            return Err(invalid(
                "kb.toml",
                "parent",
                "must be an older version than `version`",
            ));
        }
        for process in self.processes.values() {
            self.validate_process(process)?;
        }
        for method in self.methods.values() {
            self.validate_method(method)?;
        }
        for product in self.products.values() {
            self.validate_product(product)?;
        }
        Ok(())
    }

    fn validate_process(&self, p: &Process) -> Result<(), KbError> {
        let file = self.file_of("process", &p.name);
        let c = &p.capability;
        for (name, v) in [
            ("capability.thickness_mm", c.thickness_mm),
            ("capability.flatness_mm", c.flatness_mm),
            ("capability.smallest_feature_mm", c.smallest_feature_mm),
        ] {
            if let Some(v) = v {
                need(&file, name, v, v > 0.0, "must be a positive length in mm")?;
            }
        }
        for (i, d) in p.defects.iter().enumerate() {
            let entry = format!("defect[{i}]");
            if !known_kind(&d.kind) {
                return Err(invalid(
                    &file,
                    format!("{entry}.kind"),
                    format!(
                        "`{}` is not a kind stripe3d detects ({})",
                        d.kind,
                        kinds_list()
                    ),
                ));
            }
            for (n, r) in [
                ("typical_diameter_mm", d.typical_diameter_mm),
                ("typical_depth_mm", d.typical_depth_mm),
            ] {
                if !(r[0].is_finite() && r[1].is_finite() && r[0] >= 0.0 && r[0] <= r[1]) {
                    return Err(invalid(
                        &file,
                        format!("{entry}.{n}"),
                        format!(
                            "[{}, {}]: give [low, high] with 0 <= low <= high",
                            r[0], r[1]
                        ),
                    ));
                }
            }
        }
        let mut names = std::collections::BTreeSet::new();
        for (i, c) in p.causes.iter().enumerate() {
            let entry = format!("cause[{i}] `{}`", c.name);
            if !names.insert(c.name.as_str()) {
                return Err(invalid(&file, entry, "the cause is listed twice"));
            }
            if c.kinds.is_empty() {
                return Err(invalid(
                    &file,
                    format!("{entry}.kinds"),
                    "empty: name the defect kinds it produces",
                ));
            }
            for k in &c.kinds {
                if !known_kind(k) {
                    return Err(invalid(
                        &file,
                        format!("{entry}.kinds"),
                        format!("`{k}` is not a kind stripe3d detects ({})", kinds_list()),
                    ));
                }
            }
            need(
                &file,
                &format!("{entry}.prior"),
                c.prior,
                c.prior > 0.0 && c.prior <= 1.0,
                "must be in (0, 1]",
            )?;
            for (j, e) in c.evidence.iter().enumerate() {
                let ee = format!("{entry}.evidence[{j}]");
                need(
                    &file,
                    &format!("{ee}.cf"),
                    e.cf,
                    (-1.0..=1.0).contains(&e.cf) && e.cf != 0.0,
                    "must be in [-1, 1], not 0",
                )?;
                match (e.at_least, e.at_most) {
                    (None, None) => {
                        return Err(invalid(&file, ee, "give at_least, at_most or both"));
                    }
                    (Some(a), Some(b)) if a > b || a.is_nan() || b.is_nan() => {
                        return Err(invalid(
                            &file,
                            ee,
                            format!("at_least {a} > at_most {b}: it can never fire"),
                        ));
                    }
                    (a, b) => {
                        for v in [a, b].into_iter().flatten() {
                            need(&file, &ee, v, true, "bounds must be numbers")?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn validate_method(&self, m: &Method) -> Result<(), KbError> {
        let file = self.file_of("method", &m.name);
        if let Some(s) = &m.sensor {
            s.validate()
                .map_err(|e| invalid(&file, "sensor", e.to_string()))?;
        }
        if Estimator::from_name(&m.scan.extraction).is_none() {
            return Err(invalid(
                &file,
                "scan.extraction",
                format!(
                    "`{}` is not an estimator (see `stripe3d extract --help`)",
                    m.scan.extraction
                ),
            ));
        }
        if let Some(g) = m.scan.grid_mm {
            need(
                &file,
                "scan.grid_mm",
                g,
                (0.005..=5.0).contains(&g),
                "must be 0.005 to 5 mm",
            )?;
        }
        let s = &m.surface;
        need(
            &file,
            "surface.threshold_mm",
            s.threshold_mm,
            s.threshold_mm > 0.0 && s.threshold_mm < 10.0,
            "must be a positive height below 10 mm",
        )?;
        need(
            &file,
            "surface.min_confidence",
            s.min_confidence,
            (0.0..1.0).contains(&s.min_confidence),
            "must be in [0, 1)",
        )?;
        need(
            &file,
            "surface.min_coverage",
            s.min_coverage,
            (0.0..=1.0).contains(&s.min_coverage),
            "must be in [0, 1]",
        )?;
        self.surface_rules(m)?;
        for (i, st) in m.standards.iter().enumerate() {
            let entry = format!("standard[{i}]");
            if st.kind != "any" && !known_kind(&st.kind) {
                return Err(invalid(
                    &file,
                    format!("{entry}.kind"),
                    format!(
                        "`{}` is not a kind stripe3d detects (any, {})",
                        st.kind,
                        kinds_list()
                    ),
                ));
            }
            match (st.measure, st.above) {
                (Some(_), None) | (None, Some(_)) => {
                    return Err(invalid(
                        &file,
                        entry,
                        "give `measure` and `above` together (or neither: any such defect)",
                    ));
                }
                (Some(me), Some(a)) => {
                    if matches!(
                        me,
                        Measure::Recurrence | Measure::Confidence | Measure::EdgeDistanceMm
                    ) {
                        return Err(invalid(
                            &file,
                            format!("{entry}.measure"),
                            format!(
                                "`{}` describes a cause, not a size: standards compare depth_mm, area_mm2, diameter_mm, volume_mm3, elongation or count",
                                me.name()
                            ),
                        ));
                    }
                    need(
                        &file,
                        &format!("{entry}.above"),
                        a,
                        a >= 0.0,
                        "must be >= 0",
                    )?;
                }
                (None, None) => {}
            }
        }
        Ok(())
    }

    fn validate_product(&self, p: &Product) -> Result<(), KbError> {
        let file = self.file_of("product", &p.name);
        if !self.processes.contains_key(&p.process) {
            return Err(invalid(
                &file,
                "process",
                format!(
                    "`{}` is not a process of this knowledge base (known: {})",
                    p.process,
                    self.processes
                        .keys()
                        .cloned()
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        let Some(method) = self.methods.get(&p.method) else {
            return Err(invalid(
                &file,
                "method",
                format!(
                    "`{}` is not a method of this knowledge base (known: {})",
                    p.method,
                    self.methods.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            ));
        };
        let m = &p.material;
        need(
            &file,
            "material.reflectance",
            m.reflectance,
            (0.0..=1.0).contains(&m.reflectance) && m.reflectance > 0.0,
            "must be in (0, 1]",
        )?;
        need(
            &file,
            "material.gloss",
            m.gloss,
            (0.0..=1.0).contains(&m.gloss),
            "must be in [0, 1]",
        )?;
        let g = &p.geometry;
        for (n, v) in [
            ("geometry.length_mm", g.length_mm),
            ("geometry.width_mm", g.width_mm),
            ("geometry.thickness_mm", g.thickness_mm),
        ] {
            need(
                &file,
                n,
                v,
                v > 0.0 && v < 10_000.0,
                "must be a positive length in mm",
            )?;
        }
        for (n, v) in [
            ("tolerances.thickness_mm", p.tolerances.thickness_mm),
            ("tolerances.flatness_mm", p.tolerances.flatness_mm),
        ] {
            if let Some(v) = v {
                need(
                    &file,
                    n,
                    v,
                    v > 0.0,
                    "tolerances must be positive (a negative or zero tolerance admits no part)",
                )?;
            }
        }
        let (hx, hy) = (g.length_mm / 2.0, g.width_mm / 2.0);
        for (i, f) in p.features.iter().enumerate() {
            let entry = format!("feature[{i}] `{}`", f.name);
            need(
                &file,
                &format!("{entry}.diameter_mm"),
                f.diameter_mm,
                f.diameter_mm > 0.0,
                "must be positive",
            )?;
            for (n, v) in [("x_mm", f.x_mm), ("y_mm", f.y_mm)] {
                need(&file, &format!("{entry}.{n}"), v, true, "must be a number")?;
            }
            let r = f.diameter_mm / 2.0;
            if f.x_mm - r < -hx || f.x_mm + r > hx || f.y_mm - r < -hy || f.y_mm + r > hy {
                return Err(invalid(
                    &file,
                    entry,
                    format!(
                        "lies outside the {} x {} mm outline (product frame: origin at the outline's centre)",
                        g.length_mm, g.width_mm
                    ),
                ));
            }
            for (n, v) in [
                ("height_mm", f.height_mm),
                ("diameter_tolerance_mm", f.diameter_tolerance_mm),
            ] {
                if let Some(v) = v {
                    need(
                        &file,
                        &format!("{entry}.{n}"),
                        v,
                        v > 0.0,
                        "must be positive",
                    )?;
                }
            }
        }
        for (i, z) in p.zones.iter().enumerate() {
            let entry = format!("zone[{i}] `{}`", z.name);
            for v in [z.x0_mm, z.y0_mm, z.x1_mm, z.y1_mm] {
                need(&file, &entry, v, true, "corners must be numbers")?;
            }
            if !(z.x0_mm < z.x1_mm && z.y0_mm < z.y1_mm) {
                return Err(invalid(
                    &file,
                    entry,
                    "give x0_mm < x1_mm and y0_mm < y1_mm",
                ));
            }
            for (n, v) in [
                ("max_depth_mm", z.max_depth_mm),
                ("max_area_mm2", z.max_area_mm2),
            ] {
                if let Some(v) = v {
                    need(
                        &file,
                        &format!("{entry}.{n}"),
                        v,
                        v >= 0.0,
                        "limits must be >= 0",
                    )?;
                }
            }
            for (j, o) in p.zones.iter().enumerate().take(i) {
                if o.name == z.name {
                    return Err(invalid(
                        &file,
                        entry,
                        format!("zone[{j}] has the same name"),
                    ));
                }
                if z.x0_mm < o.x1_mm && o.x0_mm < z.x1_mm && z.y0_mm < o.y1_mm && o.y0_mm < z.y1_mm
                {
                    return Err(invalid(
                        &file,
                        entry,
                        format!(
                            "overlaps zone[{j}] `{}`: a defect in both would have two sets of limits",
                            o.name
                        ),
                    ));
                }
            }
        }
        for (i, st) in method.standards.iter().enumerate() {
            if let Some(zone) = &st.zone {
                if !p.zones.iter().any(|z| &z.name == zone) {
                    return Err(invalid(
                        &self.file_of("method", &method.name),
                        format!("standard[{i}].zone"),
                        format!(
                            "`{zone}` is not a zone of product `{}` ({file}), which uses this method",
                            p.name
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}
