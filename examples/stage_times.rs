//! Times each stage of the initialisation on a synthetic frame:
//! `cargo run --release --example stage_times -- [WIDTH HEIGHT]`.
use std::time::Instant;

use semdepth::init::*;
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};

fn main() {
    let a: Vec<u32> = std::env::args()
        .skip(1)
        .map(|s| s.parse().expect("number"))
        .collect();
    let (w, h) = if a.len() == 2 { (a[0], a[1]) } else { (1024, 768) };
    let cfg = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(Preset::Cluttered, Shape::Blob, 1).with_size(w, h)
    };
    let f = Scene::new(&cfg).unwrap().render(0).left;
    let p = InitParams::default();
    let n = 20;
    let time = |name: &str, run: &mut dyn FnMut()| {
        let t = Instant::now();
        for _ in 0..n {
            run();
        }
        println!("{name:>12}: {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
    };
    let roi = [0, 0, w, h];
    let scale = w.max(h).div_ceil(p.working_max_side);
    let work = downsample(&f, roi, scale);
    time("downsample", &mut || drop(downsample(&f, roi, scale)));
    time("noise", &mut || {
        std::hint::black_box(estimate_noise(&work));
    });
    let blurred = imageproc::filter::gaussian_blur_f32(&work, 2.0);
    time("blur", &mut || {
        drop(imageproc::filter::gaussian_blur_f32(&work, 2.0))
    });
    let g = Gradient::sobel(&blurred);
    time("sobel", &mut || drop(Gradient::sobel(&blurred)));
    time("thresholds", &mut || {
        std::hint::black_box(auto_thresholds(&g.magnitude, 0.001));
    });
    let (lo, hi) = auto_thresholds(&g.magnitude, 0.001);
    let thin = non_maximum_suppression(&g, lo);
    time("nms", &mut || drop(non_maximum_suppression(&g, lo)));
    let edges = hysteresis(&thin, work.width(), work.height(), lo, hi);
    time("hysteresis", &mut || {
        drop(hysteresis(&thin, work.width(), work.height(), lo, hi))
    });
    let closed = dilate_disk(&edges, 3);
    time("dilate", &mut || drop(dilate_disk(&edges, 3)));
    let regions = outer_regions(&closed);
    time("contours", &mut || drop(outer_regions(&closed)));
    time("fill", &mut || drop(fill_region(&regions[0].border)));
    let (filled, _, _) = fill_region(&regions[0].border);
    time("erode", &mut || drop(erode_disk(&filled, 3)));
    time("total", &mut || drop(initialise(&f, &p).unwrap()));
}
