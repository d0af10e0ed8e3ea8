//! `report.html` of a run and of a sweep: well-formed, self-contained, every plot it names
//! embedded as a valid PNG and on disk; the sweep's plots read back for their intervals.

use std::path::Path;

use super::*;

/// Elements without a closing tag.
const VOID: [&str; 4] = ["meta", "img", "br", "hr"];

/// A strict well-formedness check: every element closed in order (void elements excepted), every
/// attribute value quoted, no `<` or `>` in text, `&` only opening an entity.
fn check_html(html: &str) -> Result<(), String> {
    let rest = html.strip_prefix("<!DOCTYPE html>").ok_or("no doctype")?;
    let mut open: Vec<String> = Vec::new();
    let mut text = rest;
    while let Some(start) = text.find(['<', '>']) {
        check_text(&text[..start])?;
        if text[start..].starts_with('>') {
            return Err(format!("stray `>` before {:.40}", &text[start..]));
        }
        let end = text[start..].find('>').ok_or("unclosed tag")? + start;
        let tag = &text[start + 1..end];
        if tag.contains('<') {
            return Err(format!("`<` inside tag {tag:.40}"));
        }
        if let Some(name) = tag.strip_prefix('/') {
            match open.pop() {
                Some(top) if top == name => {}
                other => return Err(format!("</{name}> closes {other:?}")),
            }
        } else {
            let name: String = tag
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric())
                .collect();
            if name.is_empty() {
                return Err(format!("bad tag <{tag:.40}>"));
            }
            check_attributes(&tag[name.len()..])?;
            if !VOID.contains(&name.as_str()) {
                open.push(name);
            }
        }
        text = &text[end + 1..];
    }
    check_text(text)?;
    if open.is_empty() {
        Ok(())
    } else {
        Err(format!("never closed: {open:?}"))
    }
}

fn check_text(text: &str) -> Result<(), String> {
    for (i, _) in text.match_indices('&') {
        let entity = &text[i..text.len().min(i + 8)];
        if !["&amp;", "&lt;", "&gt;", "&quot;", "&#39;"]
            .iter()
            .any(|e| entity.starts_with(e))
        {
            return Err(format!("bare `&` in {entity}"));
        }
    }
    Ok(())
}

/// ` name="value"` pairs, nothing else.
fn check_attributes(mut rest: &str) -> Result<(), String> {
    loop {
        rest = rest.trim_start();
        if rest.is_empty() {
            return Ok(());
        }
        let eq = rest
            .find('=')
            .ok_or(format!("attribute without value: {rest:.40}"))?;
        let name = &rest[..eq];
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-') {
            return Err(format!("bad attribute name `{name}`"));
        }
        let value = rest[eq + 1..]
            .strip_prefix('"')
            .ok_or("unquoted attribute")?;
        let close = value.find('"').ok_or("unclosed attribute")?;
        check_text(&value[..close])?;
        rest = &value[close + 1..];
    }
}

fn decode_base64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {}", c as char),
    };
    let mut out = Vec::new();
    for chunk in text.as_bytes().chunks(4) {
        let n = chunk.iter().take_while(|&&c| c != b'=').count();
        let bits = (chunk[..n].iter()).fold(0u32, |acc, &c| (acc << 6) | u32::from(value(c)));
        let bits = bits << (6 * (4 - n));
        out.extend(&[(bits >> 16) as u8, (bits >> 8) as u8, bits as u8][..n - 1]);
    }
    out
}

