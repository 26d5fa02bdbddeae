//! A sampled implicit function as a NumPy `.npz`: a ZIP archive of `.npy` arrays, stored
//! without compression (`numpy.load` reads it as `np.savez` writes it). Arrays: `values`
//! (`<f4`, shape `(R, R, R)`, C order, indexed `[x, y, z]`), `origin` (`<f8`, shape `(3,)`) and
//! `spacing` (`<f8`, shape `()`). An archive of 4 GiB or more (R ≥ 1024) gets ZIP64 records,
//! as `np.savez` writes them; a smaller one is plain ZIP.

use std::io::Write;
use std::path::Path;

use super::write::write_atomically;
use crate::pipeline::grid::Grid;
use crate::Result;

/// ZIP's 32-bit sizes and offsets end below this; `0xffff_ffff` in one says "see the ZIP64
/// record".
const ZIP32_LIMIT: u64 = u32::MAX as u64;

/// Values converted to bytes (and checksummed) at a time.
const CHUNK: usize = 1 << 16;

/// Writes `grid` to `path` as `.npz`, atomically (temporary file, then rename).
pub fn write_grid(path: &Path, grid: &Grid) -> Result<()> {
    write_grid_from(path, grid, ZIP32_LIMIT)
}

/// One array of the archive: its file name, `.npy` header and values.
struct Entry<'a> {
    name: &'static str,
    header: Vec<u8>,
    data: Data<'a>,
}

/// An array's values, written little-endian.
enum Data<'a> {
    F32(&'a [f32]),
    F64(&'a [f64]),
}

impl Data<'_> {
    fn bytes(&self) -> u64 {
        match self {
            Data::F32(v) => 4 * v.len() as u64,
            Data::F64(v) => 8 * v.len() as u64,
        }
    }

    /// Calls `f` with the values' little-endian bytes, [`CHUNK`] values at a time, so that
    /// a grid is never copied whole.
    fn for_each_chunk(
        &self,
        mut f: impl FnMut(&[u8]) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        let mut buf = Vec::with_capacity(8 * CHUNK);
        match self {
            Data::F32(v) => {
                for c in v.chunks(CHUNK) {
                    buf.clear();
                    buf.extend(c.iter().flat_map(|x| x.to_le_bytes()));
                    f(&buf)?;
                }
            }
            Data::F64(v) => {
                for c in v.chunks(CHUNK) {
                    buf.clear();
                    buf.extend(c.iter().flat_map(|x| x.to_le_bytes()));
                    f(&buf)?;
                }
            }
        }
        Ok(())
    }
}

/// [`write_grid`], with ZIP64 records when the archive reaches `zip32_limit` bytes (tests
/// lower it to write small ZIP64 archives).
fn write_grid_from(path: &Path, grid: &Grid, zip32_limit: u64) -> Result<()> {
    let r = grid.res;
    let entries = [
        Entry {
            name: "values.npy",
            header: npy_header("<f4", &format!("({r}, {r}, {r})")),
            data: Data::F32(&grid.values),
        },
        Entry {
            name: "origin.npy",
            header: npy_header("<f8", "(3,)"),
            data: Data::F64(&grid.origin),
        },
        Entry {
            name: "spacing.npy",
            header: npy_header("<f8", "()"),
            data: Data::F64(std::slice::from_ref(&grid.spacing)),
        },
    ];
    // Each local header carries its entry's checksum: a first pass over the values makes
    // them (stored entries have no data descriptor).
    let mut crcs = [0u32; 3];
    for (crc, e) in crcs.iter_mut().zip(&entries) {
        let mut c = Crc32::new();
        c.update(&e.header);
        e.data
            .for_each_chunk(|b| {
                c.update(b);
                Ok(())
            })
            .expect("checksumming cannot fail");
        *crc = c.finish();
    }
    let size = |e: &Entry| e.header.len() as u64 + e.data.bytes();
    // Local headers, data and the central directory, with room for the ZIP64 extras.
    let total: u64 = entries
        .iter()
        .map(|e| size(e) + 2 * (46 + 28 + e.name.len() as u64))
        .sum::<u64>()
        + 22;
    let zip64 = total >= zip32_limit;
    write_atomically(path, |w| {
        let mut offset = 0u64;
        let mut central = Vec::new();
        for (e, &crc) in entries.iter().zip(&crcs) {
            let record = Record {
                name: e.name,
                crc,
                size: size(e),
                zip64,
            };
            let local = record.local_header();
            w.write_all(&local)?;
            w.write_all(&e.header)?;
            e.data.for_each_chunk(|b| w.write_all(b))?;
            central.extend(record.central_header(offset));
            offset += local.len() as u64 + record.size;
        }
        w.write_all(&central)?;
        w.write_all(&end_records(
            entries.len() as u16,
            central.len() as u64,
            offset,
            zip64,
        ))
    })
}

