//! Writes the intermediate images of the initialisation (edges, dilated
//! edges) next to an input image, to see why an object was or was not found:
//! `cargo run --release --example init_debug -- IMAGE OUT_PREFIX`.

use semdepth::imageio::{read_file, DecodeLimits};
use semdepth::init::{debug_stages, InitParams};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: init_debug IMAGE OUT_PREFIX");
        std::process::exit(2);
    }
    let frame = read_file(args[1].as_ref(), &DecodeLimits::default()).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2)
    });
    let stages = debug_stages(&frame, &InitParams::default());
    for (name, image) in stages {
        let path = format!("{}_{name}.png", args[2]);
        image.save(&path).expect("write stage image");
        println!("{path}");
    }
}
