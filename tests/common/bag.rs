//! A ROS1 bag writer (format 2.0) for the tests, written from the format description, independent of the
//! reader; and the ROS1 serialisation of the messages the tests record.
#![allow(dead_code)]

use std::io::Write;
use std::path::Path;

pub fn field(name: &str, value: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&((name.len() + 1 + value.len()) as u32).to_le_bytes());
    v.extend_from_slice(name.as_bytes());
    v.push(b'=');
    v.extend_from_slice(value);
    v
}

pub fn record(fields: &[(&str, Vec<u8>)], data: &[u8]) -> Vec<u8> {
    let header: Vec<u8> = fields.iter().flat_map(|(n, v)| field(n, v)).collect();
    let mut v = Vec::new();
    v.extend_from_slice(&(header.len() as u32).to_le_bytes());
    v.extend_from_slice(&header);
    v.extend_from_slice(&(data.len() as u32).to_le_bytes());
    v.extend_from_slice(data);
    v
}

pub fn time_bytes(t_ns: u64) -> Vec<u8> {
    let mut v = ((t_ns / 1_000_000_000) as u32).to_le_bytes().to_vec();
    v.extend_from_slice(&((t_ns % 1_000_000_000) as u32).to_le_bytes());
    v
}

#[derive(Clone, Copy, PartialEq)]
pub enum Compression {
    None,
    Lz4,
    Bz2,
}

pub struct Msg {
    pub topic: String,
    pub tp: String,
    pub t_ns: u64,
    pub data: Vec<u8>,
}

/// Writes `msgs` (in this order) into a bag with `per_chunk` messages per chunk, chunk k compressed with
/// `compression[k % len]`.
pub fn write_bag(path: &Path, msgs: &[Msg], per_chunk: usize, compression: &[Compression]) {
    let mut topics: Vec<(String, String)> = Vec::new();
    for m in msgs {
        if !topics.iter().any(|(t, _)| t == &m.topic) {
            topics.push((m.topic.clone(), m.tp.clone()));
        }
    }
    let conn_id = |topic: &str| topics.iter().position(|(t, _)| t == topic).unwrap() as u32;
    let conn_record = |id: u32| {
        let (topic, tp) = &topics[id as usize];
        let data: Vec<u8> = [
            field("topic", topic.as_bytes()),
            field("type", tp.as_bytes()),
            field("md5sum", b"0123456789abcdef0123456789abcdef"),
            field("message_definition", b"# test\n"),
        ]
        .concat();
        record(
            &[
                ("op", vec![0x07]),
                ("conn", id.to_le_bytes().to_vec()),
                ("topic", topic.as_bytes().to_vec()),
            ],
            &data,
        )
    };
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    let header_at = out.len();
    out.extend(vec![0u8; 4096]); // the bag header record, filled in at the end
    let mut chunk_infos = Vec::new();
    for (k, chunk_msgs) in msgs.chunks(per_chunk).enumerate() {
        let mut inner = Vec::new();
        let mut seen = std::collections::HashSet::new();
        let mut index: std::collections::BTreeMap<u32, Vec<(u64, u32)>> = Default::default();
        for m in chunk_msgs {
            let id = conn_id(&m.topic);
            if seen.insert(id) {
                inner.extend(conn_record(id));
            }
            index
                .entry(id)
                .or_default()
                .push((m.t_ns, inner.len() as u32));
            inner.extend(record(
                &[
                    ("op", vec![0x02]),
                    ("conn", id.to_le_bytes().to_vec()),
                    ("time", time_bytes(m.t_ns)),
                ],
                &m.data,
            ));
        }
        let comp = compression[k % compression.len()];
        let (name, body): (&str, Vec<u8>) = match comp {
            Compression::None => ("none", inner.clone()),
            Compression::Lz4 => {
                let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
                enc.write_all(&inner).unwrap();
                let (v, r) = enc.finish();
                r.unwrap();
                ("lz4", v)
            }
            Compression::Bz2 => {
                let mut enc = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::best());
                enc.write_all(&inner).unwrap();
                ("bz2", enc.finish().unwrap())
            }
        };
        let chunk_pos = out.len() as u64;
        out.extend(record(
            &[
                ("op", vec![0x05]),
                ("compression", name.as_bytes().to_vec()),
                ("size", (inner.len() as u32).to_le_bytes().to_vec()),
            ],
            &body,
        ));
        for (id, entries) in &index {
            let mut data = Vec::new();
            for (t, off) in entries {
                data.extend(time_bytes(*t));
                data.extend_from_slice(&off.to_le_bytes());
            }
            out.extend(record(
                &[
                    ("op", vec![0x04]),
                    ("ver", 1u32.to_le_bytes().to_vec()),
                    ("conn", id.to_le_bytes().to_vec()),
                    ("count", (entries.len() as u32).to_le_bytes().to_vec()),
                ],
                &data,
            ));
        }
        let start = chunk_msgs.iter().map(|m| m.t_ns).min().unwrap();
        let end = chunk_msgs.iter().map(|m| m.t_ns).max().unwrap();
        chunk_infos.push((chunk_pos, start, end, index));
    }
    let index_pos = out.len() as u64;
    for id in 0..topics.len() as u32 {
        out.extend(conn_record(id));
    }
    for (pos, start, end, index) in &chunk_infos {
        let mut data = Vec::new();
        for (id, e) in index {
            data.extend_from_slice(&id.to_le_bytes());
            data.extend_from_slice(&(e.len() as u32).to_le_bytes());
        }
        out.extend(record(
            &[
                ("op", vec![0x06]),
                ("ver", 1u32.to_le_bytes().to_vec()),
                ("chunk_pos", pos.to_le_bytes().to_vec()),
                ("start_time", time_bytes(*start)),
                ("end_time", time_bytes(*end)),
                ("count", (index.len() as u32).to_le_bytes().to_vec()),
            ],
            &data,
        ));
    }
    let fields = [
        ("op", vec![0x03]),
        ("index_pos", index_pos.to_le_bytes().to_vec()),
        ("conn_count", (topics.len() as u32).to_le_bytes().to_vec()),
        (
            "chunk_count",
            (chunk_infos.len() as u32).to_le_bytes().to_vec(),
        ),
    ];
    let header_len: usize = fields.iter().map(|(n, v)| 4 + n.len() + 1 + v.len()).sum();
    let pad = 4096 - 8 - header_len;
    let h = record(&fields, &vec![b' '; pad]);
    assert_eq!(h.len(), 4096);
    out[header_at..header_at + 4096].copy_from_slice(&h);
    std::fs::write(path, out).unwrap();
}

