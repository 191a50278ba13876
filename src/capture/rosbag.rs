//! ROS1 `.bag` recordings (format 2.0) read in pure Rust with the `rosbag` crate: depth images
//! (`sensor_msgs/Image`), the camera's `sensor_msgs/CameraInfo`, optional colour images, and, in bags written
//! by librealsense, the depth sensor's `Depth Units` option.
//!
//! Depth encodings: `16UC1` and `mono16` (raw 16-bit units; the depth scale is the recording's `Depth Units`
//! option when it has one, else 1 mm as ROS REP 118 defines for 16-bit depth) and `32FC1` (metres; stored as
//! 16-bit units of the depth scale, rounded to the nearest unit; NaN, ≤ 0 and out-of-range values become 0 = no
//! data). Colour encodings: `rgb8`, `bgr8`, `rgba8`, `bgra8` (stored as RGB8).
//!
//! Timestamps are the images' `header.stamp` (seconds), or the bag's receive time when the stamp is zero.
//! Topics are found automatically when there is no doubt (see [`BagImportConfig`]); the camera info and depth
//! units that belong to a depth topic are those whose topic shares the longest prefix with it (e.g.
//! `/camera/depth/image_rect_raw` ↔ `/camera/depth/camera_info`, and in librealsense's layout
//! `/device_0/sensor_0/Depth_0/image/data` ↔ `/device_0/sensor_0/Depth_0/info/camera_info` and
//! `/device_0/sensor_0/option/Depth_Units/value`).

use super::{FrameStamp, Recording, RecordingInfo, StreamFrames};
use crate::camera::RgbImage;
use crate::camera::{DepthImage, DistortionModel, Intrinsics, DEFAULT_DEPTH_SCALE};
use crate::error::{Error, Result};
use rosbag::{ChunkRecord, IndexRecord, MessageRecord, RosBag};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// The ROS message type of images.
pub const IMAGE_TYPE: &str = "sensor_msgs/Image";
/// The ROS message type of camera calibrations.
pub const CAMERA_INFO_TYPE: &str = "sensor_msgs/CameraInfo";
/// The ROS message types of TF transforms (`tf2_msgs/TFMessage`, and old ROS1 `tf`'s `tf/tfMessage`, which
/// is serialised the same way).
pub const TF_TYPES: [&str; 2] = ["tf2_msgs/TFMessage", "tf/tfMessage"];
/// The ROS message type of librealsense's option values.
pub const FLOAT32_TYPE: &str = "std_msgs/Float32";
/// The topic suffixes of librealsense's depth-units option (librealsense writes `Depth_Units`).
pub const DEPTH_UNITS_SUFFIXES: [&str; 2] =
    ["/option/Depth_Units/value", "/option/Depth Units/value"];

/// Settings of a `.bag` import. Topics left `None` are found automatically:
/// * depth: the one image topic with a depth encoding (`16UC1`, `mono16`, `32FC1`); among several, the one
///   whose name contains `depth`; still several is an error listing them;
/// * camera info: the `sensor_msgs/CameraInfo` topic sharing the longest prefix with the depth topic;
/// * colour (only with `color = true`): the one image topic with a colour encoding, or the one among several
///   whose name contains `color`/`colour`/`rgb`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BagImportConfig {
    /// The depth image topic.
    pub depth_topic: Option<String>,
    /// The camera info topic of the depth camera.
    pub camera_info_topic: Option<String>,
    /// Import colour images too (default false).
    pub color: bool,
    /// The colour image topic (implies `color`).
    pub color_topic: Option<String>,
    /// Metres per depth unit, overriding what the recording says (default: its `Depth Units` option, else
    /// 0.001 for 16-bit depth; 0.001 for `32FC1`).
    pub depth_scale: Option<f64>,
    /// Collect the TF transforms (every `tf2_msgs/TFMessage` topic; those on a topic ending in
    /// `tf_static` are static) for [`BagRecording::take_tf`] (default false).
    pub tf: bool,
}

impl BagImportConfig {
    /// Checks the settings; the error names the field: a depth scale must be a positive length, a topic a
    /// non-empty name.
    pub fn validate(&self) -> Result<()> {
        if let Some(s) = self.depth_scale {
            crate::error::check::positive("depth_scale", s)?;
        }
        for (field, topic) in [
            ("depth_topic", &self.depth_topic),
            ("camera_info_topic", &self.camera_info_topic),
            ("color_topic", &self.color_topic),
        ] {
            if topic.as_deref().is_some_and(|t| t.trim().is_empty()) {
                return Err(Error::config(field, "must name a topic, got an empty name"));
            }
        }
        Ok(())
    }
}

/// A topic of a bag.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TopicInfo {
    /// The topic name.
    pub topic: String,
    /// The ROS message type.
    pub msg_type: String,
    /// Messages on it.
    pub messages: usize,
    /// Image encoding of its first message (image topics only).
    pub encoding: Option<String>,
    /// Image size of its first message (image topics only).
    pub size: Option<(u32, u32)>,
}

