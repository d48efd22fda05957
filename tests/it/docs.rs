//! The documentation's house rules (issue 59): the README stays short, every relative link in
//! README.md and docs/*.md leads to a file (and, for `page.md#anchor`, to a heading of that
//! page), every docs page is linked from the README, and `--help` holds no dates and no timings
//! of particular runs (those belong in docs/benchmarks.md and docs/experiments.md).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The README's budget: five minutes of reading.
const README_MAX_BYTES: u64 = 15 * 1024;

#[test]
fn the_readme_is_at_most_15_kib() {
    let len = std::fs::metadata(Path::new(ROOT).join("README.md"))
        .unwrap()
        .len();
    assert!(
        len <= README_MAX_BYTES,
        "README.md is {len} bytes, over {README_MAX_BYTES}: move the detail into a page under docs/"
    );
}

/// README.md and every `docs/*.md`.
fn pages() -> Vec<PathBuf> {
    let mut pages = vec![Path::new(ROOT).join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    pages.extend(docs);
    pages
}

/// The text outside fenced code blocks and inline code spans, where Markdown links live.
fn prose(markdown: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            out.push('\n');
            continue;
        }
        if fenced {
            out.push('\n');
            continue;
        }
        // Drop `code` spans (a table cell may show `[--flag]` syntax next to a parenthesis).
        let mut in_code = false;
        for c in line.chars() {
            if c == '`' {
                in_code = !in_code;
            } else if !in_code {
                out.push(c);
            }
        }
        out.push('\n');
    }
    out
}

/// The targets of the inline links `[text](target)` and images `![alt](target)` in `markdown`.
fn link_targets(markdown: &str) -> Vec<String> {
    let text = prose(markdown);
    let mut targets = Vec::new();
    let mut rest = text.as_str();
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                // `[a](b "title")`: the target is the part before the first space.
                let target = after[..j].split_whitespace().next().unwrap_or("");
                targets.push(target.trim_matches(['<', '>']).to_owned());
                rest = &after[j + 1..];
            }
            None => break,
        }
    }
    targets
}

/// GitHub's anchor for a heading: lower case, spaces to hyphens, punctuation dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| {
            if c == ' ' {
                Some('-')
            } else if c.is_alphanumeric() || c == '-' || c == '_' {
                Some(c)
            } else {
                None
            }
        })
        .collect()
}

/// The anchors of a page's headings (`#`-style, outside code blocks), with GitHub's `-1`, `-2`
/// suffixes for repeated headings.
fn anchors(markdown: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced || !line.starts_with('#') {
            continue;
        }
        let heading = line.trim_start_matches('#');
        if !heading.starts_with(' ') {
            continue;
        }
        let base = slug(heading);
        let mut anchor = base.clone();
        let mut n = 0;
        while seen.contains(&anchor) {
            n += 1;
            anchor = format!("{base}-{n}");
        }
        seen.insert(anchor);
    }
    seen
}

fn is_external(target: &str) -> bool {
    target.contains("://") || target.starts_with("mailto:")
}

/// Every relative link of `page` that leads nowhere, as "target: why".
fn broken_links(page: &Path) -> (usize, Vec<String>) {
    let text = std::fs::read_to_string(page).unwrap();
    let dir = page.parent().unwrap();
    let mut checked = 0;
    let mut broken = Vec::new();
    for target in link_targets(&text) {
        if target.is_empty() || is_external(&target) {
            continue;
        }
        checked += 1;
        let (file, anchor) = match target.split_once('#') {
            Some((f, a)) => (f, Some(a)),
            None => (target.as_str(), None),
        };
        let resolved = if file.is_empty() {
            page.to_path_buf()
        } else {
            dir.join(file)
        };
        if !resolved.exists() {
            broken.push(format!("{target}: no file {}", resolved.display()));
            continue;
        }
        if let Some(anchor) = anchor
            && resolved.extension().is_some_and(|e| e == "md")
        {
            let heads = anchors(&std::fs::read_to_string(&resolved).unwrap());
            if !heads.contains(anchor) {
                broken.push(format!(
                    "{target}: {} has no heading with anchor #{anchor}",
                    resolved.display()
                ));
            }
        }
    }
    (checked, broken)
}

