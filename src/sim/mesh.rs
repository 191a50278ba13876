//! Triangle meshes for the simulator: a small PLY face reader and a few built-in fiducial meshes.
//!
//! Every mesh is in metres in its own object frame. The built-in meshes are made so that they rest on the
//! plane `z = 0` of their frame and are centred on the `z` axis (their bounding box is centred in x and y).

use crate::error::{Error, Result};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use std::path::Path;

/// A triangle mesh: vertices (metres, object frame) and triangles (vertex indices).
#[derive(Clone, Debug, PartialEq)]
pub struct MeshData {
    /// Vertex positions, metres.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as indices into `vertices` (counter-clockwise seen from outside where known).
    pub triangles: Vec<[u32; 3]>,
}

/// Names of the built-in meshes accepted by [`builtin_mesh`].
pub const BUILTIN_MESHES: [&str; 4] = ["bracket", "wedge", "torus", "stairs"];

impl MeshData {
    /// The axis-aligned bounds `(min, max)` of the vertices, metres; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let first = *self.vertices.first()?;
        let mut lo = first;
        let mut hi = first;
        for v in &self.vertices {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        Some((lo, hi))
    }

    /// Scales every vertex by `s` and moves the mesh so that its bounding box is centred on the z axis with its
    /// bottom at `z = 0` (so it rests on the table when placed at table height).
    pub fn normalised(mut self, s: f64) -> Self {
        if let Some((lo, hi)) = self.bounds() {
            let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]];
            for v in &mut self.vertices {
                for k in 0..3 {
                    v[k] = (v[k] - c[k]) * s;
                }
            }
        }
        self
    }

    /// Checks that there is at least one triangle, that indices are in range and coordinates finite.
    pub fn validate(&self, what: &Path) -> Result<()> {
        if self.triangles.is_empty() {
            return Err(Error::format(what, "the mesh has no triangles (faces)"));
        }
        let n = self.vertices.len() as u32;
        if let Some((i, t)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&k| k >= n))
        {
            return Err(Error::format(
                what,
                format!("face {i} uses vertex {t:?} but there are only {n} vertices"),
            ));
        }
        if self.vertices.iter().flatten().any(|c| !c.is_finite()) {
            return Err(Error::format(
                what,
                "a vertex coordinate is NaN or infinite",
            ));
        }
        Ok(())
    }

    fn push_box(&mut self, lo: [f64; 3], hi: [f64; 3]) {
        let base = self.vertices.len() as u32;
        for i in 0..8u32 {
            self.vertices.push([
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ]);
        }
        // Faces as quads (outward, counter-clockwise).
        let quads: [[u32; 4]; 6] = [
            [0, 2, 3, 1], // z-
            [4, 5, 7, 6], // z+
            [0, 1, 5, 4], // y-
            [2, 6, 7, 3], // y+
            [0, 4, 6, 2], // x-
            [1, 3, 7, 5], // x+
        ];
        for q in quads {
            self.triangles.push([base + q[0], base + q[1], base + q[2]]);
            self.triangles.push([base + q[0], base + q[2], base + q[3]]);
        }
    }
}

/// A built-in mesh by name (see [`BUILTIN_MESHES`]), about 10 cm across before scaling:
/// `bracket` (an L-shaped angle bracket), `wedge` (a ramp: a triangular prism), `torus` (a ring lying flat)
/// and `stairs` (three steps). Boxes of a union may overlap: the hidden inner faces never show in a ray cast.
pub fn builtin_mesh(name: &str) -> Option<MeshData> {
    let mut m = MeshData {
        vertices: Vec::new(),
        triangles: Vec::new(),
    };
    match name {
        "bracket" => {
            m.push_box([-0.05, -0.03, 0.0], [0.05, 0.03, 0.012]);
            m.push_box([-0.05, -0.03, 0.0], [-0.038, 0.03, 0.08]);
        }
        "stairs" => {
            m.push_box([-0.06, -0.04, 0.0], [0.06, 0.04, 0.03]);
            m.push_box([-0.02, -0.04, 0.0], [0.06, 0.04, 0.06]);
            m.push_box([0.02, -0.04, 0.0], [0.06, 0.04, 0.09]);
        }
        "wedge" => {
            // Right-angled ramp: rises from x = -0.06 to x = +0.06, 0.07 high, 0.08 deep.
            let (x0, x1, y0, y1, h) = (-0.06, 0.06, -0.04, 0.04, 0.07);
            m.vertices = vec![
                [x0, y0, 0.0],
                [x1, y0, 0.0],
                [x1, y0, h],
                [x0, y1, 0.0],
                [x1, y1, 0.0],
                [x1, y1, h],
            ];
            m.triangles = vec![
                [0, 2, 1], // side y0
                [3, 4, 5], // side y1
                [0, 1, 4],
                [0, 4, 3], // bottom
                [1, 2, 5],
                [1, 5, 4], // back x1
                [0, 3, 5],
                [0, 5, 2], // slope
            ];
        }
        "torus" => {
            let (big, small) = (0.05, 0.017);
            let (nu, nv) = (32u32, 12u32);
            for i in 0..nu {
                let a = i as f64 / nu as f64 * std::f64::consts::TAU;
                for j in 0..nv {
                    let b = j as f64 / nv as f64 * std::f64::consts::TAU;
                    let r = big + small * b.cos();
                    m.vertices
                        .push([r * a.cos(), r * a.sin(), small + small * b.sin()]);
                }
            }
            for i in 0..nu {
                for j in 0..nv {
                    let idx = |i: u32, j: u32| (i % nu) * nv + (j % nv);
                    let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
                    m.triangles.push([a, b, c]);
                    m.triangles.push([a, c, d]);
                }
            }
        }
        _ => return None,
    }
    Some(m)
}