/// A little-endian reader over a ROS1 message body.
struct Msg<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Msg<'a> {
    fn new(data: &'a [u8]) -> Self {
        Msg { data, pos: 0 }
    }
    fn take(&mut self, n: usize, what: &str) -> std::result::Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(format!(
                "truncated message: {what} needs {n} bytes at offset {}, the message has {}",
                self.pos,
                self.data.len()
            ));
        };
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u8(&mut self, what: &str) -> std::result::Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> std::result::Result<u32, String> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn f64(&mut self, what: &str) -> std::result::Result<f64, String> {
        let b = self.take(8, what)?;
        Ok(f64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn string(&mut self, what: &str) -> std::result::Result<&'a str, String> {
        let n = self.u32(what)? as usize;
        let b = self.take(n, what)?;
        std::str::from_utf8(b).map_err(|_| format!("{what} is not UTF-8"))
    }
    fn bytes(&mut self, what: &str) -> std::result::Result<&'a [u8], String> {
        let n = self.u32(what)? as usize;
        self.take(n, what)
    }
    /// `std_msgs/Header`: returns the stamp in seconds.
    fn header(&mut self) -> std::result::Result<f64, String> {
        let _seq = self.u32("header.seq")?;
        let sec = self.u32("header.stamp.sec")?;
        let nsec = self.u32("header.stamp.nsec")?;
        let _frame = self.string("header.frame_id")?;
        Ok(sec as f64 + nsec as f64 * 1e-9)
    }
}

/// A decoded `sensor_msgs/Image` (borrowing the pixel data).
#[derive(Clone, Debug, PartialEq)]
pub struct RosImage<'a> {
    /// `header.stamp`, seconds (0 when unset).
    pub stamp_s: f64,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`16UC1`, `mono16`, `32FC1`, `rgb8`, ...).
    pub encoding: &'a str,
    /// Whether multi-byte pixels are big-endian.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixel bytes, `step * height` of them (at least).
    pub data: &'a [u8],
}

impl<'a> RosImage<'a> {
    /// Decodes a ROS1-serialised `sensor_msgs/Image`; the message says what is wrong.
    pub fn decode(data: &'a [u8]) -> std::result::Result<Self, String> {
        let mut m = Msg::new(data);
        let stamp_s = m.header()?;
        let height = m.u32("height")?;
        let width = m.u32("width")?;
        let encoding = m.string("encoding")?;
        let is_bigendian = m.u8("is_bigendian")? != 0;
        let step = m.u32("step")?;
        let data = m.bytes("data")?;
        let img = RosImage {
            stamp_s,
            height,
            width,
            encoding,
            is_bigendian,
            step,
            data,
        };
        if let Some(bpp) = bytes_per_pixel(encoding) {
            img.check_layout(bpp)?;
        }
        Ok(img)
    }

    /// Checks that `step` holds a row of `bpp`-byte pixels and `data` holds `height` rows, so that nothing
    /// sized from the header is allocated or indexed beyond the message.
    fn check_layout(&self, bpp: usize) -> std::result::Result<(), String> {
        let (width, height, step, encoding) = (self.width, self.height, self.step, self.encoding);
        let row = width as u64 * bpp as u64;
        if (step as u64) < row {
            return Err(format!(
                "step {step} is less than width {width} x {bpp} bytes of {encoding}"
            ));
        }
        if (self.data.len() as u64) < step as u64 * height as u64 {
            return Err(format!(
                "data has {} bytes, fewer than step {step} x height {height}",
                self.data.len()
            ));
        }
        Ok(())
    }

    fn row(&self, v: u32, bpp: usize) -> &'a [u8] {
        let start = v as usize * self.step as usize;
        &self.data[start..start + self.width as usize * bpp]
    }

    /// The image as raw depth units of `depth_scale` metres: 16-bit encodings as they are, `32FC1` metres
    /// rounded to units (NaN, ≤ 0 and values above 65535 units become 0). Also returns the number of `32FC1`
    /// pixels set to 0 for being out of range.
    pub fn to_depth(&self, depth_scale: f64) -> std::result::Result<(DepthImage, usize), String> {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return Err(format!("the image is empty ({w}x{h})"));
        }
        let bpp = match self.encoding {
            "16UC1" | "mono16" => 2,
            "32FC1" => 4,
            other => {
                return Err(format!(
                    "encoding {other:?} is not a depth encoding (expected 16UC1, mono16 or 32FC1)"
                ))
            }
        };
        self.check_layout(bpp)?;
        let mut data = Vec::with_capacity(w as usize * h as usize);
        let mut clipped = 0;
        match self.encoding {
            "16UC1" | "mono16" => {
                for v in 0..h {
                    data.extend(self.row(v, 2).chunks_exact(2).map(|b| {
                        if self.is_bigendian {
                            u16::from_be_bytes([b[0], b[1]])
                        } else {
                            u16::from_le_bytes([b[0], b[1]])
                        }
                    }));
                }
            }
            "32FC1" => {
                for v in 0..h {
                    for b in self.row(v, 4).chunks_exact(4) {
                        let b = [b[0], b[1], b[2], b[3]];
                        let m = if self.is_bigendian {
                            f32::from_be_bytes(b)
                        } else {
                            f32::from_le_bytes(b)
                        } as f64;
                        let units = (m / depth_scale).round();
                        if m.is_finite() && m > 0.0 && units <= u16::MAX as f64 {
                            data.push(units as u16);
                        } else {
                            if m.is_finite() && m > 0.0 {
                                clipped += 1;
                            }
                            data.push(0);
                        }
                    }
                }
            }
            other => {
                return Err(format!(
                    "encoding {other:?} is not a depth encoding (expected 16UC1, mono16 or 32FC1)"
                ))
            }
        }
        Ok((
            DepthImage {
                width: w,
                height: h,
                data,
            },
            clipped,
        ))
    }

    /// The image as RGB8 (from `rgb8`, `bgr8`, `rgba8`, `bgra8`).
    pub fn to_rgb(&self) -> std::result::Result<RgbImage, String> {
        let (bpp, order): (usize, [usize; 3]) = match self.encoding {
            "rgb8" => (3, [0, 1, 2]),
            "bgr8" => (3, [2, 1, 0]),
            "rgba8" => (4, [0, 1, 2]),
            "bgra8" => (4, [2, 1, 0]),
            other => {
                return Err(format!(
                "encoding {other:?} is not a colour encoding (expected rgb8, bgr8, rgba8 or bgra8)"
            ))
            }
        };
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "the image is empty ({}x{})",
                self.width, self.height
            ));
        }
        self.check_layout(bpp)?;
        let mut data = Vec::with_capacity(self.width as usize * self.height as usize * 3);
        for v in 0..self.height {
            for p in self.row(v, bpp).chunks_exact(bpp) {
                data.extend(order.iter().map(|&i| p[i]));
            }
        }
        Ok(RgbImage {
            width: self.width,
            height: self.height,
            data,
        })
    }
}

