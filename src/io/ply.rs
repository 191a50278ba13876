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

/// Reads a PLY file's `vertex` element.
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let parser = Parser::<Vertex>::new();
    let mut reader = Reader::new(std::io::Cursor::new(bytes));
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| Error::format(path, format!("bad PLY header: {e}")))?;
    let mut cloud = None;
    for (name, def) in &header.elements {
        if let Some(PropertyDef { name: pname, .. }) = def
            .properties
            .values()
            .find(|p| matches!(p.data_type, PropertyType::List(..)) && name == "vertex")
        {
            return Err(Error::format(
                path,
                format!("vertex property `{pname}` is a list; expected scalars"),
            ));
        }
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
            for axis in ["x", "y", "z"] {
                if !def.properties.contains_key(axis) {
                    return Err(Error::format(
                        path,
                        format!("the vertex element has no `{axis}` property"),
                    ));
                }
            }
            let has_normals = has_all(
                def,
                &[
                    &["nx", "normal_x"],
                    &["ny", "normal_y"],
                    &["nz", "normal_z"],
                ],
            );
            let has_colors = has_all(
                def,
                &[
                    &["red", "r", "diffuse_red"],
                    &["green", "g", "diffuse_green"],
                    &["blue", "b", "diffuse_blue"],
                ],
            );
            cloud = Some(PointCloud {
                points: elems.iter().map(|v| v.p).collect(),
                normals: has_normals.then(|| elems.iter().map(|v| v.n).collect()),
                colors: has_colors.then(|| elems.iter().map(|v| v.c).collect()),
            });
            // Remaining elements (faces, ...) are not needed.
            break;
        }
    }
    let cloud = cloud.ok_or_else(|| Error::format(path, "the PLY file has no `vertex` element"))?;
    if header.encoding != Encoding::Ascii {
        let consumed = reader.get_ref().position() as usize;
        let is_last = header.elements.keys().last().map(|k| k.as_str()) == Some("vertex");
        if is_last && consumed < bytes.len() {
            log::warn!(
                "{}: {} bytes after the last vertex are ignored (does the header's vertex count match the data?)",
                path.display(),
                bytes.len() - consumed
            );
        }
    }
    Ok(cloud)
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
