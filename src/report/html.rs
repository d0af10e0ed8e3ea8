//! `report.html`: one self-contained page (inline CSS, plots embedded as base64 PNG, no script)
//! that a browser opens without a network.

use std::fmt::Write as _;
use std::path::Path;

use super::{ReportError, Table};

/// The page's style: readable tables, plots as wide as the page allows.
const STYLE: &str = "body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;\
color:#222}table{border-collapse:collapse;margin:0.5em 0 1.5em;font-size:0.85em}\
th,td{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#eee}\
td:first-child,td:nth-child(2){text-align:left}img{max-width:100%;border:1px solid #ddd}\
figure{margin:1em 0}figcaption{color:#555;font-size:0.9em}.holds{color:#060}\
.fails{color:#a00}.open{color:#a60}";

/// A page being written: headings, paragraphs, lists, tables and embedded plots, in order.
#[derive(Debug, Default)]
pub struct Page {
    title: String,
    body: String,
}

impl Page {
    /// An empty page with this title (also its first heading).
    pub fn new(title: &str) -> Self {
        let mut page = Self {
            title: title.to_string(),
            body: String::new(),
        };
        page.heading(1, title);
        page
    }

    /// A heading of level 1 to 3.
    pub fn heading(&mut self, level: u8, text: &str) {
        let level = level.clamp(1, 3);
        let _ = writeln!(self.body, "<h{level}>{}</h{level}>", escape(text));
    }

    /// A paragraph of plain text.
    pub fn paragraph(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p>{}</p>", escape(text));
    }

    /// A bulleted list; each item is plain text with a CSS class (`holds`, `fails`, `open`,
    /// or none).
    pub fn list(&mut self, items: &[(String, Option<&str>)]) {
        self.body.push_str("<ul>\n");
        for (text, class) in items {
            match class {
                Some(c) => {
                    let _ = writeln!(self.body, "<li class=\"{c}\">{}</li>", escape(text));
                }
                None => {
                    let _ = writeln!(self.body, "<li>{}</li>", escape(text));
                }
            }
        }
        self.body.push_str("</ul>\n");
    }

    /// A table with its header.
    pub fn table(&mut self, table: &Table) {
        self.body.push_str("<table>\n<tr>");
        for cell in table.header() {
            let _ = write!(self.body, "<th>{}</th>", escape(cell));
        }
        self.body.push_str("</tr>\n");
        for row in table.rows() {
            self.body.push_str("<tr>");
            for cell in row {
                let _ = write!(self.body, "<td>{}</td>", escape(cell));
            }
            self.body.push_str("</tr>\n");
        }
        self.body.push_str("</table>\n");
    }

    /// The PNG at `path`, embedded, named by its file name and captioned.
    ///
    /// # Errors
    /// [`ReportError::Write`] when the file cannot be read.
    pub fn image(&mut self, path: &Path, caption: &str) -> Result<(), ReportError> {
        let bytes = std::fs::read(path).map_err(|e| ReportError::Write {
            path: path.display().to_string(),
            source: Box::new(e),
        })?;
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let _ = writeln!(
            self.body,
            "<figure><img src=\"data:image/png;base64,{}\" alt=\"{}\"><figcaption>{}: {}\
             </figcaption></figure>",
            base64(&bytes),
            escape(&name),
            escape(&name),
            escape(caption)
        );
        Ok(())
    }

    /// The whole document.
    pub fn finish(self) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
             <title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n{}</body>\n</html>\n",
            escape(&self.title),
            self.body
        )
    }
}

/// `text` with the five characters HTML gives a meaning escaped.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Standard base64 with padding (RFC 4648).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_the_rfc_vectors() {
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, encoded) in cases {
            assert_eq!(base64(plain.as_bytes()), encoded, "{plain}");
        }
    }

    #[test]
    fn text_is_escaped_and_the_page_is_whole() {
        let mut page = Page::new("a <b> & \"c\"");
        let mut table = Table::new(["x<y"]);
        table.push(["1 & 2"]);
        page.table(&table);
        page.list(&[("it's".to_string(), Some("holds"))]);
        let html = page.finish();
        assert!(html.contains("<title>a &lt;b&gt; &amp; &quot;c&quot;</title>"));
        assert!(html.contains("<th>x&lt;y</th>") && html.contains("<td>1 &amp; 2</td>"));
        assert!(html.contains("<li class=\"holds\">it&#39;s</li>"));
        assert!(html.ends_with("</html>\n") && !html.contains("<script"));
    }
}
