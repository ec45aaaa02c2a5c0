//! Scene descriptions: a part on the belt, made of a plate and features, and its rasterisation to a height field.
//!
//! A scene is plain data (it derives `serde` so that `stripe3d-io` can read it from TOML). Every length is in mm,
//! in part coordinates (belt coordinates at frame 0). Features are applied in the order: plate, steps, bosses,
//! bumps, dents, scratches, holes, albedo and gloss patches, printed texture; each later feature works on the surface the earlier ones left.

use crate::SimError;
use crate::heightfield::HeightField;
use serde::{Deserialize, Serialize};

/// Default spacing of the height-field grid, mm. 0.05 mm is a quarter of a pixel's footprint in the paper's set-up.
pub const DEFAULT_GRID_MM: f64 = 0.05;
/// Largest number of grid nodes a scene may rasterise to (memory guard against mistyped sizes).
pub const MAX_GRID_NODES: usize = 40_000_000;
/// Diameters of [`Scene::defect_plate`]'s defects, mm.
pub const RANDOM_DIAMETER_MM: (f64, f64) = (2.0, 10.0);
/// Heights and depths of [`Scene::defect_plate`]'s bumps and dents, mm.
pub const RANDOM_DEPTH_MM: (f64, f64) = (0.1, 1.0);
/// Largest height (or depth) over diameter of [`Scene::defect_plate`]'s bumps and dents.
pub const RANDOM_MAX_SLOPE: f64 = 0.1;
/// Empty belt kept around the part in the grid, mm.
const GRID_MARGIN_MM: f64 = 2.0;

/// A complete scene: the part and the light around it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Name shown in manifests.
    pub name: String,
    /// Spacing of the height-field grid, mm.
    #[serde(default = "default_grid_mm")]
    pub grid_mm: f64,
    /// The conveyor belt's surface.
    #[serde(default)]
    pub belt: Belt,
    /// Ambient light.
    #[serde(default)]
    pub lighting: Lighting,
    /// The base plate of the part, if any.
    #[serde(default)]
    pub plate: Option<Plate>,
    /// Features on and defects in the plate, in application order by kind.
    #[serde(default, rename = "feature")]
    pub features: Vec<Feature>,
}

fn default_grid_mm() -> f64 {
    DEFAULT_GRID_MM
}

/// The belt: a matte plane at z = 0.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Belt {
    /// Diffuse reflectance, 0 to 1.
    pub albedo: f64,
}

impl Default for Belt {
    fn default() -> Self {
        // Dark rubber.
        Self { albedo: 0.25 }
    }
}

/// Ambient light from above.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lighting {
    /// Ambient irradiance relative to a stripe's centre at unit power (0 = dark room).
    pub ambient: f64,
    /// Natural (cos⁴) vignetting of the lens.
    pub vignetting: bool,
}

impl Default for Lighting {
    fn default() -> Self {
        Self {
            ambient: 0.03,
            vignetting: true,
        }
    }
}

/// A rectangular plate, axis-aligned, with an optional 45° chamfer on its top edges.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plate {
    /// Centre x, mm.
    #[serde(default)]
    pub center_x_mm: f64,
    /// Centre y, mm.
    #[serde(default)]
    pub center_y_mm: f64,
    /// Extent along x (conveyor travel), mm.
    pub length_mm: f64,
    /// Extent along y, mm.
    pub width_mm: f64,
    /// Thickness, mm.
    pub thickness_mm: f64,
    /// Width of the 45° chamfer on the top edges, mm.
    #[serde(default)]
    pub chamfer_mm: f64,
    /// Diffuse reflectance, 0 to 1.
    #[serde(default = "default_plate_albedo")]
    pub albedo: f64,
}

fn default_plate_albedo() -> f64 {
    0.6
}

