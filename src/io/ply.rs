//! PLY through `ply-rs-bw`: ascii and binary (both endians), float or double x,y,z, optional normals and
//! colours; other properties and elements are ignored.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use ply_rs_bw::parser::{Parser, Reader};
pub use ply_rs_bw::ply::Encoding;
use ply_rs_bw::ply::{
    Addable, ElementDef, Ply, Property, PropertyAccess, PropertyAccessResult, PropertyDef,
    PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;
use std::io::Write;
use std::path::Path;

/// One vertex as read from or written to a PLY file.
#[derive(Clone, Copy, Default)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
    c: [u8; 3],
}

impl Vertex {
    #[inline]
    fn set_f(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        match name {
            "x" => self.p[0] = v,
            "y" => self.p[1] = v,
            "z" => self.p[2] = v,
            "nx" | "normal_x" => self.n[0] = v,
            "ny" | "normal_y" => self.n[1] = v,
            "nz" | "normal_z" => self.n[2] = v,
            "red" | "r" | "diffuse_red" => self.c[0] = (v.clamp(0.0, 1.0) * 255.0).round() as u8,
            "green" | "g" | "diffuse_green" => {
                self.c[1] = (v.clamp(0.0, 1.0) * 255.0).round() as u8
            }
            "blue" | "b" | "diffuse_blue" => self.c[2] = (v.clamp(0.0, 1.0) * 255.0).round() as u8,
            _ => return PropertyAccessResult::Ignored,
        }
        PropertyAccessResult::Set
    }
    #[inline]
    fn set_int(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        match name {
            "red" | "r" | "diffuse_red" => self.c[0] = v.clamp(0.0, 255.0) as u8,
            "green" | "g" | "diffuse_green" => self.c[1] = v.clamp(0.0, 255.0) as u8,
            "blue" | "b" | "diffuse_blue" => self.c[2] = v.clamp(0.0, 255.0) as u8,
            _ => return self.set_f(name, v as f32),
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Vertex::default()
    }
    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        match property {
            Property::Float(v) => self.set_f(name, v),
            Property::Double(v) => self.set_f(name, v as f32),
            Property::Char(v) => self.set_int(name, v as f64),
            Property::UChar(v) => self.set_int(name, v as f64),
            Property::Short(v) => self.set_int(name, v as f64),
            Property::UShort(v) => self.set_int(name, v as f64),
            Property::Int(v) => self.set_int(name, v as f64),
            Property::UInt(v) => self.set_int(name, v as f64),
            _ => PropertyAccessResult::Ignored,
        }
    }
    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set_f(name, v)
    }
    fn set_double(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        self.set_f(name, v as f32)
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> PropertyAccessResult {
        self.set_int(name, v as f64)
    }
    fn get_float(&self, name: &str) -> Option<f32> {
        match name {
            "x" => Some(self.p[0]),
            "y" => Some(self.p[1]),
            "z" => Some(self.p[2]),
            "nx" => Some(self.n[0]),
            "ny" => Some(self.n[1]),
            "nz" => Some(self.n[2]),
            _ => None,
        }
    }
    fn get_uchar(&self, name: &str) -> Option<u8> {
        match name {
            "red" => Some(self.c[0]),
            "green" => Some(self.c[1]),
            "blue" => Some(self.c[2]),
            _ => None,
        }
    }
}

fn has_all(def: &ElementDef, names: &[&[&str]]) -> bool {
    names
        .iter()
        .all(|alts| alts.iter().any(|n| def.properties.contains_key(*n)))
}

fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// The fewest bytes one binary entry of `def` can take (scalars, and the count of each list).
fn min_entry_bytes(def: &ElementDef) -> usize {
    def.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => scalar_size(t),
            PropertyType::List(c, _) => scalar_size(c),
        })
        .sum()
}

fn colour_names() -> [&'static [&'static str]; 3] {
    [
        &["red", "r", "diffuse_red"],
        &["green", "g", "diffuse_green"],
        &["blue", "b", "diffuse_blue"],
    ]
}

