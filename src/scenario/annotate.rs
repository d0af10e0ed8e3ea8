//! A scenario as TOML with a comment above every table and key (`evitrack scenario`), so that
//! the full list of settings is one command away and always matches what a run reads.
//!
//! The text is [`CheckedScenario::to_toml`]'s, unchanged apart from the comment lines, so it
//! parses back to the same scenario. Comments come from [`super::comments::KEY_COMMENTS`] by
//! dotted path; array-of-tables headers (`[[tests]]`) add no index, and a table named by the user
//! (a method under `expect.methods`, a raw `methods` table) is matched through `*`.

use super::comments::KEY_COMMENTS;

/// The annotated text and the dotted paths that found no comment (empty when every table and
/// key is explained; a test keeps it empty for the built-in default and every shipped file).
pub fn annotate(toml_text: &str) -> (String, Vec<String>) {
    let mut out = String::with_capacity(toml_text.len() * 2);
    let mut missing = Vec::new();
    let mut table = String::new();
    for line in toml_text.lines() {
        let trimmed = line.trim_start();
        if let Some(header) = table_header(trimmed) {
            table = header.to_string();
            if !out.is_empty() && !out.ends_with("\n\n") {
                out.push('\n');
            }
            push_comment(&mut out, &table, &mut missing);
        } else if let Some(key) = key_of(trimmed) {
            let path = if table.is_empty() {
                key.to_string()
            } else {
                format!("{table}.{key}")
            };
            push_comment(&mut out, &path, &mut missing);
        }
        out.push_str(line);
        out.push('\n');
    }
    missing.dedup();
    (out, missing)
}

/// The comment for a dotted path: exact, else with user-named tables replaced by `*`, else the
/// shared comment of a motion's key (`motion.KEY`) or of an expectation (`expect.KEY`).
pub fn comment_for(path: &str) -> Option<&'static str> {
    let general = generalise(path);
    let shared = shared_path(&general);
    let lookup = |wanted: &str| {
        KEY_COMMENTS
            .iter()
            .find(|(key, _)| *key == wanted)
            .map(|(_, text)| *text)
    };
    lookup(path)
        .or_else(|| lookup(&general))
        .or_else(|| shared.as_deref().and_then(lookup))
}

/// Keys whose meaning does not depend on the table: a motion's fields wherever a motion sits,
/// an expectation's fields for the evidential tracker or any named method.
fn shared_path(general: &str) -> Option<String> {
    let parts: Vec<&str> = general.split('.').collect();
    match parts.as_slice() {
        ["validation" | "calibration" | "tests", key] | ["sample", "motion", key] => {
            Some(format!("motion.{key}"))
        }
        ["expect", "methods", "*", key] => Some(format!("expect.{key}")),
        _ => None,
    }
}

fn push_comment(out: &mut String, path: &str, missing: &mut Vec<String>) {
    match comment_for(path) {
        Some(text) => {
            for line in text.lines() {
                out.push_str("# ");
                out.push_str(line);
                out.push('\n');
            }
        }
        None => missing.push(path.to_string()),
    }
}

/// `expect.methods.knn.mean_error` → `expect.methods.*.mean_error`; `methods.gp.x` →
/// `methods.*.x`: these tables are named by the user.
fn generalise(path: &str) -> String {
    let mut parts: Vec<&str> = path.split('.').collect();
    match parts.as_slice() {
        ["expect", "methods", _, ..] => parts[2] = "*",
        ["methods", _, ..] => parts[1] = "*",
        _ => {}
    }
    parts.join(".")
}

/// `[a.b]` or `[[a.b]]` → `a.b` (quoted parts unquoted).
fn table_header(line: &str) -> Option<&str> {
    let inner = line
        .strip_prefix("[[")
        .and_then(|rest| rest.strip_suffix("]]"))
        .or_else(|| {
            line.strip_prefix('[')
                .and_then(|rest| rest.strip_suffix(']'))
        })?;
    Some(inner.trim().trim_matches('"'))
}

/// The key of a `key = value` line (a bare or quoted key), none for a continuation line.
fn key_of(line: &str) -> Option<&str> {
    if line.starts_with('#') || line.is_empty() {
        return None;
    }
    let (key, _) = line.split_once(" = ")?;
    let key = key.trim();
    let bare = key.trim_matches('"');
    let valid = !bare.is_empty()
        && bare
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    valid.then_some(bare)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::ScenarioSet;

    fn paths_without_comment(set: &ScenarioSet) -> Vec<String> {
        let mut missing = Vec::new();
        for variant in std::iter::once(&set.base).chain(&set.variants) {
            let (_, lacking) = annotate(&variant.to_toml().unwrap());
            missing.extend(lacking);
        }
        missing.sort();
        missing.dedup();
        missing
    }

    #[test]
    fn every_key_of_the_default_and_of_every_shipped_scenario_is_explained() {
        let mut missing = paths_without_comment(&ScenarioSet::builtin_default().unwrap());
        let folder = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios");
        for entry in std::fs::read_dir(folder).unwrap() {
            let path = entry.unwrap().path();
            let set = ScenarioSet::load(&path).unwrap_or_else(|e| panic!("{e}"));
            missing.extend(paths_without_comment(&set));
        }
        missing.sort();
        missing.dedup();
        assert!(missing.is_empty(), "keys without a comment: {missing:?}");
    }

    #[test]
    fn the_annotated_default_parses_back_to_the_same_scenario() {
        let set = ScenarioSet::builtin_default().unwrap();
        let text = set.base.to_toml().unwrap();
        let (annotated, _) = annotate(&text);
        assert!(annotated.lines().filter(|l| l.starts_with('#')).count() > 100);
        let again = ScenarioSet::parse(&annotated, "annotated").unwrap();
        assert_eq!(again.base.to_toml().unwrap(), text);
    }

    #[test]
    fn user_named_tables_match_through_a_wildcard() {
        assert_eq!(
            generalise("expect.methods.knn.mean_error"),
            "expect.methods.*.mean_error"
        );
        assert_eq!(generalise("track.constructor"), "track.constructor");
        assert_eq!(key_of("\"model.states\" = [2, 3]"), Some("model.states"));
        assert_eq!(key_of("# x = 1"), None);
        assert_eq!(table_header("[[sweep.variant]]"), Some("sweep.variant"));
    }
}
