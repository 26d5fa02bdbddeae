//! PLY header parsing and streaming decoding of element records (ASCII, binary little and big
//! endian). The body is never loaded whole: records are decoded from a `BufRead` and handed to
//! a callback one at a time.

use std::io::{BufRead, ErrorKind, Read};
use std::path::{Path, PathBuf};

use crate::error::Error;
use crate::Result;

/// Longest header line accepted; longer means the file is not a PLY header (binary garbage).
const MAX_HEADER_LINE: u64 = 64 * 1024;
/// Bytes decoded per chunk on the fixed-size binary record path.
const CHUNK_BYTES: usize = 1 << 20;

/// A PLY scalar type (both naming families map to the same variants).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Size in bytes in a binary body.
    pub(crate) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Decodes one value from the start of `b` (which holds at least `self.size()` bytes).
    #[inline(always)]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        macro_rules! rd {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if big {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Scalar::I8 => rd!(i8, 1),
            Scalar::U8 => rd!(u8, 1),
            Scalar::I16 => rd!(i16, 2),
            Scalar::U16 => rd!(u16, 2),
            Scalar::I32 => rd!(i32, 4),
            Scalar::U32 => rd!(u32, 4),
            Scalar::F32 => rd!(f32, 4),
            Scalar::F64 => rd!(f64, 8),
        }
    }
}

/// A property: a scalar, or a list with a count type and an item type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// One `property` line of the header.
#[derive(Debug, Clone)]
pub(crate) struct Property {
    pub(crate) name: String,
    pub(crate) kind: Kind,
}

/// One `element` of the header with its properties.
#[derive(Debug, Clone)]
pub(crate) struct Element {
    pub(crate) name: String,
    pub(crate) count: u64,
    pub(crate) props: Vec<Property>,
    /// Header line (1-based) of the `element` line.
    pub(crate) line: usize,
}

impl Element {
    /// Index of the property called `name`, if any.
    pub(crate) fn find(&self, name: &str) -> Option<usize> {
        self.props.iter().position(|p| p.name == name)
    }

    /// Smallest possible size of one record in the body (bytes), at least 1.
    fn min_record_bytes(&self, ascii: bool) -> u64 {
        let n: usize = self
            .props
            .iter()
            .map(|p| match (ascii, p.kind) {
                (true, _) => 2,
                (false, Kind::Scalar(t)) => t.size(),
                (false, Kind::List { count, .. }) => count.size(),
            })
            .sum();
        n.max(1) as u64
    }
}

/// Body encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Ascii,
    Binary { big_endian: bool },
}

/// The parsed header.
#[derive(Debug, Clone)]
pub(crate) struct Header {
    pub(crate) format: Format,
    pub(crate) elements: Vec<Element>,
    /// Text of the `comment` lines, after the keyword.
    pub(crate) comments: Vec<String>,
}

impl Header {
    /// Index of the element called `name`, if any.
    pub(crate) fn find(&self, name: &str) -> Option<usize> {
        self.elements.iter().position(|e| e.name == name)
    }
}

/// Streaming reader over a PLY file: header parsed on construction, then elements read in
/// file order with [`PlyReader::read_element`].
pub(crate) struct PlyReader<R: BufRead> {
    reader: R,
    path: PathBuf,
    pub(crate) header: Header,
    /// Last line consumed (1-based), meaningful for ASCII bodies.
    line: usize,
    /// Bytes consumed from the start of the file.
    offset: u64,
    file_len: u64,
    next_element: usize,
}

fn shorten(s: &str) -> String {
    const MAX: usize = 40;
    if s.chars().count() > MAX {
        let t: String = s.chars().take(MAX).collect();
        format!("{t}...")
    } else {
        s.to_string()
    }
}

const TYPE_NAMES: &str =
    "char, uchar, short, ushort, int, uint, float, double, int8, uint8, int16, uint16, int32, uint32, float32, float64";

