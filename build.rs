//! Build script. With the `realsense` feature on Linux, the executables are linked with
//! `-Wl,--exclude-libs,ALL`: the C libraries linked statically into them (LZ4 and bzip2 of the `rosbag` crate)
//! then stay out of their dynamic symbol tables. Otherwise the executable's LZ4 (1.10) interposes on the LZ4
//! copy that librealsense carries inside itself under the same names, and librealsense's playback of
//! LZ4-compressed `.bag` recordings fails ("ROSLZ4_DATA_ERROR: malformed data to decompress", measured with
//! librealsense 2.59.1).

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let realsense = std::env::var_os("CARGO_FEATURE_REALSENSE").is_some();
    let linux = std::env::var("CARGO_CFG_TARGET_OS").is_ok_and(|os| os == "linux");
    if realsense && linux {
        println!("cargo:rustc-link-arg=-Wl,--exclude-libs,ALL");
    }
}
