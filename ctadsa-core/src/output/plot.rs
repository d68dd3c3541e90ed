//! Small PNG line plots (loss curves, metric-vs-setting figures) with a built-in 5 × 7 pixel
//! font, so that no font file or plotting crate is needed.

use std::path::Path;

use crate::data::case::images::write_rgb_or_grey;
use crate::error::Result;

/// 5 × 7 glyphs: each row is 5 bits, most significant bit on the left.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '+' => [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '/' => [0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        _ => [0; 7],
    }
}

/// An RGB canvas.
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl Canvas {
    /// A white canvas.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![255; (width * height * 3) as usize] }
    }

    /// Sets a pixel (ignored outside).
    pub fn put(&mut self, x: i64, y: i64, rgb: [u8; 3]) {
        if x >= 0 && y >= 0 && x < self.width as i64 && y < self.height as i64 {
            let i = ((y as u32 * self.width + x as u32) * 3) as usize;
            self.pixels[i..i + 3].copy_from_slice(&rgb);
        }
    }

    /// A line (Bresenham) of the given thickness.
    pub fn line(&mut self, x0: f64, y0: f64, x1: f64, y1: f64, rgb: [u8; 3], thick: i64) {
        let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
        for s in 0..=steps {
            let t = s as f64 / steps as f64;
            let (x, y) = ((x0 + t * (x1 - x0)).round() as i64, (y0 + t * (y1 - y0)).round() as i64);
            for dx in 0..thick {
                for dy in 0..thick {
                    self.put(x + dx - thick / 2, y + dy - thick / 2, rgb);
                }
            }
        }
    }

    /// Text at `(x, y)` (top-left), glyphs scaled by `scale`.
    pub fn text(&mut self, x: i64, y: i64, s: &str, rgb: [u8; 3], scale: i64) {
        for (k, c) in s.chars().enumerate() {
            let g = glyph(c);
            for (r, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0x10 >> col) != 0 {
                        for a in 0..scale {
                            for b in 0..scale {
                                self.put(x + (k as i64 * 6 + col) * scale + a, y + r as i64 * scale + b, rgb);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Writes the canvas as PNG.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_rgb_or_grey(path, self.width, self.height, self.pixels.clone(), 3)
    }
}

/// A named series of `(x, y)` points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub rgb: [u8; 3],
}

/// Distinct colours for series.
pub const PALETTE: [[u8; 3]; 6] =
    [[31, 119, 180], [214, 39, 40], [44, 160, 44], [255, 127, 14], [148, 103, 189], [23, 23, 23]];

fn tick_label(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1e4 || v.abs() < 1e-2 {
        format!("{v:.1e}")
    } else if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

/// A line plot with axes, ticks, labels and a legend; `log_y` plots log10(y).
pub fn line_plot(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series], log_y: bool) -> Result<()> {
    let (w, h) = (900u32, 560u32);
    let (left, right, top, bottom) = (90.0, 20.0, 40.0, 60.0);
    let mut c = Canvas::new(w, h);
    let ty = |y: f64| if log_y { y.max(1e-12).log10() } else { y };
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().map(|&(x, y)| (x, ty(y))))
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for (x, y) in &pts {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        y1 = y0 + 1.0;
    }
    let pad = 0.05 * (y1 - y0);
    let (y0, y1) = (y0 - pad, y1 + pad);
    let px = |x: f64| left + (x - x0) / (x1 - x0) * (w as f64 - left - right);
    let py = |y: f64| top + (1.0 - (y - y0) / (y1 - y0)) * (h as f64 - top - bottom);
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    for k in 0..=5 {
        let yv = y0 + (y1 - y0) * k as f64 / 5.0;
        c.line(left, py(yv), w as f64 - right, py(yv), grey, 1);
        let label = if log_y { tick_label(10f64.powf(yv)) } else { tick_label(yv) };
        c.text(4, py(yv) as i64 - 7, &label, black, 2);
        let xv = x0 + (x1 - x0) * k as f64 / 5.0;
        c.line(px(xv), top, px(xv), h as f64 - bottom, grey, 1);
        c.text(px(xv) as i64 - 20, h as i64 - bottom as i64 + 8, &tick_label(xv), black, 2);
    }
    c.line(left, top, left, h as f64 - bottom, black, 2);
    c.line(left, h as f64 - bottom, w as f64 - right, h as f64 - bottom, black, 2);
    c.text(left as i64, 10, title, black, 2);
    c.text(w as i64 / 2 - 60, h as i64 - 22, x_label, black, 2);
    c.text(left as i64 + 10, top as i64 + 4, y_label, [90, 90, 90], 2);
    for (k, s) in series.iter().enumerate() {
        let mut prev: Option<(f64, f64)> = None;
        for &(x, y) in &s.points {
            let p = (px(x), py(ty(y)));
            if !(p.0.is_finite() && p.1.is_finite()) {
                prev = None;
                continue;
            }
            match prev {
                Some(q) => c.line(q.0, q.1, p.0, p.1, s.rgb, 2),
                None if s.points.len() == 1 => c.line(p.0 - 3.0, p.1, p.0 + 3.0, p.1, s.rgb, 3),
                None => {}
            }
            if s.points.len() <= 40 {
                c.line(p.0 - 2.0, p.1 - 2.0, p.0 + 2.0, p.1 + 2.0, s.rgb, 2);
            }
            prev = Some(p);
        }
        let ly = top as i64 + 30 + 22 * k as i64;
        c.line(w as f64 - 260.0, ly as f64 + 6.0, w as f64 - 230.0, ly as f64 + 6.0, s.rgb, 3);
        c.text(w as i64 - 222, ly, &s.name, black, 2);
    }
    c.save(path)
}