fn bytes_per_pixel(encoding: &str) -> Option<usize> {
    match encoding {
        "16UC1" | "mono16" => Some(2),
        "32FC1" | "rgba8" | "bgra8" => Some(4),
        "rgb8" | "bgr8" => Some(3),
        "mono8" | "8UC1" => Some(1),
        _ => None,
    }
}

fn is_depth_encoding(e: &str) -> bool {
    matches!(e, "16UC1" | "mono16" | "32FC1")
}

fn is_color_encoding(e: &str) -> bool {
    matches!(e, "rgb8" | "bgr8" | "rgba8" | "bgra8")
}

/// One transform of a `tf2_msgs/TFMessage`: `T_parent_child` at `stamp_s`.
#[derive(Clone, Debug, PartialEq)]
pub struct RosTransform {
    /// `header.frame_id`: the parent frame.
    pub parent: String,
    /// `child_frame_id`.
    pub child: String,
    /// `header.stamp`, seconds (0 when unset).
    pub stamp_s: f64,
    /// Maps child coordinates into the parent frame (metres; the quaternion normalised).
    pub transform: nalgebra::Isometry3<f64>,
}

/// Decodes a ROS1-serialised `tf2_msgs/TFMessage` (`geometry_msgs/TransformStamped[]`); a non-finite value
/// or a quaternion far from unit length (|‖q‖ − 1| > 1e-3) is an error naming the transform.
pub fn decode_tf_message(data: &[u8]) -> std::result::Result<Vec<RosTransform>, String> {
    let mut m = Msg::new(data);
    let n = m.u32("transforms length")? as usize;
    // Each TransformStamped takes at least 76 bytes (empty frame ids).
    if n.saturating_mul(76) > data.len() {
        return Err(format!(
            "truncated message: {n} transforms cannot fit in {} bytes",
            data.len()
        ));
    }
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let _seq = m.u32("header.seq")?;
        let sec = m.u32("header.stamp.sec")?;
        let nsec = m.u32("header.stamp.nsec")?;
        let parent = m.string("header.frame_id")?.to_string();
        let child = m.string("child_frame_id")?.to_string();
        let mut v = [0.0; 7];
        for x in &mut v {
            *x = m.f64("transform")?;
        }
        let what = format!("transform {} ({parent} -> {child})", k + 1);
        if v.iter().any(|x| !x.is_finite()) {
            return Err(format!("{what}: a value is NaN or infinite"));
        }
        let q = nalgebra::Quaternion::new(v[6], v[3], v[4], v[5]);
        if (q.norm() - 1.0).abs() > 1e-3 {
            return Err(format!(
                "{what}: the rotation quaternion has length {:.6}, not 1",
                q.norm()
            ));
        }
        out.push(RosTransform {
            parent,
            child,
            stamp_s: sec as f64 + nsec as f64 * 1e-9,
            transform: nalgebra::Isometry3::from_parts(
                nalgebra::Translation3::new(v[0], v[1], v[2]),
                nalgebra::UnitQuaternion::from_quaternion(q),
            ),
        });
    }
    Ok(out)
}

/// A decoded `sensor_msgs/CameraInfo` (the fields depthcal uses).
#[derive(Clone, Debug, PartialEq)]
pub struct RosCameraInfo {
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// The distortion model name (`plumb_bob`, `equidistant`, librealsense's `Brown Conrady`, ...).
    pub distortion_model: String,
    /// Distortion coefficients `D`.
    pub d: Vec<f64>,
    /// The camera matrix `K`, row-major.
    pub k: [f64; 9],
    /// Binning in x and y (0 or 1: none).
    pub binning: (u32, u32),
}

impl RosCameraInfo {
    /// Decodes a ROS1-serialised `sensor_msgs/CameraInfo`.
    pub fn decode(data: &[u8]) -> std::result::Result<Self, String> {
        let mut m = Msg::new(data);
        m.header()?;
        let height = m.u32("height")?;
        let width = m.u32("width")?;
        let distortion_model = m.string("distortion_model")?.to_string();
        let n = m.u32("D length")? as usize;
        if n > 64 {
            return Err(format!("D has {n} coefficients"));
        }
        let mut d = Vec::with_capacity(n);
        for _ in 0..n {
            d.push(m.f64("D")?);
        }
        let mut k = [0.0; 9];
        for v in &mut k {
            *v = m.f64("K")?;
        }
        for _ in 0..9 {
            m.f64("R")?;
        }
        for _ in 0..12 {
            m.f64("P")?;
        }
        let bx = m.u32("binning_x")?;
        let by = m.u32("binning_y")?;
        Ok(RosCameraInfo {
            height,
            width,
            distortion_model,
            d,
            k,
            binning: (bx, by),
        })
    }

