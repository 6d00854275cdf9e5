//! Charts drawn with plotters (SVG backend, into a `String`): the one
//! layer for the tool's statistical figures, next to the anatomical views
//! of [`crate::util::svg`].
//!
//! - [`figure`]: a canvas under a centred title and a subtitle, both
//!   wrapped to the width; the caller draws into the area below.
//! - [`category_svg`]: one slot per category (parameter, metric, group)
//!   along the horizontal axis, a value axis (linear or log10) with its
//!   title, and per slot a list of [`Mark`]s (boxes, ticks, vertical spans,
//!   dots). Category names are written under the slots, rotated when long.
//! - [`boxplot_svg`], [`boxplot_svg_axis`]: box-and-whisker plots (type 7
//!   quartiles, Tukey whiskers) on [`category_svg`].
//! - [`xy_svg`]: a grid of x-y panels (dots, solid or dashed polylines),
//!   each titled with labelled axes, and one legend under them.
//! - [`heatmap_svg`]: cell grids of the same rows and columns, one panel
//!   under the other, with a red-white-blue colour scale ([`diverging`]).
//!
//! Font sizes are given as rendered pixels; plotters' SVG backend writes
//! `size / 1.24`, which [`font`] compensates.

use crate::util::svg::{text_width, wrap};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// A drawing area of an SVG figure.
pub type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Light blue of boxes.
pub const BOX_FILL: RGBColor = RGBColor(0x9e, 0xca, 0xe1);
/// Red of highlighted values (medians, best estimates, outliers).
pub const HIGHLIGHT: RGBColor = RGBColor(0xd6, 0x27, 0x28);
/// Blue of data points.
pub const POINT: RGBColor = RGBColor(0x1f, 0x77, 0xb4);
/// Grey of grid lines.
pub const GRID: RGBColor = RGBColor(0xdd, 0xdd, 0xdd);
/// Grey of reference lines and ranges.
pub const REFERENCE: RGBColor = RGBColor(0x88, 0x88, 0x88);

/// A sans-serif text style rendered at `px` pixels.
pub fn font(px: f64) -> TextStyle<'static> {
    TextStyle::from(("sans-serif", px * 1.24).into_font())
}

/// Title and subtitle sizes (px).
const TITLE_PX: f64 = 14.0;
const SUBTITLE_PX: f64 = 10.0;

/// An SVG figure `w` px wide: the title (14 px) and the subtitle (10 px)
/// centred and wrapped to the width, then a white area of `body_h` px that
/// `draw` fills. The canvas is as tall as the header and the body.
pub fn figure(
    w: u32,
    body_h: u32,
    title: &str,
    subtitle: &str,
    draw: impl FnOnce(&Area),
) -> String {
    let max = f64::from(w) - 20.0;
    let mut lines: Vec<(String, f64, i32)> = Vec::new();
    let mut y = 8.0;
    for (text, px) in [(title, TITLE_PX), (subtitle, SUBTITLE_PX)] {
        for line in wrap(text, max, px) {
            lines.push((line, px, y as i32));
            y += px * 1.4;
        }
    }
    let head = (y + 6.0) as u32;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, head + body_h)).into_drawing_area();
        let _ = root.fill(&WHITE);
        for (line, px, y) in lines {
            let style = font(px).pos(Pos::new(HPos::Center, VPos::Top));
            let _ = root.draw(&Text::new(line, ((w / 2) as i32, y), style));
        }
        let (_, body) = root.split_vertically(head);
        draw(&body);
        let _ = root.present();
    }
    svg
}

/// One drawing in a category's slot; values in data units (the axis maps
/// them, log10 on a log axis), offsets and sizes in px.
#[derive(Debug, Clone)]
pub enum Mark {
    /// A filled box from `lo` to `hi`, `half` px either side of the
    /// slot's centre, outlined in black.
    Box {
        /// Bottom of the box (data units).
        lo: f64,
        /// Top of the box (data units).
        hi: f64,
        /// Half-width (px).
        half: i32,
        /// Fill colour.
        fill: RGBColor,
    },
    /// A horizontal segment at `at`, `half` px either side of the centre
    /// (median line, whisker cap).
    Tick {
        /// Height of the segment (data units).
        at: f64,
        /// Half-length (px).
        half: i32,
        /// Stroke colour.
        colour: RGBColor,
        /// Stroke width (px).
        width: u32,
    },
    /// A vertical segment from `lo` to `hi`, `dx` px right of the centre
    /// (whisker, interval, range).
    Span {
        /// Bottom end (data units).
        lo: f64,
        /// Top end (data units).
        hi: f64,
        /// Offset right of the slot's centre (px).
        dx: i32,
        /// Stroke colour.
        colour: RGBColor,
        /// Stroke width (px).
        width: u32,
    },
    /// A dot at `at`, `dx` px right of the centre; an outline when not
    /// `filled`.
    Dot {
        /// Height of the dot (data units).
        at: f64,
        /// Offset right of the slot's centre (px).
        dx: i32,
        /// Radius (px).
        radius: i32,
        /// Colour.
        colour: RGBColor,
        /// Filled, or an outline only.
        filled: bool,
    },
}

/// One slot of a category chart.
#[derive(Debug, Clone)]
pub struct Category {
    /// Label under the slot.
    pub label: String,
    /// What is drawn in the slot, in order.
    pub marks: Vec<Mark>,
}

