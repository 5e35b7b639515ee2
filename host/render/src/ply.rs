//! A small PLY reader (ASCII, binary little and big endian): the `vertex`
//! element (x y z, optional nx ny nz and u v / s t / texture_u texture_v) and
//! the `face` element (a `vertex_indices` or `vertex_index` list, polygons
//! fan-triangulated). Other elements and properties are skipped.

use crate::error::MeshError;
use crate::mesh_input::MeshInput;

#[derive(Clone, Copy, Debug, PartialEq)]
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
    fn parse(s: &str) -> Result<Scalar, MeshError> {
        Ok(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return Err(err(format!("unknown property type {s:?}"))),
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
}

#[derive(Debug)]
enum Property {
    Scalar(Scalar, String),
    List(Scalar, Scalar, String),
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Little,
    Big,
}

fn err(msg: impl Into<String>) -> MeshError {
    MeshError::Ply(msg.into())
}

/// Parses a whole PLY file.
pub fn parse(bytes: &[u8]) -> Result<MeshInput, MeshError> {
    let end = find(bytes, b"end_header").ok_or_else(|| err("no end_header line"))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| err("header is not text"))?;
    let mut body = end + b"end_header".len();
    // The header ends at the newline after end_header (\n or \r\n).
    while body < bytes.len() && bytes[body] != b'\n' {
        body += 1;
    }
    body += 1;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err(err("missing 'ply' magic"));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    _ => return Err(err(format!("unknown format {f}"))),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| err(format!("bad element count {count:?}")))?,
                props: Vec::new(),
            }),
            ["property", "list", c, i, name] => elements
                .last_mut()
                .ok_or_else(|| err("property before element"))?
                .props
                .push(Property::List(
                    Scalar::parse(c)?,
                    Scalar::parse(i)?,
                    name.to_string(),
                )),
            ["property", t, name] => elements
                .last_mut()
                .ok_or_else(|| err("property before element"))?
                .props
                .push(Property::Scalar(Scalar::parse(t)?, name.to_string())),
            _ => return Err(err(format!("unexpected header line {line:?}"))),
        }
    }
    let format = format.ok_or_else(|| err("no format line"))?;
    let mut reader = Reader {
        bytes,
        pos: body,
        format,
    };
    let mut out = MeshInput::default();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    let mut saw_vertex = false;
    for el in &elements {
        let prop_index = |names: &[&str]| {
            el.props
                .iter()
                .position(|p| matches!(p, Property::Scalar(_, n) if names.contains(&n.as_str())))
        };
        let is_vertex = el.name == "vertex";
        let is_face = el.name == "face";
        let (ix, iy, iz) = (prop_index(&["x"]), prop_index(&["y"]), prop_index(&["z"]));
        let (inx, iny, inz) = (
            prop_index(&["nx"]),
            prop_index(&["ny"]),
            prop_index(&["nz"]),
        );
        let iu = prop_index(&["u", "s", "texture_u", "texture_s"]);
        let iv = prop_index(&["v", "t", "texture_v", "texture_t"]);
        let has_n = inx.is_some() && iny.is_some() && inz.is_some();
        let has_uv = iu.is_some() && iv.is_some();
        if is_vertex {
            saw_vertex = true;
            if ix.is_none() || iy.is_none() || iz.is_none() {
                return Err(err("vertex element lacks x, y or z"));
            }
        }
        let face_list = el.props.iter().position(|p| {
            matches!(p, Property::List(_, _, n) if n == "vertex_indices" || n == "vertex_index")
        });
        if is_face && face_list.is_none() {
            return Err(err("face element lacks a vertex_indices list"));
        }
        let mut vals = vec![0f64; el.props.len()];
        let mut list: Vec<f64> = Vec::new();
        for row in 0..el.count {
            if format == Format::Ascii {
                reader.start_line();
            }
            for (k, p) in el.props.iter().enumerate() {
                match p {
                    Property::Scalar(t, _) => vals[k] = reader.read(*t)?,
                    Property::List(ct, it, _) => {
                        let n = reader.read(*ct)?;
                        if !(0.0..=1e6).contains(&n) || n.fract() != 0.0 {
                            return Err(err(format!("bad list length {n} in {} {row}", el.name)));
                        }
                        let keep = Some(k) == face_list;
                        if keep {
                            list.clear();
                        }
                        for _ in 0..n as usize {
                            let v = reader.read(*it)?;
                            if keep {
                                list.push(v);
                            }
                        }
                    }
                }
            }
            if is_vertex {
                let g = |i: Option<usize>| vals[i.unwrap()] as f32;
                out.positions.push([g(ix), g(iy), g(iz)]);
                if has_n {
                    normals.push([g(inx), g(iny), g(inz)]);
                }
                if has_uv {
                    uvs.push([g(iu), g(iv)]);
                }
            } else if is_face {
                if list.len() < 3 {
                    return Err(err(format!("face {row} has {} vertices", list.len())));
                }
                let idx: Vec<u32> = list
                    .iter()
                    .map(|&v| {
                        if v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
                            Err(err(format!("face {row} has bad index {v}")))
                        } else {
                            Ok(v as u32)
                        }
                    })
                    .collect::<Result<_, _>>()?;
                for k in 1..idx.len() - 1 {
                    out.triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
        }
    }
    if !saw_vertex {
        return Err(err("no vertex element"));
    }
    if !normals.is_empty() {
        out.normals = Some(normals);
    }
    if !uvs.is_empty() {
        out.uvs = Some(uvs);
    }
    Ok(out)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    format: Format,
}

