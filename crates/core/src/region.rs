//! Region statistics in O(contour length): pixel count and intensity sum
//! inside a polygon from line integrals along its edges (Green's theorem), and
//! sums over axis-aligned windows, both continuous in sub-pixel positions.
//!
//! Image model: pixel (x, y) is a box of constant intensity covering
//! [x - 0.5, x + 0.5) x [y - 0.5, y + 0.5) (pixel centres at integers, as in
//! the rest of semdepth). With the row-wise cumulative sum
//! F(x, y) = integral of I(t, y) for t from the area's left edge to x,
//! the sum over a polygon's interior is the line integral of F dy around it.
//! Each edge is split where it crosses a pixel row boundary. Within a row, F
//! is piecewise linear in x, so its integral G(x) (tabulated per row) is
//! piecewise quadratic, and along a straight piece, where x is linear in y,
//! the integral of F dy is exactly (dy/dx) (G(x_b) - G(x_a)). The result is
//! the exact integral of the box model: continuous in the vertex positions,
//! which is what lets the rigid search reach sub-pixel accuracy (method note,
//! section 2). Cost: one step per row crossed. (Splitting at every column
//! crossing too and using the midpoint rule is also exact but took 24 ns
//! per crossing and about 1.7x as many steps.)
//!
//! Window sums use a summed-area table; bilinear interpolation of it is the
//! exact integral of the box model over a rectangle with real-valued corners.
//! (Summing rows instead saves building the table but cost more per
//! evaluation: 3.08 against 2.74 ms per 1024x768 tracking step.) The table
//! is stored every few rows only, and F not at all (see [`PrefixSums`]).
//!
//! Sums are built over a rectangular [`PixelRect`] of the image only (the area
//! the contour can reach), so a tracking step never touches the whole frame.
//! [`PrefixSums::split`] goes further for a contour that moves a short way:
//! G only where the contour can be, and the window sums from table rows only
//! where the window's top and bottom edges can be.

use crate::geometry::Point;
use crate::imageio::GrayFrame;

/// A rectangle of whole pixels: columns `x..x + width`, rows `y..y + height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    /// First column.
    pub x: u32,
    /// First row.
    pub y: u32,
    /// Number of columns (>= 1).
    pub width: u32,
    /// Number of rows (>= 1).
    pub height: u32,
}

impl PixelRect {
    /// The whole frame.
    pub fn full(frame: &GrayFrame) -> Self {
        Self::full_size(frame.width, frame.height)
    }

    /// A whole `width` x `height` frame.
    pub fn full_size(width: u32, height: u32) -> Self {
        Self {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// This rectangle clipped to `frame`, at least one pixel (a rectangle
    /// wholly outside keeps the frame's last row or column).
    pub fn clipped_to(self, frame: &GrayFrame) -> Self {
        let (x, y) = (self.x.min(frame.width - 1), self.y.min(frame.height - 1));
        Self {
            x,
            y,
            width: self.width.min(frame.width - x).max(1),
            height: self.height.min(frame.height - y).max(1),
        }
    }

    /// [`PixelRect::covering`] the box `[x0, y0, x1, y1]` grown by `reach`
    /// on every side.
    pub fn around([x0, y0, x1, y1]: [f64; 4], reach: f64, width: u32, height: u32) -> Option<Self> {
        Self::covering(x0 - reach, y0 - reach, x1 + reach, y1 + reach, width, height)
    }

    /// The pixels whose boxes meet the continuous box `[x0, x1] x [y0, y1]`,
    /// clipped to a `width` x `height` image; `None` when nothing is left.
    pub fn covering(x0: f64, y0: f64, x1: f64, y1: f64, width: u32, height: u32) -> Option<Self> {
        let cx0 = (x0 + 0.5).floor().max(0.0);
        let cy0 = (y0 + 0.5).floor().max(0.0);
        let cx1 = ((x1 + 0.5).floor()).min(width as f64 - 1.0);
        let cy1 = ((y1 + 0.5).floor()).min(height as f64 - 1.0);
        if !(cx0 <= cx1 && cy0 <= cy1) {
            return None;
        }
        Some(Self {
            x: cx0 as u32,
            y: cy0 as u32,
            width: (cx1 - cx0) as u32 + 1,
            height: (cy1 - cy0) as u32 + 1,
        })
    }

    /// Continuous extent `[x0, y0, x1, y1]` of the pixel boxes.
    pub fn extent(&self) -> [f64; 4] {
        [
            self.x as f64 - 0.5,
            self.y as f64 - 0.5,
            (self.x + self.width) as f64 - 0.5,
            (self.y + self.height) as f64 - 0.5,
        ]
    }
}

/// Count and intensity sum of a region.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RegionSum {
    /// Area in pixels (continuous).
    pub count: f64,
    /// Integral of the intensity over the area.
    pub sum: f64,
}

impl RegionSum {
    /// Mean intensity (0 for an empty region).
    pub fn mean(&self) -> f64 {
        if self.count > 0.0 {
            self.sum / self.count
        } else {
            0.0
        }
    }
}

/// What a run of polygon edges (an open path) contributes to the region
/// sums: paths that join into a closed chain add up to the enclosed
/// region ([`PathSum::region`]). Lets polygons that share edges (the
/// occlusion bands share the contour) walk them once.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathSum {
    /// Twice the signed area swept (shoelace terms of the edges).
    pub twice_area: f64,
    /// Signed intensity integral along the edges (see
    /// [`PrefixSums::edge_integral`]).
    pub sum: f64,
}

impl std::ops::Add for PathSum {
    type Output = Self;
    fn add(self, other: Self) -> Self {
        Self {
            twice_area: self.twice_area + other.twice_area,
            sum: self.sum + other.sum,
        }
    }
}

impl PathSum {
    /// The region enclosed by a closed chain of paths, in either orientation.
    pub fn region(self) -> RegionSum {
        let sign = if self.twice_area < 0.0 { -1.0 } else { 1.0 };
        RegionSum {
            count: 0.5 * self.twice_area.abs(),
            sum: self.sum * sign,
        }
    }
}

/// Row-wise integrals of the cumulative sums and a summed-area table over a
/// rectangle of an image, with intensities `sample + offset` (the offset
/// keeps them positive for the `z ln z` energy).
///
/// Building the tables is a large part of a tracking step (they cover the
/// object, its window and the search reach: 450x450 pixels per view for the
/// 1024x768 benchmark), so they are kept small: per pixel one f64 (G) plus a
/// quarter of one (the summed-area table is stored every
/// [`PrefixSums::SAT_ROW_STEP`] rows; the rows between are added from G when
/// a window corner falls there). F, the row-wise cumulative sum, is not
/// stored: it follows from G and the pixel itself. Three full f64 tables
/// (F, G, summed-area) took 1.4 of 3.9 ms per 1024x768 step; these take
/// 0.5 of 2.9 ms.
#[derive(Debug)]
pub struct PrefixSums<'a> {
    /// The image the tables were built from (pixel values for F).
    frame: &'a GrayFrame,
    /// Added to every sample.
    offset: f64,
    /// The covered pixels.
    rect: PixelRect,
    /// Count and sum over the reference area, whose mean scales the energy
    /// (`m_ref`): the covered area unless set by
    /// [`PrefixSums::with_reference`].
    reference: RegionSum,
    /// Row stride of `g` and `sat`: `rect.width + 1`.
    stride: usize,
    /// `g[r * stride + c]`: G, the integral of F over the first `c` pixels
    /// of row `r` (G at the left edge of pixel c), where F is the sum of the
    /// first pixels of the row.
    g: Vec<f64>,
    /// `sat[k * stride + c]`: sum of the pixels in rows `< k * SAT_ROW_STEP`,
    /// columns `< c` (a summed-area table kept every `SAT_ROW_STEP` rows).
    /// Empty when `window` serves the window sums.
    sat: Vec<f64>,
    /// Tables built by [`PrefixSums::split`]: the window sums come from
    /// these rows over a larger area instead of from `sat`.
    window: Option<WindowRows>,
    /// How far inside `rect` a polygon must stay to count as contained
    /// (0 unless built by [`PrefixSums::split`], whose callers also sum
    /// bands this far outside their contours).
    guard: f64,
}