    /// The intrinsics (librealsense conventions, which ROS shares: pixel (0, 0) is the centre of the top-left
    /// pixel), with the given depth scale. `plumb_bob` and `rational_polynomial` (whose extra coefficients must
    /// be zero) map to Brown-Conrady, `equidistant` to Kannala-Brandt; librealsense's own model names are
    /// understood too. All-zero coefficients give the model `none`.
    pub fn to_intrinsics(&self, depth_scale: f64) -> std::result::Result<Intrinsics, String> {
        if !matches!(self.binning, (0 | 1, 0 | 1)) {
            return Err(format!(
                "binning {}x{} is not supported (the intrinsics would not describe the image)",
                self.binning.0, self.binning.1
            ));
        }
        let name = self.distortion_model.trim();
        let all_zero = self.d.iter().all(|&c| c == 0.0);
        let model = if all_zero {
            DistortionModel::None
        } else if name.eq_ignore_ascii_case("rational_polynomial") {
            if self.d.iter().skip(5).any(|&c| c != 0.0) {
                return Err(format!(
                    "distortion model rational_polynomial with non-zero k4..k6 ({:?}) is not supported",
                    &self.d[5..]
                ));
            }
            DistortionModel::BrownConrady
        } else {
            name.parse::<DistortionModel>()?
        };
        let max = if model == DistortionModel::KannalaBrandt4 {
            4
        } else {
            5
        };
        if self.d.iter().skip(max).any(|&c| c != 0.0) {
            return Err(format!(
                "distortion model {name:?} with {} coefficients: at most {max} are used",
                self.d.len()
            ));
        }
        let mut coeffs = [0.0; 5];
        for (c, d) in coeffs.iter_mut().zip(&self.d) {
            *c = *d;
        }
        let intr = Intrinsics {
            fx: self.k[0],
            fy: self.k[4],
            ppx: self.k[2],
            ppy: self.k[5],
            coeffs,
            model,
            width: self.width,
            height: self.height,
            depth_scale,
            rms: None,
        };
        if self.k[1] != 0.0 {
            return Err(format!("K has a skew term ({}); not supported", self.k[1]));
        }
        intr.validate().map_err(|m| format!("K: {m}"))?;
        Ok(intr)
    }
}

fn bag_error(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::format(path, format!("not a readable ROS1 bag: {e}"))
}

/// Checks what `rosbag` would otherwise panic or fail obscurely on: the version line and an index position
/// inside the file (an unindexed bag, e.g. from an interrupted recording, has none).
fn check_bag_header(path: &Path, data: &[u8], file_len: u64) -> Result<()> {
    const SQLITE: &[u8] = b"SQLite format 3\0";
    if data.starts_with(SQLITE) {
        return Err(Error::format(
            path,
            "this is a ROS2 (.db3, SQLite) recording, not a ROS1 bag; import it through librealsense (build with \
             --features realsense)",
        ));
    }
    let version = b"#ROSBAG V2.0\n";
    if !data.starts_with(version) {
        let line: String = data
            .iter()
            .take(16)
            .take_while(|&&b| b != b'\n')
            .map(|&b| {
                if b.is_ascii_graphic() || b == b' ' {
                    b as char
                } else {
                    '?'
                }
            })
            .collect();
        return Err(Error::format(
            path,
            format!(
                "not a ROS1 bag of format 2.0: the file starts with {line:?}, not \"#ROSBAG V2.0\""
            ),
        ));
    }
    let mut m = Msg::new(&data[version.len()..]);
    let header = m.bytes("bag header").map_err(|e| bag_error(path, e))?;
    let mut fields = Msg::new(header);
    let mut index_pos = None;
    while fields.pos < header.len() {
        let f = fields
            .bytes("header field")
            .map_err(|e| bag_error(path, e))?;
        if let Some(v) = f.strip_prefix(b"index_pos=") {
            if v.len() == 8 {
                index_pos = Some(u64::from_le_bytes(v.try_into().expect("8 bytes")));
            }
        }
    }
    // The header record's data (padding) follows; the chunk section starts after it.
    let _ = m
        .bytes("bag header padding")
        .map_err(|e| bag_error(path, e))?;
    let chunks_start = (version.len() + m.pos) as u64;
    match index_pos {
        Some(p) if p >= chunks_start && p <= file_len => Ok(()),
        _ => Err(Error::format(
            path,
            "the bag has no index (index_pos is 0, inside the header or past the end of the file): the \
             recording was probably interrupted; `rosbag reindex` repairs it",
        )),
    }
}

