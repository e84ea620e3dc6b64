//! Per-sector contrast ratios of a first-pair template in later images:
//! `sector_ratios FIRST NEXT...` (left = right = the same image each pair).
use semdepth::imageio::{read_file, DecodeLimits};
use semdepth::tracker::{StereoTracker, TrackerParams};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let mut params = TrackerParams::default();
    if let Ok(v) = std::env::var("OCC") {
        params.occlusion.min_contrast_ratio = v.parse().unwrap();
    }
    let mut t = StereoTracker::new(params);
    for path in &a[1..] {
        let f = read_file(path.as_ref(), &DecodeLimits::default()).unwrap();
        let r = t.process(&f, &f).unwrap();
        let (l, rr) = (r.left.unwrap(), r.right.unwrap());
        println!(
            "{path}: {:?} disparity {:?} occluded L {:.2} R {:.2} centroid {:?}",
            r.status, r.disparity_px, l.occluded_fraction, rr.occluded_fraction, l.centroid
        );
    }
}