/// Rows of a summed-area table over the area window sums come from, stored
/// only where a window's top or bottom edge can lie (see
/// [`PrefixSums::split`]).
#[derive(Debug)]
struct WindowRows {
    /// The covered pixels.
    rect: PixelRect,
    /// Row stride of `sat`: `rect.width + 1`.
    stride: usize,
    /// `slot[r]` (local rows `0..=height`): where table row `r` (the sums
    /// over rows `< r`) is stored in `sat`, or [`WindowRows::NOT_STORED`].
    slot: Vec<u32>,
    /// The stored rows, `stride` entries each: entry `c` sums columns `< c`.
    sat: Vec<f64>,
}

impl Clone for PrefixSums<'_> {
    fn clone(&self) -> Self {
        let window = self.window.as_ref().map(|w| WindowRows {
            rect: w.rect,
            stride: w.stride,
            slot: w.slot.clone(),
            sat: TablePool::copy(&w.sat),
        });
        Self {
            g: TablePool::copy(&self.g),
            sat: TablePool::copy(&self.sat),
            window,
            ..*self
        }
    }
}

impl Drop for PrefixSums<'_> {
    fn drop(&mut self) {
        TablePool::give(std::mem::take(&mut self.g));
        TablePool::give(std::mem::take(&mut self.sat));
        if let Some(window) = self.window.as_mut() {
            TablePool::give(std::mem::take(&mut window.sat));
        }
    }
}

/// True when every point lies in the box `[x0, y0, x1, y1]` (edges
/// included).
fn all_within(points: &[Point], [x0, y0, x1, y1]: [f64; 4]) -> bool {
    points
        .iter()
        .all(|p| p[0] >= x0 && p[0] <= x1 && p[1] >= y0 && p[1] <= y1)
}

impl<'a> PrefixSums<'a> {
    /// Rows between two stored rows of the summed-area table. A window
    /// lookup adds up to this many rows of F per corner; 4 keeps that under
    /// 5% of an energy evaluation and the table at 2 bytes per pixel.
    pub const SAT_ROW_STEP: usize = 4;

    /// Builds the tables over `rect` (clipped to the frame) in one pass;
    /// `offset` is added to every sample. Exact for areas up to 65536
    /// pixels on a side (every decoder limits frames to 8192).
    pub fn new(frame: &'a GrayFrame, rect: PixelRect, offset: u16) -> Self {
        let rect = rect.clipped_to(frame);
        let (g, sat) = build_tables::<true>(frame, rect, offset);
        Self::assemble(frame, offset, rect, g, sat, None, 0.0)
    }

    /// Tables for a fit that moves a known contour a short way: G over
    /// `polygons` (clipped to the frame), where the contours and the bands
    /// summed around them can lie, and the window sums over `windows`, from
    /// a summed-area table stored only at the rows of `edge_rows`, the
    /// spans of y (image coordinates) where a window's top or bottom edge
    /// can lie. A polygon counts as contained only `guard` px inside
    /// `polygons` ([`PrefixSums::contains`]), and a window as covered only
    /// when its edges lie in those rows ([`PrefixSums::covers_window`]).
    ///
    /// A tracker's windows reach far past its contours (margin 0.3 x the
    /// object's size): for the 1024x768 benchmark blob, G over the window
    /// area took 417 px a side, against 310 for the contour's reach, and
    /// the step went from 0.83 to 0.74 ms (minimum, alternated).
    pub fn split(
        frame: &'a GrayFrame,
        polygons: PixelRect,
        guard: f64,
        windows: PixelRect,
        edge_rows: &[[f64; 2]],
        offset: u16,
    ) -> Self {
        let rect = polygons.clipped_to(frame);
        let (g, _) = build_tables::<false>(frame, rect, offset);
        let window = WindowRows::new(frame, windows.clipped_to(frame), edge_rows, offset);
        Self::assemble(frame, offset, rect, g, Vec::new(), Some(window), guard.max(0.0))
    }

    /// The tables with the whole covered area as the reference area.
    fn assemble(
        frame: &'a GrayFrame,
        offset: u16,
        rect: PixelRect,
        g: Vec<f64>,
        sat: Vec<f64>,
        window: Option<WindowRows>,
        guard: f64,
    ) -> Self {
        let mut sums = Self {
            frame,
            offset: f64::from(offset),
            rect,
            reference: RegionSum::default(),
            stride: rect.width as usize + 1,
            g,
            sat,
            window,
            guard,
        };
        sums.reference = sums.total();
        sums
    }

    /// The same tables with `area` (clipped to the covered area) as the
    /// reference area: a caller that builds tables of different reaches
    /// around one object keeps its energies comparable by giving them all
    /// the same reference.
    pub fn with_reference(mut self, area: PixelRect) -> Self {
        let [x0, y0, x1, y1] = area.extent();
        self.reference = self.rect_sum(x0, y0, x1, y1);
        self
    }

    /// Mean intensity of the reference area (`m_ref` of the energy).
    pub fn reference_mean(&self) -> f64 {
        self.reference.mean()
    }

    /// The covered pixels.
    pub fn rect(&self) -> PixelRect {
        self.rect
    }

    /// Continuous extent `[x0, y0, x1, y1]` of the whole image the tables
    /// were built from.
    pub fn image_extent(&self) -> [f64; 4] {
        PixelRect::full(self.frame).extent()
    }

    /// True when every vertex lies inside the covered area (so the polygon's
    /// sums are exact, not clamped).
    pub fn contains(&self, points: &[Point]) -> bool {
        all_within(points, self.polygon_extent())
    }

    /// True when every vertex lies inside the covered area itself, the
    /// guard of [`PrefixSums::split`] not deducted: a polygon that is a
    /// band's outer edge (the guard is the room left for such bands
    /// around contours that [`PrefixSums::contains`]).
    pub fn covers(&self, points: &[Point]) -> bool {
        all_within(points, self.rect.extent())
    }

    /// True when the box `[x0, y0, x1, y1]` (e.g. a polygon's bounding box)
    /// lies inside the covered area: the same test as [`PrefixSums::contains`]
    /// for a caller that has the bounding box already.
    pub fn contains_box(&self, [x0, y0, x1, y1]: [f64; 4]) -> bool {
        let [ex0, ey0, ex1, ey1] = self.polygon_extent();
        x0 >= ex0 && y0 >= ey0 && x1 <= ex1 && y1 <= ey1
    }