impl<R: BufRead> PlyReader<R> {
    /// Parses the header from the start of `reader`. `file_len` bounds memory reservations.
    pub(crate) fn new(reader: R, path: &Path, file_len: u64) -> Result<Self> {
        let mut me = PlyReader {
            reader,
            path: path.to_path_buf(),
            header: Header {
                format: Format::Ascii,
                elements: Vec::new(),
                comments: Vec::new(),
            },
            line: 0,
            offset: 0,
            file_len,
            next_element: 0,
        };
        me.header = me.parse_header()?;
        Ok(me)
    }

    fn parse_err(&self, message: String) -> Error {
        Error::Parse {
            path: self.path.clone(),
            message,
        }
    }

    fn io_err(&self, source: std::io::Error) -> Error {
        Error::Io {
            path: self.path.clone(),
            source,
        }
    }

    /// Reads one raw line (without the line ending); `None` at end of file.
    fn header_line(&mut self) -> Result<Option<String>> {
        let mut buf = Vec::new();
        let n = (&mut self.reader)
            .take(MAX_HEADER_LINE)
            .read_until(b'\n', &mut buf)
            .map_err(|e| self.io_err(e))?;
        if n == 0 {
            return Ok(None);
        }
        self.offset += n as u64;
        self.line += 1;
        if buf.last() != Some(&b'\n') && n as u64 == MAX_HEADER_LINE {
            return Err(self.parse_err(format!(
                "header line {} is longer than {} bytes; the header is malformed or `end_header` is missing",
                self.line, MAX_HEADER_LINE
            )));
        }
        while matches!(buf.last(), Some(b'\n' | b'\r')) {
            buf.pop();
        }
        Ok(Some(String::from_utf8_lossy(&buf).into_owned()))
    }

    fn parse_header(&mut self) -> Result<Header> {
        match self.header_line()? {
            Some(l) if l.trim_end() == "ply" => {}
            Some(l) => {
                return Err(self.parse_err(format!(
                    "line 1: not a PLY file (the first line is '{}', expected 'ply')",
                    shorten(&l)
                )))
            }
            None => {
                return Err(self.parse_err(
                    "line 1: not a PLY file (the file is empty, expected 'ply')".into(),
                ))
            }
        }
        let mut format = None;
        let mut elements: Vec<Element> = Vec::new();
        let mut comments = Vec::new();
        loop {
            let Some(text) = self.header_line()? else {
                return Err(self.parse_err(format!(
                    "the header has no `end_header` line (file ends at line {})",
                    self.line
                )));
            };
            let ln = self.line;
            let tok: Vec<&str> = text.split_whitespace().collect();
            let Some(&kw) = tok.first() else { continue };
            match kw {
                "comment" => {
                    comments.push(text.trim_start()["comment".len()..].trim().to_string());
                }
                "obj_info" => {}
                "end_header" => break,
                "format" => {
                    let f = match tok.get(1).copied() {
                        Some("ascii") => Format::Ascii,
                        Some("binary_little_endian") => Format::Binary { big_endian: false },
                        Some("binary_big_endian") => Format::Binary { big_endian: true },
                        other => {
                            return Err(self.parse_err(format!(
                                "line {ln}: unknown format '{}' (expected ascii, binary_little_endian or binary_big_endian)",
                                shorten(other.unwrap_or(""))
                            )))
                        }
                    };
                    format = Some(f);
                }
                "element" => {
                    if tok.len() != 3 {
                        return Err(self.parse_err(format!(
                            "line {ln}: expected `element <name> <count>`, found '{}'",
                            shorten(&text)
                        )));
                    }
                    let count: u64 = tok[2].parse().map_err(|_| {
                        self.parse_err(format!(
                            "line {ln}: the count of element '{}' is not a number: '{}'",
                            tok[1],
                            shorten(tok[2])
                        ))
                    })?;
                    elements.push(Element {
                        name: tok[1].to_string(),
                        count,
                        props: Vec::new(),
                        line: ln,
                    });
                }
                "property" => {
                    let prop = self.parse_property(&tok, &text, ln)?;
                    let Some(el) = elements.last_mut() else {
                        return Err(self.parse_err(format!(
                            "line {ln}: property '{}' appears before any `element` line",
                            prop.name
                        )));
                    };
                    el.props.push(prop);
                }
                other => {
                    return Err(self.parse_err(format!(
                        "line {ln}: unknown header keyword '{}'",
                        shorten(other)
                    )))
                }
            }
        }
        let Some(format) = format else {
            return Err(self.parse_err(format!(
                "line {}: the header has no `format` line",
                self.line
            )));
        };
        Ok(Header {
            format,
            elements,
            comments,
        })
    }

