//! Closed polygons: length, area, centroid, orientation, resampling, rigid
//! transforms, point-in-polygon and rasterisation.
//!
//! Coordinates are pixels, x to the right and y down, with the centre of the
//! top-left pixel at (0, 0). Because y points down, a polygon whose vertices
//! run clockwise on screen has a positive signed area here.

/// A point or vector in pixel coordinates.
pub type Point = [f64; 2];

/// A closed polygon: the last vertex connects back to the first.
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(transparent))]
pub struct Polygon {
    /// Vertices in order; no repeated closing vertex.
    pub points: Vec<Point>,
}

/// Area moments of a polygon's interior, from which centroid and principal
/// axis follow (Green's theorem; exact for straight edges).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Moments {
    /// Signed area (positive when the vertices run clockwise on screen).
    pub area: f64,
    /// First moments: integral of x and of y over the interior (signed).
    pub mx: f64,
    pub my: f64,
    /// Second moments: integral of x^2, x*y and y^2 (signed).
    pub mxx: f64,
    pub mxy: f64,
    pub myy: f64,
}

impl Polygon {
    /// A polygon from its vertices.
    pub fn new(points: Vec<Point>) -> Self {
        Self { points }
    }

    /// A regular polygon approximating a circle (useful in tests).
    pub fn circle(center: Point, radius: f64, vertices: usize) -> Self {
        let points = (0..vertices)
            .map(|i| {
                let t = i as f64 / vertices as f64 * std::f64::consts::TAU;
                [center[0] + radius * t.cos(), center[1] + radius * t.sin()]
            })
            .collect();
        Self { points }
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Iterates over the edges as (start, end) pairs, closing the loop.
    pub fn edges(&self) -> impl Iterator<Item = (Point, Point)> + '_ {
        let n = self.points.len();
        (0..n).map(move |i| (self.points[i], self.points[(i + 1) % n]))
    }

    /// Perimeter length L.
    pub fn length(&self) -> f64 {
        self.edges().map(|(a, b)| dist(a, b)).sum()
    }

    /// Area moments of the interior (see [`Moments`]).
    pub fn moments(&self) -> Moments {
        let mut m = Moments {
            area: 0.0,
            mx: 0.0,
            my: 0.0,
            mxx: 0.0,
            mxy: 0.0,
            myy: 0.0,
        };
        for (a, b) in self.edges() {
            let cross = a[0] * b[1] - b[0] * a[1];
            m.area += cross;
            m.mx += (a[0] + b[0]) * cross;
            m.my += (a[1] + b[1]) * cross;
            m.mxx += (a[0] * a[0] + a[0] * b[0] + b[0] * b[0]) * cross;
            m.myy += (a[1] * a[1] + a[1] * b[1] + b[1] * b[1]) * cross;
            m.mxy += (a[0] * b[1] + 2.0 * a[0] * a[1] + 2.0 * b[0] * b[1] + b[0] * a[1]) * cross;
        }
        m.area /= 2.0;
        m.mx /= 6.0;
        m.my /= 6.0;
        m.mxx /= 12.0;
        m.myy /= 12.0;
        m.mxy /= 24.0;
        m
    }

    /// Signed area (positive for clockwise-on-screen vertex order).
    pub fn signed_area(&self) -> f64 {
        self.edges().map(|(a, b)| a[0] * b[1] - b[0] * a[1]).sum::<f64>() / 2.0
    }

    /// Enclosed area A (always >= 0).
    pub fn area(&self) -> f64 {
        self.signed_area().abs()
    }

    /// Centroid of the enclosed area; for a degenerate polygon, the mean of
    /// the vertices.
    pub fn centroid(&self) -> Point {
        let m = self.moments();
        if m.area.abs() < 1e-12 {
            return self.vertex_mean();
        }
        [m.mx / m.area, m.my / m.area]
    }

    /// Mean of the vertices.
    pub fn vertex_mean(&self) -> Point {
        let n = self.points.len().max(1) as f64;
        let s = self
            .points
            .iter()
            .fold([0.0, 0.0], |s, p| [s[0] + p[0], s[1] + p[1]]);
        [s[0] / n, s[1] / n]
    }

