//! PCL's PCD format: `DATA ascii`, `binary` and `binary_compressed` (LZF), any numeric field types; reads
//! x,y,z, optional normal_x/y/z and rgb/rgba.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::borrow::Cow;
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

/// What the header's key lines say, before they are checked against each other.
#[derive(Default)]
struct RawHeader {
    names: Vec<String>,
    sizes: Vec<usize>,
    types: Vec<u8>,
    counts: Vec<usize>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
    /// The `DATA` kind, lower case (`ascii`, `binary`, `binary_compressed`).
    data_kind: String,
    /// Byte offset of the first byte after the `DATA` line.
    data_start: usize,
}

/// A checked header: the fields with their byte layout in a binary record, and the point count.
struct Header {
    fields: Vec<Field>,
    /// Bytes per point in a binary record.
    record: usize,
    /// Points in the file.
    n: usize,
    data_kind: String,
    data_start: usize,
}

/// The values of every point, row-major (rows = points, columns = fields, first element of each), and the
/// raw bits of the packed rgb field when there is one.
struct Table {
    values: Vec<f64>,
    rgb_bits: Vec<u32>,
}

/// Reads a PCD file: the header's lines, their layout, the data in its encoding, then the cloud.
pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let err = |msg: String| Error::format(path, msg);
    let header = layout(scan_header(bytes, &err)?, &err)?;
    let find = |names: &[&str]| {
        header
            .fields
            .iter()
            .position(|f| names.contains(&f.name.as_str()))
    };
    let [Some(fx), Some(fy), Some(fz)] = [find(&["x"]), find(&["y"]), find(&["z"])] else {
        return Err(err("FIELDS must include x, y and z".into()));
    };
    let fnorm = [
        find(&["normal_x", "nx"]),
        find(&["normal_y", "ny"]),
        find(&["normal_z", "nz"]),
    ];
    let frgb = find(&["rgb", "rgba"]);
    let table = match header.data_kind.as_str() {
        "ascii" => read_ascii(&header, bytes, frgb, &err)?,
        "binary" | "binary_compressed" => {
            let data = binary_records(&header, bytes, &err)?;
            return Ok(cloud_from_records(
                &header,
                &data,
                [fx, fy, fz],
                fnorm,
                frgb,
            ));
        }
        other => {
            return Err(err(format!(
                "DATA `{other}` is not supported (ascii, binary, binary_compressed)"
            )))
        }
    };
    let (n, nf) = (header.n, header.fields.len());
    let get = |i: usize, j: usize| table.values[i * nf + j] as f32;
    let normals = match fnorm {
        [Some(a), Some(b), Some(c)] => {
            Some((0..n).map(|i| [get(i, a), get(i, b), get(i, c)]).collect())
        }
        _ => None,
    };
    Ok(PointCloud {
        points: (0..n)
            .map(|i| [get(i, fx), get(i, fy), get(i, fz)])
            .collect(),
        normals,
        colors: frgb.map(|_| table.rgb_bits.iter().map(|&b| rgb_from_bits(b)).collect()),
    })
}

/// Reads the header's lines up to and including `DATA`.
fn scan_header(bytes: &[u8], err: &impl Fn(String) -> Error) -> Result<RawHeader> {
    let mut raw = RawHeader::default();
    let mut pos = 0;
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
        let first = rest.first().copied().unwrap_or("");
        match key.as_str() {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => raw.names = rest.iter().map(|n| n.to_string()).collect(),
            "SIZE" => {
                raw.sizes = rest
                    .iter()
                    .map(|s| parse_usize(s, "SIZE"))
                    .collect::<Result<_>>()?
            }
            "TYPE" => raw.types = rest.iter().map(|s| s.as_bytes()[0]).collect(),
            "COUNT" => {
                raw.counts = rest
                    .iter()
                    .map(|s| parse_usize(s, "COUNT"))
                    .collect::<Result<_>>()?
            }
            "WIDTH" => raw.width = Some(parse_usize(first, "WIDTH")?),
            "HEIGHT" => raw.height = Some(parse_usize(first, "HEIGHT")?),
            "POINTS" => raw.points = Some(parse_usize(first, "POINTS")?),
            "DATA" => {
                raw.data_kind = first.to_ascii_lowercase();
                raw.data_start = pos;
                return Ok(raw);
            }
            other => return Err(err(format!("line {lineno}: unknown header key `{other}`"))),
        }
    }
}