fn cloud_from(def: &ElementDef, elems: &[Vertex]) -> PointCloud {
    let has_normals = has_all(
        def,
        &[
            &["nx", "normal_x"],
            &["ny", "normal_y"],
            &["nz", "normal_z"],
        ],
    );
    let has_colors = has_all(def, &colour_names());
    PointCloud {
        points: elems.iter().map(|v| v.p).collect(),
        normals: has_normals.then(|| elems.iter().map(|v| v.n).collect()),
        colors: has_colors.then(|| elems.iter().map(|v| v.c).collect()),
    }
}

/// Reads a PLY file's `vertex` element.
///
/// A header whose vertex count disagrees with the data (fewer vertices in the data, or data left after the
/// last vertex when `vertex` is the last element) is an error in every encoding. ASCII `nan`/`inf` values
/// are read as such (the caller drops non-finite points with a warning).
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let parser = Parser::<Vertex>::new();
    let mut reader = Reader::new(std::io::Cursor::new(bytes));
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| Error::format(path, format!("bad PLY header: {e}")))?;
    let body = reader.get_ref().position() as usize;
    let Some(vdef) = header.elements.get("vertex") else {
        return Err(Error::format(path, "the PLY file has no `vertex` element"));
    };
    if let Some(PropertyDef { name: pname, .. }) = vdef
        .properties
        .values()
        .find(|p| matches!(p.data_type, PropertyType::List(..)))
    {
        return Err(Error::format(
            path,
            format!("vertex property `{pname}` is a list; expected scalars"),
        ));
    }
    for axis in ["x", "y", "z"] {
        if !vdef.properties.contains_key(axis) {
            return Err(Error::format(
                path,
                format!("the vertex element has no `{axis}` property"),
            ));
        }
    }
    let is_last = header.elements.keys().last().map(|k| k.as_str()) == Some("vertex");
    if header.encoding == Encoding::Ascii {
        return read_ascii(path, bytes, body, &header.elements, is_last);
    }
    // Every count of the header is checked against the data's length before the payload is read.
    let avail = bytes.len().saturating_sub(body);
    let mut need = 0usize;
    for (name, def) in &header.elements {
        let min = min_entry_bytes(def);
        need = def
            .count
            .checked_mul(min)
            .and_then(|b| need.checked_add(b))
            .filter(|&b| b <= avail)
            .ok_or_else(|| {
                Error::format(
                    path,
                    format!(
                        "element `{name}`: the header says {} entries of at least {min} bytes, more than the {avail} \
                         bytes of data after the header (truncated file, or a header that overstates the count)",
                        def.count
                    ),
                )
            })?;
        if name == "vertex" {
            break;
        }
    }
    let mut cloud = None;
    for (name, def) in &header.elements {
        let elems = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(|e| {
                Error::format(
                    path,
                    format!(
                        "element `{name}` (header says {} entries): data is truncated or corrupt: {e}",
                        def.count
                    ),
                )
            })?;
        if name == "vertex" {
            cloud = Some(cloud_from(def, &elems));
            // Remaining elements (faces, ...) are not needed.
            break;
        }
    }
    let cloud = cloud.ok_or_else(|| Error::format(path, "the PLY file has no `vertex` element"))?;
    let consumed = reader.get_ref().position() as usize;
    if is_last && consumed < bytes.len() {
        return Err(Error::format(
            path,
            format!(
                "{} bytes of data follow the last of the header's {} vertices: the header's vertex count does not \
                 match the data",
                bytes.len() - consumed,
                cloud.len()
            ),
        ));
    }
    Ok(cloud)
}

