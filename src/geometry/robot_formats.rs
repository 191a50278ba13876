//! The calibrated `T_base1_base2` in the formats robot controllers and ROS read: a ROS 2 launch file
//! (`tf2_ros static_transform_publisher`), a URDF / xacro fixed joint, a TF YAML file, a KUKA FRAME,
//! a Universal Robots pose and an ABB work object.
//!
//! `T_base1_base2` maps the other robot's base coordinates (`child`) into the reference robot's base
//! (`parent`): it is the pose of the child base in the parent base. Conventions:
//!
//! * ROS / TF: metres, unit quaternion `(x, y, z, w)` with `w ≥ 0`.
//! * URDF: `<origin xyz=".." rpy=".."/>`, metres and radians, `rpy` fixed-axis roll-pitch-yaw:
//!   `R = Rz(yaw)·Ry(pitch)·Rx(roll)` ([`rpy_from_rotation`]).
//! * KUKA: `{X, Y, Z, A, B, C}` in mm and degrees, `R = Rz(A)·Ry(B)·Rx(C)`.
//! * UR: `p[x, y, z, rx, ry, rz]`, metres and a rotation vector in radians.
//! * ABB: `wobjdata` with the user frame `[[x, y, z], [q1, q2, q3, q4]]`, mm and `q1..q4 = w, x, y, z`.
//!
//! Numbers are written with fixed decimals: metres, radians and quaternions 9 (1 nm, 1 nrad), the
//! matrix 12, millimetres 6 and degrees 9.

use crate::error::{Error, Result};
use crate::geometry::pose::{
    isometry_to_abb, isometry_to_ur, isometry_to_xyzquat, rpy_from_rotation, KukaPose,
};
use crate::geometry::transform::isometry_to_rows;
use nalgebra::Isometry3;

/// The file name of the 4x4 matrix (row-major, metres; read back by `read_matrix_file`).
pub const MATRIX_FILE: &str = "T_base1_base2.txt";
/// The file name of the ROS 2 Python launch file.
pub const LAUNCH_FILE: &str = "static_tf.launch.py";
/// The file name of the URDF / xacro fixed joint.
pub const URDF_FILE: &str = "base_joint.urdf.xacro";
/// The file name of the TF YAML file.
pub const TF_YAML_FILE: &str = "tf.yaml";
/// The file name of the KUKA FRAME.
pub const KUKA_FILE: &str = "kuka_base.txt";
/// The file name of the UR pose.
pub const UR_FILE: &str = "ur_pose.txt";
/// The file name of the ABB work object.
pub const ABB_FILE: &str = "abb_wobj.txt";

/// Checks a ROS / TF frame id: 1 to 256 characters of ASCII letters, digits, `_`, `-`, `.` and `/`, at
/// least one of them a letter or digit. Such a name is written into a launch file, a URDF and a YAML file
/// without any quoting problem.
pub fn check_frame_id(f: &str) -> std::result::Result<(), String> {
    if f.is_empty() || f.len() > 256 {
        return Err(format!("frame id {f:?} must have 1 to 256 characters"));
    }
    if !f
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c))
    {
        return Err(format!(
            "frame id {f:?}: only ASCII letters, digits and _ - . / are allowed"
        ));
    }
    if !f.chars().any(|c| c.is_ascii_alphanumeric()) {
        return Err(format!("frame id {f:?} holds no letter or digit"));
    }
    Ok(())
}

/// The parent (reference base) and child (other base) frame ids of the transform.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frames {
    /// The reference robot's base frame id (`base1`).
    pub parent: String,
    /// The other robot's base frame id (`base2`).
    pub child: String,
}

impl Frames {
    /// Frame ids checked with [`check_frame_id`], and different from each other.
    pub fn new(parent: &str, child: &str) -> Result<Self> {
        for f in [parent, child] {
            check_frame_id(f).map_err(Error::InvalidInput)?;
        }
        if parent == child {
            return Err(Error::InvalidInput(format!(
                "the parent and child frame ids are both {parent:?}; they must differ"
            )));
        }
        Ok(Frames {
            parent: parent.to_string(),
            child: child.to_string(),
        })
    }
}

/// `v` with `prec` decimals, without a negative zero.
pub fn fixed(v: f64, prec: usize) -> String {
    let s = format!("{v:.prec$}");
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

fn m9(v: f64) -> String {
    fixed(v, 9)
}

/// The 4x4 matrix, one row per line, 12 decimals (the format of `write_matrix_file`).
pub fn matrix_text(t: &Isometry3<f64>) -> String {
    let m = isometry_to_rows(t);
    let mut s = String::new();
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|k| fixed(m[r * 4 + k], 12)).collect();
        s.push_str(&row.join(" "));
        s.push('\n');
    }
    s
}

