//! A small grouped bar chart written as PNG with the `png` crate alone (no font or system
//! libraries): bars with error whiskers, a 0–100 % axis, value labels and a legend, text drawn
//! with a built-in 5×7 pixel font (upper-case letters, digits and a few signs; lower case is
//! drawn upper case, anything else as `?`).
use crate::EvalError;
use std::path::Path;

/// One bar: a value in [0, 1] and its spread (a whisker of ± spread; 0 draws none).
pub type Bar = (f64, f64);

/// One panel: a title and groups of bars (one value per series; `None` draws no bar).
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    /// Title above the panel.
    pub title: String,
    /// `(group label, one bar per series)`.
    pub groups: Vec<(String, Vec<Option<Bar>>)>,
}

/// Panels stacked vertically with a shared legend.
#[derive(Debug, Clone, PartialEq)]
pub struct BarChart {
    /// Series names (legend), one colour each.
    pub series: Vec<String>,
    /// The panels.
    pub panels: Vec<Panel>,
}

/// An RGB image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];
const BLACK: [u8; 3] = [0, 0, 0];
const GRID: [u8; 3] = [220, 220, 220];
const SCALE: u32 = 2;
const GLYPH_W: u32 = 6 * SCALE;
/// A legend entry's text starts this far right of its colour swatch's left edge.
const LEGEND_TEXT_DX: i64 = 26;

impl Image {
    /// A white image.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            rgb: vec![255; (width * height * 3) as usize],
        }
    }

    /// Colour of a pixel (`None` outside).
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 3]> {
        (x < self.width && y < self.height).then(|| {
            let i = ((y * self.width + x) * 3) as usize;
            [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
        })
    }

    fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as u32) < self.width && (y as u32) < self.height {
            let i = ((y as u32 * self.width + x as u32) * 3) as usize;
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for y in y0.min(y1)..y0.max(y1) {
            for x in x0.min(x1)..x0.max(x1) {
                self.put(x, y, c);
            }
        }
    }

    fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let rows = glyph(ch);
            for (r, row) in rows.iter().enumerate() {
                for (col, b) in row.bytes().enumerate() {
                    if b == b'#' {
                        let px = x + (k as u32 * GLYPH_W) as i64 + (col as u32 * SCALE) as i64;
                        let py = y + (r as u32 * SCALE) as i64;
                        self.rect(px, py, px + SCALE as i64, py + SCALE as i64, c);
                    }
                }
            }
        }
    }

    fn text_centered(&mut self, cx: i64, y: i64, s: &str, c: [u8; 3]) {
        let w = (s.chars().count() as u32 * GLYPH_W) as i64;
        self.text(cx - w / 2, y, s, c);
    }

    /// Writes the image as an 8-bit RGB PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), EvalError> {
        let png_err = |reason: String| EvalError::Png {
            path: path.to_owned(),
            reason,
        };
        let file = std::fs::File::create(path).map_err(|error| EvalError::Io {
            path: path.to_owned(),
            error,
        })?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), self.width, self.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .and_then(|mut w| w.write_image_data(&self.rgb))
            .map_err(|e| png_err(e.to_string()))
    }
}

impl BarChart {
    /// Draws the chart.
    pub fn render(&self) -> Image {
        let n_series = self.series.len().max(1) as i64;
        let n_groups = self
            .panels
            .iter()
            .map(|p| p.groups.len())
            .max()
            .unwrap_or(1)
            .max(1) as i64;
        let bar_w = 40i64;
        let group_gap = 40i64;
        let left = 70i64;
        let longest_label = self
            .panels
            .iter()
            .flat_map(|p| p.groups.iter().map(|g| g.0.chars().count()))
            .max()
            .unwrap_or(0) as i64;
        let group_w = (n_series * bar_w + group_gap).max(longest_label * GLYPH_W as i64 + 16);
        // Wide enough for the bars and for every title and legend entry (both start at `left`).
        let text_w = |s: &str| s.chars().count() as i64 * GLYPH_W as i64;
        let widest_text = self
            .panels
            .iter()
            .map(|p| text_w(&p.title))
            .chain(self.series.iter().map(|s| LEGEND_TEXT_DX + text_w(s)))
            .max()
            .unwrap_or(0);
        let width = (left + n_groups * group_w + 30)
            .max(left + widest_text + 20)
            .max(520);
        let panel_h = 320i64;
        let plot_h = 200i64;
        let legend_rows = self.series.len() as i64;
        let height = self.panels.len() as i64 * panel_h + 20 + legend_rows * 22;
        let mut img = Image::new(width as u32, height as u32);
        for (pi, panel) in self.panels.iter().enumerate() {
            let top = pi as i64 * panel_h + 10;
            img.text(left, top, &panel.title, BLACK);
            let y0 = top + 50 + plot_h; // the 0 % line
            let y_of = |v: f64| y0 - (v.clamp(0.0, 1.0) * plot_h as f64).round() as i64;
            for t in 0..=4 {
                let v = t as f64 / 4.0;
                let y = y_of(v);
                img.rect(left, y, width - 20, y + 1, GRID);
                img.text(left - 48, y - 7, &format!("{:>3}", t * 25), BLACK);
            }
            img.rect(left, top + 50, left + 1, y0 + 1, BLACK);
            img.rect(left, y0, width - 20, y0 + 1, BLACK);
            for (gi, (label, values)) in panel.groups.iter().enumerate() {
                let gx = left + (group_w - n_series * bar_w) / 2 + gi as i64 * group_w;
                for (si, v) in values.iter().enumerate() {
                    let Some((value, spread)) = v else { continue };
                    let x = gx + si as i64 * bar_w;
                    let color = PALETTE[si % PALETTE.len()];
                    img.rect(x + 2, y_of(*value), x + bar_w - 2, y0, color);
                    if *spread > 0.0 {
                        let (hi, lo) = (y_of(value + spread), y_of(value - spread));
                        let cx = x + bar_w / 2;
                        img.rect(cx, hi, cx + 1, lo + 1, BLACK);
                        img.rect(cx - 4, hi, cx + 5, hi + 1, BLACK);
                        img.rect(cx - 4, lo, cx + 5, lo + 1, BLACK);
                    }
                    let label = format!("{:.0}", 100.0 * value);
                    let top_of_bar = y_of(value + spread.max(0.0));
                    img.text_centered(x + bar_w / 2, top_of_bar - 18, &label, BLACK);
                }
                img.text_centered(gx + n_series * bar_w / 2, y0 + 10, label, BLACK);
            }
        }
        let ly = self.panels.len() as i64 * panel_h + 10;
        for (si, name) in self.series.iter().enumerate() {
            let y = ly + si as i64 * 22;
            img.rect(left, y, left + 16, y + 14, PALETTE[si % PALETTE.len()]);
            img.text(left + LEGEND_TEXT_DX, y, name, BLACK);
        }
        img
    }
}

