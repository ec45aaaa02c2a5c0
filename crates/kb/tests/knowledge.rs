//! The knowledge files: the shipped example loads, and contradictory, incomplete or malformed knowledge is refused
//! with the file and entry named (never a panic).

use proptest::prelude::*;
use stripe3d_kb::{KbError, KnowledgeBase, SHIPPED_FILES, SourceFile, shipped};

fn files() -> Vec<SourceFile> {
    SHIPPED_FILES
        .iter()
        .map(|(p, t)| SourceFile {
            path: (*p).into(),
            text: (*t).into(),
        })
        .collect()
}

/// The shipped files with `path`'s text edited by `edit`.
fn edited(path: &str, edit: impl Fn(&str) -> String) -> Result<KnowledgeBase, KbError> {
    let mut f = files();
    let e = f.iter_mut().find(|f| f.path == path).expect("shipped file");
    e.text = edit(&e.text);
    KnowledgeBase::from_files(&f)
}

fn refused(r: Result<KnowledgeBase, KbError>, file: &str, words: &[&str]) {
    let e = r.expect_err("must be refused").to_string();
    assert!(e.starts_with(file), "names the file {file}: {e}");
    for w in words {
        assert!(e.contains(w), "mentions `{w}`: {e}");
    }
}

#[test]
fn the_shipped_example_is_valid_and_survives_a_round_trip() {
    let kb = shipped().expect("shipped knowledge base");
    assert_eq!(kb.manifest.version, 1);
    assert_eq!(kb.products.len(), 4);
    assert!(kb.products.contains_key("cover-plate") && kb.products.contains_key("demo-bracket"));
    assert_eq!(kb.processes.len(), 5);
    let again = KnowledgeBase::from_files(&kb.to_files().expect("files")).expect("reloads");
    assert!(
        stripe3d_kb::diff::diff(&kb, &again).is_empty(),
        "{:?}",
        stripe3d_kb::diff::diff(&kb, &again)
    );
}

#[test]
fn contradictory_or_incomplete_knowledge_is_refused_by_name() {
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("process = \"stamping\"", "process = \"forging\"")
        }),
        "products/cover-plate.toml",
        &["process", "forging", "stamping"],
    );
    refused(
        edited("products/cover-plate.toml", |t| {
            format!(
                "{t}\n[[zone]]\nname = \"overlap\"\nx0_mm = 0.0\ny0_mm = 0.0\nx1_mm = 30.0\ny1_mm = 20.0\n"
            )
        }),
        "products/cover-plate.toml",
        &["zone[1]", "overlaps", "gasket seat"],
    );
    refused(
        edited("methods/stripes-11.toml", |t| {
            t.replace("kind = \"anomaly\"", "kind = \"crack\"")
        }),
        "methods/stripes-11.toml",
        &["standard[8].kind", "crack", "not a kind"],
    );
    refused(
        edited("processes/stamping.toml", |t| {
            t.replace("kinds = [\"scratch\"]", "kinds = [\"wrinkle\"]")
        }),
        "processes/stamping.toml",
        &["galling", "wrinkle"],
    );
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("thickness_mm = 0.1", "thickness_mm = -0.1")
        }),
        "products/cover-plate.toml",
        &["tolerances.thickness_mm", "positive"],
    );
    refused(
        edited("methods/stripes-11.toml", |t| {
            t.replace("zone = \"gasket seat\"", "zone = \"flange\"")
        }),
        "methods/stripes-11.toml",
        &["standard[9].zone", "flange", "which uses this method"],
    );
    refused(
        edited("processes/stamping.toml", |t| {
            t.replace("prior = 0.3", "prior = 1.5")
        }),
        "processes/stamping.toml",
        &["prior", "(0, 1]"],
    );
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("x_mm = -28.0", "x_mm = -45.0")
        }),
        "products/cover-plate.toml",
        &["mounting hole 1", "outside"],
    );
    refused(
        edited("methods/stripes-11.toml", |t| {
            t.replace("extraction = \"steger\"", "extraction = \"magic\"")
        }),
        "methods/stripes-11.toml",
        &["scan.extraction", "magic"],
    );
    refused(
        edited("kb.toml", |t| t.replace("version = 1", "version = 0")),
        "kb.toml",
        &["version"],
    );
}