/// Every embedded image: (the file it names, its bytes), each checked to decode as a PNG and to
/// equal the file of that name in `dir`.
fn images(html: &str, dir: &Path) -> Vec<String> {
    let mut names = Vec::new();
    for part in html.split("<img src=\"").skip(1) {
        let data = part
            .strip_prefix("data:image/png;base64,")
            .expect("embedded, not linked");
        let (data, rest) = data.split_once('"').unwrap();
        let name = rest
            .split("alt=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        let bytes = decode_base64(data);
        image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
            .unwrap_or_else(|e| panic!("{name}: not a PNG: {e}"));
        assert_eq!(std::fs::read(dir.join(name)).unwrap(), bytes, "{name}");
        names.push(name.to_string());
    }
    names
}

#[test]
fn the_html_check_is_strict() {
    assert!(check_html("<!DOCTYPE html><p>a &amp; b<img src=\"x\"></p>").is_ok());
    for bad in [
        "<p>a</p>",
        "<!DOCTYPE html><p>a",
        "<!DOCTYPE html><p><b>a</p></b>",
        "<!DOCTYPE html><p>a & b</p>",
        "<!DOCTYPE html><p>a > b</p>",
        "<!DOCTYPE html><p class=x>a</p>",
    ] {
        assert!(check_html(bad).is_err(), "{bad}");
    }
    assert_eq!(decode_base64("Zm9vYmE="), b"fooba");
}

#[test]
fn a_runs_report_holds_its_tables_methods_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("struck.toml");
    let faults = "faults = [{ kind = \"stuck\", features = [\"size_line0\"], value = 2.5, \
                  units = \"sd\", share = 0.3 }]\n";
    std::fs::write(
        &scenario,
        format!("{faults}{}", small_scenario("struck", "")),
    )
    .unwrap();
    let out = dir.path().join("out");
    run_expecting("run", &scenario, &out, 0);
    let run = out.join("struck");
    let html = std::fs::read_to_string(run.join("report.html")).unwrap();
    check_html(&html).unwrap();
    assert!(!html.contains("<script") && !html.contains("src=\"http"));
    let names = images(&html, &run);
    for plot in [
        "errors-test0-circle.png",
        "track-test0-circle.png",
        "track-test0-circle-knn.png",
        "risk-coverage.png",
        "roc.png",
    ] {
        assert!(names.iter().any(|n| n == plot), "{plot} not in {names:?}");
    }
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("results.json")).unwrap()).unwrap();
    for method in results["methods"].as_array().unwrap() {
        let name = method["method"].as_str().unwrap();
        assert!(html.contains(&format!("<td>{name}</td>")), "{name} missing");
    }
    for section in ["<h2>Errors</h2>", "<h2>Faults</h2>", "<h2>Confidence</h2>"] {
        assert!(html.contains(section), "{section}");
    }
    // The error over time shades the struck frames.
    let errors = image::open(run.join("errors-test0-circle.png"))
        .unwrap()
        .to_rgb8();
    let shade = evitrack::report::FAULT_SHADE;
    assert!(errors.pixels().any(|p| p.0 == [shade.0, shade.1, shade.2]));
}

#[test]
fn a_sweeps_report_and_plots_show_intervals_with_seeds() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("noisy.toml");
    let extra = "[sweep.grid]\n\"sim.noise.sigma\" = [0.0, 8.0]\n\
                 [[sweep.finding]]\nname = \"noise < none\"\nleft = \"noise.sigma=8.0\"\n\
                 right = \"noise.sigma=0.0\"\n";
    std::fs::write(&scenario, small_scenario("noisy", extra)).unwrap();
    let (one, three) = (dir.path().join("one"), dir.path().join("three"));
    run_expecting("sweep", &scenario, &one, 0);
    let out = evitrack(
        &[
            "sweep",
            scenario.to_str().unwrap(),
            "--out",
            three.to_str().unwrap(),
            "--seeds",
            "3",
        ],
        "",
    );
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let interval = evitrack::report::INTERVAL;
    let evidential = evitrack::report::method_colour("evidential");
    let pixels = |dir: &Path, file: &str, c: (u8, u8, u8)| {
        let image = image::open(dir.join(file)).unwrap().to_rgb8();
        image.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count()
    };
    for file in ["sweep-errors.png", "sweep-setting.png"] {
        let i = (interval.0, interval.1, interval.2);
        assert_eq!(pixels(&one, file, i), 0, "{file}: one seed, no interval");
        assert!(
            pixels(&three, file, i) > 20,
            "{file}: intervals with --seeds 3"
        );
        let e = (evidential.0, evidential.1, evidential.2);
        assert!(pixels(&one, file, e) > 50, "{file}: the evidential colour");
        assert_ne!(
            std::fs::read(one.join(file)).unwrap(),
            std::fs::read(three.join(file)).unwrap()
        );
    }
    for (dir, seeds) in [(&one, false), (&three, true)] {
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        check_html(&html).unwrap();
        let names = images(&html, dir);
        assert_eq!(names, ["sweep-errors.png", "sweep-setting.png"]);
        assert_eq!(html.contains("<h2>Across seeds</h2>"), seeds);
        // The stated finding, in words.
        let said = html.split("<li class=\"").nth(1).unwrap();
        let verdict = if seeds {
            "noise &lt; none: "
        } else {
            "noise &lt; none: untested: one seed"
        };
        assert!(said.contains(verdict), "{said:.200}");
    }
    let run_page = one.join("noisy-noise.sigma=0.0/report.html");
    check_html(&std::fs::read_to_string(run_page).unwrap()).unwrap();
}