fn prop_f64(p: &Property) -> Option<f64> {
    Some(match p {
        Property::Float(v) => *v as f64,
        Property::Double(v) => *v,
        Property::Char(v) => *v as f64,
        Property::UChar(v) => *v as f64,
        Property::Short(v) => *v as f64,
        Property::UShort(v) => *v as f64,
        Property::Int(v) => *v as f64,
        Property::UInt(v) => *v as f64,
        _ => return None,
    })
}

fn prop_list(p: &Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListInt(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUInt(v) => v.iter().map(|&x| x as i64).collect(),
        _ => return None,
    })
}

/// Reads a triangle mesh from a PLY file (ascii or binary): the `vertex` element's `x, y, z` and the `face`
/// element's `vertex_indices` (or `vertex_index`) lists. Polygons with more than three corners are split into
/// a triangle fan. Units are the file's (the simulator scales meshes to a chosen size anyway).
pub fn read_ply_mesh(path: impl AsRef<Path>) -> Result<MeshData> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let parser = Parser::<DefaultElement>::new();
    let ply = parser
        .read_ply(&mut std::io::Cursor::new(&bytes))
        .map_err(|e| Error::format(path, format!("not a readable PLY file: {e}")))?;
    let verts = ply
        .payload
        .get("vertex")
        .ok_or_else(|| Error::format(path, "no `vertex` element"))?;
    let mut vertices = Vec::with_capacity(verts.len());
    for (i, v) in verts.iter().enumerate() {
        let mut p = [0.0; 3];
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            p[k] = v.get(*name).and_then(prop_f64).ok_or_else(|| {
                Error::format(path, format!("vertex {i}: no numeric property `{name}`"))
            })?;
        }
        vertices.push(p);
    }
    let faces = ply
        .payload
        .get("face")
        .ok_or_else(|| Error::format(path, "no `face` element: a mesh needs faces"))?;
    let mut triangles = Vec::with_capacity(faces.len());
    for (i, f) in faces.iter().enumerate() {
        let idx = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(prop_list)
            .ok_or_else(|| {
                Error::format(
                    path,
                    format!("face {i}: no integer list property `vertex_indices`"),
                )
            })?;
        if idx.len() < 3 || idx.iter().any(|&k| k < 0 || k >= vertices.len() as i64) {
            return Err(Error::format(
                path,
                format!(
                    "face {i}: bad vertex list {idx:?} ({} vertices)",
                    vertices.len()
                ),
            ));
        }
        for k in 1..idx.len() - 1 {
            triangles.push([idx[0] as u32, idx[k] as u32, idx[k + 1] as u32]);
        }
    }
    let m = MeshData {
        vertices,
        triangles,
    };
    m.validate(path)?;
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_rest_on_z0_and_ply_faces_read() {
        for name in BUILTIN_MESHES {
            let m = builtin_mesh(name).unwrap();
            m.validate(Path::new(name)).unwrap();
            let (lo, _) = m.bounds().unwrap();
            assert!(lo[2].abs() < 1e-12, "{name}");
        }
        let dir = std::env::temp_dir().join(format!("depthcal-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("quad.ply");
        std::fs::write(
            &p,
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n\
             0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n",
        )
        .unwrap();
        let m = read_ply_mesh(&p).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        std::fs::write(
            &p,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n\
             end_header\n0 0 0\n",
        )
        .unwrap();
        let e = read_ply_mesh(&p).unwrap_err().to_string();
        assert!(e.contains("quad.ply") && e.contains("face"), "{e}");
        let _ = std::fs::remove_dir_all(dir);
    }
}
