//! A tool (the generator's tip) sweeping down at 8 px per pair over a
//! particle as bright as itself, as in `tests/session_synth.rs`
//! (`a_tool_passing_in_front_of_the_particle`), tracked alone with a `roi`
//! hint: prints the tool's status, left centroid error, hidden share and
//! rotation per pair.
//! `cargo run --release --example tool_probe -- SEED` (env NOISY=1 for the
//! noisy preset, DUMP=dir for overlays: tracked red, truth green).
use semdepth::display::{render_png, Overlay};
use semdepth::init::InitParams;
use semdepth::synth::Preset;
use semdepth::tracker::{StereoTracker, TrackerParams};

// The scene as the test builds it.
#[path = "../tests/common/mod.rs"]
mod common;

fn main() {
    let seed: u64 = std::env::args().nth(1).unwrap().parse().unwrap();
    let dir = std::env::var("DUMP").ok();
    let preset = if std::env::var("NOISY").is_ok() {
        Preset::Noisy
    } else {
        Preset::Clean
    };
    let (tool, particle) = common::tool_over_particle(preset, seed, 24);
    let a0 = tool.render(0);
    let mut t = StereoTracker::new(TrackerParams {
        init: InitParams {
            roi: Some(a0.truth.left.roi_hint(0.1)),
            ..Default::default()
        },
        ..Default::default()
    });
    for k in 0..24 {
        let (a, b) = (tool.render(k), particle.render(k));
        let (w, h) = (a.left.width, a.left.height);
        let left = common::composite(&b.left, &a.left, &a.truth.left.polygon.rasterize(w, h));
        let right = common::composite(&b.right, &a.right, &a.truth.right.polygon.rasterize(w, h));
        let r = t.process(&left, &right).unwrap();
        let c = r.left.as_ref().map(|l| {
            (
                l.centroid[0] - a.truth.left.centroid[0],
                l.centroid[1] - a.truth.left.centroid[1],
                l.occluded_fraction,
            )
        });
        println!(
            "{k}: {:?} {:.2?} theta {:.3?} {:?}",
            r.status,
            c,
            t.state().map(|s| s.left.theta),
            r.reason
        );
        if let Some(dir) = &dir {
            // The state's contour where the pair has none (lost).
            let tracked = r
                .left
                .as_ref()
                .map(|v| v.contour.clone())
                .or_else(|| t.state().map(|s| semdepth::fit::place(&s.template, s.left)));
            let mut overlays = vec![Overlay {
                contour: &a.truth.left.polygon.points,
                colour: [0, 255, 0],
            }];
            if let Some(contour) = &tracked {
                overlays.push(Overlay {
                    contour,
                    colour: [255, 0, 0],
                });
            }
            let png = render_png(&left, None, &overlays).unwrap();
            std::fs::write(format!("{dir}/tool_{k:02}.png"), png).unwrap();
        }
    }
}
