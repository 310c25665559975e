//! Small line charts written as PNG, with no system fonts or libraries: a
//! built-in 5×7 bitmap font, straight lines, linear or log axes. Used for
//! the tokenizer's error-versus-bins figure and the trainer's loss curves.

use std::io::Write;

#[derive(Clone, Debug)]
pub struct Line {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub color: [u8; 3],
}

#[derive(Clone, Debug, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub lines: Vec<Line>,
}

/// Distinct line colours, in order.
pub const PALETTE: [[u8; 3]; 6] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
    [127, 127, 127],
];

struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = 3 * (y as usize * self.w + x as usize);
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }
    fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: [u8; 3], thick: i64) {
        let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
        for s in 0..=steps {
            let t = s as f64 / steps as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            for dx in 0..thick {
                for dy in 0..thick {
                    self.set(
                        x.round() as i64 + dx - thick / 2,
                        y.round() as i64 + dy - thick / 2,
                        c,
                    );
                }
            }
        }
    }
    /// Text at (x, y) top-left, `scale` pixels per font pixel; vertical
    /// text runs bottom-to-top.
    fn text(&mut self, s: &str, x: i64, y: i64, scale: i64, c: [u8; 3], vertical: bool) {
        for (i, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (0b10000 >> col) == 0 {
                        continue;
                    }
                    for a in 0..scale {
                        for b in 0..scale {
                            let (gx, gy) = (i as i64 * 6 + col, row as i64);
                            if vertical {
                                self.set(x + gy * scale + a, y - gx * scale - b, c);
                            } else {
                                self.set(x + gx * scale + a, y + gy * scale + b, c);
                            }
                        }
                    }
                }
            }
        }
    }
}

fn text_width(s: &str, scale: i64) -> i64 {
    s.chars().count() as i64 * 6 * scale
}

/// Tick values for a linear axis: about 5 "nice" steps (1, 2, 5 × 10ⁿ).
fn nice_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).max(1e-300);
    let raw = span / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| span / s <= 6.0)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = vec![];
    while t <= hi + step * 1e-9 {
        out.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    out
}