impl Reader<'_> {
    fn start_line(&mut self) {
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
    }

    fn read(&mut self, t: Scalar) -> Result<f64, MeshError> {
        if self.format == Format::Ascii {
            while self.pos < self.bytes.len() && matches!(self.bytes[self.pos], b' ' | b'\t') {
                self.pos += 1;
            }
            let start = self.pos;
            while self.pos < self.bytes.len() && !self.bytes[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            if start == self.pos {
                return Err(err("unexpected end of ASCII data"));
            }
            let s = std::str::from_utf8(&self.bytes[start..self.pos])
                .map_err(|_| err("non-text ASCII data"))?;
            return s
                .parse::<f64>()
                .map_err(|_| err(format!("bad number {s:?}")));
        }
        let n = t.size();
        let raw = self
            .bytes
            .get(self.pos..self.pos + n)
            .ok_or_else(|| err("file ends inside the binary data"))?;
        self.pos += n;
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(raw);
        if self.format == Format::Big {
            b[..n].reverse();
        }
        Ok(match t {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(b),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_quad_with_normals_and_uvs() {
        let text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float s\nproperty float t\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n1 1 0 0 0 1 1 1\n0 1 0 0 0 1 0 1\n4 0 1 2 3\n";
        let m = parse(text.as_bytes()).unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.uvs.unwrap()[2], [1.0, 1.0]);
        assert_eq!(m.normals.unwrap()[0], [0.0, 0.0, 1.0]);
    }

    #[test]
    fn binary_little_endian_with_extra_element() {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 1\nproperty list uchar uint vertex_indices\nelement edge 1\nproperty int a\nend_header\n".to_vec();
        for p in [[0f32, 0., 0.], [2., 0., 0.], [0., 3., 0.]] {
            for c in p {
                b.extend(c.to_le_bytes());
            }
            b.push(255);
        }
        b.push(3);
        for i in [0u32, 1, 2] {
            b.extend(i.to_le_bytes());
        }
        b.extend(7i32.to_le_bytes());
        let m = parse(&b).unwrap();
        assert_eq!(m.positions[2], [0.0, 3.0, 0.0]);
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert!(m.normals.is_none());
    }

    #[test]
    fn truncated_binary_is_an_error() {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
        b.extend([0u8; 20]);
        let e = parse(&b).unwrap_err();
        assert!(e.to_string().contains("ends inside"), "{e}");
    }

    #[test]
    fn garbage_is_an_error() {
        assert!(parse(b"hello").is_err());
        assert!(
            parse(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
                .is_err()
        );
    }
}
