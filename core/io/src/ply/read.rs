//! PLY read record by record, for scans and designs alike: the header, then each element's
//! records in order (ASCII, binary little or big endian), every scalar and list entry as an
//! f64 (exact for every PLY type). Nothing is held but the record being read.

use std::io::BufRead;
use std::path::Path;

use crate::scan::error::{Context, Result, ScanError, bail};

/// How the records are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Encoding {
    Ascii,
    Little,
    Big,
}

/// A PLY scalar type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Type {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Type {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Type::I8,
            "uchar" | "uint8" => Type::U8,
            "short" | "int16" => Type::I16,
            "ushort" | "uint16" => Type::U16,
            "int" | "int32" => Type::I32,
            "uint" | "uint32" => Type::U32,
            "float" | "float32" => Type::F32,
            "double" | "float64" => Type::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Type::I8 | Type::U8 => 1,
            Type::I16 | Type::U16 => 2,
            Type::I32 | Type::U32 | Type::F32 => 4,
            Type::F64 => 8,
        }
    }

    fn decode(self, b: &[u8], enc: Encoding) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().expect("sized");
                (if enc == Encoding::Big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match self {
            Type::I8 => b[0] as i8 as f64,
            Type::U8 => b[0] as f64,
            Type::I16 => num!(i16, 2),
            Type::U16 => num!(u16, 2),
            Type::I32 => num!(i32, 4),
            Type::U32 => num!(u32, 4),
            Type::F32 => num!(f32, 4),
            Type::F64 => num!(f64, 8),
        }
    }
}

/// A property of an element: a scalar, or a list of scalars after its count.
#[derive(Debug, Clone)]
pub(crate) enum Property {
    Scalar(String, Type),
    List {
        name: String,
        count: Type,
        item: Type,
    },
}

/// An element of the header: its name, how many records, and their properties.
#[derive(Debug, Clone)]
pub(crate) struct Element {
    pub(crate) name: String,
    pub(crate) count: u64,
    pub(crate) properties: Vec<Property>,
}

impl Element {
    /// The first scalar property with one of these names.
    pub(crate) fn scalar(&self, names: &[&str]) -> Option<usize> {
        self.properties
            .iter()
            .position(|p| matches!(p, Property::Scalar(n, _) if names.contains(&n.as_str())))
    }
}

/// Where each property of a binary record of `e` starts, and the record's size; `None` when a
/// list makes the records' sizes vary. Such records are read a block at a time.
pub(crate) fn fixed_layout(e: &Element) -> Option<(Vec<(usize, Type)>, usize)> {
    let mut at = 0;
    let mut layout = Vec::with_capacity(e.properties.len());
    for p in &e.properties {
        let Property::Scalar(_, t) = *p else {
            return None;
        };
        layout.push((at, t));
        at += t.size();
    }
    Some((layout, at))
}

/// A PLY header: the encoding, the elements in file order, and its length in lines.
pub(crate) struct Header {
    pub(crate) encoding: Encoding,
    pub(crate) elements: Vec<Element>,
    pub(crate) lines: u64,
}

impl Header {
    /// Where the points are: the `vertex` element, which need not come first.
    pub(crate) fn vertex_element(&self, path: &Path) -> Result<usize> {
        self.element("vertex")
            .with_context(|| format!("{} has no `vertex` element", path.display()))
    }

    /// The element of this name, if the file has one.
    pub(crate) fn element(&self, name: &str) -> Option<usize> {
        self.elements.iter().position(|e| e.name == name)
    }
}

/// Reads the header, leaving `reader` at the first record.
pub(crate) fn header(reader: &mut impl BufRead, path: &Path) -> Result<Header> {
    let mut line = String::new();
    let mut lines = 0u64;
    let mut read = |line: &mut String| -> Result<()> {
        line.clear();
        if reader.read_line(line)? == 0 {
            bail!("{}: the PLY header has no end_header", path.display());
        }
        lines += 1;
        Ok(())
    };
    read(&mut line)?;
    if line.trim() != "ply" {
        bail!(
            "{} is not a PLY file (it does not start with `ply`)",
            path.display()
        );
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        read(&mut line)?;
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["end_header"] => break,
            ["format", enc, _] => {
                encoding = Some(match *enc {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    other => bail!("{}: unknown PLY format {other}", path.display()),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .with_context(|| format!("{}: bad element count {count:?}", path.display()))?,
                properties: Vec::new(),
            }),
            ["property", "list", c, i, name] => {
                let (Some(count), Some(item)) = (Type::parse(c), Type::parse(i)) else {
                    bail!(
                        "{}: unknown PLY list types in {:?}",
                        path.display(),
                        line.trim()
                    );
                };
                elements
                    .last_mut()
                    .context("a PLY property before any element")?
                    .properties
                    .push(Property::List {
                        name: name.to_string(),
                        count,
                        item,
                    });
            }
            ["property", t, name] => {
                let t = Type::parse(t)
                    .with_context(|| format!("{}: unknown PLY type {t}", path.display()))?;
                elements
                    .last_mut()
                    .context("a PLY property before any element")?
                    .properties
                    .push(Property::Scalar(name.to_string(), t));
            }
            [] | ["comment", ..] | ["obj_info", ..] => {}
            _ => bail!(
                "{}: unexpected PLY header line {:?}",
                path.display(),
                line.trim()
            ),
        }
    }
    Ok(Header {
        encoding: encoding
            .with_context(|| format!("{}: the PLY header has no format line", path.display()))?,
        elements,
        lines,
    })
}

