//! The one CSV layer: every CSV file the tool reads (landmark sets, centre
//! files, radiograph films, kinematics, stiffness and ratio tables, the
//! dimension and layout templates) is split into cells here, by the `csv`
//! crate, under one policy:
//!
//! - a UTF-8 byte-order mark at the start is dropped ([`strip_bom`]);
//! - a line whose first non-blank character is `#` is a comment: it is
//!   handed to the reader as a [`CsvItem::Comment`] (its trimmed text, in
//!   file order among the rows), which gives meaning to the ones it knows
//!   (`# units: mm`, read with [`comment_value`]) and ignores the rest;
//! - blank lines (nothing but blanks) are skipped;
//! - lines end in LF or CRLF;
//! - cells are separated by commas and trimmed; a cell in double quotes may
//!   hold commas, line ends and doubled quotes (`"a ""b"", c"`), and a cell
//!   written with blanks around its quotes (`x, "12.5" ,y`) reads as its
//!   content too;
//! - every row carries the 1-based line of the file on which it starts, and
//!   its errors name the file and that line ([`CsvRecord::error`]).
//!
//! Rows may have any number of cells: the reader says how many it expects.
//! Sizes are bounded where the text is read ([`super::input`]).

use crate::error::{Error, Result};
use std::collections::VecDeque;
use std::io::Cursor;
use std::path::{Path, PathBuf};

/// `text` without a leading UTF-8 byte-order mark (spreadsheets and Windows
/// editors write one). The one place the mark is dropped from text handed
/// to a parser (files read through [`super::input`] are already without it).
pub fn strip_bom(text: &str) -> &str {
    text.strip_prefix('\u{feff}').unwrap_or(text)
}

/// `s` trimmed, without one pair of enclosing double quotes.
pub fn unquote(s: &str) -> &str {
    let t = s.trim();
    t.strip_prefix('"')
        .and_then(|x| x.strip_suffix('"'))
        .unwrap_or(t)
}

/// The value of a `# key: value` comment when its key is `key` (any case;
/// any number of `#`, blanks around key and value allowed).
pub fn comment_value<'a>(comment: &'a str, key: &str) -> Option<&'a str> {
    let c = comment.trim().trim_start_matches('#').trim();
    let (k, v) = c.split_once(':')?;
    if k.trim().eq_ignore_ascii_case(key) {
        Some(v.trim())
    } else {
        None
    }
}

/// A `#` comment line.
#[derive(Debug, Clone, PartialEq)]
pub struct CsvComment {
    /// 1-based line in the file.
    pub line: u64,
    /// The line, trimmed (starting with `#`).
    pub text: String,
}

/// One row of cells.
#[derive(Debug, Clone)]
pub struct CsvRecord {
    line: u64,
    source: String,
    cells: csv::StringRecord,
}

impl CsvRecord {
    /// The 1-based line on which the row starts.
    pub fn line(&self) -> u64 {
        self.line
    }

    /// `line N`, the location of errors about this row.
    pub fn at(&self) -> String {
        format!("line {}", self.line)
    }

    /// A parse error of `path` at this row's line.
    pub fn error(&self, path: &Path, message: impl Into<String>) -> Error {
        Error::parse(path, self.at(), message.into())
    }

    /// The first line of the row as written, trimmed (for messages that
    /// quote what was found).
    pub fn source(&self) -> &str {
        &self.source
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// A row without cells (never yielded: blank lines are skipped).
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Cell `i`, or `""` beyond the end of the row.
    pub fn cell(&self, i: usize) -> &str {
        self.cells.get(i).unwrap_or("")
    }

    /// The cells in order.
    pub fn cells(&self) -> csv::StringRecordIter<'_> {
        self.cells.iter()
    }

    /// Every cell empty (`,,,`, a spreadsheet's empty row).
    pub fn all_empty(&self) -> bool {
        self.cells.iter().all(str::is_empty)
    }

    /// An error unless the row has one cell per column of `header` (its
    /// header row).
    pub fn check_width(&self, header: &CsvRecord, path: &Path) -> Result<()> {
        if self.len() == header.len() {
            return Ok(());
        }
        Err(self.error(
            path,
            format!(
                "{} cells, but the header row (line {}) has {}: expected one cell per column",
                self.len(),
                header.line(),
                header.len()
            ),
        ))
    }

    /// The cells, without the empty ones that end the row (`a,b,c,,`:
    /// spreadsheet exports) beyond the first `keep`.
    pub fn cells_trimmed(&self, keep: usize) -> Vec<&str> {
        let mut v: Vec<&str> = self.cells.iter().collect();
        while v.len() > keep && v.last().is_some_and(|c| c.is_empty()) {
            v.pop();
        }
        v
    }
}

