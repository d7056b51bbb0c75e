//! The map in ARCHITECTURE.md stays true. It names every file under each workspace crate's `src/`
//! (any file type, recursively, `target/` ignored), it names nothing that does not exist on disk,
//! and each crate root (`src/lib.rs`) names each module it declares in its `//!` doc as `` `NAME` ``
//! or `` [`NAME`] ``. The crates are the `members` of the root Cargo.toml that have a `src/`.
//!
//! The map is the fenced block (opened by ` ```text `) on the line right after the marker line
//! `<!-- map: every file under each crate's src/; tests/tests/map.rs checks it -->`.
//! Each non-empty line is a path token, then optionally whitespace and free text (which may hold
//! anything, slashes included: only the first token is a path). A token ending in `/` is a
//! directory, otherwise a file; it may hold several segments (`server/src/runtime/`). Indentation is
//! spaces: a line's parent is the nearest preceding line with less indentation whose token ends in
//! `/`, and its full path is the parent's full path plus its token; a line with no such parent is
//! relative to the repository root. A line whose first character cannot start a path (anything but
//! a letter, a digit, `_` or `.`, e.g. `#`, `-`, `|`, `(`) is a comment. A description cannot go on
//! to the next line: that line would be read as a path.
//!
//! ```text
//! protocol/                 what crosses the wire
//!   src/
//!     lib.rs                the crate root
//! server/src/               the server
//!   runtime/
//!     mod.rs
//! README.md                 named files outside a crate's src/ must exist too
//! ```

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

const MARKER: &str = "<!-- map: every file under each crate's src/; tests/tests/map.rs checks it -->";

fn repo_root() -> PathBuf {
    impact_core::scene::checkout()
}

/// The map block: the lines of the ```text fence right after the marker line.
fn map_block(markdown: &str) -> Result<String, String> {
    let mut lines = markdown.lines().skip_while(|line| line.trim_end() != MARKER);
    if lines.next().is_none() {
        return Err(format!("ARCHITECTURE.md has no map: expected a line that is exactly\n{MARKER}"));
    }
    if lines.next().map(str::trim_end) != Some("```text") {
        return Err(format!("ARCHITECTURE.md: the line after\n{MARKER}\nmust open the map with ```text"));
    }
    let mut block = Vec::new();
    for line in lines {
        if line.trim() == "```" {
            return Ok(block.join("\n"));
        }
        block.push(line);
    }
    Err("ARCHITECTURE.md: the map's ```text block is never closed".to_string())
}

/// The full path of every line of the map, in order; directories end in `/`.
fn parse_map(block: &str) -> Vec<String> {
    let mut dirs: Vec<(usize, String)> = Vec::new();
    let mut paths = Vec::new();
    for line in block.lines() {
        let text = line.trim_start();
        let indent = line.len() - text.len();
        let Some(token) = text.split_whitespace().next() else { continue };
        if !token.starts_with(|c: char| c.is_alphanumeric() || c == '_' || c == '.') {
            continue;
        }
        let parent = dirs.iter().rev().find(|(i, _)| *i < indent).map_or("", |(_, path)| path.as_str());
        let path = format!("{parent}{token}");
        if path.ends_with('/') {
            dirs.push((indent, path.clone()));
        }
        paths.push(path);
    }
    paths
}

/// The workspace members: the strings of the `members = [...]` array of the root Cargo.toml.
fn workspace_members(cargo_toml: &str) -> Vec<String> {
    let Some(start) = cargo_toml.lines().position(|line| line.trim_start().starts_with("members")) else {
        return Vec::new();
    };
    let rest = cargo_toml.lines().skip(start).collect::<Vec<_>>().join("\n");
    let array = rest.split_once('[').and_then(|(_, after)| after.split_once(']')).map_or("", |(inside, _)| inside);
    array.split('"').skip(1).step_by(2).map(str::to_string).collect()
}

/// The crates checked: members with a `src/` directory.
fn crates(root: &Path) -> Vec<String> {
    let manifest = fs::read_to_string(root.join("Cargo.toml")).expect("read the root Cargo.toml");
    workspace_members(&manifest).into_iter().filter(|member| root.join(member).join("src").is_dir()).collect()
}