#[test]
fn every_relative_link_in_the_readme_and_docs_resolves() {
    let mut checked = 0;
    let mut broken = Vec::new();
    for page in pages() {
        let (n, b) = broken_links(&page);
        checked += n;
        broken.extend(b.into_iter().map(|b| format!("{}: {b}", page.display())));
    }
    assert!(
        checked >= 10,
        "only {checked} relative links found: is the link parser still reading the pages?"
    );
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_readme_links_every_docs_page() {
    let readme = std::fs::read_to_string(Path::new(ROOT).join("README.md")).unwrap();
    let linked: BTreeSet<String> = link_targets(&readme)
        .into_iter()
        .map(|t| t.split('#').next().unwrap_or("").to_owned())
        .collect();
    let missing: Vec<String> = pages()
        .iter()
        .skip(1)
        .map(|p| format!("docs/{}", p.file_name().unwrap().to_string_lossy()))
        .filter(|p| !linked.contains(p))
        .collect();
    assert!(
        missing.is_empty(),
        "README.md does not link these docs pages: {missing:?}"
    );
}

#[test]
fn the_link_checker_catches_a_broken_link_and_anchor() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("b.md"), "# Some heading: `rig run`\n").unwrap();
    let page = dir.path().join("a.md");
    std::fs::write(
        &page,
        "[ok](b.md) [ok](b.md#some-heading-rig-run) [web](https://example.org/x)\n\
         `[not a link](nowhere.md)`\n\
         [gone](missing.md) [bad anchor](b.md#other)\n",
    )
    .unwrap();
    let (checked, broken) = broken_links(&page);
    assert_eq!(checked, 4);
    assert_eq!(broken.len(), 2, "{broken:?}");
    assert!(broken[0].starts_with("missing.md"));
    assert!(broken[1].starts_with("b.md#other"));
}

