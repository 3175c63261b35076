//! Text of rendered pictures (titles, colour-bar ticks, swatch labels):
//! glyph outlines of a real font, rasterised to anti-aliased coverage and
//! blended into the image.
//!
//! **Rasteriser: [`ab_glyph`]**: pure Rust, actively maintained (regular
//! releases, used by `glyph_brush`, `imageproc` and game engines), parsing
//! through `ttf-parser`, the common Rust font parser; only its `std`
//! feature is enabled (no variable fonts), so it brings in only
//! `ab_glyph_rasterizer` and `ttf-parser` (with a thin owning wrapper).
//! It gives exact per-pixel coverage, advances and kerning, which is all a
//! label needs. `fontdue` would do as well; its own layout engine and glyph
//! caches are more than a handful of labels per picture calls for.
//!
//! **Font: Ubuntu Light** (Dalton Maag for Canonical), under the
//! [Ubuntu Font Licence 1.0], taken as bytes from the
//! [`epaint_default_fonts`] crate (egui's default fonts), so nothing is
//! fetched or committed here. It has every glyph the pictures print —
//! digits, Latin letters, `‰` (U+2030), `%`, `³`, `°`, `τ`, `×`, `−`, `·`,
//! `…` — checked by the tests below (it has no `□`, which only report.html
//! prints, as HTML text), and a light proportional face reads well at the
//! 9–30 px sizes used, with its coverage darkened a little at small sizes.
//! (Hack, the crate's other text face, is monospaced and squeezes `‰` into
//! one cell.) A character without a glyph would show as the font's
//! `.notdef` box; [`has_glyph`] tells.
//!
//! Layout unit: a *line* of text at size `size` px is a box `size` px tall
//! (the font's ascent − descent) with the baseline at the rounded ascent.
//! [`Label`] is one placed line; its [`Label::rect`] bounds every pixel its
//! drawing can touch (the line box united with the glyphs' ink), which is
//! what [`super::layout`] keeps apart.
//!
//! [Ubuntu Font Licence 1.0]: https://ubuntu.com/legal/font-licence

use std::sync::OnceLock;

use ab_glyph::{point, Font, FontRef, Glyph, PxScale, ScaleFont};

use super::image::{Image, Rgb};

/// The embedded font's name, for messages and docs.
pub const FONT_NAME: &str = "Ubuntu Light";

fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    FONT.get_or_init(|| {
        FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT)
            .expect("the embedded Ubuntu Light font parses")
    })
}

/// Line height in text-scale units: a line at text scale `s` is `9 s` px.
pub const LINE_UNITS: usize = 9;

/// Line height in pixels at text `scale` (18 px at scale 2).
pub fn line_height(scale: usize) -> usize {
    LINE_UNITS * scale.max(1)
}

/// Whether the embedded font has a glyph of its own for `c` (not `.notdef`).
pub fn has_glyph(c: char) -> bool {
    font().glyph_id(c).0 != 0
}

/// The font's glyph index of `c` (0 is `.notdef`).
pub fn glyph_index(c: char) -> u16 {
    font().glyph_id(c).0
}

/// An integer pixel rectangle `[x, x + w) × [y, y + h)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Rect {
    pub x: i64,
    pub y: i64,
    pub w: i64,
    pub h: i64,
}

impl Rect {
    pub fn right(&self) -> i64 {
        self.x + self.w
    }

    pub fn bottom(&self) -> i64 {
        self.y + self.h
    }

    /// Whether the two share a pixel (touching edges do not overlap).
    pub fn overlaps(&self, o: &Rect) -> bool {
        self.x < o.right() && o.x < self.right() && self.y < o.bottom() && o.y < self.bottom()
    }

    /// Whether the rectangle lies inside a `width × height` image.
    pub fn inside(&self, width: usize, height: usize) -> bool {
        self.x >= 0 && self.y >= 0 && self.right() <= width as i64 && self.bottom() <= height as i64
    }

    /// The smallest rectangle holding both.
    pub fn union(&self, o: &Rect) -> Rect {
        let (x0, y0) = (self.x.min(o.x), self.y.min(o.y));
        let (x1, y1) = (self.right().max(o.right()), self.bottom().max(o.bottom()));
        Rect {
            x: x0,
            y: y0,
            w: x1 - x0,
            h: y1 - y0,
        }
    }

    fn offset(&self, dx: i64, dy: i64) -> Rect {
        Rect {
            x: self.x + dx,
            y: self.y + dy,
            ..*self
        }
    }
}