/// What [`CsvReader`] yields: comments and rows in file order.
#[derive(Debug, Clone)]
pub enum CsvItem {
    /// A comment line.
    Comment(CsvComment),
    /// A data row.
    Record(CsvRecord),
}

impl CsvItem {
    /// The row, or None after handing the comment to `on_comment` (which
    /// reads the `#` lines the format defines).
    pub fn record_or(
        self,
        on_comment: impl FnOnce(&CsvComment) -> Result<()>,
    ) -> Result<Option<CsvRecord>> {
        match self {
            CsvItem::Record(r) => Ok(Some(r)),
            CsvItem::Comment(c) => on_comment(&c).map(|()| None),
        }
    }
}

/// Reads the comments and rows of a CSV text (see the module docs).
/// Iterate it for both in file order, or call [`CsvReader::records`] for
/// the rows alone. After an error it yields nothing more.
pub struct CsvReader {
    path: PathBuf,
    /// Over the text with its comment lines blanked (line ends kept, so
    /// line numbers stay the file's).
    rdr: csv::Reader<Cursor<String>>,
    /// Byte offsets of the text's `\n`s.
    newlines: Vec<usize>,
    comments: VecDeque<CsvComment>,
    /// The next row read (or the error in its place), with its line.
    next_row: Option<(u64, Result<CsvRecord>)>,
    done: bool,
}

impl CsvReader {
    /// A reader over `text`; `path` names the file in errors.
    pub fn new(text: &str, path: &Path) -> CsvReader {
        let (blanked, comments) = split_comments(strip_bom(text));
        let newlines = blanked
            .bytes()
            .enumerate()
            .filter(|&(_, b)| b == b'\n')
            .map(|(i, _)| i)
            .collect();
        let rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(Cursor::new(blanked));
        CsvReader {
            path: path.to_path_buf(),
            rdr,
            newlines,
            comments,
            next_row: None,
            done: false,
        }
    }

    /// The rows alone (comments dropped).
    pub fn records(self) -> impl Iterator<Item = Result<CsvRecord>> {
        self.filter_map(|item| match item {
            Ok(CsvItem::Record(r)) => Some(Ok(r)),
            Ok(CsvItem::Comment(_)) => None,
            Err(e) => Some(Err(e)),
        })
    }

    fn text(&self) -> &str {
        self.rdr.get_ref().get_ref()
    }

    /// The 1-based line on which the row at byte `b` starts, and that
    /// line's byte offset. The csv crate's offset may point at the line end
    /// before the row (its own line count misses CRLF and blank lines):
    /// the newlines before the offset are counted, then line ends stepped
    /// over.
    fn line_at(&self, b: u64) -> (u64, usize) {
        let text = self.text().as_bytes();
        let mut b = usize::try_from(b).unwrap_or(usize::MAX).min(text.len());
        let mut line = self.newlines.partition_point(|&o| o < b) as u64 + 1;
        while let Some(&c) = text.get(b) {
            match c {
                b'\n' => line += 1,
                b'\r' => {}
                _ => break,
            }
            b += 1;
        }
        (line, b)
    }

    /// The next non-blank row, or None at the end of the text.
    fn read_row(&mut self) -> Option<(u64, Result<CsvRecord>)> {
        let mut cells = csv::StringRecord::new();
        loop {
            match self.rdr.read_record(&mut cells) {
                Ok(false) => return None,
                Ok(true) => {}
                Err(e) => {
                    let line = e.position().map_or(0, |p| self.line_at(p.byte()).0);
                    let at = if line > 0 {
                        format!("line {line}")
                    } else {
                        "file".to_string()
                    };
                    let msg = format!("cannot read the row: {e}");
                    return Some((line, Err(Error::parse(&self.path, at, msg))));
                }
            }
            if cells.len() == 1 && cells[0].is_empty() {
                continue; // a line of blanks
            }
            let (line, start) = cells.position().map_or((0, 0), |p| self.line_at(p.byte()));
            let rest = &self.text().as_bytes()[start..];
            let end = rest.iter().position(|&c| c == b'\n').unwrap_or(rest.len());
            let source = String::from_utf8_lossy(&rest[..end]).trim().to_string();
            if cells
                .iter()
                .any(|c| c.len() >= 2 && unquote(c).len() != c.len())
            {
                cells = cells.iter().map(unquote).collect();
            }
            return Some((
                line,
                Ok(CsvRecord {
                    line,
                    source,
                    cells,
                }),
            ));
        }
    }
}

impl Iterator for CsvReader {
    type Item = Result<CsvItem>;

    fn next(&mut self) -> Option<Result<CsvItem>> {
        if self.done {
            return None;
        }
        if self.next_row.is_none() {
            self.next_row = self.read_row();
        }
        let comment_first = match (&self.next_row, self.comments.front()) {
            (Some((line, _)), Some(c)) => c.line < *line,
            (None, Some(_)) => true,
            (_, None) => false,
        };
        if comment_first {
            return self.comments.pop_front().map(|c| Ok(CsvItem::Comment(c)));
        }
        let (_, row) = self.next_row.take()?;
        if row.is_err() {
            self.done = true;
        }
        Some(row.map(CsvItem::Record))
    }
}

