//! PCL's PCD format: `DATA ascii`, `binary` and `binary_compressed` (LZF), any numeric field types; reads
//! x,y,z, optional normal_x/y/z and rgb/rgba.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::path::Path;

#[derive(Clone, Debug)]
struct Field {
    name: String,
    size: usize,
    kind: u8, // b'F', b'I', b'U'
    count: usize,
    offset: usize, // byte offset inside a binary record
}

impl Field {
    fn read(&self, b: &[u8]) -> f64 {
        match (self.kind, self.size) {
            (b'F', 4) => f32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            (b'F', 8) => f64::from_le_bytes(b[..8].try_into().unwrap()),
            (b'I', 1) => b[0] as i8 as f64,
            (b'I', 2) => i16::from_le_bytes(b[..2].try_into().unwrap()) as f64,
            (b'I', 4) => i32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            (b'I', 8) => i64::from_le_bytes(b[..8].try_into().unwrap()) as f64,
            (b'U', 1) => b[0] as f64,
            (b'U', 2) => u16::from_le_bytes(b[..2].try_into().unwrap()) as f64,
            (b'U', 4) => u32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
            (b'U', 8) => u64::from_le_bytes(b[..8].try_into().unwrap()) as f64,
            _ => f64::NAN,
        }
    }
    fn bytes(&self) -> usize {
        self.size * self.count
    }
}

fn rgb_from_bits(bits: u32) -> [u8; 3] {
    [(bits >> 16) as u8, (bits >> 8) as u8, bits as u8]
}

/// The most an LZF stream can expand: a 3-byte back-reference yields at most 264 bytes.
const LZF_MAX_RATIO: usize = 88;

/// Decompresses LZF (as used by PCL's binary_compressed).
fn lzf_decompress(input: &[u8], out_len: usize) -> std::result::Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(out_len.min(input.len().saturating_mul(LZF_MAX_RATIO)));
    let mut i = 0;
    while i < input.len() {
        let ctrl = input[i] as usize;
        i += 1;
        if ctrl < 32 {
            let n = ctrl + 1;
            if i + n > input.len() {
                return Err("compressed data ends inside a literal run".into());
            }
            out.extend_from_slice(&input[i..i + n]);
            i += n;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                len += *input.get(i).ok_or("compressed data truncated")? as usize;
                i += 1;
            }
            let back = ((ctrl & 0x1f) << 8)
                + *input.get(i).ok_or("compressed data truncated")? as usize
                + 1;
            i += 1;
            if back > out.len() {
                return Err("compressed data refers before its start".into());
            }
            let start = out.len() - back;
            for k in 0..len + 2 {
                let b = out[start + k];
                out.push(b);
            }
        }
        if out.len() > out_len {
            return Err("compressed data is longer than its header says".into());
        }
    }
    if out.len() != out_len {
        return Err(format!(
            "decompressed {} bytes, header says {out_len}",
            out.len()
        ));
    }
    Ok(out)
}

