//! The `stripe3d` command: thin wiring of the library crates. See `stripe3d --help`.

/// `println!` for the command's output, without its panic when stdout goes away: a reader that stopped early
/// (`stripe3d history | head`) ends the command quietly with success, as the pipe's reader chose; any other failure
/// to write (a full disk behind a redirection) ends it with a message and a non-zero exit.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($arg)*) {
            crate::stdout_failed(e)
        }
    }};
}

mod bench;
mod coding_bench;
mod defects;
mod extract;
mod fuzzy;
mod inspect;
mod knowledge;
mod learning_bench;
mod robustness_bench;
mod run;
mod scan;
mod scan_bench;
mod sensor_bench;
mod simulate;
mod validation_bench;

#[cfg(test)]
#[path = "../tests/support/doc_commands.rs"]
mod doc_commands;

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::PathBuf;

/// stripe3d: laser-stripe 3-D inspection of parts on a conveyor.
#[derive(Debug, Parser)]
#[command(name = "stripe3d", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the main job end to end on the built-in demo scene.
    Demo {
        /// Folder for everything the demo writes.
        #[arg(long, default_value = "stripe3d-demo")]
        out: PathBuf,
    },
    /// Render laser-stripe frames of a scene with exact ground truth.
    Simulate(simulate::SimulateArgs),
    /// Find the sub-pixel centre of every laser stripe on every scan line of camera frames.
    Extract(extract::ExtractArgs),
    /// Fit the triangulation models from images of a flat plate at known heights.
    Calibrate(scan::CalibrateArgs),
    /// Turn a sequence of frames into the part's point cloud and range image.
    Scan(scan::ScanArgs),
    /// Find, classify and measure the defects of a scanned part (bumps, dents, holes, scratches, edge chips).
    Inspect(inspect::InspectArgs),
    /// On the line: frames from a source, every part on the belt found and inspected as it passes (JSON lines).
    Run(run::RunArgs),
    /// The knowledge base: check a product's design, show, diff versions, start your own from the example.
    #[command(subcommand)]
    Kb(knowledge::KbCommand),
    /// Record an operator's judgement of an inspection (confirmed, false alarm, missed defect, reviewed).
    Feedback(knowledge::FeedbackArgs),
    /// List and filter past inspections; diagnose them as a batch.
    History(knowledge::HistoryArgs),
    /// Learn a new knowledge-base version from operators' feedback (cause priors, fuzzy rule parameters).
    Learn(knowledge::LearnArgs),
    /// Measure accuracy (against the simulator's ground truth) and speed.
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Fuzzy engines (FLL, FCL): evaluate, convert.
    #[command(subcommand)]
    Fuzzy(fuzzy::FuzzyCommand),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result: Result<()> = match cli.command {
        Command::Demo { out } => simulate::demo(&out),
        Command::Simulate(args) => simulate::simulate(&args).map(|_| ()),
        Command::Fuzzy(cmd) => fuzzy::run(&cmd),
        Command::Extract(args) => extract::extract(&args),
        Command::Bench(cmd) => bench::run(&cmd),
        Command::Calibrate(args) => scan::run_calibrate(&args).map(|_| ()),
        Command::Scan(args) => scan::run_scan(&args).map(|_| ()),
        Command::Inspect(args) => inspect::run_inspect(&args).map(|_| ()),
        Command::Run(args) => run::run(&args),
        Command::Kb(cmd) => knowledge::run_kb(&cmd),
        Command::Feedback(args) => knowledge::run_feedback(&args),
        Command::History(args) => knowledge::run_history(&args),
        Command::Learn(args) => knowledge::run_learn(&args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // The reader of our output stopped early (`stripe3d extract ... | head`): its choice, not a failure.
        Err(e) if broken_pipe(&e) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_text(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Ends the command after a failed write to stdout (see `say!`).
fn stdout_failed(e: std::io::Error) -> ! {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        std::process::exit(0);
    }
    eprintln!("error: cannot write the output: {e}");
    std::process::exit(1)
}

/// True when the error is a write to a pipe whose reader has gone.
fn broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// The error and its causes on one line, each cause once: errors that already quote their source (the file's
/// "cannot read: No such file or directory") would otherwise repeat it.
fn error_text(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let c = cause.to_string();
        if text.contains(&c) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&c);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::{Cli, doc_commands};
    use clap::Parser;

    /// Every `stripe3d` command in the README's and `docs/`'s shell blocks is one this binary accepts: the same
    /// subcommands, flags and values (the files they name are not opened here; the getting-started walk runs).
    #[test]
    fn every_command_in_the_documents_parses() {
        let mut count = 0;
        for doc in doc_commands::documents() {
            for c in doc_commands::commands_in(&doc) {
                count += 1;
                if let Err(e) = Cli::try_parse_from(&c.words) {
                    panic!(
                        "{}: `{}` is not a valid command:\n{e}",
                        c.place,
                        c.words.join(" ")
                    );
                }
            }
        }
        assert!(count >= 30, "only {count} commands found in the documents");
    }

    /// The extraction itself: continuations joined, comments dropped, other programs' lines and other blocks
    /// left out, and a mistyped flag caught.
    #[test]
    fn document_commands_are_read_as_a_shell_reads_them() {
        let dir = tempfile::tempdir().expect("tmp");
        let page = dir.path().join("page.md");
        std::fs::write(
            &page,
            "text\n```sh\ncargo build\nstripe3d kb init my-kb   # a comment\nstripe3d scan --sensor \"a b.toml\" \\\n    --calib c.toml --out o f\n```\n```\nstripe3d not-shell\n```\n",
        )
        .expect("write");
        let cmds = doc_commands::commands_in(&page);
        let words: Vec<Vec<String>> = cmds.iter().map(|c| c.words.clone()).collect();
        assert_eq!(
            words,
            vec![
                vec!["stripe3d", "kb", "init", "my-kb"],
                vec![
                    "stripe3d", "scan", "--sensor", "a b.toml", "--calib", "c.toml", "--out", "o",
                    "f"
                ],
            ]
        );
        assert!(cmds[1].place.ends_with("page.md:5"), "{}", cmds[1].place);
        assert!(Cli::try_parse_from(&words[1]).is_ok());
        assert!(Cli::try_parse_from(["stripe3d", "scan", "--sensr", "a.toml"]).is_err());
    }
}
