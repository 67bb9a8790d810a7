//! Error histograms drawn with plain pixels (bars, axes, ticks and a tiny
//! built-in bitmap font), in the manner of the published figures.

use image::{Rgb, RgbImage};

use crate::draw::{draw_text, fill_rect, hline, line, nice_ceil, text_width, vline, TEXT_HEIGHT};

/// Options of [`histogram`].
#[derive(Clone, Debug, PartialEq)]
pub struct HistogramOptions {
    /// Image size in pixels. Default 800 x 480.
    pub width: u32,
    pub height: u32,
    /// Number of bins. Default 20.
    pub bins: usize,
    /// Right end of the x axis in pixels of error; errors beyond it fall in
    /// the last bin. Default `None`: the 98th percentile, rounded up to a
    /// round number.
    pub max_px: Option<f64>,
}

impl Default for HistogramOptions {
    fn default() -> Self {
        Self { width: 800, height: 480, bins: 20, max_px: None }
    }
}

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const BAR: Rgb<u8> = Rgb([70, 130, 180]);
const MEDIAN: Rgb<u8> = Rgb([214, 39, 40]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);

const LEFT: u32 = 70;
const RIGHT: u32 = 30;
const TOP: u32 = 50;
const BOTTOM: u32 = 60;

/// A histogram of reprojection errors: x = error in pixels (bins), y = number
/// of clicks, the median marked by a red line. `title` is drawn upper-case.
pub fn histogram(errors_px: &[f64], title: &str, options: &HistogramOptions) -> RgbImage {
    let width = options.width.max(LEFT + RIGHT + 100);
    let height = options.height.max(TOP + BOTTOM + 100);
    let bins = options.bins.max(1);
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let (plot_w, plot_h) = (width - LEFT - RIGHT, height - TOP - BOTTOM);
    let (x0, y0) = (LEFT, TOP + plot_h); // origin of the axes, in image pixels

    let errors: Vec<f64> = errors_px.iter().copied().filter(|e| e.is_finite()).collect();
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    let auto_max = sorted.get((sorted.len() * 98 / 100).min(sorted.len().saturating_sub(1))).copied().unwrap_or(1.0);
    let bin_width_px = nice_ceil(options.max_px.unwrap_or(auto_max).max(1e-9) / bins as f64);
    let x_max_px = bin_width_px * bins as f64;
    let mut counts = vec![0usize; bins];
    for e in &errors {
        let bin = ((e / bin_width_px).floor().max(0.0) as usize).min(bins - 1);
        if let Some(c) = counts.get_mut(bin) {
            *c += 1;
        }
    }
    let max_count = counts.iter().copied().max().unwrap_or(0).max(1);
    let y_step = nice_ceil(max_count as f64 / 5.0).max(1.0);
    let y_max = (max_count as f64 / y_step).ceil() * y_step;
    let x_of = |v: f64| x0 as f64 + v / x_max_px * plot_w as f64;
    let y_of = |v: f64| y0 as f64 - v / y_max * plot_h as f64;

    // Horizontal grid and y ticks.
    let mut tick = 0.0;
    while tick <= y_max + 1e-9 {
        let y = y_of(tick).round() as u32;
        hline(&mut img, x0, x0 + plot_w, y, GRID);
        hline(&mut img, x0 - 6, x0, y, BLACK);
        let label = format_tick(tick);
        let label_w = text_width(&label);
        draw_text(&mut img, (x0 - 10).saturating_sub(label_w), y.saturating_sub(5), &label, BLACK);
        tick += y_step;
    }
    // Bars.
    for (bin, count) in counts.iter().enumerate() {
        if *count == 0 {
            continue;
        }
        let left = x_of(bin as f64 * bin_width_px).round() as u32 + 1;
        let right = x_of((bin + 1) as f64 * bin_width_px).round() as u32 - 1;
        let top = y_of(*count as f64).round() as u32;
        fill_rect(&mut img, left, top, right, y0, BAR);
    }
    // Axes and x ticks (every other bin when crowded).
    hline(&mut img, x0, x0 + plot_w, y0, BLACK);
    vline(&mut img, x0, TOP, y0, BLACK);
    let label_every = if bins > 10 { bins.div_ceil(10) } else { 1 };
    for bin in 0..=bins {
        let x = x_of(bin as f64 * bin_width_px).round() as u32;
        vline(&mut img, x, y0, y0 + 5, BLACK);
        if bin % label_every == 0 {
            let label = format_tick(bin as f64 * bin_width_px);
            draw_text(&mut img, x.saturating_sub(text_width(&label) / 2), y0 + 10, &label, BLACK);
        }
    }
    let x_label = "ERROR (PX)";
    draw_text(&mut img, x0 + plot_w / 2 - text_width(x_label) / 2, y0 + 35, x_label, BLACK);
    draw_text(&mut img, 8, TOP - 20, "N", BLACK);
    // Median.
    let (median, _) = crate::median_mean(&errors);
    if let Some(median) = median {
        let x = x_of(median.min(x_max_px)).round() as u32;
        for dx in 0..2 {
            vline(&mut img, x + dx, TOP, y0, MEDIAN);
        }
        let label = format!("MEDIAN {}", format_value(median));
        let label_x = if x + 8 + text_width(&label) < width { x + 6 } else { x.saturating_sub(text_width(&label) + 6) };
        draw_text(&mut img, label_x, TOP + 4, &label, MEDIAN);
    }
    let title = format!("{}   N={}", title.to_uppercase(), errors.len());
    draw_text(&mut img, LEFT, 14, &title, BLACK);
    img
}