/// The `Node(...)` of one static transform in a ROS 2 launch file (8 spaces in, a trailing comma).
fn launch_node(t: &Isometry3<f64>, f: &Frames) -> String {
    let q = isometry_to_xyzquat(t);
    let node: String = format!("depthcal_{}_to_{}", f.parent, f.child)
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    let mut args = String::new();
    for (flag, v) in ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"]
        .iter()
        .zip(q)
    {
        args.push_str(&format!("                \"{flag}\", \"{}\",\n", m9(v)));
    }
    format!(
        r#"        Node(
            package="tf2_ros",
            executable="static_transform_publisher",
            name="{node}",
            arguments=[
{args}                "--frame-id", "{parent}",
                "--child-frame-id", "{child}",
            ],
        ),
"#,
        parent = f.parent,
        child = f.child,
    )
}

/// A ROS 2 Python launch file of `nodes` (each from [`launch_node`]) after the `header` comment lines.
fn launch_file(header: &str, nodes: &str) -> String {
    format!(
        r#"{header}from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
{nodes}    ])
"#
    )
}

/// A ROS 2 Python launch file running `tf2_ros static_transform_publisher` with `--x --y --z --qx --qy
/// --qz --qw --frame-id --child-frame-id`.
pub fn ros2_launch_py(t: &Isometry3<f64>, f: &Frames) -> String {
    launch_file(
        &format!(
            "# Generated by depthcal calibrate: T_base1_base2, the pose of {} in {}\n\
             # (metres, unit quaternion x y z w). Run: ros2 launch ./static_tf.launch.py\n",
            f.child, f.parent
        ),
        &launch_node(t, f),
    )
}

/// The ROS 2 launch file of a cell of three or more robots: one static transform per robot, each the
/// pose of its base in the reference base (`frames.parent`).
pub fn ros2_launch_py_robots(robots: &[(Isometry3<f64>, Frames)]) -> String {
    let parent = robots.first().map_or("", |(_, f)| f.parent.as_str());
    let nodes: String = robots.iter().map(|(t, f)| launch_node(t, f)).collect();
    launch_file(
        &format!(
            "# Generated by depthcal calibrate: the pose of each robot's base in {parent}, one static\n\
             # transform per robot (metres, unit quaternion x y z w). Run: ros2 launch ./static_tf.launch.py\n"
        ),
        &nodes,
    )
}

/// One fixed `<joint>` of a URDF from the parent base link to the child base link (2 spaces in).
fn urdf_joint(t: &Isometry3<f64>, f: &Frames) -> String {
    let v = t.translation.vector;
    let rpy = rpy_from_rotation(t.rotation.to_rotation_matrix().matrix());
    format!(
        r#"  <joint name="{parent}_to_{child}" type="fixed">
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{} {} {}" rpy="{} {} {}"/>
  </joint>
"#,
        m9(v.x),
        m9(v.y),
        m9(v.z),
        m9(rpy[0]),
        m9(rpy[1]),
        m9(rpy[2]),
        parent = f.parent,
        child = f.child,
    )
}

/// A URDF fixed joint from the parent base link to the child base link, as a xacro file (include it with
/// `<xacro:include filename="base_joint.urdf.xacro"/>`).
pub fn urdf_xacro(t: &Isometry3<f64>, f: &Frames) -> String {
    format!(
        r#"<?xml version="1.0"?>
<!-- Generated by depthcal calibrate: T_base1_base2, the pose of {child} in {parent}.
     origin: metres; rpy: radians, fixed axes, R = Rz(yaw) Ry(pitch) Rx(roll). -->
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="depthcal_base_joint">
{joint}</robot>
"#,
        parent = f.parent,
        child = f.child,
        joint = urdf_joint(t, f),
    )
}

/// The URDF / xacro of a cell of three or more robots: one fixed joint per robot from the reference base
/// link to its base link.
pub fn urdf_xacro_robots(robots: &[(Isometry3<f64>, Frames)]) -> String {
    let parent = robots.first().map_or("", |(_, f)| f.parent.as_str());
    let joints: String = robots.iter().map(|(t, f)| urdf_joint(t, f)).collect();
    format!(
        r#"<?xml version="1.0"?>
<!-- Generated by depthcal calibrate: the pose of each robot's base in {parent}, one fixed joint per robot.
     origin: metres; rpy: radians, fixed axes, R = Rz(yaw) Ry(pitch) Rx(roll). -->
<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="depthcal_base_joints">
{joints}</robot>
"#
    )
}

