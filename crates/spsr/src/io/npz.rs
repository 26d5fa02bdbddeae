//! A sampled implicit function as a NumPy `.npz`: a ZIP archive of `.npy` arrays, stored
//! without compression (`numpy.load` reads it as `np.savez` writes it). Arrays: `values`
//! (`<f4`, shape `(R, R, R)`, C order, indexed `[x, y, z]`), `origin` (`<f8`, shape `(3,)`) and
//! `spacing` (`<f8`, shape `()`). Written without ZIP64, so a grid holds under 4 GiB of values
//! (R ≤ 1023).

use std::io::Write;
use std::path::Path;

use super::write::write_atomically;
use crate::pipeline::grid::Grid;
use crate::{Error, Result};

/// Writes `grid` to `path` as `.npz`, atomically (temporary file, then rename).
pub fn write_grid(path: &Path, grid: &Grid) -> Result<()> {
    let r = grid.res;
    let values: Vec<u8> = grid.values.iter().flat_map(|v| v.to_le_bytes()).collect();
    let arrays = [
        (
            "values.npy",
            npy_header("<f4", &format!("({r}, {r}, {r})")),
            values,
        ),
        (
            "origin.npy",
            npy_header("<f8", "(3,)"),
            grid.origin.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ),
        (
            "spacing.npy",
            npy_header("<f8", "()"),
            grid.spacing.to_le_bytes().to_vec(),
        ),
    ];
    let total: u64 = arrays
        .iter()
        .map(|(_, h, d)| (h.len() + d.len() + 128) as u64)
        .sum();
    if total > u64::from(u32::MAX) {
        return Err(Error::Output {
            path: path.to_path_buf(),
            message: format!(
                "a grid of {r}³ values is over 4 GiB, which needs ZIP64; spsr writes grids of \
                 at most 1023³"
            ),
        });
    }
    write_atomically(path, |w| {
        let mut offset = 0u32;
        let mut central = Vec::new();
        let mut count = 0u16;
        for (name, header, data) in &arrays {
            let size = (header.len() + data.len()) as u32;
            let mut crc = Crc32::new();
            crc.update(header);
            crc.update(data);
            let crc = crc.finish();
            let local = entry_header(0x0403_4b50, name, crc, size, None);
            w.write_all(&local)?;
            w.write_all(header)?;
            w.write_all(data)?;
            central.extend(entry_header(0x0201_4b50, name, crc, size, Some(offset)));
            offset += local.len() as u32 + size;
            count += 1;
        }
        w.write_all(&central)?;
        let mut end = Vec::with_capacity(22);
        end.extend(0x0605_4b50u32.to_le_bytes());
        end.extend([0u8; 4]); // this disk, the disk of the central directory
        end.extend(count.to_le_bytes());
        end.extend(count.to_le_bytes());
        end.extend((central.len() as u32).to_le_bytes());
        end.extend(offset.to_le_bytes());
        end.extend(0u16.to_le_bytes()); // no comment
        w.write_all(&end)
    })
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

/// A stored (uncompressed) entry's local header (`offset` None) or central directory record.
fn entry_header(signature: u32, name: &str, crc: u32, size: u32, offset: Option<u32>) -> Vec<u8> {
    let mut h = Vec::with_capacity(46 + name.len());
    h.extend(signature.to_le_bytes());
    if offset.is_some() {
        h.extend(20u16.to_le_bytes()); // made by: version 2.0
    }
    h.extend(20u16.to_le_bytes()); // needed: version 2.0
    h.extend(0u16.to_le_bytes()); // flags
    h.extend(0u16.to_le_bytes()); // method: stored
    h.extend(0u16.to_le_bytes()); // time 00:00
    h.extend(0x21u16.to_le_bytes()); // date 1980-01-01: fixed, so the file is reproducible
    h.extend(crc.to_le_bytes());
    h.extend(size.to_le_bytes()); // compressed
    h.extend(size.to_le_bytes()); // uncompressed
    h.extend((name.len() as u16).to_le_bytes());
    h.extend(0u16.to_le_bytes()); // extra field
    if let Some(offset) = offset {
        h.extend(0u16.to_le_bytes()); // comment
        h.extend(0u16.to_le_bytes()); // disk
        h.extend(0u16.to_le_bytes()); // internal attributes
        h.extend(0u32.to_le_bytes()); // external attributes
        h.extend(offset.to_le_bytes());
    }
    h.extend(name.as_bytes());
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
