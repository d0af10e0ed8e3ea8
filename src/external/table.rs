//! A feature program's output, checked: a header `frame,<value names>` and one row per frame,
//! in order. Every problem names the program, the line and, for a value, its column.

use super::ExternalError;
use crate::features::{ExternalFeatureConfig, FeatureRows, MissingValues};

/// The values of `program`'s output `text`, one row per frame in the declared order of its
/// values. `files` are the frames' paths in the dataset folder, in order: a row's `frame` is the
/// frame's index from 0 or its path.
pub(super) fn read(
    text: &[u8],
    program: &ExternalFeatureConfig,
    files: &[String],
) -> Result<FeatureRows, ExternalError> {
    let label = program.label();
    let header_error = |message: String| ExternalError::Header {
        program: label.clone(),
        message,
    };
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(text);
    let mut records = reader.records();
    let header = match records.next() {
        None => return Err(header_error("the output is empty".into())),
        Some(Err(e)) => return Err(header_error(format!("unreadable: {e}"))),
        Some(Ok(h)) => h,
    };
    if header.get(0) != Some("frame") {
        return Err(header_error(format!(
            "the first column must be `frame`, found `{}`",
            header.get(0).unwrap_or_default()
        )));
    }
    // Column of each declared value.
    let mut columns = vec![None; program.values.len()];
    for (c, name) in header.iter().enumerate().skip(1) {
        let Some(v) = program.values.iter().position(|n| n == name) else {
            return Err(header_error(format!(
                "column `{name}` is not a declared value (declared: {})",
                program.values.join(", ")
            )));
        };
        if columns[v].replace(c).is_some() {
            return Err(header_error(format!("column `{name}` appears twice")));
        }
    }
    if let Some(v) = columns.iter().position(Option::is_none) {
        return Err(header_error(format!(
            "no column for the declared value `{}`",
            program.values[v]
        )));
    }
    let columns: Vec<usize> = columns.into_iter().flatten().collect();
    let mut rows = Vec::with_capacity(files.len());
    while let Some(record) = records.next() {
        let frame = rows.len();
        let record = record.map_err(|e| ExternalError::Row {
            program: label.clone(),
            line: e.position().map_or(0, |p| p.line()),
            frame,
            column: None,
            message: format!("unreadable: {e}"),
        })?;
        let line = record.position().map_or(0, |p| p.line());
        let row_error = |column: Option<&str>, message: String| ExternalError::Row {
            program: label.clone(),
            line,
            frame,
            column: column.map(str::to_string),
            message,
        };
        if frame >= files.len() {
            return Err(ExternalError::RowCount {
                program: label.clone(),
                expected: files.len(),
                got: frame + 1 + records.count(),
            });
        }
        if record.len() != header.len() {
            return Err(row_error(
                None,
                format!("{} fields, the header has {}", record.len(), header.len()),
            ));
        }
        let named = &record[0];
        if named != frame.to_string() && named != files[frame] {
            return Err(row_error(
                Some("frame"),
                format!(
                    "`{named}` where frame {frame} (`{}`) was expected: write one row per frame, \
                     in order",
                    files[frame]
                ),
            ));
        }
        let mut values = Vec::with_capacity(columns.len());
        for (&c, name) in columns.iter().zip(&program.values) {
            let cell = &record[c];
            if cell.is_empty() || cell == "NA" {
                if program.missing == MissingValues::Error {
                    return Err(row_error(
                        Some(name),
                        "the value is missing, and the program declares none may be \
                         (set `missing = \"allowed\"` if it may)"
                            .into(),
                    ));
                }
                values.push(None);
                continue;
            }
            let value: f64 = cell
                .parse()
                .map_err(|_| row_error(Some(name), format!("`{cell}` is not a number")))?;
            if !value.is_finite() {
                return Err(row_error(
                    Some(name),
                    format!("`{cell}` is not finite: leave the cell empty for a missing value"),
                ));
            }
            values.push(Some(value));
        }
        rows.push(values);
    }
    if rows.len() != files.len() {
        return Err(ExternalError::RowCount {
            program: label,
            expected: files.len(),
            got: rows.len(),
        });
    }
    Ok(rows)
}
