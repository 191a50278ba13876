//! Square fiducial marker families: OpenCV's ArUco dictionaries and the AprilTag families OpenCV also
//! predefines. Only the names and sizes live here (no OpenCV needed), so cell manifests and the simulator
//! can name a dictionary in any build; detection and the bit tables are in `vision::markers` (cargo
//! feature `vision`).
//!
//! Names are parsed case-insensitively (`-` may stand for `_`):
//!
//! | dictionary | accepted names | [`Display`](std::fmt::Display) |
//! | --- | --- | --- |
//! | ArUco `N×N` (N = 4…7), 50/100/250/1000 markers | `DICT_4X4_50`, `4x4_50`, ... | `DICT_4X4_50` |
//! | original ArUco (5×5, 1024 markers) | `DICT_ARUCO_ORIGINAL`, `aruco_original` | `DICT_ARUCO_ORIGINAL` |
//! | AprilTag 16h5, 25h9, 36h10, 36h11 | `tag36h11`, `36h11`, `apriltag_36h11`, `DICT_APRILTAG_36h11` | `tag36h11` |
//!
//! In every family the printed marker is a black square of `bits() + 2` cells per side: a one-cell black
//! border around `bits() × bits()` data cells (an AprilTag print adds a white cell outside the black
//! border; it is not part of the marker's side length).
//!
//! The marker frame and the bit tables follow OpenCV's `drawMarker` (`vision::markers`,
//! `vision::dictionary_bits`). For the AprilTag families OpenCV draws each tag turned by a half turn
//! relative to AprilTag's own images (the official tag PNGs): whoever renders AprilTag's tables must turn
//! them to match.

use crate::error::{Error, Result};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;
use std::str::FromStr;

/// A square fiducial marker dictionary (family): which bit patterns are markers, and their ids.
#[allow(non_camel_case_types)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum MarkerDictionary {
    /// ArUco 4×4, ids 0–49 (OpenCV `DICT_4X4_50`).
    Aruco4x4_50,
    /// ArUco 4×4, ids 0–99 (OpenCV `DICT_4X4_100`).
    Aruco4x4_100,
    /// ArUco 4×4, ids 0–249 (OpenCV `DICT_4X4_250`).
    Aruco4x4_250,
    /// ArUco 4×4, ids 0–999 (OpenCV `DICT_4X4_1000`).
    Aruco4x4_1000,
    /// ArUco 5×5, ids 0–49 (OpenCV `DICT_5X5_50`).
    Aruco5x5_50,
    /// ArUco 5×5, ids 0–99 (OpenCV `DICT_5X5_100`).
    Aruco5x5_100,
    /// ArUco 5×5, ids 0–249 (OpenCV `DICT_5X5_250`).
    Aruco5x5_250,
    /// ArUco 5×5, ids 0–999 (OpenCV `DICT_5X5_1000`).
    Aruco5x5_1000,
    /// ArUco 6×6, ids 0–49 (OpenCV `DICT_6X6_50`).
    Aruco6x6_50,
    /// ArUco 6×6, ids 0–99 (OpenCV `DICT_6X6_100`).
    Aruco6x6_100,
    /// ArUco 6×6, ids 0–249 (OpenCV `DICT_6X6_250`).
    Aruco6x6_250,
    /// ArUco 6×6, ids 0–999 (OpenCV `DICT_6X6_1000`).
    Aruco6x6_1000,
    /// ArUco 7×7, ids 0–49 (OpenCV `DICT_7X7_50`).
    Aruco7x7_50,
    /// ArUco 7×7, ids 0–99 (OpenCV `DICT_7X7_100`).
    Aruco7x7_100,
    /// ArUco 7×7, ids 0–249 (OpenCV `DICT_7X7_250`).
    Aruco7x7_250,
    /// ArUco 7×7, ids 0–999 (OpenCV `DICT_7X7_1000`).
    Aruco7x7_1000,
    /// The original ArUco library's 5×5 dictionary, ids 0–1023 (OpenCV `DICT_ARUCO_ORIGINAL`).
    ArucoOriginal,
    /// AprilTag 16h5 (4×4 bits), ids 0–29 (OpenCV `DICT_APRILTAG_16h5`).
    AprilTag16h5,
    /// AprilTag 25h9 (5×5 bits), ids 0–34 (OpenCV `DICT_APRILTAG_25h9`).
    AprilTag25h9,
    /// AprilTag 36h10 (6×6 bits), ids 0–2319 (OpenCV `DICT_APRILTAG_36h10`).
    AprilTag36h10,
    /// AprilTag 36h11 (6×6 bits), ids 0–586 (OpenCV `DICT_APRILTAG_36h11`): the usual AprilTag family.
    AprilTag36h11,
}

use MarkerDictionary as D;

