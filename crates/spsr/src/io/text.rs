//! Plain-text point files: one point per line, values separated by whitespace and/or commas.
//! Blank lines and lines starting with `#` are ignored.
//!
//! The first data line fixes the layout by its number of values:
//!
//! | values | layout |
//! |---|---|
//! | 3–5 | `x y z` (positions only) |
//! | 6–8 | `x y z nx ny nz` |
//! | 9 or more | `x y z nx ny nz r g b` |
//!
//! Values beyond the layout are ignored, on every line; a later line with fewer values than
//! the layout is an error. Six values are always read as position and normal, never as
//! position and colour. Colours that are all integers in `0..=255` become `u8` attributes
//! `red green blue`; otherwise they are kept as `f32` values (taken to be in `[0, 1]`).
//!
//! Writing ([`write_text`]) uses the same layouts: `x y z`, `x y z nx ny nz`, or with colours
//! (as bytes) `x y z nx ny nz r g b`.

use std::io::{BufRead, Write};
use std::path::Path;

use crate::attributes::{Attribute, AttributeData};
use crate::error::Error;
use crate::points::PointCloud;
use crate::Result;

use super::write::Encoder;

/// Reads a text point file from `reader`; `path` is only used in error messages. With
/// `need_normals`, a file whose first data line has fewer than six values is
/// [`Error::MissingNormals`].
pub(crate) fn read_text_points<R: BufRead>(
    reader: R,
    path: &Path,
    need_normals: bool,
) -> Result<PointCloud> {
    super::whole_cloud(|emit| read_text_chunks(reader, path, need_normals, usize::MAX, emit))
}

/// Reads the points in clouds of at most `chunk` points, handed to `emit` in file order.
/// Whether colours are bytes is decided per chunk (the whole file, when it is one chunk).
pub(crate) fn read_text_chunks<R: BufRead>(
    mut reader: R,
    path: &Path,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let parse_err = |message: String| Error::Parse {
        path: path.to_path_buf(),
        message,
    };
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut colors: [Vec<f32>; 3] = Default::default();
    let mut colors_are_bytes = true;
    let mut emitted = false;
    let mut raw = Vec::new();
    let mut line = 0usize;
    // Values per point: 3, 6 or 9; 0 until the first data line.
    let mut layout = 0usize;
    let describe = |layout: usize| match layout {
        3 => "`x y z`",
        6 => "`x y z nx ny nz`",
        _ => "`x y z nx ny nz r g b`",
    };
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
                "line {line}: not valid text; expected numbers such as `x y z nx ny nz`"
            ))
        })?;
        let t = text.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let mut vals = [0.0f64; 9];
        let mut count = 0usize;
        let limit = if layout == 0 { 9 } else { layout };
        for tok in t
            .split(|c: char| c == ',' || c.is_ascii_whitespace())
            .filter(|s| !s.is_empty())
        {
            if count == limit {
                break; // extra columns are ignored
            }
            vals[count] = tok.parse::<f64>().map_err(|_| {
                let tok: String = tok.chars().take(40).collect();
                parse_err(format!(
                    "line {line}: '{tok}' is not a number (column {}); expected {}",
                    count + 1,
                    describe(if layout == 0 { 6 } else { layout })
                ))
            })?;
            count += 1;
        }
        if layout == 0 {
            layout = match count {
                0..=2 => {
                    return Err(parse_err(format!(
                        "line {line}: found {count} numbers, expected at least 3 (`x y z`, optionally followed by `nx ny nz` and `r g b`)"
                    )))
                }
                3..=5 => 3,
                6..=8 => 6,
                _ => 9,
            };
            if need_normals && layout == 3 {
                return Err(Error::MissingNormals {
                    path: path.to_path_buf(),
                });
            }
        } else if count < layout {
            return Err(parse_err(format!(
                "line {line}: found {count} numbers, expected {layout} ({}) like the first point",
                describe(layout)
            )));
        }
        positions.push([vals[0], vals[1], vals[2]]);
        if layout >= 6 {
            normals.push([vals[3], vals[4], vals[5]]);
        }
        if layout == 9 {
            for k in 0..3 {
                let c = vals[6 + k];
                colors_are_bytes &= c.fract() == 0.0 && (0.0..=255.0).contains(&c);
                colors[k].push(c as f32);
            }
        }
        if positions.len() == chunk {
            emit(cloud(
                std::mem::take(&mut positions),
                std::mem::take(&mut normals),
                std::mem::take(&mut colors),
                colors_are_bytes,
            ))?;
            emitted = true;
            colors_are_bytes = true;
        }
    }
    if !positions.is_empty() || !emitted {
        emit(cloud(positions, normals, colors, colors_are_bytes))?;
    }
    Ok(())
}

/// The points read, as a cloud; colours become `red green blue` in bytes or floats.
fn cloud(
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    colors: [Vec<f32>; 3],
    colors_are_bytes: bool,
) -> PointCloud {
    let mut attributes = Vec::new();
    if !colors[0].is_empty() {
        for (name, c) in ["red", "green", "blue"].into_iter().zip(colors) {
            let data = if colors_are_bytes {
                AttributeData::U8(c.into_iter().map(|v| v as u8).collect())
            } else {
                AttributeData::F32(c)
            };
            attributes.push(Attribute::new(name, data));
        }
    }
    PointCloud {
        positions,
        normals,
        attributes,
        scan_origins: Vec::new(),
    }
}

/// Writes a cloud as text, one point per line; numbers in their shortest exact form.
pub(crate) fn write_text<W: Write>(out: &mut W, cloud: &PointCloud) -> std::io::Result<()> {
    let with_normals = cloud.has_normals();
    let colours = cloud.colors().filter(|_| with_normals);
    let mut enc = Encoder::new(out);
    for (i, p) in cloud.positions.iter().enumerate() {
        write!(enc.buf, "{} {} {}", p[0], p[1], p[2])?;
        if with_normals {
            let n = cloud.normals[i];
            write!(enc.buf, " {} {} {}", n[0], n[1], n[2])?;
        }
        if let Some(c) = &colours {
            let [r, g, b, _] = c.unit(i).map(|x| (x * 255.0).round() as u8);
            write!(enc.buf, " {r} {g} {b}")?;
        }
        enc.buf.push(b'\n');
        enc.maybe_flush()?;
    }
    enc.finish()
}