/// The value (vertical) axis of a category chart.
#[derive(Debug, Clone)]
pub struct ValueAxis {
    /// Axis title.
    pub label: String,
    /// Plotted range in data units (both > 0 on a log axis).
    pub range: (f64, f64),
    /// Tick values in data units the axis should show: their labels set
    /// the axis' width and their number is the most ticks drawn (plotters
    /// picks 1/2/5 steps in plotted units within that number).
    pub ticks: Vec<f64>,
    /// Tick label of a value.
    pub format: fn(f64) -> String,
    /// log10 axis.
    pub log: bool,
    /// Grid lines at the ticks.
    pub grid: bool,
    /// Dashed reference line across the chart (e.g. 0 or 1).
    pub reference: Option<f64>,
}

impl ValueAxis {
    /// Plotted coordinate of a value.
    fn map(&self, v: f64) -> f64 {
        if self.log {
            v.max(1e-300).log10()
        } else {
            v
        }
    }
}

/// A chart of categories along the horizontal axis.
#[derive(Debug, Clone)]
pub struct CategoryChart {
    /// Title above the chart.
    pub title: String,
    /// Line under the title.
    pub subtitle: String,
    /// The value axis.
    pub axis: ValueAxis,
    /// The slots, left to right.
    pub categories: Vec<Category>,
    /// Width of one slot (px).
    pub slot: u32,
    /// Minimum canvas width (px).
    pub min_width: u32,
    /// Height of the plotting area (px).
    pub plot_h: u32,
}

/// Font sizes of a category chart (px): tick and category labels, axis title.
const LABEL_PX: f64 = 12.0;
const AXIS_PX: f64 = 12.0;

/// Draw a category chart: the value axis with ticks, labels and title on
/// the left, optional grid and reference line, each category's marks in
/// its slot and its name under it (rotated by 90 degrees when a name is
/// wider than its slot).
pub fn category_svg(c: &CategoryChart) -> String {
    let n = c.categories.len().max(1);
    let widest_tick = c
        .axis
        .ticks
        .iter()
        .map(|t| text_width(&(c.axis.format)(*t), LABEL_PX))
        .fold(0.0, f64::max);
    let left = (widest_tick + AXIS_PX * 1.6 + 16.0).ceil() as u32;
    let right = 20;
    let w = (6 + left + right + c.slot * n as u32).max(c.min_width);
    let slot = f64::from(w - 6 - left - right) / n as f64;
    let widest_name = c
        .categories
        .iter()
        .map(|k| text_width(&k.label, LABEL_PX))
        .fold(0.0, f64::max);
    let rotate = widest_name > slot - 8.0;
    let bottom = if rotate {
        (widest_name + 16.0).ceil() as u32
    } else {
        (LABEL_PX * 2.5) as u32
    };
    figure(w, c.plot_h + bottom + 10, &c.title, &c.subtitle, |area| {
        draw_categories(area, c, (left, right, bottom), slot, rotate);
    })
}

fn draw_categories(
    area: &Area,
    c: &CategoryChart,
    margins: (u32, u32, u32),
    slot: f64,
    rotate: bool,
) {
    let (left, right, bottom) = margins;
    let ax = &c.axis;
    let n = c.categories.len().max(1) as f64;
    let (y0, y1) = (ax.map(ax.range.0), ax.map(ax.range.1));
    let chart = ChartBuilder::on(area)
        .margin_top(10)
        // room for the rotated axis title, which plotters puts at the very edge
        .margin_left(6)
        .margin_right(right)
        .y_label_area_size(left)
        .x_label_area_size(bottom)
        .build_cartesian_2d(0.0..n, y0..y1);
    let Ok(mut chart) = chart else {
        return;
    };
    let log = ax.log;
    let format = ax.format;
    let label = move |t: &f64| format(if log { 10f64.powf(*t) } else { *t });
    let mut mesh = chart.configure_mesh();
    mesh.disable_x_mesh()
        .x_labels(0)
        .y_labels(ax.ticks.len().max(2))
        .y_desc(ax.label.as_str())
        .y_label_formatter(&label)
        .label_style(font(LABEL_PX))
        .axis_desc_style(font(AXIS_PX));
    if ax.grid {
        mesh.bold_line_style(GRID).light_line_style(TRANSPARENT);
    } else {
        mesh.disable_y_mesh();
    }
    let _ = mesh.draw();
    if let Some(r) = ax.reference {
        let y = ax.map(r);
        let _ = chart.draw_series(DashedLineSeries::new(
            [(0.0, y), (n, y)],
            4,
            3,
            REFERENCE.stroke_width(1),
        ));
    }
    let px = 1.0 / slot;
    for (k, cat) in c.categories.iter().enumerate() {
        let xc = k as f64 + 0.5;
        for m in &cat.marks {
            draw_mark(&mut chart, ax, xc, px, m);
        }
        let style = if rotate {
            font(LABEL_PX)
                .transform(FontTransform::Rotate270)
                .pos(Pos::new(HPos::Right, VPos::Center))
        } else {
            font(LABEL_PX).pos(Pos::new(HPos::Center, VPos::Top))
        };
        let name = EmptyElement::at((xc, y0)) + Text::new(cat.label.clone(), (0, 8), style);
        let _ = chart.plotting_area().draw(&name);
    }
}