fn fmt_tick(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.0E}")
    } else if a >= 10.0 {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Render a chart as a PNG file's bytes.
pub fn render_png(chart: &Chart, width: usize, height: usize) -> Vec<u8> {
    let mut cv = Canvas {
        w: width,
        h: height,
        px: vec![255; width * height * 3],
    };
    let (left, right, top, bottom) = (110.0, width as f64 - 30.0, 60.0, height as f64 - 80.0);
    let tx = |v: f64, log: bool| if log { v.max(1e-300).log10() } else { v };
    let pts: Vec<(f64, f64)> = chart
        .lines
        .iter()
        .flat_map(|l| l.points.iter())
        .filter(|(x, y)| {
            x.is_finite()
                && y.is_finite()
                && (!chart.log_x || *x > 0.0)
                && (!chart.log_y || *y > 0.0)
        })
        .map(|&(x, y)| (tx(x, chart.log_x), tx(y, chart.log_y)))
        .collect();
    let fold = |f: fn(&(f64, f64)) -> f64, init: f64, pick: fn(f64, f64) -> f64| {
        pts.iter().map(f).fold(init, pick)
    };
    let (mut x0, mut x1) = (
        fold(|p| p.0, f64::INFINITY, f64::min),
        fold(|p| p.0, f64::NEG_INFINITY, f64::max),
    );
    let (mut y0, mut y1) = (
        fold(|p| p.1, f64::INFINITY, f64::min),
        fold(|p| p.1, f64::NEG_INFINITY, f64::max),
    );
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-12 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-12 {
        y1 = y0 + 1.0;
    }
    let pad = (y1 - y0) * 0.05;
    let (y0, y1) = (y0 - pad, y1 + pad);
    let sx = |v: f64| left + (v - x0) / (x1 - x0) * (right - left);
    let sy = |v: f64| bottom - (v - y0) / (y1 - y0) * (bottom - top);
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    let ticks = |lo: f64, hi: f64, log: bool| -> Vec<(f64, String)> {
        if log && hi - lo >= 1.0 {
            (lo.ceil() as i64..=hi.floor() as i64)
                .map(|e| (e as f64, fmt_tick(10f64.powi(e as i32))))
                .collect()
        } else {
            nice_ticks(lo, hi)
                .into_iter()
                .map(|t| (t, fmt_tick(if log { 10f64.powf(t) } else { t })))
                .collect()
        }
    };
    for (t, label) in ticks(x0, x1, chart.log_x) {
        let x = sx(t);
        cv.line((x, top), (x, bottom), grey, 1);
        cv.text(
            &label,
            (x - text_width(&label, 2) as f64 / 2.0) as i64,
            bottom as i64 + 8,
            2,
            black,
            false,
        );
    }
    for (t, label) in ticks(y0, y1, chart.log_y) {
        let y = sy(t);
        cv.line((left, y), (right, y), grey, 1);
        cv.text(
            &label,
            left as i64 - 8 - text_width(&label, 2),
            y as i64 - 7,
            2,
            black,
            false,
        );
    }
    cv.line((left, top), (left, bottom), black, 2);
    cv.line((left, bottom), (right, bottom), black, 2);
    cv.text(
        &chart.title,
        (width as i64 - text_width(&chart.title, 3)) / 2,
        14,
        3,
        black,
        false,
    );
    cv.text(
        &chart.x_label,
        ((left + right) / 2.0) as i64 - text_width(&chart.x_label, 2) / 2,
        height as i64 - 40,
        2,
        black,
        false,
    );
    cv.text(
        &chart.y_label,
        14,
        ((top + bottom) / 2.0) as i64 + text_width(&chart.y_label, 2) / 2,
        2,
        black,
        true,
    );
    for (i, l) in chart.lines.iter().enumerate() {
        let p: Vec<(f64, f64)> = l
            .points
            .iter()
            .filter(|(x, y)| {
                x.is_finite()
                    && y.is_finite()
                    && (!chart.log_x || *x > 0.0)
                    && (!chart.log_y || *y > 0.0)
            })
            .map(|&(x, y)| (sx(tx(x, chart.log_x)), sy(tx(y, chart.log_y))))
            .collect();
        for w in p.windows(2) {
            cv.line(w[0], w[1], l.color, 3);
        }
        for &q in &p {
            cv.line((q.0 - 3.0, q.1), (q.0 + 3.0, q.1), l.color, 3);
        }
        let ly = top as i64 + 10 + 24 * i as i64;
        let lx = right as i64 - 20 - text_width(&l.name, 2) - 40;
        cv.line(
            (lx as f64, ly as f64 + 7.0),
            (lx as f64 + 30.0, ly as f64 + 7.0),
            l.color,
            3,
        );
        cv.text(&l.name, lx + 38, ly, 2, black, false);
    }
    encode_png(width, height, &cv.px)
}

/// An 8-bit RGB PNG.
pub fn encode_png(w: usize, h: usize, rgb: &[u8]) -> Vec<u8> {
    let mut raw = Vec::with_capacity(h * (1 + 3 * w));
    for row in rgb.chunks(3 * w) {
        raw.push(0);
        raw.extend_from_slice(row);
    }
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&raw).expect("in-memory write");
    let idat = z.finish().expect("in-memory write");
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut crc = crc32fast::Hasher::new();
        crc.update(kind);
        crc.update(data);
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        out.extend_from_slice(&crc.finalize().to_be_bytes());
    };
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&(w as u32).to_be_bytes());
    ihdr.extend_from_slice(&(h as u32).to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", &idat);
    chunk(b"IEND", &[]);
    out
}