    /// Orientation of the principal (long) axis of the enclosed area, in
    /// radians in (-pi/2, pi/2], measured from +x towards +y (clockwise on
    /// screen). Undefined (returns 0) for shapes without a long axis.
    pub fn orientation(&self) -> f64 {
        match self.central_moments() {
            Some([mu20, mu11, mu02]) => 0.5 * (2.0 * mu11).atan2(mu20 - mu02),
            None => 0.0,
        }
    }

    /// Central second moments of the enclosed area per unit area,
    /// `[mu20, mu11, mu02]`; None for a degenerate polygon.
    fn central_moments(&self) -> Option<[f64; 3]> {
        let m = self.moments();
        if m.area.abs() < 1e-12 {
            return None;
        }
        let c = [m.mx / m.area, m.my / m.area];
        Some([
            m.mxx / m.area - c[0] * c[0],
            m.mxy / m.area - c[0] * c[1],
            m.myy / m.area - c[1] * c[1],
        ])
    }

    /// Standard deviations of the enclosed area along its principal axes,
    /// long axis first (square roots of the central second moments'
    /// eigenvalues): the shape's size along and across itself, whatever
    /// its position and rotation. Zero for a degenerate polygon.
    pub fn principal_spreads(&self) -> [f64; 2] {
        match self.central_moments() {
            Some(mu) => {
                let [small, large] = symmetric_eigenvalues(mu);
                [large.max(0.0).sqrt(), small.max(0.0).sqrt()]
            }
            None => [0.0; 2],
        }
    }

    /// Area of the part of the enclosed area within `length` of its
    /// farthest point along the unit vector `direction`: the shape of an
    /// end, say a tool's free end (its tip), whatever the part behind it.
    pub fn end_area(&self, direction: Point, length: f64) -> f64 {
        let along = |p: &Point| direction[0] * p[0] + direction[1] * p[1];
        let far = self.points.iter().map(along).fold(f64::NEG_INFINITY, f64::max);
        if !far.is_finite() {
            return 0.0;
        }
        Polygon::new(HalfPlane::new(direction, far - length).clip(&self.points)).area()
    }