type Chart<'a, 'b> = ChartContext<
    'a,
    SVGBackend<'b>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// Draw one mark of the slot centred at `xc`; `px` is one pixel in
/// horizontal data units.
fn draw_mark(chart: &mut Chart, ax: &ValueAxis, xc: f64, px: f64, m: &Mark) {
    let y = |v: f64| ax.map(v);
    let area = chart.plotting_area();
    let _ = match *m {
        Mark::Box { lo, hi, half, fill } => {
            let corners = [
                (xc - f64::from(half) * px, y(hi)),
                (xc + f64::from(half) * px, y(lo)),
            ];
            area.draw(&Rectangle::new(corners, fill.filled()))
                .and_then(|_| area.draw(&Rectangle::new(corners, BLACK.stroke_width(1))))
        }
        Mark::Tick {
            at,
            half,
            colour,
            width,
        } => area.draw(&PathElement::new(
            [
                (xc - f64::from(half) * px, y(at)),
                (xc + f64::from(half) * px, y(at)),
            ],
            colour.stroke_width(width),
        )),
        Mark::Span {
            lo,
            hi,
            dx,
            colour,
            width,
        } => {
            let x = xc + f64::from(dx) * px;
            area.draw(&PathElement::new(
                [(x, y(lo)), (x, y(hi))],
                colour.stroke_width(width),
            ))
        }
        Mark::Dot {
            at,
            dx,
            radius,
            colour,
            filled,
        } => {
            let style = if filled {
                colour.filled()
            } else {
                colour.stroke_width(1)
            };
            area.draw(&Circle::new(
                (xc + f64::from(dx) * px, y(at)),
                radius,
                style,
            ))
        }
    };
}

/// Tick step of a "nice" axis (1, 2 or 5 times a power of ten) for `span`.
pub(crate) fn nice_step(span: f64) -> f64 {
    let raw = (span / 5.0).max(1e-12);
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    let k = if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    };
    k * p
}

/// Box-and-whisker statistics of a sample: quartiles (type 7), whisker
/// ends at the furthest values within 1.5 IQR of the box, and the values
/// beyond them.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxStats {
    /// First quartile.
    pub q1: f64,
    /// Median.
    pub median: f64,
    /// Third quartile.
    pub q3: f64,
    /// Lower whisker end: the smallest value within 1.5 IQR below `q1`.
    pub lo: f64,
    /// Upper whisker end: the largest value within 1.5 IQR above `q3`.
    pub hi: f64,
    /// Values beyond the whiskers.
    pub outliers: Vec<f64>,
}

impl BoxStats {
    /// The statistics of the finite values of `v`; `None` when there are none.
    pub fn of(v: &[f64]) -> Option<BoxStats> {
        let v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        let q = |p| crate::util::quantile(&v, p);
        let (q1, median, q3) = (q(0.25)?, q(0.5)?, q(0.75)?);
        let iqr = q3 - q1;
        let lo = v
            .iter()
            .copied()
            .filter(|x| *x >= q1 - 1.5 * iqr)
            .fold(f64::INFINITY, f64::min);
        let hi = v
            .iter()
            .copied()
            .filter(|x| *x <= q3 + 1.5 * iqr)
            .fold(f64::NEG_INFINITY, f64::max);
        let outliers = v.iter().copied().filter(|x| *x < lo || *x > hi).collect();
        Some(BoxStats {
            q1,
            median,
            q3,
            lo,
            hi,
            outliers,
        })
    }

    /// The marks of a box plot with a box `half` px either side of the centre.
    fn marks(&self, half: i32) -> Vec<Mark> {
        let mut m = Vec::new();
        for (a, b) in [(self.q3, self.hi), (self.q1, self.lo)] {
            m.push(Mark::Span {
                lo: a,
                hi: b,
                dx: 0,
                colour: BLACK,
                width: 1,
            });
            m.push(Mark::Tick {
                at: b,
                half: half / 2,
                colour: BLACK,
                width: 1,
            });
        }
        m.push(Mark::Box {
            lo: self.q1,
            hi: self.q3,
            half,
            fill: BOX_FILL,
        });
        m.push(Mark::Tick {
            at: self.median,
            half,
            colour: BLACK,
            width: 2,
        });
        m.extend(self.outliers.iter().map(|&x| Mark::Dot {
            at: x,
            dx: 0,
            radius: 3,
            colour: HIGHLIGHT,
            filled: false,
        }));
        m
    }
}

/// A box plot, one box per `(label, values)` series: boxes at the
/// quartiles (type 7), median line, whiskers to the furthest value within
/// 1.5 IQR, outliers as circles ([`BoxStats`]). The value axis includes 0
/// and is rounded to a 1/2/5 tick step. Non-finite values are ignored; an
/// empty series gets its label and no box. Deterministic text.
pub fn boxplot_svg(title: &str, y_label: &str, series: &[(String, Vec<f64>)]) -> String {
    boxplot_svg_axis(title, y_label, series, true)
}