    /// Where a contained polygon may lie: the covered area less the guard.
    fn polygon_extent(&self) -> [f64; 4] {
        let [x0, y0, x1, y1] = self.rect.extent();
        let d = self.guard;
        [x0 + d, y0 + d, x1 - d, y1 - d]
    }

    /// True when the window `[x0, y0, x1, y1]` lies inside the covered area
    /// on every side where that area does not end at the image border:
    /// then [`PrefixSums::rect_sum`] clips it only where the image ends.
    pub fn covers_window(&self, window: [f64; 4]) -> bool {
        match &self.window {
            Some(rows) => rows.covers(self.frame, window),
            None => covers_in(self.rect, self.frame, window),
        }
    }

    /// Signed intensity integral along the edge a -> b: the integral of
    /// F(x, y) dy. Summed over a closed polygon it is the interior's intensity
    /// sum, with the sign of the polygon's signed area.
    #[inline]
    pub fn edge_integral(&self, a: Point, b: Point) -> f64 {
        let (a, b) = (self.local(a), self.local(b));
        self.edge_sum(a, b, self.vertex_g(a), self.vertex_g(b))
    }

    /// A point in local coordinates: pixel (c, r) of the rect covers u in
    /// [c, c+1), v in [r, r+1).
    #[inline(always)]
    fn local(&self, p: Point) -> Point {
        [
            p[0] - (self.rect.x as f64 - 0.5),
            p[1] - (self.rect.y as f64 - 0.5),
        ]
    }

    /// The row a local v lies in, clamped to the area: the part of an edge
    /// above (below) the area counts as part of the first (last) row.
    #[inline(always)]
    fn row_of(&self, v: f64) -> usize {
        cell(v.max(0.0)).min(self.rect.height as usize - 1)
    }

    /// G at a local point, in the row it lies in: what the pieces of both
    /// edges meeting there look up at that end.
    #[inline(always)]
    fn vertex_g(&self, p: Point) -> f64 {
        self.g(self.row_at(self.row_of(p[1])), p[0])
    }

    /// The integral of F dv along the local edge a -> b, given G at both
    /// ends ([`PrefixSums::vertex_g`]).
    ///
    /// Walked downwards, the edge is split into pieces at the row
    /// boundaries v = k it crosses; in row r the piece from u to u' adds
    /// (G_r(u') - G_r(u)) / slope. Grouped by boundary instead of by piece,
    /// that is (G at the bottom end - G at the top end + the sum over the
    /// boundaries of G_{k-1}(u_k) - G_k(u_k)) / slope: one lookup of both
    /// rows per boundary, with one column and fraction, and the ends' G
    /// shared with the neighbouring edges. (Walking piece by piece, with
    /// two lookups per boundary and the ends' pieces treated apart, took
    /// about 25 ns more per edge.)
    #[inline(always)]
    fn edge_sum(&self, a: Point, b: Point, g_a: f64, g_b: f64) -> f64 {
        let (top, bottom, g_top, g_bottom, sign) = if b[1] > a[1] {
            (a, b, g_a, g_b, 1.0)
        } else if b[1] < a[1] {
            (b, a, g_b, g_a, -1.0)
        } else {
            return 0.0;
        };
        // du/dv: one division per edge.
        let slope = (bottom[0] - top[0]) / (bottom[1] - top[1]);
        // Boundaries k with top < k <= bottom (a vertex on a boundary ends
        // its edge in the row above), inside the area.
        let (first, last) = (self.row_of(top[1]) + 1, self.row_of(bottom[1]));
        let u_at = |k: usize| top[0] + slope * (k as f64 - top[1]);
        if slope.abs() <= 1e-3 {
            // (Nearly) vertical: dividing by the slope would lose the
            // digits, and F is (all but) constant across each piece.
            let mut sum = 0.0;
            let (mut u, mut v, mut row) = (top[0], top[1], first - 1);
            for k in first..=last {
                let u_next = u_at(k);
                sum += self.f(self.row_at(row), 0.5 * (u + u_next)) * (k as f64 - v);
                (u, v, row) = (u_next, k as f64, k);
            }
            sum += self.f(self.row_at(row), 0.5 * (u + bottom[0])) * (bottom[1] - v);
            return sign * sum;
        }
        let mut sum = g_bottom - g_top;
        if top[0].min(bottom[0]) > 0.0 && top[0].max(bottom[0]) < self.rect.width as f64 {
            // Every crossing lies inside the area's columns. Stepping u and
            // the row starts from boundary to boundary instead of computing
            // them for each: 20% fewer instructions per crossing.
            let mut u = u_at(first);
            let mut below = self.row_at(first);
            for _ in first..=last {
                sum += self.g_step_down(below, u);
                u += slope;
                below.table += self.stride;
                below.samples += self.frame.width as usize;
            }
        } else {
            for k in first..=last {
                let u = u_at(k);
                sum += self.g(self.row_at(k - 1), u) - self.g(self.row_at(k), u);
            }
        }
        sign * sum / slope
    }

    /// G in the row above `below` minus G in row `below` at local `u`, for
    /// `0 < u < width` and `below` not the first row: [`PrefixSums::g`] in
    /// both rows with one column and fraction.
    #[inline(always)]
    fn g_step_down(&self, below: RowStart, u: f64) -> f64 {
        let c = cell(u);
        let t = u - c as f64;
        let above = below.table - self.stride;
        let (a0, a1) = (self.g[above + c], self.g[above + c + 1]);
        let (b0, b1) = (self.g[below.table + c], self.g[below.table + c + 1]);
        let above_sample = self.frame.data[below.samples - self.frame.width as usize + c];
        let di = f64::from(above_sample) - f64::from(self.frame.data[below.samples + c]);
        (a0 - b0) + t * ((a1 - a0) - (b1 - b0)) - 0.5 * t * (1.0 - t) * di
    }

    /// Where local row `r` starts in `g` and in the frame's samples.
    #[inline(always)]
    fn row_at(&self, r: usize) -> RowStart {
        RowStart {
            table: r * self.stride,
            samples: (self.rect.y as usize + r) * self.frame.width as usize + self.rect.x as usize,
        }
    }

    /// Sample plus offset of local pixel `c` in a row.
    #[inline(always)]
    fn pixel(&self, row: RowStart, c: usize) -> f64 {
        self.frame.data[row.samples + c] as f64 + self.offset
    }

    /// F at the left edge of local pixel `c` (`c <= width`): from
    /// G(c) - G(c-1) = F(c-1) + I(c-1)/2 and F(c) = F(c-1) + I(c-1).
    #[inline(always)]
    fn f_at_edge(&self, row: RowStart, c: usize) -> f64 {
        if c == 0 {
            return 0.0;
        }
        self.g[row.table + c] - self.g[row.table + c - 1] + 0.5 * self.pixel(row, c - 1)
    }

