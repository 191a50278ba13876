//! Intel RealSense (cargo feature `realsense`): live capture from a connected camera with `realsense-rust`,
//! and import of recordings through librealsense's own playback.
//!
//! * [`Camera`] streams depth (Z16) and optionally colour (RGB8) through a librealsense pipeline and reads the
//!   camera's own intrinsics (`rs2_intrinsics` of the depth stream) and depth scale (the depth sensor's
//!   `Depth Units` option). Colour is stored as the colour sensor delivers it (not aligned to depth).
//! * [`PlaybackRecording`] plays a recording back (ROS2 `.db3` from librealsense ≥ 2.59, ROS1 `.bag` from
//!   older versions) sensor by sensor, not through a pipeline: a pipeline's frame syncer drops frames (in a
//!   test, the first depth frame of a recording), the sensors deliver every recorded frame. Each playback
//!   starts one sensor only (the playback begins reading when the first sensor starts, so frames of a sensor
//!   started after it would be lost) and runs as fast as the frames are handled (not in real time, so nothing
//!   is dropped). The recording is played once per sensor to list the frames and their timestamps, and once
//!   per sensor again to copy the frames chosen by the pose matching.
//!
//! Timestamps are librealsense's frame timestamps converted from milliseconds to seconds.

use super::{FrameStamp, Recording, RecordingInfo, StreamFrames};
use crate::camera::RgbImage;
use crate::camera::{DepthImage, DistortionModel, Intrinsics};
use crate::error::{Error, Result};
use realsense_sys as sys;
use std::collections::{HashMap, HashSet};
use std::ffi::{c_void, CStr, CString};
use std::path::Path;
use std::ptr::NonNull;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The librealsense model of `rs2_intrinsics` as depthcal's model.
fn model_from_rs2(model: sys::rs2_distortion) -> std::result::Result<DistortionModel, String> {
    #[allow(non_upper_case_globals)]
    match model {
        sys::rs2_distortion_RS2_DISTORTION_NONE => Ok(DistortionModel::None),
        sys::rs2_distortion_RS2_DISTORTION_BROWN_CONRADY => Ok(DistortionModel::BrownConrady),
        sys::rs2_distortion_RS2_DISTORTION_INVERSE_BROWN_CONRADY => {
            Ok(DistortionModel::InverseBrownConrady)
        }
        sys::rs2_distortion_RS2_DISTORTION_KANNALA_BRANDT4 => Ok(DistortionModel::KannalaBrandt4),
        sys::rs2_distortion_RS2_DISTORTION_MODIFIED_BROWN_CONRADY => Err(
            "distortion model modified Brown-Conrady (a forward-only model) is not supported for depth".into(),
        ),
        sys::rs2_distortion_RS2_DISTORTION_FTHETA => {
            Err("distortion model F-Theta fisheye is not supported".into())
        }
        other => Err(format!("unknown librealsense distortion model {other}")),
    }
}

/// depthcal intrinsics of librealsense's `rs2_intrinsics` with the depth scale in metres per unit.
pub fn intrinsics_from_rs2(
    i: &sys::rs2_intrinsics,
    depth_scale: f64,
) -> std::result::Result<Intrinsics, String> {
    let model = model_from_rs2(i.model)?;
    if i.width <= 0 || i.height <= 0 {
        return Err(format!("image size {}x{}", i.width, i.height));
    }
    let intr = Intrinsics {
        fx: i.fx as f64,
        fy: i.fy as f64,
        ppx: i.ppx as f64,
        ppy: i.ppy as f64,
        coeffs: i.coeffs.map(|c| c as f64),
        model,
        width: i.width as u32,
        height: i.height as u32,
        depth_scale,
        rms: None,
    };
    intr.validate()?;
    Ok(intr)
}

// ---------------------------------------------------------------------------------------------------------
// Live capture (realsense-rust).

/// Settings of live capture.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CaptureConfig {
    /// The camera's serial number (default: the only camera connected; several is an error).
    pub serial: Option<String>,
    /// Depth (and colour) width, pixels (default 848, the D400 depth optimum).
    pub width: u32,
    /// Height, pixels (default 480).
    pub height: u32,
    /// Frames per second (default 30).
    pub fps: u32,
    /// Stream colour too (default false).
    pub color: bool,
    /// Frames dropped after the stream starts, so that auto-exposure settles (default 30).
    pub warmup_frames: usize,
    /// Frames dropped before each frame taken, so that the frame is from after the robot stopped (default 5).
    pub settle_frames: usize,
    /// How long to wait for one frame, seconds (default 5).
    pub timeout_s: f64,
}

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            serial: None,
            width: 848,
            height: 480,
            fps: 30,
            color: false,
            warmup_frames: 30,
            settle_frames: 5,
            timeout_s: 5.0,
        }
    }
}