    /// Bounding box as (min x, min y, max x, max y).
    pub fn bounds(&self) -> [f64; 4] {
        self.points.iter().fold(
            [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY],
            |b, p| [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])],
        )
    }

    /// The polygon moved by `d`.
    pub fn translated(&self, d: Point) -> Self {
        Self::new(self.points.iter().map(|p| [p[0] + d[0], p[1] + d[1]]).collect())
    }

    /// The polygon rotated by `angle` radians (clockwise on screen) about `center`.
    pub fn rotated_about(&self, center: Point, angle: f64) -> Self {
        let (s, c) = angle.sin_cos();
        Self::new(
            self.points
                .iter()
                .map(|p| {
                    let dx = p[0] - center[0];
                    let dy = p[1] - center[1];
                    [center[0] + c * dx - s * dy, center[1] + s * dx + c * dy]
                })
                .collect(),
        )
    }

    /// The polygon scaled by `factor` about the origin (used to map a
    /// contour found on a downsampled image back to full resolution).
    pub fn scaled(&self, factor: f64, offset: Point) -> Self {
        Self::new(
            self.points
                .iter()
                .map(|p| [p[0] * factor + offset[0], p[1] * factor + offset[1]])
                .collect(),
        )
    }

    /// Every vertex moved by `distance` along the outward normal (the
    /// perpendicular of the line through its two neighbours); negative values
    /// move inwards. For small distances this grows or shrinks the outline
    /// by about `distance` everywhere.
    pub fn offset_along_normals(&self, distance: f64) -> Self {
        self.offset_along(&self.outward_normals(), distance)
    }

    /// Every vertex moved by `distance` along its own direction of
    /// `normals` (one per vertex, e.g. [`Polygon::outward_normals`] of a
    /// smoothed copy).
    pub fn offset_along(&self, normals: &[Point], distance: f64) -> Self {
        let points = self
            .points
            .iter()
            .zip(normals)
            .map(|(p, n)| [p[0] + distance * n[0], p[1] + distance * n[1]])
            .collect();
        Self::new(points)
    }

    /// Unit outward normal at every vertex: perpendicular to the chord
    /// through its two neighbours.
    pub fn outward_normals(&self) -> Vec<Point> {
        let n = self.points.len();
        let outward = if self.signed_area() >= 0.0 { 1.0 } else { -1.0 };
        (0..n)
            .map(|i| {
                let (a, b) = (self.points[(i + n - 1) % n], self.points[(i + 1) % n]);
                let t = [b[0] - a[0], b[1] - a[1]];
                let l = t[0].hypot(t[1]).max(1e-12);
                [outward * t[1] / l, -outward * t[0] / l]
            })
            .collect()
    }

    /// Moving average over `2 * half + 1` neighbouring vertices (the outline
    /// is closed, so the window wraps); unchanged when it has fewer than
    /// `2 * half + 3` vertices.
    pub fn moving_average(&self, half: usize) -> Self {
        let n = self.points.len();
        if n < 2 * half + 3 {
            return self.clone();
        }
        let k = (2 * half + 1) as f64;
        let points = (0..n)
            .map(|i| {
                let mut s = [0.0, 0.0];
                for j in 0..=2 * half {
                    let p = self.points[(i + n + j - half) % n];
                    s[0] += p[0];
                    s[1] += p[1];
                }
                [s[0] / k, s[1] / k]
            })
            .collect();
        Self::new(points)
    }

    /// Resamples the outline to vertices about `spacing` apart along its
    /// length (the nearest whole number of them), at least `min_vertices`.
    pub fn resampled_every(&self, spacing: f64, min_vertices: usize) -> Self {
        self.resampled(((self.length() / spacing).round() as usize).max(min_vertices))
    }

    /// Resamples the outline to `n` vertices evenly spaced along its length,
    /// starting at the first vertex.
    pub fn resampled(&self, n: usize) -> Self {
        let total = self.length();
        if self.points.len() < 2 || n < 3 || total <= 0.0 {
            return self.clone();
        }
        let step = total / n as f64;
        let mut out = Vec::with_capacity(n);
        let mut edges = self.edges();
        let (mut a, mut b) = edges.next().expect("at least two vertices");
        let mut edge_len = dist(a, b);
        let mut along = 0.0; // distance walked into the current edge
        for i in 0..n {
            let mut remaining = if i == 0 { 0.0 } else { step };
            // Move to the next edge while the step does not fit in this one.
            while remaining > edge_len - along {
                remaining -= edge_len - along;
                match edges.next() {
                    Some((na, nb)) => {
                        (a, b) = (na, nb);
                        edge_len = dist(a, b);
                        along = 0.0;
                    }
                    None => {
                        // Rounding at the very end of the loop.
                        remaining = 0.0;
                        along = edge_len;
                    }
                }
            }
            along += remaining;
            let t = if edge_len > 0.0 { along / edge_len } else { 0.0 };
            out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
        }
        Self::new(out)
    }

    /// True when no two non-adjacent edges intersect (the outline does not
    /// cross or touch itself). Edges are bucketed in a grid of cells about
    /// twice the mean edge length, so the check is O(n) for even spacing.
    pub fn is_simple(&self) -> bool {
        let n = self.points.len();
        if n < 4 {
            return n == 3;
        }
        let [x0, y0, x1, y1] = self.bounds();
        // At most about 4n cells, however far apart a few vertices lie.
        let cell = (2.0 * self.length() / n as f64)
            .max(((x1 - x0) * (y1 - y0) / (4 * n) as f64).sqrt())
            .max(1e-9);
        let cols = (((x1 - x0) / cell).floor() as usize + 1).min(4096);
        let rows = (((y1 - y0) / cell).floor() as usize + 1).min(4096);
        let cell_x = |x: f64| (((x - x0) / cell).floor().max(0.0) as usize).min(cols - 1);
        let cell_y = |y: f64| (((y - y0) / cell).floor().max(0.0) as usize).min(rows - 1);
        let mut grid: Vec<Vec<usize>> = vec![Vec::new(); cols * rows];
        for i in 0..n {
            let (a, b) = (self.points[i], self.points[(i + 1) % n]);
            for cy in cell_y(a[1].min(b[1]))..=cell_y(a[1].max(b[1])) {
                for cx in cell_x(a[0].min(b[0]))..=cell_x(a[0].max(b[0])) {
                    grid[cy * cols + cx].push(i);
                }
            }
        }
        for bucket in &grid {
            for (k, &i) in bucket.iter().enumerate() {
                for &j in &bucket[k + 1..] {
                    let adjacent =
                        j == i + 1 || i == j + 1 || (i == 0 && j == n - 1) || (j == 0 && i == n - 1);
                    if adjacent || i == j {
                        continue;
                    }
                    let (a, b) = (self.points[i], self.points[(i + 1) % n]);
                    let (c, d) = (self.points[j], self.points[(j + 1) % n]);
                    if segments_intersect(a, b, c, d) {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// The part inside the box `[x0, y0, x1, y1]` (Sutherland-Hodgman
    /// against its four sides: exact area for any simple outline, since the
    /// box is convex).
    pub fn clipped_to_box(&self, bounds: [f64; 4]) -> Self {
        Self::new(
            HalfPlane::sides_of_box(bounds)
                .iter()
                .fold(self.points.clone(), |p, side| side.clip(&p)),
        )
    }

    /// The polygon with every vertex within `tolerance` of a side of the box
    /// `[x0, y0, x1, y1]` (or outside it) moved onto that side.
    pub fn snapped_to_box(&self, [x0, y0, x1, y1]: [f64; 4], tolerance: f64) -> Self {
        let snap = |v: f64, lo: f64, hi: f64| {
            if v < lo + tolerance {
                lo
            } else if v > hi - tolerance {
                hi
            } else {
                v
            }
        };
        Self::new(
            self.points
                .iter()
                .map(|p| [snap(p[0], x0, x1), snap(p[1], y0, y1)])
                .collect(),
        )
    }

    /// True when `p` lies inside (even-odd rule; points exactly on an edge
    /// may go either way).
    pub fn contains(&self, p: Point) -> bool {
        let mut inside = false;
        let n = self.points.len();
        let mut j = n.wrapping_sub(1);
        for i in 0..n {
            let a = self.points[i];
            let b = self.points[j];
            if (a[1] > p[1]) != (b[1] > p[1]) {
                let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
                if p[0] < x {
                    inside = !inside;
                }
            }
            j = i;
        }
        inside
    }

    /// A `width * height` row-major mask of the pixels whose centres lie
    /// inside (even-odd rule, scan-line fill: O(pixels + edges * rows)).
    pub fn rasterize(&self, width: u32, height: u32) -> Vec<bool> {
        let (w, h) = (width as usize, height as usize);
        let mut mask = vec![false; w * h];
        let mut crossings: Vec<f64> = Vec::new();
        for y in 0..h {
            let py = y as f64;
            crossings.clear();
            for (a, b) in self.edges() {
                if (a[1] > py) != (b[1] > py) {
                    crossings.push(a[0] + (py - a[1]) / (b[1] - a[1]) * (b[0] - a[0]));
                }
            }
            crossings.sort_by(|p, q| p.total_cmp(q));
            for pair in crossings.chunks_exact(2) {
                // Pixel centres x with pair[0] < x < pair[1] (approximately; a
                // centre exactly on the left crossing counts as inside).
                let start = pair[0].ceil().max(0.0) as usize;
                let end_f = pair[1].ceil().min(w as f64);
                if end_f <= 0.0 {
                    continue;
                }
                let end = end_f as usize;
                if start < end {
                    mask[y * w + start..y * w + end].fill(true);
                }
            }
        }
        mask
    }
}

/// The points `p` with `normal . p >= offset`: one side of a line. A
/// tracked object cut by the image border carries the border's half-plane
/// with it (see [`crate::fit::RigidTemplate::cuts`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct HalfPlane {
    /// Normal pointing into the half-plane (unit length for [`HalfPlane::depth`]
    /// to be a distance).
    pub normal: Point,
    /// `normal . p` on the boundary line.
    pub offset: f64,
}

impl HalfPlane {
    /// The four half-planes whose intersection is the box `[x0, y0, x1, y1]`.
    pub fn sides_of_box([x0, y0, x1, y1]: [f64; 4]) -> [Self; 4] {
        [
            Self::new([1.0, 0.0], x0),
            Self::new([0.0, 1.0], y0),
            Self::new([-1.0, 0.0], -x1),
            Self::new([0.0, -1.0], -y1),
        ]
    }

    /// The half-plane `normal . p >= offset`.
    pub const fn new(normal: Point, offset: f64) -> Self {
        Self { normal, offset }
    }

    /// Signed distance of `p` inside the half-plane (negative outside).
    #[inline]
    pub fn depth(&self, p: Point) -> f64 {
        self.normal[0] * p[0] + self.normal[1] * p[1] - self.offset
    }

    /// The half-plane after rotating the plane by `theta` about the origin
    /// and moving it by `shift` (the motion that places a template).
    pub fn moved(&self, theta: f64, shift: Point) -> Self {
        let (s, c) = theta.sin_cos();
        let [nx, ny] = self.normal;
        let normal = [c * nx - s * ny, s * nx + c * ny];
        Self::new(normal, self.offset + normal[0] * shift[0] + normal[1] * shift[1])
    }

    /// The part of the polygon `poly` inside (Sutherland-Hodgman against one
    /// half-plane; the area is exact also for non-convex input).
    pub fn clip(&self, poly: &[Point]) -> Vec<Point> {
        let mut out = Vec::with_capacity(poly.len() + 4);
        let len = poly.len();
        for i in 0..len {
            let a = poly[i];
            let b = poly[(i + 1) % len];
            let (da, db) = (self.depth(a), self.depth(b));
            if da >= 0.0 {
                out.push(a);
            }
            if (da >= 0.0) != (db >= 0.0) {
                let t = da / (da - db);
                out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        }
        out
    }
}

/// Eigenvalues of the symmetric 2x2 matrix `[[a, b], [b, c]]` given as
/// `[a, b, c]`, smallest first.
pub fn symmetric_eigenvalues([a, b, c]: [f64; 3]) -> [f64; 2] {
    let mean = 0.5 * (a + c);
    let root = (0.25 * (a - c).powi(2) + b * b).sqrt();
    [mean - root, mean + root]
}

/// The solution of the 3x3 linear system `m x = v` by Cramer's rule;
/// `None` unless the determinant's magnitude exceeds `min_abs_det` (the
/// caller's scale for a degenerate system). Used for small least-squares
/// normal equations (an edge profile, a circle fit).
pub fn solve3(m: &[[f64; 3]; 3], v: &[f64; 3], min_abs_det: f64) -> Option<[f64; 3]> {
    let det3 = |a: &[[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let d = det3(m);
    if d.is_nan() || d.abs() <= min_abs_det {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut a = *m;
        for r in 0..3 {
            a[r][k] = v[r];
        }
        *xk = det3(&a) / d;
    }
    Some(x)
}

/// A point carried rigidly with a tracked contour: fixed relative to the
/// contour's centroid and orientation when it is made, placed again from a
/// later centroid and orientation. It tells where a contour puts a point
/// that its own centroid does not follow (an object's centroid, when only
/// the part inside the image is tracked).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CarriedPoint {
    offset: Point,
    angle: f64,
}

impl CarriedPoint {
    /// `point` relative to a contour with this `centroid` and orientation
    /// `angle` (radians, as [`Polygon::orientation`]).
    pub fn new(point: Point, centroid: Point, angle: f64) -> Self {
        Self {
            offset: [point[0] - centroid[0], point[1] - centroid[1]],
            angle,
        }
    }

    /// The point for the contour at `centroid` and orientation `angle`. The
    /// turn is taken modulo pi, the period of an orientation.
    pub fn at(&self, centroid: Point, angle: f64) -> Point {
        let half = std::f64::consts::FRAC_PI_2;
        let turn = (angle - self.angle + half).rem_euclid(std::f64::consts::PI) - half;
        let (sin, cos) = turn.sin_cos();
        let [x, y] = self.offset;
        [centroid[0] + x * cos - y * sin, centroid[1] + x * sin + y * cos]
    }
}

/// Euclidean distance between two points.
#[inline]
pub fn dist(a: Point, b: Point) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Distance from `p` to the segment a-b.
pub fn segment_distance(p: Point, a: Point, b: Point) -> f64 {
    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
    let t = (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / (ex * ex + ey * ey).max(1e-18)).clamp(0.0, 1.0);
    (p[0] - a[0] - t * ex).hypot(p[1] - a[1] - t * ey)
}

/// Distance between the segments a-b and c-d when they do not cross.
pub fn segments_distance(a: Point, b: Point, c: Point, d: Point) -> f64 {
    segment_distance(a, c, d)
        .min(segment_distance(b, c, d))
        .min(segment_distance(c, a, b))
        .min(segment_distance(d, a, b))
}

/// True when segments a-b and c-d share a point (touching counts).
pub fn segments_intersect(a: Point, b: Point, c: Point, d: Point) -> bool {
    let orient = |p: Point, q: Point, r: Point| (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    let (d1, d2) = (orient(c, d, a), orient(c, d, b));
    let (d3, d4) = (orient(a, b, c), orient(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    let on_segment = |p: Point, q: Point, r: Point| {
        r[0] >= p[0].min(q[0]) && r[0] <= p[0].max(q[0]) && r[1] >= p[1].min(q[1]) && r[1] <= p[1].max(q[1])
    };
    (d1 == 0.0 && on_segment(c, d, a))
        || (d2 == 0.0 && on_segment(c, d, b))
        || (d3 == 0.0 && on_segment(a, b, c))
        || (d4 == 0.0 && on_segment(a, b, d))
}

/// Intersection over union of two equally sized masks (1.0 when both are empty).
pub fn mask_iou(a: &[bool], b: &[bool]) -> f64 {
    assert_eq!(a.len(), b.len(), "masks must have equal size");
    let (mut inter, mut union) = (0usize, 0usize);
    for (&p, &q) in a.iter().zip(b) {
        inter += (p && q) as usize;
        union += (p || q) as usize;
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

/// Intersection over union of the regions of two polygons, on the pixel
/// grid of their common bounding box (pixel centres inside).
pub fn polygon_iou(a: &Polygon, b: &Polygon) -> f64 {
    let ([ax0, ay0, ax1, ay1], [bx0, by0, bx1, by1]) = (a.bounds(), b.bounds());
    let (x0, y0) = (ax0.min(bx0).floor() - 1.0, ay0.min(by0).floor() - 1.0);
    let (w, h) = (
        (ax1.max(bx1) - x0).ceil() as u32 + 2,
        (ay1.max(by1) - y0).ceil() as u32 + 2,
    );
    let shift = [-x0, -y0];
    mask_iou(
        &a.translated(shift).rasterize(w, h),
        &b.translated(shift).rasterize(w, h),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_3x3_system_is_solved_and_a_singular_one_refused() {
        let x = solve3(
            &[[2.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 4.0]],
            &[3.0, 5.0, 5.0],
            1e-12,
        )
        .unwrap();
        assert!(x.iter().all(|v| (v - 1.0).abs() < 1e-12), "{x:?}");
        assert!(solve3(
            &[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]],
            &[1.0, 2.0, 3.0],
            1e-12
        )
        .is_none());
    }

    #[test]
    fn a_carried_point_turns_and_moves_with_its_contour() {
        let carried = CarriedPoint::new([12.0, 5.0], [10.0, 5.0], 0.3);
        // Moved by (3, -1) and turned by a quarter turn.
        let p = carried.at([13.0, 4.0], 0.3 + std::f64::consts::FRAC_PI_2 - 1e-9);
        assert!((p[0] - 13.0).abs() < 1e-6 && (p[1] - 6.0).abs() < 1e-6, "{p:?}");
        // An orientation that wrapped by pi is no turn.
        let q = carried.at([10.0, 5.0], 0.3 - std::f64::consts::PI);
        assert!((q[0] - 12.0).abs() < 1e-9 && (q[1] - 5.0).abs() < 1e-9, "{q:?}");
    }

    #[test]
    fn polygon_iou_of_overlapping_squares() {
        let a = rect(0.0, 0.0, 10.0, 10.0);
        let b = rect(5.0, 0.0, 15.0, 10.0);
        let iou = polygon_iou(&a, &b);
        assert!((iou - 1.0 / 3.0).abs() < 0.02, "{iou}");
        assert_eq!(polygon_iou(&a, &a), 1.0);
    }

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Polygon {
        Polygon::new(vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    }

    #[test]
    fn rectangle_measures() {
        let r = rect(2.0, 3.0, 12.0, 7.0);
        assert!((r.area() - 40.0).abs() < 1e-12);
        assert!((r.length() - 28.0).abs() < 1e-12);
        let c = r.centroid();
        assert!((c[0] - 7.0).abs() < 1e-12 && (c[1] - 5.0).abs() < 1e-12);
        // Long axis along x.
        assert!(r.orientation().abs() < 1e-12);
        let rot = r.rotated_about(c, 0.3);
        assert!((rot.orientation() - 0.3).abs() < 1e-9);
        assert!((rot.area() - 40.0).abs() < 1e-9);
        // A uniform strip of length L has standard deviation L / sqrt(12)
        // along it, whatever its rotation.
        let [long, short] = rot.principal_spreads();
        assert!((long - 10.0 / 12f64.sqrt()).abs() < 1e-9, "{long}");
        assert!((short - 4.0 / 12f64.sqrt()).abs() < 1e-9, "{short}");
    }

    #[test]
    fn end_area_is_the_area_near_the_far_end() {
        // A 40 x 10 bar ending in a triangle 10 long: within 10 of the tip
        // lies the triangle (50), within 20 the triangle and 10 of bar.
        let tool = Polygon::new(vec![
            [0.0, 0.0],
            [40.0, 0.0],
            [50.0, 5.0],
            [40.0, 10.0],
            [0.0, 10.0],
        ]);
        assert!((tool.end_area([1.0, 0.0], 10.0) - 50.0).abs() < 1e-9);
        assert!((tool.end_area([1.0, 0.0], 20.0) - 150.0).abs() < 1e-9);
        // The other end is square.
        assert!((tool.end_area([-1.0, 0.0], 10.0) - 100.0).abs() < 1e-9);
        assert_eq!(Polygon::new(vec![]).end_area([1.0, 0.0], 10.0), 0.0);
    }

    #[test]
    fn circle_area_and_resampling() {
        let c = Polygon::circle([50.0, 40.0], 20.0, 400);
        assert!((c.area() - std::f64::consts::PI * 400.0).abs() < 1.0);
        let r = c.resampled(37);
        assert_eq!(r.len(), 37);
        let spacing: Vec<f64> = r.edges().map(|(a, b)| dist(a, b)).collect();
        let mean = spacing.iter().sum::<f64>() / spacing.len() as f64;
        assert!(
            spacing.iter().all(|s| (s - mean).abs() < 0.05 * mean),
            "{spacing:?}"
        );
    }

    #[test]
    fn rasterize_matches_contains() {
        let p = Polygon::new(vec![
            [3.3, 2.2],
            [30.7, 5.1],
            [25.2, 28.9],
            [14.0, 15.5],
            [4.1, 24.6],
        ]);
        let mask = p.rasterize(40, 32);
        let mut differ = 0;
        for y in 0..32 {
            for x in 0..40 {
                if mask[y * 40 + x] != p.contains([x as f64, y as f64]) {
                    differ += 1;
                }
            }
        }
        assert_eq!(differ, 0);
        let count = mask.iter().filter(|&&m| m).count() as f64;
        assert!((count - p.area()).abs() < 0.05 * p.area());
    }

    #[test]
    fn offset_grows_a_circle_by_the_distance() {
        for c in [Polygon::circle([0.0, 0.0], 10.0, 360), {
            let mut p = Polygon::circle([0.0, 0.0], 10.0, 360);
            p.points.reverse();
            p
        }] {
            let grown = c.offset_along_normals(1.5);
            assert!(
                (grown.area() - std::f64::consts::PI * 11.5f64.powi(2)).abs() < 0.5,
                "{}",
                grown.area()
            );
        }
    }

    #[test]
    fn simple_and_self_crossing_outlines() {
        assert!(Polygon::circle([5.0, 5.0], 20.0, 500).is_simple());
        assert!(rect(0.0, 0.0, 3.0, 2.0).is_simple());
        // A bow tie crosses itself.
        let bow = Polygon::new(vec![[0.0, 0.0], [10.0, 10.0], [10.0, 0.0], [0.0, 10.0]]);
        assert!(!bow.is_simple());
        // A circle with one vertex pushed across the far side.
        let mut c = Polygon::circle([0.0, 0.0], 10.0, 60);
        c.points[0] = [-15.0, 0.5];
        assert!(!c.is_simple());
    }

    #[test]
    fn iou_of_shifted_masks() {
        let a = rect(0.0, 0.0, 10.0, 10.0).rasterize(20, 20);
        let b = rect(5.0, 0.0, 15.0, 10.0).rasterize(20, 20);
        let iou = mask_iou(&a, &b);
        assert!((iou - 50.0 / 150.0).abs() < 1e-9, "{iou}");
    }
}