/// The glyphs of `text` at `size` px, positioned with the line box's
/// top-left at the origin, and the line's advance width.
fn glyphs(text: &str, size: f32) -> (Vec<Glyph>, f32) {
    let f = font().as_scaled(PxScale::from(size));
    let baseline = f.ascent().round();
    let mut x = 0.0f32;
    let mut prev = None;
    let mut out = Vec::with_capacity(text.len());
    for c in text.chars() {
        let id = f.glyph_id(c);
        if let Some(p) = prev {
            x += f.kern(p, id);
        }
        out.push(id.with_scale_and_position(f.scale(), point(x, baseline)));
        x += f.h_advance(id);
        prev = Some(id);
    }
    (out, x)
}

/// Anti-aliased coverage of one line of text: `alpha` in `[0, 1]`, row
/// major over `rect`, which is relative to the line box's top-left and
/// holds the line box and all ink.
#[derive(Clone, Debug, PartialEq)]
pub struct Coverage {
    pub rect: Rect,
    pub alpha: Vec<f32>,
}

impl Coverage {
    /// Sum of the coverage (ink in pixels).
    pub fn ink(&self) -> f64 {
        self.alpha.iter().map(|&a| a as f64).sum()
    }
}

/// The box of `text` at `size` (relative to its line box's top-left) and
/// the outlined glyphs that fill it.
fn outline(text: &str, size: f32) -> (Rect, Vec<ab_glyph::OutlinedGlyph>) {
    let (gs, advance) = glyphs(text, size);
    let mut rect = Rect {
        x: 0,
        y: 0,
        w: advance.ceil().max(0.0) as i64,
        h: size.ceil() as i64,
    };
    let outlined: Vec<_> = gs
        .into_iter()
        .filter_map(|g| font().outline_glyph(g))
        .collect();
    for o in &outlined {
        let b = o.px_bounds();
        let ink = Rect {
            x: b.min.x.floor() as i64,
            y: b.min.y.floor() as i64,
            w: (b.max.x.ceil() - b.min.x.floor()) as i64,
            h: (b.max.y.ceil() - b.min.y.floor()) as i64,
        };
        rect = rect.union(&ink);
    }
    (rect, outlined)
}

/// The box of `text` at `size` px relative to its line box's top-left:
/// the line box (advance × size) united with the ink.
pub fn measure(text: &str, size: f32) -> Rect {
    outline(text, size).0
}

/// Rasterises one line of `text` at `size` px (coverage darkened by
/// [`stem_darkening`]).
pub fn rasterise(text: &str, size: f32) -> Coverage {
    let (rect, outlined) = outline(text, size);
    let (w, h) = (rect.w.max(0) as usize, rect.h.max(0) as usize);
    let mut alpha = vec![0f32; w * h];
    for o in &outlined {
        let b = o.px_bounds();
        let (ox, oy) = (b.min.x as i64 - rect.x, b.min.y as i64 - rect.y);
        o.draw(|gx, gy, c| {
            let (x, y) = (ox + gx as i64, oy + gy as i64);
            if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                let a = &mut alpha[y as usize * w + x as usize];
                *a = (*a + c).min(1.0);
            }
        });
    }
    let gamma = stem_darkening(size);
    for a in &mut alpha {
        *a = a.powf(gamma);
    }
    Coverage { rect, alpha }
}

/// Exponent applied to coverage: a light face's stems at 9 px cover only
/// about half a pixel and would print grey; `coverage^γ`, γ < 1, darkens
/// partial pixels, more at small sizes (γ = 0.6 at 9 px, 0.75 at 18 px,
/// 0.85 from 24 px), as FreeType's stem darkening does.
fn stem_darkening(size: f32) -> f32 {
    (0.45 + size / 60.0).clamp(0.6, 0.85)
}

/// One line of text placed in a picture: `(x, y)` is its line box's
/// top-left, `rect` every pixel its drawing can touch.
#[derive(Clone, Debug, PartialEq)]
pub struct Label {
    pub text: String,
    pub size: f32,
    pub x: i64,
    pub y: i64,
    pub rect: Rect,
}

impl Label {
    /// `text` at `size` px with its line box's top-left at the origin.
    pub fn new(text: impl Into<String>, size: f32) -> Label {
        let text = text.into();
        let rect = measure(&text, size);
        Label {
            text,
            size,
            x: 0,
            y: 0,
            rect,
        }
    }

    /// Width of [`Label::rect`].
    pub fn width(&self) -> i64 {
        self.rect.w
    }

