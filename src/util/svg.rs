//! Shared SVG drawing (plotters, SVG backend only) of spine figures in the
//! two anatomical views: frontal (seen from anterior: horizontal axis =
//! -Z, the subject's right on the viewer's left) and sagittal (seen from
//! the right: horizontal axis = X, anterior to the right); vertical axis
//! = Y (superior). Lengths in mm, equal scales on both axes. Used by the
//! base builder's views (`base::views`) and the generator's and
//! evaluation's figures (`evaluate::plot`).
//!
//! A figure holds point series (dots, optionally joined), circles given in
//! model units (wrap spheres) and mesh silhouettes. Silhouettes are the
//! projected triangles rasterised on a grid of about 2 px and written as
//! one rectangle per run of covered cells in a row, so a figure of many
//! meshes stays small (tens of kB instead of a dot per vertex).
//!
//! Also text measuring and wrapping ([`text_width`], [`wrap`]) for the
//! charts of [`crate::util::charts`].

use nalgebra::Point3;
use plotters::prelude::*;
use std::collections::BTreeSet;

/// One of the two views.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// The ground Y-Z plane: horizontal -Z, vertical Y.
    Frontal,
    /// The ground X-Y plane: horizontal X, vertical Y.
    Sagittal,
}

impl View {
    /// Both views, frontal first.
    pub const BOTH: [View; 2] = [View::Frontal, View::Sagittal];

    /// Horizontal coordinate of a point (mm).
    pub fn horizontal(self, p: &Point3<f64>) -> f64 {
        match self {
            View::Frontal => -p.z * 1e3,
            View::Sagittal => p.x * 1e3,
        }
    }

    /// Short name (`frontal`, `sagittal`).
    pub fn name(self) -> &'static str {
        match self {
            View::Frontal => "frontal",
            View::Sagittal => "sagittal",
        }
    }

    /// What the view shows, for captions.
    pub fn caption(self) -> &'static str {
        match self {
            View::Frontal => "frontal (from anterior; right on the left)",
            View::Sagittal => "sagittal (from the right; anterior to the right)",
        }
    }

    /// The horizontal axis' title.
    pub fn horizontal_label(self) -> &'static str {
        match self {
            View::Frontal => "towards the subject's left (mm)",
            View::Sagittal => "anterior (mm)",
        }
    }

    /// (horizontal, vertical) of a point (mm).
    fn project(self, p: &Point3<f64>) -> (f64, f64) {
        (self.horizontal(p), p.y * 1e3)
    }
}

/// A series of points (ground, m).
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend label (empty: not in the legend).
    pub label: String,
    /// Colour of its dots and line.
    pub colour: RGBColor,
    /// The points in ground (m).
    pub points: Vec<Point3<f64>>,
    /// Dot radius (px); 0 draws no dots.
    pub radius: i32,
    /// Join the points by a line (in the given order).
    pub line: bool,
}

/// Circles of given radius in model units (e.g. wrap spheres), outlines.
#[derive(Debug, Clone)]
pub struct Circles {
    /// Legend label (empty: not in the legend).
    pub label: String,
    /// Outline colour.
    pub colour: RGBColor,
    /// (centre in ground (m), radius (m)).
    pub circles: Vec<(Point3<f64>, f64)>,
}

/// Mesh silhouettes: triangles in ground (m), filled.
#[derive(Debug, Clone)]
pub struct Silhouette {
    /// Legend label (empty: not in the legend).
    pub label: String,
    /// Fill colour.
    pub colour: RGBColor,
    /// The triangles' vertices in ground (m).
    pub triangles: Vec<[Point3<f64>; 3]>,
}

/// A figure: what to draw, in drawing order silhouettes, circles, series.
#[derive(Debug, Clone)]
pub struct Figure {
    /// Title above the views.
    pub title: String,
    /// Size in px (width, height).
    pub size: (u32, u32),
    /// Mesh silhouettes, drawn first.
    pub silhouettes: Vec<Silhouette>,
    /// Circle sets, drawn over the silhouettes.
    pub circles: Vec<Circles>,
    /// Point series, drawn over the circles.
    pub series: Vec<Series>,
    /// Text placed just right of a point (e.g. level names), drawn last.
    pub labels: Vec<(Point3<f64>, String)>,
}

