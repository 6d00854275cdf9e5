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
        lo: f64,
        hi: f64,
        half: i32,
        fill: RGBColor,
    },
    /// A horizontal segment at `at`, `half` px either side of the centre
    /// (median line, whisker cap).
    Tick {
        at: f64,
        half: i32,
        colour: RGBColor,
        width: u32,
    },
    /// A vertical segment from `lo` to `hi`, `dx` px right of the centre
    /// (whisker, interval, range).
    Span {
        lo: f64,
        hi: f64,
        dx: i32,
        colour: RGBColor,
        width: u32,
    },
    /// A dot at `at`, `dx` px right of the centre; an outline when not
    /// `filled`.
    Dot {
        at: f64,
        dx: i32,
        radius: i32,
        colour: RGBColor,
        filled: bool,
    },
}

/// One slot of a category chart.
#[derive(Debug, Clone)]
pub struct Category {
    pub label: String,
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
    pub title: String,
    pub subtitle: String,
    pub axis: ValueAxis,
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
    pub q1: f64,
    pub median: f64,
    pub q3: f64,
    pub lo: f64,
    pub hi: f64,
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
}