impl CaptureConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        check::at_least("width", self.width as usize, 1)?;
        check::at_least("height", self.height as usize, 1)?;
        check::at_least("fps", self.fps as usize, 1)?;
        check::positive("timeout_s", self.timeout_s)?;
        if self.serial.as_deref().is_some_and(|s| s.trim().is_empty()) {
            return Err(Error::config(
                "serial",
                "must be a serial number, got an empty string",
            ));
        }
        Ok(())
    }
}

/// A frame taken from a live camera.
#[derive(Clone, Debug)]
pub struct LiveFrame {
    /// The depth image (units of the camera's depth scale).
    pub depth: DepthImage,
    /// The colour image, when colour is streamed.
    pub color: Option<RgbImage>,
    /// librealsense's timestamp, seconds.
    pub t_s: f64,
    /// librealsense's frame number of the depth frame.
    pub frame_number: u64,
}

/// A connected RealSense camera streaming depth (and colour).
pub struct Camera {
    pipeline: realsense_rust::pipeline::ActivePipeline,
    intrinsics: Intrinsics,
    cfg: CaptureConfig,
    /// The camera's name (e.g. `Intel RealSense D435`).
    pub name: String,
    /// The camera's serial number.
    pub serial: String,
}

fn rs_err(what: &str, e: impl std::fmt::Display) -> Error {
    Error::Failed(format!("librealsense: {what}: {e}"))
}