/// What the local header and the central directory say of a stored entry.
struct Record {
    name: &'static str,
    crc: u32,
    size: u64,
    /// Sizes (and offsets) in a ZIP64 extra field, with `0xffff_ffff` in the 32-bit fields.
    zip64: bool,
}

impl Record {
    /// The ZIP version needed to extract: 2.0, or 4.5 with ZIP64.
    fn version(&self) -> u16 {
        if self.zip64 {
            45
        } else {
            20
        }
    }

    /// The local file header.
    fn local_header(&self) -> Vec<u8> {
        let mut h = self.common(0x0403_4b50, None);
        if self.zip64 {
            // ZIP64 extra: uncompressed and compressed size.
            h.extend(1u16.to_le_bytes());
            h.extend(16u16.to_le_bytes());
            h.extend(self.size.to_le_bytes());
            h.extend(self.size.to_le_bytes());
        }
        h
    }

    /// The central directory record of the entry whose local header starts at `offset`.
    fn central_header(&self, offset: u64) -> Vec<u8> {
        let mut h = self.common(0x0201_4b50, Some(offset));
        if self.zip64 {
            // ZIP64 extra: uncompressed size, compressed size, local header offset.
            h.extend(1u16.to_le_bytes());
            h.extend(24u16.to_le_bytes());
            h.extend(self.size.to_le_bytes());
            h.extend(self.size.to_le_bytes());
            h.extend(offset.to_le_bytes());
        }
        h
    }

    /// The header up to and including the name (`offset` None: the local header).
    fn common(&self, signature: u32, offset: Option<u64>) -> Vec<u8> {
        let size32 = if self.zip64 {
            u32::MAX
        } else {
            self.size as u32
        };
        let extra: u16 = match (self.zip64, offset) {
            (false, _) => 0,
            (true, None) => 20,
            (true, Some(_)) => 28,
        };
        let mut h = Vec::with_capacity(46 + self.name.len() + usize::from(extra));
        h.extend(signature.to_le_bytes());
        if offset.is_some() {
            h.extend(self.version().to_le_bytes()); // made by
        }
        h.extend(self.version().to_le_bytes()); // needed
        h.extend(0u16.to_le_bytes()); // flags
        h.extend(0u16.to_le_bytes()); // method: stored
        h.extend(0u16.to_le_bytes()); // time 00:00
        h.extend(0x21u16.to_le_bytes()); // date 1980-01-01: fixed, so the file is reproducible
        h.extend(self.crc.to_le_bytes());
        h.extend(size32.to_le_bytes()); // compressed
        h.extend(size32.to_le_bytes()); // uncompressed
        h.extend((self.name.len() as u16).to_le_bytes());
        h.extend(extra.to_le_bytes());
        if let Some(offset) = offset {
            let offset32 = if self.zip64 { u32::MAX } else { offset as u32 };
            h.extend(0u16.to_le_bytes()); // comment
            h.extend(0u16.to_le_bytes()); // disk
            h.extend(0u16.to_le_bytes()); // internal attributes
            h.extend(0u32.to_le_bytes()); // external attributes
            h.extend(offset32.to_le_bytes());
        }
        h.extend(self.name.as_bytes());
        h
    }
}

