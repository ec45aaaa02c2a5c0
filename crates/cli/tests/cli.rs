//! End-to-end tests of the `stripe3d` command: the contract and the refusals.

use std::path::Path;
use std::process::{Command, Output};

// Shared with the binary's test that parses every documented command; this file runs only the walk.
#[allow(dead_code)]
#[path = "support/doc_commands.rs"]
mod doc_commands;

fn stripe3d(args: &[&str]) -> Output {
    // Inspections are recorded in the history: keep the tests' records out of the user's default database.
    let db = std::env::temp_dir().join(format!("stripe3d-cli-tests-{}.sqlite", std::process::id()));
    Command::new(env!("CARGO_BIN_EXE_stripe3d"))
        .env("STRIPE3D_DB", db)
        .args(args)
        .output()
        .expect("run stripe3d")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn simulate_writes_frames_truth_and_manifest() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("run");
    let o = stripe3d(&[
        "simulate",
        "--scene",
        "demo",
        "--frames",
        "2",
        "--out",
        out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in [
        "frames/frame_00000.png",
        "frames/frame_00001.png",
        "truth/stripes.csv",
        "truth/heightmap.tiff",
        "truth/heightmap.json",
        "truth/heightmap.png",
        "truth/defects.json",
        "sensor.toml",
        "scene.toml",
        "manifest.json",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let csv = std::fs::read_to_string(out.join("truth/stripes.csv")).expect("csv");
    assert!(csv.starts_with("frame,row,stripe,u,x_mm,y_mm,z_mm,part_x_mm\n"));
    assert!(csv.lines().count() > 5000);
    // The written sensor and scene reproduce the run.
    let again = dir.path().join("again");
    let o = stripe3d(&[
        "simulate",
        "--scene",
        out.join("scene.toml").to_str().expect("utf8"),
        "--sensor",
        out.join("sensor.toml").to_str().expect("utf8"),
        "--frames",
        "2",
        "--out",
        again.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(out.join("frames/frame_00001.png")).expect("a"),
        std::fs::read(again.join("frames/frame_00001.png")).expect("b")
    );
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write");
    p.to_str().expect("utf8").to_string()
}

#[test]
fn bad_sensor_files_are_refused_with_file_line_and_field() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("o");
    let out = out.to_str().expect("utf8");
    let missing = dir.path().join("nope.toml");
    let o = stripe3d(&[
        "simulate",
        "--sensor",
        missing.to_str().expect("utf8"),
        "--out",
        out,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nope.toml"), "{}", stderr(&o));

    let bad = write(
        dir.path(),
        "bad.toml",
        "[camera]\nwidth = 648\nheight = 480\nfx = 0\nfy = 1\ncx = 1\ncy = 1\nheight_mm = 100\n[laser]\nstripes = 3\n",
    );
    let o = stripe3d(&["simulate", "--sensor", &bad, "--out", out]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("bad.toml:4: camera.fx"), "{e}");

    let malformed = write(dir.path(), "malformed.toml", "[camera]\nwidth = \"wide\"\n");
    let o = stripe3d(&["simulate", "--sensor", &malformed, "--out", out]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("malformed.toml:2"), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"));
}

#[test]
fn unwritable_output_and_bad_arguments_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let file = write(dir.path(), "afile", "x");
    let o = stripe3d(&["simulate", "--frames", "1", "--out", &format!("{file}/sub")]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cannot write"), "{}", stderr(&o));

    let out = dir.path().join("o");
    let out = out.to_str().expect("utf8");
    let o = stripe3d(&["simulate", "--scene", "no-such-scene", "--out", out]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no built-in scene"), "{}", stderr(&o));

    let enc = write(dir.path(), "enc.txt", "0\n0.5\n# a comment\n0.2\n");
    let o = stripe3d(&["simulate", "--encoder", &enc, "--out", out]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("enc.txt:4"), "{}", stderr(&o));

    let o = stripe3d(&["simulate", "--frames", "0", "--out", out]);
    assert!(!o.status.success());
    let o = stripe3d(&["simulate", "--bits", "9", "--out", out]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("camera.bits"), "{}", stderr(&o));
}

const DIMMER_FLL: &str = "Engine: dimmer
InputVariable: Ambient
  range: 0 1
  term: DARK Triangle 0 0.25 0.5
  term: MEDIUM Triangle 0.25 0.5 0.75
  term: BRIGHT Triangle 0.5 0.75 1
OutputVariable: Power
  range: 0 1
  aggregation: Maximum
  defuzzifier: Centroid 200
  default: nan
  term: LOW Triangle 0 0.25 0.5
  term: MEDIUM Triangle 0.25 0.5 0.75
  term: HIGH Triangle 0.5 0.75 1
RuleBlock:
  implication: Minimum
  rule: if Ambient is DARK then Power is HIGH
  rule: if Ambient is MEDIUM then Power is MEDIUM
  rule: if Ambient is BRIGHT then Power is LOW
";

#[test]
fn fuzzy_eval_follows_its_contract() {
    let dir = tempfile::tempdir().expect("tmp");
    let engine = write(dir.path(), "dimmer.fll", DIMMER_FLL);
    // Extra columns are ignored; columns are matched by name, in any order.
    let inputs = write(dir.path(), "in.fld", "Power Ambient\n9 0.25\n9 0\n9 0.5\n");
    let o = stripe3d(&["fuzzy", "eval", &engine, "--inputs", &inputs]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        out,
        "Ambient Power\n0.250000000 0.750000000\n0.000000000 nan\n0.500000000 0.500000000\n"
    );

    // Standard input.
    let mut child = Command::new(env!("CARGO_BIN_EXE_stripe3d"))
        .args(["fuzzy", "eval", &engine])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    use std::io::Write as _;
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(b"Ambient\n0.75\n")
        .expect("write");
    let o = child.wait_with_output().expect("wait");
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        "Ambient Power\n0.750000000 0.250000000\n"
    );

    // Errors name the file and line.
    let bad = write(
        dir.path(),
        "bad.fll",
        &DIMMER_FLL.replace("then Power is HIGH", "then Power is HUGE"),
    );
    let o = stripe3d(&["fuzzy", "eval", &bad, "--inputs", &inputs]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("bad.fll:17"), "{}", stderr(&o));
    let missing = write(dir.path(), "missing.fld", "Light\n0.5\n");
    let o = stripe3d(&["fuzzy", "eval", &engine, "--inputs", &missing]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("Ambient"), "{}", stderr(&o));
    let ragged = write(dir.path(), "ragged.fld", "Ambient\n0.5\n0.1 0.2\n");
    let o = stripe3d(&["fuzzy", "eval", &engine, "--inputs", &ragged]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("ragged.fld:3"), "{}", stderr(&o));
    assert!(
        o.stdout.is_empty(),
        "nothing printed for a table that fails"
    );

    // Export writes FLL that evaluates identically.
    let o = stripe3d(&["fuzzy", "export", &engine]);
    assert!(o.status.success());
    let exported = write(
        dir.path(),
        "exported.fll",
        &String::from_utf8_lossy(&o.stdout),
    );
    let o = stripe3d(&["fuzzy", "eval", &exported, "--inputs", &inputs]);
    assert_eq!(String::from_utf8_lossy(&o.stdout), out);
}

#[test]
fn extract_follows_its_contract_and_refuses_bad_images() {
    let dir = tempfile::tempdir().expect("tmp");
    let sim = dir.path().join("sim");
    let o = stripe3d(&[
        "simulate",
        "--scene",
        "plate",
        "--frames",
        "2",
        "--out",
        sim.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let f0 = sim.join("frames/frame_00000.png");
    let f1 = sim.join("frames/frame_00001.png");
    let (f0, f1) = (f0.to_str().expect("utf8"), f1.to_str().expect("utf8"));

    // A reader that stops early (`| head`): a quiet, successful end, not an error or a panic.
    let mut child = Command::new(env!("CARGO_BIN_EXE_stripe3d"))
        .args(["extract", f0, f1])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    {
        use std::io::Read as _;
        let mut head = [0u8; 100];
        let mut out = child.stdout.take().expect("stdout");
        out.read_exact(&mut head).expect("the first lines");
        assert!(head.starts_with(b"frame,row,x"));
    }
    let o = child.wait_with_output().expect("wait");
    assert!(o.status.success(), "{:?}: {}", o.status, stderr(&o));
    assert!(o.stderr.is_empty(), "{}", stderr(&o));

    let o = stripe3d(&["extract", f0, "--method", "blais-rioux8"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = String::from_utf8_lossy(&o.stdout).into_owned();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("row,x,intensity,width,score"));
    let rows: Vec<(u32, f64)> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 5, "{l}");
            (f[0].parse().expect("row"), f[1].parse().expect("x"))
        })
        .collect();
    assert!(
        rows.len() > 480 * 10,
        "11 stripes on most rows: {}",
        rows.len()
    );
    assert!(
        rows.windows(2)
            .all(|w| w[0].0 < w[1].0 || (w[0].0 == w[1].0 && w[0].1 < w[1].1)),
        "sorted by row then x"
    );

    let o = stripe3d(&["extract", f0, f1, "--format", "csv"]);
    let csv = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(csv.starts_with("frame,row,x,intensity,width,score\n0,"));
    assert!(csv.contains("\n1,"));

    let o = stripe3d(&[
        "extract",
        f0,
        "--format",
        "json",
        "--axis",
        "rows",
        "--threshold",
        "20",
        "--method",
        "fuzzy",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let p = &v["frames"][0]["points"][0];
    for key in ["row", "x", "intensity", "width", "score"] {
        assert!(p.get(key).is_some(), "{key} in {p}");
    }
    assert!(v["frames"][0]["empty_lines"].is_array());

    // Throughput over a folder of frames: the contract's last line; an empty folder is refused by name.
    let frames = sim.join("frames");
    let o = stripe3d(&[
        "bench",
        "throughput",
        frames.to_str().expect("utf8"),
        "--method",
        "linear",
        "--threads",
        "2",
        "--seconds",
        "0.05",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    let last = out.lines().last().unwrap_or("");
    assert!(
        last.starts_with("throughput: ")
            && last.contains(" frames/s on 1 thread, ")
            && last.ends_with(" frames/s on 2 threads (method linear, 648x480)"),
        "{out}"
    );
    let hollow = dir.path().join("hollow");
    std::fs::create_dir(&hollow).expect("mkdir");
    let o = stripe3d(&["bench", "throughput", hollow.to_str().expect("utf8")]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("hollow") && stderr(&o).contains("no PNG"),
        "{}",
        stderr(&o)
    );

    // Bad input: a clear message naming the file, non-zero exit, nothing on stdout.
    let junk = write(dir.path(), "junk.png", "not an image");
    let empty = write(dir.path(), "empty.pgm", "");
    for (file, says) in [
        (junk.as_str(), "junk.png"),
        (empty.as_str(), "empty.pgm"),
        ("/no/such/frame.png", "frame.png"),
    ] {
        let o = stripe3d(&["extract", f0, file]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(says), "{}", stderr(&o));
        assert!(o.stdout.is_empty());
    }
    // The operating system's reason is given once, not once per level of the error chain.
    let o = stripe3d(&["extract", "/no/such/frame.png"]);
    assert_eq!(
        stderr(&o).matches("No such file").count(),
        1,
        "{}",
        stderr(&o)
    );
    let o = stripe3d(&["extract", f0, "--max-pixels", "1000"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("max-pixels"), "{}", stderr(&o));
    let o = stripe3d(&["extract", f0, "--method", "magic"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("gaussian"),
        "lists the methods: {}",
        stderr(&o)
    );
    let o = stripe3d(&["extract", f0, "--threshold", "-3"]);
    assert!(!o.status.success());
    // Cut stripes: dropped only when asked (no more points than the default), marked in JSON; out of range refused.
    let count = |o: &std::process::Output| String::from_utf8_lossy(&o.stdout).lines().count();
    let all = stripe3d(&["extract", f0]);
    let dropped = stripe3d(&[
        "extract",
        f0,
        "--max-asymmetry",
        "0.2",
        "--cut-asymmetry",
        "off",
    ]);
    assert!(dropped.status.success(), "{}", stderr(&dropped));
    assert!(count(&dropped) <= count(&all));
    let o = stripe3d(&["extract", f0, "--format", "json", "--cut-asymmetry", "0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert!(v["frames"][0]["points"][0]["cut"].is_boolean());
    for flag in ["--max-asymmetry", "--cut-asymmetry"] {
        for bad in ["1.5", "-0.1", "nan", "inf", "abc"] {
            let arg = format!("{flag}={bad}");
            let o = stripe3d(&["extract", f0, &arg]);
            assert!(!o.status.success(), "{arg}");
            assert!(stderr(&o).contains(flag), "{}", stderr(&o));
            assert!(o.stdout.is_empty());
        }
    }
    // A picture of what was found: a PNG at most --picture-side on a side; where it cannot be written, an error that
    // names it and nothing on stdout.
    let pic = dir.path().join("found.png");
    let pic_s = pic.to_str().expect("utf8");
    let o = stripe3d(&["extract", f0, "--picture", pic_s, "--picture-side", "324"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let png = std::fs::read(&pic).expect("picture");
    assert!(png.starts_with(b"\x89PNG"));
    // 648 x 480 shrunk by 2: the IHDR's width and height.
    let (w, h) = (
        u32::from_be_bytes(png[16..20].try_into().expect("w")),
        u32::from_be_bytes(png[20..24].try_into().expect("h")),
    );
    assert_eq!((w, h), (324, 240));
    let o = stripe3d(&["extract", f0, "--picture", "/no/such/dir/found.png"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("found.png"), "{}", stderr(&o));
    assert!(o.stdout.is_empty());
    let o = stripe3d(&["extract", f0, "--picture", pic_s, "--picture-side", "3"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("picture-side"), "{}", stderr(&o));
    // A frame without stripes gives the header only.
    let dark = dir.path().join("dark.pgm");
    std::fs::write(&dark, [b"P5\n8 4\n255\n".as_slice(), &[7u8; 32]].concat()).expect("write");
    let o = stripe3d(&["extract", dark.to_str().expect("utf8")]);
    assert!(o.status.success());
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        "row,x,intensity,width,score\n"
    );
}

#[test]
fn demo_calibrates_scans_and_inspects_and_refuses_bad_input() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("stripe3d-demo");
    let o = stripe3d(&["demo", "--out", out.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    getting_started_runs_as_written(dir.path());
    for f in [
        "calib.toml",
        "calibration/plate-10mm.png",
        "scan/cloud.ply",
        "scan/range.tiff",
        "scan/range.json",
        "scan/range.png",
        "scan/range-colour.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let ply = std::fs::read(out.join("scan/cloud.ply")).expect("ply");
    assert!(ply.starts_with(b"ply\nformat binary_little_endian 1.0\n"));
    let s = |p: &str| out.join(p).to_str().expect("utf8").to_string();
    let (sensor, calib, frames) = (
        s("simulation/sensor.toml"),
        s("calib.toml"),
        s("simulation/frames"),
    );
    let scan_out = dir.path().join("scan2");
    let scan_out = scan_out.to_str().expect("utf8");
    // Encoder: wrong count, then going backwards.
    let enc = write(dir.path(), "enc.txt", "0\n0.5\n");
    let o = stripe3d(&[
        "scan",
        "--sensor",
        &sensor,
        "--calib",
        &calib,
        "--out",
        scan_out,
        "--encoder",
        &enc,
        &frames,
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("2 positions for 22 frames"),
        "{}",
        stderr(&o)
    );
    let back: String = (0..22)
        .map(|k| format!("{}\n", if k == 7 { 1.0 } else { 0.5 * k as f64 }))
        .collect();
    let enc = write(dir.path(), "back.txt", &back);
    let o = stripe3d(&[
        "scan",
        "--sensor",
        &sensor,
        "--calib",
        &calib,
        "--out",
        scan_out,
        "--encoder",
        &enc,
        &frames,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("back.txt:8"), "{}", stderr(&o));
    // One frame: a profile, with a warning in range.json and on stderr.
    let one = dir.path().join("one");
    std::fs::create_dir_all(&one).expect("dir");
    let first = std::fs::read_dir(&frames)
        .expect("frames")
        .map(|e| e.expect("entry").path())
        .min()
        .expect("a frame");
    std::fs::copy(&first, one.join("frame_0000.png")).expect("copy");
    let one_out = dir.path().join("one-scan");
    // `stripe3d scan` of the demo's sensor and calibration, from a folder of frames into another.
    let scan_folder = |from: &Path, to: &Path| {
        stripe3d(&[
            "scan",
            "--sensor",
            &sensor,
            "--calib",
            &calib,
            "--out",
            to.to_str().expect("utf8"),
            from.to_str().expect("utf8"),
        ])
    };
    let o = scan_folder(&one, &one_out);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("warning: one frame"), "{}", stderr(&o));
    let json = std::fs::read_to_string(one_out.join("range.json")).expect("range.json");
    assert!(
        json.contains("one frame: the range image is a single profile"),
        "{json}"
    );
    // Inspected, the one-frame range image's warning reaches the report and keeps the verdict from `accept`.
    let one_report = dir.path().join("one-inspection");
    let o = stripe3d(&[
        "inspect",
        "--out",
        one_report.to_str().expect("utf8"),
        one_out.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("warning: scan: one frame"),
        "{}",
        stderr(&o)
    );
    let report = std::fs::read_to_string(one_report.join("report.json")).expect("report.json");
    assert!(report.contains("scan: one frame"), "{report}");
    assert!(report.contains("\"verdict\": \"incomplete\""), "{report}");
    // A calibration whose planes do not fit the frames (the lasers moved by 36 mm since): warned, naming it.
    let text = std::fs::read_to_string(&calib).expect("calib");
    let moved: String = text
        .lines()
        .map(|l| match l.strip_prefix("offset_mm = ") {
            Some(v) => format!("offset_mm = {}\n", v.parse::<f64>().expect("offset") + 30.0),
            None => format!("{l}\n"),
        })
        .collect();
    let moved = write(dir.path(), "moved.toml", &moved);
    let warned_out = dir.path().join("warned-scan");
    let warned_out = warned_out.to_str().expect("utf8");
    let o = stripe3d(&[
        "scan", "--sensor", &sensor, "--calib", &moved, "--out", warned_out, &frames,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("lie where no calibrated stripe can put them"),
        "{}",
        stderr(&o)
    );
    // The fitting calibration: no warning.
    let o = stripe3d(&[
        "scan", "--sensor", &sensor, "--calib", &calib, "--out", warned_out, &frames,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    // Dark frames (the laser off): nothing to measure, said so, and nothing written.
    let dark = dir.path().join("dark");
    std::fs::create_dir_all(&dark).expect("dir");
    let mut pgm = b"P5\n648 480\n255\n".to_vec();
    pgm.extend(std::iter::repeat_n(3u8, 648 * 480));
    for k in 0..3 {
        std::fs::write(dark.join(format!("frame_{k}.pgm")), &pgm).expect("frame");
    }
    let dark_out = dir.path().join("dark-scan");
    let o = scan_folder(&dark, &dark_out);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("nothing was measured in 3 frames"),
        "{}",
        stderr(&o)
    );
    assert!(!dark_out.join("cloud.ply").exists());
    // The demo's frames as a colour camera would give them (the green laser in G, a quarter of it in R and B):
    // `--laser green` (and auto) scan them as the grey frames.
    let colour = dir.path().join("colour");
    std::fs::create_dir_all(&colour).expect("dir");
    for entry in std::fs::read_dir(&frames).expect("frames") {
        let path = entry.expect("entry").path();
        let f = stripe3d_io::images::read_frame(&path).expect("frame");
        let rgb: Vec<u8> = f
            .image
            .data()
            .iter()
            .flat_map(|&v| {
                let g = v.min(255) as u8;
                [g / 4, g, g / 4]
            })
            .collect();
        let name = path.file_name().expect("name");
        stripe3d_io::images::write_rgb_png(
            &colour.join(name),
            f.image.width(),
            f.image.height(),
            &rgb,
        )
        .expect("colour frame");
    }
    let points = |dir: &Path| -> u64 {
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("range.json")).expect("range.json"),
        )
        .expect("json");
        json["points"].as_u64().expect("points")
    };
    let grey = points(&out.join("scan"));
    for laser in [vec!["--laser", "green"], vec![]] {
        let colour_out = dir.path().join("colour-scan");
        let mut args = vec![
            "scan",
            "--sensor",
            &sensor,
            "--calib",
            &calib,
            "--out",
            colour_out.to_str().expect("utf8"),
        ];
        args.extend(laser.iter().copied());
        args.push(colour.to_str().expect("utf8"));
        let o = stripe3d(&args);
        assert!(o.status.success(), "{laser:?}: {}", stderr(&o));
        let n = points(&colour_out);
        assert!(
            (n as f64 - grey as f64).abs() < 0.01 * grey as f64,
            "{laser:?}: {n} points from colour frames, {grey} from grey"
        );
    }
    // A calibration from another camera.
    let other = std::fs::read_to_string(&calib)
        .expect("calib")
        .replace("width = 648", "width = 640");
    let other = write(dir.path(), "other.toml", &other);
    let o = stripe3d(&[
        "scan", "--sensor", &sensor, "--calib", &other, "--out", scan_out, &frames,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("640x480"), "{}", stderr(&o));
    assert!(
        !Path::new(scan_out).join("cloud.ply").exists(),
        "nothing written on refusal"
    );
    // Bad grid, range and coding arguments.
    let coding = write(
        dir.path(),
        "coding.toml",
        "margin = 0.3\noutlier_cost = -1\n",
    );
    let ranged = write(dir.path(), "ranged.toml", "max_height_mm = 20\n");
    for (flag, value, needle) in [
        ("--grid-mm", "0", "positive"),
        ("--range", "5:1", "above MIN"),
        ("--coding", coding.as_str(), "coding.toml:2: outlier_cost"),
        ("--coding", ranged.as_str(), "--range MIN:MAX"),
        ("--coding", "no-such-coding.toml", "no-such-coding.toml"),
    ] {
        let o = stripe3d(&[
            "scan", "--sensor", &sensor, "--calib", &calib, "--out", scan_out, flag, value, &frames,
        ]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(needle), "{flag}: {}", stderr(&o));
        assert!(
            !Path::new(scan_out).join("cloud.ply").exists(),
            "{flag}: nothing written"
        );
    }
    // A coding file naming a few parameters scans; the rest keep their defaults.
    let tuned = write(
        dir.path(),
        "tuned.toml",
        "# our line's coding\nfaint_intensity = 0.15\ntilt_cost_per_mm = 1.6\n",
    );
    let o = stripe3d(&[
        "scan", "--sensor", &sensor, "--calib", &calib, "--out", scan_out, "--coding", &tuned,
        &frames,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(Path::new(scan_out).join("cloud.ply").exists());
    std::fs::remove_dir_all(scan_out).expect("clean");
    // Calibration refusals.
    let plate = s("calibration/plate-10mm.png");
    let o = stripe3d(&[
        "calibrate",
        "--sensor",
        &sensor,
        "--plane",
        &format!("10:{plate}"),
        "--plane",
        &format!("5:{}", s("calibration/plate-5mm.png")),
        "--out",
        &s("c2.toml"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("three heights"), "{}", stderr(&o));
    let o = stripe3d(&[
        "calibrate",
        "--sensor",
        &sensor,
        "--plane",
        &plate,
        "--out",
        &s("c3.toml"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("HEIGHT_MM:IMAGE"), "{}", stderr(&o));
    // The demo's inspection: report and pictures, the fields other tools read.
    for f in [
        "inspection/report.json",
        "inspection/defects.png",
        "inspection/deviation.png",
        "golden/scan/range.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let report: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("inspection/report.json")).expect("report"),
    )
    .expect("json");
    assert_eq!(report["status"], "inspected");
    assert!(
        ["accept", "rework", "reject", "incomplete"]
            .contains(&report["verdict"].as_str().expect("verdict"))
    );
    // The knowledge base's part of the report.
    assert_eq!(report["product"], "demo-bracket");
    assert_eq!(report["knowledge_base"]["version"], 1);
    assert!(
        report["trace"].as_array().is_some_and(|t| !t.is_empty()),
        "{report}"
    );
    assert!(report["diagnosis"].is_array());
    assert!(report["features"].is_array());
    let defects = report["defects"].as_array().expect("defects");
    assert!(
        !defects.is_empty(),
        "the demo part has a bump, a dent and a hole"
    );
    for d in defects {
        for k in [
            "kind",
            "x_mm",
            "y_mm",
            "area_mm2",
            "depth_mm",
            "volume_mm3",
            "bbox_mm",
            "confidence",
        ] {
            assert!(!d[k].is_null(), "{k} missing in {d}");
        }
    }
    // The golden scan against itself: nothing deviates.
    let insp = dir.path().join("self");
    let golden = s("golden/scan");
    let o = stripe3d(&[
        "inspect",
        "--reference",
        &golden,
        "--out",
        insp.to_str().expect("utf8"),
        &golden,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(insp.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(
        report["defects"].as_array().map(Vec::len),
        Some(0),
        "{report}"
    );
    // Refusals: a product file that is not there, an unknown product, frames without a calibration, a missing
    // reference.
    let o = stripe3d(&["inspect", "--product", "p.toml", "--out", &s("i1"), &golden]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("p.toml"), "{}", stderr(&o));
    let o = stripe3d(&["inspect", "--product", "teapot", "--out", &s("i1"), &golden]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("teapot") && stderr(&o).contains("cover-plate"),
        "{}",
        stderr(&o)
    );
    let o = stripe3d(&[
        "inspect",
        "--product",
        "demo-bracket",
        "--out",
        &s("i1"),
        &golden,
    ]);
    assert!(!o.status.success(), "a golden method without --reference");
    assert!(stderr(&o).contains("--reference"), "{}", stderr(&o));
    let o = stripe3d(&["inspect", "--sensor", &sensor, "--out", &s("i2"), &frames]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--calib"), "{}", stderr(&o));
    // Inspecting frames reads stripe coding's options as scanning does; on a range image they are refused, not
    // ignored.
    let o = stripe3d(&[
        "inspect",
        "--sensor",
        &sensor,
        "--calib",
        &calib,
        "--coding",
        &coding,
        "--out",
        &s("i2"),
        &frames,
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("coding.toml:2: outlier_cost"),
        "{}",
        stderr(&o)
    );
    for extra in [
        ["--range", "-1:40"],
        ["--coding", coding.as_str()],
        ["--grid-mm", "0.3"],
        ["--sensor", sensor.as_str()],
    ] {
        let mut argv = vec!["inspect", "--out", "unused"];
        argv.extend(extra);
        argv.push(&golden);
        let o = stripe3d(&argv);
        assert!(!o.status.success(), "{extra:?}");
        assert!(
            stderr(&o).contains(extra[0]) && stderr(&o).contains("range image"),
            "{extra:?}: {}",
            stderr(&o)
        );
    }
    let o = stripe3d(&[
        "inspect",
        "--reference",
        &s("nowhere"),
        "--out",
        &s("i3"),
        &golden,
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nowhere"), "{}", stderr(&o));
    // A scan of the empty belt shows no part: the report says so and the exit is non-zero.
    let belt = dir.path().join("belt");
    let o = stripe3d(&[
        "simulate",
        "--scene",
        "belt",
        "--frames",
        "3",
        "--out",
        belt.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = stripe3d(&[
        "inspect",
        "--sensor",
        &sensor,
        "--calib",
        &calib,
        "--out",
        &s("i4"),
        belt.join("frames").to_str().expect("utf8"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no part"), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("i4/report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["status"], "error");
    assert_eq!(report["verdict"], "not-inspected");
    knowledge_base_history_and_learning(&out);
}

/// `docs/getting-started.md`, every command as written, in a folder holding the demo's output `stripe3d-demo/`.
fn getting_started_runs_as_written(folder: &Path) {
    let page = doc_commands::repo_root().join("docs/getting-started.md");
    let commands = doc_commands::commands_in(&page);
    assert!(
        commands.len() >= 10,
        "only {} commands in {}",
        commands.len(),
        page.display()
    );
    for c in &commands {
        let o = Command::new(env!("CARGO_BIN_EXE_stripe3d"))
            .current_dir(folder)
            .env("STRIPE3D_DB", folder.join("default-history.sqlite"))
            .args(&c.words[1..])
            .output()
            .expect("run stripe3d");
        assert!(
            o.status.success(),
            "{}: `{}` failed:\n{}",
            c.place,
            c.words.join(" "),
            stderr(&o)
        );
    }
    for f in [
        "my-calib.toml",
        "my-scan/range.json",
        "my-inspection/report.json",
        "my-kb-v2/kb.toml",
    ] {
        assert!(folder.join(f).is_file(), "the walk wrote no {f}");
    }
}

/// The knowledge-base commands on the demo's output: history, feedback, learning, diff, design check, and their
/// refusals.
fn knowledge_base_history_and_learning(out: &Path) {
    let s = |p: &str| out.join(p).to_str().expect("utf8").to_string();
    let db = s("history.sqlite");
    assert!(
        out.join("history.sqlite").is_file(),
        "the demo records its inspection"
    );
    let o = stripe3d(&["history", "--db", &db, "--format", "csv"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(csv.starts_with("id,time_utc,part_id,product,"), "{csv}");
    assert!(csv.contains(",demo-1,demo-bracket,"), "{csv}");
    // Five more inspections of the demo scan, each judged by an operator.
    for k in 0..5 {
        let o = stripe3d(&[
            "inspect",
            "--product",
            "demo-bracket",
            "--reference",
            &s("golden/scan"),
            "--db",
            &db,
            "--part-id",
            &format!("again-{k}"),
            "--out",
            &s(&format!("again-{k}")),
            &s("scan"),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        let id = text
            .split("recorded as inspection ")
            .nth(1)
            .and_then(|t| t.split_whitespace().next())
            .expect("inspection id")
            .to_string();
        let o = stripe3d(&[
            "feedback",
            &id,
            "--db",
            &db,
            "--reviewed",
            "--operator",
            "test",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let o = stripe3d(&[
            "feedback",
            &id,
            "--db",
            &db,
            "--missed",
            "-1.5,-2",
            "--kind",
            "dent",
            "--cause",
            "shrinkage",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    // Bad feedback: no such defect, no such inspection, a place that is not a place, a kind nobody detects, no
    // judgement, no database (none is created).
    let nowhere = s("nowhere.sqlite");
    for (args, words) in [
        (
            vec!["feedback", "2", "--db", &db, "--confirm", "99"],
            "no defect 99",
        ),
        (
            vec!["feedback", "999", "--db", &db, "--reviewed"],
            "no inspection 999",
        ),
        (
            vec![
                "feedback", "2", "--db", &db, "--missed", "here", "--kind", "dent",
            ],
            "X,Y",
        ),
        (
            vec![
                "feedback", "2", "--db", &db, "--missed", "1,2", "--kind", "crack",
            ],
            "crack",
        ),
        (vec!["feedback", "2", "--db", &db], "--reviewed"),
        (
            vec!["feedback", "2", "--db", &nowhere, "--reviewed"],
            "no history there",
        ),
    ] {
        let o = stripe3d(&args);
        assert!(!o.status.success(), "{args:?}");
        assert!(stderr(&o).contains(words), "{args:?}: {}", stderr(&o));
    }
    assert!(!out.join("nowhere.sqlite").exists());
    for (args, words) in [
        (
            vec!["history", "--db", &db, "--since", "yesterday"],
            "--since yesterday",
        ),
        (vec!["history", "--db", &db, "--verdict", "maybe"], "maybe"),
    ] {
        let o = stripe3d(&args);
        assert!(
            !o.status.success() && stderr(&o).contains(words),
            "{args:?}: {}",
            stderr(&o)
        );
    }
    let o = stripe3d(&[
        "history",
        "--db",
        &db,
        "--since",
        "2000-01-01",
        "--verdict",
        "reject",
        "--format",
        "json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let listed: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert!(listed.as_array().is_some_and(|a| !a.is_empty()), "{listed}");
    let o = stripe3d(&[
        "history",
        "--db",
        &db,
        "--product",
        "demo-bracket",
        "--diagnose",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("6 inspection(s)"));
    assert!(
        stderr(&o).contains("batch diagnosis over 6"),
        "{}",
        stderr(&o)
    );
    // Learning writes version 2 (the confirmed causes move the priors) into a new folder, never over one.
    let v2 = s("kb-v2");
    let o = stripe3d(&[
        "learn",
        "--product",
        "demo-bracket",
        "--db",
        &db,
        "--out",
        &v2,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(text.contains("shrinkage"), "{text}");
    assert!(out.join("kb-v2/kb.toml").is_file());
    let o = stripe3d(&[
        "learn",
        "--product",
        "demo-bracket",
        "--db",
        &db,
        "--out",
        &v2,
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("never overwritten"),
        "{}",
        stderr(&o)
    );
    let o = stripe3d(&["kb", "diff", "shipped", &v2]);
    assert!(o.status.success(), "{}", stderr(&o));
    let diff = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(diff.contains("kb.version: 1 -> 2"), "{diff}");
    assert!(
        diff.contains("process `die-casting`.cause[1].prior"),
        "{diff}"
    );
    // The learned version inspects.
    let o = stripe3d(&[
        "inspect",
        "--product",
        "demo-bracket",
        "--kb",
        &v2,
        "--reference",
        &s("golden/scan"),
        "--no-history",
        "--out",
        &s("with-v2"),
        &s("scan"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Too little feedback to learn from.
    let o = stripe3d(&[
        "learn",
        "--product",
        "cover-plate",
        "--db",
        &db,
        "--out",
        &s("kb-none"),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("at least"),
        "{}",
        stderr(&o)
    );
    // A database that is not one.
    std::fs::write(out.join("junk.sqlite"), vec![b'x'; 4096]).expect("junk");
    let o = stripe3d(&["history", "--db", &s("junk.sqlite")]);
    assert!(
        !o.status.success() && stderr(&o).contains("not a stripe3d history"),
        "{}",
        stderr(&o)
    );
    // Design assistance, and a knowledge base of your own that is broken.
    let o = stripe3d(&["kb", "check", "demo-bracket"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        text.contains("gloss 0.35"),
        "the demo bracket is glossy: {text}"
    );
    assert!(text.contains("shadow"), "its boss throws a shadow: {text}");
    let mine = s("my-kb");
    let o = stripe3d(&["kb", "init", &mine]);
    assert!(o.status.success(), "{}", stderr(&o));
    let product = out.join("my-kb/products/cover-plate.toml");
    let t = std::fs::read_to_string(&product).expect("product");
    std::fs::write(
        &product,
        t.replace("thickness_mm = 0.1", "thickness_mm = 0.01"),
    )
    .expect("edit");
    let o = stripe3d(&["kb", "check", product.to_str().expect("utf8"), "--strict"]);
    assert!(
        !o.status.success(),
        "a tolerance tighter than stamping holds"
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("tighter than process `stamping`"));
    std::fs::write(
        &product,
        t.replace("process = \"stamping\"", "process = \"forging\""),
    )
    .expect("edit");
    let o = stripe3d(&["kb", "show", "--kb", &mine]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("products/cover-plate.toml") && stderr(&o).contains("forging"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn bench_sensor_prints_the_papers_table_beside_ours() {
    let o = stripe3d(&["bench", "sensor", "--repeats", "1"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    for row in [
        "| lateral resolution | 1.696",
        "| depth resolution | 0.22 mm",
        "| depth range | 0.44 mm to 7 cm",
        "| scanned area |",
        "| profiling rate | 4 cm²/s",
        "| time per 11-stripe depth image |",
    ] {
        assert!(out.contains(row), "{row} missing in\n{out}");
    }
    // The noise-limited depth resolution is measured, and far below the paper's 0.22 mm.
    let line = out
        .lines()
        .find(|l| l.starts_with("| depth resolution"))
        .expect("row");
    let sigma: f64 = line
        .split('|')
        .nth(3)
        .and_then(|c| c.trim().split(' ').next())
        .and_then(|v| v.parse().ok())
        .expect("a number");
    assert!(sigma > 0.0 && sigma < 0.022, "{line}");
}

#[test]
fn bench_defects_writes_every_defect_to_csv_and_refuses_a_missing_folder() {
    let dir = tempfile::tempdir().expect("tmp");
    let missing = dir.path().join("no-such-folder").join("d.csv");
    let o = stripe3d(&[
        "bench",
        "defects",
        "--parts",
        "1",
        "--clean",
        "0",
        "--csv",
        missing.to_str().expect("utf8"),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("does not exist"), "{}", stderr(&o));
    let csv = dir.path().join("d.csv");
    let o = stripe3d(&[
        "bench",
        "defects",
        "--parts",
        "1",
        "--clean",
        "1",
        "--defects",
        "2",
        "--csv",
        csv.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).expect("csv written");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    assert_eq!(header.len(), 17, "{header:?}");
    assert_eq!(header[..3], ["plate", "seed", "truth_kind"]);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // Every true defect has a line (the clean plate none unless something false was found on it).
    let truths: Vec<&Vec<&str>> = rows.iter().filter(|r| !r[2].is_empty()).collect();
    assert_eq!(truths.len(), 2, "{rows:?}");
    for r in &rows {
        assert_eq!(r.len(), 17, "{r:?}");
    }
    for r in truths {
        assert!(["bump", "dent", "hole"].contains(&r[2]), "{r:?}");
        let area: f64 = r[6].parse().expect("truth area");
        assert!(area > 0.0, "{r:?}");
        if !r[8].is_empty() {
            let err: f64 = r[15].parse().expect("area error");
            let found: f64 = r[11].parse().expect("found area");
            assert!((100.0 * (found - area) / area - err).abs() < 0.1, "{r:?}");
        }
    }
}

#[test]
fn bench_defects_against_a_golden_plate_finds_the_defects_and_says_so() {
    let o = stripe3d(&[
        "bench",
        "defects",
        "--parts",
        "1",
        "--clean",
        "1",
        "--defects",
        "2",
        "--golden",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("reference: golden scan of a clean plate, render seed 2000001"),
        "{out}"
    );
    // Both defects of the plate found, nothing on the clean one.
    assert!(out.contains("| recall | 100.00% (2 of 2) |"), "{out}");
    assert!(
        out.contains("| false defects on clean plates | 0 on 0 of 1 plates |"),
        "{out}"
    );
}

#[test]
fn bench_coding_scores_a_scan_against_the_truth_and_refuses_bad_arguments() {
    let o = stripe3d(&["bench", "coding", "--scene", "block", "--frames", "3"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let row = out
        .lines()
        .find(|l| l.starts_with("| after temporal reconciliation |"))
        .expect("the reconciled row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    // | stage | points | coded | right | wrong | off the truth | right of matched | target |
    let points: usize = cells[2].parse().expect("points");
    let right: usize = cells[4].parse().expect("right");
    assert!(points > 1000 && right > points / 2, "{row}");
    // The block hides four stripes in its rows and is coded without a wrong index (coding.rs measures the same).
    assert_eq!(cells[5], "0", "{row}");
    assert_eq!(cells[8], "met", "{row}");
    for (args, says) in [
        (vec!["--scene", "no-such-scene"], "no built-in scene"),
        (vec!["--frames", "0"], "give 1 to"),
        (
            vec!["--scene", "demo", "--defect-plate", "3"],
            "cannot be used with",
        ),
    ] {
        let mut all = vec!["bench", "coding"];
        all.extend(args);
        let o = stripe3d(&all);
        assert!(!o.status.success(), "{all:?}");
        assert!(stderr(&o).contains(says), "{all:?}: {}", stderr(&o));
    }
}

#[test]
fn bench_scans_scores_random_scans_against_their_truth_and_refuses_bad_arguments() {
    // Scene 2: a 3.2 mm printed plate under 20 stripes at 0.15 mm a frame (the spacetime analysis applies).
    let o = stripe3d(&[
        "bench", "scans", "--scenes", "1", "--seed", "2", "--frames", "8",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("1 with a frame step fine enough for the spacetime analysis"),
        "{out}"
    );
    let summary = out.lines().last().expect("a summary");
    assert!(
        summary.starts_with("summary: scans over 1 scenes (0 not scanned)"),
        "{summary}"
    );
    let row = out
        .lines()
        .find(|l| l.starts_with("| gross errors"))
        .expect("the gross row");
    let gross: f64 = row
        .split('|')
        .nth(2)
        .expect("median")
        .trim()
        .parse()
        .expect("a rate");
    assert!(gross < 0.05, "{row}");
    for (args, says) in [
        (vec!["--scenes", "0"], "--scenes must be at least 1"),
        (vec!["--frames", "1"], "--frames must be at least 2"),
    ] {
        let mut all = vec!["bench", "scans"];
        all.extend(args);
        let o = stripe3d(&all);
        assert!(!o.status.success(), "{all:?}");
        assert!(stderr(&o).contains(says), "{all:?}: {}", stderr(&o));
    }
}

/// The validation set's scans (`../shared/validation/`, another renderer's frames), scored as its README says; skipped
/// with a message when the set is not beside the checkout.
#[test]
fn bench_validation_scores_the_sets_scans_with_heights_texture_cannot_bend() {
    let set = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/validation");
    if !set.join("scans").is_dir() {
        eprintln!("skipped: ../shared/validation/ is not beside the checkout");
        return;
    }
    let o = stripe3d(&["bench", "validation", set.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let row = out
        .lines()
        .find(|l| l.starts_with("| texture_defects |"))
        .expect("the textured plate's row");
    // | scan | frames | points | gross | RMS mm | coverage | dropped | defects | s |
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let rms: f64 = cells[5].parse().expect("RMS");
    // Each frame's centres give 0.030 mm and 202 defects here: the printed pattern bends them.
    assert!(rms <= 0.02, "{row}");
    let defects: Vec<usize> = cells[8]
        .split(|c: char| !c.is_ascii_digit())
        .filter(|t| !t.is_empty())
        .map(|t| t.parse().expect("a count"))
        .collect();
    // true / reported / matched (right kind)
    assert_eq!(defects[0], 5, "{row}");
    assert!(defects[1] <= 10 && defects[2] >= 4, "{row}");
    assert!(
        out.lines()
            .last()
            .expect("summary")
            .contains("scans over 3"),
        "{out}"
    );
}

/// A reader that stops early (`stripe3d kb show | head -1`) ends the command quietly with success, never a panic.
#[test]
fn output_to_a_closed_pipe_ends_quietly() {
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_stripe3d"))
        .args(["kb", "show"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run stripe3d");
    drop(child.stdout.take()); // the reader goes away before the first line
    let o = child.wait_with_output().expect("wait");
    let err = stderr(&o);
    assert!(!err.contains("panicked"), "{err}");
    assert!(o.status.success(), "{err}");
}

#[test]
fn run_inspects_every_part_on_the_belt_as_it_passes_and_refuses_bad_sources() {
    let dir = tempfile::tempdir().expect("tmp");
    let p = |name: &str| dir.path().join(name).display().to_string();
    // The paper's sensor with the belt four times as fast (2 mm a frame): a part passes in about 100 frames.
    let o = stripe3d(&[
        "simulate",
        "--scene",
        "plate",
        "--frames",
        "1",
        "--out",
        &p("base"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let sensor = std::fs::read_to_string(dir.path().join("base/sensor.toml")).expect("sensor");
    assert!(sensor.contains("speed_mm_s = 10.0"), "{sensor}");
    std::fs::write(
        dir.path().join("fast.toml"),
        sensor.replace("speed_mm_s = 10.0", "speed_mm_s = 40.0"),
    )
    .expect("write");
    let db = p("line.sqlite");
    let o = stripe3d(&[
        "run",
        "--source",
        "sim:plate",
        "--product",
        "cover-plate",
        "--parts",
        "2",
        "--sensor",
        &p("fast.toml"),
        "--db",
        &db,
        "--out",
        &p("parts"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    let parts: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object a line"))
        .collect();
    assert_eq!(parts.len(), 2, "{out}");
    let x = |v: &serde_json::Value, i: usize| v["x_mm"][i].as_f64().expect("x_mm");
    for (k, part) in parts.iter().enumerate() {
        assert_eq!(part["part"], k + 1);
        assert_eq!(part["product"], "cover-plate");
        assert_eq!(part["complete"], true);
        assert!(
            ["accept", "rework", "reject"].contains(&part["verdict"].as_str().expect("verdict"))
        );
        // The 80 mm plate, found within a bin and the trailing face.
        let length = x(part, 1) - x(part, 0);
        assert!((length - 80.0).abs() <= 2.0, "{part}");
        assert!(
            part["first_frame"].as_u64() < part["last_frame"].as_u64(),
            "{part}"
        );
        assert!(part["history_id"].is_i64(), "{part}");
        assert!(
            part["defects"].is_array() && part["diagnosis"].is_array(),
            "{part}"
        );
        let report = dir.path().join(format!("parts/part-{}/report.json", k + 1));
        assert!(report.is_file(), "{}", report.display());
    }
    // The second part follows the first by the pitch: its length and the default gap (the view's length and 10 mm).
    let pitch = x(&parts[0], 0) - x(&parts[1], 0);
    assert!(pitch > 180.0 && pitch < 220.0, "{pitch}");
    assert!(
        stderr(&o).contains("0 dropped; 2 part(s)"),
        "{}",
        stderr(&o)
    );
    let o = stripe3d(&["history", "--db", &db]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("line-part-2"));

    // A recording replayed: the plate in view from the first frame, swept by the 60th.
    let o = stripe3d(&["demo", "--out", &p("demo")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = stripe3d(&[
        "simulate",
        "--scene",
        "plate",
        "--frames",
        "60",
        "--sensor",
        &p("fast.toml"),
        "--out",
        &p("rec"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let calib = p("demo/calib.toml");
    let o = stripe3d(&[
        "run",
        "--source",
        &format!("replay:{}", p("rec/frames")),
        "--product",
        "cover-plate",
        "--sensor",
        &p("fast.toml"),
        "--calib",
        &calib,
        "--no-history",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(out.lines().count(), 1, "{out}");
    let part: serde_json::Value =
        serde_json::from_str(out.lines().next().expect("a part")).expect("JSON");
    assert_eq!(part["first_frame"], 0, "{part}");
    // The same parts whatever the number of threads.
    let o1 = stripe3d(&[
        "run",
        "--source",
        &format!("replay:{}", p("rec/frames")),
        "--product",
        "cover-plate",
        "--sensor",
        &p("fast.toml"),
        "--calib",
        &calib,
        "--no-history",
        "--threads",
        "1",
    ]);
    assert!(o1.status.success(), "{}", stderr(&o1));
    assert_eq!(o1.stdout, o.stdout);
    // Stopped while the plate is in view: handed on as incomplete, and said so.
    let o = stripe3d(&[
        "run",
        "--source",
        &format!("replay:{}", p("rec/frames")),
        "--product",
        "cover-plate",
        "--sensor",
        &p("fast.toml"),
        "--calib",
        &calib,
        "--no-history",
        "--frames",
        "20",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let part: serde_json::Value = serde_json::from_str(
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .next()
            .expect("a part"),
    )
    .expect("JSON");
    assert_eq!(part["verdict"], "incomplete", "{part}");
    assert!(
        part["warnings"][0]
            .as_str()
            .is_some_and(|w| w.contains("still in view")),
        "{part}"
    );

    // Refusals: each names what is wrong, exits non-zero, prints no part.
    let refused = |args: &[&str], says: &str| {
        let o = stripe3d(args);
        assert!(!o.status.success(), "{args:?}");
        assert!(o.stdout.is_empty(), "{args:?}");
        assert!(stderr(&o).contains(says), "{args:?}: {}", stderr(&o));
    };
    let fast = p("fast.toml");
    refused(
        &["run", "--source", "camera:0", "--product", "cover-plate"],
        "give sim:SCENE, replay:DIR or folder:DIR",
    );
    refused(
        &[
            "run",
            "--source",
            "sim:teapot",
            "--product",
            "cover-plate",
            "--no-history",
        ],
        "no built-in scene `teapot`",
    );
    refused(
        &[
            "run",
            "--source",
            "sim:plate",
            "--product",
            "cover-plate",
            "--gap-mm",
            "10",
            "--no-history",
            "--sensor",
            &fast,
        ],
        "at least the view's length",
    );
    refused(
        &[
            "run",
            "--source",
            "sim:plate",
            "--product",
            "demo-bracket",
            "--no-history",
        ],
        "golden scan",
    );
    refused(
        &[
            "run",
            "--source",
            "replay:/no/such/folder",
            "--product",
            "cover-plate",
            "--no-history",
            "--sensor",
            &fast,
            "--calib",
            &calib,
        ],
        "no such folder",
    );
    refused(
        &[
            "run",
            "--source",
            &format!("replay:{}", p("rec/frames")),
            "--product",
            "cover-plate",
            "--no-history",
        ],
        "need --sensor",
    );
}