/// Checks the header's lines against each other and lays the fields out in a binary record.
fn layout(raw: RawHeader, err: &impl Fn(String) -> Error) -> Result<Header> {
    if raw.names.is_empty() {
        return Err(err("header has no FIELDS line".into()));
    }
    let nf = raw.names.len();
    if !raw.sizes.is_empty() && raw.sizes.len() != nf
        || !raw.types.is_empty() && raw.types.len() != nf
        || !raw.counts.is_empty() && raw.counts.len() != nf
    {
        return Err(err(format!(
            "FIELDS names {nf} fields but SIZE/TYPE/COUNT give {}/{}/{}",
            raw.sizes.len(),
            raw.types.len(),
            raw.counts.len()
        )));
    }
    let mut fields = Vec::with_capacity(nf);
    let mut offset = 0usize;
    for (k, name) in raw.names.into_iter().enumerate() {
        let f = Field {
            name,
            size: *raw.sizes.get(k).unwrap_or(&4),
            kind: *raw.types.get(k).unwrap_or(&b'F'),
            count: *raw.counts.get(k).unwrap_or(&1),
            offset,
        };
        check_field(&f, err)?;
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
        fields.push(f);
    }
    let n = match (raw.points, raw.width) {
        (Some(n), _) => n,
        (None, Some(w)) => w.checked_mul(raw.height.unwrap_or(1)).ok_or_else(|| {
            err(format!(
                "WIDTH {w} x HEIGHT {} overflows the point count",
                raw.height.unwrap_or(1)
            ))
        })?,
        (None, None) => return Err(err("header has neither POINTS nor WIDTH".into())),
    };
    Ok(Header {
        fields,
        record: offset,
        n,
        data_kind: raw.data_kind,
        data_start: raw.data_start,
    })
}

/// A field's type, size and count must be ones depthcal reads.
fn check_field(f: &Field, err: &impl Fn(String) -> Error) -> Result<()> {
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
    Ok(())
}

