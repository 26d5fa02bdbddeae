//! A streaming LZF decompressor (the compression of PCD `binary_compressed` data).
//!
//! LZF is a byte-oriented LZ77 variant. Each block starts with a control byte `c`:
//! `c < 32` is a literal run of `c + 1` bytes that follow; otherwise `len = c >> 5`
//! (7 meaning: add the next byte), the back-reference distance is
//! `((c & 31) << 8) + next byte + 1`, and `len + 2` bytes are copied from that far back in
//! the output (the copy may overlap what it writes). Distances never exceed 8192 bytes, so
//! the decoder keeps only the last 8 KiB of output plus what the caller has not read yet.

use std::io::{self, Read};

/// Longest back-reference distance LZF can encode.
const WINDOW: usize = 8192;
/// Decoded bytes held before the consumed part is dropped.
const COMPACT_AT: usize = 1 << 20;
/// Compressed bytes read from the source at a time.
const INPUT_CHUNK: usize = 1 << 16;

/// Decompresses an LZF stream read from `input` (which must end where the stream ends).
pub(crate) struct LzfReader<R: Read> {
    input: R,
    inbuf: Vec<u8>,
    ipos: usize,
    input_done: bool,
    /// Recent output (at least the last `WINDOW` bytes) followed by unread output.
    out: Vec<u8>,
    /// Next unread byte of `out`.
    pos: usize,
    /// Bytes produced before `out[0]`.
    dropped: u64,
}

fn corrupt(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

impl<R: Read> LzfReader<R> {
    pub(crate) fn new(input: R) -> Self {
        Self {
            input,
            inbuf: Vec::new(),
            ipos: 0,
            input_done: false,
            out: Vec::new(),
            pos: 0,
            dropped: 0,
        }
    }

    /// Total bytes decompressed so far.
    fn produced(&self) -> u64 {
        self.dropped + self.out.len() as u64
    }

    /// The next compressed byte, or `None` at the end of the input.
    fn next_in(&mut self) -> io::Result<Option<u8>> {
        if self.ipos == self.inbuf.len() {
            if self.input_done {
                return Ok(None);
            }
            self.inbuf.resize(INPUT_CHUNK, 0);
            let n = loop {
                match self.input.read(&mut self.inbuf) {
                    Ok(n) => break n,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            };
            self.inbuf.truncate(n);
            self.ipos = 0;
            if n == 0 {
                self.input_done = true;
                return Ok(None);
            }
        }
        self.ipos += 1;
        Ok(Some(self.inbuf[self.ipos - 1]))
    }

    fn need_in(&mut self, what: &str) -> io::Result<u8> {
        self.next_in()?.ok_or_else(|| {
            corrupt(format!(
                "the compressed data end inside a block ({what}) after {} decompressed bytes",
                self.produced()
            ))
        })
    }

    /// Decodes one block; false at the end of the input.
    fn decode_block(&mut self) -> io::Result<bool> {
        let Some(ctrl) = self.next_in()? else {
            return Ok(false);
        };
        if self.pos > COMPACT_AT {
            let cut = self.pos.min(self.out.len() - WINDOW);
            self.out.drain(..cut);
            self.pos -= cut;
            self.dropped += cut as u64;
        }
        if ctrl < 32 {
            for _ in 0..=ctrl {
                let b = self.need_in("literal run")?;
                self.out.push(b);
            }
        } else {
            let mut len = usize::from(ctrl >> 5);
            if len == 7 {
                len += usize::from(self.need_in("match length")?);
            }
            len += 2;
            let dist =
                (usize::from(ctrl & 31) << 8) + usize::from(self.need_in("match offset")?) + 1;
            if dist > self.out.len() {
                return Err(corrupt(format!(
                    "a back-reference reaches {dist} bytes back, before the start of the data, at decompressed byte {}",
                    self.produced()
                )));
            }
            let start = self.out.len() - dist;
            for k in 0..len {
                let b = self.out[start + k];
                self.out.push(b);
            }
        }
        Ok(true)
    }
}

impl<R: Read> Read for LzfReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        while self.out.len() - self.pos < buf.len() && self.decode_block()? {}
        let n = buf.len().min(self.out.len() - self.pos);
        buf[..n].copy_from_slice(&self.out[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(data: &[u8]) -> io::Result<Vec<u8>> {
        let mut out = Vec::new();
        LzfReader::new(data).read_to_end(&mut out)?;
        Ok(out)
    }

    #[test]
    fn literals_and_overlapping_references() {
        // "abc", then copy 2+2 = 4 bytes from 3 back (overlapping): "abcabca".
        assert_eq!(
            decode(&[2, b'a', b'b', b'c', 2 << 5, 2]).unwrap(),
            b"abcabca"
        );
        // Long match: len 7 + 3 + 2 = 12 copies of "x" from 1 back.
        assert_eq!(decode(&[0, b'x', 7 << 5, 3, 0]).unwrap(), vec![b'x'; 13]);
        assert_eq!(decode(&[]).unwrap(), Vec::<u8>::new());
    }

    #[test]
    fn long_streams_keep_the_window_across_compaction() {
        // 3 MB of a repeating 8000-byte pattern: one literal prefix, then references 8000 back.
        let pattern: Vec<u8> = (0..8000u32).map(|i| (i * 7 % 251) as u8).collect();
        let mut enc = Vec::new();
        for chunk in pattern.chunks(32) {
            enc.push(chunk.len() as u8 - 1);
            enc.extend_from_slice(chunk);
        }
        let total = 3_000_000usize;
        let mut produced = pattern.len();
        let d = 8000 - 1;
        while produced < total {
            let len = (total - produced).min(264);
            if len < 3 {
                break;
            }
            let l = len - 2;
            if l < 7 {
                enc.push(((l as u8) << 5) | (d >> 8) as u8);
            } else {
                enc.push((7 << 5) | (d >> 8) as u8);
                enc.push((l - 7) as u8);
            }
            enc.push((d & 255) as u8);
            produced += len;
        }
        let out = decode(&enc).unwrap();
        assert_eq!(out.len(), produced);
        assert!(out.iter().enumerate().all(|(i, &b)| b == pattern[i % 8000]));
    }

    #[test]
    fn corrupt_streams_are_errors() {
        for bad in [
            &[5u8, 1, 2][..],
            &[0, 1, 1 << 5],
            &[0, 1, 1 << 5, 4],
            &[7 << 5],
        ] {
            let e = decode(bad).unwrap_err();
            assert_eq!(e.kind(), io::ErrorKind::InvalidData, "{bad:?}");
        }
    }
}