/// `text` with every comment line made empty (line ends kept: the csv
/// crate skips empty lines and does not count the comment lines it would
/// skip itself), and the comments.
fn split_comments(text: &str) -> (String, VecDeque<CsvComment>) {
    let mut out = String::with_capacity(text.len());
    let mut comments = VecDeque::new();
    for (i, l) in text.split_inclusive('\n').enumerate() {
        let t = l.trim();
        if t.starts_with('#') {
            comments.push_back(CsvComment {
                line: i as u64 + 1,
                text: t.to_string(),
            });
            if l.ends_with("\r\n") {
                out.push_str("\r\n");
            } else if l.ends_with('\n') {
                out.push('\n');
            }
        } else {
            out.push_str(l);
        }
    }
    (out, comments)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn items(text: &str) -> Vec<CsvItem> {
        CsvReader::new(text, Path::new("t.csv"))
            .collect::<Result<_>>()
            .unwrap()
    }

    /// (line, cells) of the rows; (line, text) of the comments as a
    /// one-cell row starting with `#`.
    fn lines(text: &str) -> Vec<(u64, Vec<String>)> {
        items(text)
            .into_iter()
            .map(|it| match it {
                CsvItem::Comment(c) => (c.line, vec![c.text]),
                CsvItem::Record(r) => (r.line(), r.cells().map(str::to_string).collect()),
            })
            .collect()
    }

    fn row(line: u64, cells: &[&str]) -> (u64, Vec<String>) {
        (line, cells.iter().map(|c| c.to_string()).collect())
    }

    #[test]
    fn rows_and_comments_keep_the_file_lines() {
        // By hand: line 1 comment, 2 header, 3 blank, 4 row, 5 indented
        // comment, 6 blanks only, 7 row.
        let want = vec![
            row(1, &["# units: mm"]),
            row(2, &["name", "x"]),
            row(4, &["a", "1"]),
            row(5, &["# note, with a comma"]),
            row(7, &["b", "2"]),
        ];
        let lf = "# units: mm\nname,x\n\na,1\n  # note, with a comma\n   \nb,2\n";
        assert_eq!(lines(lf), want);
        assert_eq!(lines(&lf.replace('\n', "\r\n")), want);
        // a byte-order mark, and no line end at the end
        let bom = format!("\u{feff}{}", lf.trim_end());
        assert_eq!(lines(&bom), want);
    }

    #[test]
    fn quoted_cells_hold_commas_quotes_and_line_ends() {
        let text =
            "name,x\n\"L3, SEC\",\"1\"\n x , \"2\" ,\"say \"\"hi\"\"\"\n\"two\nlines\",3\nlast,4\n";
        assert_eq!(
            lines(text),
            vec![
                row(1, &["name", "x"]),
                row(2, &["L3, SEC", "1"]),
                row(3, &["x", "2", "say \"hi\""]),
                row(4, &["two\nlines", "3"]),
                row(6, &["last", "4"]),
            ]
        );
    }

    #[test]
    fn a_row_names_its_line_and_quotes_its_source() {
        let text = "\u{feff}# c\r\n\r\nname,x\r\nL3_SEC, abc ,\r\n";
        let rows: Vec<CsvRecord> = CsvReader::new(text, Path::new("dir/t.csv"))
            .records()
            .collect::<Result<_>>()
            .unwrap();
        assert_eq!(rows.len(), 2);
        let r = &rows[1];
        assert_eq!(r.source(), "L3_SEC, abc ,");
        assert_eq!(r.cells_trimmed(1), vec!["L3_SEC", "abc"]);
        assert_eq!(r.cells_trimmed(3), vec!["L3_SEC", "abc", ""]);
        assert_eq!(r.cell(7), "");
        assert_eq!(
            r.error(Path::new("dir/t.csv"), "bad").to_string(),
            "dir/t.csv: line 4: bad"
        );
    }

    #[test]
    fn comment_values() {
        assert_eq!(comment_value("# units: mm", "units"), Some("mm"));
        assert_eq!(comment_value("#Units :  m ", "units"), Some("m"));
        assert_eq!(comment_value("## frame: LPS", "frame"), Some("LPS"));
        assert_eq!(comment_value("# frame LPS", "frame"), None);
        assert_eq!(comment_value("# units: mm", "frame"), None);
        assert_eq!(unquote(" \"a,b\" "), "a,b");
        assert_eq!(unquote("\""), "\"");
        assert_eq!(strip_bom("\u{feff}a"), "a");
    }
}
