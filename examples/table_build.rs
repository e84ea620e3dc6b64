//! Times the two parts of a region sum on a 1024x768 noise frame: building
//! the tables over a square area (next to a plain sum over the same
//! samples), and one polygon sum over an outline with the free fit's 6-px
//! vertex spacing, per row crossing:
//! `cargo run --release --example table_build -- [SIDE] [REPEATS]`.
use semdepth::geometry::Point;
use semdepth::imageio::GrayFrame;
use semdepth::region::{PixelRect, PrefixSums};

fn main() {
    let a: Vec<u32> = std::env::args()
        .skip(1)
        .map(|s| s.parse().expect("number"))
        .collect();
    let side = a.first().copied().unwrap_or(453).clamp(64, 700);
    let repeats = a.get(1).copied().unwrap_or(2000).max(50) as usize;
    let (w, h) = (1024u32, 768u32);
    let data = (0..w * h)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u16)
        .collect();
    let frame = GrayFrame {
        width: w,
        height: h,
        bit_depth: 8,
        data,
    };
    let rect = PixelRect {
        x: 100,
        y: 50,
        width: side,
        height: side.min(h - 50),
    };
    let (build_med, build_min) = median_and_min(repeats, 1, &mut || {
        drop(std::hint::black_box(PrefixSums::new(&frame, rect, 1)))
    });
    let (sum_med, sum_min) = median_and_min(repeats, 1, &mut || {
        let mut s = 0u64;
        for r in rect.y..rect.y + rect.height {
            let row = &frame.row(r)[rect.x as usize..(rect.x + rect.width) as usize];
            s += row.iter().map(|&v| u64::from(v)).sum::<u64>();
        }
        std::hint::black_box(s);
    });
    println!(
        "{side}x{}: tables median {build_med:.4} ms (min {build_min:.4}); plain sum median {sum_med:.4} ms (min {sum_min:.4}); ratio {:.2}",
        rect.height,
        build_med / sum_med
    );
    let sums = PrefixSums::new(&frame, rect, 1);
    let centre = [
        rect.x as f64 + side as f64 / 2.0,
        rect.y as f64 + rect.height as f64 / 2.0,
    ];
    let radius = (side as f64 / 2.0 - 20.0) / 1.1;
    let n = (std::f64::consts::TAU * radius / 6.0).round() as usize;
    // Sixteen poses a sixteenth of a pixel apart, as in a rigid fit.
    let poses: Vec<Vec<Point>> = (0..16)
        .map(|k| {
            let d = k as f64 / 16.0;
            (0..n)
                .map(|i| {
                    let a = i as f64 / n as f64 * std::f64::consts::TAU;
                    let r = radius * (1.0 + 0.1 * (3.0 * a).sin());
                    [centre[0] + d + r * a.cos(), centre[1] - d + r * a.sin()]
                })
                .collect()
        })
        .collect();
    let mut k = 0;
    // Batches of 50, so that the minimum is not one lucky call.
    let (poly_med, poly_min) = median_and_min(repeats / 50, 50, &mut || {
        std::hint::black_box(sums.polygon(&poses[k % 16]));
        k += 1;
    });
    let height: f64 = {
        let ys = poses[0].iter().map(|p| p[1]);
        ys.clone().fold(f64::MIN, f64::max) - ys.fold(f64::MAX, f64::min)
    };
    // Each row of the outline's height is crossed twice.
    let crossings = 2.0 * height;
    println!(
        "polygon of {n} vertices, radius {radius:.0}: median {:.2} us (min {:.2}), {:.1} ns per row crossing",
        poly_med * 1e3,
        poly_min * 1e3,
        poly_med * 1e6 / crossings
    );
}

/// Median and minimum over `samples` timings of `per_sample` calls of
/// `run`, ms per call.
fn median_and_min(samples: usize, per_sample: usize, run: &mut dyn FnMut()) -> (f64, f64) {
    let mut times: Vec<f64> = (0..samples.max(1))
        .map(|_| {
            let t = std::time::Instant::now();
            for _ in 0..per_sample {
                run();
            }
            t.elapsed().as_secs_f64() * 1e3 / per_sample as f64
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], times[0])
}