/// [`boxplot_svg`], with the value axis fitted to the data alone when
/// `include_zero` is false.
pub fn boxplot_svg_axis(
    title: &str,
    y_label: &str,
    series: &[(String, Vec<f64>)],
    include_zero: bool,
) -> String {
    let all = series
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .filter(|x| x.is_finite());
    let start = if include_zero {
        (0.0f64, 0.0f64)
    } else {
        (f64::INFINITY, f64::NEG_INFINITY)
    };
    let (dmin, dmax) = all.fold(start, |(a, b), x| (a.min(x), b.max(x)));
    let (dmin, dmax) = if dmin.is_finite() {
        (dmin, dmax)
    } else {
        (0.0, 1.0)
    };
    let dmax = if dmax - dmin < 1e-12 {
        dmin + 1.0
    } else {
        dmax
    };
    let step = nice_step(dmax - dmin);
    let ymin = (dmin / step).floor() * step;
    let ymax = (dmax / step).ceil() * step;
    let ticks = ((ymax - ymin) / step).round() as i64;
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let format: fn(f64) -> String = match decimals {
        0 => |t| format!("{t:.0}"),
        1 => |t| format!("{t:.1}"),
        2 => |t| format!("{t:.2}"),
        3 => |t| format!("{t:.3}"),
        _ => |t| format!("{t:.4}"),
    };
    let n = series.len().max(1) as f64;
    // the slot as wide as the old 560 px canvas allowed; the box half of it, at most 80 px
    let half = ((540.0 / n).max(120.0) * 0.25).min(40.0) as i32;
    let chart = CategoryChart {
        title: title.to_string(),
        subtitle: String::new(),
        axis: ValueAxis {
            label: y_label.to_string(),
            range: (ymin, ymax),
            ticks: (0..=ticks).map(|i| ymin + step * i as f64).collect(),
            format,
            log: false,
            grid: false,
            reference: (ymin < 0.0 && ymax > 0.0).then_some(0.0),
        },
        categories: series
            .iter()
            .map(|(name, v)| Category {
                label: name.clone(),
                marks: BoxStats::of(v).map(|b| b.marks(half)).unwrap_or_default(),
            })
            .collect(),
        slot: 120,
        min_width: 560,
        plot_h: 290,
    };
    category_svg(&chart)
}

/// Red-white-blue of a value in [-1, 1] (clamped): blue below 0, white at
/// 0, red above.
pub fn diverging(v: f64) -> RGBColor {
    let v = if v.is_finite() {
        v.clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let fade = |k: f64| (255.0 * k).round() as u8;
    if v >= 0.0 {
        RGBColor(255, fade(1.0 - v), fade(1.0 - v))
    } else {
        RGBColor(fade(1.0 + v), fade(1.0 + v), 255)
    }
}

/// A tick label formatter for values `step` apart: as many decimals as the
/// step needs, no `-0`.
fn decimals_for(step: f64) -> usize {
    (-step.log10().floor()).clamp(0.0, 6.0) as usize
}

fn tick_label(v: f64, decimals: usize) -> String {
    let t = format!("{v:.decimals$}");
    if t.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        t.trim_start_matches('-').to_string()
    } else {
        t
    }
}

/// One axis of an x-y panel: its title (with the unit) and plotted range.
#[derive(Debug, Clone)]
pub struct Axis {
    /// Axis title, with the unit.
    pub label: String,
    /// Plotted range (data units).
    pub range: (f64, f64),
}

/// How a layer of an x-y panel is drawn.
#[derive(Debug, Clone)]
pub enum LayerKind {
    /// Filled dots of `radius` px.
    Dots {
        /// Dot centres (x, y) in data units.
        points: Vec<(f64, f64)>,
        /// Dot radius (px).
        radius: u32,
    },
    /// Polylines, each its own path.
    Lines {
        /// Polylines of (x, y) points in data units.
        lines: Vec<Vec<(f64, f64)>>,
        /// Stroke width (px).
        width: u32,
        /// Dashed rather than solid.
        dashed: bool,
    },
}

/// One layer of an x-y panel; layers of the same `label` share a legend
/// entry (an empty label has none).
#[derive(Debug, Clone)]
pub struct Layer {
    /// Legend label (empty: no legend entry).
    pub label: String,
    /// Colour of its dots or lines.
    pub colour: RGBColor,
    /// What it draws.
    pub kind: LayerKind,
}

/// One x-y panel: a titled chart with two labelled axes.
#[derive(Debug, Clone)]
pub struct XyPanel {
    /// Panel title.
    pub title: String,
    /// Horizontal axis.
    pub x: Axis,
    /// Vertical axis.
    pub y: Axis,
    /// Layers, drawn in order.
    pub layers: Vec<Layer>,
}

/// A figure of x-y panels on a grid (row by row), with one legend under
/// them for every labelled layer.
#[derive(Debug, Clone)]
pub struct XyFigure {
    /// Title above the figure.
    pub title: String,
    /// Line under the title.
    pub subtitle: String,
    /// The panels, row by row.
    pub panels: Vec<XyPanel>,
    /// Panels per row.
    pub columns: usize,
    /// Size of one panel with its axes (px).
    pub panel: (u32, u32),
}

const PANEL_TITLE_PX: f64 = 11.0;
const TICK_PX: f64 = 10.0;
const LEGEND_PX: f64 = 10.0;
const LEGEND_ROW: u32 = 18;

/// The legend's entries: the first layer of each label, in order.
fn legend_entries(f: &XyFigure) -> Vec<&Layer> {
    let mut out: Vec<&Layer> = Vec::new();
    for l in f.panels.iter().flat_map(|p| p.layers.iter()) {
        if !l.label.is_empty() && !out.iter().any(|o| o.label == l.label) {
            out.push(l);
        }
    }
    out
}