/// The ASCII payload, read here rather than by `ply-rs` so that `nan`/`inf` are numbers and errors name the
/// line. Each element entry is one line; blank lines are skipped.
fn read_ascii(
    path: &Path,
    bytes: &[u8],
    body: usize,
    elements: &ply_rs_bw::ply::KeyMap<ElementDef>,
    vertex_is_last: bool,
) -> Result<PointCloud> {
    let err = |msg: String| Error::format(path, msg);
    let text = std::str::from_utf8(&bytes[body.min(bytes.len())..])
        .map_err(|_| err("the ASCII data is not text".into()))?;
    let first_line = 1 + bytes[..body.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count();
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + first_line, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    for (name, def) in elements {
        if name != "vertex" {
            for i in 0..def.count {
                if lines.next().is_none() {
                    return Err(err(format!(
                        "element `{name}`: the header says {} entries, the data ends after {i} (truncated file, or a header that overstates the count)",
                        def.count
                    )));
                }
            }
            continue;
        }
        // At most one vertex per two bytes of text: never reserve more than the file can hold.
        let mut elems = Vec::with_capacity(def.count.min(text.len() / 2 + 1));
        for i in 0..def.count {
            let Some((lineno, line)) = lines.next() else {
                return Err(err(format!(
                    "the header says {} vertices, the data ends after {i} (truncated file, or a header that overstates the count)",
                    def.count
                )));
            };
            let mut toks = line.split_whitespace();
            let mut v = Vertex::default();
            for (pname, p) in &def.properties {
                let tok = toks.next().ok_or_else(|| {
                    err(format!(
                        "line {lineno}: vertex {i}: property `{pname}` is missing"
                    ))
                })?;
                let x: f64 = tok.parse().map_err(|_| {
                    err(format!(
                        "line {lineno}: vertex {i}: property `{pname}` value `{tok}` is not a number"
                    ))
                })?;
                match &p.data_type {
                    PropertyType::Scalar(ScalarType::Float | ScalarType::Double) => {
                        v.set_f(pname, x as f32);
                    }
                    _ => {
                        v.set_int(pname, x);
                    }
                }
            }
            elems.push(v);
        }
        if vertex_is_last {
            if let Some((lineno, _)) = lines.next() {
                return Err(err(format!(
                    "line {lineno}: data continues after the header's {} vertices: the header's vertex count does \
                     not match the data",
                    def.count
                )));
            }
        }
        return Ok(cloud_from(def, &elems));
    }
    Err(err("the PLY file has no `vertex` element".into()))
}

/// Writes binary little-endian PLY.
pub(super) fn write(w: &mut dyn Write, cloud: &PointCloud) -> std::io::Result<()> {
    write_with(w, cloud, Encoding::BinaryLittleEndian)
}

/// Writes PLY in the given encoding: float x,y,z, then nx,ny,nz and uchar red,green,blue when present.
pub(super) fn write_with(
    w: &mut dyn Write,
    cloud: &PointCloud,
    encoding: Encoding,
) -> std::io::Result<()> {
    let mut ply = Ply::<Vertex>::new();
    ply.header.encoding = encoding;
    ply.header.comments.push("written by depthcal".into());
    let mut def = ElementDef::new("vertex".into());
    let mut names = vec!["x", "y", "z"];
    if cloud.normals.is_some() {
        names.extend(["nx", "ny", "nz"]);
    }
    for n in &names {
        def.properties.add(PropertyDef::new(
            (*n).into(),
            PropertyType::Scalar(ScalarType::Float),
        ));
    }
    if cloud.colors.is_some() {
        for n in ["red", "green", "blue"] {
            def.properties.add(PropertyDef::new(
                n.into(),
                PropertyType::Scalar(ScalarType::UChar),
            ));
        }
    }
    def.count = cloud.len();
    ply.header.elements.add(def);
    let verts: Vec<Vertex> = (0..cloud.len())
        .map(|i| Vertex {
            p: cloud.points[i],
            n: cloud.normals.as_ref().map_or([0.0; 3], |n| n[i]),
            c: cloud.colors.as_ref().map_or([0; 3], |c| c[i]),
        })
        .collect();
    ply.payload.insert("vertex".into(), verts);
    let mut out = w;
    Writer::<Vertex>::new().write_ply_unchecked(&mut out, &ply)?;
    Ok(())
}
