//! The `depthcal` command-line tool: a thin layer over the library (parsing, printing, progress).

mod cli;

fn main() {
    std::process::exit(cli::run());
}