/// One feature of the part.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Feature {
    /// A rectangle of the plate raised (or, negative, lowered) by `height_mm`.
    Step {
        /// Corner x, mm.
        x0_mm: f64,
        /// Corner y, mm.
        y0_mm: f64,
        /// Opposite corner x, mm.
        x1_mm: f64,
        /// Opposite corner y, mm.
        y1_mm: f64,
        /// Height added to the surface, mm.
        height_mm: f64,
    },
    /// A cylinder standing on the surface (a boss), with an optional 45° chamfer on its top edge.
    Boss {
        /// Centre x, mm.
        x_mm: f64,
        /// Centre y, mm.
        y_mm: f64,
        /// Diameter, mm.
        diameter_mm: f64,
        /// Height above the surface at its centre, mm.
        height_mm: f64,
        /// Chamfer width, mm.
        #[serde(default)]
        chamfer_mm: f64,
    },
    /// A smooth bump (raised cosine bell): a defect.
    Bump {
        /// Centre x, mm.
        x_mm: f64,
        /// Centre y, mm.
        y_mm: f64,
        /// Diameter of the footprint, mm.
        diameter_mm: f64,
        /// Peak height, mm.
        height_mm: f64,
    },
    /// A smooth dent (inverted raised cosine bell): a defect.
    Dent {
        /// Centre x, mm.
        x_mm: f64,
        /// Centre y, mm.
        y_mm: f64,
        /// Diameter of the footprint, mm.
        diameter_mm: f64,
        /// Greatest depth, mm.
        depth_mm: f64,
    },
    /// A scratch or gouge: a groove along a segment with a raised-cosine cross-section and rounded ends.
    Scratch {
        /// Start x, mm.
        x0_mm: f64,
        /// Start y, mm.
        y0_mm: f64,
        /// End x, mm.
        x1_mm: f64,
        /// End y, mm.
        y1_mm: f64,
        /// Width of the groove, mm.
        width_mm: f64,
        /// Greatest depth, mm.
        depth_mm: f64,
    },
    /// A through-hole showing the belt: a defect unless `designed`.
    Hole {
        /// Centre x, mm.
        x_mm: f64,
        /// Centre y, mm.
        y_mm: f64,
        /// Diameter, mm.
        diameter_mm: f64,
        /// A hole the product is meant to have (not a defect).
        #[serde(default)]
        designed: bool,
    },
    /// A patch of different diffuse reflectance (print, stain, machining mark).
    Albedo {
        /// Corner x, mm.
        x0_mm: f64,
        /// Corner y, mm.
        y0_mm: f64,
        /// Opposite corner x, mm.
        x1_mm: f64,
        /// Opposite corner y, mm.
        y1_mm: f64,
        /// Diffuse reflectance, 0 to 1.
        albedo: f64,
    },
    /// A glossy patch: `gloss` of the light is reflected specularly (highlights, and ghost stripes where the
    /// mirrored laser sheets land on other surfaces).
    Gloss {
        /// Corner x, mm.
        x0_mm: f64,
        /// Corner y, mm.
        y0_mm: f64,
        /// Opposite corner x, mm.
        x1_mm: f64,
        /// Opposite corner y, mm.
        y1_mm: f64,
        /// Specular fraction, 0 to 1.
        gloss: f64,
    },
    /// Printed texture: the rectangle cut into square cells, each of a diffuse reflectance drawn log-uniformly
    /// between `low` and `high` (a contrast of `high / low`) from a hash of `seed` and the cell.
    Texture {
        /// Corner x, mm.
        x0_mm: f64,
        /// Corner y, mm.
        y0_mm: f64,
        /// Opposite corner x, mm.
        x1_mm: f64,
        /// Opposite corner y, mm.
        y1_mm: f64,
        /// Side of a cell, mm.
        cell_mm: f64,
        /// Darkest reflectance, 0 to 1.
        low: f64,
        /// Brightest reflectance, `low` to 1.
        high: f64,
        /// Seed of the cells' draws.
        #[serde(default)]
        seed: u64,
    },
}

/// The reflectance of texture cell `(i, j)`: log-uniform in `[low, high]` from a hash of the seed and the cell
/// (SplitMix64's finaliser, so that neighbouring cells are independent).
fn texture_albedo(seed: u64, i: i64, j: i64, low: f64, high: f64) -> f64 {
    let mut z = seed
        ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    let t = (z >> 11) as f64 / (1u64 << 53) as f64;
    if low <= 0.0 {
        return low + t * (high - low);
    }
    low * (high / low).powf(t)
}

/// The ground truth of one defect put into the scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DefectTruth {
    /// `bump`, `dent`, `scratch` or `hole`.
    pub kind: String,
    /// Centroid x in part coordinates, mm.
    pub x_mm: f64,
    /// Centroid y in part coordinates, mm.
    pub y_mm: f64,
    /// Footprint diameter, mm.
    pub diameter_mm: f64,
    /// Footprint area, mm².
    pub area_mm2: f64,
    /// Greatest height (bump) or depth (dent, hole: the surface height it removes), mm.
    pub depth_mm: f64,
    /// Volume added or removed, mm³ (summed over the grid).
    pub volume_mm3: f64,
}

