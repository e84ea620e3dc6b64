//! The `semdepth` binary: parses the command line and hands over to
//! [`semdepth::cli`].

use clap::Parser;

fn main() {
    let cli = semdepth::cli::Cli::parse();
    if let Err(e) = semdepth::cli::run(cli) {
        eprintln!("semdepth: {e}");
        std::process::exit(e.exit_code);
    }
}