    /// F at local u in `row` (0 left of the area, the row total right of
    /// it).
    #[inline(always)]
    fn f(&self, row: RowStart, u: f64) -> f64 {
        let w = self.rect.width as usize;
        let u = u.clamp(0.0, w as f64);
        let c = cell(u).min(w - 1);
        let t = u - c as f64;
        // F(c) + t I(c), with F(c) = G(c+1) - G(c) - I(c)/2.
        self.g[row.table + c + 1] - self.g[row.table + c] + (t - 0.5) * self.pixel(row, c)
    }

    /// G (the integral of F from the area's left edge) at local u in `row`;
    /// linear beyond the right edge, 0 left of the area.
    #[inline(always)]
    fn g(&self, row: RowStart, u: f64) -> f64 {
        let w = self.rect.width as usize;
        if u <= 0.0 {
            return 0.0;
        }
        if u >= w as f64 {
            return self.g[row.table + w] + self.f_at_edge(row, w) * (u - w as f64);
        }
        let c = cell(u);
        let t = u - c as f64;
        // G(c) + t F(c) + t^2 I(c) / 2 with F(c) = G(c+1) - G(c) - I(c)/2:
        // linear interpolation of G less a parabola.
        let (g0, g1) = (self.g[row.table + c], self.g[row.table + c + 1]);
        g0 + t * (g1 - g0) - 0.5 * t * (1.0 - t) * self.pixel(row, c)
    }

    /// Count (absolute area) and intensity sum inside a closed polygon.
    pub fn polygon(&self, points: &[Point]) -> RegionSum {
        self.walk(points, true).region()
    }

    /// The edges `points[i] -> points[i + 1]` of an open path (no closing
    /// edge); each edge's terms are exactly those [`PrefixSums::polygon`]
    /// adds for it.
    pub fn path(&self, points: &[Point]) -> PathSum {
        self.walk(points, false)
    }

    /// The edges of `points` in order, and the closing edge back to the
    /// first vertex when `closed`.
    #[inline(always)]
    fn walk(&self, points: &[Point], closed: bool) -> PathSum {
        let n = points.len();
        let (mut twice_area, mut sum) = (0.0, 0.0);
        let Some(&first) = points.first() else {
            return PathSum::default();
        };
        // Each vertex ends one edge and starts the next: one lookup of G
        // there serves both.
        let first_local = self.local(first);
        let g_first = self.vertex_g(first_local);
        let (mut a_local, mut g_a) = (first_local, g_first);
        let edges = if closed { n } else { n - 1 };
        for i in 0..edges {
            let a = points[i];
            let (b, b_local, g_b) = if i + 1 == n {
                (first, first_local, g_first)
            } else {
                let b = points[i + 1];
                let b_local = self.local(b);
                (b, b_local, self.vertex_g(b_local))
            };
            twice_area += a[0] * b[1] - b[0] * a[1];
            sum += self.edge_sum(a_local, b_local, g_a, g_b);
            (a_local, g_a) = (b_local, g_b);
        }
        PathSum { twice_area, sum }
    }

    /// Count and sum over the continuous box `[x0, x1] x [y0, y1]` clipped to
    /// the covered area.
    pub fn rect_sum(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> RegionSum {
        if let Some(rows) = &self.window {
            return rows.rect_sum(x0, y0, x1, y1);
        }
        box_sum(self.rect, [x0, y0, x1, y1], |u, v| self.integral_at(u, v))
    }

    /// Sum over the whole covered area (the window area for tables built by
    /// [`PrefixSums::split`]).
    pub fn total(&self) -> RegionSum {
        if let Some(rows) = &self.window {
            let [x0, y0, x1, y1] = rows.rect.extent();
            return rows.rect_sum(x0, y0, x1, y1);
        }
        RegionSum {
            count: self.rect.width as f64 * self.rect.height as f64,
            sum: self.sat_at(self.rect.height as usize, self.rect.width as usize),
        }
    }

    /// The summed-area table at row `r` (`<= height`), column `c`
    /// (`<= width`): the stored row at or above, plus the rows of F between.
    #[inline]
    fn sat_at(&self, r: usize, c: usize) -> f64 {
        let k = r / Self::SAT_ROW_STEP;
        let mut s = self.sat[k * self.stride + c];
        for row in k * Self::SAT_ROW_STEP..r {
            s += self.f_at_edge(self.row_at(row), c);
        }
        s
    }

    /// Bilinear interpolation of the summed-area table at local (u, v).
    #[inline]
    fn integral_at(&self, u: f64, v: f64) -> f64 {
        let (w, h) = (self.rect.width as usize, self.rect.height as usize);
        let c = cell(u.max(0.0)).min(w - 1);
        let r = cell(v.max(0.0)).min(h - 1);
        let (fu, fv) = (u - c as f64, v - r as f64);
        let (top_left, top_right) = (self.sat_at(r, c), self.sat_at(r, c + 1));
        let row = self.row_at(r);
        let bottom_left = top_left + self.f_at_edge(row, c);
        let bottom_right = top_right + self.f_at_edge(row, c + 1);
        let top = top_left + fu * (top_right - top_left);
        let bottom = bottom_left + fu * (bottom_right - bottom_left);
        top + fv * (bottom - top)
    }
}

/// Count and sum over the continuous box `[x0, y0, x1, y1]` clipped to
/// `rect`, from a summed-area table's interpolation at local (u, v).
#[inline]
fn box_sum(rect: PixelRect, [x0, y0, x1, y1]: [f64; 4], integral_at: impl Fn(f64, f64) -> f64) -> RegionSum {
    let [ex0, ey0, ex1, ey1] = rect.extent();
    let (x0, x1) = (x0.max(ex0), x1.min(ex1));
    let (y0, y1) = (y0.max(ey0), y1.min(ey1));
    if !(x0 < x1 && y0 < y1) {
        return RegionSum::default();
    }
    let g = |x: f64, y: f64| integral_at(x - ex0, y - ey0);
    RegionSum {
        count: (x1 - x0) * (y1 - y0),
        sum: g(x1, y1) - g(x0, y1) - g(x1, y0) + g(x0, y0),
    }
}

/// True when the window `[x0, y0, x1, y1]` lies inside `rect` on every
/// side where `rect` does not end at the border of `frame`.
fn covers_in(rect: PixelRect, frame: &GrayFrame, [x0, y0, x1, y1]: [f64; 4]) -> bool {
    let [ex0, ey0, ex1, ey1] = rect.extent();
    (x0 >= ex0 || rect.x == 0)
        && (y0 >= ey0 || rect.y == 0)
        && (x1 <= ex1 || rect.x + rect.width == frame.width)
        && (y1 <= ey1 || rect.y + rect.height == frame.height)
}

impl WindowRows {
    /// Marks a table row that is not stored.
    const NOT_STORED: u32 = u32::MAX;