// ROS1 serialisation of the messages.

pub fn ros_header(t_ns: u64, frame: &str) -> Vec<u8> {
    let mut v = 7u32.to_le_bytes().to_vec();
    v.extend(time_bytes(t_ns));
    v.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    v.extend_from_slice(frame.as_bytes());
    v
}

pub fn ros_string(s: &str) -> Vec<u8> {
    let mut v = (s.len() as u32).to_le_bytes().to_vec();
    v.extend_from_slice(s.as_bytes());
    v
}

/// A `sensor_msgs/Image` with `pad` extra bytes at the end of each row.
pub fn image_msg(
    t_ns: u64,
    (w, h): (u32, u32),
    encoding: &str,
    big_endian: bool,
    bpp: u32,
    pixels: &[u8],
    pad: u32,
) -> Vec<u8> {
    let step = w * bpp + pad;
    let mut data = Vec::new();
    for r in 0..h as usize {
        let row = (w * bpp) as usize;
        data.extend_from_slice(&pixels[r * row..(r + 1) * row]);
        data.extend(vec![0xEEu8; pad as usize]);
    }
    let mut v = ros_header(t_ns, "camera_depth_optical_frame");
    v.extend_from_slice(&h.to_le_bytes());
    v.extend_from_slice(&w.to_le_bytes());
    v.extend(ros_string(encoding));
    v.push(big_endian as u8);
    v.extend_from_slice(&step.to_le_bytes());
    v.extend_from_slice(&(data.len() as u32).to_le_bytes());
    v.extend(data);
    v
}

pub struct Cam {
    pub w: u32,
    pub h: u32,
    pub fx: f64,
    pub fy: f64,
    pub ppx: f64,
    pub ppy: f64,
    pub model: &'static str,
    pub d: Vec<f64>,
}

pub fn camera_info_msg(t_ns: u64, c: &Cam) -> Vec<u8> {
    let mut v = ros_header(t_ns, "camera_depth_optical_frame");
    v.extend_from_slice(&c.h.to_le_bytes());
    v.extend_from_slice(&c.w.to_le_bytes());
    v.extend(ros_string(c.model));
    v.extend_from_slice(&(c.d.len() as u32).to_le_bytes());
    for d in &c.d {
        v.extend_from_slice(&d.to_le_bytes());
    }
    let k = [c.fx, 0.0, c.ppx, 0.0, c.fy, c.ppy, 0.0, 0.0, 1.0];
    let r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let p = [
        c.fx, 0.0, c.ppx, 0.0, 0.0, c.fy, c.ppy, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    for x in k.iter().chain(&r).chain(&p) {
        v.extend_from_slice(&x.to_le_bytes());
    }
    v.extend_from_slice(&0u32.to_le_bytes()); // binning_x
    v.extend_from_slice(&0u32.to_le_bytes()); // binning_y
    for _ in 0..4 {
        v.extend_from_slice(&0u32.to_le_bytes()); // roi
    }
    v.push(0);
    v
}

pub fn msg(topic: &str, tp: &str, t_ns: u64, data: Vec<u8>) -> Msg {
    Msg {
        topic: topic.into(),
        tp: tp.into(),
        t_ns,
        data,
    }
}