/// What a record gives its reader: `Scalar(property, value)` for a scalar, `List(property,
/// count)` before a list's entries, then `Item(property, value)` for each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Value {
    Scalar(usize, f64),
    List(usize, usize),
    Item(usize, f64),
}

/// Puts scalar property `k`'s value `x` in the slot of `v` that `at` gives it, if any.
#[inline]
pub(crate) fn place<const N: usize>(v: &mut [f64; N], at: [Option<usize>; N], k: usize, x: f64) {
    if let Some(slot) = at.iter().position(|&a| a == Some(k)) {
        v[slot] = x;
    }
}

/// How a record ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Record {
    /// Read whole.
    Read,
    /// An ASCII line whose tokens are not the record's numbers; the line is passed.
    Malformed,
    /// The file ended.
    End,
}

/// Reads a header's records one at a time, with buffers reused from record to record.
pub(crate) struct Records<R> {
    reader: R,
    encoding: Encoding,
    text: String,
    buf: [u8; 8],
}

impl<R: BufRead> Records<R> {
    /// Records of a file whose header `reader` has just read.
    pub(crate) fn new(reader: R, encoding: Encoding) -> Self {
        Self {
            reader,
            encoding,
            text: String::new(),
            buf: [0; 8],
        }
    }

    /// Reads one record of `e`, handing `take` its values in order. An ASCII record stops at
    /// its first token that is not a number (what was taken before stands), and is
    /// [`Record::Malformed`]; a binary one that the file cuts short is [`Record::End`].
    pub(crate) fn next(&mut self, e: &Element, take: &mut impl FnMut(Value)) -> Result<Record> {
        if self.encoding == Encoding::Ascii {
            self.text.clear();
            if self.reader.read_line(&mut self.text)? == 0 {
                return Ok(Record::End);
            }
            let mut tokens = self.text.split_ascii_whitespace();
            // A `float` is read as one, so that it has the value a binary file would give.
            let mut number = |t: Type| {
                let token = tokens.next()?;
                match t {
                    Type::F32 => token.parse::<f32>().ok().map(f64::from),
                    _ => token.parse::<f64>().ok(),
                }
            };
            for (k, p) in e.properties.iter().enumerate() {
                match *p {
                    Property::Scalar(_, t) => match number(t) {
                        Some(x) => take(Value::Scalar(k, x)),
                        None => return Ok(Record::Malformed),
                    },
                    Property::List { count: c, item, .. } => {
                        let Some(n) = number(c).and_then(count) else {
                            return Ok(Record::Malformed);
                        };
                        take(Value::List(k, n));
                        for _ in 0..n {
                            match number(item) {
                                Some(x) => take(Value::Item(k, x)),
                                None => return Ok(Record::Malformed),
                            }
                        }
                    }
                }
            }
            return Ok(Record::Read);
        }
        for (k, p) in e.properties.iter().enumerate() {
            match *p {
                Property::Scalar(_, t) => match self.binary(t)? {
                    Some(x) => take(Value::Scalar(k, x)),
                    None => return Ok(Record::End),
                },
                Property::List { count: c, item, .. } => {
                    let Some(n) = self.binary(c)? else {
                        return Ok(Record::End);
                    };
                    let n = count(n).with_context(|| format!("a list of {n} entries"))?;
                    take(Value::List(k, n));
                    for _ in 0..n {
                        match self.binary(item)? {
                            Some(x) => take(Value::Item(k, x)),
                            None => return Ok(Record::End),
                        }
                    }
                }
            }
        }
        Ok(Record::Read)
    }

    /// Whole binary records of `size` bytes into `buf` (a multiple of `size` long), as many as
    /// fit or as the file still holds: how many. Fewer than fit means the file ended.
    pub(crate) fn block(&mut self, buf: &mut [u8], size: usize) -> Result<usize> {
        let mut filled = 0;
        while filled < buf.len() {
            match self.reader.read(&mut buf[filled..]) {
                Ok(0) => break,
                Ok(k) => filled += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(ScanError::Io(e)),
            }
        }
        Ok(filled / size)
    }

    /// The value of a scalar of type `t` at the start of `b`, a binary record's bytes.
    pub(crate) fn decode(&self, t: Type, b: &[u8]) -> f64 {
        t.decode(b, self.encoding)
    }

    /// One binary scalar; `None` where the file ends.
    fn binary(&mut self, t: Type) -> Result<Option<f64>> {
        let b = &mut self.buf[..t.size()];
        match self.reader.read_exact(b) {
            Ok(()) => Ok(Some(t.decode(b, self.encoding))),
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(None),
            Err(e) => Err(ScanError::Io(e)),
        }
    }
}

/// A list's count or a vertex index: a whole number, not negative, below `u32::MAX`.
pub(crate) fn whole(x: f64) -> Option<u32> {
    (x >= 0.0 && x.fract() == 0.0 && x < u32::MAX as f64).then_some(x as u32)
}

/// A list's count.
fn count(n: f64) -> Option<usize> {
    whole(n).map(|n| n as usize)
}