impl Figure {
    /// An empty figure of the default size (600 x 800 px).
    pub fn new(title: impl Into<String>) -> Figure {
        Figure {
            title: title.into(),
            size: (600, 800),
            silhouettes: Vec::new(),
            circles: Vec::new(),
            series: Vec::new(),
            labels: Vec::new(),
        }
    }

    /// Every point that sets the figure's extent.
    fn extent_points(&self) -> impl Iterator<Item = &Point3<f64>> {
        self.silhouettes
            .iter()
            .flat_map(|s| s.triangles.iter().flatten())
            .chain(
                self.circles
                    .iter()
                    .flat_map(|c| c.circles.iter().map(|(p, _)| p)),
            )
            .chain(self.series.iter().flat_map(|s| s.points.iter()))
    }

    /// The SVG text of the figure in `view`, captioned `title: view`.
    pub fn draw(&self, view: View) -> String {
        let title = format!("{}: {}", self.title, view.caption());
        draw(self, view, &title)
    }

    /// Both views: `[(view name, svg)]`.
    pub fn draw_both(&self) -> Vec<(String, String)> {
        View::BOTH
            .iter()
            .map(|v| (v.name().to_string(), self.draw(*v)))
            .collect()
    }
}

fn finite(p: &Point3<f64>) -> bool {
    p.x.is_finite() && p.y.is_finite() && p.z.is_finite()
}

/// Covered cells `(row, column)` of the projected triangles on a grid of
/// `cell` mm with origin `o`: cells whose centre is inside a triangle, and
/// the cells of its corners (so slivers still show).
fn raster(tris: &[[Point3<f64>; 3]], view: View, o: (f64, f64), cell: f64) -> BTreeSet<(i64, i64)> {
    let mut out = BTreeSet::new();
    let idx = |x: f64, x0: f64| ((x - x0) / cell).floor() as i64;
    for t in tris {
        if !t.iter().all(finite) {
            continue;
        }
        let q = t.map(|p| view.project(&p));
        for (h, v) in q {
            out.insert((idx(v, o.1), idx(h, o.0)));
        }
        let (h0, h1) = (
            q[0].0.min(q[1].0).min(q[2].0),
            q[0].0.max(q[1].0).max(q[2].0),
        );
        let (v0, v1) = (
            q[0].1.min(q[1].1).min(q[2].1),
            q[0].1.max(q[1].1).max(q[2].1),
        );
        let cross = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
            (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
        };
        let area = cross(q[0], q[1], q[2]);
        if area.abs() < 1e-12 {
            continue;
        }
        for r in idx(v0, o.1)..=idx(v1, o.1) {
            for c in idx(h0, o.0)..=idx(h1, o.0) {
                let p = (o.0 + (c as f64 + 0.5) * cell, o.1 + (r as f64 + 0.5) * cell);
                let w = [
                    cross(q[1], q[2], p) / area,
                    cross(q[2], q[0], p) / area,
                    cross(q[0], q[1], p) / area,
                ];
                if w.iter().all(|&x| x >= -1e-9) {
                    out.insert((r, c));
                }
            }
        }
    }
    out
}

/// Runs of consecutive covered cells per row: (row, first column, last column).
fn runs(cells: &BTreeSet<(i64, i64)>) -> Vec<(i64, i64, i64)> {
    let mut out: Vec<(i64, i64, i64)> = Vec::new();
    for &(r, c) in cells {
        match out.last_mut() {
            Some(last) if last.0 == r && last.2 + 1 == c => last.2 = c,
            _ => out.push((r, c, c)),
        }
    }
    out
}

