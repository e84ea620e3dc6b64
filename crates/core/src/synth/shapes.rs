//! Dense outlines of the synthetic objects in object coordinates (centroid
//! at the origin, principal pose along +x), plus polygon helpers: half-plane
//! clipping, exact overlap areas and edge subdivision.

use std::f64::consts::TAU;

use rand::Rng;

use super::config::Shape;
use crate::geometry::{HalfPlane, Point, Polygon};

/// Fewest vertices of an object outline.
pub const MIN_VERTICES: usize = 256;
/// Longest edge of an object outline in pixels.
const MAX_SPACING: f64 = 1.0;

/// The outline of `shape` with characteristic size `size` (pixels), random
/// details drawn from `rng`, moved so that its area centroid is the origin.
pub fn object_outline(shape: Shape, size: f64, rng: &mut impl Rng) -> Polygon {
    let poly = match shape {
        Shape::Blob => blob(size / 2.0, 4, 0.22, rng),
        Shape::Sphere => circle(size / 2.0),
        Shape::Tip => {
            let back = rng.gen_range(0.16..0.22) * size;
            let front = (rng.gen_range(0.02..0.04) * size).max(1.5);
            tapered_capsule(back, front, size - back - front)
        }
        Shape::Rod => {
            let radius = rng.gen_range(0.06..0.10) * size;
            tapered_capsule(radius, radius, size - 2.0 * radius)
        }
    };
    centred(poly)
}

/// A small irregular particle of mean radius `radius`, centroid at the origin.
pub fn particle_outline(radius: f64, rng: &mut impl Rng) -> Polygon {
    centred(blob(radius, 3, 0.18, rng))
}

/// The polygon moved so that its area centroid is the origin.
pub fn centred(poly: Polygon) -> Polygon {
    let c = poly.centroid();
    poly.translated([-c[0], -c[1]])
}

/// Number of vertices for an outline of the given perimeter.
fn vertex_count(perimeter: f64) -> usize {
    ((perimeter / MAX_SPACING).ceil() as usize).max(MIN_VERTICES)
}

/// A circle of radius `r` about the origin.
fn circle(r: f64) -> Polygon {
    Polygon::circle([0.0, 0.0], r, vertex_count(TAU * r))
}

/// A star-shaped outline r(t) = R (1 + sum a_k cos(k t + phi_k)) with
/// harmonics 2..=`harmonics`+1 whose amplitudes sum to at most `max_sum`.
fn blob(radius: f64, harmonics: usize, max_sum: f64, rng: &mut impl Rng) -> Polygon {
    let mut terms: Vec<(f64, f64, f64)> = (0..harmonics)
        .map(|i| {
            let k = (i + 2) as f64;
            let amp = rng.gen_range(0.0..0.12) / (k - 1.0).powf(0.8);
            (k, amp, rng.gen_range(0.0..TAU))
        })
        .collect();
    let sum: f64 = terms.iter().map(|t| t.1).sum();
    if sum > max_sum {
        terms.iter_mut().for_each(|t| t.1 *= max_sum / sum);
    }
    // Perimeter bound: the radius stays below R (1 + max_sum), and the
    // harmonics add at most sum k a_k of arc length per radian.
    let wiggle: f64 = terms.iter().map(|t| t.0 * t.1).sum();
    let n = vertex_count(TAU * radius * (1.0 + max_sum + wiggle));
    let points = (0..n)
        .map(|i| {
            let t = i as f64 / n as f64 * TAU;
            let r = radius * (1.0 + terms.iter().map(|&(k, a, p)| a * (k * t + p).cos()).sum::<f64>());
            [r * t.cos(), r * t.sin()]
        })
        .collect();
    Polygon::new(points)
}