/// Name and serial number of every RealSense device librealsense finds.
pub fn list_devices() -> Result<Vec<(String, String)>> {
    use realsense_rust::{context::Context, kind::Rs2CameraInfo};
    let ctx = Context::new().map_err(|e| rs_err("cannot create a context", e))?;
    let info = |d: &realsense_rust::device::Device, k| {
        d.info(k)
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    Ok(ctx
        .query_devices(HashSet::new())
        .iter()
        .map(|d| {
            (
                info(d, Rs2CameraInfo::Name),
                info(d, Rs2CameraInfo::SerialNumber),
            )
        })
        .collect())
}

/// librealsense's version as `major.minor.patch`.
pub fn librealsense_version() -> String {
    let mut err = std::ptr::null_mut();
    // SAFETY: a plain query; the error, if any, is freed.
    let v = unsafe { sys::rs2_get_api_version(&mut err) };
    if !err.is_null() {
        // SAFETY: err came from librealsense.
        unsafe { sys::rs2_free_error(err) };
        return "unknown".into();
    }
    format!("{}.{}.{}", v / 10000, (v / 100) % 100, v % 100)
}

impl Camera {
    /// Opens the camera of `cfg.serial` (or the only one connected) and starts streaming. With no camera
    /// connected the error says what was looked for.
    pub fn open(cfg: &CaptureConfig) -> Result<Self> {
        cfg.validate()?;
        use realsense_rust::{
            config::Config,
            context::Context,
            kind::{Rs2CameraInfo, Rs2Format, Rs2Option, Rs2StreamKind},
            pipeline::InactivePipeline,
        };
        let devices = list_devices()?;
        let looked_for = match &cfg.serial {
            Some(s) => format!("a RealSense camera with serial number {s}"),
            None => "a RealSense camera".to_string(),
        };
        if devices.is_empty() {
            return Err(Error::Failed(format!(
                "no RealSense camera found: librealsense {} enumerated no device while looking for {looked_for} \
                 (USB). Check the cable (USB 3), that `rs-enumerate-devices` lists the camera, and the udev rules \
                 (99-realsense-libusb.rules) or run as root",
                librealsense_version()
            )));
        }
        let serial = match &cfg.serial {
            Some(s) => {
                if !devices.iter().any(|(_, n)| n == s) {
                    return Err(Error::Failed(format!(
                        "no RealSense camera with serial number {s}; connected: {devices:?}"
                    )));
                }
                s.clone()
            }
            None if devices.len() > 1 => {
                return Err(Error::InvalidInput(format!(
                    "{} RealSense cameras are connected ({devices:?}); choose one with its serial number",
                    devices.len()
                )))
            }
            None => devices[0].1.clone(),
        };
        let ctx = Context::new().map_err(|e| rs_err("cannot create a context", e))?;
        let mut config = Config::new();
        let c_serial = CString::new(serial.clone())
            .map_err(|_| Error::InvalidInput(format!("serial number {serial:?}")))?;
        config
            .enable_device_from_serial(&c_serial)
            .map_err(|e| rs_err("cannot select the camera", e))?;
        let (w, h, fps) = (cfg.width as usize, cfg.height as usize, cfg.fps as usize);
        config
            .enable_stream(Rs2StreamKind::Depth, None, w, h, Rs2Format::Z16, fps)
            .map_err(|e| rs_err("cannot enable the depth stream", e))?;
        if cfg.color {
            config
                .enable_stream(Rs2StreamKind::Color, None, w, h, Rs2Format::Rgb8, fps)
                .map_err(|e| rs_err("cannot enable the colour stream", e))?;
        }
        let pipeline =
            InactivePipeline::try_from(&ctx).map_err(|e| rs_err("cannot make a pipeline", e))?;
        let pipeline = pipeline.start(Some(config)).map_err(|e| {
            rs_err(
                &format!(
                    "cannot start depth{} at {w}x{h} @ {fps} fps on camera {serial}",
                    if cfg.color { " + colour RGB8" } else { " Z16" }
                ),
                e,
            )
        })?;
        let profile = pipeline.profile();
        let depth_profile = profile
            .streams()
            .iter()
            .find(|s| s.kind() == Rs2StreamKind::Depth)
            .ok_or_else(|| Error::Failed("the started pipeline has no depth stream".into()))?;
        let rs_intr = depth_profile
            .intrinsics()
            .map_err(|e| rs_err("cannot read the depth stream's intrinsics", e))?;
        let depth_units = profile
            .device()
            .sensors()
            .iter()
            .find_map(|s| s.get_option(Rs2Option::DepthUnits))
            .ok_or_else(|| {
                Error::Failed("no sensor of the camera reports the Depth Units option".into())
            })?;
        let intrinsics = intrinsics_from_rs2(&rs_intr.0, depth_units as f64)
            .map_err(|m| Error::Failed(format!("camera {serial}: depth stream intrinsics: {m}")))?;
        let name = profile
            .device()
            .info(Rs2CameraInfo::Name)
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut cam = Camera {
            pipeline,
            intrinsics,
            cfg: cfg.clone(),
            name,
            serial,
        };
        for _ in 0..cfg.warmup_frames {
            cam.wait()?;
        }
        Ok(cam)
    }

    /// The depth stream's intrinsics with the camera's depth scale.
    pub fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    fn wait(&mut self) -> Result<realsense_rust::frame::CompositeFrame> {
        let t = Duration::from_secs_f64(self.cfg.timeout_s.max(0.01));
        self.pipeline.wait(Some(t)).map_err(|e| {
            rs_err(
                &format!(
                    "no frame from camera {} within {:.1} s",
                    self.serial, self.cfg.timeout_s
                ),
                e,
            )
        })
    }

    /// Takes one frame: drops `settle_frames` frames, then copies the next depth (and colour) frame.
    pub fn grab(&mut self) -> Result<LiveFrame> {
        use realsense_rust::frame::{ColorFrame, DepthFrame, FrameEx};
        for _ in 0..self.cfg.settle_frames {
            self.wait()?;
        }
        let start = Instant::now();
        loop {
            let frames = self.wait()?;
            let depth = frames.frames_of_type::<DepthFrame>();
            let color = frames.frames_of_type::<ColorFrame>();
            let (Some(d), c) = (depth.first(), color.first()) else {
                if start.elapsed().as_secs_f64() > self.cfg.timeout_s {
                    return Err(Error::Failed(format!(
                        "camera {}: no depth frame within {:.1} s",
                        self.serial, self.cfg.timeout_s
                    )));
                }
                continue;
            };
            if self.cfg.color && c.is_none() {
                continue;
            }
            // SAFETY: get_data points at get_data_size bytes of the frame, which lives as long as `d`.
            let bytes = unsafe {
                std::slice::from_raw_parts(
                    d.get_data() as *const c_void as *const u8,
                    d.get_data_size(),
                )
            };
            let depth = copy_z16(bytes, d.width(), d.height(), d.stride())
                .map_err(|m| Error::Failed(format!("camera {}: depth frame: {m}", self.serial)))?;
            let color = match c {
                Some(c) if self.cfg.color => {
                    // SAFETY: as above.
                    let bytes = unsafe {
                        std::slice::from_raw_parts(
                            c.get_data() as *const c_void as *const u8,
                            c.get_data_size(),
                        )
                    };
                    Some(
                        copy_rgb(bytes, c.width(), c.height(), c.stride(), 3, [0, 1, 2]).map_err(
                            |m| Error::Failed(format!("camera {}: colour frame: {m}", self.serial)),
                        )?,
                    )
                }
                _ => None,
            };
            return Ok(LiveFrame {
                depth,
                color,
                t_s: d.timestamp() * 1e-3,
                frame_number: d.frame_number(),
            });
        }
    }
}

fn copy_z16(
    bytes: &[u8],
    w: usize,
    h: usize,
    stride: usize,
) -> std::result::Result<DepthImage, String> {
    if w == 0 || h == 0 || stride < 2 * w || bytes.len() < stride * (h - 1) + 2 * w {
        return Err(format!(
            "{w}x{h} Z16 with stride {stride} does not fit in {} bytes",
            bytes.len()
        ));
    }
    let mut data = Vec::with_capacity(w * h);
    for v in 0..h {
        let row = &bytes[v * stride..v * stride + 2 * w];
        data.extend(
            row.chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]])),
        );
    }
    Ok(DepthImage {
        width: w as u32,
        height: h as u32,
        data,
    })
}

