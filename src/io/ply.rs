//! PLY through `ply-rs-bw`: ascii and binary (both endians), float or double x,y,z, optional normals and
//! colours; other properties and elements are ignored.
//!
//! `ply-rs-bw` parses every header. The binary payload of a file whose `vertex` element and the elements
//! before it hold scalars only (what depthcal, Open3D, PCL and the RealSense SDK write) is decoded here,
//! straight from the bytes: `ply-rs-bw` hands each value to a per-property callback by name. Reading a 6 MB
//! binary PLY of 250 000 points with normals (`read_cloud`, the file in the page cache) took 22.2 ms through
//! it and takes 3.4 ms decoded here; 7.6 ms and 1.5 ms without normals (`cargo bench --bench io`, 2 cores).
//! Every other file (lists before the vertices, ASCII) goes through `ply-rs-bw` as before, and the tests
//! hold the two decodings to the same clouds, bit for bit, on random layouts.

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

/// Whether the vertex element has all three normal components, and all three colour channels.
fn attributes(def: &ElementDef) -> (bool, bool) {
    let normals = has_all(
        def,
        &[
            &["nx", "normal_x"],
            &["ny", "normal_y"],
            &["nz", "normal_z"],
        ],
    );
    (normals, has_all(def, &colour_names()))
}

fn cloud_from(def: &ElementDef, elems: &[Vertex]) -> PointCloud {
    let (has_normals, has_colors) = attributes(def);
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
    read_with(path, bytes, true)
}