/// `rig … --help`'s text (long help: it includes the long descriptions of enum values).
fn help(path: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(path)
        .arg("--help")
        .output()
        .expect("run the rig binary");
    assert!(
        out.status.success(),
        "rig {} --help failed: {}",
        path.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The subcommand names listed under "Commands:" in a help text (`help` itself left out).
fn subcommands(help: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut in_list = false;
    for line in help.lines() {
        if line.trim_end() == "Commands:" {
            in_list = true;
            continue;
        }
        if in_list {
            if !line.starts_with("  ") {
                break;
            }
            // An entry is "  name  what it does"; a wrapped description is indented further.
            if line.starts_with("   ") {
                continue;
            }
            if let Some(name) = line.split_whitespace().next()
                && name != "help"
            {
                names.push(name.to_owned());
            }
        }
    }
    names
}

/// What a help text must not hold, as "why: the context": a date (`2026-11-30`), a year after
/// "on" ("on 2026's VM"), "measured on", "took" with a figure, or "N min on" / "N s on" (the
/// time one run took on one machine).
fn dated_or_timed(text: &str) -> Vec<String> {
    let b = text.as_bytes();
    let digit = |i: usize| b.get(i).is_some_and(|c| c.is_ascii_digit());
    let mut found = Vec::new();
    let context = |i: usize| {
        let lo = text.floor_char_boundary(i.saturating_sub(30));
        let hi = text.ceil_char_boundary((i + 40).min(text.len()));
        text[lo..hi].replace('\n', " ")
    };
    for (i, &c) in b.iter().enumerate() {
        // 20YY-MM-DD, not inside a longer number.
        if c == b'2'
            && b.get(i + 1) == Some(&b'0')
            && (i == 0 || !b[i - 1].is_ascii_digit())
            && digit(i + 2)
            && digit(i + 3)
            && b.get(i + 4) == Some(&b'-')
            && digit(i + 5)
            && digit(i + 6)
            && b.get(i + 7) == Some(&b'-')
            && digit(i + 8)
            && digit(i + 9)
        {
            found.push(format!("a date: …{}…", context(i)));
        }
    }
    let lower = text.to_lowercase();
    let lb = lower.as_bytes();
    for (pattern, why) in [
        ("measured on", "a measurement's occasion"),
        ("on 20", "a year"),
        ("took ", "a run's time"),
        (" min on ", "a run's time"),
        (" s on ", "a run's time"),
    ] {
        let mut from = 0;
        while let Some(k) = lower[from..].find(pattern) {
            let i = from + k;
            from = i + pattern.len();
            let after = i + pattern.len();
            let hit = match pattern {
                // A year of this project's era, "on 2020" to "on 2039", not "on 2048 images".
                "on 20" => {
                    lb.get(after).is_some_and(|c| matches!(c, b'2' | b'3'))
                        && lb.get(after + 1).is_some_and(|c| c.is_ascii_digit())
                        && !lb.get(after + 2).is_some_and(|c| c.is_ascii_digit())
                }
                // "took 5.4 min", "took about 47 min".
                "took " => lower[after..]
                    .split_whitespace()
                    .take(2)
                    .any(|w| w.starts_with(|c: char| c.is_ascii_digit())),
                // "47 min on", "383 s on": a figure just before.
                " min on " | " s on " => i > 0 && lb[i - 1].is_ascii_digit(),
                _ => true,
            };
            if hit {
                found.push(format!("{why}: …{}…", context(i)));
            }
        }
    }
    found
}

#[test]
fn the_help_checker_catches_dates_and_run_timings() {
    for bad in [
        "47 min end to end on 2 cores on 2026-11-30",
        "(383 s on an AVX-512 VM)",
        "p99 3.9 ms, measured on the CI machine",
        "the translation took 5.4 min",
        "as fast as on 2026's VM",
    ] {
        assert!(!dated_or_timed(bad).is_empty(), "not caught: {bad:?}");
    }
    for good in [
        "Run the simulated clock this many times faster than real time [default: 10]",
        "sized to finish in under two hours on 2 CPU cores",
        "How long to stream or check, seconds [default: 3]",
        "a few minutes; 20 epochs on 2 cores",
        "FID on 2048 images of each set",
        "One 320×240 frame; the goal is 240 trajectories in 3 min",
    ] {
        assert!(
            dated_or_timed(good).is_empty(),
            "false alarm on {good:?}: {:?}",
            dated_or_timed(good)
        );
    }
}

#[test]
fn no_help_text_holds_a_date_or_a_run_timing() {
    let mut visited = Vec::new();
    let mut problems = Vec::new();
    let mut queue: Vec<Vec<String>> = vec![Vec::new()];
    while let Some(path) = queue.pop() {
        let args: Vec<&str> = path.iter().map(String::as_str).collect();
        let text = help(&args);
        for p in dated_or_timed(&text) {
            problems.push(format!("rig {} --help: {p}", args.join(" ")));
        }
        for sub in subcommands(&text) {
            let mut child = path.clone();
            child.push(sub);
            queue.push(child);
        }
        visited.push(format!("rig {}", args.join(" ")).trim_end().to_owned());
    }
    // The walk must reach the nested commands, or it checks nothing of them.
    for must in [
        "rig",
        "rig run",
        "rig reproduce",
        "rig demo",
        "rig bench run",
        "rig bench train",
        "rig train force",
        "rig ft tare",
        "rig sim render",
        "rig dataset export",
    ] {
        assert!(
            visited.iter().any(|v| v == must),
            "`{must} --help` was not visited (visited: {visited:?})"
        );
    }
    assert!(
        problems.is_empty(),
        "help text must say what and how; dates and run timings go to docs/benchmarks.md or \
         docs/experiments.md:\n{}",
        problems.join("\n")
    );
}