    /// Moved so that `rect` starts at `x`.
    pub fn with_left(mut self, x: i64) -> Label {
        let d = x - self.rect.x;
        self.x += d;
        self.rect = self.rect.offset(d, 0);
        self
    }

    /// Moved so that `rect` is centred on `cx`.
    pub fn with_centre(self, cx: i64) -> Label {
        let w = self.rect.w;
        self.with_left(cx - w / 2)
    }

    /// Moved so that the line box's top is at `y`.
    pub fn with_top(mut self, y: i64) -> Label {
        let d = y - self.y;
        self.y += d;
        self.rect = self.rect.offset(0, d);
        self
    }

    /// Blends the text's coverage in `colour` over `img` (clipped).
    pub fn draw(&self, img: &mut Image, colour: Rgb) {
        let cov = rasterise(&self.text, self.size);
        let w = cov.rect.w.max(0) as usize;
        if w == 0 {
            return;
        }
        for (j, row) in cov.alpha.chunks(w).enumerate() {
            for (i, &a) in row.iter().enumerate() {
                if a > 0.0 {
                    let x = self.x + cov.rect.x + i as i64;
                    let y = self.y + cov.rect.y + j as i64;
                    img.blend(x, y, colour, a as f64);
                }
            }
        }
    }
}

/// `text` as a label at most `max_w` px wide: at `size` if it fits, else
/// at a smaller size down to 70 % of it (not below 7 px), else shortened
/// with `…` at that smallest size; `None` when not even `…` fits. A
/// smaller label is centred vertically in the line of `size`.
pub fn fit_label(text: &str, size: f32, max_w: i64) -> Option<Label> {
    let min = (0.7 * size).max(7.0).min(size);
    let centred = |l: Label| {
        let dy = ((size - l.size) / 2.0).round() as i64;
        l.with_top(dy)
    };
    let mut s = size;
    loop {
        let l = Label::new(text, s);
        if l.width() <= max_w {
            return Some(centred(l));
        }
        if s <= min {
            break;
        }
        s = (0.93 * s).max(min);
    }
    let chars: Vec<char> = text.chars().collect();
    (0..chars.len()).rev().find_map(|n| {
        let head: String = chars[..n].iter().collect();
        let l = Label::new(format!("{}…", head.trim_end()), min);
        (l.width() <= max_w).then(|| centred(l))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_font_has_every_glyph_the_pictures_print() {
        for c in "0123456789.-+e‰%°τ×−·³…,()=/_: ".chars() {
            assert!(has_glyph(c), "{c:?}");
        }
        for c in ('a'..='z').chain('A'..='Z') {
            assert!(has_glyph(c), "{c:?}");
        }
        assert_ne!(glyph_index('‰'), glyph_index('%'));
    }

    #[test]
    fn text_is_drawn_inside_its_rect() {
        let size = 18.0;
        let l = Label::new("S-fitmap a, 1/d³ (d = 1% of diagonal) ‰", size)
            .with_left(5)
            .with_top(7);
        assert_eq!(l.rect.x, 5);
        let mut img = Image::new(l.rect.right() as usize + 5, 40, [255, 255, 255]);
        l.draw(&mut img, [0, 0, 0]);
        let mut inked = 0;
        for y in 0..img.height {
            for x in 0..img.width {
                if img.get(x, y) != [255, 255, 255] {
                    inked += 1;
                    let r = Rect {
                        x: x as i64,
                        y: y as i64,
                        w: 1,
                        h: 1,
                    };
                    assert!(r.overlaps(&l.rect), "ink at {x}, {y} outside {:?}", l.rect);
                }
            }
        }
        assert!(inked > 200, "{inked}");
        // Anti-aliased: grey levels between the ink and the paper.
        let greys = img
            .pixels
            .iter()
            .filter(|p| p[0] > 30 && p[0] < 225)
            .count();
        assert!(greys > 50, "{greys} grey pixels");
    }

    #[test]
    fn long_text_is_shrunk_then_shortened() {
        let text = "distance to limit surface, ‰ of diagonal";
        let full = Label::new(text, 18.0);
        let l = fit_label(text, 18.0, full.width() - 20).unwrap();
        assert_eq!(l.text, text);
        assert!(l.size < 18.0 && l.width() <= full.width() - 20);
        let l = fit_label(text, 18.0, 60).unwrap();
        assert!(l.text.ends_with('…') && l.width() <= 60, "{l:?}");
        assert!(fit_label(text, 18.0, 2).is_none());
    }
}