/// Every file under `dir`, recursively, as a `/`-separated path relative to `root`; skips `target/`.
fn files_under(root: &Path, dir: &Path, out: &mut BTreeSet<String>) {
    for entry in fs::read_dir(dir).unwrap_or_else(|e| panic!("read {}: {e}", dir.display())) {
        let path = entry.expect("read a directory entry").path();
        if path.is_dir() {
            if path.file_name().is_some_and(|name| name != "target") {
                files_under(root, &path, out);
            }
        } else {
            let relative = path.strip_prefix(root).expect("a path under the root");
            out.insert(relative.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/"));
        }
    }
}

/// Checks 1 and 2: the files under the crates' `src/` the map misses, and the paths it names that do not exist.
fn map_problems(root: &Path) -> Result<Vec<String>, String> {
    let markdown = fs::read_to_string(root.join("ARCHITECTURE.md")).map_err(|e| format!("ARCHITECTURE.md: {e}"))?;
    let named: BTreeSet<String> = parse_map(&map_block(&markdown)?).into_iter().collect();
    let mut on_disk = BTreeSet::new();
    for member in crates(root) {
        files_under(root, &root.join(member).join("src"), &mut on_disk);
    }
    let mut problems: Vec<String> = on_disk
        .iter()
        .filter(|file| !named.contains(*file))
        .map(|file| format!("missing from the map: {file}"))
        .collect();
    for path in &named {
        let full = root.join(path.trim_end_matches('/'));
        let exists = if path.ends_with('/') { full.is_dir() } else { full.is_file() };
        if !exists {
            problems.push(format!("in the map but not on disk: {path}"));
        }
    }
    Ok(problems)
}

/// The modules a crate root declares by a line starting `mod NAME;`, `pub mod NAME;` or `pub(crate) mod NAME;`
/// (unindented, so not those inside an inline module); `#[cfg(...)]` lines above them change nothing.
fn declared_modules(source: &str) -> Vec<&str> {
    source
        .lines()
        .filter_map(|line| {
            let rest = ["pub mod ", "pub(crate) mod ", "mod "].iter().find_map(|p| line.trim_end().strip_prefix(p))?;
            rest.strip_suffix(';').filter(|name| name.chars().all(|c| c.is_alphanumeric() || c == '_'))
        })
        .collect()
}

/// The crate doc: the `//!` lines at the top of the file, before its first item.
fn crate_doc(source: &str) -> String {
    let top = source.lines().map(str::trim).take_while(|l| l.is_empty() || l.starts_with("//") || l.starts_with("#!"));
    top.filter_map(|line| line.strip_prefix("//!")).collect::<Vec<_>>().join("\n")
}

/// Check 3: each module a crate's `src/lib.rs` declares is named, backticked, in its crate doc.
fn doc_problems(root: &Path) -> Vec<String> {
    let mut problems = Vec::new();
    for member in crates(root) {
        let lib = format!("{member}/src/lib.rs");
        let Ok(source) = fs::read_to_string(root.join(&lib)) else { continue };
        let doc = crate_doc(&source);
        for name in declared_modules(&source) {
            if !doc.contains(&format!("`{name}`")) {
                problems.push(format!("{lib}: module {name} is not named in the crate doc"));
            }
        }
    }
    problems.sort();
    problems
}

#[test]
fn map_names_every_file() {
    let problems = map_problems(&repo_root()).unwrap_or_else(|e| panic!("{e}"));
    assert!(
        problems.is_empty(),
        "the map in ARCHITECTURE.md disagrees with the disk:\n{}\nfix: edit the map block after `{MARKER}` in ARCHITECTURE.md so it names every file under each crate's \
         src/ and nothing that is gone",
        problems.join("\n")
    );
}

#[test]
fn crate_docs_name_every_module() {
    let problems = doc_problems(&repo_root());
    assert!(
        problems.is_empty(),
        "a crate doc does not name a module it declares:\n{}\nfix: name each module in its crate root's `//!` doc as `name` or [`name`]",
        problems.join("\n")
    );
}

#[test]
fn the_parser_nests_dedents_and_skips_comments() {
    let block = "
# a comment, and a blank line above
protocol/                 what crosses the wire: ids/ and codec.rs are words here
  src/
    lib.rs                the crate root
      (a comment deeper in)
    ids.rs
server/src/runtime/       several segments in one token
  mod.rs
  server/
    tick.rs               the tick loop
  egress.rs               back to runtime/ after the dedent
- a list item is a comment
README.md
";
    let expected = [
        "protocol/",
        "protocol/src/",
        "protocol/src/lib.rs",
        "protocol/src/ids.rs",
        "server/src/runtime/",
        "server/src/runtime/mod.rs",
        "server/src/runtime/server/",
        "server/src/runtime/server/tick.rs",
        "server/src/runtime/egress.rs",
        "README.md",
    ];
    assert_eq!(parse_map(block), expected);
}

#[test]
fn the_block_follows_the_marker() {
    let markdown = format!("# Title\n```text\nnot/this\n```\n{MARKER}\n```text\na/\n  b.rs\n```\nafter.rs\n");
    assert_eq!(map_block(&markdown).map(|block| parse_map(&block)), Ok(vec!["a/".to_string(), "a/b.rs".to_string()]));
    assert!(map_block("no marker here").unwrap_err().contains(MARKER));
    assert!(map_block(&format!("{MARKER}\n\n```text\n```")).is_err());
}

#[test]
fn the_checks_find_every_problem_in_a_fixture() {
    let root = std::env::temp_dir().join(format!("impact-map-test-{}", std::process::id()));
    let write = |path: &str, text: &str| {
        let path = root.join(path);
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(path, text).unwrap();
    };
    write("Cargo.toml", "[workspace]\nmembers = [\n  \"a\",\n  \"b\", \"nosrc\",\n]\nexclude = [\"c\"]\n");
    write(
        "ARCHITECTURE.md",
        &format!("{MARKER}\n```text\na/src/\n  lib.rs  the root of a/\n  gone.rs\nREADME.md\n```\n"),
    );
    write("a/src/lib.rs", "//! The [`x`] module.\n\npub mod x;\n#[cfg(test)]\nmod y;\npub(crate) mod z;\n");
    write("a/src/x.rs", "");
    write("a/src/target/skipped.rs", "");
    write("b/src/bin/tool/main.rs", "mod helper;\n");
    write("c/src/unlisted.rs", "");
    write("nosrc/README.md", "");
    let (map, docs) = (map_problems(&root), doc_problems(&root));
    fs::remove_dir_all(&root).unwrap();
    let expected = [
        "missing from the map: a/src/x.rs",
        "missing from the map: b/src/bin/tool/main.rs",
        "in the map but not on disk: README.md",
        "in the map but not on disk: a/src/gone.rs",
    ];
    assert_eq!(map, Ok(expected.map(str::to_string).to_vec()));
    let expected = [
        "a/src/lib.rs: module y is not named in the crate doc",
        "a/src/lib.rs: module z is not named in the crate doc",
    ];
    assert_eq!(docs, expected);
}