/// The fields of one `geometry_msgs/TransformStamped` in YAML, each line after `indent` (the first line
/// after `first` instead).
fn tf_entry(t: &Isometry3<f64>, f: &Frames, first: &str, indent: &str) -> String {
    let q = isometry_to_xyzquat(t);
    format!(
        "{first}header:\n{indent}  frame_id: \"{parent}\"\n\
         {indent}child_frame_id: \"{child}\"\n\
         {indent}transform:\n{indent}  translation:\n{indent}    x: {}\n{indent}    y: {}\n{indent}    z: {}\n\
         {indent}  rotation:\n{indent}    x: {}\n{indent}    y: {}\n{indent}    z: {}\n{indent}    w: {}\n",
        m9(q[0]),
        m9(q[1]),
        m9(q[2]),
        m9(q[3]),
        m9(q[4]),
        m9(q[5]),
        m9(q[6]),
        parent = f.parent,
        child = f.child,
    )
}

/// A TF YAML file in the shape of `geometry_msgs/TransformStamped` (frame ids, translation in metres,
/// rotation quaternion).
pub fn tf_yaml(t: &Isometry3<f64>, f: &Frames) -> String {
    format!(
        "# Generated by depthcal calibrate: T_base1_base2, the pose of {} in {} (metres).\n{}",
        f.child,
        f.parent,
        tf_entry(t, f, "", "")
    )
}

/// The TF YAML of a cell of three or more robots, in the shape of `tf2_msgs/TFMessage`: `transforms`, one
/// `geometry_msgs/TransformStamped` per robot.
pub fn tf_yaml_robots(robots: &[(Isometry3<f64>, Frames)]) -> String {
    let parent = robots.first().map_or("", |(_, f)| f.parent.as_str());
    let entries: String = robots
        .iter()
        .map(|(t, f)| tf_entry(t, f, "  - ", "    "))
        .collect();
    format!(
        "# Generated by depthcal calibrate: the pose of each robot's base in {parent} (metres).\ntransforms:\n{entries}"
    )
}

/// A KUKA FRAME literal `{X .., Y .., Z .., A .., B .., C ..}` (mm, degrees), e.g. for `BASE_DATA[n]`.
pub fn kuka_base_text(t: &Isometry3<f64>, f: &Frames) -> String {
    let k = KukaPose::from_isometry(t);
    format!(
        "; Generated by depthcal calibrate: T_base1_base2, the pose of {} in {}, as a KUKA FRAME:\n\
         ; mm and degrees, R = Rz(A)*Ry(B)*Rx(C). Enter it as a base frame (BASE_DATA[n]) on the\n\
         ; reference robot's controller.\n\
         {{X {},Y {},Z {},A {},B {},C {}}}\n",
        f.child,
        f.parent,
        fixed(k.x_mm, 6),
        fixed(k.y_mm, 6),
        fixed(k.z_mm, 6),
        m9(k.a_deg),
        m9(k.b_deg),
        m9(k.c_deg),
    )
}

/// A URScript pose `p[x, y, z, rx, ry, rz]` (metres, rotation vector in radians).
pub fn ur_pose_text(t: &Isometry3<f64>, f: &Frames) -> String {
    let u = isometry_to_ur(t);
    let vals: Vec<String> = u.iter().map(|v| m9(*v)).collect();
    format!(
        "# Generated by depthcal calibrate: T_base1_base2, the pose of {} in {}, as a URScript pose:\n\
         # x, y, z in metres, rx, ry, rz a rotation vector (axis * angle) in radians.\n\
         p[{}]\n",
        f.child,
        f.parent,
        vals.join(", ")
    )
}

/// An ABB RAPID `wobjdata` whose user frame is the transform (mm, quaternion `q1..q4 = w, x, y, z`).
pub fn abb_wobj_text(t: &Isometry3<f64>, f: &Frames) -> String {
    let a = isometry_to_abb(t);
    let p: Vec<String> = a[..3].iter().map(|v| fixed(*v, 6)).collect();
    let q: Vec<String> = a[3..].iter().map(|v| m9(*v)).collect();
    format!(
        "! Generated by depthcal calibrate: T_base1_base2, the pose of {} in {}, as the user frame\n\
         ! of an ABB work object: mm and a unit quaternion q1..q4 = w, x, y, z.\n\
         PERS wobjdata wobj_depthcal := [FALSE, TRUE, \"\", [[{}], [{}]], [[0, 0, 0], [1, 0, 0, 0]]];\n",
        f.child,
        f.parent,
        p.join(", "),
        q.join(", ")
    )
}

/// The ROS 2 command line that publishes the transform as a static TF (metres, quaternion x y z w).
pub fn ros2_static_tf_command(t: &Isometry3<f64>, f: &Frames) -> String {
    let xq = isometry_to_xyzquat(t);
    format!(
        "ros2 run tf2_ros static_transform_publisher --x {:.6} --y {:.6} --z {:.6} --qx {:.8} --qy {:.8} --qz {:.8} --qw {:.8} --frame-id {} --child-frame-id {}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6], f.parent, f.child
    )
}

