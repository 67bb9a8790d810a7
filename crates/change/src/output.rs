//! A change map as files: a PLY of the core points, a top-down PNG and a CSV of regions.

use image::{Rgb, RgbImage};
use revisit_eval::draw::{draw_text, fill_rect, hline, nice_ceil, text_width, vline, TEXT_HEIGHT};

use crate::ChangeMap;

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
/// A measured cell whose change is within its level of detection.
const STABLE: Rgb<u8> = Rgb([205, 205, 205]);

/// Diverging colour of a signed change scaled to -1..1: blue (lowered), white, red (raised).
fn diverging(t: f64) -> [u8; 3] {
    let t = if t.is_finite() { t.clamp(-1.0, 1.0) } else { 0.0 };
    let (low, high) = ([33.0, 102.0, 172.0], [178.0, 24.0, 43.0]);
    let end = if t < 0.0 { low } else { high };
    let a = t.abs();
    let mix = |k: usize| (255.0 * (1.0 - a) + end[k] * a).round() as u8;
    [mix(0), mix(1), mix(2)]
}

/// The colour scale's half range: the 98th percentile of the significant changes' magnitude
/// (of all changes when none is significant), rounded up to a round number.
fn colour_range(map: &ChangeMap) -> f64 {
    let significant: Vec<f64> = map.cells.iter().filter(|c| c.significant).map(|c| c.change.abs()).collect();
    let mut values =
        if significant.is_empty() { map.cells.iter().map(|c| c.change.abs()).collect() } else { significant };
    values.sort_by(f64::total_cmp);
    let p98 = values.get((values.len() * 98 / 100).min(values.len().saturating_sub(1))).copied().unwrap_or(1.0);
    nice_ceil(p98.max(1e-9))
}

fn colour(range: f64, cell: &crate::Cell) -> [u8; 3] {
    if cell.significant {
        diverging(cell.change / range)
    } else {
        STABLE.0
    }
}

/// The core points as a binary little-endian PLY (Open3D, CloudCompare, MeshLab): `double x,
/// y, z`, `uchar red, green, blue` (signed change: blue lowered, red raised, grey within the
/// level of detection), `float change, lod95` (model units) and `uchar significant`.
pub fn encode_ply(map: &ChangeMap) -> Vec<u8> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment Revisit change from {} to {}\nelement vertex {}\n\
         property double x\nproperty double y\nproperty double z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         property float change\nproperty float lod95\nproperty uchar significant\nend_header\n",
        map.from.replace('\n', " "),
        map.to.replace('\n', " "),
        map.cells.len()
    );
    let range = colour_range(map);
    let mut out = Vec::with_capacity(header.len() + map.cells.len() * 36);
    out.extend_from_slice(header.as_bytes());
    for cell in &map.cells {
        for value in cell.core.coords.iter() {
            out.extend_from_slice(&value.to_le_bytes());
        }
        out.extend_from_slice(&colour(range, cell));
        out.extend_from_slice(&(cell.change as f32).to_le_bytes());
        out.extend_from_slice(&(cell.lod95 as f32).to_le_bytes());
        out.push(u8::from(cell.significant));
    }
    out
}