/// Entries laid out in rows within `max` px: (row, x) of each.
fn legend_layout(labels: &[&str], max: f64) -> Vec<(u32, f64)> {
    let (mut row, mut x) = (0u32, 0.0);
    let mut out = Vec::new();
    for l in labels {
        let w = 24.0 + text_width(l, LEGEND_PX);
        if x > 0.0 && x + w > max {
            row += 1;
            x = 0.0;
        }
        out.push((row, x));
        x += w + 16.0;
    }
    out
}

/// Draw an x-y figure: each panel's title, axes with tick labels and
/// titles, light grid, layers in order; the legend below the panels.
pub fn xy_svg(f: &XyFigure) -> String {
    let cols = f.columns.max(1);
    let rows = f.panels.len().div_ceil(cols).max(1);
    let w = (cols as u32 * f.panel.0 + 20).max(360);
    let entries = legend_entries(f);
    let labels: Vec<&str> = entries.iter().map(|l| l.label.as_str()).collect();
    let layout = legend_layout(&labels, f64::from(w) - 20.0);
    let legend_rows = layout.last().map_or(0, |(r, _)| r + 1);
    let grid_h = rows as u32 * f.panel.1;
    let body_h = grid_h + legend_rows * LEGEND_ROW + 10;
    figure(w, body_h, &f.title, &f.subtitle, |area| {
        for (k, p) in f.panels.iter().enumerate() {
            let (r, c) = ((k / cols) as u32, (k % cols) as u32);
            let x0 = 10 + c * f.panel.0;
            let y0 = r * f.panel.1;
            let cell = area.clone().shrink((x0, y0), f.panel);
            draw_panel(&cell, p);
        }
        for (l, (row, x)) in entries.iter().zip(layout) {
            let y = (grid_h + row * LEGEND_ROW + LEGEND_ROW / 2) as i32;
            draw_key(area, l, (10 + x as i32, y));
        }
    })
}

/// A legend entry: the layer's key (a dot or a line) and its label, the
/// key's left end at `at`.
fn draw_key(area: &Area, l: &Layer, (x, y): (i32, i32)) {
    let _ = match &l.kind {
        LayerKind::Dots { radius, .. } => area.draw(&Circle::new(
            (x + 8, y),
            (*radius).max(2),
            l.colour.filled(),
        )),
        LayerKind::Lines { width, dashed, .. } if *dashed => area
            .draw(&PathElement::new(
                [(x, y), (x + 6, y)],
                l.colour.stroke_width(*width),
            ))
            .and_then(|_| {
                area.draw(&PathElement::new(
                    [(x + 10, y), (x + 16, y)],
                    l.colour.stroke_width(*width),
                ))
            }),
        LayerKind::Lines { width, .. } => area.draw(&PathElement::new(
            [(x, y), (x + 16, y)],
            l.colour.stroke_width(*width),
        )),
    };
    let style = font(LEGEND_PX).pos(Pos::new(HPos::Left, VPos::Center));
    let _ = area.draw(&Text::new(l.label.clone(), (x + 24, y), style));
}

/// The range of an axis, widened when empty or not finite.
fn axis_range(a: &Axis) -> (f64, f64) {
    let (lo, hi) = a.range;
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 {
        (lo - 1.0, hi + 1.0)
    } else {
        (lo, hi)
    }
}

/// One panel of an x-y figure in its area.
fn draw_panel(area: &Area, p: &XyPanel) {
    let (x0, x1) = axis_range(&p.x);
    let (y0, y1) = axis_range(&p.y);
    let (dx, dy) = (
        decimals_for(nice_step(x1 - x0)),
        decimals_for(nice_step(y1 - y0)),
    );
    let widest = [y0, y1, 0.5 * (y0 + y1)]
        .iter()
        .map(|v| text_width(&tick_label(*v, dy), TICK_PX) + text_width("-", TICK_PX))
        .fold(0.0, f64::max);
    let left = (widest + AXIS_PX * 1.6 + 10.0).ceil() as u32;
    let chart = ChartBuilder::on(area)
        .caption(p.title.as_str(), font(PANEL_TITLE_PX))
        .margin_top(6)
        .margin_left(4)
        .margin_right(16)
        .margin_bottom(4)
        .y_label_area_size(left)
        .x_label_area_size((TICK_PX + AXIS_PX * 2.4) as u32)
        .build_cartesian_2d(x0..x1, y0..y1);
    let Ok(mut chart) = chart else {
        return;
    };
    let fx = move |v: &f64| tick_label(*v, dx);
    let fy = move |v: &f64| tick_label(*v, dy);
    let _ = chart
        .configure_mesh()
        .x_labels(5)
        .y_labels(5)
        .x_desc(p.x.label.as_str())
        .y_desc(p.y.label.as_str())
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .label_style(font(TICK_PX))
        .axis_desc_style(font(AXIS_PX))
        .bold_line_style(GRID)
        .light_line_style(TRANSPARENT)
        .draw();
    for l in &p.layers {
        let _ = match &l.kind {
            LayerKind::Dots { points, radius } => chart.draw_series(
                points
                    .iter()
                    .map(|&q| Circle::new(q, *radius, l.colour.filled())),
            ),
            LayerKind::Lines {
                lines,
                width,
                dashed: true,
            } => chart.draw_series(lines.iter().flat_map(|line| {
                DashedLineSeries::new(line.clone(), 4, 3, l.colour.stroke_width(*width))
            })),
            LayerKind::Lines { lines, width, .. } => chart.draw_series(
                lines
                    .iter()
                    .map(|line| PathElement::new(line.clone(), l.colour.stroke_width(*width))),
            ),
        };
    }
}