/// The convex hull of a circle of radius `r0` at the origin and one of
/// radius `r1` at (`length`, 0): a capsule when r0 == r1, a teardrop-like
/// tapered tip when r1 < r0.
fn tapered_capsule(r0: f64, r1: f64, length: f64) -> Polygon {
    // Angle (from +x) of the tangent points on both circles.
    let phi = ((r0 - r1) / length).clamp(-1.0, 1.0).acos();
    let side = (length * length - (r0 - r1).powi(2)).max(0.0).sqrt();
    let perimeter = r0 * (TAU - 2.0 * phi) + r1 * 2.0 * phi + 2.0 * side;
    let step = perimeter / vertex_count(perimeter) as f64;
    let mut pts: Vec<Point> = Vec::new();
    // Back arc: phi .. 2 pi - phi through pi (screen: y down, this runs clockwise).
    arc(&mut pts, [0.0, 0.0], r0, phi, TAU - phi, step);
    let a = polar([0.0, 0.0], r0, TAU - phi);
    let b = polar([length, 0.0], r1, -phi);
    segment(&mut pts, a, b, step);
    arc(&mut pts, [length, 0.0], r1, -phi, phi, step);
    let c = polar([length, 0.0], r1, phi);
    let d = polar([0.0, 0.0], r0, phi);
    segment(&mut pts, c, d, step);
    Polygon::new(pts)
}

fn polar(c: Point, r: f64, t: f64) -> Point {
    [c[0] + r * t.cos(), c[1] + r * t.sin()]
}

/// Appends points of an arc from angle `t0` to `t1` (excluding the end).
fn arc(out: &mut Vec<Point>, c: Point, r: f64, t0: f64, t1: f64, step: f64) {
    let n = ((r * (t1 - t0).abs() / step).ceil() as usize).max(1);
    out.extend((0..n).map(|i| polar(c, r, t0 + (t1 - t0) * i as f64 / n as f64)));
}

/// Appends points of a straight segment from `a` to `b` (excluding the end).
fn segment(out: &mut Vec<Point>, a: Point, b: Point, step: f64) {
    let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
    let n = ((len / step).ceil() as usize).max(1);
    out.extend((0..n).map(|i| {
        let t = i as f64 / n as f64;
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
    }));
}

/// The polygon with every edge longer than `max_len` split evenly; the
/// original vertices are kept, so the shape is unchanged.
pub fn subdivided(poly: &Polygon, max_len: f64) -> Vec<Point> {
    let mut out = Vec::with_capacity(poly.len());
    for (a, b) in poly.edges() {
        let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        segment(&mut out, a, b, max_len.min(len.max(1e-9)));
    }
    out
}

/// The part of `poly` with `n . p >= s` (see [`HalfPlane::clip`]).
pub fn clip_half_plane(poly: &[Point], n: Point, s: f64) -> Vec<Point> {
    HalfPlane::new(n, s).clip(poly)
}

/// Area (>= 0) of a vertex list by the shoelace formula.
pub fn area_of(points: &[Point]) -> f64 {
    let n = points.len();
    let mut s = 0.0;
    for i in 0..n {
        let a = points[i];
        let b = points[(i + 1) % n];
        s += a[0] * b[1] - b[0] * a[1];
    }
    (s / 2.0).abs()
}

/// Area of `poly` inside the convex polygon `convex` (vertices in either order).
pub fn overlap_with_convex(poly: &[Point], convex: &[Point]) -> f64 {
    let n = convex.len();
    // Inward normals depend on the orientation of `convex`.
    let signed: f64 = (0..n)
        .map(|i| {
            let (a, b) = (convex[i], convex[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum();
    let orient = if signed >= 0.0 { 1.0 } else { -1.0 };
    let mut clipped = poly.to_vec();
    for i in 0..n {
        if clipped.is_empty() {
            break;
        }
        let (a, b) = (convex[i], convex[(i + 1) % n]);
        // For positive signed area (y down, clockwise on screen) the interior
        // lies on the side of (-(b-a).y, (b-a).x).
        let normal = [-(b[1] - a[1]) * orient, (b[0] - a[0]) * orient];
        let s = normal[0] * a[0] + normal[1] * a[1];
        clipped = clip_half_plane(&clipped, normal, s);
    }
    area_of(&clipped)
}

/// Largest distance of a vertex from the origin.
pub fn max_radius(poly: &Polygon) -> f64 {
    poly.points
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1]).sqrt())
        .fold(0.0, f64::max)
}
