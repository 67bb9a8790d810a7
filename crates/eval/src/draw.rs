//! Plain-pixel drawing for the figures (lines, boxes and a tiny built-in
//! bitmap font, drawn upper-case), shared by the histograms and the change map.

use image::{Rgb, RgbImage};

/// Pixels per font dot: a glyph is 3 x 5 dots, 4 dots apart.
pub const FONT_SCALE: u32 = 2;
/// Height of a line of text, pixels.
pub const TEXT_HEIGHT: u32 = 5 * FONT_SCALE;

/// The smallest of 1, 2, 2.5, 5 times a power of ten that is >= `value`.
pub fn nice_ceil(value: f64) -> f64 {
    if !(value.is_finite() && value > 0.0) {
        return 1.0;
    }
    let power = 10f64.powf(value.log10().floor());
    [1.0, 2.0, 2.5, 5.0, 10.0].iter().map(|m| m * power).find(|v| *v >= value * (1.0 - 1e-12)).unwrap_or(10.0 * power)
}

/// One pixel, skipped when outside the image.
pub fn put(img: &mut RgbImage, x: u32, y: u32, color: Rgb<u8>) {
    if x < img.width() && y < img.height() {
        img.put_pixel(x, y, color);
    }
}

/// A horizontal line from `x_from` to `x_to` inclusive.
pub fn hline(img: &mut RgbImage, x_from: u32, x_to: u32, y: u32, color: Rgb<u8>) {
    for x in x_from..=x_to {
        put(img, x, y, color);
    }
}

/// A vertical line from `y_from` to `y_to` inclusive.
pub fn vline(img: &mut RgbImage, x: u32, y_from: u32, y_to: u32, color: Rgb<u8>) {
    for y in y_from..=y_to {
        put(img, x, y, color);
    }
}

/// A straight line between two points (inclusive), `width` pixels thick;
/// pixels outside the image are skipped.
pub fn line(img: &mut RgbImage, from: (f64, f64), to: (f64, f64), width: u32, color: Rgb<u8>) {
    let steps = (to.0 - from.0).abs().max((to.1 - from.1).abs()).ceil().max(1.0) as usize;
    for k in 0..=steps {
        let t = k as f64 / steps as f64;
        let (x, y) = (from.0 + t * (to.0 - from.0), from.1 + t * (to.1 - from.1));
        if x >= 0.0 && y >= 0.0 {
            let (x, y) = (x.round() as u32, y.round() as u32);
            fill_rect(img, x, y, x + width - 1, y + width - 1, color);
        }
    }
}

/// A filled box, corners inclusive.
pub fn fill_rect(img: &mut RgbImage, left: u32, top: u32, right: u32, bottom: u32, color: Rgb<u8>) {
    for y in top..=bottom {
        hline(img, left, right, y, color);
    }
}

/// Width of `text` drawn with [`draw_text`], pixels.
pub fn text_width(text: &str) -> u32 {
    text.chars().count() as u32 * 4 * FONT_SCALE
}

/// `text` with its top-left corner at (`x`, `y`); pixels outside the image are skipped.
pub fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, color: Rgb<u8>) {
    for (k, c) in text.chars().enumerate() {
        let rows = glyph(c);
        let left = x + k as u32 * 4 * FONT_SCALE;
        for (row, bits) in rows.iter().enumerate() {
            for col in 0..3u32 {
                if bits & (0b100 >> col) != 0 {
                    let (px, py) = (left + col * FONT_SCALE, y + row as u32 * FONT_SCALE);
                    fill_rect(img, px, py, px + FONT_SCALE - 1, py + FONT_SCALE - 1, color);
                }
            }
        }
    }
}

/// A 3x5 bitmap glyph: five rows, three bits each (left bit first).
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b001, 0b010, 0b010],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        'A' => [0b010, 0b101, 0b111, 0b101, 0b101],
        'B' => [0b110, 0b101, 0b110, 0b101, 0b110],
        'C' => [0b011, 0b100, 0b100, 0b100, 0b011],
        'D' => [0b110, 0b101, 0b101, 0b101, 0b110],
        'E' => [0b111, 0b100, 0b110, 0b100, 0b111],
        'F' => [0b111, 0b100, 0b110, 0b100, 0b100],
        'G' => [0b011, 0b100, 0b101, 0b101, 0b011],
        'H' => [0b101, 0b101, 0b111, 0b101, 0b101],
        'I' => [0b111, 0b010, 0b010, 0b010, 0b111],
        'J' => [0b001, 0b001, 0b001, 0b101, 0b010],
        'K' => [0b101, 0b101, 0b110, 0b101, 0b101],
        'L' => [0b100, 0b100, 0b100, 0b100, 0b111],
        'M' => [0b101, 0b111, 0b111, 0b101, 0b101],
        'N' => [0b110, 0b101, 0b101, 0b101, 0b101],
        'O' => [0b010, 0b101, 0b101, 0b101, 0b010],
        'P' => [0b110, 0b101, 0b110, 0b100, 0b100],
        'Q' => [0b010, 0b101, 0b101, 0b110, 0b011],
        'R' => [0b110, 0b101, 0b110, 0b101, 0b101],
        'S' => [0b011, 0b100, 0b010, 0b001, 0b110],
        'T' => [0b111, 0b010, 0b010, 0b010, 0b010],
        'U' => [0b101, 0b101, 0b101, 0b101, 0b111],
        'V' => [0b101, 0b101, 0b101, 0b101, 0b010],
        'W' => [0b101, 0b101, 0b111, 0b111, 0b101],
        'X' => [0b101, 0b101, 0b010, 0b101, 0b101],
        'Y' => [0b101, 0b101, 0b010, 0b010, 0b010],
        'Z' => [0b111, 0b001, 0b010, 0b100, 0b111],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        ',' => [0b000, 0b000, 0b000, 0b010, 0b100],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        '+' => [0b000, 0b010, 0b111, 0b010, 0b000],
        ':' => [0b000, 0b010, 0b000, 0b010, 0b000],
        '=' => [0b000, 0b111, 0b000, 0b111, 0b000],
        '>' => [0b100, 0b010, 0b001, 0b010, 0b100],
        '<' => [0b001, 0b010, 0b100, 0b010, 0b001],
        '/' => [0b001, 0b001, 0b010, 0b100, 0b100],
        '_' => [0b000, 0b000, 0b000, 0b000, 0b111],
        '(' => [0b010, 0b100, 0b100, 0b100, 0b010],
        ')' => [0b010, 0b001, 0b001, 0b001, 0b010],
        '%' => [0b101, 0b001, 0b010, 0b100, 0b101],
        ' ' => [0; 5],
        _ => [0b111, 0b001, 0b010, 0b000, 0b010],
    }
}
