//! `depthcal convert`: convert a pose file between KUKA XYZ-ABC, 4x4 matrix, x,y,z+quaternion, UR pose
//! vector, ABB x,y,z+q1..q4 and Fanuc XYZ-WPR rows.

use clap::Args as ClapArgs;
use depthcal::io::poses::{format_poses, read_poses, write_poses, PoseFormat};
use std::path::PathBuf;

/// Arguments of `depthcal convert`.
#[derive(ClapArgs)]
pub struct Args {
    /// The pose CSV file to convert.
    pub poses: PathBuf,
    /// Input format: kuka, matrix, xyzquat, ur, abb or fanuc (default: recognised from the header line).
    #[arg(long)]
    pub from: Option<PoseFormat>,
    /// Output format: kuka, matrix, xyzquat, ur, abb or fanuc.
    #[arg(long)]
    pub to: PoseFormat,
    /// Output file (written atomically); default: stdout.
    #[arg(long, short)]
    pub output: Option<PathBuf>,
}

/// Runs `depthcal convert`.
pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(out) = &a.output {
        super::guard::check_output_file("--output", out, &[])?;
        let mut inputs = super::guard::Inputs::default();
        inputs.add("the input pose file", &a.poses);
        inputs.check_output("--output", out)?;
    }
    let (from, records) = read_poses(&a.poses, a.from)?;
    match &a.output {
        Some(out) => {
            write_poses(out, &records, a.to)?;
            eprintln!(
                "converted {} poses from {from} to {} -> {}",
                records.len(),
                a.to,
                out.display()
            );
        }
        None => print!("{}", format_poses(&records, a.to)),
    }
    Ok(())
}