fn copy_rgb(
    bytes: &[u8],
    w: usize,
    h: usize,
    stride: usize,
    bpp: usize,
    order: [usize; 3],
) -> std::result::Result<RgbImage, String> {
    if w == 0 || h == 0 || stride < bpp * w || bytes.len() < stride * (h - 1) + bpp * w {
        return Err(format!(
            "{w}x{h} colour with {bpp} bytes per pixel and stride {stride} does not fit in {} bytes",
            bytes.len()
        ));
    }
    let mut data = Vec::with_capacity(w * h * 3);
    for v in 0..h {
        let row = &bytes[v * stride..v * stride + bpp * w];
        for p in row.chunks_exact(bpp) {
            data.extend(order.iter().map(|&i| p[i]));
        }
    }
    Ok(RgbImage {
        width: w as u32,
        height: h as u32,
        data,
    })
}

// ---------------------------------------------------------------------------------------------------------
// Playback (realsense-sys): owned handles that free themselves.

fn check(err: *mut sys::rs2_error, what: &str) -> std::result::Result<(), String> {
    if err.is_null() {
        return Ok(());
    }
    // SAFETY: err is a librealsense error; its message is a C string valid until the error is freed.
    let msg = unsafe {
        let m = sys::rs2_get_error_message(err);
        let s = if m.is_null() {
            "unknown error".to_string()
        } else {
            CStr::from_ptr(m).to_string_lossy().into_owned()
        };
        sys::rs2_free_error(err);
        s
    };
    Err(format!("{what}: {msg}"))
}

macro_rules! call {
    ($what:expr, $f:ident ( $($arg:expr),* )) => {{
        let mut err = std::ptr::null_mut();
        // SAFETY: every pointer passed is a live librealsense handle owned by this module.
        let r = unsafe { sys::$f($($arg,)* &mut err) };
        check(err, $what).map(|_| r)
    }};
}

macro_rules! handle {
    ($name:ident, $raw:ty, $free:ident) => {
        struct $name(NonNull<$raw>);
        impl Drop for $name {
            fn drop(&mut self) {
                // SAFETY: the handle is owned and freed once.
                unsafe { sys::$free(self.0.as_ptr()) }
            }
        }
        impl $name {
            fn new(p: *mut $raw, what: &str) -> std::result::Result<Self, String> {
                NonNull::new(p)
                    .map($name)
                    .ok_or_else(|| format!("{what}: null handle"))
            }
        }
    };
}

handle!(Ctx, sys::rs2_context, rs2_delete_context);
handle!(Dev, sys::rs2_device, rs2_delete_device);
handle!(SensorList, sys::rs2_sensor_list, rs2_delete_sensor_list);
handle!(Sensor, sys::rs2_sensor, rs2_delete_sensor);
handle!(
    ProfileList,
    sys::rs2_stream_profile_list,
    rs2_delete_stream_profiles_list
);

/// A stream of a sensor of the playback device.
struct StreamChoice {
    sensor: usize,
    profile_index: i32,
    uid: i32,
    format: sys::rs2_format,
    name: String,
}

/// What one playback pass collects from the frame callback.
#[derive(Default)]
struct Collector {
    /// The uids of the depth and colour streams of the playback running (uids differ between playbacks).
    depth_uid: Option<i32>,
    color_uid: Option<i32>,
    color_format: sys::rs2_format,
    /// Every depth and colour frame seen: (frame number, timestamp ms).
    seen_depth: Vec<(u64, f64)>,
    seen_color: Vec<(u64, f64)>,
    /// Frame numbers of the depth and colour frames to copy.
    want_depth: HashSet<u64>,
    want_color: HashSet<u64>,
    depth: HashMap<u64, DepthImage>,
    color: HashMap<u64, RgbImage>,
    error: Option<String>,
}