/// `(dictionary, canonical name, bits per side, marker count)`, in OpenCV's
/// `PREDEFINED_DICTIONARY_NAME` order.
const TABLE: [(MarkerDictionary, &str, u32, u32); 21] = [
    (D::Aruco4x4_50, "DICT_4X4_50", 4, 50),
    (D::Aruco4x4_100, "DICT_4X4_100", 4, 100),
    (D::Aruco4x4_250, "DICT_4X4_250", 4, 250),
    (D::Aruco4x4_1000, "DICT_4X4_1000", 4, 1000),
    (D::Aruco5x5_50, "DICT_5X5_50", 5, 50),
    (D::Aruco5x5_100, "DICT_5X5_100", 5, 100),
    (D::Aruco5x5_250, "DICT_5X5_250", 5, 250),
    (D::Aruco5x5_1000, "DICT_5X5_1000", 5, 1000),
    (D::Aruco6x6_50, "DICT_6X6_50", 6, 50),
    (D::Aruco6x6_100, "DICT_6X6_100", 6, 100),
    (D::Aruco6x6_250, "DICT_6X6_250", 6, 250),
    (D::Aruco6x6_1000, "DICT_6X6_1000", 6, 1000),
    (D::Aruco7x7_50, "DICT_7X7_50", 7, 50),
    (D::Aruco7x7_100, "DICT_7X7_100", 7, 100),
    (D::Aruco7x7_250, "DICT_7X7_250", 7, 250),
    (D::Aruco7x7_1000, "DICT_7X7_1000", 7, 1000),
    (D::ArucoOriginal, "DICT_ARUCO_ORIGINAL", 5, 1024),
    (D::AprilTag16h5, "tag16h5", 4, 30),
    (D::AprilTag25h9, "tag25h9", 5, 35),
    (D::AprilTag36h10, "tag36h10", 6, 2320),
    (D::AprilTag36h11, "tag36h11", 6, 587),
];

impl MarkerDictionary {
    /// Every dictionary, in OpenCV's `PREDEFINED_DICTIONARY_NAME` order.
    pub const ALL: [MarkerDictionary; 21] = {
        let mut all = [D::Aruco4x4_50; 21];
        let mut i = 0;
        while i < 21 {
            all[i] = TABLE[i].0;
            i += 1;
        }
        all
    };

    fn entry(self) -> &'static (MarkerDictionary, &'static str, u32, u32) {
        &TABLE[self as usize]
    }

    /// Data bits per side of the marker (inside the one-cell black border): 4 for `4x4_*` and tag16h5,
    /// 5 for `5x5_*`, the original ArUco and tag25h9, 6 for `6x6_*`, tag36h10 and tag36h11, 7 for `7x7_*`.
    pub fn bits(self) -> u32 {
        self.entry().2
    }

    /// Number of markers: ids run from 0 to `marker_count() − 1`.
    pub fn marker_count(self) -> u32 {
        self.entry().3
    }

    /// True for the AprilTag families (which AprilTag's own detector also reads).
    pub fn is_apriltag(self) -> bool {
        matches!(
            self,
            D::AprilTag16h5 | D::AprilTag25h9 | D::AprilTag36h10 | D::AprilTag36h11
        )
    }

    /// The name of OpenCV's predefined dictionary, e.g. `DICT_6X6_250` or `DICT_APRILTAG_36h11`.
    pub fn opencv_name(self) -> String {
        if self.is_apriltag() {
            format!("DICT_APRILTAG_{}", &self.entry().1[3..])
        } else {
            self.entry().1.to_string()
        }
    }

    /// The index of OpenCV's predefined dictionary (`cv::aruco::PREDEFINED_DICTIONARY_NAME`, 0–20).
    pub fn opencv_index(self) -> i32 {
        self as i32
    }

    /// The accepted names, for error messages.
    fn accepted_names() -> String {
        let aruco: Vec<&str> = TABLE
            .iter()
            .filter(|e| !e.0.is_apriltag())
            .map(|e| e.1)
            .collect();
        format!(
            "{} (or without DICT_, e.g. 4x4_50, aruco_original), tag16h5, tag25h9, tag36h10, tag36h11 \
             (or 36h11, apriltag_36h11, DICT_APRILTAG_36h11); case does not matter",
            aruco.join(", ")
        )
    }
}

impl fmt::Display for MarkerDictionary {
    /// The canonical name: OpenCV's (`DICT_4X4_50`, `DICT_ARUCO_ORIGINAL`) for the ArUco dictionaries,
    /// AprilTag's (`tag36h11`) for the AprilTag families.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.entry().1)
    }
}

impl FromStr for MarkerDictionary {
    type Err = Error;

