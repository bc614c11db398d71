//! CSV output of the figures: a `#` comment header with the parameters, a column-name line,
//! then the rows.

use super::{FigureError, Written};
use std::fmt::Write as _;
use std::path::Path;

/// The start of a CSV text: each of `comment` as a `# ` line, then the `columns` line.
pub fn csv_head(comment: &[&str], columns: &str) -> String {
    let mut s = String::new();
    for c in comment {
        let _ = writeln!(s, "# {c}");
    }
    let _ = writeln!(s, "{columns}");
    s
}

/// Writes `out/name` with `header` lines (each prefixed by `# `), `columns`, and `rows`.
pub fn write_csv(
    out: &Path,
    name: &str,
    header: &[String],
    columns: &str,
    rows: &[String],
    written: &mut Written,
) -> Result<(), FigureError> {
    let mut s = String::new();
    for h in header {
        let _ = writeln!(s, "# {h}");
    }
    let _ = writeln!(s, "{columns}");
    for r in rows {
        let _ = writeln!(s, "{r}");
    }
    let path = out.join(name);
    std::fs::write(&path, s).map_err(|e| FigureError {
        path: path.clone(),
        message: e.to_string(),
    })?;
    written.files.push(path);
    Ok(())
}

/// Parses a CSV written by [`write_csv`]: (header comment lines, column names, rows of fields).
pub fn read_csv(text: &str) -> (Vec<String>, Vec<String>, Vec<Vec<String>>) {
    let mut header = Vec::new();
    let mut columns = Vec::new();
    let mut rows = Vec::new();
    for line in text.lines() {
        if let Some(h) = line.strip_prefix("# ") {
            header.push(h.to_string());
        } else if columns.is_empty() {
            columns = line.split(',').map(str::to_string).collect();
        } else if !line.is_empty() {
            rows.push(line.split(',').map(str::to_string).collect());
        }
    }
    (header, columns, rows)
}