unsafe extern "C" fn on_frame(frame: *mut sys::rs2_frame, user: *mut c_void) {
    if frame.is_null() || user.is_null() {
        return;
    }
    let result = std::panic::catch_unwind(|| {
        // SAFETY: `user` is the &Mutex<Collector> that outlives the playback (see `play`).
        let collector = unsafe { &*(user as *const Mutex<Collector>) };
        let Ok(mut c) = collector.lock() else { return };
        if let Err(m) = collect(frame, &mut c) {
            c.error.get_or_insert(m);
        }
    });
    // SAFETY: the callback owns the frame and releases it once.
    unsafe { sys::rs2_release_frame(frame) };
    let _ = result;
}

/// The fields of a stream profile.
struct ProfileData {
    stream: sys::rs2_stream,
    format: sys::rs2_format,
    index: i32,
    uid: i32,
    fps: i32,
}

fn profile_data(p: *const sys::rs2_stream_profile) -> std::result::Result<ProfileData, String> {
    let (mut stream, mut format, mut index, mut uid, mut fps) = (0, 0, 0, 0, 0);
    call!(
        "stream profile data",
        rs2_get_stream_profile_data(p, &mut stream, &mut format, &mut index, &mut uid, &mut fps)
    )?;
    Ok(ProfileData {
        stream,
        format,
        index,
        uid,
        fps,
    })
}

fn collect(frame: *mut sys::rs2_frame, c: &mut Collector) -> std::result::Result<(), String> {
    let profile = call!("frame profile", rs2_get_frame_stream_profile(frame))?;
    let ProfileData { uid, .. } = profile_data(profile)?;
    let is_depth = Some(uid) == c.depth_uid;
    let is_color = Some(uid) == c.color_uid;
    if !is_depth && !is_color {
        return Ok(());
    }
    let number = call!("frame number", rs2_get_frame_number(frame))? as u64;
    let t_ms = call!("frame timestamp", rs2_get_frame_timestamp(frame))?;
    if is_depth {
        c.seen_depth.push((number, t_ms));
    } else {
        c.seen_color.push((number, t_ms));
    }
    let wanted = if is_depth {
        c.want_depth.contains(&number)
    } else {
        c.want_color.contains(&number)
    };
    if !wanted {
        return Ok(());
    }
    let w = call!("frame width", rs2_get_frame_width(frame))?.max(0) as usize;
    let h = call!("frame height", rs2_get_frame_height(frame))?.max(0) as usize;
    let stride = call!("frame stride", rs2_get_frame_stride_in_bytes(frame))?.max(0) as usize;
    let size = call!("frame size", rs2_get_frame_data_size(frame))?.max(0) as usize;
    let data = call!("frame data", rs2_get_frame_data(frame))?;
    if data.is_null() {
        return Err(format!("frame {number} has no data"));
    }
    // SAFETY: librealsense gives `size` bytes at `data`, alive while the frame is held.
    let bytes = unsafe { std::slice::from_raw_parts(data as *const u8, size) };
    if is_depth {
        let d = copy_z16(bytes, w, h, stride).map_err(|m| format!("depth frame {number}: {m}"))?;
        c.depth.insert(number, d);
    } else {
        #[allow(non_upper_case_globals)]
        let (bpp, order) = match c.color_format {
            sys::rs2_format_RS2_FORMAT_RGB8 => (3, [0, 1, 2]),
            sys::rs2_format_RS2_FORMAT_BGR8 => (3, [2, 1, 0]),
            sys::rs2_format_RS2_FORMAT_RGBA8 => (4, [0, 1, 2]),
            _ => (4, [2, 1, 0]),
        };
        let img = copy_rgb(bytes, w, h, stride, bpp, order)
            .map_err(|m| format!("colour frame {number}: {m}"))?;
        c.color.insert(number, img);
    }
    Ok(())
}

/// The device of a recording, opened for playback (not in real time).
struct Playback {
    // Field order is drop order: sensors and device before the context.
    sensors: Vec<Sensor>,
    _list: SensorList,
    dev: Dev,
    _ctx: Ctx,
}