/// One line of a [`log_log`] plot: its name (in the legend), colour and
/// points (x, y, whether the point is estimated rather than measured).
pub struct Series<'a> {
    pub name: &'a str,
    pub color: Rgb<u8>,
    pub points: Vec<(f64, f64, bool)>,
}

/// A log-log line plot, one line per series, each point a dot (measured:
/// filled, estimated: hollow), decades on both axes, a legend upper left.
/// Points that are not positive are left out.
pub fn log_log(series: &[Series], title: &str, x_label: &str, y_label: &str, width: u32, height: u32) -> RgbImage {
    let width = width.max(LEFT + RIGHT + 200);
    let height = height.max(TOP + BOTTOM + 100);
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let (plot_w, plot_h) = (width - LEFT - RIGHT, height - TOP - BOTTOM);
    let (x0, y0) = (LEFT, TOP + plot_h);
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let points = || series.iter().flat_map(|s| s.points.iter()).filter(|p| positive(p.0) && positive(p.1));
    let decades = |values: Vec<f64>| {
        let low = values.iter().copied().fold(f64::INFINITY, f64::min);
        let high = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if low.is_finite() {
            (low.log10().floor(), high.log10().ceil().max(low.log10().floor() + 1.0))
        } else {
            (0.0, 1.0)
        }
    };
    let (x_low, x_high) = decades(points().map(|p| p.0).collect());
    let (y_low, y_high) = decades(points().map(|p| p.1).collect());
    let x_of = |v: f64| x0 as f64 + (v.log10() - x_low) / (x_high - x_low) * plot_w as f64;
    let y_of = |v: f64| y0 as f64 - (v.log10() - y_low) / (y_high - y_low) * plot_h as f64;
    for decade in y_low as i32..=y_high as i32 {
        let y = y_of(10f64.powi(decade)).round() as u32;
        hline(&mut img, x0, x0 + plot_w, y, GRID);
        let label = format!("{}", 10f64.powi(decade));
        draw_text(&mut img, (x0 - 10).saturating_sub(text_width(&label)), y.saturating_sub(5), &label, BLACK);
    }
    for decade in x_low as i32..=x_high as i32 {
        let x = x_of(10f64.powi(decade)).round() as u32;
        vline(&mut img, x, TOP, y0, GRID);
        let label = format!("{}", 10f64.powi(decade));
        draw_text(&mut img, x.saturating_sub(text_width(&label) / 2), y0 + 10, &label, BLACK);
    }
    hline(&mut img, x0, x0 + plot_w, y0, BLACK);
    vline(&mut img, x0, TOP, y0, BLACK);
    for (k, s) in series.iter().enumerate() {
        let at: Vec<(f64, f64, bool)> = s
            .points
            .iter()
            .filter(|p| positive(p.0) && positive(p.1))
            .map(|&(x, y, estimated)| (x_of(x), y_of(y), estimated))
            .collect();
        for pair in at.windows(2) {
            line(&mut img, (pair[0].0, pair[0].1), (pair[1].0, pair[1].1), 2, s.color);
        }
        for &(x, y, estimated) in &at {
            let (x, y) = (x.round() as u32, y.round() as u32);
            fill_rect(&mut img, x.saturating_sub(4), y.saturating_sub(4), x + 4, y + 4, s.color);
            if estimated {
                fill_rect(&mut img, x.saturating_sub(2), y.saturating_sub(2), x + 2, y + 2, WHITE);
            }
        }
        let legend_y = TOP + 8 + k as u32 * (TEXT_HEIGHT + 6);
        fill_rect(&mut img, x0 + 10, legend_y, x0 + 24, legend_y + TEXT_HEIGHT - 1, s.color);
        draw_text(&mut img, x0 + 30, legend_y, &s.name.to_uppercase(), BLACK);
    }
    let note = "HOLLOW: ESTIMATED";
    draw_text(&mut img, x0 + plot_w - text_width(note) - 4, y0 - TEXT_HEIGHT - 6, note, BLACK);
    draw_text(&mut img, x0 + plot_w / 2 - text_width(x_label) / 2, y0 + 35, &x_label.to_uppercase(), BLACK);
    draw_text(&mut img, 8, TOP - 20, &y_label.to_uppercase(), BLACK);
    draw_text(&mut img, LEFT, 14, &title.to_uppercase(), BLACK);
    img
}

