//! Distance of the tracker's template (first left frame, after the free fit)
//! from the true outline: `template_check PRESET SHAPE SEED`.
use clap::ValueEnum;
use semdepth::geometry::{dist, Polygon};
use semdepth::synth::{Preset, Scene, Shape, SynthConfig};
use semdepth::tracker::{StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let preset = Preset::from_str(&a[1], true).unwrap();
    let shape = Shape::from_str(&a[2], true).unwrap();
    let seed: u64 = a[3].parse().unwrap();
    let cfg = SynthConfig {
        frames: 1,
        ..SynthConfig::preset(preset, shape, seed)
    };
    let pair = Scene::new(&cfg).unwrap().render(0);
    let mut t = StereoTracker::new(TrackerParams::default());
    let r = t.process(&pair.left, &pair.right).unwrap();
    let contour = Polygon::new(r.left.unwrap().contour);
    let truth = pair.truth.left.polygon.resampled(2000);
    // Signed distance: positive outside the truth.
    let d: Vec<f64> = contour
        .points
        .iter()
        .map(|p| {
            let m = truth
                .points
                .iter()
                .map(|q| dist(*p, *q))
                .fold(f64::INFINITY, f64::min);
            if truth.contains(*p) {
                -m
            } else {
                m
            }
        })
        .collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let (mn, mx) = d.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(*v), b.max(*v))
    });
    println!(
        "{} vertices: offset mean {mean:+.3} sd {sd:.3} min {mn:+.3} max {mx:+.3}; area {:.0} vs {:.0}",
        d.len(),
        contour.area(),
        truth.area()
    );
    let worst: Vec<String> = d
        .iter()
        .enumerate()
        .filter(|(_, v)| v.abs() > 0.8)
        .map(|(i, v)| format!("{i}:{v:+.2}"))
        .collect();
    println!("worst: {worst:?}");
}