#[test]
fn malformed_files_are_refused_with_the_line() {
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("[geometry]", "[geometry")
        }),
        "products/cover-plate.toml",
        &["line"],
    );
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("gloss = 0.05", "gloss = 0.05\nshine = 1")
        }),
        "products/cover-plate.toml",
        &["shine"],
    );
    refused(
        edited("products/cover-plate.toml", |t| {
            t.replace("name = \"cover-plate\"", "name = \"plate\"")
        }),
        "products/cover-plate.toml",
        &["file name"],
    );
    let mut f = files();
    f.retain(|f| f.path != "kb.toml");
    refused(KnowledgeBase::from_files(&f), "kb.toml", &["missing"]);
    let mut f = files();
    f.push(SourceFile {
        path: "notes.txt".into(),
        text: "hello".into(),
    });
    refused(KnowledgeBase::from_files(&f), "notes.txt", &["not part"]);
    let mut f = files();
    f.push(SourceFile {
        path: "products/cover-plate-copy.toml".into(),
        text: SHIPPED_FILES[2]
            .1
            .replace("name = \"cover-plate\"", "name = \"cover-plate-copy\"")
            .replace("[[zone]]", "[[zone]]\n[[zone]]"),
    });
    assert!(KnowledgeBase::from_files(&f).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    /// Arbitrary bytes in any knowledge file: an error or a knowledge base, never a panic.
    #[test]
    fn arbitrary_text_never_panics(which in 0usize..12, text in ".{0,400}") {
        let mut f = files();
        let k = which % f.len();
        f[k].text = text;
        let _ = KnowledgeBase::from_files(&f);
    }

    /// Numbers anywhere in a product: an error or a knowledge base, never a panic.
    #[test]
    fn arbitrary_numbers_never_panic(a in proptest::num::f64::ANY, b in -1e9f64..1e9) {
        let _ = edited("products/cover-plate.toml", |t| t.replace("x_mm = -28.0", &format!("x_mm = {a:?}")).replace("length_mm = 80.0", &format!("length_mm = {b:?}")));
        let _ = edited("processes/stamping.toml", |t| t.replace("cf = 0.8", &format!("cf = {b:?}")).replace("prior = 0.3", &format!("prior = {a:?}")));
    }
}

#[test]
fn the_design_check_anticipates_what_the_set_up_and_the_process_cannot_do() {
    use stripe3d_kb::check::{Severity, check_product};
    let kb = shipped().expect("kb");
    let (fig, findings) = check_product(&kb, "demo-bracket").expect("check");
    assert!(
        fig.lateral_across_mm > 0.1 && fig.lateral_across_mm < 0.3,
        "{fig:?}"
    );
    assert!(
        findings.iter().all(|f| f.severity != Severity::Problem),
        "{findings:#?}"
    );
    assert!(
        findings
            .iter()
            .any(|f| f.subject == "material" && f.message.contains("gloss"))
    );
    assert!(
        findings
            .iter()
            .any(|f| f.subject == "feature `boss`" && f.message.contains("shadow"))
    );
    // Tighter than stamping holds, a zone limit below the detection threshold, a dark material.
    let kb = edited("products/cover-plate.toml", |t| {
        t.replace("thickness_mm = 0.1", "thickness_mm = 0.01")
            .replace("max_depth_mm = 0.1", "max_depth_mm = 0.02")
            .replace("reflectance = 0.6", "reflectance = 0.05")
    })
    .expect("valid, if unwise");
    let (_, findings) = check_product(&kb, "cover-plate").expect("check");
    let has = |sev: Severity, subject: &str, words: &str| {
        findings
            .iter()
            .any(|f| f.severity == sev && f.subject == subject && f.message.contains(words))
    };
    assert!(
        has(
            Severity::Problem,
            "tolerance thickness",
            "tighter than process `stamping`"
        ),
        "{findings:#?}"
    );
    assert!(
        has(
            Severity::Warning,
            "tolerance thickness",
            "measurement uncertainty"
        ),
        "{findings:#?}"
    );
    assert!(
        has(
            Severity::Problem,
            "zone `gasket seat`",
            "below the detection threshold"
        ),
        "{findings:#?}"
    );
    assert!(has(Severity::Warning, "material", "dim"), "{findings:#?}");
    assert_eq!(findings[0].severity, Severity::Problem, "worst first");
}
