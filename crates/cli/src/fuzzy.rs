//! `stripe3d fuzzy`: evaluate and convert fuzzy engines (FLL, FCL) from the command line.

use anyhow::{Context, Result, bail};
use clap::Subcommand;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use stripe3d_fuzzy::{Engine, FuzzyError, fcl, fld, fll};

/// Largest inputs table read, bytes.
const MAX_TABLE_BYTES: u64 = 512 << 20;

/// Subcommands of `stripe3d fuzzy`.
#[derive(Debug, Subcommand)]
pub enum FuzzyCommand {
    /// Evaluate an engine on a table of inputs (FLD: a header of names, then rows of numbers).
    ///
    /// Rows are evaluated in order on one engine. Output (stdout) is FLD: the input names then the output
    /// names, and per row the inputs followed by the outputs, 9 decimals, `nan` for NaN.
    Eval {
        /// The engine: an .fll or .fcl file.
        engine: PathBuf,
        /// The inputs table [default: standard input]. Columns are matched to input variables by name; other
        /// columns are ignored.
        #[arg(long)]
        inputs: Option<PathBuf>,
    },
    /// Print an engine (.fll or .fcl) as FLL.
    Export {
        /// The engine: an .fll or .fcl file.
        engine: PathBuf,
    },
}

fn located(path: &Path, e: FuzzyError) -> anyhow::Error {
    match e {
        FuzzyError::Syntax { line, message } if line > 0 => {
            anyhow::anyhow!("{}:{line}: {message}", path.display())
        }
        other => anyhow::anyhow!("{}: {other}", path.display()),
    }
}

/// Loads an engine from an FLL or FCL file (by extension, or by content when the extension says neither).
pub fn load_engine(path: &Path) -> Result<Engine> {
    let meta =
        std::fs::metadata(path).with_context(|| format!("{}: cannot read", path.display()))?;
    if meta.len() > fll::MAX_FLL_BYTES as u64 {
        bail!(
            "{}: {} bytes is larger than an engine may be ({} bytes)",
            path.display(),
            meta.len(),
            fll::MAX_FLL_BYTES
        );
    }
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read as text", path.display()))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let is_fcl = match ext.as_deref() {
        Some("fcl") => true,
        Some("fll") => false,
        _ => text.contains("FUNCTION_BLOCK"),
    };
    if is_fcl {
        fcl::read(&text)
    } else {
        fll::read(&text)
    }
    .map_err(|e| located(path, e))
}

/// Runs `stripe3d fuzzy ...`.
pub fn run(cmd: &FuzzyCommand) -> Result<()> {
    match cmd {
        FuzzyCommand::Eval { engine, inputs } => {
            let mut e = load_engine(engine)?;
            let (name, text) = match inputs {
                Some(p) => {
                    let mut s = String::new();
                    std::fs::File::open(p)
                        .with_context(|| format!("{}: cannot read", p.display()))?
                        .take(MAX_TABLE_BYTES)
                        .read_to_string(&mut s)
                        .with_context(|| format!("{}: cannot read as text", p.display()))?;
                    (p.display().to_string(), s)
                }
                None => {
                    let mut s = String::new();
                    std::io::stdin()
                        .take(MAX_TABLE_BYTES)
                        .read_to_string(&mut s)
                        .context("standard input")?;
                    ("<stdin>".to_string(), s)
                }
            };
            let out = fld::evaluate(&mut e, &text).map_err(|err| match err {
                FuzzyError::Syntax { line, message } => anyhow::anyhow!("{name}:{line}: {message}"),
                other => anyhow::anyhow!("{name}: {other}"),
            })?;
            // Checked, not `print!`: a reader that stops early ends the run quietly (main), not with a panic.
            std::io::stdout().lock().write_all(out.as_bytes())?;
            Ok(())
        }
        FuzzyCommand::Export { engine } => {
            std::io::stdout()
                .lock()
                .write_all(fll::write(&load_engine(engine)?).as_bytes())?;
            Ok(())
        }
    }
}