    fn parse_property(&self, tok: &[&str], text: &str, ln: usize) -> Result<Property> {
        let ty = |s: &str| {
            Scalar::parse(s).ok_or_else(|| {
                self.parse_err(format!(
                    "line {ln}: unknown property type '{}' (expected one of {TYPE_NAMES})",
                    shorten(s)
                ))
            })
        };
        match tok {
            [_, "list", ct, it, name] => {
                let count = ty(ct)?;
                let item = ty(it)?;
                if !count.is_integer() {
                    return Err(self.parse_err(format!(
                        "line {ln}: the count type of list property '{name}' must be an integer type, not '{ct}'"
                    )));
                }
                Ok(Property {
                    name: name.to_string(),
                    kind: Kind::List { count, item },
                })
            }
            [_, t, name] if *t != "list" => Ok(Property {
                name: name.to_string(),
                kind: Kind::Scalar(ty(t)?),
            }),
            _ => Err(self.parse_err(format!(
                "line {ln}: expected `property <type> <name>` or `property list <count type> <item type> <name>`, found '{}'",
                shorten(text)
            ))),
        }
    }

    /// A safe capacity for the records of element `idx`: its count, bounded by what the file
    /// can actually hold (so a bogus count cannot trigger a huge allocation).
    pub(crate) fn capacity_hint(&self, idx: usize) -> usize {
        let el = &self.header.elements[idx];
        let ascii = self.header.format == Format::Ascii;
        let fits = self.file_len / el.min_record_bytes(ascii) + 1;
        el.count.min(fits).min(usize::MAX as u64) as usize
    }

    fn truncated(&self, el: &Element, rec: u64) -> Error {
        let where_ = match self.header.format {
            Format::Ascii => format!("after line {}", self.line),
            Format::Binary { .. } => format!("at byte offset {}", self.offset),
        };
        self.parse_err(format!(
            "file is truncated: the data ends {where_}, in {} record {rec} of {} (0-based); the element is declared on header line {}",
            el.name, el.count, el.line
        ))
    }

    /// Reads element `idx` (elements must be read in file order). For every record, `f` gets
    /// the record index, the values of the scalar properties `scalars` (property indices, in
    /// that order), and the items of list property `list` (empty when `None`). All values are
    /// converted to `f64`. Pass no scalars and no list to skip an element.
    pub(crate) fn read_element<F>(
        &mut self,
        idx: usize,
        scalars: &[usize],
        list: Option<usize>,
        mut f: F,
    ) -> Result<()>
    where
        F: FnMut(u64, &[f64], &[f64]) -> Result<()>,
    {
        debug_assert_eq!(idx, self.next_element, "PLY elements must be read in order");
        self.next_element = idx + 1;
        let el = self.header.elements[idx].clone();
        // slot[p] = position in `scalars` of property p.
        let mut slot = vec![None; el.props.len()];
        for (k, &p) in scalars.iter().enumerate() {
            slot[p] = Some(k);
        }
        let has_lists = el.props.iter().any(|p| matches!(p.kind, Kind::List { .. }));
        match self.header.format {
            Format::Ascii => self.read_ascii(&el, &slot, scalars.len(), list, &mut f),
            Format::Binary { big_endian } if !has_lists => {
                self.read_binary_fixed(&el, &slot, scalars.len(), big_endian, &mut f)
            }
            Format::Binary { big_endian } => {
                self.read_binary_lists(&el, &slot, scalars.len(), list, big_endian, &mut f)
            }
        }
    }