impl Playback {
    fn open(path: &Path) -> std::result::Result<Self, String> {
        let c_path = CString::new(path.to_string_lossy().into_owned())
            .map_err(|_| "the path holds a NUL byte".to_string())?;
        let ctx = Ctx::new(
            call!(
                "create context",
                rs2_create_context(sys::RS2_API_VERSION as i32)
            )?,
            "context",
        )?;
        let dev = Dev::new(
            call!(
                "open the recording",
                rs2_context_add_device(ctx.0.as_ptr(), c_path.as_ptr())
            )?,
            "playback device",
        )?;
        call!(
            "set playback to as fast as possible",
            rs2_playback_device_set_real_time(dev.0.as_ptr(), 0)
        )?;
        let list = SensorList::new(
            call!("query sensors", rs2_query_sensors(dev.0.as_ptr()))?,
            "sensor list",
        )?;
        let n = call!("count sensors", rs2_get_sensors_count(list.0.as_ptr()))?;
        let mut sensors = Vec::with_capacity(n.max(0) as usize);
        for i in 0..n {
            sensors.push(Sensor::new(
                call!("get sensor", rs2_create_sensor(list.0.as_ptr(), i))?,
                "sensor",
            )?);
        }
        Ok(Playback {
            sensors,
            _list: list,
            dev,
            _ctx: ctx,
        })
    }

    fn profiles(&self, s: usize) -> std::result::Result<(ProfileList, i32), String> {
        let list = ProfileList::new(
            call!(
                "stream profiles",
                rs2_get_stream_profiles(self.sensors[s].0.as_ptr())
            )?,
            "profiles",
        )?;
        let n = call!(
            "count profiles",
            rs2_get_stream_profiles_count(list.0.as_ptr())
        )?;
        Ok((list, n))
    }

    /// The depth stream (Z16) and, with `color`, the colour stream.
    fn streams(
        &self,
        color: bool,
    ) -> std::result::Result<(StreamChoice, Option<StreamChoice>, Vec<String>), String> {
        let mut depth = None;
        let mut col = None;
        let mut all = Vec::new();
        for s in 0..self.sensors.len() {
            let (list, n) = self.profiles(s)?;
            for i in 0..n {
                let p = call!("profile", rs2_get_stream_profile(list.0.as_ptr(), i))?;
                let ProfileData {
                    stream,
                    format,
                    index,
                    uid,
                    fps,
                } = profile_data(p)?;
                let name = format!(
                    "{} {index} ({}, {fps} fps)",
                    stream_name(stream),
                    format_name(format)
                );
                all.push(name.clone());
                let choice = StreamChoice {
                    sensor: s,
                    profile_index: i,
                    uid,
                    format,
                    name,
                };
                if stream == sys::rs2_stream_RS2_STREAM_DEPTH
                    && format == sys::rs2_format_RS2_FORMAT_Z16
                    && depth.is_none()
                {
                    depth = Some(choice);
                } else if color
                    && stream == sys::rs2_stream_RS2_STREAM_COLOR
                    && col.is_none()
                    && [
                        sys::rs2_format_RS2_FORMAT_RGB8,
                        sys::rs2_format_RS2_FORMAT_BGR8,
                        sys::rs2_format_RS2_FORMAT_RGBA8,
                        sys::rs2_format_RS2_FORMAT_BGRA8,
                    ]
                    .contains(&format)
                {
                    col = Some(choice);
                }
            }
        }
        let depth = depth.ok_or_else(|| format!("no Z16 depth stream (streams: {all:?})"))?;
        if color && col.is_none() {
            return Err(format!(
                "no colour stream in RGB8, BGR8, RGBA8 or BGRA8 (streams: {all:?})"
            ));
        }
        Ok((depth, col, all))
    }

    fn intrinsics(&self, depth: &StreamChoice) -> std::result::Result<Intrinsics, String> {
        let (list, _) = self.profiles(depth.sensor)?;
        let p = call!(
            "profile",
            rs2_get_stream_profile(list.0.as_ptr(), depth.profile_index)
        )?;
        // SAFETY: rs2_intrinsics is plain data; zeroes are a valid value to be overwritten.
        let mut intr: sys::rs2_intrinsics = unsafe { std::mem::zeroed() };
        call!(
            "depth intrinsics",
            rs2_get_video_stream_intrinsics(p, &mut intr)
        )?;
        let sensor = self.sensors[depth.sensor].0.as_ptr() as *const sys::rs2_options;
        let supported = call!(
            "depth units",
            rs2_supports_option(sensor, sys::rs2_option_RS2_OPTION_DEPTH_UNITS)
        )?;
        if supported == 0 {
            return Err("the depth sensor has no Depth Units option".into());
        }
        let units = call!(
            "depth units",
            rs2_get_option(sensor, sys::rs2_option_RS2_OPTION_DEPTH_UNITS)
        )?;
        intrinsics_from_rs2(&intr, units as f64).map_err(|m| format!("depth intrinsics: {m}"))
    }