/// The regions as CSV: `id,sign,cells,area,x,y,z` (centre, model frame), `east,north` (centre,
/// map frame), `mean_change,peak_change,mean_lod95`; sizes in the model's unit.
pub fn regions_csv(map: &ChangeMap) -> Result<String, csv::Error> {
    let mut writer = csv::Writer::from_writer(Vec::new());
    writer.write_record([
        "id",
        "sign",
        "cells",
        "area",
        "x",
        "y",
        "z",
        "east",
        "north",
        "mean_change",
        "peak_change",
        "mean_lod95",
    ])?;
    let num = |v: f64| format!("{v:.4}");
    for r in &map.regions {
        writer.write_record([
            r.id.to_string(),
            r.sign.name().to_owned(),
            r.cells.len().to_string(),
            format!("{:.6}", r.area),
            num(r.centre.x),
            num(r.centre.y),
            num(r.centre.z),
            num(r.centre_map[0]),
            num(r.centre_map[1]),
            num(r.mean_change),
            num(r.peak_change),
            num(r.mean_lod95),
        ])?;
    }
    let bytes = writer.into_inner().map_err(|e| e.into_error())?;
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

const MARGIN: u32 = 20;
const TITLE: u32 = 50;
const LEGEND: u32 = 150;
const FOOTER: u32 = 60;
/// The map's longer side, pixels, about.
const MAP_SIDE: usize = 900;

/// A top-down PNG of the measured area, north (the map frame's) up: each cell coloured by its
/// signed change (grey within its level of detection, white unmeasured), regions numbered as in
/// the CSV, a scale bar and a colour bar in `unit`.
pub fn map_png(map: &ChangeMap, unit: &str) -> RgbImage {
    let grid = &map.grid;
    // The window of measured cells (the grid spans every point, strays included).
    let (c0, c1) =
        (map.cells.iter().map(|c| c.col).min().unwrap_or(0), map.cells.iter().map(|c| c.col).max().unwrap_or(0));
    let (r0, r1) =
        (map.cells.iter().map(|c| c.row).min().unwrap_or(0), map.cells.iter().map(|c| c.row).max().unwrap_or(0));
    let (cols, rows) = (c1 - c0 + 1, r1 - r0 + 1);
    let k = (MAP_SIDE / cols.max(rows)).clamp(1, 16) as u32;
    let (map_w, map_h) = (cols as u32 * k, rows as u32 * k);
    let width = (MARGIN + map_w + LEGEND).max(520);
    let height = TITLE + map_h + FOOTER;
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let range = colour_range(map);
    for cell in &map.cells {
        let (left, top) = (MARGIN + (cell.col - c0) as u32 * k, TITLE + (r1 - cell.row) as u32 * k);
        fill_rect(&mut img, left, top, left + k - 1, top + k - 1, Rgb(colour(range, cell)));
    }
    hline(&mut img, MARGIN - 1, MARGIN + map_w, TITLE - 1, BLACK);
    hline(&mut img, MARGIN - 1, MARGIN + map_w, TITLE + map_h, BLACK);
    vline(&mut img, MARGIN - 1, TITLE - 1, TITLE + map_h, BLACK);
    vline(&mut img, MARGIN + map_w, TITLE - 1, TITLE + map_h, BLACK);
    for region in &map.regions {
        let x = MARGIN as f64 + ((region.centre_map[0] - grid.min[0]) / grid.cell - c0 as f64) * k as f64;
        let y = (TITLE + map_h) as f64 - ((region.centre_map[1] - grid.min[1]) / grid.cell - r0 as f64) * k as f64;
        let label = region.id.to_string();
        let (lx, ly) = ((x as u32).saturating_sub(text_width(&label) / 2), (y as u32).saturating_sub(TEXT_HEIGHT / 2));
        fill_rect(
            &mut img,
            lx.saturating_sub(1),
            ly.saturating_sub(1),
            lx + text_width(&label),
            ly + TEXT_HEIGHT,
            WHITE,
        );
        draw_text(&mut img, lx, ly, &label, BLACK);
    }
    let plural = if map.regions.len() == 1 { "" } else { "S" };
    let title =
        format!("CHANGE FROM {} TO {}: {} REGION{plural}   (SIZES IN {unit})", map.from, map.to, map.regions.len());
    draw_text(&mut img, MARGIN, 18, &title, BLACK);

    // Scale bar: a round length near a fifth of the map's width.
    let bar = nice_ceil(cols as f64 * grid.cell / 5.0);
    let bar_px = ((bar / grid.cell) * k as f64).round() as u32;
    let y = TITLE + map_h + 20;
    fill_rect(&mut img, MARGIN, y, MARGIN + bar_px, y + 4, BLACK);
    vline(&mut img, MARGIN, y - 4, y + 8, BLACK);
    vline(&mut img, MARGIN + bar_px, y - 4, y + 8, BLACK);
    draw_text(&mut img, MARGIN + bar_px + 10, y - 2, &format!("{} {unit}", format_size(bar)), BLACK);

    // Colour bar: +range at the top, -range at the bottom.
    let (bar_left, bar_top) = (MARGIN + map_w + 20, TITLE);
    let bar_h = map_h.clamp(100, 300);
    for dy in 0..bar_h {
        let t = 1.0 - 2.0 * dy as f64 / (bar_h - 1) as f64;
        hline(&mut img, bar_left, bar_left + 20, bar_top + dy, Rgb(diverging(t)));
    }
    let label = |v: f64| if v > 0.0 { format!("+{}", format_size(v)) } else { format_size(v) };
    draw_text(&mut img, bar_left + 28, bar_top, &label(range), BLACK);
    draw_text(&mut img, bar_left + 28, bar_top + bar_h / 2 - TEXT_HEIGHT / 2, "0", BLACK);
    draw_text(&mut img, bar_left + 28, bar_top + bar_h - TEXT_HEIGHT, &label(-range), BLACK);
    let stable_top = bar_top + bar_h + 20;
    fill_rect(&mut img, bar_left, stable_top, bar_left + 20, stable_top + 12, STABLE);
    draw_text(&mut img, bar_left + 28, stable_top + 1, "< LOD95", BLACK);
    img
}

fn format_size(value: f64) -> String {
    let text = format!("{value:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_owned()
}
