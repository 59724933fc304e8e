//! A 3×5 pixel font for digits (grain ids on overlays), so drawing needs no
//! font file. Other characters are drawn as a small box.

/// Rows of each glyph, top first; bit 2 is the left column.
const DIGITS: [[u8; 5]; 10] = [
    [0b111, 0b101, 0b101, 0b101, 0b111],
    [0b010, 0b110, 0b010, 0b010, 0b111],
    [0b111, 0b001, 0b111, 0b100, 0b111],
    [0b111, 0b001, 0b011, 0b001, 0b111],
    [0b101, 0b101, 0b111, 0b001, 0b001],
    [0b111, 0b100, 0b111, 0b001, 0b111],
    [0b111, 0b100, 0b111, 0b101, 0b111],
    [0b111, 0b001, 0b010, 0b010, 0b010],
    [0b111, 0b101, 0b111, 0b101, 0b111],
    [0b111, 0b101, 0b111, 0b001, 0b111],
];
const OTHER: [u8; 5] = [0b000, 0b111, 0b101, 0b111, 0b000];

/// Calls `plot(x, y)` for every lit pixel of `text` centred on (cx, cy),
/// each font pixel drawn as a `scale`×`scale` square.
pub fn draw_text(text: &str, cx: i64, cy: i64, scale: i64, mut plot: impl FnMut(i64, i64)) {
    let n = text.chars().count() as i64;
    let width = (4 * n - 1) * scale;
    let (x0, y0) = (cx - width / 2, cy - 5 * scale / 2);
    for (k, ch) in text.chars().enumerate() {
        let glyph = ch.to_digit(10).map(|d| DIGITS[d as usize]).unwrap_or(OTHER);
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..3 {
                if bits & (0b100 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        plot(
                            x0 + (4 * k as i64 + col) * scale + dx,
                            y0 + row as i64 * scale + dy,
                        );
                    }
                }
            }
        }
    }
}