fn draw(fig: &Figure, view: View, title: &str) -> String {
    let (mut h0, mut h1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in fig.extent_points().filter(|p| finite(p)) {
        let (h, v) = view.project(p);
        h0 = h0.min(h);
        h1 = h1.max(h);
        v0 = v0.min(v);
        v1 = v1.max(v);
    }
    if h0 > h1 {
        (h0, h1, v0, v1) = (-100.0, 100.0, 0.0, 500.0);
    }
    let span = (h1 - h0).max(v1 - v0) * 1.1 + 1.0;
    let (hc, vc) = (0.5 * (h0 + h1), 0.5 * (v0 + v1));
    let (w, ht) = fig.size;
    let hspan = span * w as f64 / ht as f64;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, ht)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(
                (hc - 0.5 * hspan)..(hc + 0.5 * hspan),
                (vc - 0.5 * span)..(vc + 0.5 * span),
            );
        let Ok(mut chart) = chart else {
            return format!(
                "<svg xmlns=\"http://www.w3.org/2000/svg\"><text x=\"10\" y=\"20\">{title}</text></svg>"
            );
        };
        let _ = chart
            .configure_mesh()
            .x_desc(view.horizontal_label())
            .y_desc("superior (mm)")
            .draw();
        // about 2 px of the plotting area
        let cell = span / (ht.max(100) as f64 - 100.0).max(1.0) * 2.0;
        for s in &fig.silhouettes {
            let col = s.colour;
            let org = (hc - 0.5 * hspan, vc - 0.5 * span);
            let rects = runs(&raster(&s.triangles, view, org, cell));
            let r = chart.draw_series(rects.into_iter().map(|(r, c0, c1)| {
                let x0 = org.0 + c0 as f64 * cell;
                let x1 = org.0 + (c1 + 1) as f64 * cell;
                let y0 = org.1 + r as f64 * cell;
                Rectangle::new([(x0, y0), (x1, y0 + cell)], col.filled())
            }));
            if let (Ok(a), false) = (r, s.label.is_empty()) {
                a.label(s.label.clone()).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 16, y + 4)], col.filled())
                });
            }
        }
        for c in &fig.circles {
            let col = c.colour;
            let r = chart.draw_series(c.circles.iter().map(|(p, rad)| {
                let (h, v) = view.project(p);
                let pts: Vec<(f64, f64)> = (0..=48)
                    .map(|k| {
                        let a = k as f64 * std::f64::consts::TAU / 48.0;
                        (h + rad * 1e3 * a.cos(), v + rad * 1e3 * a.sin())
                    })
                    .collect();
                PathElement::new(pts, col.stroke_width(1))
            }));
            if let (Ok(a), false) = (r, c.label.is_empty()) {
                a.label(c.label.clone())
                    .legend(move |(x, y)| Circle::new((x + 8, y), 5, col.stroke_width(1)));
            }
        }
        for s in &fig.series {
            let pts: Vec<(f64, f64)> = s.points.iter().map(|p| view.project(p)).collect();
            let col = s.colour;
            if s.line && pts.len() > 1 {
                let r = chart.draw_series(LineSeries::new(pts.clone(), col.stroke_width(2)));
                if let (Ok(a), false) = (r, s.label.is_empty()) {
                    a.label(s.label.clone()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2))
                    });
                }
            }
            if s.radius > 0 {
                let r = chart.draw_series(
                    pts.iter()
                        .map(|(x, y)| Circle::new((*x, *y), s.radius, col.filled())),
                );
                if let (Ok(a), false, false) = (r, s.line, s.label.is_empty()) {
                    a.label(s.label.clone())
                        .legend(move |(x, y)| Circle::new((x + 8, y), 4, col.filled()));
                }
            }
        }
        let _ = chart.draw_series(fig.labels.iter().map(|(p, t)| {
            EmptyElement::at(view.project(p)) + Text::new(t.clone(), (7, -6), ("sans-serif", 10))
        }));
        let corner = legend_corner(
            fig,
            view,
            (hc - 0.5 * hspan, vc - 0.5 * span),
            (hspan, span),
        );
        let _ = chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(corner)
            .draw();
        let _ = root.present();
    }
    svg
}