/// 5×7 glyphs, one byte a row (low 5 bits, leftmost pixel highest).
/// Lower-case letters are drawn as capitals; unknown characters as a box.
fn glyph(c: char) -> [u8; 7] {
    let c = c.to_ascii_uppercase();
    let rows: [&str; 7] = match c {
        ' ' => ["     "; 7],
        '0' => [
            " ### ", "#   #", "#  ##", "# # #", "##  #", "#   #", " ### ",
        ],
        '1' => [
            "  #  ", " ##  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### ",
        ],
        '2' => [
            " ### ", "#   #", "    #", "   # ", "  #  ", " #   ", "#####",
        ],
        '3' => [
            "#####", "   # ", "  #  ", "   # ", "    #", "#   #", " ### ",
        ],
        '4' => [
            "   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # ",
        ],
        '5' => [
            "#####", "#    ", "#### ", "    #", "    #", "#   #", " ### ",
        ],
        '6' => [
            "  ## ", " #   ", "#    ", "#### ", "#   #", "#   #", " ### ",
        ],
        '7' => [
            "#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   ",
        ],
        '8' => [
            " ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### ",
        ],
        '9' => [
            " ### ", "#   #", "#   #", " ####", "    #", "   # ", " ##  ",
        ],
        'A' => [
            " ### ", "#   #", "#   #", "#####", "#   #", "#   #", "#   #",
        ],
        'B' => [
            "#### ", "#   #", "#   #", "#### ", "#   #", "#   #", "#### ",
        ],
        'C' => [
            " ### ", "#   #", "#    ", "#    ", "#    ", "#   #", " ### ",
        ],
        'D' => [
            "###  ", "#  # ", "#   #", "#   #", "#   #", "#  # ", "###  ",
        ],
        'E' => [
            "#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#####",
        ],
        'F' => [
            "#####", "#    ", "#    ", "#### ", "#    ", "#    ", "#    ",
        ],
        'G' => [
            " ### ", "#   #", "#    ", "# ###", "#   #", "#   #", " ####",
        ],
        'H' => [
            "#   #", "#   #", "#   #", "#####", "#   #", "#   #", "#   #",
        ],
        'I' => [
            " ### ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", " ### ",
        ],
        'J' => [
            "  ###", "   # ", "   # ", "   # ", "   # ", "#  # ", " ##  ",
        ],
        'K' => [
            "#   #", "#  # ", "# #  ", "##   ", "# #  ", "#  # ", "#   #",
        ],
        'L' => [
            "#    ", "#    ", "#    ", "#    ", "#    ", "#    ", "#####",
        ],
        'M' => [
            "#   #", "## ##", "# # #", "# # #", "#   #", "#   #", "#   #",
        ],
        'N' => [
            "#   #", "#   #", "##  #", "# # #", "#  ##", "#   #", "#   #",
        ],
        'O' => [
            " ### ", "#   #", "#   #", "#   #", "#   #", "#   #", " ### ",
        ],
        'P' => [
            "#### ", "#   #", "#   #", "#### ", "#    ", "#    ", "#    ",
        ],
        'Q' => [
            " ### ", "#   #", "#   #", "#   #", "# # #", "#  # ", " ## #",
        ],
        'R' => [
            "#### ", "#   #", "#   #", "#### ", "# #  ", "#  # ", "#   #",
        ],
        'S' => [
            " ####", "#    ", "#    ", " ### ", "    #", "    #", "#### ",
        ],
        'T' => [
            "#####", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ", "  #  ",
        ],
        'U' => [
            "#   #", "#   #", "#   #", "#   #", "#   #", "#   #", " ### ",
        ],
        'V' => [
            "#   #", "#   #", "#   #", "#   #", "#   #", " # # ", "  #  ",
        ],
        'W' => [
            "#   #", "#   #", "#   #", "# # #", "# # #", "# # #", " # # ",
        ],
        'X' => [
            "#   #", "#   #", " # # ", "  #  ", " # # ", "#   #", "#   #",
        ],
        'Y' => [
            "#   #", "#   #", " # # ", "  #  ", "  #  ", "  #  ", "  #  ",
        ],
        'Z' => [
            "#####", "    #", "   # ", "  #  ", " #   ", "#    ", "#####",
        ],
        '.' => [
            "     ", "     ", "     ", "     ", "     ", " ##  ", " ##  ",
        ],
        ',' => [
            "     ", "     ", "     ", "     ", " ##  ", "  #  ", " #   ",
        ],
        ':' => [
            "     ", " ##  ", " ##  ", "     ", " ##  ", " ##  ", "     ",
        ],
        '-' => [
            "     ", "     ", "     ", "#####", "     ", "     ", "     ",
        ],
        '+' => [
            "     ", "  #  ", "  #  ", "#####", "  #  ", "  #  ", "     ",
        ],
        '=' => [
            "     ", "     ", "#####", "     ", "#####", "     ", "     ",
        ],
        '/' => [
            "     ", "    #", "   # ", "  #  ", " #   ", "#    ", "     ",
        ],
        '(' => [
            "   # ", "  #  ", " #   ", " #   ", " #   ", "  #  ", "   # ",
        ],
        ')' => [
            " #   ", "  #  ", "   # ", "   # ", "   # ", "  #  ", " #   ",
        ],
        '%' => [
            "##   ", "##  #", "   # ", "  #  ", " #   ", "#  ##", "   ##",
        ],
        '_' => [
            "     ", "     ", "     ", "     ", "     ", "     ", "#####",
        ],
        '\'' => [
            " ##  ", "  #  ", " #   ", "     ", "     ", "     ", "     ",
        ],
        '°' => [
            " ##  ", "#  # ", "#  # ", " ##  ", "     ", "     ", "     ",
        ],
        '<' => [
            "   # ", "  #  ", " #   ", "#    ", " #   ", "  #  ", "   # ",
        ],
        '>' => [
            " #   ", "  #  ", "   # ", "    #", "   # ", "  #  ", " #   ",
        ],
        '[' => [
            " ### ", " #   ", " #   ", " #   ", " #   ", " #   ", " ### ",
        ],
        ']' => [
            " ### ", "   # ", "   # ", "   # ", "   # ", "   # ", " ### ",
        ],
        _ => [
            "#####", "#   #", "#   #", "#   #", "#   #", "#   #", "#####",
        ],
    };
    rows.map(|r| r.bytes().fold(0u8, |acc, b| (acc << 1) | (b == b'#') as u8))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_has_a_valid_header_and_checksums() {
        let chart = Chart {
            title: "Error vs bins".into(),
            x_label: "bins".into(),
            y_label: "error (rad)".into(),
            log_x: true,
            log_y: true,
            lines: vec![Line {
                name: "mean".into(),
                points: vec![(8.0, 0.2), (360.0, 0.005), (1024.0, 0.0017)],
                color: PALETTE[0],
            }],
        };
        let png = render_png(&chart, 640, 400);
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&png[12..16], b"IHDR");
        assert_eq!(u32::from_be_bytes(png[16..20].try_into().unwrap()), 640);
        // IHDR's CRC covers its type and data.
        let crc = crc32fast::hash(&png[12..29]);
        assert_eq!(u32::from_be_bytes(png[29..33].try_into().unwrap()), crc);
        assert_eq!(&png[png.len() - 8..png.len() - 4], b"IEND");
        // The image is not blank: the zlib stream inflates to some dark pixels.
        let idat_len = u32::from_be_bytes(png[33..37].try_into().unwrap()) as usize;
        let mut d = flate2::read::ZlibDecoder::new(&png[41..41 + idat_len]);
        let mut raw = Vec::new();
        std::io::Read::read_to_end(&mut d, &mut raw).unwrap();
        assert_eq!(raw.len(), 400 * (1 + 640 * 3));
        assert!(raw.iter().filter(|&&b| b < 100).count() > 1000);
    }

    #[test]
    fn ticks_are_nice() {
        let t = nice_ticks(0.0, 1.0);
        assert_eq!(t.len(), 6);
        assert!(t
            .iter()
            .enumerate()
            .all(|(i, v)| (v - 0.2 * i as f64).abs() < 1e-9));
        assert_eq!(fmt_tick(0.25), "0.25");
        assert_eq!(fmt_tick(360.0), "360");
        assert_eq!(glyph('a'), glyph('A'));
    }
}