/// The largest decompressed chunk accepted (real recordings write chunks of a few MB).
const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Walks the bag's records (headers only, seeking over the data) and checks every length against the file
/// and every chunk's claimed decompressed `size` against its compressed data, before the `rosbag` crate
/// allocates that size.
fn check_bag_records(path: &Path, file: std::fs::File, file_len: u64) -> Result<()> {
    use std::io::{Read, Seek};
    let mut r = std::io::BufReader::new(file);
    let mut pos = 13u64; // after "#ROSBAG V2.0\n"
    r.seek(std::io::SeekFrom::Start(pos))
        .map_err(|e| Error::io(path, e))?;
    let read_u32 = |r: &mut std::io::BufReader<std::fs::File>| -> Option<u32> {
        let mut b = [0u8; 4];
        r.read_exact(&mut b).ok().map(|_| u32::from_le_bytes(b))
    };
    let mut k = 0usize;
    while pos < file_len {
        let at = |what: String| {
            Error::format(
                path,
                format!("not a readable ROS1 bag: record {k} at byte {pos}: {what}"),
            )
        };
        let hlen =
            read_u32(&mut r).ok_or_else(|| at("truncated record header length".into()))? as u64;
        if hlen > file_len - pos - 4 {
            return Err(at(format!(
                "header length {hlen} runs past the end of the file ({file_len} bytes)"
            )));
        }
        let mut header = vec![0u8; hlen as usize];
        r.read_exact(&mut header)
            .map_err(|e| at(format!("header: {e}")))?;
        let dlen =
            read_u32(&mut r).ok_or_else(|| at("truncated record data length".into()))? as u64;
        let data_at = pos + 8 + hlen;
        if data_at > file_len || dlen > file_len - data_at {
            return Err(at(format!(
                "data length {dlen} runs past the end of the file ({file_len} bytes)"
            )));
        }
        let mut fields = Msg::new(&header);
        let (mut op, mut compression, mut size) = (None, None, None);
        while fields.pos < header.len() {
            let Ok(f) = fields.bytes("header field") else {
                break; // the rosbag crate reports malformed fields
            };
            if let Some(v) = f.strip_prefix(b"op=") {
                op = v.first().copied();
            } else if let Some(v) = f.strip_prefix(b"compression=") {
                compression = Some(v.to_vec());
            } else if let Some(v) = f.strip_prefix(b"size=") {
                size = <[u8; 4]>::try_from(v).ok().map(u32::from_le_bytes);
            }
        }
        if op == Some(0x05) {
            if let Some(size) = size.map(u64::from) {
                let comp =
                    String::from_utf8_lossy(compression.as_deref().unwrap_or(b"?")).to_string();
                if comp == "none" && size != dlen {
                    return Err(at(format!(
                        "chunk header field `size` says {size} bytes, but the uncompressed chunk has {dlen}"
                    )));
                }
                let max = match comp.as_str() {
                    "lz4" => dlen.saturating_mul(256).saturating_add(1 << 16),
                    _ => MAX_CHUNK_BYTES,
                }
                .min(MAX_CHUNK_BYTES);
                if size > max {
                    return Err(at(format!(
                        "chunk header field `size` says {size} bytes, which {dlen} bytes of {comp} data cannot hold"
                    )));
                }
            }
        }
        r.seek_relative(dlen as i64)
            .map_err(|e| at(format!("data: {e}")))?;
        pos = data_at + dlen;
        k += 1;
    }
    Ok(())
}

/// Calls `f(topic, type, bag_time_ns, data)` for every message of the bag, in file order.
fn for_each_message(
    path: &Path,
    bag: &RosBag,
    conns: &mut HashMap<u32, (String, String)>,
    mut f: impl FnMut(&str, &str, u64, &[u8]) -> Result<()>,
) -> Result<()> {
    for rec in bag.chunk_records() {
        let ChunkRecord::Chunk(chunk) = rec.map_err(|e| bag_error(path, e))? else {
            continue;
        };
        for msg in chunk.messages() {
            match msg.map_err(|e| bag_error(path, e))? {
                MessageRecord::Connection(c) => {
                    conns.insert(c.id, (c.topic.to_string(), c.tp.to_string()));
                }
                MessageRecord::MessageData(d) => {
                    let Some((topic, tp)) = conns.get(&d.conn_id) else {
                        return Err(bag_error(
                            path,
                            format!(
                                "a message names connection {} that the bag does not define",
                                d.conn_id
                            ),
                        ));
                    };
                    f(topic, tp, d.time, d.data)?;
                }
            }
        }
    }
    Ok(())
}

/// One image message found in the first pass.
#[derive(Clone, Debug)]
struct ImageMeta {
    t_s: f64,
    /// Ordinal of the message on its topic (file order).
    ordinal: u64,
}

/// A ROS1 bag opened for import: the topics, the chosen depth (and colour) topic, the intrinsics.
pub struct BagRecording {
    info: RecordingInfo,
    bag: RosBag,
    conns: HashMap<u32, (String, String)>,
    /// Every topic of the bag, by name.
    pub topics: Vec<TopicInfo>,
    /// The camera info topic the intrinsics come from.
    pub camera_info_topic: String,
    /// Where the depth scale came from (`option topic`, `config`, `REP 118 default`).
    pub depth_scale_source: String,
    tf: super::tf::TfBuffer,
}

fn longest_prefix<'a>(
    target: &str,
    candidates: impl Iterator<Item = &'a String>,
) -> Vec<&'a String> {
    let common = |a: &str| {
        a.bytes()
            .zip(target.bytes())
            .take_while(|(x, y)| x == y)
            .count()
    };
    let all: Vec<&String> = candidates.collect();
    let best = all.iter().map(|c| common(c)).max().unwrap_or(0);
    all.into_iter().filter(|c| common(c) == best).collect()
}

