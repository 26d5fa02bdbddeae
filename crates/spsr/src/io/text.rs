//! Plain-text point files: one point per line, `x y z nx ny nz`, separated by whitespace
//! and/or commas. Blank lines and lines starting with `#` are ignored; extra columns after the
//! sixth (colours, confidences, ...) are ignored.

use std::io::BufRead;
use std::path::Path;

use crate::error::Error;
use crate::points::PointCloud;
use crate::Result;

/// Reads a text point file from `reader`; `path` is only used in error messages.
pub(crate) fn read_text_points<R: BufRead>(mut reader: R, path: &Path) -> Result<PointCloud> {
    let parse_err = |message: String| Error::Parse {
        path: path.to_path_buf(),
        message,
    };
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut raw = Vec::new();
    let mut line = 0usize;
    let mut first_data = true;
    loop {
        raw.clear();
        let n = reader
            .read_until(b'\n', &mut raw)
            .map_err(|source| Error::Io {
                path: path.to_path_buf(),
                source,
            })?;
        if n == 0 {
            break;
        }
        line += 1;
        let mut bytes: &[u8] = &raw;
        if line == 1 {
            bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
        }
        let text = std::str::from_utf8(bytes).map_err(|_| {
            parse_err(format!(
                "line {line}: not valid text; expected `x y z nx ny nz`"
            ))
        })?;
        let t = text.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let mut vals = [0.0f64; 6];
        let mut count = 0usize;
        for tok in t
            .split(|c: char| c == ',' || c.is_ascii_whitespace())
            .filter(|s| !s.is_empty())
        {
            if count == 6 {
                break; // extra columns are ignored
            }
            vals[count] = tok.parse::<f64>().map_err(|_| {
                let tok: String = tok.chars().take(40).collect();
                parse_err(format!(
                    "line {line}: '{tok}' is not a number (column {}); expected `x y z nx ny nz`",
                    count + 1
                ))
            })?;
            count += 1;
        }
        if count < 6 {
            if first_data && count == 3 {
                return Err(Error::MissingNormals {
                    path: path.to_path_buf(),
                });
            }
            return Err(parse_err(format!(
                "line {line}: found {count} numbers, expected 6 (`x y z nx ny nz`)"
            )));
        }
        first_data = false;
        positions.push([vals[0], vals[1], vals[2]]);
        normals.push([vals[3], vals[4], vals[5]]);
    }
    Ok(PointCloud { positions, normals })
}