/// One panel of a heat map: cells `(row, column, value in [-1, 1])`.
#[derive(Debug, Clone)]
pub struct HeatPanel {
    /// Panel title.
    pub title: String,
    /// Cells `(row, column, value in [-1, 1])`.
    pub cells: Vec<(usize, usize, f64)>,
}

/// The colour scale of a heat map: the bar from -1 (blue) to +1 (red),
/// ticks at `ticks` (in [-1, 1]), and per row of tick labels its caption
/// (e.g. a unit) and one label per tick.
#[derive(Debug, Clone)]
pub struct ColourScale {
    /// Title of the bar.
    pub title: String,
    /// Tick positions in [-1, 1].
    pub ticks: Vec<f64>,
    /// Rows of tick labels: caption and one label per tick.
    pub rows: Vec<(String, Vec<String>)>,
}

/// Heat maps of the same rows and columns, one panel under the other, and
/// their colour scale ([`diverging`]) at the bottom.
#[derive(Debug, Clone)]
pub struct HeatMap {
    /// Title above the figure.
    pub title: String,
    /// Line under the title.
    pub subtitle: String,
    /// Row names, top to bottom.
    pub rows: Vec<String>,
    /// Number of columns.
    pub columns: usize,
    /// Size of one cell (px).
    pub cell: (u32, u32),
    /// Title of the horizontal axis.
    pub x_label: String,
    /// Labels under the columns: (centre in columns, text).
    pub column_ticks: Vec<(f64, String)>,
    /// Column ranges `[a, b)` underlined under each panel.
    pub marked: Vec<(usize, usize)>,
    /// The panels, top to bottom.
    pub panels: Vec<HeatPanel>,
    /// The colour scale under them.
    pub scale: ColourScale,
}

const HEAT_TICK_PX: f64 = 8.0;
const SCALE_SWATCH: u32 = 12;
const SCALE_STEPS: u32 = 21;

/// Draw a heat map: per panel its title, row names at the left, one
/// rectangle per cell, the marked column ranges underlined, the column
/// labels and the axis title; then the colour scale with its tick labels.
pub fn heatmap_svg(h: &HeatMap) -> String {
    let left = h
        .rows
        .iter()
        .map(|r| text_width(r, TICK_PX))
        .fold(0.0, f64::max)
        .ceil() as u32
        + 16;
    let (cw, ch) = h.cell;
    let grid_w = cw * h.columns as u32;
    let panel_h = PANEL_TITLE_PX as u32 + 8 + ch * h.rows.len() as u32 + 6 + 2 * AXIS_PX as u32 + 8;
    let captions = h
        .scale
        .rows
        .iter()
        .map(|(c, _)| text_width(c, HEAT_TICK_PX))
        .fold(0.0, f64::max)
        .ceil() as u32;
    let bar_x = (captions + 20).max(left);
    let bar_w = SCALE_SWATCH * SCALE_STEPS;
    let w = (left + grid_w + 20).max(bar_x + bar_w + 40).max(360);
    let scale_title = wrap(&h.scale.title, f64::from(w) - 20.0, TICK_PX);
    let scale_h =
        scale_title.len() as u32 * 14 + SCALE_SWATCH + 4 + h.scale.rows.len() as u32 * 12 + 8;
    let body_h = h.panels.len() as u32 * panel_h + scale_h;
    figure(w, body_h, &h.title, &h.subtitle, |area| {
        for (k, p) in h.panels.iter().enumerate() {
            draw_heat_panel(area, h, p, (left, k as u32 * panel_h));
        }
        let y = h.panels.len() as u32 * panel_h;
        draw_scale(area, &h.scale, &scale_title, (bar_x, y));
    })
}

/// One heat-map panel with its top-left corner at `(left, y0)` (`left`:
/// where the cells start).
fn draw_heat_panel(area: &Area, h: &HeatMap, p: &HeatPanel, (left, y0): (u32, u32)) {
    let (cw, ch) = (h.cell.0 as i32, h.cell.1 as i32);
    let (left, y0) = (left as i32, y0 as i32);
    let title = font(PANEL_TITLE_PX).pos(Pos::new(HPos::Left, VPos::Top));
    let _ = area.draw(&Text::new(p.title.clone(), (left, y0), title));
    let top = y0 + PANEL_TITLE_PX as i32 + 8;
    let name = font(TICK_PX).pos(Pos::new(HPos::Right, VPos::Center));
    for (r, row) in h.rows.iter().enumerate() {
        let y = top + ch * r as i32 + ch / 2;
        let _ = area.draw(&Text::new(row.clone(), (left - 6, y), name.clone()));
    }
    for &(r, c, v) in &p.cells {
        let (x, y) = (left + cw * c as i32, top + ch * r as i32);
        let _ = area.draw(&Rectangle::new(
            [(x, y), (x + cw, y + ch)],
            diverging(v).filled(),
        ));
    }
    let bottom = top + ch * h.rows.len() as i32;
    let grid_w = cw * h.columns as i32;
    let _ = area.draw(&Rectangle::new(
        [(left, top), (left + grid_w, bottom)],
        REFERENCE.stroke_width(1),
    ));
    for &(a, b) in &h.marked {
        let _ = area.draw(&Rectangle::new(
            [
                (left + cw * a as i32, bottom + 2),
                (left + cw * b as i32, bottom + 5),
            ],
            BLACK.filled(),
        ));
    }
    let tick = font(HEAT_TICK_PX).pos(Pos::new(HPos::Center, VPos::Top));
    for (at, label) in &h.column_ticks {
        let x = left + (at * f64::from(cw)).round() as i32;
        let _ = area.draw(&Text::new(label.clone(), (x, bottom + 7), tick.clone()));
    }
    let desc = font(AXIS_PX).pos(Pos::new(HPos::Center, VPos::Top));
    let _ = area.draw(&Text::new(
        h.x_label.clone(),
        (left + grid_w / 2, bottom + 8 + HEAT_TICK_PX as i32 + 4),
        desc,
    ));
}

