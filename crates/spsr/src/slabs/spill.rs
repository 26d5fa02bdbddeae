//! The spill files of a slab run: the usable points, already in the unit cube, one file per
//! column (a cell of the block depth along x) in the work folder. A slab reads its columns and
//! the neighbouring columns' points within its padding, in column order and, within a column,
//! in input order, so that the points of every finest cell keep their input order (the
//! samples are then the in-core run's, bit for bit). A point's carried attributes follow it
//! in its record.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use crate::pipeline::prepare::UnitPoint;
use crate::{Error, Result};

/// Values of one spilled point before its attributes: position, unit normal and weight.
const FIXED: usize = 7;

/// Bytes of one spilled point with `channels` attribute values: all `f64`, little endian.
fn record_len(channels: usize) -> usize {
    8 * (FIXED + channels)
}

/// The column files of a run, written point by point.
pub(crate) struct ColumnWriter {
    dir: PathBuf,
    files: Vec<Option<BufWriter<File>>>,
    pub counts: Vec<u64>,
    channels: usize,
    record: Vec<u8>,
}

impl ColumnWriter {
    /// Column files for points with `channels` attribute values each.
    pub fn new(dir: &Path, columns: usize, channels: usize) -> Self {
        ColumnWriter {
            dir: dir.to_path_buf(),
            files: (0..columns).map(|_| None).collect(),
            counts: vec![0; columns],
            channels,
            record: Vec::with_capacity(record_len(channels)),
        }
    }

    /// Appends a point and its attribute values (`channels` of them) to column `c`'s file
    /// (created on first use).
    pub fn push(&mut self, c: usize, p: &UnitPoint, values: &[f64]) -> Result<()> {
        debug_assert_eq!(values.len(), self.channels);
        if self.files[c].is_none() {
            let path = column_path(&self.dir, c);
            let f = File::create(&path).map_err(|e| io_err(&path, e))?;
            self.files[c] = Some(BufWriter::with_capacity(1 << 16, f));
        }
        let w = self.files[c].as_mut().expect("opened above");
        let rec = &mut self.record;
        rec.clear();
        let fixed = [p.0[0], p.0[1], p.0[2], p.1[0], p.1[1], p.1[2], p.2];
        for v in fixed.iter().chain(values) {
            rec.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(rec)
            .map_err(|e| io_err(&column_path(&self.dir, c), e))?;
        self.counts[c] += 1;
        Ok(())
    }

    /// Flushes and closes every file; a full disk is reported here at the latest.
    pub fn finish(mut self) -> Result<Vec<u64>> {
        for (c, f) in self.files.iter_mut().enumerate() {
            if let Some(w) = f.take() {
                let path = column_path(&self.dir, c);
                let file = w.into_inner().map_err(|e| io_err(&path, e.into_error()))?;
                file.sync_all().map_err(|e| io_err(&path, e))?;
            }
        }
        Ok(self.counts)
    }
}

/// The points of columns `columns` whose x lies in `[lo, hi)`, in column order, and their
/// attribute values (`channels` per point, point after point).
pub(crate) fn read_columns(
    dir: &Path,
    columns: std::ops::Range<usize>,
    counts: &[u64],
    channels: usize,
    (lo, hi): (f64, f64),
) -> Result<(Vec<UnitPoint>, Vec<f64>)> {
    let mut points = Vec::new();
    let mut values = Vec::new();
    let mut rec = vec![0u8; record_len(channels)];
    for c in columns {
        if counts[c] == 0 {
            continue;
        }
        let path = column_path(dir, c);
        let f = File::open(&path).map_err(|e| io_err(&path, e))?;
        let mut r = BufReader::with_capacity(1 << 16, f);
        for _ in 0..counts[c] {
            r.read_exact(&mut rec).map_err(|e| io_err(&path, e))?;
            let v = |k: usize| f64::from_le_bytes(rec[k * 8..k * 8 + 8].try_into().expect("8"));
            if v(0) >= lo && v(0) < hi {
                points.push(([v(0), v(1), v(2)], [v(3), v(4), v(5)], v(6)));
                values.extend((FIXED..FIXED + channels).map(v));
            }
        }
    }
    Ok((points, values))
}

/// Deletes the column files (once every slab has read its points).
pub(crate) fn remove_columns(dir: &Path, counts: &[u64]) -> Result<()> {
    (0..counts.len())
        .filter(|&c| counts[c] > 0)
        .try_for_each(|c| remove_file(&column_path(dir, c)))
}

/// Deletes a file; one already gone is fine (a step run again).
pub(crate) fn remove_file(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(io_err(path, e)),
        _ => Ok(()),
    }
}

fn column_path(dir: &Path, c: usize) -> PathBuf {
    dir.join(format!("column-{c:05}.points"))
}

pub(crate) fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}