/// `DATA ascii`: one line per point, whitespace-separated values, `nan` allowed.
fn read_ascii(
    h: &Header,
    bytes: &[u8],
    frgb: Option<usize>,
    err: &impl Fn(String) -> Error,
) -> Result<Table> {
    let (n, nf) = (h.n, h.fields.len());
    let data_len = bytes.len() - h.data_start;
    // Values per point in the file (a field of COUNT k has k of them); each needs at least one character and a
    // separator, and the size is checked against the data's length before anything is allocated, so a header
    // claiming more points than the file can hold is an error, not an allocation.
    let per_point = h
        .fields
        .iter()
        .try_fold(0usize, |a, f| a.checked_add(f.count))
        .ok_or_else(|| err("the COUNTs overflow".into()))?;
    let need = n.checked_mul(per_point).and_then(|v| v.checked_mul(2));
    if need.is_none_or(|b| b > data_len + 1) {
        return Err(too_many(
            n,
            data_len,
            need.map(|b| b.saturating_sub(1)),
            "ASCII data",
            err,
        ));
    }
    let mut table = Table {
        values: Vec::with_capacity(n * nf),
        rgb_bits: Vec::new(),
    };
    let text = std::str::from_utf8(&bytes[h.data_start..])
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
        for (j, f) in h.fields.iter().enumerate() {
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
            table.values.push(v);
            if Some(j) == frgb {
                table.rgb_bits.push(if f.kind == b'F' {
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
    Ok(table)
}

/// The error for a header that claims more points than the data can hold.
fn too_many(
    n: usize,
    data_len: usize,
    need: Option<usize>,
    what: &str,
    err: &impl Fn(String) -> Error,
) -> Error {
    err(format!(
        "header says {n} points ({}), but the file has only {data_len} bytes of data",
        match need {
            Some(b) => format!("at least {b} bytes of {what}"),
            None => format!("more bytes of {what} than can be counted"),
        }
    ))
}

/// `DATA binary` and `binary_compressed`: the point-major records (`n × record` bytes), decompressed and
/// reordered from PCL's field-major layout for the latter. Every size is checked against the file first.
fn binary_records<'a>(
    h: &Header,
    bytes: &'a [u8],
    err: &impl Fn(String) -> Error,
) -> Result<Cow<'a, [u8]>> {
    let (n, record, pos) = (h.n, h.record, h.data_start);
    let data_len = bytes.len() - pos;
    let need = n.checked_mul(record);
    if h.data_kind == "binary" {
        return match need {
            Some(b) if b <= data_len => Ok(Cow::Borrowed(&bytes[pos..pos + b])),
            _ => Err(err(format!(
                "binary data is truncated: header says {n} points ({} bytes), file has {data_len} bytes",
                need.map_or("too many".to_string(), |b| b.to_string())
            ))),
        };
    }
    if data_len < 8 {
        return Err(err("binary_compressed data is truncated".into()));
    }
    let le_u32 = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let (csize, usize_) = (le_u32(pos), le_u32(pos + 4));
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
    let soa = lzf_decompress(&bytes[pos + 8..pos + 8 + csize], usize_)
        .map_err(|m| err(format!("binary_compressed: {m}")))?;
    // Convert the field-major layout into point-major records.
    let mut aos = vec![0u8; usize_];
    let mut base = 0;
    for f in &h.fields {
        let fb = f.bytes();
        for i in 0..n {
            aos[i * record + f.offset..i * record + f.offset + fb]
                .copy_from_slice(&soa[base + i * fb..base + (i + 1) * fb]);
        }
        base += fb * n;
    }
    Ok(Cow::Owned(aos))
}

/// The cloud of binary records (`DATA binary`, or `binary_compressed` once decompressed and interleaved):
/// only the fields it keeps are read, straight from each record (fields `xyz`, `normals` and `rgb` by index;
/// a field of COUNT k gives its first value). 6 MB of binary PCD with normals reads in about 3 ms where a
/// table of every field as `f64` took 20.7 ms (`cargo bench --bench io`: 2.8 ms).
fn cloud_from_records(
    h: &Header,
    data: &[u8],
    xyz: [usize; 3],
    normals: [Option<usize>; 3],
    rgb: Option<usize>,
) -> PointCloud {
    // n * record <= data length (checked by `binary_records`) and record >= 1.
    let records = data.chunks_exact(h.record.max(1)).take(h.n);
    let at = |r: &[u8], j: usize| {
        let f = &h.fields[j];
        f.read(&r[f.offset..]) as f32
    };
    // Three fields of each record: float fields (the common case) read at fixed offsets, others through
    // the per-value type dispatch.
    let three = |j: [usize; 3]| -> Vec<[f32; 3]> {
        if j.iter()
            .all(|&j| (h.fields[j].kind, h.fields[j].size) == (b'F', 4))
        {
            let o = j.map(|j| h.fields[j].offset);
            let f = |r: &[u8], o: usize| f32::from_le_bytes(r[o..o + 4].try_into().unwrap());
            records
                .clone()
                .map(|r| [f(r, o[0]), f(r, o[1]), f(r, o[2])])
                .collect()
        } else {
            records
                .clone()
                .map(|r| [at(r, j[0]), at(r, j[1]), at(r, j[2])])
                .collect()
        }
    };
    let normals = match normals {
        [Some(a), Some(b), Some(c)] => Some(three([a, b, c])),
        _ => None,
    };
    PointCloud {
        points: three(xyz),
        normals,
        colors: rgb.map(|j| {
            let o = h.fields[j].offset;
            records
                .map(|r| rgb_from_bits(u32::from_le_bytes(r[o..o + 4].try_into().unwrap())))
                .collect()
        }),
    }
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

    /// Random layouts (field types, sizes, counts and order, extra fields, packed rgb) written as binary
    /// and as ASCII read to the same cloud, bit for bit: the binary records are read field by field, the
    /// ASCII through the table.
    #[test]
    fn binary_records_read_as_their_ascii_text_on_random_layouts() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let kinds: [(u8, usize); 10] = [
            (b'F', 4),
            (b'F', 4),
            (b'F', 8),
            (b'I', 1),
            (b'I', 2),
            (b'I', 4),
            (b'U', 1),
            (b'U', 2),
            (b'U', 4),
            (b'U', 8),
        ];
        for case in 0..200 {
            let mut names: Vec<&str> = vec!["x", "y", "z"];
            for extra in [
                "normal_x",
                "normal_y",
                "normal_z",
                "intensity",
                "rgb",
                "label",
            ] {
                if next() % 3 == 0 {
                    names.push(extra);
                }
            }
            let k = (next() % names.len() as u64) as usize;
            let last = names.len() - 1;
            names.swap(k, last);
            let fields: Vec<(&str, u8, usize, usize)> = names
                .iter()
                .map(|&n| {
                    let (t, z) = if n == "rgb" {
                        (b'U', 4)
                    } else {
                        kinds[(next() % kinds.len() as u64) as usize]
                    };
                    (n, t, z, if n == "label" { 2 } else { 1 })
                })
                .collect();
            let n = (next() % 30) as usize;
            let head = |data: &str| {
                format!(
                    "FIELDS {}\nSIZE {}\nTYPE {}\nCOUNT {}\nWIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA {data}\n",
                    fields.iter().map(|f| f.0).collect::<Vec<_>>().join(" "),
                    fields.iter().map(|f| f.2.to_string()).collect::<Vec<_>>().join(" "),
                    fields.iter().map(|f| (f.1 as char).to_string()).collect::<Vec<_>>().join(" "),
                    fields.iter().map(|f| f.3.to_string()).collect::<Vec<_>>().join(" "),
                )
            };
            let (mut bin, mut text) = (head("binary").into_bytes(), head("ascii"));
            for _ in 0..n {
                let mut line = Vec::new();
                for &(_, t, z, count) in &fields {
                    for _ in 0..count {
                        let r = next();
                        match (t, z) {
                            (b'F', 4) => {
                                let v = (r % 20_000) as f32 / 64.0 - 150.0;
                                bin.extend(v.to_le_bytes());
                                line.push(format!("{v:?}"));
                            }
                            (b'F', _) => {
                                let v = (r % 20_000) as f64 / 128.0 - 70.0;
                                bin.extend(v.to_le_bytes());
                                line.push(format!("{v:?}"));
                            }
                            (b'I', _) => {
                                let v = (r % 200) as i64 - 100;
                                bin.extend(&v.to_le_bytes()[..z]);
                                line.push(v.to_string());
                            }
                            _ => {
                                let v = r % if z == 1 { 256 } else { 65_536 };
                                bin.extend(&v.to_le_bytes()[..z]);
                                line.push(v.to_string());
                            }
                        }
                    }
                }
                text.push_str(&line.join(" "));
                text.push('\n');
            }
            let b = read(Path::new("b.pcd"), &bin).unwrap_or_else(|e| panic!("case {case}: {e}"));
            let a = read(Path::new("a.pcd"), text.as_bytes())
                .unwrap_or_else(|e| panic!("case {case}: {e}"));
            let bits =
                |p: &[[f32; 3]]| -> Vec<u32> { p.iter().flatten().map(|v| v.to_bits()).collect() };
            assert_eq!(bits(&b.points), bits(&a.points), "case {case}");
            assert_eq!(
                b.normals.as_deref().map(bits),
                a.normals.as_deref().map(bits),
                "case {case}"
            );
            assert_eq!(b.colors, a.colors, "case {case}");
            assert_eq!(b.len(), n);
        }
    }
}