    /// Reads until `buf` is full or the file ends; returns the number of bytes read.
    fn read_full(&mut self, buf: &mut [u8]) -> Result<usize> {
        let mut got = 0;
        while got < buf.len() {
            match self.reader.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(self.io_err(e)),
            }
        }
        Ok(got)
    }

    /// Binary records without lists: fixed size, decoded chunk by chunk.
    fn read_binary_fixed<F>(
        &mut self,
        el: &Element,
        slot: &[Option<usize>],
        nvals: usize,
        big: bool,
        f: &mut F,
    ) -> Result<()>
    where
        F: FnMut(u64, &[f64], &[f64]) -> Result<()>,
    {
        // (offset in record, type, destination slot) for the wanted properties.
        let mut fields = Vec::new();
        let mut rec_size = 0usize;
        for (p, prop) in el.props.iter().enumerate() {
            if let Kind::Scalar(t) = prop.kind {
                if let Some(k) = slot[p] {
                    fields.push((rec_size, t, k));
                }
                rec_size += t.size();
            }
        }
        if el.count == 0 {
            return Ok(());
        }
        if rec_size == 0 {
            // Records with no properties occupy no bytes.
            let vals = vec![0.0; nvals];
            for r in 0..el.count {
                f(r, &vals, &[])?;
            }
            return Ok(());
        }
        let chunk_recs = (CHUNK_BYTES / rec_size).max(1) as u64;
        let alloc_recs = chunk_recs.min(el.count) as usize;
        let mut buf = vec![0u8; alloc_recs * rec_size];
        let mut vals = vec![0.0f64; nvals];
        let mut done = 0u64;
        while done < el.count {
            let n = chunk_recs.min(el.count - done) as usize;
            let bytes = n * rec_size;
            let got = self.read_full(&mut buf[..bytes])?;
            if got < bytes {
                self.offset += got as u64;
                return Err(self.truncated(el, done + (got / rec_size) as u64));
            }
            self.offset += bytes as u64;
            if nvals > 0 {
                for (r, rec) in buf[..bytes].chunks_exact(rec_size).enumerate() {
                    for &(off, t, k) in &fields {
                        vals[k] = t.decode(&rec[off..], big);
                    }
                    f(done + r as u64, &vals, &[])?;
                }
            }
            done += n as u64;
        }
        Ok(())
    }

    fn fill(&mut self, buf: &mut [u8], el: &Element, rec: u64) -> Result<()> {
        match self.reader.read_exact(buf) {
            Ok(()) => {
                self.offset += buf.len() as u64;
                Ok(())
            }
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => Err(self.truncated(el, rec)),
            Err(e) => Err(self.io_err(e)),
        }
    }

    /// Binary records with list properties: variable size, decoded property by property.
    fn read_binary_lists<F>(
        &mut self,
        el: &Element,
        slot: &[Option<usize>],
        nvals: usize,
        list: Option<usize>,
        big: bool,
        f: &mut F,
    ) -> Result<()>
    where
        F: FnMut(u64, &[f64], &[f64]) -> Result<()>,
    {
        let mut small = [0u8; 8];
        let mut scratch: Vec<u8> = Vec::new();
        let mut vals = vec![0.0f64; nvals];
        let mut items: Vec<f64> = Vec::new();
        for r in 0..el.count {
            for (p, prop) in el.props.iter().enumerate() {
                match prop.kind {
                    Kind::Scalar(t) => {
                        self.fill(&mut small[..t.size()], el, r)?;
                        if let Some(k) = slot[p] {
                            vals[k] = t.decode(&small, big);
                        }
                    }
                    Kind::List { count, item } => {
                        self.fill(&mut small[..count.size()], el, r)?;
                        let n = count.decode(&small, big);
                        if n < 0.0 {
                            return Err(self.parse_err(format!(
                                "{} record {r} (0-based), byte offset {}: list '{}' has a negative length {n}",
                                el.name, self.offset, prop.name
                            )));
                        }
                        let bytes = n as u64 * item.size() as u64;
                        if bytes > self.file_len.saturating_sub(self.offset) {
                            return Err(self.truncated(el, r));
                        }
                        scratch.resize(bytes as usize, 0);
                        let mut tmp = std::mem::take(&mut scratch);
                        let res = self.fill(&mut tmp, el, r);
                        scratch = tmp;
                        res?;
                        if list == Some(p) {
                            items.clear();
                            items.extend(
                                scratch
                                    .chunks_exact(item.size())
                                    .map(|c| item.decode(c, big)),
                            );
                        }
                    }
                }
            }
            f(r, &vals, &items)?;
        }
        Ok(())
    }

    /// ASCII records: one record per line (blank lines are skipped).
    fn read_ascii<F>(
        &mut self,
        el: &Element,
        slot: &[Option<usize>],
        nvals: usize,
        list: Option<usize>,
        f: &mut F,
    ) -> Result<()>
    where
        F: FnMut(u64, &[f64], &[f64]) -> Result<()>,
    {
        let mut raw = Vec::new();
        let mut vals = vec![0.0f64; nvals];
        let mut items: Vec<f64> = Vec::new();
        for r in 0..el.count {
            // Next non-blank line.
            let text = loop {
                raw.clear();
                let n = self
                    .reader
                    .read_until(b'\n', &mut raw)
                    .map_err(|e| self.io_err(e))?;
                if n == 0 {
                    return Err(self.truncated(el, r));
                }
                self.line += 1;
                self.offset += n as u64;
                let t = std::str::from_utf8(&raw).map_err(|_| {
                    self.parse_err(format!(
                        "line {}: not valid text (expected the values of {} record {r})",
                        self.line, el.name
                    ))
                })?;
                if !t.trim().is_empty() {
                    break t;
                }
            };
            let ln = self.line;
            let mut tok = text.split_ascii_whitespace();
            let mut ntok = 0usize;
            let err = |msg: String| Error::Parse {
                path: self.path.clone(),
                message: format!("line {ln} ({} record {r}, 0-based): {msg}", el.name),
            };
            let mut next = |what: &str| -> Result<f64> {
                let t = tok.next().ok_or_else(|| {
                    err(format!(
                        "too few values: the line ends before {what} (only {ntok} values)"
                    ))
                })?;
                ntok += 1;
                t.parse::<f64>()
                    .map_err(|_| err(format!("'{}' is not a number ({what})", shorten(t))))
            };
            for (p, prop) in el.props.iter().enumerate() {
                match prop.kind {
                    Kind::Scalar(t) => {
                        let mut v = next(&format!("property '{}'", prop.name))?;
                        if t == Scalar::F32 {
                            // Same value as the binary encoding of the declared type would give.
                            v = v as f32 as f64;
                        }
                        if let Some(k) = slot[p] {
                            vals[k] = v;
                        }
                    }
                    Kind::List { .. } => {
                        let what = format!("the length of list '{}'", prop.name);
                        let n = next(&what)?;
                        if !(n >= 0.0 && n.fract() == 0.0 && n <= u32::MAX as f64) {
                            return Err(err(format!("{what} is not a non-negative integer: {n}")));
                        }
                        let keep = list == Some(p);
                        if keep {
                            items.clear();
                        }
                        let what = format!("an item of list '{}'", prop.name);
                        for _ in 0..n as u64 {
                            let v = next(&what)?;
                            if keep {
                                items.push(v);
                            }
                        }
                    }
                }
            }
            if let Some(extra) = tok.next() {
                return Err(err(format!(
                    "too many values: '{}' after the {ntok} values of the record; one record per line is expected",
                    shorten(extra)
                )));
            }
            f(r, &vals, &items)?;
        }
        Ok(())
    }
}