    /// The table rows over `rect` (clipped to the frame) that window edges
    /// in the spans `edge_rows` read, and those the whole area's sum reads.
    /// Column sums of the pixels are carried down the area and summed along
    /// at each stored row.
    fn new(frame: &GrayFrame, rect: PixelRect, edge_rows: &[[f64; 2]], offset: u16) -> Self {
        let (w, h) = (rect.width as usize, rect.height as usize);
        let stride = w + 1;
        let mut slot = vec![Self::NOT_STORED; h + 1];
        let mut wanted = vec![false; h + 1];
        // The whole area's sums (the reference, `total`) read the first two
        // and the last two rows.
        for r in [0, 1, h - 1, h] {
            wanted[r] = true;
        }
        let top = rect.y as f64 - 0.5;
        for &[lo, hi] in edge_rows {
            // An edge at local v reads rows cell(v) and cell(v) + 1 (v
            // clipped to the area, the last row's cell to h - 1).
            let row = |y: f64| cell((y - top).clamp(0.0, h as f64)).min(h - 1);
            let (first, last) = (row(lo.min(hi)), row(lo.max(hi)) + 1);
            wanted[first..=last].fill(true);
        }
        let mut stored = 0;
        for (s, _) in slot.iter_mut().zip(&wanted).filter(|(_, &w)| w) {
            *s = stored;
            stored += 1;
        }
        let mut sat = TablePool::take(stored as usize * stride);
        // Column sums of the samples alone, in u32 (below 2^32 for up to
        // 65536 rows of 16-bit samples): they vectorise, where i64 sums
        // with the offset added per sample took 2.5 instructions per pixel.
        // The offset's share, offset * rows * columns, is added per entry.
        let mut column = vec![0u32; w];
        // Row h is always stored, so every row is carried down.
        for r in 0..=h {
            if slot[r] != Self::NOT_STORED {
                let out = &mut sat[slot[r] as usize * stride..][..stride];
                out[0] = 0.0;
                let per_column = i64::from(offset) * r as i64;
                let (mut acc, mut offsets) = (0i64, 0i64);
                for (o, &c) in out[1..].iter_mut().zip(&column) {
                    acc += i64::from(c);
                    offsets += per_column;
                    *o = (acc + offsets) as f64;
                }
            }
            if r < h {
                let src = &frame.row(rect.y + r as u32)[rect.x as usize..rect.x as usize + w];
                for (c, &v) in column.iter_mut().zip(src) {
                    *c += u32::from(v);
                }
            }
        }
        Self {
            rect,
            stride,
            slot,
            sat,
        }
    }

    /// True when the window lies inside the area (except across the image
    /// border) and its top and bottom edges read stored rows.
    fn covers(&self, frame: &GrayFrame, window: [f64; 4]) -> bool {
        let [_, y0, _, y1] = window;
        let [_, ey0, _, ey1] = self.rect.extent();
        covers_in(self.rect, frame, window)
            && [y0, y1]
                .iter()
                .all(|&y| self.rows_at(y.clamp(ey0, ey1) - ey0).is_some())
    }

    /// The pixel row local `v` lies in (clamped to the area), and where the
    /// table rows above and below it start in `sat`, when both are stored.
    #[inline]
    fn rows_at(&self, v: f64) -> Option<(usize, usize, usize)> {
        let r = cell(v.max(0.0)).min(self.rect.height as usize - 1);
        let (above, below) = (self.slot[r], self.slot[r + 1]);
        if above == Self::NOT_STORED || below == Self::NOT_STORED {
            return None;
        }
        Some((r, above as usize * self.stride, below as usize * self.stride))
    }

    /// [`PrefixSums::rect_sum`] from the stored rows; the sum is NaN when a
    /// window edge falls on rows that are not stored.
    fn rect_sum(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> RegionSum {
        box_sum(self.rect, [x0, y0, x1, y1], |u, v| self.integral_at(u, v))
    }

    /// Bilinear interpolation of the table at local (u, v): the same
    /// arithmetic as [`PrefixSums`]' own table, on whole-number entries, so
    /// the sums are identical.
    #[inline]
    fn integral_at(&self, u: f64, v: f64) -> f64 {
        let Some((r, above, below)) = self.rows_at(v) else {
            return f64::NAN;
        };
        let c = cell(u.max(0.0)).min(self.rect.width as usize - 1);
        let (fu, fv) = (u - c as f64, v - r as f64);
        let (top_left, top_right) = (self.sat[above + c], self.sat[above + c + 1]);
        let (bottom_left, bottom_right) = (self.sat[below + c], self.sat[below + c + 1]);
        let top = top_left + fu * (top_right - top_left);
        let bottom = bottom_left + fu * (bottom_right - bottom_left);
        top + fv * (bottom - top)
    }
}

/// The G table over `rect` (already clipped to the frame), and with `SAT`
/// the summed-area table every [`PrefixSums::SAT_ROW_STEP`] rows (empty
/// without), in one pass.
fn build_tables<const SAT: bool>(frame: &GrayFrame, rect: PixelRect, offset: u16) -> (Vec<f64>, Vec<f64>) {
    const STEP: usize = PrefixSums::SAT_ROW_STEP;
    let (w, h) = (rect.width as usize, rect.height as usize);
    let stride = w + 1;
    let mut g = TablePool::take(stride * h);
    let mut sat = if SAT {
        TablePool::take(stride * (h / STEP + 1))
    } else {
        Vec::new()
    };
    // The sums are accumulated in integers: F and the column sums are
    // whole numbers and G a multiple of 1/2, all below 2^53 (samples
    // plus offset < 2^17 and sides <= 2^16 give F < 2^33, 2G < 2^50), so
    // the f64 tables are exactly those an f64 accumulation gave, and
    // the integer chains are shorter (measured: 1024x768 step 1.535 ->
    // 1.47 ms, reference outputs bit-identical).
    let offset_i = i64::from(offset);
    // Column sums of F over the rows so far: the summed-area table's
    // current row, stored every SAT_ROW_STEP rows.
    let mut column = vec![0i64; if SAT { stride } else { 0 }];
    let store = |sat: &mut [f64], k: usize, column: &[i64]| {
        if !SAT {
            return;
        }
        for (out, &c) in sat[k * stride..(k + 1) * stride].iter_mut().zip(column) {
            *out = c as f64;
        }
    };
    // Four rows at a time (SAT_ROW_STEP = 4): four independent chains,
    // and the column sums updated once per block with the four rows'
    // F together (measured: 1024x768 step 1.28 -> 1.19 ms, tables
    // bit-identical).
    let src_row = |r: usize| &frame.row(rect.y + r as u32)[rect.x as usize..rect.x as usize + w];
    let mut blocks = g.chunks_exact_mut(STEP * stride);
    for (b, block) in (&mut blocks).enumerate() {
        store(&mut sat, b, &column);
        let (g0, rest) = block.split_at_mut(stride);
        let (g1, rest) = rest.split_at_mut(stride);
        let (g2, g3) = rest.split_at_mut(stride);
        let r = b * STEP;
        let (s0, s1, s2, s3) = (src_row(r), src_row(r + 1), src_row(r + 2), src_row(r + 3));
        // F before and after the pixel, and twice G, per row.
        let (mut acc, mut twice) = ([0i64; STEP], [0i64; STEP]);
        for g_row in [&mut *g0, &mut *g1, &mut *g2, &mut *g3] {
            g_row[0] = 0.0;
        }
        for c in 0..w {
            let v = [s0[c], s1[c], s2[c], s3[c]];
            for j in 0..STEP {
                trapezoid_step(&mut acc[j], &mut twice[j], v[j], offset_i);
            }
            g0[c + 1] = twice[0] as f64 * 0.5;
            g1[c + 1] = twice[1] as f64 * 0.5;
            g2[c + 1] = twice[2] as f64 * 0.5;
            g3[c + 1] = twice[3] as f64 * 0.5;
            if SAT {
                column[c + 1] += acc[0] + acc[1] + acc[2] + acc[3];
            }
        }
    }
    // The table row after the last block, then the last rows (fewer
    // than four), which no stored table row follows.
    store(&mut sat, h / STEP, &column);
    let first_left = h - h % STEP;
    for (i, g_row) in blocks.into_remainder().chunks_exact_mut(stride).enumerate() {
        let src = src_row(first_left + i);
        let (mut acc, mut twice_g) = (0i64, 0i64);
        g_row[0] = 0.0;
        for (&v, g_out) in src.iter().zip(&mut g_row[1..]) {
            trapezoid_step(&mut acc, &mut twice_g, v, offset_i);
            *g_out = twice_g as f64 * 0.5;
        }
    }
    (g, sat)
}

/// Where a row of the covered area starts: in [`PrefixSums`]' G table and in
/// the frame's samples.
#[derive(Clone, Copy, Debug)]
struct RowStart {
    /// Index of the row's first entry in `g`.
    table: usize,
    /// Index of the row's first covered sample in the frame.
    samples: usize,
}

/// Per-thread pool of table buffers, so consecutive tracking steps reuse
/// memory instead of allocating (and zeroing) it: fresh allocations of this
/// size came back zeroed by `memset` and page faults, 9% of a 1024x768 step.
/// It keeps at most [`TablePool::MAX_BYTES`] per thread; the rest goes back
/// to the allocator.
struct TablePool {
    /// Spare buffers, with their old contents (every entry is overwritten
    /// before it is read).
    spares: Vec<Vec<f64>>,
    /// Capacity held, bytes.
    bytes: usize,
}

/// The integer part of a local coordinate `x >= 0` (larger than any area
/// side when `x >= 2^31`). Through `i32` because Rust's saturating `f64 as
/// usize` takes twice the instructions, and this runs at every row crossing
/// (cachegrind, same conversions: 45 -> 23 million instructions).
#[inline(always)]
fn cell(x: f64) -> usize {
    x as i32 as usize
}

/// One pixel of a row: F (`acc`, the sum so far) grows by the sample plus
/// offset, and twice G by F before and after it (F is linear over the
/// pixel, so its integral is the trapezoid).
#[inline(always)]
fn trapezoid_step(acc: &mut i64, twice_g: &mut i64, sample: u16, offset: i64) {
    let before = *acc;
    *acc += i64::from(sample) + offset;
    *twice_g += before + *acc;
}

thread_local! {
    static POOL: std::cell::RefCell<TablePool> = const {
        std::cell::RefCell::new(TablePool { spares: Vec::new(), bytes: 0 })
    };
}

impl TablePool {
    /// Most memory kept per thread (the tables of a few tracking steps of
    /// 2048x2048 frames).
    const MAX_BYTES: usize = 64 << 20;