/// What the first pass over a bag's messages found: the topics, each image topic's stamps, the camera infos
/// and the depth-units options by topic, and the TF transforms (when asked for).
struct BagScan {
    topics: Vec<TopicInfo>,
    images: HashMap<String, Vec<ImageMeta>>,
    infos: HashMap<String, Vec<RosCameraInfo>>,
    units: HashMap<String, f32>,
    tf: super::tf::TfBuffer,
}

impl BagRecording {
    /// The TF transforms of the bag (empty unless [`BagImportConfig::tf`] asked for them); leaves an empty
    /// buffer behind.
    pub fn take_tf(&mut self) -> super::tf::TfBuffer {
        std::mem::take(&mut self.tf)
    }

    /// Opens a bag, lists its topics and chooses the topics of `cfg` (see [`BagImportConfig`]); reads the
    /// camera info and the timestamps of every depth (and colour) image. Errors name the file and the topic.
    pub fn open(path: impl AsRef<Path>, cfg: &BagImportConfig) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        cfg.validate()?;
        check_bag_file(&path)?;
        let bag = RosBag::new(&path).map_err(|e| bag_error(&path, e))?;
        let mut conns: HashMap<u32, (String, String)> = HashMap::new();
        for rec in bag.index_records() {
            if let IndexRecord::Connection(c) = rec.map_err(|e| bag_error(&path, e))? {
                conns.insert(c.id, (c.topic.to_string(), c.tp.to_string()));
            }
        }
        let mut scan = scan_messages(&path, &bag, &mut conns, cfg)?;
        let topics = &scan.topics;
        let depth_topic = choose_image_topic(
            &path,
            topics,
            &cfg.depth_topic,
            "depth",
            is_depth_encoding,
            &["depth"],
        )?;
        let color_topic = if cfg.color || cfg.color_topic.is_some() {
            Some(choose_image_topic(
                &path,
                topics,
                &cfg.color_topic,
                "colour",
                is_color_encoding,
                &["color", "colour", "rgb"],
            )?)
        } else {
            None
        };
        let info_topic = choose_info_topic(&path, cfg, &scan, &depth_topic)?;
        let depth_info = topics
            .iter()
            .find(|t| t.topic == depth_topic)
            .expect("chosen topic exists");
        let encoding = depth_info.encoding.clone().unwrap_or_default();
        let (depth_scale, depth_scale_source) =
            depth_scale_of(&path, cfg, &encoding, &depth_topic, &scan.units)?;
        let intrinsics =
            fixed_intrinsics(&path, &scan.infos[&info_topic], &info_topic, depth_scale)?;
        if let Some((w, h)) = depth_info.size {
            if (w, h) != (intrinsics.width, intrinsics.height) {
                return Err(Error::format(
                    &path,
                    format!(
                        "topic {depth_topic} has {w}x{h} images but {info_topic} says {}x{}",
                        intrinsics.width, intrinsics.height
                    ),
                ));
            }
        }
        let depth = image_stream(&scan.images, &depth_topic);
        let color = color_topic
            .as_deref()
            .map(|t| image_stream(&scan.images, t));
        scan.tf.finish();
        Ok(BagRecording {
            info: RecordingInfo {
                path,
                intrinsics,
                depth,
                color,
            },
            bag,
            conns,
            topics: scan.topics,
            camera_info_topic: info_topic,
            depth_scale_source,
            tf: scan.tf,
        })
    }
}

/// The bag's header and record lengths are checked against the file before the rosbag crate reads it.
fn check_bag_file(path: &Path) -> Result<()> {
    use std::io::Read;
    let mut head = Vec::with_capacity(4096);
    std::fs::File::open(path)
        .and_then(|f| f.take(1 << 16).read_to_end(&mut head))
        .map_err(|e| Error::io(path, e))?;
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    check_bag_header(path, &head, len)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    check_bag_records(path, file, len)
}

/// The first pass over every message: topics, image stamps, camera infos, depth-units options and (when
/// `cfg.tf`) the TF transforms.
fn scan_messages(
    path: &Path,
    bag: &RosBag,
    conns: &mut HashMap<u32, (String, String)>,
    cfg: &BagImportConfig,
) -> Result<BagScan> {
    let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
    let mut images: HashMap<String, Vec<ImageMeta>> = HashMap::new();
    let mut infos: HashMap<String, Vec<RosCameraInfo>> = HashMap::new();
    let mut units: HashMap<String, f32> = HashMap::new();
    let mut tf = super::tf::TfBuffer::new();
    for_each_message(path, bag, conns, |topic, tp, time_ns, data| {
        let info = topics
            .entry(topic.to_string())
            .or_insert_with(|| TopicInfo {
                topic: topic.to_string(),
                msg_type: tp.to_string(),
                messages: 0,
                encoding: None,
                size: None,
            });
        let ordinal = info.messages as u64;
        info.messages += 1;
        let at = |msg: String| {
            Error::format(
                path,
                format!("topic {topic} message {}: {tp}: {msg}", ordinal + 1),
            )
        };
        // A message's own stamp, or the bag's receive time when the stamp is zero.
        let stamp = |s: f64| if s > 0.0 { s } else { time_ns as f64 * 1e-9 };
        match tp {
            IMAGE_TYPE => {
                let img = RosImage::decode(data).map_err(at)?;
                if info.encoding.is_none() {
                    info.encoding = Some(img.encoding.to_string());
                    info.size = Some((img.width, img.height));
                }
                images
                    .entry(topic.to_string())
                    .or_default()
                    .push(ImageMeta {
                        t_s: stamp(img.stamp_s),
                        ordinal,
                    });
            }
            CAMERA_INFO_TYPE => {
                let ci = RosCameraInfo::decode(data).map_err(at)?;
                infos.entry(topic.to_string()).or_default().push(ci);
            }
            FLOAT32_TYPE if DEPTH_UNITS_SUFFIXES.iter().any(|x| topic.ends_with(x)) => {
                let b: [u8; 4] = data
                    .get(..4)
                    .and_then(|b| b.try_into().ok())
                    .ok_or_else(|| at("truncated message: a Float32 needs 4 bytes".into()))?;
                units.insert(topic.to_string(), f32::from_le_bytes(b));
            }
            t if cfg.tf && TF_TYPES.contains(&t) => {
                let is_static = topic.trim_end_matches('/').ends_with("tf_static");
                for x in decode_tf_message(data).map_err(at)? {
                    tf.insert(
                        &x.parent,
                        &x.child,
                        stamp(x.stamp_s),
                        x.transform,
                        is_static,
                    );
                }
            }
            _ => {}
        }
        Ok(())
    })?;
    Ok(BagScan {
        topics: topics.into_values().collect(),
        images,
        infos,
        units,
        tf,
    })
}

