//! PLY point clouds, streamed: the header is parsed, elements before `vertex` are skipped, and
//! vertices are decoded record by record (ASCII, binary little or big endian). `x y z` are
//! required; `intensity` (or CloudCompare's `scalar_intensity`) is kept. No pose.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

use super::error::{Context, Result, ScanError, bail};
use asbuilt_protocol::ScanPoint;

use super::{Batcher, ReadNotes, ScanInfo, Sink};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
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
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
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

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
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
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => num!(i16, 2),
            Scalar::U16 => num!(u16, 2),
            Scalar::I32 => num!(i32, 4),
            Scalar::U32 => num!(u32, 4),
            Scalar::F32 => num!(f32, 4),
            Scalar::F64 => num!(f64, 8),
        }
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar(String, Scalar),
    List(Scalar, Scalar),
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
}

struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    lines: u64,
}

impl Header {
    /// Where the points are: the `vertex` element, which need not come first.
    fn vertex_element(&self, path: &Path) -> Result<usize> {
        self.elements
            .iter()
            .position(|e| e.name == "vertex")
            .with_context(|| format!("{} has no `vertex` element", path.display()))
    }
}

fn header(reader: &mut impl BufRead, path: &Path) -> Result<Header> {
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
            ["property", "list", c, i, _] => {
                let (Some(c), Some(i)) = (Scalar::parse(c), Scalar::parse(i)) else {
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
                    .push(Property::List(c, i));
            }
            ["property", t, name] => {
                let t = Scalar::parse(t)
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

pub fn scans(path: &Path) -> Result<Vec<ScanInfo>> {
    let mut reader = BufReader::new(File::open(path)?);
    let h = header(&mut reader, path)?;
    let vertex = &h.elements[h.vertex_element(path)?];
    Ok(vec![ScanInfo {
        index: 0,
        name: super::stem(path),
        points: Some(vertex.count),
        pose: None,
        offset: 0,
        first_line: 0,
    }])
}

/// Reads one binary record of `e`, calling `take(property index, value)` for scalars.
fn binary_record(
    reader: &mut impl Read,
    e: &Element,
    enc: Encoding,
    buf: &mut [u8; 8],
    take: &mut impl FnMut(usize, f64),
) -> Result<()> {
    for (k, p) in e.properties.iter().enumerate() {
        match p {
            Property::Scalar(_, t) => {
                reader.read_exact(&mut buf[..t.size()])?;
                take(k, t.decode(&buf[..], enc));
            }
            Property::List(c, i) => {
                reader.read_exact(&mut buf[..c.size()])?;
                let n = c.decode(&buf[..], enc) as usize;
                for _ in 0..n {
                    reader.read_exact(&mut buf[..i.size()])?;
                }
            }
        }
    }
    Ok(())
}

pub fn stream(path: &Path, chunk: usize, sink: &mut Sink) -> Result<ReadNotes> {
    let mut reader = BufReader::with_capacity(1 << 20, File::open(path)?);
    let h = header(&mut reader, path)?;
    let vi = h.vertex_element(path)?;
    let vertex = &h.elements[vi];
    let find = |names: &[&str]| {
        vertex
            .properties
            .iter()
            .position(|p| matches!(p, Property::Scalar(n, _) if names.contains(&n.as_str())))
    };
    let (Some(ix), Some(iy), Some(iz)) = (find(&["x"]), find(&["y"]), find(&["z"])) else {
        bail!("{}: the vertex element needs x, y and z", path.display());
    };
    let ii = find(&["intensity", "scalar_intensity"]);
    let mut notes = ReadNotes::default();
    let mut out = Batcher::new(chunk, sink);
    let mut line_no = h.lines;
    let mut buf = [0u8; 8];
    let mut text = String::new();
    let truncated = |n: u64| {
        ScanError::Content(format!(
            "{}: the file ends after {n} of {} vertices (truncated?)",
            path.display(),
            vertex.count
        ))
    };
    // Skip what comes before the vertices.
    for e in &h.elements[..vi] {
        for _ in 0..e.count {
            if h.encoding == Encoding::Ascii {
                text.clear();
                if reader.read_line(&mut text)? == 0 {
                    return Err(truncated(0));
                }
                line_no += 1;
            } else {
                binary_record(&mut reader, e, h.encoding, &mut buf, &mut |_, _| {})
                    .map_err(|_| truncated(0))?;
            }
        }
    }
    let mut v = [0f64; 4];
    for n in 0..vertex.count {
        v = [f64::NAN, f64::NAN, f64::NAN, 0.0];
        let mut take = |k: usize, x: f64| {
            if k == ix {
                v[0] = x
            } else if k == iy {
                v[1] = x
            } else if k == iz {
                v[2] = x
            } else if Some(k) == ii {
                v[3] = x
            }
        };
        if h.encoding == Encoding::Ascii {
            text.clear();
            if reader.read_line(&mut text)? == 0 {
                return Err(truncated(n));
            }
            line_no += 1;
            let mut ok = true;
            let mut tokens = text.split_whitespace();
            for (k, p) in vertex.properties.iter().enumerate() {
                match p {
                    Property::Scalar(..) => match tokens.next().map(str::parse::<f64>) {
                        Some(Ok(x)) => take(k, x),
                        _ => ok = false,
                    },
                    Property::List(..) => {
                        let c: usize = tokens.next().and_then(|t| t.parse().ok()).unwrap_or(0);
                        tokens.by_ref().take(c).for_each(drop);
                    }
                }
            }
            if !ok {
                notes.malformed(line_no);
                continue;
            }
        } else {
            binary_record(&mut reader, vertex, h.encoding, &mut buf, &mut take)
                .map_err(|_| truncated(n))?;
        }
        let mut p = ScanPoint::new(v[0] as f32, v[1] as f32, v[2] as f32);
        p.intensity = v[3] as f32;
        out.push(p)?;
    }
    let _ = v;
    out.finish()?;
    Ok(notes)
}