    /// Parses any accepted name (see the module documentation), case-insensitively.
    fn from_str(s: &str) -> Result<Self> {
        let n = s.trim().to_ascii_lowercase().replace('-', "_");
        let n = n.strip_prefix("dict_").unwrap_or(&n);
        let april = n
            .strip_prefix("apriltag_")
            .or_else(|| n.strip_prefix("apriltag"))
            .unwrap_or(n);
        let april = april.strip_prefix("tag").unwrap_or(april);
        let found = TABLE.iter().find(|e| {
            let canon = e.1.to_ascii_lowercase();
            if e.0.is_apriltag() {
                april == &canon[3..]
            } else {
                n == canon.strip_prefix("dict_").unwrap_or(&canon)
            }
        });
        found.map(|e| e.0).ok_or_else(|| {
            Error::InvalidInput(format!(
                "unknown marker dictionary {s:?}: expected one of {}",
                MarkerDictionary::accepted_names()
            ))
        })
    }
}

impl Serialize for MarkerDictionary {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.entry().1)
    }
}

impl<'de> Deserialize<'de> for MarkerDictionary {
    fn deserialize<De: Deserializer<'de>>(d: De) -> std::result::Result<Self, De::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_in_every_accepted_spelling() {
        for (s, d) in [
            ("DICT_4X4_50", D::Aruco4x4_50),
            ("4x4_50", D::Aruco4x4_50),
            ("dict_5x5_100", D::Aruco5x5_100),
            ("DICT_5X5_100", D::Aruco5x5_100),
            ("6x6_250", D::Aruco6x6_250),
            ("7X7-1000", D::Aruco7x7_1000),
            ("DICT_ARUCO_ORIGINAL", D::ArucoOriginal),
            ("aruco_original", D::ArucoOriginal),
            ("tag36h11", D::AprilTag36h11),
            ("36h11", D::AprilTag36h11),
            ("apriltag_36h11", D::AprilTag36h11),
            ("DICT_APRILTAG_36h11", D::AprilTag36h11),
            ("DICT_APRILTAG_36H11", D::AprilTag36h11),
            (" Tag25h9 ", D::AprilTag25h9),
            ("tag16h5", D::AprilTag16h5),
            ("tag36h10", D::AprilTag36h10),
        ] {
            assert_eq!(s.parse::<MarkerDictionary>().unwrap(), d, "{s}");
        }
        for d in MarkerDictionary::ALL {
            assert_eq!(d.to_string().parse::<MarkerDictionary>().unwrap(), d);
            assert_eq!(d.opencv_name().parse::<MarkerDictionary>().unwrap(), d);
        }
        for bad in [
            "", "4x4", "4x4_51", "8x8_50", "tag36h12", "36h11x", "dict_", "aruco",
        ] {
            let e = bad.parse::<MarkerDictionary>().unwrap_err().to_string();
            assert!(
                e.contains("DICT_4X4_50")
                    && e.contains("tag36h11")
                    && e.contains(&format!("{bad:?}")),
                "{e}"
            );
        }
    }

    #[test]
    fn sizes_and_opencv_names() {
        assert_eq!(MarkerDictionary::ALL.len(), 21);
        for (i, d) in MarkerDictionary::ALL.iter().enumerate() {
            assert_eq!(d.opencv_index(), i as i32);
        }
        assert_eq!(D::AprilTag36h11.bits(), 6);
        assert_eq!(D::AprilTag36h11.marker_count(), 587);
        assert_eq!(D::AprilTag36h11.opencv_name(), "DICT_APRILTAG_36h11");
        assert_eq!(D::AprilTag16h5.bits(), 4);
        assert_eq!(D::ArucoOriginal.bits(), 5);
        assert_eq!(D::ArucoOriginal.marker_count(), 1024);
        assert_eq!(D::Aruco7x7_250.bits(), 7);
        assert_eq!(D::Aruco7x7_250.opencv_name(), "DICT_7X7_250");
        assert!(D::AprilTag25h9.is_apriltag() && !D::ArucoOriginal.is_apriltag());
    }

    #[test]
    fn serde_uses_the_name() {
        #[derive(Serialize, Deserialize, PartialEq, Debug)]
        struct T {
            dict: MarkerDictionary,
        }
        let t: T = toml::from_str("dict = \"36h11\"").unwrap();
        assert_eq!(t.dict, D::AprilTag36h11);
        assert_eq!(toml::to_string(&t).unwrap().trim(), "dict = \"tag36h11\"");
        let j = serde_json::to_string(&D::Aruco4x4_50).unwrap();
        assert_eq!(j, "\"DICT_4X4_50\"");
        let e = serde_json::from_str::<MarkerDictionary>("\"5x5\"").unwrap_err();
        assert!(e.to_string().contains("unknown marker dictionary"), "{e}");
    }
}