    /// Plays the whole recording once with the streams `choices` (all of one sensor) open, handing their frames
    /// to the collector. Only one sensor is started per playback: the playback starts reading when the first
    /// sensor starts, and frames of a sensor started later would be lost.
    fn play(
        &self,
        choices: &[&StreamChoice],
        collector: &Mutex<Collector>,
    ) -> std::result::Result<(), String> {
        let user = collector as *const Mutex<Collector> as *mut c_void;
        let sensor = choices[0].sensor;
        debug_assert!(choices.iter().all(|c| c.sensor == sensor));
        let s = self.sensors[sensor].0.as_ptr();
        let (list, _) = self.profiles(sensor)?;
        let mut profiles = Vec::with_capacity(choices.len());
        for ch in choices {
            profiles.push(call!(
                "profile",
                rs2_get_stream_profile(list.0.as_ptr(), ch.profile_index)
            )?);
        }
        if profiles.len() == 1 {
            call!("open sensor", rs2_open(s, profiles[0]))?;
        } else {
            call!(
                "open sensor",
                rs2_open_multiple(s, profiles.as_mut_ptr(), profiles.len() as i32)
            )?;
        }
        // Frames seen so far (earlier playbacks of other sensors included).
        let count = || {
            collector
                .lock()
                .map(|c| c.seen_depth.len() + c.seen_color.len())
                .unwrap_or(usize::MAX)
        };
        let before = count();
        let mut started = false;
        let mut result = (|| -> std::result::Result<(), String> {
            call!("start sensor", rs2_start(s, Some(on_frame), user))?;
            started = true;
            // Wait for the playback to finish.
            let begin = Instant::now();
            let mut playing_seen = false;
            loop {
                let st = call!(
                    "playback status",
                    rs2_playback_device_get_current_status(self.dev.0.as_ptr())
                )?;
                if st == sys::rs2_playback_status_RS2_PLAYBACK_STATUS_PLAYING {
                    playing_seen = true;
                }
                let any = count() > before;
                if st == sys::rs2_playback_status_RS2_PLAYBACK_STATUS_STOPPED
                    && (playing_seen || any || begin.elapsed() > Duration::from_secs(2))
                {
                    return Ok(());
                }
                if begin.elapsed() > Duration::from_secs(3600) {
                    return Err("playback did not finish within an hour".into());
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        })();
        let stop = if started {
            call!("stop sensor", rs2_stop(s))
        } else {
            Ok(())
        };
        let close = call!("close sensor", rs2_close(s));
        drop(list);
        result = result.and(stop).and(close);
        result
    }
}

fn stream_name(s: sys::rs2_stream) -> &'static str {
    #[allow(non_upper_case_globals)]
    match s {
        sys::rs2_stream_RS2_STREAM_DEPTH => "Depth",
        sys::rs2_stream_RS2_STREAM_COLOR => "Color",
        sys::rs2_stream_RS2_STREAM_INFRARED => "Infrared",
        _ => "stream",
    }
}

fn format_name(f: sys::rs2_format) -> String {
    #[allow(non_upper_case_globals)]
    match f {
        sys::rs2_format_RS2_FORMAT_Z16 => "Z16".into(),
        sys::rs2_format_RS2_FORMAT_RGB8 => "RGB8".into(),
        sys::rs2_format_RS2_FORMAT_BGR8 => "BGR8".into(),
        sys::rs2_format_RS2_FORMAT_RGBA8 => "RGBA8".into(),
        sys::rs2_format_RS2_FORMAT_BGRA8 => "BGRA8".into(),
        sys::rs2_format_RS2_FORMAT_YUYV => "YUYV".into(),
        other => format!("format {other}"),
    }
}

/// A RealSense recording (`.db3`, `.bag`) read through librealsense's playback.
pub struct PlaybackRecording {
    info: RecordingInfo,
    color_wanted: bool,
    /// Every stream the recording holds (for messages).
    pub streams: Vec<String>,
}

/// What one playback pass found.
struct Pass {
    intrinsics: Intrinsics,
    depth: StreamChoice,
    color: Option<StreamChoice>,
    streams: Vec<String>,
    collector: Collector,
}

impl PlaybackRecording {
    fn pass(
        path: &Path,
        color: bool,
        want_depth: HashSet<u64>,
        want_color: HashSet<u64>,
    ) -> std::result::Result<Pass, String> {
        let pb = Playback::open(path)?;
        let (d, c, all) = pb.streams(color)?;
        let intr = pb.intrinsics(&d)?;
        drop(pb);
        let collector = Mutex::new(Collector {
            color_format: c.as_ref().map(|c| c.format).unwrap_or(0),
            want_depth,
            want_color,
            ..Default::default()
        });
        // One playback per sensor (true = the depth stream, false = the colour stream).
        let groups: Vec<Vec<bool>> = match &c {
            Some(c) if c.sensor == d.sensor => vec![vec![true, false]],
            Some(_) => vec![vec![true], vec![false]],
            None => vec![vec![true]],
        };
        for group in groups {
            let pb = Playback::open(path)?;
            let (d2, c2, _) = pb.streams(color)?;
            let mut chosen: Vec<&StreamChoice> = Vec::with_capacity(group.len());
            for &is_depth in &group {
                chosen.push(if is_depth {
                    &d2
                } else {
                    c2.as_ref()
                        .ok_or("the colour stream is missing on another opening")?
                });
            }
            {
                let mut col = collector
                    .lock()
                    .map_err(|_| "the frame callback panicked".to_string())?;
                col.depth_uid = group.contains(&true).then_some(d2.uid);
                col.color_uid = if group.contains(&false) {
                    c2.as_ref().map(|c| c.uid)
                } else {
                    None
                };
            }
            pb.play(&chosen, &collector)?;
        }
        let collector = collector
            .into_inner()
            .map_err(|_| "the frame callback panicked".to_string())?;
        if let Some(e) = &collector.error {
            return Err(e.clone());
        }
        Ok(Pass {
            intrinsics: intr,
            depth: d,
            color: c,
            streams: all,
            collector,
        })
    }