/// Raised cosine bell of unit height over a disc of radius `r0`.
fn bell(r: f64, r0: f64) -> f64 {
    if r >= r0 {
        0.0
    } else {
        0.5 * (1.0 + (std::f64::consts::PI * r / r0).cos())
    }
}

fn check(field: String, v: f64, ok: bool, what: &str) -> Result<(), SimError> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(SimError::InvalidScene {
            field,
            reason: format!("{v} {what}"),
        })
    }
}

impl Scene {
    /// The built-in scenes, by name: `demo`, `plate`, `block`, `belt`.
    pub fn builtin(name: &str) -> Option<Scene> {
        match name {
            "demo" => Some(Self::demo()),
            "plate" => Some(Self::flat_plate()),
            "block" => Some(Self::block()),
            "belt" => Some(Self::empty_belt()),
            _ => None,
        }
    }

    /// Names accepted by [`Scene::builtin`].
    pub const BUILTIN_NAMES: [&'static str; 4] = ["demo", "plate", "block", "belt"];

    /// The demo part: an 80 x 60 x 10 mm chamfered plate with a step, a boss, a designed hole, a printed mark, a
    /// glossy patch in front of the boss (which throws a ghost stripe onto it), and one bump, one dent and one
    /// through-hole as defects.
    pub fn demo() -> Scene {
        Scene {
            name: "demo".into(),
            grid_mm: DEFAULT_GRID_MM,
            belt: Belt::default(),
            lighting: Lighting::default(),
            plate: Some(Plate {
                center_x_mm: -5.0,
                center_y_mm: 0.0,
                length_mm: 80.0,
                width_mm: 60.0,
                thickness_mm: 10.0,
                chamfer_mm: 1.0,
                albedo: 0.6,
            }),
            features: vec![
                Feature::Step {
                    x0_mm: -45.0,
                    y0_mm: 12.0,
                    x1_mm: -20.0,
                    y1_mm: 30.0,
                    height_mm: 4.0,
                },
                Feature::Boss {
                    x_mm: 18.0,
                    y_mm: 15.0,
                    diameter_mm: 14.0,
                    height_mm: 8.0,
                    chamfer_mm: 1.0,
                },
                Feature::Hole {
                    x_mm: 20.0,
                    y_mm: -18.0,
                    diameter_mm: 8.0,
                    designed: true,
                },
                Feature::Bump {
                    x_mm: -25.0,
                    y_mm: -10.0,
                    diameter_mm: 6.0,
                    height_mm: 0.6,
                },
                Feature::Dent {
                    x_mm: -3.0,
                    y_mm: -16.0,
                    diameter_mm: 5.0,
                    depth_mm: 0.4,
                },
                Feature::Hole {
                    x_mm: -12.0,
                    y_mm: 8.0,
                    diameter_mm: 3.0,
                    designed: false,
                },
                Feature::Albedo {
                    x0_mm: -40.0,
                    y0_mm: -28.0,
                    x1_mm: -30.0,
                    y1_mm: -22.0,
                    albedo: 0.2,
                },
                Feature::Gloss {
                    x0_mm: -4.0,
                    y0_mm: 9.0,
                    x1_mm: 8.0,
                    y1_mm: 21.0,
                    gloss: 0.35,
                },
            ],
        }
    }

    /// A plain 80 x 60 x 10 mm matte plate.
    pub fn flat_plate() -> Scene {
        Scene {
            name: "plate".into(),
            grid_mm: DEFAULT_GRID_MM,
            belt: Belt::default(),
            lighting: Lighting::default(),
            plate: Some(Plate {
                center_x_mm: 0.0,
                center_y_mm: 0.0,
                length_mm: 80.0,
                width_mm: 60.0,
                thickness_mm: 10.0,
                chamfer_mm: 0.0,
                albedo: 0.6,
            }),
            features: vec![],
        }
    }

    /// A matte plate of `thickness_mm` larger than the paper's field of view (200 x 160 mm), on a 0.5 mm grid (the
    /// plate is flat, so the coarse grid is exact): a calibration target, and the flat part of accuracy tests.
    pub fn covering_plate(thickness_mm: f64) -> Scene {
        Scene {
            name: format!("covering-plate-{thickness_mm}mm"),
            grid_mm: 0.5,
            plate: Some(Plate {
                center_x_mm: 0.0,
                center_y_mm: 0.0,
                length_mm: 200.0,
                width_mm: 160.0,
                thickness_mm,
                chamfer_mm: 0.0,
                albedo: 0.6,
            }),
            ..Scene::flat_plate()
        }
    }

    /// A 30 mm tall 40 x 40 mm block (the absolute-height test piece).
    pub fn block() -> Scene {
        Scene {
            name: "block".into(),
            grid_mm: DEFAULT_GRID_MM,
            belt: Belt::default(),
            lighting: Lighting::default(),
            plate: Some(Plate {
                center_x_mm: 0.0,
                center_y_mm: 0.0,
                length_mm: 40.0,
                width_mm: 40.0,
                thickness_mm: 30.0,
                chamfer_mm: 0.0,
                albedo: 0.6,
            }),
            features: vec![],
        }
    }

    /// The empty belt.
    pub fn empty_belt() -> Scene {
        Scene {
            name: "belt".into(),
            grid_mm: DEFAULT_GRID_MM,
            belt: Belt::default(),
            lighting: Lighting::default(),
            plate: None,
            features: vec![],
        }
    }

    /// The flat 80 x 60 x 10 mm plate with `defects` random bumps, dents and through-holes (a third of each on
    /// average), drawn from `seed`: diameters [`RANDOM_DIAMETER_MM`], bump heights and dent depths
    /// [`RANDOM_DEPTH_MM`] but at most [`RANDOM_MAX_SLOPE`] times the diameter (dents from handling and die debris
    /// are shallow), centres at least 3 mm from the plate's edges and defects at least 3 mm apart. The defect
    /// benchmark and the detection tests inspect these.
    pub fn defect_plate(seed: u64, defects: usize) -> Scene {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut scene = Scene::flat_plate();
        scene.name = format!("defect-plate-{seed}");
        let (hx, hy) = (40.0, 30.0);
        let mut placed: Vec<(f64, f64, f64)> = Vec::new();
        let mut attempts = 0;
        while placed.len() < defects && attempts < 10_000 {
            attempts += 1;
            let d = rng.random_range(RANDOM_DIAMETER_MM.0..=RANDOM_DIAMETER_MM.1);
            let r = d / 2.0;
            let x = rng.random_range(-hx + 3.0 + r..=hx - 3.0 - r);
            let y = rng.random_range(-hy + 3.0 + r..=hy - 3.0 - r);
            if placed
                .iter()
                .any(|&(px, py, pr)| (px - x).hypot(py - y) < pr + r + 3.0)
            {
                continue;
            }
            let depth = rng
                .random_range(RANDOM_DEPTH_MM.0..=RANDOM_DEPTH_MM.1)
                .min(RANDOM_MAX_SLOPE * d)
                .max(RANDOM_DEPTH_MM.0);
            let feature = match rng.random_range(0..3) {
                0 => Feature::Bump {
                    x_mm: x,
                    y_mm: y,
                    diameter_mm: d,
                    height_mm: depth,
                },
                1 => Feature::Dent {
                    x_mm: x,
                    y_mm: y,
                    diameter_mm: d,
                    depth_mm: depth,
                },
                _ => Feature::Hole {
                    x_mm: x,
                    y_mm: y,
                    diameter_mm: d,
                    designed: false,
                },
            };
            scene.features.push(feature);
            placed.push((x, y, r));
        }
        scene
    }

    /// Checks every number of the scene; the error names the field (`feature[3].diameter_mm`).
    pub fn validate(&self) -> Result<(), SimError> {
        let unit = |v: f64| (0.0..=1.0).contains(&v);
        check(
            "grid_mm".into(),
            self.grid_mm,
            self.grid_mm >= 0.005 && self.grid_mm <= 5.0,
            "must be 0.005 to 5 mm",
        )?;
        check(
            "belt.albedo".into(),
            self.belt.albedo,
            unit(self.belt.albedo),
            "must be 0 to 1",
        )?;
        check(
            "lighting.ambient".into(),
            self.lighting.ambient,
            self.lighting.ambient >= 0.0,
            "must be >= 0",
        )?;
        if let Some(p) = &self.plate {
            check("plate.center_x_mm".into(), p.center_x_mm, true, "")?;
            check("plate.center_y_mm".into(), p.center_y_mm, true, "")?;
            check(
                "plate.length_mm".into(),
                p.length_mm,
                p.length_mm > 0.0,
                "must be > 0",
            )?;
            check(
                "plate.width_mm".into(),
                p.width_mm,
                p.width_mm > 0.0,
                "must be > 0",
            )?;
            check(
                "plate.thickness_mm".into(),
                p.thickness_mm,
                p.thickness_mm > 0.0 && p.thickness_mm < 1000.0,
                "must be 0 to 1000",
            )?;
            let half = 0.5 * p.length_mm.min(p.width_mm);
            check(
                "plate.chamfer_mm".into(),
                p.chamfer_mm,
                p.chamfer_mm >= 0.0 && p.chamfer_mm < half.min(p.thickness_mm),
                "must be >= 0 and smaller than the plate",
            )?;
            check(
                "plate.albedo".into(),
                p.albedo,
                unit(p.albedo),
                "must be 0 to 1",
            )?;
        }
        for (i, f) in self.features.iter().enumerate() {
            let name = |field: &str| format!("feature[{i}].{field}");
            let rect = |x0: f64, y0: f64, x1: f64, y1: f64| -> Result<(), SimError> {
                check(name("x0_mm"), x0, true, "")?;
                check(name("y0_mm"), y0, true, "")?;
                check(name("x1_mm"), x1, x1 > x0, "must be greater than x0_mm")?;
                check(name("y1_mm"), y1, y1 > y0, "must be greater than y0_mm")
            };
            let disc = |x: f64, y: f64, d: f64| -> Result<(), SimError> {
                check(name("x_mm"), x, true, "")?;
                check(name("y_mm"), y, true, "")?;
                check(name("diameter_mm"), d, d > 0.0, "must be > 0")
            };
            match *f {
                Feature::Step {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    height_mm,
                } => {
                    rect(x0_mm, y0_mm, x1_mm, y1_mm)?;
                    check(
                        name("height_mm"),
                        height_mm,
                        height_mm.abs() < 1000.0,
                        "must be within +-1000",
                    )?;
                }
                Feature::Boss {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    height_mm,
                    chamfer_mm,
                } => {
                    disc(x_mm, y_mm, diameter_mm)?;
                    check(
                        name("height_mm"),
                        height_mm,
                        height_mm > 0.0 && height_mm < 1000.0,
                        "must be 0 to 1000",
                    )?;
                    check(
                        name("chamfer_mm"),
                        chamfer_mm,
                        chamfer_mm >= 0.0 && chamfer_mm < (0.5 * diameter_mm).min(height_mm),
                        "must be >= 0 and smaller than the boss",
                    )?;
                }
                Feature::Bump {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    height_mm,
                } => {
                    disc(x_mm, y_mm, diameter_mm)?;
                    check(name("height_mm"), height_mm, height_mm > 0.0, "must be > 0")?;
                }
                Feature::Dent {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    depth_mm,
                } => {
                    disc(x_mm, y_mm, diameter_mm)?;
                    check(name("depth_mm"), depth_mm, depth_mm > 0.0, "must be > 0")?;
                }
                Feature::Hole {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    ..
                } => disc(x_mm, y_mm, diameter_mm)?,
                Feature::Scratch {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    width_mm,
                    depth_mm,
                } => {
                    disc(x0_mm, y0_mm, width_mm)?;
                    disc(x1_mm, y1_mm, width_mm)?;
                    check(name("depth_mm"), depth_mm, depth_mm > 0.0, "must be > 0")?;
                }
                Feature::Albedo {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    albedo,
                } => {
                    rect(x0_mm, y0_mm, x1_mm, y1_mm)?;
                    check(name("albedo"), albedo, unit(albedo), "must be 0 to 1")?;
                }
                Feature::Gloss {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    gloss,
                } => {
                    rect(x0_mm, y0_mm, x1_mm, y1_mm)?;
                    check(name("gloss"), gloss, unit(gloss), "must be 0 to 1")?;
                }
                Feature::Texture {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    cell_mm,
                    low,
                    high,
                    ..
                } => {
                    rect(x0_mm, y0_mm, x1_mm, y1_mm)?;
                    check(name("cell_mm"), cell_mm, cell_mm > 0.0, "must be > 0")?;
                    check(name("low"), low, unit(low), "must be 0 to 1")?;
                    check(
                        name("high"),
                        high,
                        unit(high) && high >= low,
                        "must be low to 1",
                    )?;
                }
            }
        }
        Ok(())
    }

    /// The part's footprint (x0, y0, x1, y1) in mm, or `None` for an empty belt.
    fn footprint(&self) -> Option<[f64; 4]> {
        let mut b: Option<[f64; 4]> = None;
        let mut add = |r: [f64; 4]| {
            b = Some(match b {
                None => r,
                Some(o) => [
                    o[0].min(r[0]),
                    o[1].min(r[1]),
                    o[2].max(r[2]),
                    o[3].max(r[3]),
                ],
            });
        };
        if let Some(p) = &self.plate {
            add([
                p.center_x_mm - p.length_mm / 2.0,
                p.center_y_mm - p.width_mm / 2.0,
                p.center_x_mm + p.length_mm / 2.0,
                p.center_y_mm + p.width_mm / 2.0,
            ]);
        }
        for f in &self.features {
            match *f {
                Feature::Step {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    ..
                } => add([x0_mm, y0_mm, x1_mm, y1_mm]),
                Feature::Boss {
                    x_mm,
                    y_mm,
                    diameter_mm: d,
                    ..
                }
                | Feature::Bump {
                    x_mm,
                    y_mm,
                    diameter_mm: d,
                    ..
                } => add([
                    x_mm - d / 2.0,
                    y_mm - d / 2.0,
                    x_mm + d / 2.0,
                    y_mm + d / 2.0,
                ]),
                _ => {}
            }
        }
        b
    }

    /// Rasterises the scene into a height field with albedo and gloss, and returns the truth of its defects.
    pub fn rasterize(&self) -> Result<(HeightField, Vec<DefectTruth>), SimError> {
        self.validate()?;
        let g = self.grid_mm;
        let Some(fp) = self.footprint() else {
            return Ok((HeightField::flat_belt(self.belt.albedo), vec![]));
        };
        let x0 = fp[0] - GRID_MARGIN_MM;
        let y0 = fp[1] - GRID_MARGIN_MM;
        let nx = ((fp[2] - fp[0] + 2.0 * GRID_MARGIN_MM) / g).ceil() as usize + 1;
        let ny = ((fp[3] - fp[1] + 2.0 * GRID_MARGIN_MM) / g).ceil() as usize + 1;
        if nx.saturating_mul(ny) > MAX_GRID_NODES {
            return Err(SimError::InvalidScene {
                field: "grid_mm".into(),
                reason: format!(
                    "{nx} x {ny} grid nodes exceed the limit of {MAX_GRID_NODES}; use a coarser grid_mm"
                ),
            });
        }
        let mut h = vec![0f32; nx * ny];
        let mut albedo = vec![self.belt.albedo as f32; nx * ny];
        let mut gloss = vec![0f32; nx * ny];
        let node = |i: usize, j: usize| (x0 + i as f64 * g, y0 + j as f64 * g);
        // Index ranges of the nodes inside [a, b] along each axis.
        let span = |a: f64, b: f64, o: f64, n: usize| -> std::ops::Range<usize> {
            let lo = ((a - o) / g).ceil().max(0.0) as usize;
            let hi = (((b - o) / g).floor() + 1.0).clamp(0.0, n as f64) as usize;
            lo.min(hi)..hi
        };
        let mut on_part = vec![false; nx * ny];
        if let Some(p) = &self.plate {
            let (px0, px1) = (
                p.center_x_mm - p.length_mm / 2.0,
                p.center_x_mm + p.length_mm / 2.0,
            );
            let (py0, py1) = (
                p.center_y_mm - p.width_mm / 2.0,
                p.center_y_mm + p.width_mm / 2.0,
            );
            for j in span(py0, py1, y0, ny) {
                for i in span(px0, px1, x0, nx) {
                    let (x, y) = node(i, j);
                    let edge = (x - px0).min(px1 - x).min(y - py0).min(py1 - y);
                    let drop = (p.chamfer_mm - edge).max(0.0);
                    let k = j * nx + i;
                    h[k] = (p.thickness_mm - drop) as f32;
                    albedo[k] = p.albedo as f32;
                    on_part[k] = true;
                }
            }
        }
        let plate_albedo = self.plate.as_ref().map_or(0.6, |p| p.albedo) as f32;
        let mut defects = Vec::new();
        let cell_area = g * g;
        // Features in application order by kind.
        for f in &self.features {
            if let Feature::Step {
                x0_mm,
                y0_mm,
                x1_mm,
                y1_mm,
                height_mm,
            } = *f
            {
                for j in span(y0_mm, y1_mm, y0, ny) {
                    for i in span(x0_mm, x1_mm, x0, nx) {
                        let k = j * nx + i;
                        if !on_part[k] {
                            albedo[k] = plate_albedo;
                            on_part[k] = true;
                        }
                        h[k] = (f64::from(h[k]) + height_mm).max(0.0) as f32;
                    }
                }
            }
        }
        for f in &self.features {
            if let Feature::Boss {
                x_mm,
                y_mm,
                diameter_mm,
                height_mm,
                chamfer_mm,
            } = *f
            {
                let r0 = diameter_mm / 2.0;
                // The boss stands on the surface found at its centre.
                let base = {
                    let i = ((x_mm - x0) / g).round().clamp(0.0, (nx - 1) as f64) as usize;
                    let j = ((y_mm - y0) / g).round().clamp(0.0, (ny - 1) as f64) as usize;
                    f64::from(h[j * nx + i])
                };
                let top = base + height_mm;
                for j in span(y_mm - r0, y_mm + r0, y0, ny) {
                    for i in span(x_mm - r0, x_mm + r0, x0, nx) {
                        let (x, y) = node(i, j);
                        let r = ((x - x_mm).powi(2) + (y - y_mm).powi(2)).sqrt();
                        if r <= r0 {
                            let k = j * nx + i;
                            let z = top - (chamfer_mm - (r0 - r)).max(0.0);
                            if f64::from(h[k]) < z {
                                h[k] = z as f32;
                            }
                            if !on_part[k] {
                                albedo[k] = plate_albedo;
                                on_part[k] = true;
                            }
                        }
                    }
                }
            }
        }
        for f in &self.features {
            let (x_mm, y_mm, diameter_mm, amount, kind) = match *f {
                Feature::Bump {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    height_mm,
                } => (x_mm, y_mm, diameter_mm, height_mm, "bump"),
                Feature::Dent {
                    x_mm,
                    y_mm,
                    diameter_mm,
                    depth_mm,
                } => (x_mm, y_mm, diameter_mm, -depth_mm, "dent"),
                _ => continue,
            };
            let r0 = diameter_mm / 2.0;
            let mut volume = 0.0;
            for j in span(y_mm - r0, y_mm + r0, y0, ny) {
                for i in span(x_mm - r0, x_mm + r0, x0, nx) {
                    let (x, y) = node(i, j);
                    let r = ((x - x_mm).powi(2) + (y - y_mm).powi(2)).sqrt();
                    let dz = amount * bell(r, r0);
                    if dz != 0.0 {
                        let k = j * nx + i;
                        h[k] = (f64::from(h[k]) + dz).max(0.0) as f32;
                        volume += dz.abs() * cell_area;
                    }
                }
            }
            defects.push(DefectTruth {
                kind: kind.into(),
                x_mm,
                y_mm,
                diameter_mm,
                area_mm2: std::f64::consts::PI * r0 * r0,
                depth_mm: amount.abs(),
                volume_mm3: volume,
            });
        }
        for f in &self.features {
            if let Feature::Scratch {
                x0_mm,
                y0_mm,
                x1_mm,
                y1_mm,
                width_mm,
                depth_mm,
            } = *f
            {
                let r0 = width_mm / 2.0;
                let (dx, dy) = (x1_mm - x0_mm, y1_mm - y0_mm);
                let len2 = (dx * dx + dy * dy).max(1e-12);
                let mut volume = 0.0;
                for j in span(y0_mm.min(y1_mm) - r0, y0_mm.max(y1_mm) + r0, y0, ny) {
                    for i in span(x0_mm.min(x1_mm) - r0, x0_mm.max(x1_mm) + r0, x0, nx) {
                        let (x, y) = node(i, j);
                        let t = (((x - x0_mm) * dx + (y - y0_mm) * dy) / len2).clamp(0.0, 1.0);
                        let r = (x - x0_mm - t * dx).hypot(y - y0_mm - t * dy);
                        let dz = depth_mm * bell(r, r0);
                        if dz != 0.0 {
                            let k = j * nx + i;
                            h[k] = (f64::from(h[k]) - dz).max(0.0) as f32;
                            volume += dz * cell_area;
                        }
                    }
                }
                let length = len2.sqrt();
                defects.push(DefectTruth {
                    kind: "scratch".into(),
                    x_mm: (x0_mm + x1_mm) / 2.0,
                    y_mm: (y0_mm + y1_mm) / 2.0,
                    diameter_mm: length + width_mm,
                    area_mm2: length * width_mm + std::f64::consts::PI * r0 * r0,
                    depth_mm,
                    volume_mm3: volume,
                });
            }
        }
        for f in &self.features {
            if let Feature::Hole {
                x_mm,
                y_mm,
                diameter_mm,
                designed,
            } = *f
            {
                let r0 = diameter_mm / 2.0;
                let mut volume = 0.0;
                let mut deepest: f64 = 0.0;
                for j in span(y_mm - r0, y_mm + r0, y0, ny) {
                    for i in span(x_mm - r0, x_mm + r0, x0, nx) {
                        let (x, y) = node(i, j);
                        if (x - x_mm).powi(2) + (y - y_mm).powi(2) <= r0 * r0 {
                            let k = j * nx + i;
                            volume += f64::from(h[k]) * cell_area;
                            deepest = deepest.max(f64::from(h[k]));
                            h[k] = 0.0;
                            albedo[k] = self.belt.albedo as f32;
                            on_part[k] = false;
                        }
                    }
                }
                if !designed {
                    defects.push(DefectTruth {
                        kind: "hole".into(),
                        x_mm,
                        y_mm,
                        diameter_mm,
                        area_mm2: std::f64::consts::PI * r0 * r0,
                        depth_mm: deepest,
                        volume_mm3: volume,
                    });
                }
            }
        }
        for f in &self.features {
            let (rect, value, is_gloss) = match *f {
                Feature::Albedo {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    albedo,
                } => ([x0_mm, y0_mm, x1_mm, y1_mm], albedo, false),
                Feature::Gloss {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    gloss,
                } => ([x0_mm, y0_mm, x1_mm, y1_mm], gloss, true),
                _ => continue,
            };
            for j in span(rect[1], rect[3], y0, ny) {
                for i in span(rect[0], rect[2], x0, nx) {
                    let k = j * nx + i;
                    if on_part[k] {
                        if is_gloss {
                            gloss[k] = value as f32;
                        } else {
                            albedo[k] = value as f32;
                        }
                    }
                }
            }
        }
        for f in &self.features {
            if let Feature::Texture {
                x0_mm,
                y0_mm,
                x1_mm,
                y1_mm,
                cell_mm,
                low,
                high,
                seed,
            } = *f
            {
                for j in span(y0_mm, y1_mm, y0, ny) {
                    for i in span(x0_mm, x1_mm, x0, nx) {
                        let k = j * nx + i;
                        if on_part[k] {
                            let (x, y) = node(i, j);
                            let (ci, cj) = (
                                ((x - x0_mm) / cell_mm).floor() as i64,
                                ((y - y0_mm) / cell_mm).floor() as i64,
                            );
                            albedo[k] = texture_albedo(seed, ci, cj, low, high) as f32;
                        }
                    }
                }
            }
        }
        let mirrors = self
            .features
            .iter()
            .filter_map(|f| match *f {
                Feature::Gloss {
                    x0_mm,
                    y0_mm,
                    x1_mm,
                    y1_mm,
                    gloss,
                } => Some(([x0_mm, y0_mm, x1_mm, y1_mm], gloss)),
                _ => None,
            })
            .collect::<Vec<_>>();
        let mut field = HeightField::new(x0, y0, g, nx, ny, h, albedo, gloss, self.belt.albedo)?;
        for (rect, gloss) in mirrors {
            field.add_mirror(rect, gloss);
        }
        Ok((field, defects))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_scenes_are_valid_and_rasterize() {
        for name in Scene::BUILTIN_NAMES {
            let s = Scene::builtin(name).expect("builtin");
            s.validate().expect("valid");
        }
        let (hf, defects) = Scene::demo().rasterize().expect("raster");
        assert_eq!(defects.len(), 3, "bump, dent and the undesigned hole");
        // plate top, on the step, on the boss, in the designed hole
        assert!((hf.height_at(-5.0, -5.0) - 10.0).abs() < 1e-6);
        assert!((hf.height_at(-30.0, 20.0) - 14.0).abs() < 1e-6);
        assert!((hf.height_at(18.0, 15.0) - 18.0).abs() < 1e-6);
        assert_eq!(hf.height_at(20.0, -18.0), 0.0);
        let bump = &defects[0];
        assert_eq!(bump.kind, "bump");
        // volume of a raised cosine bell: h pi R^2 (1/2 - 2/pi^2)
        let r: f64 = 3.0;
        let expect =
            0.6 * std::f64::consts::PI * r * r * (0.5 - 2.0 / std::f64::consts::PI.powi(2));
        assert!(
            (bump.volume_mm3 - expect).abs() < 0.01 * expect,
            "{} vs {expect}",
            bump.volume_mm3
        );
    }

    #[test]
    fn bad_numbers_name_their_field() {
        let mut s = Scene::demo();
        s.features[3] = Feature::Bump {
            x_mm: 0.0,
            y_mm: 0.0,
            diameter_mm: -1.0,
            height_mm: 1.0,
        };
        let e = s.validate().expect_err("negative diameter");
        assert!(e.to_string().contains("feature[3].diameter_mm"), "{e}");
        let mut s = Scene::flat_plate();
        s.grid_mm = 0.0001;
        assert!(s.validate().is_err());
        s.grid_mm = f64::NAN;
        assert!(s.validate().is_err());
    }
}