/// The ROS 1 command line that publishes the transform as a static TF.
pub fn ros1_static_tf_command(t: &Isometry3<f64>, f: &Frames) -> String {
    let xq = isometry_to_xyzquat(t);
    format!(
        "rosrun tf2_ros static_transform_publisher {:.6} {:.6} {:.6} {:.8} {:.8} {:.8} {:.8} {} {}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6], f.parent, f.child
    )
}

/// Every transform file of `calibrate --output` but `calibration.json`: (file name, content).
pub fn transform_files(t: &Isometry3<f64>, f: &Frames) -> Vec<(&'static str, String)> {
    vec![
        (MATRIX_FILE, matrix_text(t)),
        (LAUNCH_FILE, ros2_launch_py(t, f)),
        (URDF_FILE, urdf_xacro(t, f)),
        (TF_YAML_FILE, tf_yaml(t, f)),
        (KUKA_FILE, kuka_base_text(t, f)),
        (UR_FILE, ur_pose_text(t, f)),
        (ABB_FILE, abb_wobj_text(t, f)),
    ]
}

/// A robot name as it stands in an output file name: ASCII letters, digits, `_`, `-` and `.` kept, every
/// other character `_`.
pub fn file_token(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "_-.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The other robots' names as they stand in output file names ([`file_token`]); two names that differ only
/// in characters a file name cannot hold (or match the reference's) get the robot's position too.
pub fn robot_file_tokens(reference: &str, robots: &[&str]) -> Vec<String> {
    let mut used = vec![file_token(reference)];
    robots
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let mut token = file_token(n);
            if used.contains(&token) {
                token = format!("{token}_{}", k + 2);
            }
            used.push(token.clone());
            token
        })
        .collect()
}

/// One robot of a cell of three or more robots in `calibrate --output`: its name, `T_reference_robot`
/// and the frame ids (`parent`: the reference base, `child`: this robot's base).
#[derive(Clone, Debug)]
pub struct RobotOutput {
    /// The robot's name (its files are named by [`file_token`] of it).
    pub name: String,
    /// `T_reference_robot`, metres.
    pub transform: Isometry3<f64>,
    /// The frame ids.
    pub frames: Frames,
}

/// The file names of [`robot_transform_files`] for a reference robot and the other robots' names (the
/// content does not matter for the names).
pub fn robot_transform_file_names(reference: &str, robots: &[&str]) -> Vec<String> {
    let outs: Vec<RobotOutput> = robots
        .iter()
        .map(|n| RobotOutput {
            name: n.to_string(),
            transform: Isometry3::identity(),
            frames: Frames {
                parent: "a".into(),
                child: "b".into(),
            },
        })
        .collect();
    robot_transform_files(reference, &outs)
        .into_iter()
        .map(|(n, _)| n)
        .collect()
}

/// Every transform file of `calibrate --output` for a cell of three or more robots: one ROS 2 launch file,
/// one URDF / xacro and one TF YAML file with a static transform (joint, entry) per robot, and per robot
/// its matrix `T_<reference>_<robot>.txt` and its KUKA, UR and ABB frames (`kuka_base_<robot>.txt`,
/// `ur_pose_<robot>.txt`, `abb_wobj_<robot>.txt`): (file name, content).
pub fn robot_transform_files(reference: &str, robots: &[RobotOutput]) -> Vec<(String, String)> {
    let pairs: Vec<(Isometry3<f64>, Frames)> = robots
        .iter()
        .map(|r| (r.transform, r.frames.clone()))
        .collect();
    let mut files = vec![
        (LAUNCH_FILE.to_string(), ros2_launch_py_robots(&pairs)),
        (URDF_FILE.to_string(), urdf_xacro_robots(&pairs)),
        (TF_YAML_FILE.to_string(), tf_yaml_robots(&pairs)),
    ];
    let names: Vec<&str> = robots.iter().map(|r| r.name.as_str()).collect();
    let tokens = robot_file_tokens(reference, &names);
    let reference = file_token(reference);
    for (r, token) in robots.iter().zip(tokens) {
        let (t, f) = (&r.transform, &r.frames);
        files.push((format!("T_{reference}_{token}.txt"), matrix_text(t)));
        files.push((format!("kuka_base_{token}.txt"), kuka_base_text(t, f)));
        files.push((format!("ur_pose_{token}.txt"), ur_pose_text(t, f)));
        files.push((format!("abb_wobj_{token}.txt"), abb_wobj_text(t, f)));
    }
    files
}