    /// Opens a recording: reads the depth stream's intrinsics and depth scale and lists every depth (and,
    /// with `color`, colour) frame with its timestamp (one playback).
    pub fn open(path: impl AsRef<Path>, color: bool) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        if !path.is_file() {
            return Err(Error::io(
                &path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such recording"),
            ));
        }
        let at = |m: String| Error::format(&path, format!("librealsense playback: {m}"));
        let Pass {
            intrinsics,
            depth: d,
            color: c,
            streams,
            collector: col,
        } = Self::pass(&path, color, HashSet::new(), HashSet::new()).map_err(at)?;
        let list = |seen: &[(u64, f64)], name: &str| -> Result<StreamFrames> {
            let mut frames: Vec<FrameStamp> = seen
                .iter()
                .map(|s| FrameStamp {
                    t_s: s.1 * 1e-3,
                    key: s.0,
                })
                .collect();
            let mut keys = HashSet::new();
            if let Some(f) = frames.iter().find(|f| !keys.insert(f.key)) {
                return Err(at(format!(
                    "stream {name} repeats frame number {}; frames cannot be told apart",
                    f.key
                )));
            }
            frames.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
            Ok(StreamFrames {
                name: name.to_string(),
                frames,
            })
        };
        let depth = list(&col.seen_depth, &d.name)?;
        let color = c
            .as_ref()
            .map(|c| list(&col.seen_color, &c.name))
            .transpose()?;
        Ok(PlaybackRecording {
            color_wanted: color.is_some(),
            info: RecordingInfo {
                path,
                intrinsics,
                depth,
                color,
            },
            streams,
        })
    }
}

impl Recording for PlaybackRecording {
    fn info(&self) -> &RecordingInfo {
        &self.info
    }

    fn read_frames(
        &mut self,
        depth: &[u64],
        color: &[u64],
    ) -> Result<(Vec<DepthImage>, Vec<RgbImage>)> {
        let path = &self.info.path;
        let at = |m: String| Error::format(path, format!("librealsense playback: {m}"));
        let got = Self::pass(
            path,
            self.color_wanted,
            depth.iter().copied().collect(),
            color.iter().copied().collect(),
        )
        .map_err(at)?
        .collector;
        let missing = |what: &str, k: u64| {
            at(format!(
                "{what} frame number {k} was listed on the first playback but not delivered on the second"
            ))
        };
        let d = depth
            .iter()
            .map(|k| {
                got.depth
                    .get(k)
                    .cloned()
                    .ok_or_else(|| missing("depth", *k))
            })
            .collect::<Result<Vec<_>>>()?;
        let c = color
            .iter()
            .map(|k| {
                got.color
                    .get(k)
                    .cloned()
                    .ok_or_else(|| missing("colour", *k))
            })
            .collect::<Result<Vec<_>>>()?;
        Ok((d, c))
    }
}
