//! Checks over every page (the README and `docs/*.md`): each `<!-- checked: NAME -->` marker
//! is one a per-page file checks and each check has its marker once, every relative link and
//! anchor resolves, and the pages speak of the product only.

use super::helpers::{read, root};
use std::collections::BTreeSet;

/// The pages: the README and every `docs/*.md`, as (path from the root, text).
fn pages() -> Vec<(String, String)> {
    let mut names: Vec<String> = std::fs::read_dir(root().join("docs"))
        .expect("docs/")
        .map(|e| {
            e.expect("docs/ entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.ends_with(".md"))
        .map(|n| format!("docs/{n}"))
        .collect();
    names.sort();
    names.insert(0, "README.md".into());
    names.into_iter().map(|n| (n.clone(), read(&n))).collect()
}

/// The checked tables, by marker name.
const CHECKED: [&str; 32] = [
    "m7-costs",
    "m7-targets",
    "frontier",
    "accuracy-rms-crlb",
    "accuracy-crlb",
    "failure-maps",
    "low-snr-detection",
    "fig-minima",
    "fig5-fig6",
    "star-flags",
    "star-provenance",
    "frame-obstructions",
    "tracker-config",
    "tracker-memory",
    "readout-plan",
    "accuracy-width-unknown",
    "psf-shapes",
    "accuracy-frames",
    "accuracy-frames-field",
    "trail-bound",
    "trail-rates",
    "acquisition-rates",
    "sil-rates",
    "bright-availability",
    "first-attitude",
    "exposure-chart",
    "ident-tetra3rs",
    "realsky-tetra3rs",
    "realsky-optics",
    "realsky-optics-residuals",
    "realsky-more",
    "pil-figures",
];

#[test]
fn every_marker_is_checked_and_every_check_has_its_marker() {
    let mut seen = Vec::new();
    for (page, text) in pages() {
        for l in text.lines() {
            if let Some(rest) = l.trim().strip_prefix("<!-- checked: ") {
                let name = rest.strip_suffix(" -->").expect("marker ends with -->");
                assert!(
                    CHECKED.contains(&name),
                    "{page}: marker {name:?} is not checked by host-tests/tests/cli/docs_numbers/"
                );
                seen.push(name.to_string());
            }
        }
    }
    for name in CHECKED {
        let n = seen.iter().filter(|s| s.as_str() == name).count();
        assert_eq!(n, 1, "marker {name:?} appears {n} times in the pages");
    }
}

/// GitHub's anchor of a heading: lower case, punctuation but `-` and `_` dropped, spaces as
/// `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The lines of a page outside fenced code blocks.
fn prose(text: &str) -> Vec<&str> {
    let mut fenced = false;
    text.lines()
        .filter(|l| {
            if l.trim_start().starts_with("```") {
                fenced = !fenced;
                return false;
            }
            !fenced
        })
        .collect()
}

/// The anchors of a page's headings.
fn anchors(text: &str) -> BTreeSet<String> {
    prose(text)
        .iter()
        .filter_map(|l| {
            let t = l.trim_start_matches('#');
            (l.starts_with('#') && t.starts_with(' ')).then(|| slug(t))
        })
        .collect()
}

/// The targets of a line's markdown links and images, `[text](target)`.
fn link_targets(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                out.push(after[..j].to_string());
                rest = &after[j + 1..];
            }
            None => break,
        }
    }
    out
}

#[test]
fn every_relative_link_resolves() {
    let mut checked = 0;
    for (page, text) in pages() {
        let dir = root().join(&page).parent().unwrap().to_path_buf();
        for line in prose(&text) {
            for target in link_targets(line) {
                if target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                let (path, anchor) = match target.split_once('#') {
                    Some((p, a)) => (p, Some(a)),
                    None => (target.as_str(), None),
                };
                let file = if path.is_empty() {
                    root().join(&page)
                } else {
                    dir.join(path)
                };
                assert!(
                    file.exists(),
                    "{page}: link {target} -> {} does not exist",
                    file.display()
                );
                if let Some(a) = anchor {
                    let text = std::fs::read_to_string(&file).expect("a linked page");
                    assert!(
                        anchors(&text).contains(a),
                        "{page}: link {target}: no heading #{a} in {}",
                        file.display()
                    );
                }
                checked += 1;
            }
        }
    }
    assert!(
        checked > 20,
        "only {checked} links found: is the parser broken?"
    );
}

#[test]
fn pages_speak_of_the_product() {
    for (page, text) in pages() {
        let lower = text.to_lowercase();
        // Phrases of a development log, not of the product ("at the time of" is followed by
        // "writing": split so that this file does not read as one).
        let dated = ["at the time of", " writing"].concat();
        for word in ["session", dated.as_str()] {
            assert!(!lower.contains(word), "{page}: {word:?}");
        }
        for (i, _) in lower.match_indices("issue") {
            let next = lower[i + 5..].trim_start_matches([' ', '\'', 's']);
            assert!(
                !next.starts_with(|c: char| c.is_ascii_digit()),
                "{page}: an issue number: {:?}",
                &text[i..(i + 12).min(text.len())]
            );
        }
    }
}
