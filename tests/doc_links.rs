//! Every relative link in the docs (`README.md`, `docs/`, the crates' READMEs) names a file that
//! exists: a results file moved or renamed fails here, not in a reader's browser.

use std::path::{Path, PathBuf};

/// The Markdown files under `dir`, recursively.
fn markdown_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    for entry in entries {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            markdown_under(&path, out);
        } else if path.extension().is_some_and(|e| e == "md") {
            out.push(path);
        }
    }
}

/// The targets of the inline links `[text](target)` of a Markdown text, without a `#fragment`.
fn link_targets(text: &str) -> Vec<&str> {
    let mut targets = Vec::new();
    let mut rest = text;
    while let Some(at) = rest.find("](") {
        rest = &rest[at + 2..];
        let end = rest.find([')', ' ', '\n']).unwrap_or(rest.len());
        let target = rest[..end].split('#').next().unwrap_or("");
        targets.push(target);
        rest = &rest[end..];
    }
    targets
}

#[test]
fn link_targets_are_read_as_written() {
    let text = "a [b](docs/X.md#part) c [d](https://e.org/f) [g](#only-anchor) [h](results/i.txt)";
    assert_eq!(link_targets(text), vec!["docs/X.md", "https://e.org/f", "", "results/i.txt"]);
}

#[test]
fn every_relative_link_in_the_docs_resolves() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    markdown_under(&root.join("docs"), &mut files);
    for krate in ["ctadsa-core", "ctadsa-render", "ctadsa-ops", "ctadsa-cli"] {
        let readme = root.join(krate).join("README.md");
        if readme.exists() {
            files.push(readme);
        }
    }
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let dir = file.parent().expect("a file has a folder");
        for target in link_targets(&text) {
            if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            checked += 1;
            if !dir.join(target).exists() {
                broken.push(format!("{}: {target}", file.strip_prefix(root).unwrap_or(file).display()));
            }
        }
    }
    assert!(checked > 50, "only {checked} relative links found: is the link reader broken?");
    assert!(broken.is_empty(), "links to files that do not exist:\n{}", broken.join("\n"));
}