/// Reads a PCD file.
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let err = |msg: String| Error::format(path, msg);
    let mut pos = 0;
    let mut fields: Vec<Field> = Vec::new();
    let (mut sizes, mut types, mut counts) = (Vec::new(), Vec::new(), Vec::new());
    let mut npoints: Option<usize> = None;
    let (mut width, mut height) = (None, None);
    let data_kind;
    let mut lineno = 0;
    loop {
        if pos >= bytes.len() {
            return Err(err("header has no DATA line".into()));
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |k| pos + k);
        let line = std::str::from_utf8(&bytes[pos..end])
            .map_err(|_| err(format!("header line {} is not text", lineno + 1)))?
            .trim()
            .to_string();
        pos = (end + 1).min(bytes.len());
        lineno += 1;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut toks = line.split_whitespace();
        let key = toks.next().unwrap_or("").to_ascii_uppercase();
        let rest: Vec<&str> = toks.collect();
        let parse_usize = |s: &str, what: &str| {
            s.parse::<usize>()
                .map_err(|_| err(format!("line {lineno}: {what} `{s}` is not a count")))
        };
        match key.as_str() {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => {
                fields = rest
                    .iter()
                    .map(|n| Field {
                        name: n.to_string(),
                        size: 4,
                        kind: b'F',
                        count: 1,
                        offset: 0,
                    })
                    .collect()
            }
            "SIZE" => {
                sizes = rest
                    .iter()
                    .map(|s| parse_usize(s, "SIZE"))
                    .collect::<Result<_>>()?
            }
            "TYPE" => types = rest.iter().map(|s| s.as_bytes()[0]).collect(),
            "COUNT" => {
                counts = rest
                    .iter()
                    .map(|s| parse_usize(s, "COUNT"))
                    .collect::<Result<_>>()?
            }
            "WIDTH" => width = Some(parse_usize(rest.first().unwrap_or(&""), "WIDTH")?),
            "HEIGHT" => height = Some(parse_usize(rest.first().unwrap_or(&""), "HEIGHT")?),
            "POINTS" => npoints = Some(parse_usize(rest.first().unwrap_or(&""), "POINTS")?),
            "DATA" => {
                data_kind = rest.first().unwrap_or(&"").to_ascii_lowercase();
                break;
            }
            other => return Err(err(format!("line {lineno}: unknown header key `{other}`"))),
        }
    }
    if fields.is_empty() {
        return Err(err("header has no FIELDS line".into()));
    }
    let nf = fields.len();
    if !sizes.is_empty() && sizes.len() != nf
        || !types.is_empty() && types.len() != nf
        || !counts.is_empty() && counts.len() != nf
    {
        return Err(err(format!(
            "FIELDS names {nf} fields but SIZE/TYPE/COUNT give {}/{}/{}",
            sizes.len(),
            types.len(),
            counts.len()
        )));
    }
    let mut offset = 0usize;
    for (k, f) in fields.iter_mut().enumerate() {
        f.size = *sizes.get(k).unwrap_or(&4);
        f.kind = *types.get(k).unwrap_or(&b'F');
        f.count = *counts.get(k).unwrap_or(&1);
        if !matches!(
            (f.kind, f.size),
            (b'F', 4 | 8) | (b'I' | b'U', 1 | 2 | 4 | 8)
        ) {
            return Err(err(format!(
                "field `{}` has unsupported TYPE {} SIZE {}",
                f.name, f.kind as char, f.size
            )));
        }
        if f.count == 0 {
            return Err(err(format!(
                "field `{}` has COUNT 0; every field needs COUNT of at least 1",
                f.name
            )));
        }
        if matches!(f.name.as_str(), "rgb" | "rgba") && f.size != 4 {
            return Err(err(format!(
                "field `{}` has SIZE {}; a packed rgb/rgba field must have SIZE 4",
                f.name, f.size
            )));
        }
        f.offset = offset;
        offset = f
            .size
            .checked_mul(f.count)
            .and_then(|b| offset.checked_add(b))
            .ok_or_else(|| {
                err(format!(
                    "field `{}`: SIZE {} x COUNT {} overflows the record size",
                    f.name, f.size, f.count
                ))
            })?;
    }
    let record = offset;
    let n = match (npoints, width) {
        (Some(n), _) => n,
        (None, Some(w)) => w.checked_mul(height.unwrap_or(1)).ok_or_else(|| {
            err(format!(
                "WIDTH {w} x HEIGHT {} overflows the point count",
                height.unwrap_or(1)
            ))
        })?,
        (None, None) => return Err(err("header has neither POINTS nor WIDTH".into())),
    };
    let find = |names: &[&str]| fields.iter().position(|f| names.contains(&f.name.as_str()));
    let ix = [find(&["x"]), find(&["y"]), find(&["z"])];
    let [Some(fx), Some(fy), Some(fz)] = ix else {
        return Err(err("FIELDS must include x, y and z".into()));
    };
    let fnorm = [
        find(&["normal_x", "nx"]),
        find(&["normal_y", "ny"]),
        find(&["normal_z", "nz"]),
    ];
    let has_normals = fnorm.iter().all(|f| f.is_some());
    let frgb = find(&["rgb", "rgba"]);
    let data_len = bytes.len() - pos;
    // Values per point in the file (a field of COUNT k has k of them); each needs at least one character and a
    // separator in ASCII, and every size below is checked against the data's length before anything is
    // allocated, so a header claiming more points than the file can hold is an error, not an allocation.
    let per_point = fields
        .iter()
        .try_fold(0usize, |a, f| a.checked_add(f.count))
        .ok_or_else(|| err("the COUNTs overflow".into()))?;
    let too_many = |need: Option<usize>, what: &str| {
        err(format!(
            "header says {n} points ({}), but the file has only {data_len} bytes of data",
            match need {
                Some(b) => format!("at least {b} bytes of {what}"),
                None => format!("more bytes of {what} than can be counted"),
            }
        ))
    };

    // A row-major table of values: rows = points, columns = fields (first element of each).
    let mut values: Vec<f64>;
    let mut rgb_bits: Vec<u32> = Vec::new();
    match data_kind.as_str() {
        "ascii" => {
            let need = n.checked_mul(per_point).and_then(|v| v.checked_mul(2));
            if need.is_none_or(|b| b > data_len + 1) {
                return Err(too_many(need.map(|b| b.saturating_sub(1)), "ASCII data"));
            }
            values = Vec::with_capacity(n * nf);
            let text = std::str::from_utf8(&bytes[pos..])
                .map_err(|_| err("ASCII data is not text".into()))?;
            let mut row = 0;
            for (k, line) in text.lines().enumerate() {
                let line = line.trim();
                if line.is_empty() {
                    continue;
                }
                if row >= n {
                    return Err(err(format!(
                        "data line {}: more points than the header's {n}",
                        k + 1
                    )));
                }
                let toks: Vec<&str> = line.split_whitespace().collect();
                let mut t = 0;
                for (j, f) in fields.iter().enumerate() {
                    let tok = toks.get(t).ok_or_else(|| {
                        err(format!(
                            "data line {} (point {row}): missing field `{}`",
                            k + 1,
                            f.name
                        ))
                    })?;
                    let v: f64 = if tok.eq_ignore_ascii_case("nan") {
                        f64::NAN
                    } else {
                        tok.parse().map_err(|_| {
                            err(format!(
                                "data line {} (point {row}): field `{}` value `{tok}` is not a number",
                                k + 1,
                                f.name
                            ))
                        })?
                    };
                    values.push(v);
                    if Some(j) == frgb {
                        rgb_bits.push(if f.kind == b'F' {
                            (v as f32).to_bits()
                        } else {
                            v as u32
                        });
                    }
                    t += f.count;
                }
                row += 1;
            }
            if row != n {
                return Err(err(format!("header says {n} points, the data has {row}")));
            }
        }
        "binary" | "binary_compressed" => {
            let need = n.checked_mul(record);
            let data: std::borrow::Cow<[u8]> = if data_kind == "binary" {
                let need = match need {
                    Some(b) if b <= data_len => b,
                    _ => {
                        return Err(err(format!(
                            "binary data is truncated: header says {n} points ({} bytes), file has {data_len} bytes",
                            need.map_or("too many".to_string(), |b| b.to_string())
                        )))
                    }
                };
                std::borrow::Cow::Borrowed(&bytes[pos..pos + need])
            } else {
                if data_len < 8 {
                    return Err(err("binary_compressed data is truncated".into()));
                }
                let csize = u32::from_le_bytes(bytes[pos..pos + 4].try_into().unwrap()) as usize;
                let usize_ =
                    u32::from_le_bytes(bytes[pos + 4..pos + 8].try_into().unwrap()) as usize;
                if need != Some(usize_) {
                    return Err(err(format!(
                        "binary_compressed: uncompressed size {usize_} does not match {n} points of {record} bytes"
                    )));
                }
                if csize > data_len - 8 {
                    return Err(err(format!(
                        "binary_compressed data is truncated: the compressed size says {csize} bytes, the file has {} after it",
                        data_len - 8
                    )));
                }
                if usize_ > csize.saturating_mul(LZF_MAX_RATIO) {
                    return Err(err(format!(
                        "binary_compressed: uncompressed size {usize_} is impossible from {csize} bytes of LZF data \
                         (at most {LZF_MAX_RATIO} times larger)"
                    )));
                }
                let src = &bytes[pos + 8..pos + 8 + csize];
                let soa = lzf_decompress(src, usize_)
                    .map_err(|m| err(format!("binary_compressed: {m}")))?;
                // Convert the field-major layout into point-major records.
                let mut aos = vec![0u8; usize_];
                let mut base = 0;
                for f in &fields {
                    let fb = f.bytes();
                    for i in 0..n {
                        aos[i * record + f.offset..i * record + f.offset + fb]
                            .copy_from_slice(&soa[base + i * fb..base + (i + 1) * fb]);
                    }
                    base += fb * n;
                }
                std::borrow::Cow::Owned(aos)
            };
            // n * record <= data length and record >= nf, so this fits.
            values = vec![0f64; n * nf];
            if frgb.is_some() {
                rgb_bits = vec![0u32; n];
            }
            for i in 0..n {
                let rec = &data[i * record..(i + 1) * record];
                for (j, f) in fields.iter().enumerate() {
                    let b = &rec[f.offset..];
                    values[i * nf + j] = f.read(b);
                    if Some(j) == frgb {
                        rgb_bits[i] = u32::from_le_bytes(b[..4].try_into().unwrap());
                    }
                }
            }
        }
        other => {
            return Err(err(format!(
                "DATA `{other}` is not supported (ascii, binary, binary_compressed)"
            )))
        }
    }
    let get = |i: usize, j: usize| values[i * nf + j] as f32;
    Ok(PointCloud {
        points: (0..n)
            .map(|i| [get(i, fx), get(i, fy), get(i, fz)])
            .collect(),
        normals: has_normals.then(|| {
            let [a, b, c] = fnorm.map(|f| f.unwrap());
            (0..n).map(|i| [get(i, a), get(i, b), get(i, c)]).collect()
        }),
        colors: frgb.map(|_| rgb_bits.iter().map(|&b| rgb_from_bits(b)).collect()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lzf_literal_and_backref() {
        // literal "abc" (ctrl 2), then back-reference of length 3 (ctrl (1<<5)|0, offset 2 → back 3).
        let data = [2u8, b'a', b'b', b'c', 1 << 5, 2];
        assert_eq!(lzf_decompress(&data, 6).unwrap(), b"abcabc");
        assert!(lzf_decompress(&data, 5).is_err());
    }

    #[test]
    fn ascii_and_binary_agree() {
        let ascii = b"VERSION .7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 16711680\n4 5 6 255\n";
        let c = read(Path::new("a.pcd"), ascii).unwrap();
        assert_eq!(c.points, vec![[1., 2., 3.], [4., 5., 6.]]);
        assert_eq!(c.colors.as_ref().unwrap()[0], [255, 0, 0]);
        let mut bin =
            b"FIELDS x y z\nSIZE 4 4 8\nTYPE F F F\nWIDTH 2\nPOINTS 2\nDATA binary\n".to_vec();
        for p in [[1f32, 2., 3.], [4., 5., 6.]] {
            bin.extend(p[0].to_le_bytes());
            bin.extend(p[1].to_le_bytes());
            bin.extend((p[2] as f64).to_le_bytes());
        }
        let b = read(Path::new("b.pcd"), &bin).unwrap();
        assert_eq!(b.points, c.points);
        bin.truncate(bin.len() - 3);
        let e = read(Path::new("b.pcd"), &bin).unwrap_err().to_string();
        assert!(e.contains("b.pcd") && e.contains("truncated"), "{e}");
    }
}