/// `topic (type, encoding)` of every topic that `pred` keeps, for error messages.
fn describe_topics(topics: &[TopicInfo], pred: impl Fn(&TopicInfo) -> bool) -> Vec<String> {
    topics
        .iter()
        .filter(|t| pred(t))
        .map(|t| {
            format!(
                "{} ({}, {})",
                t.topic,
                t.msg_type,
                t.encoding.as_deref().unwrap_or("-")
            )
        })
        .collect()
}

/// The image topic of a `kind` (depth or colour): the one asked for (checked), else the only candidate, or
/// among several the only one whose name contains one of `hints`.
fn choose_image_topic(
    path: &Path,
    topics: &[TopicInfo],
    want: &Option<String>,
    kind: &str,
    is_kind: fn(&str) -> bool,
    hints: &[&str],
) -> Result<String> {
    if let Some(t) = want {
        let Some(info) = topics.iter().find(|i| &i.topic == t) else {
            return Err(Error::format(
                path,
                format!(
                    "no topic {t:?}; the image topics are {:?}",
                    describe_topics(topics, |i| i.msg_type == IMAGE_TYPE)
                ),
            ));
        };
        let enc = info.encoding.as_deref().unwrap_or("");
        if info.msg_type != IMAGE_TYPE || !is_kind(enc) {
            return Err(Error::format(
                path,
                format!(
                    "topic {t} is {} with encoding {enc:?}, not a {kind} image topic",
                    info.msg_type
                ),
            ));
        }
        return Ok(t.clone());
    }
    let cands: Vec<&TopicInfo> = topics
        .iter()
        .filter(|i| i.msg_type == IMAGE_TYPE && is_kind(i.encoding.as_deref().unwrap_or("")))
        .collect();
    let pick: Vec<&&TopicInfo> = if cands.len() > 1 {
        cands
            .iter()
            .filter(|i| {
                let l = i.topic.to_ascii_lowercase();
                hints.iter().any(|h| l.contains(h))
            })
            .collect()
    } else {
        cands.iter().collect()
    };
    match pick.as_slice() {
        [one] => Ok(one.topic.clone()),
        [] if cands.is_empty() => Err(Error::format(
            path,
            format!(
                "no {kind} image topic; the bag's topics are {:?}",
                describe_topics(topics, |_| true)
            ),
        )),
        _ => Err(Error::format(
            path,
            format!(
                "several {kind} image topics {:?}: choose one with the {kind} topic option",
                cands.iter().map(|c| c.topic.as_str()).collect::<Vec<_>>()
            ),
        )),
    }
}

/// The camera info topic: the one asked for (checked), else the one sharing the longest prefix with the
/// depth topic.
fn choose_info_topic(
    path: &Path,
    cfg: &BagImportConfig,
    scan: &BagScan,
    depth_topic: &str,
) -> Result<String> {
    if let Some(t) = &cfg.camera_info_topic {
        if !scan.infos.contains_key(t) {
            return Err(Error::format(
                path,
                format!(
                    "no {CAMERA_INFO_TYPE} messages on topic {t:?}; camera info topics: {:?}",
                    scan.infos.keys().collect::<Vec<_>>()
                ),
            ));
        }
        return Ok(t.clone());
    }
    match longest_prefix(depth_topic, scan.infos.keys()).as_slice() {
        [one] => Ok((*one).clone()),
        [] => Err(Error::format(
            path,
            format!(
                "no {CAMERA_INFO_TYPE} topic: the intrinsics of {depth_topic} are unknown (topics: {:?})",
                describe_topics(&scan.topics, |_| true)
            ),
        )),
        several => Err(Error::format(
            path,
            format!(
                "several camera info topics fit {depth_topic} equally: {several:?}; choose one with the \
                 camera info topic option"
            ),
        )),
    }
}

