//! What the line-oriented mesh readers (OBJ, OFF, ASCII STL) share: numbered lines of text,
//! numbers with errors that name the line, and vertex colours given as numbers.

use std::io::BufRead;
use std::path::Path;

use crate::attributes::{Attribute, AttributeData};
use crate::Result;

use super::{io_err, parse_err};

/// The lines of a text file, numbered from 1: [`Lines::advance`] reads the next one, and
/// [`Lines::text`] is its text without the end of line, comments and surrounding whitespace.
pub(crate) struct Lines<'p, R> {
    reader: R,
    path: &'p Path,
    number: usize,
    raw: Vec<u8>,
    text: std::ops::Range<usize>,
}

impl<'p, R: BufRead> Lines<'p, R> {
    pub(crate) fn new(reader: R, path: &'p Path) -> Self {
        Self {
            reader,
            path,
            number: 0,
            raw: Vec::new(),
            text: 0..0,
        }
    }

    /// Reads the next line, removing everything from `comment` on; false at the end of the
    /// file.
    pub(crate) fn advance(&mut self, comment: Option<char>) -> Result<bool> {
        self.raw.clear();
        self.text = 0..0;
        let n = self
            .reader
            .read_until(b'\n', &mut self.raw)
            .map_err(|e| io_err(self.path, e))?;
        if n == 0 {
            return Ok(false);
        }
        self.number += 1;
        let bom = if self.number == 1 && self.raw.starts_with(b"\xEF\xBB\xBF") {
            3
        } else {
            0
        };
        let text = std::str::from_utf8(&self.raw[bom..]).map_err(|_| {
            parse_err(
                self.path,
                format!("line {}: not valid text (UTF-8)", self.number),
            )
        })?;
        let text = comment
            .and_then(|c| text.find(c))
            .map_or(text, |i| &text[..i]);
        let start = bom + (text.len() - text.trim_start().len());
        self.text = start..start + text.trim().len();
        Ok(true)
    }

    /// Reads up to the next line that is not empty once comments are removed; false at the
    /// end of the file.
    pub(crate) fn advance_to_data(&mut self, comment: Option<char>) -> Result<bool> {
        while self.advance(comment)? {
            if !self.text.is_empty() {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// The text of the current line (empty before the first and after the last).
    pub(crate) fn text(&self) -> &str {
        // Checked to be UTF-8 in `advance`, and the range ends on character boundaries.
        std::str::from_utf8(&self.raw[self.text.clone()]).unwrap_or_default()
    }

    /// The number of the current line, from 1.
    pub(crate) fn number(&self) -> usize {
        self.number
    }

    /// A parse error about the current line.
    pub(crate) fn error(&self, message: impl std::fmt::Display) -> crate::error::Error {
        parse_err(self.path, format!("line {}: {message}", self.number))
    }

    /// Parses `token` of the current line as a number, or says what it is instead.
    pub(crate) fn number_in<T: std::str::FromStr>(&self, token: &str, what: &str) -> Result<T> {
        token.parse().map_err(|_| {
            let token: String = token.chars().take(40).collect();
            self.error(format!("'{token}' is not {what}"))
        })
    }
}

/// Vertex colours read as numbers, `[r, g, b, a]` per vertex (`a` NaN where not given),
/// turned into attributes `red green blue [alpha]`. Values that are all whole numbers from 0
/// to 255, some above 1, are bytes (`u8`); anything else is taken to be in `[0, 1]` (`f32`).
/// Alpha is kept when some vertex gives it; where one does not, it is opaque.
pub(crate) fn colour_attributes(colours: &[[f64; 4]]) -> Vec<Attribute> {
    let values = || colours.iter().flatten().filter(|v| !v.is_nan());
    let bytes = values().all(|&v| v.fract() == 0.0 && (0.0..=255.0).contains(&v))
        && values().any(|&v| v > 1.0);
    let has_alpha = colours.iter().any(|c| !c[3].is_nan());
    let names = ["red", "green", "blue", "alpha"];
    let channels = if has_alpha { 4 } else { 3 };
    (0..channels)
        .map(|k| {
            let column = colours.iter().map(|c| c[k]);
            let data = if bytes {
                AttributeData::U8(
                    column
                        .map(|v| if v.is_nan() { 255 } else { v as u8 })
                        .collect(),
                )
            } else {
                AttributeData::F32(
                    column
                        .map(|v| if v.is_nan() { 1.0 } else { v as f32 })
                        .collect(),
                )
            };
            Attribute::new(names[k], data)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_colours_need_a_value_above_one() {
        let a = colour_attributes(&[[255.0, 0.0, 7.0, f64::NAN]]);
        assert_eq!(a.len(), 3);
        assert_eq!(a[0].data, AttributeData::U8(vec![255]));
        let a = colour_attributes(&[[1.0, 0.0, 0.5, f64::NAN], [0.0, 1.0, 0.0, 0.5]]);
        assert_eq!(a.len(), 4);
        assert_eq!(a[3].data, AttributeData::F32(vec![1.0, 0.5]));
    }

    #[test]
    fn lines_are_numbered_and_comments_removed() {
        let text = b"\xEF\xBB\xBFOFF # header\n\n  # only a comment\n1 2 3\r\n";
        let mut l = Lines::new(&text[..], Path::new("t.off"));
        assert!(l.advance_to_data(Some('#')).unwrap());
        assert_eq!((l.number(), l.text()), (1, "OFF"));
        assert!(l.advance_to_data(Some('#')).unwrap());
        assert_eq!((l.number(), l.text()), (4, "1 2 3"));
        assert!(!l.advance_to_data(Some('#')).unwrap());
    }
}