/// The colour scale: its title, the bar from `bar_x`, and the rows of
/// tick labels with their captions at the left edge.
fn draw_scale(area: &Area, s: &ColourScale, title: &[String], (bar_x, y0): (u32, u32)) {
    let (bar_x, mut y) = (bar_x as i32, y0 as i32);
    let head = font(TICK_PX).pos(Pos::new(HPos::Left, VPos::Top));
    for line in title {
        let _ = area.draw(&Text::new(line.clone(), (10, y), head.clone()));
        y += 14;
    }
    let sw = SCALE_SWATCH as i32;
    for k in 0..SCALE_STEPS as i32 {
        let v = -1.0 + 2.0 * f64::from(k) / f64::from(SCALE_STEPS - 1);
        let x = bar_x + sw * k;
        let _ = area.draw(&Rectangle::new(
            [(x, y), (x + sw, y + sw)],
            diverging(v).filled(),
        ));
    }
    let bar_w = sw * SCALE_STEPS as i32;
    let at = |t: f64| bar_x + ((t.clamp(-1.0, 1.0) + 1.0) * 0.5 * f64::from(bar_w)).round() as i32;
    for t in &s.ticks {
        let _ = area.draw(&PathElement::new(
            [(at(*t), y + sw), (at(*t), y + sw + 3)],
            BLACK.stroke_width(1),
        ));
    }
    y += sw + 4;
    let caption = font(HEAT_TICK_PX).pos(Pos::new(HPos::Left, VPos::Top));
    let label = font(HEAT_TICK_PX).pos(Pos::new(HPos::Center, VPos::Top));
    for (name, labels) in &s.rows {
        let _ = area.draw(&Text::new(name.clone(), (10, y), caption.clone()));
        for (t, l) in s.ticks.iter().zip(labels) {
            let _ = area.draw(&Text::new(l.clone(), (at(*t), y), label.clone()));
        }
        y += 12;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_stats_are_type7_quartiles_with_tukey_whiskers() {
        // 1..=5: quartiles (type 7) 2, 3, 4; IQR 2, so 1..5 lie within the fences.
        let b = BoxStats::of(&[5.0, 1.0, 3.0, 2.0, 4.0, f64::NAN]).unwrap();
        assert_eq!(
            (b.q1, b.median, b.q3, b.lo, b.hi),
            (2.0, 3.0, 4.0, 1.0, 5.0)
        );
        assert!(b.outliers.is_empty());
        // 100 lies beyond q3 + 1.5 IQR: an outlier, the whisker stops at 5
        let b = BoxStats::of(&[1.0, 2.0, 3.0, 4.0, 5.0, 100.0]).unwrap();
        assert_eq!(b.hi, 5.0);
        assert_eq!(b.outliers, vec![100.0]);
        assert!(BoxStats::of(&[f64::NAN]).is_none());
    }

    /// The `y` of the text whose content is `label` and of the box's top and bottom.
    fn text_y(svg: &str, label: &str) -> f64 {
        let end = svg.find(&format!(">\n{label}\n</text>")).unwrap();
        let at = svg[..end].rfind("<text").unwrap();
        let k = svg[at..].find(" y=\"").unwrap() + at + 4;
        svg[k..k + svg[k..].find('"').unwrap()].parse().unwrap()
    }

    #[test]
    fn box_spans_the_quartiles_on_the_axis() {
        // 1..=5: quartiles 2 and 4; axis 0..5 in steps of 1.
        let svg = boxplot_svg("t", "mm", &[("a".into(), vec![5.0, 1.0, 3.0, 2.0, 4.0])]);
        let y2 = text_y(&svg, "2");
        let y4 = text_y(&svg, "4");
        // the box: the light-blue rectangle
        let fill = format!(
            "fill=\"#{:02X}{:02X}{:02X}\"",
            BOX_FILL.0, BOX_FILL.1, BOX_FILL.2
        );
        let at = svg.find(&fill).unwrap();
        let rect = &svg[svg[..at].rfind("<rect").unwrap()..at];
        let attr = |name: &str| -> f64 {
            let k = rect.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
            rect[k..k + rect[k..].find('"').unwrap()].parse().unwrap()
        };
        let (top, height) = (attr("y"), attr("height"));
        assert!((top - y4).abs() <= 1.0, "{top} vs tick 4 at {y4}");
        assert!(
            (top + height - y2).abs() <= 1.0,
            "{} vs tick 2 at {y2}",
            top + height
        );
        assert!(svg.contains("\n5\n</text>") && !svg.contains("\n6\n</text>"));
    }

    #[test]
    fn box_plot_survives_empty_and_non_finite_series() {
        let svg = boxplot_svg_axis(
            "a & b",
            "deg",
            &[
                ("empty".into(), vec![]),
                ("nan".into(), vec![f64::NAN, f64::INFINITY]),
                ("neg".into(), vec![-40.0, -41.0, -39.5]),
            ],
            false,
        );
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("a &amp; b"));
        let fill = format!(
            "fill=\"#{:02X}{:02X}{:02X}\"",
            BOX_FILL.0, BOX_FILL.1, BOX_FILL.2
        );
        assert_eq!(svg.matches(&fill).count(), 1);
        assert!(!svg.contains("NaN") && !svg.contains("inf"));
        assert_eq!(nice_step(4.0), 1.0);
        assert_eq!(nice_step(0.04), 0.01);
        assert_eq!(nice_step(30.0), 10.0);
    }

    /// The numeric attribute `name` of an SVG element's text.
    fn attr(el: &str, name: &str) -> f64 {
        let k = el.find(&format!(" {name}=\"")).unwrap() + name.len() + 3;
        el[k..k + el[k..].find('"').unwrap()].parse().unwrap()
    }

    /// Every element of `tag` whose text contains `needle`.
    fn elements<'a>(svg: &'a str, tag: &str, needle: &str) -> Vec<&'a str> {
        svg.split('<')
            .filter(|e| e.starts_with(tag) && e.contains(needle))
            .collect()
    }

    #[test]
    fn xy_dots_sit_at_their_ticks_and_the_legend_names_each_label_once() {
        let dots = |points: Vec<(f64, f64)>| Layer {
            label: "cases".into(),
            colour: POINT,
            kind: LayerKind::Dots { points, radius: 3 },
        };
        let axis = |label: &str| Axis {
            label: label.into(),
            range: (0.0, 1.0),
        };
        let panel = |title: &str, points| XyPanel {
            title: title.into(),
            x: axis("measured (deg)"),
            y: axis("predicted (deg)"),
            layers: vec![dots(points)],
        };
        let svg = xy_svg(&XyFigure {
            title: "t".into(),
            subtitle: "s".into(),
            panels: vec![
                panel("first", vec![(0.0, 0.0), (1.0, 1.0)]),
                panel("second", vec![(0.5, 0.5)]),
            ],
            columns: 2,
            panel: (250, 230),
        });
        assert!(svg.contains("\nfirst\n") && svg.contains("\nsecond\n"));
        assert_eq!(svg.matches("\ncases\n").count(), 1, "one legend entry");
        let fill = format!("fill=\"#{:02X}{:02X}{:02X}\"", POINT.0, POINT.1, POINT.2);
        let circles = elements(&svg, "circle", &fill);
        // three data dots and the legend's key
        assert_eq!(circles.len(), 4);
        let (a, b) = (circles[0], circles[1]);
        // the x tick "1.0" of the first panel stands under the dot at x = 1
        let tick = elements(&svg, "text", "text-anchor=\"middle\"")
            .into_iter()
            .find(|t| t.ends_with(">\n1.0\n"))
            .unwrap();
        assert!((attr(b, "cx") - attr(tick, "x")).abs() <= 1.0);
        assert!(attr(b, "cx") > attr(a, "cx") && attr(b, "cy") < attr(a, "cy"));
    }

    #[test]
    fn heat_cells_take_their_row_column_and_colour() {
        let svg = heatmap_svg(&HeatMap {
            title: "map".into(),
            subtitle: String::new(),
            rows: vec!["L4_L5".into(), "L5_S1".into()],
            columns: 3,
            cell: (6, 14),
            x_label: "case".into(),
            column_ticks: vec![(0.5, "1".into())],
            marked: vec![(1, 2)],
            panels: vec![HeatPanel {
                title: "fit".into(),
                cells: vec![(0, 0, -1.0), (1, 2, 2.0)],
            }],
            scale: ColourScale {
                title: "colour".into(),
                ticks: vec![-1.0, 0.0, 1.0],
                rows: vec![("deg".into(), vec!["-1".into(), "0".into(), "+1".into()])],
            },
        });
        assert_eq!(diverging(0.0), WHITE);
        assert_eq!(diverging(f64::NAN), WHITE);
        let cell = |fill: &str| {
            let r = elements(&svg, "rect", fill)
                .into_iter()
                .find(|r| attr(r, "width") == 6.0)
                .unwrap();
            (attr(r, "x"), attr(r, "y"))
        };
        let (blue, red) = (cell("fill=\"#0000FF\""), cell("fill=\"#FF0000\""));
        assert_eq!((red.0 - blue.0, red.1 - blue.1), (12.0, 14.0));
        // the marked column: a black bar under the second column
        let bar = elements(&svg, "rect", "fill=\"#000000\"");
        assert_eq!(bar.len(), 1);
        assert_eq!(attr(bar[0], "x"), blue.0 + 6.0);
        assert!(attr(bar[0], "y") > red.1 + 14.0);
        for t in ["L4_L5", "L5_S1", "case", "+1"] {
            assert!(svg.contains(&format!("\n{t}\n")), "{t}");
        }
    }
}