/// The depth scale in metres per unit and where it came from: given, the 32FC1 convention, the depth-units
/// option topic of the depth topic, or ROS REP 118's 1 mm.
fn depth_scale_of(
    path: &Path,
    cfg: &BagImportConfig,
    encoding: &str,
    depth_topic: &str,
    units: &HashMap<String, f32>,
) -> Result<(f64, String)> {
    let (depth_scale, source) = match cfg.depth_scale {
        Some(s) => (s, "given".to_string()),
        None if encoding == "32FC1" => (
            DEFAULT_DEPTH_SCALE,
            "default 1 mm units for 32FC1 metres".to_string(),
        ),
        None => {
            let best = longest_prefix(depth_topic, units.keys());
            match best.first() {
                Some(t) if best.len() == 1 => (units[*t] as f64, t.to_string()),
                _ => (
                    DEFAULT_DEPTH_SCALE,
                    "default 1 mm (ROS REP 118 16-bit depth)".to_string(),
                ),
            }
        }
    };
    if !(depth_scale.is_finite() && depth_scale > 0.0) {
        return Err(Error::format(
            path,
            format!(
                "depth scale {depth_scale} (from {source}) must be a positive number of metres"
            ),
        ));
    }
    Ok((depth_scale, source))
}

/// The intrinsics of the first camera info message; every later message must be the same.
fn fixed_intrinsics(
    path: &Path,
    cis: &[RosCameraInfo],
    info_topic: &str,
    depth_scale: f64,
) -> Result<Intrinsics> {
    let intrinsics = cis[0]
        .to_intrinsics(depth_scale)
        .map_err(|m| Error::format(path, format!("topic {info_topic} message 1: {m}")))?;
    if let Some(k) = cis.iter().position(|c| c != &cis[0]) {
        return Err(Error::format(
            path,
            format!(
                "topic {info_topic}: message {} differs from message 1; depthcal imports recordings with fixed \
                 intrinsics",
                k + 1
            ),
        ));
    }
    Ok(intrinsics)
}

/// An image topic's frames in time order.
fn image_stream(images: &HashMap<String, Vec<ImageMeta>>, topic: &str) -> StreamFrames {
    let mut frames: Vec<FrameStamp> = images
        .get(topic)
        .map(|v| {
            v.iter()
                .map(|m| FrameStamp {
                    t_s: m.t_s,
                    key: m.ordinal,
                })
                .collect()
        })
        .unwrap_or_default();
    frames.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    StreamFrames {
        name: topic.to_string(),
        frames,
    }
}

impl Recording for BagRecording {
    fn info(&self) -> &RecordingInfo {
        &self.info
    }

    fn read_frames(
        &mut self,
        depth: &[u64],
        color: &[u64],
    ) -> Result<(Vec<DepthImage>, Vec<RgbImage>)> {
        let depth_topic = self.info.depth.name.clone();
        let color_topic = self.info.color.as_ref().map(|c| c.name.clone());
        let want_d: HashMap<u64, Vec<usize>> = group(depth);
        let want_c: HashMap<u64, Vec<usize>> = group(color);
        let mut out_d: Vec<Option<DepthImage>> = vec![None; depth.len()];
        let mut out_c: Vec<Option<RgbImage>> = vec![None; color.len()];
        let mut ord: HashMap<String, u64> = HashMap::new();
        let path = self.info.path.clone();
        let intr = &self.info.intrinsics;
        let (scale, w, h) = (intr.depth_scale, intr.width, intr.height);
        for_each_message(&path, &self.bag, &mut self.conns, |topic, tp, _, data| {
            if tp != IMAGE_TYPE {
                return Ok(());
            }
            let is_d = topic == depth_topic;
            let is_c = color_topic.as_deref() == Some(topic);
            if !is_d && !is_c {
                return Ok(());
            }
            let o = ord.entry(topic.to_string()).or_insert(0);
            let ordinal = *o;
            *o += 1;
            let at = |msg: String| {
                Error::format(
                    &path,
                    format!("topic {topic} message {}: {msg}", ordinal + 1),
                )
            };
            if is_d {
                if let Some(slots) = want_d.get(&ordinal) {
                    let img = RosImage::decode(data).map_err(at)?;
                    let (d, clipped) = img.to_depth(scale).map_err(at)?;
                    if (d.width, d.height) != (w, h) {
                        return Err(at(format!(
                            "image is {}x{} but the camera info says {w}x{h}",
                            d.width, d.height
                        )));
                    }
                    if clipped > 0 {
                        log::warn!(
                            "{}: topic {topic} message {}: {clipped} pixels beyond {:.2} m set to no data",
                            path.display(),
                            ordinal + 1,
                            scale * u16::MAX as f64
                        );
                    }
                    for &s in slots {
                        out_d[s] = Some(d.clone());
                    }
                }
            }
            if is_c {
                if let Some(slots) = want_c.get(&ordinal) {
                    let img = RosImage::decode(data).map_err(at)?;
                    let c = img.to_rgb().map_err(at)?;
                    for &s in slots {
                        out_c[s] = Some(c.clone());
                    }
                }
            }
            Ok(())
        })?;
        let missing = || {
            Error::format(
                &path,
                "a frame listed on the first pass was not found again",
            )
        };
        let d = out_d
            .into_iter()
            .map(|x| x.ok_or_else(missing))
            .collect::<Result<_>>()?;
        let c = out_c
            .into_iter()
            .map(|x| x.ok_or_else(missing))
            .collect::<Result<_>>()?;
        Ok((d, c))
    }
}

fn group(keys: &[u64]) -> HashMap<u64, Vec<usize>> {
    let mut m: HashMap<u64, Vec<usize>> = HashMap::new();
    for (i, &k) in keys.iter().enumerate() {
        m.entry(k).or_default().push(i);
    }
    m
}
