//! How well a real stereo pair fixes the rigid disparity:
//! `energy_valley LEFT RIGHT [RADIUS STEP]`.
//!
//! Tracks (LEFT, RIGHT) as a first pair, then prints the region energy of
//! the tracked right contour moved by every (dx, dy) on a grid of +-RADIUS
//! px (default 8, step 2), relative to its lowest value, and finally the
//! tracked disparity for several window margins. On the quartz images
//! (01 -> 03) the energy lies in a diagonal valley that is nearly flat over
//! several pixels, and the disparity moves along it with the margin: the
//! particle's silhouette changes with tilt, so no rigid shift fits exactly.
use semdepth::energy::{evaluate, EnergyParams};
use semdepth::geometry::{Point, Polygon};
use semdepth::imageio::{read_file, DecodeLimits, GrayFrame};
use semdepth::region::{PixelRect, PrefixSums};
use semdepth::tracker::{PairResult, StereoTracker, TrackerParams};

fn track(left: &GrayFrame, right: &GrayFrame, params: TrackerParams) -> PairResult {
    StereoTracker::new(params)
        .process(left, right)
        .unwrap_or_else(|e| panic!("pair: {e}"))
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 3 {
        eprintln!("usage: energy_valley LEFT RIGHT [RADIUS STEP]");
        std::process::exit(2);
    }
    let load =
        |p: &str| read_file(p.as_ref(), &DecodeLimits::default()).unwrap_or_else(|e| panic!("{p}: {e}"));
    let (left, right) = (load(&a[1]), load(&a[2]));
    let radius: f64 = a.get(3).map_or(8.0, |v| v.parse().expect("RADIUS"));
    let step: f64 = a.get(4).map_or(2.0, |v| v.parse().expect("STEP"));

    let result = track(&left, &right, TrackerParams::default());
    let Some(tracked) = result.right.as_ref() else {
        eprintln!("not tracked: {:?}", result.reason);
        std::process::exit(1);
    };
    let contour: &[Point] = &tracked.contour;
    let energy = EnergyParams::default();
    let margin = energy.margin_for_area(Polygon::new(contour.to_vec()).area());
    let sums = PrefixSums::new(&right, PixelRect::full(&right), 1);
    let n = (radius / step).round() as i32;
    let offsets: Vec<f64> = (-n..=n).map(|k| k as f64 * step).collect();
    let grid: Vec<Vec<f64>> = offsets
        .iter()
        .map(|&dy| {
            offsets
                .iter()
                .map(|&dx| {
                    let moved: Vec<Point> = contour.iter().map(|p| [p[0] + dx, p[1] + dy]).collect();
                    evaluate(&sums, &moved, &energy, margin).energy
                })
                .collect()
        })
        .collect();
    let lowest = grid.iter().flatten().copied().fold(f64::INFINITY, f64::min);
    let d = result.disparity_px.unwrap_or([f64::NAN; 2]);
    println!(
        "tracked disparity ({:.2}, {:.2}); energy at the tracked pose {:.1} (margin {margin:.0} px)",
        d[0], d[1], tracked.energy
    );
    println!("energy minus the grid's lowest, rows dy, columns dx (offsets from the tracked pose):");
    print!("{:>7}", "dy\\dx");
    for dx in &offsets {
        print!(" {dx:>7.1}");
    }
    println!();
    for (dy, row) in offsets.iter().zip(&grid) {
        print!("{dy:>7.1}");
        for e in row {
            print!(" {:>7.1}", e - lowest);
        }
        println!();
    }
    println!("tracked disparity by window margin:");
    for margin_px in [16.0, 32.0, 64.0, 128.0] {
        let mut params = TrackerParams::default();
        params.energy.margin_px = Some(margin_px);
        let r = track(&left, &right, params);
        let d = r.disparity_px.unwrap_or([f64::NAN; 2]);
        println!("  margin {margin_px:>5.0} px: ({:.2}, {:.2})", d[0], d[1]);
    }
    println!("  default ({margin:.0} px): ({:.2}, {:.2})", d[0], d[1]);
}