/// The 5×7 glyph of `c` (rows top to bottom, `#` = ink).
fn glyph(c: char) -> [&'static str; 7] {
    let c = match c {
        'κ' => 'K',
        '±' => '~',
        '’' => '\'',
        c => c.to_ascii_uppercase(),
    };
    match c {
        ' ' => ["     "; 7],
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
            "#### ", "#   #", "#   #", "#   #", "#   #", "#   #", "#### ",
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
            "#### ", "    #", "    #", " ### ", "    #", "    #", "#### ",
        ],
        '4' => [
            "   # ", "  ## ", " # # ", "#  # ", "#####", "   # ", "   # ",
        ],
        '5' => [
            "#####", "#    ", "#### ", "    #", "    #", "#   #", " ### ",
        ],
        '6' => [
            " ### ", "#    ", "#    ", "#### ", "#   #", "#   #", " ### ",
        ],
        '7' => [
            "#####", "    #", "   # ", "  #  ", " #   ", " #   ", " #   ",
        ],
        '8' => [
            " ### ", "#   #", "#   #", " ### ", "#   #", "#   #", " ### ",
        ],
        '9' => [
            " ### ", "#   #", "#   #", " ####", "    #", "    #", " ### ",
        ],
        '%' => [
            "##   ", "##  #", "   # ", "  #  ", " #   ", "#  ##", "   ##",
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
        '_' => [
            "     ", "     ", "     ", "     ", "     ", "     ", "#####",
        ],
        '+' => [
            "     ", "  #  ", "  #  ", "#####", "  #  ", "  #  ", "     ",
        ],
        '~' => [
            "  #  ", "  #  ", "#####", "  #  ", "  #  ", "     ", "#####",
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
        '=' => [
            "     ", "     ", "#####", "     ", "#####", "     ", "     ",
        ],
        '\'' => [
            "  #  ", "  #  ", " #   ", "     ", "     ", "     ", "     ",
        ],
        _ => [
            " ### ", "#   #", "    #", "   # ", "  #  ", "     ", "  #  ",
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glyphs_are_five_by_seven() {
        for c in (' '..='~').chain(['κ', '±', '’']) {
            for row in glyph(c) {
                assert_eq!(row.len(), 5, "{c:?}");
            }
        }
        assert_ne!(glyph('A'), glyph('?'));
        assert_ne!(glyph('\''), glyph('?'));
        assert_eq!(glyph('’'), glyph('\''));
        assert_eq!(glyph('a'), glyph('A'));
    }

    #[test]
    fn bars_have_the_height_of_their_value() {
        let chart = BarChart {
            series: vec!["ONE".into(), "TWO".into()],
            panels: vec![Panel {
                title: "SR".into(),
                groups: vec![("EASY".into(), vec![Some((0.5, 0.0)), Some((1.0, 0.0))])],
            }],
        };
        let img = chart.render();
        // Geometry of `render`: left 70, group width 144 (2 bars of 40 + a 64 px label), plot 200 px high
        // ending at y = 10 + 50 + 200.
        let x_first = 70 + 32 + 20;
        let x_second = x_first + 40;
        let y0 = 10 + 50 + 200;
        let column = |x: u32| {
            (0..img.height)
                .filter(|&y| {
                    img.pixel(x, y) == Some(PALETTE[0]) || img.pixel(x, y) == Some(PALETTE[1])
                })
                .filter(|&y| y < y0 as u32)
                .count()
        };
        assert_eq!(column(x_first), 100);
        assert_eq!(column(x_second), 200);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chart.png");
        img.write_png(&path).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let reader = decoder.read_info().unwrap();
        assert_eq!(reader.info().width, img.width);
    }

    #[test]
    fn a_long_title_is_drawn_whole() {
        let title = "CHALLENGING: SUCCESS RATE BY KAPPA QUARTER (%)";
        let chart = BarChart {
            series: vec!["ONE".into()],
            panels: vec![Panel {
                title: title.into(),
                groups: vec![("A".into(), vec![Some((0.5, 0.0))])],
            }],
        };
        let img = chart.render();
        // The title starts at x = 70, y = 10; its last glyph (')') has ink in its 7-row band.
        let last = 70 + (title.chars().count() as u32 - 1) * GLYPH_W;
        let inked = (last..last + GLYPH_W)
            .flat_map(|x| (10..10 + 7 * SCALE).map(move |y| (x, y)))
            .any(|(x, y)| img.pixel(x, y) == Some(BLACK));
        assert!(img.width >= last + GLYPH_W, "width {}", img.width);
        assert!(inked, "the title's last glyph is not drawn");
    }
}