/// [`read`], with the binary payload of scalar-only elements decoded here (`direct`, [`read_binary_scalars`])
/// or always by `ply-rs` (the reference the direct decoding is tested against).
fn read_with(path: &Path, bytes: &[u8], direct: bool) -> Result<PointCloud> {
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
    if direct {
        if let Some(cloud) = read_binary_scalars(
            path,
            bytes,
            body,
            &header.elements,
            header.encoding,
            is_last,
        )? {
            return Ok(cloud);
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
    if is_last {
        no_trailing_data(path, bytes, consumed, cloud.len())?;
    }
    Ok(cloud)
}

/// The binary payload ends with the last of the header's `vertices` (at `consumed`) when `vertex` is the
/// last element: data after it means the header's count is wrong.
fn no_trailing_data(path: &Path, bytes: &[u8], consumed: usize, vertices: usize) -> Result<()> {
    if consumed < bytes.len() {
        return Err(Error::format(
            path,
            format!(
                "{} bytes of data follow the last of the header's {vertices} vertices: the header's vertex count \
                 does not match the data",
                bytes.len() - consumed
            ),
        ));
    }
    Ok(())
}

/// Where one scalar vertex property goes: the same meaning as [`Vertex::set_f`] (float and double
/// properties) and [`Vertex::set_int`] (integer ones), settled once per file instead of once per value.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    Point(usize),
    Normal(usize),
    /// A colour channel from a float in 0-1.
    ColourFloat(usize),
    /// A colour channel from an integer in 0-255.
    ColourInt(usize),
    Ignored,
}

impl Slot {
    fn of(name: &str, t: &ScalarType) -> Slot {
        let colour = colour_names().iter().position(|alts| alts.contains(&name));
        let float = matches!(t, ScalarType::Float | ScalarType::Double);
        match (name, colour) {
            (_, Some(k)) if float => Slot::ColourFloat(k),
            (_, Some(k)) => Slot::ColourInt(k),
            ("x", _) => Slot::Point(0),
            ("y", _) => Slot::Point(1),
            ("z", _) => Slot::Point(2),
            ("nx" | "normal_x", _) => Slot::Normal(0),
            ("ny" | "normal_y", _) => Slot::Normal(1),
            ("nz" | "normal_z", _) => Slot::Normal(2),
            _ => Slot::Ignored,
        }
    }
}

/// One scalar of `t` at the start of `b` in the file's byte order, as `f64` (exact for every PLY scalar
/// type).
#[inline]
fn scalar(b: &[u8], t: &ScalarType, big: bool) -> f64 {
    macro_rules! num {
        ($ty:ty, $n:expr) => {{
            let a: [u8; $n] = b[..$n].try_into().expect("the entry holds the scalar");
            (if big {
                <$ty>::from_be_bytes(a)
            } else {
                <$ty>::from_le_bytes(a)
            }) as f64
        }};
    }
    match t {
        ScalarType::Char => b[0] as i8 as f64,
        ScalarType::UChar => b[0] as f64,
        ScalarType::Short => num!(i16, 2),
        ScalarType::UShort => num!(u16, 2),
        ScalarType::Int => num!(i32, 4),
        ScalarType::UInt => num!(u32, 4),
        ScalarType::Float => num!(f32, 4),
        ScalarType::Double => num!(f64, 8),
    }
}

/// The binary payload's `vertex` element read straight from the bytes when it and every element before it
/// hold scalars only (fixed-size entries: the common case, read at memory speed); `None` otherwise, for
/// `ply-rs` to read. The values mean what they mean through `ply-rs` ([`Slot`]). The header's counts were
/// checked against the data's length before.
fn read_binary_scalars(
    path: &Path,
    bytes: &[u8],
    body: usize,
    elements: &ply_rs_bw::ply::KeyMap<ElementDef>,
    encoding: Encoding,
    vertex_is_last: bool,
) -> Result<Option<PointCloud>> {
    let big = match encoding {
        Encoding::BinaryLittleEndian => false,
        Encoding::BinaryBigEndian => true,
        Encoding::Ascii => return Ok(None),
    };
    let scalars = |def: &ElementDef| {
        def.properties
            .values()
            .all(|p| matches!(p.data_type, PropertyType::Scalar(_)))
    };
    let mut at = body;
    for (name, def) in elements {
        if !scalars(def) {
            return Ok(None);
        }
        let size = min_entry_bytes(def);
        let Some(len) = def.count.checked_mul(size) else {
            return Ok(None);
        };
        if name != "vertex" {
            at = at.saturating_add(len);
            continue;
        }
        let Some(data) = bytes.get(at..).and_then(|d| d.get(..len)) else {
            return Ok(None);
        };
        let props: Vec<(usize, ScalarType, Slot)> = def
            .properties
            .values()
            .scan(0usize, |off, p| {
                let PropertyType::Scalar(t) = &p.data_type else {
                    return None;
                };
                let here = *off;
                *off += scalar_size(t);
                Some((here, t.clone(), Slot::of(&p.name, t)))
            })
            .collect();
        let (has_normals, has_colors) = attributes(def);
        let n = def.count;
        let mut points = Vec::with_capacity(n);
        let mut normals = Vec::with_capacity(if has_normals { n } else { 0 });
        let mut colors = Vec::with_capacity(if has_colors { n } else { 0 });
        // The common layout, float coordinates and normals and no colours, in one tight loop (the last
        // property of a slot wins, as in the general loop below).
        let float_at = |slot: Slot| -> Option<Option<usize>> {
            let mut at = None;
            for (off, t, s) in &props {
                if *s == slot {
                    if *t != ScalarType::Float {
                        return None;
                    }
                    at = Some(*off);
                }
            }
            Some(at)
        };
        let xyz: Option<Vec<usize>> = (0..3).map(|k| float_at(Slot::Point(k)).flatten()).collect();
        let nxyz: Option<Vec<Option<usize>>> = (0..3).map(|k| float_at(Slot::Normal(k))).collect();
        let common = matches!((&xyz, &nxyz, has_colors), (Some(_), Some(_), false));
        if let (Some(xyz), Some(nxyz), false) = (xyz, nxyz, has_colors) {
            let f = |e: &[u8], off: usize| -> f32 {
                let a: [u8; 4] = e[off..off + 4]
                    .try_into()
                    .expect("the entry holds the float");
                if big {
                    f32::from_be_bytes(a)
                } else {
                    f32::from_le_bytes(a)
                }
            };
            let entries = data.chunks_exact(size);
            points.extend(
                entries
                    .clone()
                    .map(|e| [f(e, xyz[0]), f(e, xyz[1]), f(e, xyz[2])]),
            );
            if has_normals {
                let o: Vec<usize> = nxyz.iter().map(|o| o.expect("has_normals")).collect();
                normals.extend(entries.map(|e| [f(e, o[0]), f(e, o[1]), f(e, o[2])]));
            }
        }
        for entry in data.chunks_exact(size).take(if common { 0 } else { n }) {
            let mut v = Vertex::default();
            for (off, t, slot) in &props {
                let x = scalar(&entry[*off..], t, big);
                match *slot {
                    Slot::Point(k) => v.p[k] = x as f32,
                    Slot::Normal(k) => v.n[k] = x as f32,
                    Slot::ColourFloat(k) => {
                        v.c[k] = ((x as f32).clamp(0.0, 1.0) * 255.0).round() as u8
                    }
                    Slot::ColourInt(k) => v.c[k] = x.clamp(0.0, 255.0) as u8,
                    Slot::Ignored => {}
                }
            }
            points.push(v.p);
            if has_normals {
                normals.push(v.n);
            }
            if has_colors {
                colors.push(v.c);
            }
        }
        if vertex_is_last {
            no_trailing_data(path, bytes, at + len, n)?;
        }
        return Ok(Some(PointCloud {
            points,
            normals: has_normals.then_some(normals),
            colors: has_colors.then_some(colors),
        }));
    }
    Ok(None)
}

/// The ASCII payload, read here rather than by `ply-rs`/// The ASCII payload, read here rather than by `ply-rs` so that `nan`/`inf` are numbers and errors name the
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A scalar's bytes in the file's order.
    fn put(out: &mut Vec<u8>, t: &str, v: f64, big: bool) {
        macro_rules! b {
            ($x:expr) => {
                if big {
                    out.extend_from_slice(&$x.to_be_bytes())
                } else {
                    out.extend_from_slice(&$x.to_le_bytes())
                }
            };
        }
        match t {
            "char" => b!(v as i8),
            "uchar" => b!(v as u8),
            "short" => b!(v as i16),
            "ushort" => b!(v as u16),
            "int" => b!(v as i32),
            "uint" => b!(v as u32),
            "float" => b!(v as f32),
            _ => b!(v),
        }
    }

    /// A small deterministic generator (xorshift).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn pick<'a, T>(&mut self, v: &'a [T]) -> &'a T {
            &v[(self.next() % v.len() as u64) as usize]
        }
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn same(a: &PointCloud, b: &PointCloud) -> bool {
        let bits =
            |p: &[[f32; 3]]| -> Vec<u32> { p.iter().flatten().map(|v| v.to_bits()).collect() };
        bits(&a.points) == bits(&b.points)
            && a.normals.as_deref().map(bits) == b.normals.as_deref().map(bits)
            && a.colors == b.colors
    }

    #[test]
    fn direct_decoding_reads_what_ply_rs_reads_on_random_layouts() {
        let types = [
            "char", "uchar", "short", "ushort", "int", "uint", "float", "double",
        ];
        let names = [
            "x",
            "y",
            "z",
            "nx",
            "ny",
            "nz",
            "normal_x",
            "red",
            "green",
            "blue",
            "r",
            "diffuse_blue",
            "alpha",
            "intensity",
            "curvature",
        ];
        let path = Path::new("random.ply");
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut direct_used = 0;
        for case in 0..300 {
            let big = rng.next().is_multiple_of(2);
            // x, y, z (float or double, sometimes an integer), then a random selection of the others.
            let mut props: Vec<(String, &str)> = ["x", "y", "z"]
                .iter()
                .map(|n| {
                    (
                        n.to_string(),
                        *rng.pick(&["float", "float", "double", "int", "short"]),
                    )
                })
                .collect();
            for _ in 0..rng.next() % 6 {
                let n = rng.pick(&names[3..]).to_string();
                if !props.iter().any(|(m, _)| *m == n) {
                    props.push((n, *rng.pick(&types)));
                }
            }
            let k = (rng.next() % props.len() as u64) as usize;
            let last = props.len() - 1;
            props.swap(k, last);
            // Sometimes an element before the vertices (scalars, or a list: then ply-rs reads all), and
            // sometimes one after them.
            let before = rng.next() % 3;
            let after = rng.next().is_multiple_of(2);
            let count = (rng.next() % 40) as usize;
            let mut head = format!(
                "ply\nformat {} 1.0\n",
                if big {
                    "binary_big_endian"
                } else {
                    "binary_little_endian"
                }
            );
            let mut data = Vec::new();
            match before {
                1 => {
                    head.push_str("element camera 2\nproperty float f\nproperty uchar u\n");
                    for _ in 0..2 {
                        put(&mut data, "float", 1.5, big);
                        put(&mut data, "uchar", 7.0, big);
                    }
                }
                2 => {
                    head.push_str("element tag 1\nproperty list uchar int ids\n");
                    put(&mut data, "uchar", 2.0, big);
                    put(&mut data, "int", 3.0, big);
                    put(&mut data, "int", 4.0, big);
                }
                _ => {}
            }
            head.push_str(&format!("element vertex {count}\n"));
            for (n, t) in &props {
                head.push_str(&format!("property {t} {n}\n"));
            }
            if after {
                head.push_str("element face 1\nproperty list uchar int vertex_indices\n");
            }
            head.push_str("end_header\n");
            for _ in 0..count {
                for (n, t) in &props {
                    let v = match *t {
                        "float" | "double" if n.len() > 1 && rng.next().is_multiple_of(8) => {
                            f64::NAN
                        }
                        "float" | "double" => rng.unit() * 4.0 - 1.5,
                        "char" | "short" | "int" => (rng.next() % 300) as f64 - 150.0,
                        _ => (rng.next() % 300) as f64,
                    };
                    put(&mut data, t, v, big);
                }
            }
            if after {
                put(&mut data, "uchar", 1.0, big);
                put(&mut data, "int", 0.0, big);
            }
            let mut bytes = head.into_bytes();
            bytes.extend_from_slice(&data);
            let a = read_with(path, &bytes, true).unwrap_or_else(|e| panic!("case {case}: {e}"));
            let b = read_with(path, &bytes, false).unwrap_or_else(|e| panic!("case {case}: {e}"));
            assert!(same(&a, &b), "case {case}: the decodings differ");
            assert_eq!(a.len(), count);
            if before != 2 {
                direct_used += 1;
            }
            // One byte short, or one too many with the vertices last: both decodings refuse.
            if count > 0 && !after {
                let short = &bytes[..bytes.len() - 1];
                assert!(
                    read_with(path, short, true).is_err() && read_with(path, short, false).is_err()
                );
                let mut long = bytes.clone();
                long.push(0);
                let (x, y) = (read_with(path, &long, true), read_with(path, &long, false));
                assert!(x.is_err() && y.is_err(), "case {case}: {x:?} {y:?}");
            }
        }
        assert!(direct_used > 150, "{direct_used}");
    }

    #[test]
    fn clouds_read_back_as_written_in_both_byte_orders() {
        let path = Path::new("written.ply");
        let points: Vec<[f32; 3]> = (0..500)
            .map(|i| [i as f32 * 0.01, -(i as f32) * 0.002, f32::NAN.min(i as f32)])
            .collect();
        let normals: Vec<[f32; 3]> = (0..500).map(|i| [0.0, (i as f32).sin(), 1.0]).collect();
        let colors: Vec<[u8; 3]> = (0..500).map(|i| [i as u8, 7, 255]).collect();
        for (n, c) in [(false, false), (true, false), (true, true), (false, true)] {
            let cloud = PointCloud {
                points: points.clone(),
                normals: n.then(|| normals.clone()),
                colors: c.then(|| colors.clone()),
            };
            for enc in [Encoding::BinaryLittleEndian, Encoding::BinaryBigEndian] {
                let mut buf = Vec::new();
                write_with(&mut buf, &cloud, enc).unwrap();
                let a = read_with(path, &buf, true).unwrap();
                assert!(same(&a, &cloud), "normals {n}, colours {c}, {enc:?}");
                assert!(same(&a, &read_with(path, &buf, false).unwrap()));
            }
        }
    }
}
