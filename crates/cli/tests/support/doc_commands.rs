//! The `stripe3d` commands written in the documents' shell blocks (```` ```sh ````), so that tests can parse and
//! run them exactly as a reader would type them: the documents cannot drift from the command.

use std::path::{Path, PathBuf};

/// One command found in a document.
pub struct DocCommand {
    /// The document and the line the command starts on, `docs/x.md:12`.
    pub place: String,
    /// Its words as a POSIX shell splits them, `stripe3d` first.
    pub words: Vec<String>,
}

/// The repository's root folder.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The documents: `README.md` and every Markdown page of `docs/`, in name order.
pub fn documents() -> Vec<PathBuf> {
    let root = repo_root();
    let mut pages: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ folder")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    pages.sort();
    pages.insert(0, root.join("README.md"));
    pages
}

/// Every `stripe3d` command in the shell blocks of `path`; a line ending in `\` continues on the next.
pub fn commands_in(path: &Path) -> Vec<DocCommand> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let name = path
        .strip_prefix(repo_root())
        .unwrap_or(path)
        .display()
        .to_string();
    let (mut in_block, mut is_sh) = (false, false);
    let mut pending: Option<(usize, String)> = None;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with("```") {
            is_sh = !in_block && t == "```sh";
            in_block = !in_block;
            assert!(
                pending.is_none(),
                "{name}:{}: a `\\` continues into the block's end",
                n + 1
            );
            continue;
        }
        if !(in_block && is_sh) {
            continue;
        }
        let (start, mut command) = pending.take().unwrap_or((n + 1, String::new()));
        if let Some(head) = line.trim_end().strip_suffix('\\') {
            command.push_str(head);
            command.push(' ');
            pending = Some((start, command));
            continue;
        }
        command.push_str(line);
        let words = shlex::split(&command).unwrap_or_else(|| {
            panic!("{name}:{start}: the shell cannot split this line (a quote left open)")
        });
        if words.first().is_some_and(|w| w == "stripe3d") {
            out.push(DocCommand {
                place: format!("{name}:{start}"),
                words,
            });
        }
    }
    out
}