fn format_tick(value: f64) -> String {
    let text = format!("{value:.2}");
    text.trim_end_matches('0').trim_end_matches('.').to_owned()
}

fn format_value(value: f64) -> String {
    if value >= 100.0 {
        format!("{value:.0}")
    } else {
        format!("{value:.2}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_log_puts_each_point_on_its_decades() {
        let red = Rgb([200, 0, 0]);
        let series = [Series {
            name: "a",
            color: red,
            points: vec![(10.0, 1.0, false), (1000.0, 100.0, true), (0.0, 5.0, false)],
        }];
        let img = log_log(&series, "t", "x", "y", 600, 400);
        // x spans 10..1000 (two decades), y 1..100: the first point is the origin, the second the far corner.
        let (x0, y0) = (LEFT, 400 - BOTTOM);
        assert_eq!(*img.get_pixel(x0 + 3, y0 - 3), red);
        let (x1, y1) = (600 - RIGHT, TOP);
        assert_eq!(*img.get_pixel(x1, y1), WHITE, "an estimated point is hollow");
        assert_eq!(*img.get_pixel(x1 - 3, y1 + 3), red);
        // Half way along the line between them (a straight line in log-log).
        let (xm, ym) = ((x0 + x1) / 2, (y0 + y1) / 2);
        assert!((0..3).any(|d| *img.get_pixel(xm, ym - 1 + d) == red));
    }

    #[test]
    fn nice_numbers() {
        assert_eq!(nice_ceil(0.9), 1.0);
        assert_eq!(nice_ceil(1.2), 2.0);
        assert_eq!(nice_ceil(2.2), 2.5);
        assert_eq!(nice_ceil(30.0), 50.0);
        assert_eq!(nice_ceil(0.05), 0.05);
    }
}