/// The corner of the plotting area whose legend-sized box holds the fewest
/// data points (series, circle centres, labels), so the legend covers as
/// little data as possible; upper left on ties. `org` and `size` are the
/// plotted ranges (mm).
fn legend_corner(
    fig: &Figure,
    view: View,
    org: (f64, f64),
    size: (f64, f64),
) -> SeriesLabelPosition {
    let entries = fig.series.iter().filter(|s| !s.label.is_empty()).count()
        + fig.circles.iter().filter(|c| !c.label.is_empty()).count()
        + fig
            .silhouettes
            .iter()
            .filter(|s| !s.label.is_empty())
            .count();
    let longest = fig
        .series
        .iter()
        .map(|s| s.label.chars().count())
        .chain(fig.circles.iter().map(|c| c.label.chars().count()))
        .max()
        .unwrap_or(0);
    // The legend box as fractions of the plotting area (about 520 x 700 px).
    let (fw, fh) = (
        ((longest as f64 * 7.0 + 50.0) / 520.0).min(1.0),
        ((entries as f64 * 20.0 + 16.0) / 700.0).min(1.0),
    );
    let points: Vec<(f64, f64)> = fig
        .series
        .iter()
        .flat_map(|s| s.points.iter())
        .chain(
            fig.circles
                .iter()
                .flat_map(|c| c.circles.iter().map(|(p, _)| p)),
        )
        .chain(fig.labels.iter().map(|(p, _)| p))
        .map(|p| view.project(p))
        .map(|(h, v)| ((h - org.0) / size.0, (v - org.1) / size.1))
        .collect();
    let corners = [
        (SeriesLabelPosition::UpperLeft, 0.0, 1.0 - fh),
        (SeriesLabelPosition::UpperRight, 1.0 - fw, 1.0 - fh),
        (SeriesLabelPosition::LowerLeft, 0.0, 0.0),
        (SeriesLabelPosition::LowerRight, 1.0 - fw, 0.0),
    ];
    let inside = |x0: f64, y0: f64| {
        points
            .iter()
            .filter(|(x, y)| (x0..=x0 + fw).contains(x) && (y0..=y0 + fh).contains(y))
            .count()
    };
    corners
        .into_iter()
        .min_by_key(|(_, x0, y0)| inside(*x0, *y0))
        .map(|(c, _, _)| c)
        .unwrap_or(SeriesLabelPosition::UpperLeft)
}

/// Width (px) that `text` may take at `font_px` in the sans-serif fonts
/// figures are viewed with: 0.62 em per character bounds DejaVu Sans and
/// Arial for the mixed text of titles (a layout estimate, on the safe side).
pub fn text_width(text: &str, font_px: f64) -> f64 {
    text.chars().count() as f64 * 0.62 * font_px
}

/// `text` broken at spaces into lines of at most `max_px` at `font_px`
/// (a single word longer than that keeps its own line).
pub fn wrap(text: &str, max_px: f64, font_px: f64) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    for word in text.split_whitespace() {
        match lines.last_mut() {
            Some(l) if text_width(&format!("{l} {word}"), font_px) <= max_px => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raster_covers_a_square_and_nothing_outside() {
        // a 10 x 10 mm square in the sagittal plane (X, Y), two triangles
        let p = |x: f64, y: f64| Point3::new(x * 1e-3, y * 1e-3, 0.0);
        let tris = vec![
            [p(0.0, 0.0), p(10.0, 0.0), p(10.0, 10.0)],
            [p(0.0, 0.0), p(10.0, 10.0), p(0.0, 10.0)],
        ];
        let cells = raster(&tris, View::Sagittal, (0.0, 0.0), 1.0);
        // every cell centre in the square, plus the corner cells on the far edges
        for r in 0..10 {
            for c in 0..10 {
                assert!(cells.contains(&(r, c)), "({r}, {c}) missing");
            }
        }
        assert!(cells
            .iter()
            .all(|&(r, c)| (0..=10).contains(&r) && (0..=10).contains(&c)));
        // one run per row
        let rr = runs(&cells);
        assert!(rr.iter().filter(|r| r.0 < 10).all(|r| r.1 == 0 && r.2 >= 9));
    }

    #[test]
    fn views_project_as_documented() {
        let p = Point3::new(0.01, 0.2, 0.03);
        assert_eq!(View::Frontal.project(&p), (-30.0, 200.0));
        assert_eq!(View::Sagittal.project(&p), (10.0, 200.0));
    }

    #[test]
    fn figure_is_valid_svg_with_every_element() {
        let mut f = Figure::new("t");
        f.series.push(Series {
            label: "centres".into(),
            colour: BLACK,
            points: vec![Point3::new(0.0, 0.1, 0.0), Point3::new(0.01, 0.2, 0.0)],
            radius: 3,
            line: true,
        });
        f.circles.push(Circles {
            label: "spheres".into(),
            colour: BLUE,
            circles: vec![(Point3::new(0.0, 0.15, 0.0), 0.01)],
        });
        let svg = f.draw(View::Sagittal);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("centres") && svg.contains("spheres"));
        assert!(svg.matches("<circle").count() >= 2);
    }
}