    /// A buffer of exactly `n` entries with unspecified contents: the
    /// smallest spare that holds `n`, else a new zeroed one.
    fn take(n: usize) -> Vec<f64> {
        let reused = POOL
            .try_with(|pool| {
                let mut pool = pool.borrow_mut();
                let best = (0..pool.spares.len())
                    .filter(|&i| pool.spares[i].capacity() >= n)
                    .min_by_key(|&i| pool.spares[i].capacity())?;
                let buffer = pool.spares.swap_remove(best);
                pool.bytes -= buffer.capacity() * std::mem::size_of::<f64>();
                Some(buffer)
            })
            .ok()
            .flatten();
        let mut buffer = reused.unwrap_or_default();
        // Shrinking or keeping the length writes nothing; only growth fills.
        buffer.resize(n, 0.0);
        buffer
    }

    /// A pooled copy of `table`.
    fn copy(table: &[f64]) -> Vec<f64> {
        let mut buffer = Self::take(table.len());
        buffer.copy_from_slice(table);
        buffer
    }

    /// Returns a buffer to the pool (dropped when the pool is full).
    fn give(buffer: Vec<f64>) {
        let bytes = buffer.capacity() * std::mem::size_of::<f64>();
        if bytes == 0 {
            return;
        }
        let _ = POOL.try_with(|pool| {
            let mut pool = pool.borrow_mut();
            if pool.bytes + bytes <= Self::MAX_BYTES {
                pool.bytes += bytes;
                pool.spares.push(buffer);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_frame(w: u32, h: u32, seed: u64) -> GrayFrame {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let data = (0..w * h).map(|_| rng.gen_range(0..=255u16)).collect();
        GrayFrame::new(w, h, 8, data).unwrap()
    }

    /// Box-model integral by supersampling each pixel `k x k` times.
    fn brute_force(frame: &GrayFrame, poly: &[Point], k: usize, offset: f64) -> RegionSum {
        let polygon = crate::geometry::Polygon::new(poly.to_vec());
        let [bx0, by0, bx1, by1] = polygon.bounds();
        let (mut count, mut sum) = (0.0, 0.0);
        let cell = 1.0 / k as f64;
        for y in (by0.floor() as i64 - 1).max(0)..=(by1.ceil() as i64 + 1).min(frame.height as i64 - 1) {
            for x in (bx0.floor() as i64 - 1).max(0)..=(bx1.ceil() as i64 + 1).min(frame.width as i64 - 1) {
                let mut inside = 0usize;
                for sy in 0..k {
                    for sx in 0..k {
                        let p = [
                            x as f64 - 0.5 + (sx as f64 + 0.5) * cell,
                            y as f64 - 0.5 + (sy as f64 + 0.5) * cell,
                        ];
                        inside += polygon.contains(p) as usize;
                    }
                }
                let a = inside as f64 * cell * cell;
                count += a;
                sum += a * (frame.get(x as u32, y as u32) as f64 + offset);
            }
        }
        RegionSum { count, sum }
    }

    fn random_polygon(rng: &mut impl Rng, center: Point, radius: f64) -> Vec<Point> {
        // A star-shaped polygon (simple) with random radii and 5..40 vertices.
        let n = rng.gen_range(5..40);
        let mut angles: Vec<f64> = (0..n)
            .map(|_| rng.gen_range(0.0..std::f64::consts::TAU))
            .collect();
        angles.sort_by(|a, b| a.total_cmp(b));
        angles
            .iter()
            .map(|&t| {
                let r = radius * rng.gen_range(0.4..1.0);
                [center[0] + r * t.cos(), center[1] + r * t.sin()]
            })
            .collect()
    }

    #[test]
    fn polygon_sums_match_supersampled_brute_force() {
        let frame = random_frame(64, 48, 1);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        for case in 0..40 {
            let c = [rng.gen_range(20.0..44.0), rng.gen_range(18.0..30.0)];
            let radius = rng.gen_range(4.0..16.0);
            let mut poly = random_polygon(&mut rng, c, radius);
            if case % 2 == 1 {
                poly.reverse(); // both orientations
            }
            let fast = sums.polygon(&poly);
            let slow = brute_force(&frame, &poly, 32, 1.0);
            // Supersampling at 32x32 resolves the boundary to ~1/32 px: the
            // two agree to 0.5% of the area and of the sum.
            assert!(
                (fast.count - slow.count).abs() < 0.005 * slow.count + 0.05,
                "case {case}: count {fast:?} vs {slow:?}"
            );
            assert!(
                (fast.sum - slow.sum).abs() < 0.005 * slow.sum + 10.0,
                "case {case}: sum {fast:?} vs {slow:?}"
            );
        }
    }

    /// The box-model integral by a second exact method: split every edge at
    /// each pixel row and column crossing, where F is linear and the midpoint
    /// rule exact (the first implementation; 1.7x more steps).
    fn split_everywhere(frame: &GrayFrame, poly: &[Point], offset: f64) -> f64 {
        let f = |x: f64, row: i64| {
            // F at image x in an image row: sum of the boxes left of x.
            let row = row.clamp(0, frame.height as i64 - 1) as u32;
            let u = (x + 0.5).clamp(0.0, frame.width as f64);
            let c = (u as usize).min(frame.width as usize - 1);
            let before: f64 = (0..c).map(|i| frame.get(i as u32, row) as f64 + offset).sum();
            before + (u - c as f64) * (frame.get(c as u32, row) as f64 + offset)
        };
        let mut total = 0.0;
        for i in 0..poly.len() {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            let mut ts = vec![0.0, 1.0];
            for (p, q) in [(a[0], b[0]), (a[1], b[1])] {
                let (lo, hi) = (p.min(q), p.max(q));
                let mut k = (lo + 0.5).ceil();
                while k - 0.5 < hi {
                    ts.push(((k - 0.5) - p) / (q - p));
                    k += 1.0;
                }
            }
            ts.sort_by(|x, y| x.total_cmp(y));
            for w in ts.windows(2) {
                let tm = 0.5 * (w[0] + w[1]);
                let (x, y) = (a[0] + tm * (b[0] - a[0]), a[1] + tm * (b[1] - a[1]));
                total += f(x, (y + 0.5).floor() as i64) * (w[1] - w[0]) * (b[1] - a[1]);
            }
        }
        let twice_area: f64 = (0..poly.len())
            .map(|i| {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                a[0] * b[1] - b[0] * a[1]
            })
            .sum();
        total * twice_area.signum()
    }

    #[test]
    fn row_integrals_equal_splitting_at_every_crossing() {
        let frame = random_frame(48, 40, 9);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(10);
        for case in 0..30 {
            let c = [rng.gen_range(16.0..32.0), rng.gen_range(14.0..26.0)];
            let radius = rng.gen_range(3.0..12.0);
            let poly = random_polygon(&mut rng, c, radius);
            let (fast, reference) = (sums.polygon(&poly).sum, split_everywhere(&frame, &poly, 1.0));
            assert!(
                (fast - reference).abs() < 1e-9 * reference.abs(),
                "case {case}: {fast} vs {reference}"
            );
        }
    }

    #[test]
    fn vertical_edges_edges_on_row_boundaries_and_edges_leaving_the_area_equal_splitting() {
        // The cases the boundary-grouped walk treats apart: (nearly)
        // vertical edges, vertices exactly on row boundaries (local v an
        // integer: image y = k + 0.5), and crossings outside the area's
        // rows and columns (clamped to the first / last row and column).
        let frame = random_frame(40, 32, 11);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let cases: [&[Point]; 5] = [
            &[[5.2, 3.1], [5.2, 20.7], [18.9, 20.7], [18.9, 3.1]],
            &[[6.3, 4.5], [6.3004, 25.5], [30.1, 25.5], [29.9, 4.5]],
            &[[-6.0, -4.2], [12.3, -5.0], [14.1, 9.6], [-3.3, 12.2]],
            &[[25.0, 20.0], [47.5, 22.2], [44.0, 39.0], [30.2, 36.4]],
            &[[10.5, 2.5], [20.5, 2.5], [20.5, 12.5], [15.2, 17.5], [10.5, 12.5]],
        ];
        for (case, poly) in cases.iter().enumerate() {
            for reversed in [false, true] {
                let mut poly = poly.to_vec();
                if reversed {
                    poly.reverse();
                }
                let (fast, reference) = (sums.polygon(&poly).sum, split_everywhere(&frame, &poly, 1.0));
                assert!(
                    (fast - reference).abs() < 1e-9 * reference.abs(),
                    "case {case} (reversed {reversed}): {fast} vs {reference}"
                );
            }
        }
    }

    #[test]
    fn open_paths_joined_into_a_loop_give_the_polygon() {
        let frame = random_frame(48, 40, 11);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        for case in 0..30 {
            let c = [rng.gen_range(16.0..32.0), rng.gen_range(14.0..26.0)];
            let radius = rng.gen_range(3.0..12.0);
            let poly = random_polygon(&mut rng, c, radius);
            // Split the loop at a random vertex; both paths share it and the
            // first vertex.
            let cut = rng.gen_range(1..poly.len());
            let mut rest = poly[cut..].to_vec();
            rest.push(poly[0]);
            let joined = (sums.path(&poly[..=cut]) + sums.path(&rest)).region();
            let whole = sums.polygon(&poly);
            assert!(
                (joined.sum - whole.sum).abs() < 1e-9 * whole.sum.abs()
                    && (joined.count - whole.count).abs() < 1e-9 * whole.count,
                "case {case}: {joined:?} vs {whole:?}"
            );
            // The reversed loop encloses the same region.
            let mut reversed = poly.clone();
            reversed.push(poly[0]);
            reversed.reverse();
            let back = sums.path(&reversed).region();
            assert!(
                (back.sum - whole.sum).abs() < 1e-9 * whole.sum.abs(),
                "case {case}"
            );
        }
    }

    #[test]
    fn pixel_aligned_rectangle_is_exact() {
        let frame = random_frame(32, 32, 3);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 0);
        // Boxes of pixels 5..=12 x 7..=20.
        let poly = vec![[4.5, 6.5], [12.5, 6.5], [12.5, 20.5], [4.5, 20.5]];
        let exact: f64 = (7..=20)
            .flat_map(|y| (5..=12).map(move |x| (x, y)))
            .map(|(x, y)| frame.get(x, y) as f64)
            .sum();
        let s = sums.polygon(&poly);
        assert!((s.sum - exact).abs() < 1e-6, "{} vs {exact}", s.sum);
        assert!((s.count - 112.0).abs() < 1e-12);
        let r = sums.rect_sum(4.5, 6.5, 12.5, 20.5);
        assert!((r.sum - exact).abs() < 1e-6 && (r.count - 112.0).abs() < 1e-12);
    }

    #[test]
    fn sums_are_continuous_in_subpixel_shifts() {
        let frame = random_frame(64, 64, 4);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let base = random_polygon(&mut rand_chacha::ChaCha8Rng::seed_from_u64(5), [32.0, 32.0], 14.0);
        let mut last = sums.polygon(&base).sum;
        // Shifting by 1/1000 px changes the sum by at most 1/1000 of the
        // perimeter times the largest intensity: no jumps at pixel boundaries.
        let perimeter = crate::geometry::Polygon::new(base.clone()).length();
        for step in 1..=2000 {
            let d = step as f64 * 0.001;
            let moved: Vec<Point> = base.iter().map(|p| [p[0] + d, p[1] + 0.7 * d]).collect();
            let s = sums.polygon(&moved).sum;
            assert!(
                (s - last).abs() <= 0.001 * 1.3 * perimeter * 256.0 + 1e-6,
                "jump at step {step}: {last} -> {s}"
            );
            last = s;
        }
    }

    #[test]
    fn subrect_sums_equal_full_frame_sums() {
        let frame = random_frame(80, 60, 6);
        let full = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let rect = PixelRect::covering(20.2, 10.7, 60.3, 45.1, 80, 60).unwrap();
        let part = PrefixSums::new(&frame, rect, 1);
        let poly = random_polygon(&mut rand_chacha::ChaCha8Rng::seed_from_u64(7), [40.0, 28.0], 14.0);
        assert!(part.contains(&poly));
        let (a, b) = (full.polygon(&poly), part.polygon(&poly));
        assert!((a.sum - b.sum).abs() < 1e-6 * a.sum && (a.count - b.count).abs() < 1e-9);
        let (a, b) = (
            full.rect_sum(25.3, 12.9, 51.1, 40.2),
            part.rect_sum(25.3, 12.9, 51.1, 40.2),
        );
        assert!((a.sum - b.sum).abs() < 1e-6 * a.sum, "{a:?} {b:?}");
    }

    #[test]
    fn rect_sum_matches_brute_force_for_fractional_corners() {
        let frame = random_frame(40, 40, 8);
        let sums = PrefixSums::new(&frame, PixelRect::full(&frame), 1);
        let poly = vec![[5.3, 7.8], [30.1, 7.8], [30.1, 22.45], [5.3, 22.45]];
        let slow = brute_force(&frame, &poly, 40, 1.0);
        let fast = sums.rect_sum(5.3, 7.8, 30.1, 22.45);
        assert!(
            (fast.sum - slow.sum).abs() < 0.002 * slow.sum,
            "{fast:?} vs {slow:?}"
        );
        let via_polygon = sums.polygon(&poly);
        assert!(
            (fast.sum - via_polygon.sum).abs() < 1e-6 * fast.sum,
            "{fast:?} vs {via_polygon:?}"
        );
        assert!((sums.total().sum - (frame.data.iter().map(|&v| v as f64 + 1.0).sum::<f64>())).abs() < 1e-6);
    }

    /// The window sums read the summed-area table, stored every
    /// `SAT_ROW_STEP` rows, plus rows of F: every row residue, the last row
    /// and a sub-rectangle off the origin must agree with the exact polygon
    /// route (which uses G only).
    #[test]
    fn rect_sums_equal_polygon_sums_at_every_row_phase() {
        let frame = random_frame(53, 47, 9);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(10);
        for rect in [
            PixelRect::full(&frame),
            PixelRect {
                x: 3,
                y: 5,
                width: 41,
                height: 39,
            },
        ] {
            let sums = PrefixSums::new(&frame, rect, 1);
            let [ex0, ey0, ex1, ey1] = rect.extent();
            for _ in 0..200 {
                let x0 = rng.gen_range(ex0..ex1 - 1.0);
                let y0 = rng.gen_range(ey0..ey1 - 1.0);
                let x1 = rng.gen_range(x0 + 0.5..=ex1);
                let y1 = rng.gen_range(y0 + 0.5..=ey1);
                let fast = sums.rect_sum(x0, y0, x1, y1);
                let exact = sums.polygon(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]]);
                assert!(
                    (fast.sum - exact.sum).abs() < 1e-9 * exact.sum.max(1.0),
                    "{rect:?} [{x0}, {y0}, {x1}, {y1}]: {fast:?} vs {exact:?}"
                );
            }
        }
    }

    /// Tables reuse pooled buffers with stale contents: building small,
    /// large and small again (and cloning) gives the same sums as fresh.
    #[test]
    fn reused_buffers_give_identical_sums() {
        let small = random_frame(30, 20, 11);
        let large = random_frame(90, 70, 12);
        let poly = vec![[3.2, 4.1], [22.7, 2.9], [25.3, 15.2], [6.6, 17.8]];
        let first = PrefixSums::new(&small, PixelRect::full(&small), 1).polygon(&poly);
        drop(PrefixSums::new(&large, PixelRect::full(&large), 1));
        let again = PrefixSums::new(&small, PixelRect::full(&small), 1);
        assert_eq!(again.polygon(&poly), first);
        let copy = again.clone();
        drop(again);
        assert_eq!(copy.polygon(&poly), first);
        assert_eq!(
            copy.rect_sum(1.0, 1.0, 20.0, 15.0),
            PrefixSums::new(&small, PixelRect::full(&small), 1).rect_sum(1.0, 1.0, 20.0, 15.0)
        );
    }

    /// Split tables: window sums with their edges in the given spans are
    /// bit-identical to full tables' (whole-number table entries either
    /// way); windows with an edge elsewhere are not covered and sum to NaN;
    /// polygon sums agree to 1e-9; containment keeps the guard; the total
    /// is the window area's.
    #[test]
    fn split_tables_equal_full_tables_where_they_cover() {
        let frame = random_frame(120, 100, 13);
        let windows = PixelRect {
            x: 4,
            y: 3,
            width: 110,
            height: 92,
        };
        let polygons = PixelRect {
            x: 30,
            y: 28,
            width: 60,
            height: 45,
        };
        let spans = [[10.0, 14.5], [80.2, 84.0]];
        let full = PrefixSums::new(&frame, windows, 1);
        let split = PrefixSums::split(&frame, polygons, 3.0, windows, &spans, 1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(14);
        for _ in 0..300 {
            let (x0, x1) = (rng.gen_range(3.5..40.0), rng.gen_range(70.0..113.5));
            let (y0, y1) = (rng.gen_range(10.0..14.5), rng.gen_range(80.2..84.0));
            let window = [x0, y0, x1, y1];
            assert!(split.covers_window(window), "{window:?}");
            assert_eq!(
                split.rect_sum(x0, y0, x1, y1),
                full.rect_sum(x0, y0, x1, y1),
                "{window:?}"
            );
        }
        for window in [[10.0, 20.0, 90.0, 82.0], [10.0, 12.0, 90.0, 60.0]] {
            assert!(!split.covers_window(window), "{window:?}");
            let [x0, y0, x1, y1] = window;
            assert!(split.rect_sum(x0, y0, x1, y1).sum.is_nan(), "{window:?}");
        }
        assert_eq!(split.total(), full.total());
        for _ in 0..50 {
            let poly = random_polygon(&mut rng, [60.0, 50.0], 15.0);
            assert!(split.contains(&poly));
            let (a, b) = (full.polygon(&poly), split.polygon(&poly));
            assert!((a.count - b.count).abs() < 1e-9, "{a:?} {b:?}");
            assert!((a.sum - b.sum).abs() < 1e-9 * a.sum, "{a:?} {b:?}");
        }
        // Inside the G table but within the guard of its edge.
        let near_edge = [[31.0, 40.0], [50.0, 40.0], [40.0, 55.0]];
        assert!(full.contains(&near_edge) && !split.contains(&near_edge));
        assert!(!split.contains_box([31.0, 40.0, 50.0, 55.0]));
    }
}