/// The end of the archive: with ZIP64, its end-of-central-directory record and locator; then
/// the end-of-central-directory record, for `count` entries whose directory of `size` bytes
/// starts at `start`.
fn end_records(count: u16, size: u64, start: u64, zip64: bool) -> Vec<u8> {
    let mut end = Vec::with_capacity(22 + 56 + 20);
    if zip64 {
        end.extend(0x0606_4b50u32.to_le_bytes());
        end.extend(44u64.to_le_bytes()); // the record's size after this field
        end.extend(45u16.to_le_bytes()); // made by
        end.extend(45u16.to_le_bytes()); // needed
        end.extend([0u8; 8]); // this disk, the disk of the central directory
        end.extend(u64::from(count).to_le_bytes());
        end.extend(u64::from(count).to_le_bytes());
        end.extend(size.to_le_bytes());
        end.extend(start.to_le_bytes());
        end.extend(0x0706_4b50u32.to_le_bytes());
        end.extend(0u32.to_le_bytes()); // the disk of the ZIP64 record
        end.extend((start + size).to_le_bytes()); // where it starts
        end.extend(1u32.to_le_bytes()); // disks
    }
    let clamp = |v: u64| if zip64 { u32::MAX } else { v as u32 };
    end.extend(0x0605_4b50u32.to_le_bytes());
    end.extend([0u8; 4]); // this disk, the disk of the central directory
    end.extend(count.to_le_bytes());
    end.extend(count.to_le_bytes());
    end.extend(clamp(size).to_le_bytes());
    end.extend(clamp(start).to_le_bytes());
    end.extend(0u16.to_le_bytes()); // no comment
    end
}

/// The `.npy` version 1.0 header of an array: magic, version, length, and the dictionary
/// padded with spaces so that the data starts at a multiple of 64 bytes.
fn npy_header(descr: &str, shape: &str) -> Vec<u8> {
    let dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    let unpadded = 10 + dict.len() + 1;
    let len = unpadded.div_ceil(64) * 64;
    let mut h = b"\x93NUMPY\x01\x00".to_vec();
    h.extend(((len - 10) as u16).to_le_bytes());
    h.extend(dict.as_bytes());
    h.resize(len - 1, b' ');
    h.push(b'\n');
    h
}

/// CRC-32 (IEEE 802.3, reflected, as ZIP uses), byte by byte through a table.
struct Crc32 {
    table: [u32; 256],
    value: u32,
}

impl Crc32 {
    fn new() -> Self {
        let table = std::array::from_fn(|n| {
            let mut c = n as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
            c
        });
        Crc32 {
            table,
            value: 0xffff_ffff,
        }
    }

    fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.value =
                self.table[((self.value ^ u32::from(b)) & 0xff) as usize] ^ (self.value >> 8);
        }
    }

    fn finish(&self) -> u32 {
        self.value ^ 0xffff_ffff
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_of_the_check_string() {
        let mut c = Crc32::new();
        c.update(b"123456789");
        assert_eq!(c.finish(), 0xcbf4_3926);
    }

    fn u16_at(b: &[u8], at: usize) -> usize {
        u16::from_le_bytes([b[at], b[at + 1]]) as usize
    }

    fn u32_at(b: &[u8], at: usize) -> u64 {
        u64::from(u32::from_le_bytes(b[at..at + 4].try_into().unwrap()))
    }

    fn u64_at(b: &[u8], at: usize) -> u64 {
        u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
    }

    /// The entries of a stored ZIP archive (ZIP64 or not), read through its central
    /// directory: names and data, each checked against its CRC.
    fn entries(b: &[u8]) -> Vec<(String, Vec<u8>)> {
        let end = b.len() - 22;
        assert_eq!(u32_at(b, end), 0x0605_4b50);
        let (mut count, mut size, mut start) = (
            u16_at(b, end + 10) as u64,
            u32_at(b, end + 12),
            u32_at(b, end + 16),
        );
        if start == u64::from(u32::MAX) {
            let locator = end - 20;
            assert_eq!(u32_at(b, locator), 0x0706_4b50);
            let record = u64_at(b, locator + 8) as usize;
            assert_eq!(u32_at(b, record), 0x0606_4b50);
            (count, size, start) = (
                u64_at(b, record + 32),
                u64_at(b, record + 40),
                u64_at(b, record + 48),
            );
        }
        let mut at = start as usize;
        let mut out = Vec::new();
        for _ in 0..count {
            assert_eq!(u32_at(b, at), 0x0201_4b50);
            let (crc, mut len, mut offset) =
                (u32_at(b, at + 16), u32_at(b, at + 20), u32_at(b, at + 42));
            let (n, e) = (u16_at(b, at + 28), u16_at(b, at + 30));
            let name = String::from_utf8(b[at + 46..at + 46 + n].to_vec()).unwrap();
            if len == u64::from(u32::MAX) {
                let x = at + 46 + n;
                assert_eq!((u16_at(b, x), u16_at(b, x + 2)), (1, 24));
                (len, offset) = (u64_at(b, x + 4), u64_at(b, x + 20));
            }
            let local = offset as usize;
            assert_eq!(u32_at(b, local), 0x0403_4b50);
            let data = local + 30 + u16_at(b, local + 26) + u16_at(b, local + 28);
            let data = b[data..data + len as usize].to_vec();
            let mut c = Crc32::new();
            c.update(&data);
            assert_eq!(u64::from(c.finish()), crc, "{name}");
            out.push((name, data));
            at += 46 + n + e + u16_at(b, at + 32);
        }
        assert_eq!(at as u64, start + size);
        out
    }

    /// The same arrays, whether the archive is plain ZIP or ZIP64 (forced here on a small
    /// grid); Python's `zipfile` reads both and finds every checksum right, where Python is.
    #[test]
    fn zip64_archives_hold_the_same_arrays() {
        let grid = Grid {
            res: 3,
            origin: [1.0, 2.0, 3.0],
            spacing: 0.5,
            values: (0..27).map(|v| v as f32 - 13.5).collect(),
        };
        let dir = tempfile::tempdir().unwrap();
        let mut read = Vec::new();
        for (limit, name) in [(ZIP32_LIMIT, "plain.npz"), (0, "zip64.npz")] {
            let path = dir.path().join(name);
            write_grid_from(&path, &grid, limit).unwrap();
            let bytes = std::fs::read(&path).unwrap();
            let zip64 = bytes.windows(4).any(|w| w == 0x0606_4b50u32.to_le_bytes());
            assert_eq!(zip64, limit == 0, "{name}");
            let e = entries(&bytes);
            let names: Vec<&str> = e.iter().map(|(n, _)| n.as_str()).collect();
            assert_eq!(names, ["values.npy", "origin.npy", "spacing.npy"]);
            let values = &e[0].1[npy_header("<f4", "(3, 3, 3)").len()..];
            for (k, v) in grid.values.iter().enumerate() {
                assert_eq!(values[4 * k..4 * k + 4], v.to_le_bytes());
            }
            read.push(e);
            let script = "import sys, zipfile\n\
                          z = zipfile.ZipFile(sys.argv[1])\n\
                          assert z.testzip() is None\n\
                          print(*(i.file_size for i in z.infolist()))";
            match std::process::Command::new("python3")
                .args(["-c", script])
                .arg(&path)
                .output()
            {
                Ok(out) => assert!(
                    out.status.success(),
                    "{name}: {}",
                    String::from_utf8_lossy(&out.stderr)
                ),
                Err(e) => eprintln!("skipped Python's check: {e}"),
            }
        }
        assert_eq!(read[0], read[1]);
    }

    #[test]
    fn npy_headers_align_the_data_to_64_bytes() {
        for shape in ["()", "(3,)", "(100, 100, 100)"] {
            let h = npy_header("<f4", shape);
            assert_eq!(h.len() % 64, 0);
            assert_eq!(*h.last().unwrap(), b'\n');
            assert_eq!(u16::from_le_bytes([h[8], h[9]]) as usize, h.len() - 10);
        }
    }
}
