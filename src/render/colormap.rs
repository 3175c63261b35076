//! Colour maps and colour bars.
//!
//! One sequential map for every scalar field (error, F_S, F_M): blue → cyan
//! → green → yellow → red, bright enough everywhere that the shading still
//! reads on top of it (a dark end like viridis' purple would hide the shape
//! where the values are low, i.e. where a good fit is). Unprojectable
//! regions get [`UNPROJECTABLE`], a magenta that the map never produces.

use super::image::{Image, Rgb};
use super::layout::BarLayout;

/// Stops of the map, at `0, 1/4, 1/2, 3/4, 1`, linear RGB in [0, 1].
const STOPS: [[f32; 3]; 5] = [
    [0.20, 0.33, 0.88],
    [0.15, 0.72, 0.90],
    [0.38, 0.85, 0.36],
    [0.97, 0.80, 0.18],
    [0.86, 0.17, 0.12],
];

/// The colour of `t` in `[0, 1]` (clamped; NaN maps to 0).
pub fn colour_map(t: f64) -> [f32; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    if t >= 1.0 {
        return STOPS[STOPS.len() - 1];
    }
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = (x - i as f64) as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    [
        a[0] + f * (b[0] - a[0]),
        a[1] + f * (b[1] - a[1]),
        a[2] + f * (b[2] - a[2]),
    ]
}

/// The zero colour of the map (`colour_map(0.0)`).
pub const ZERO: [f32; 3] = STOPS[0];

/// Regions that normal projection does not reach (Fitmaps §4, "Unp.").
pub const UNPROJECTABLE: [f32; 3] = [0.85, 0.20, 0.80];

/// Plain surfaces: a neutral clay.
pub const CLAY: [f32; 3] = [0.80, 0.78, 0.74];

/// The limit surface under patch lines: a light blue-grey, so that dark
/// lines and red markers stand out.
pub const PATCH_SURFACE: [f32; 3] = [0.74, 0.80, 0.88];

/// Patch boundary lines.
pub const LINE: [f32; 3] = [0.06, 0.07, 0.10];

/// Extraordinary-vertex markers.
pub const MARKER: Rgb = [220, 30, 30];

pub const TEXT: Rgb = [20, 20, 20];
pub const BACKGROUND: Rgb = [255, 255, 255];

pub fn to_rgb8(c: [f32; 3]) -> Rgb {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// How values map to `[0, 1]` along a colour bar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scale {
    Linear,
    /// log10 between `lo` and `hi` (both > 0).
    Log,
}

/// A colour bar: the value range, how it maps to colours, a title and the
/// tick labels' formatting.
#[derive(Clone, Debug, PartialEq)]
pub struct ColourBar {
    pub title: String,
    pub lo: f64,
    pub hi: f64,
    pub scale: Scale,
    /// Extra swatch after the bar, e.g. `("unprojectable", UNPROJECTABLE)`.
    pub swatch: Option<(String, [f32; 3])>,
}

impl ColourBar {
    /// The position of `x` along the bar in `[0, 1]` (clamped).
    pub fn t(&self, x: f64) -> f64 {
        let (a, b, v) = match self.scale {
            Scale::Linear => (self.lo, self.hi, x),
            Scale::Log => (
                self.lo.max(f64::MIN_POSITIVE).log10(),
                self.hi.max(f64::MIN_POSITIVE).log10(),
                x.max(f64::MIN_POSITIVE).log10(),
            ),
        };
        if b.partial_cmp(&a) != Some(std::cmp::Ordering::Greater) {
            return 0.0;
        }
        ((v - a) / (b - a)).clamp(0.0, 1.0)
    }

    pub fn colour(&self, x: f64) -> [f32; 3] {
        colour_map(self.t(x))
    }

    /// Tick values: five evenly spaced (linearly or in log).
    pub fn ticks(&self) -> Vec<f64> {
        (0..5)
            .map(|k| {
                let f = k as f64 / 4.0;
                match self.scale {
                    Scale::Linear => self.lo + f * (self.hi - self.lo),
                    Scale::Log => {
                        let (a, b) = (self.lo.log10(), self.hi.log10());
                        10f64.powf(a + f * (b - a))
                    }
                }
            })
            .collect()
    }
}

/// Compact tick label: 3 significant digits, no exponent for the ranges we
/// show (per mille errors, sizes in d, a·d³).
pub fn format_tick(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if a < 1e-3 {
        // Scientific below 0.001 (small a·d³ of the S-fitmap): "2.7e-6".
        return format!("{x:.1e}");
    }
    let digits = if a >= 100.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 {
        2
    } else {
        // Enough decimals for 3 significant digits.
        (2 - a.log10().floor() as i64).clamp(2, 8) as usize
    };
    let mut s = format!("{x:.digits$}");
    if s.contains('.') {
        while s.ends_with('0') {
            s.pop();
        }
        if s.ends_with('.') {
            s.pop();
        }
    }
    s
}

/// Draws `bar` as laid out by [`super::layout::bar_layout`]: the framed
/// colour ramp, the tick marks of the labelled ticks, the swatch and every
/// label.
pub fn draw_bar(img: &mut Image, bar: &ColourBar, lay: &BarLayout) {
    let r = lay.bar;
    for i in 0..r.w {
        let t = (i as f64 + 0.5) / r.w as f64;
        img.fill_rect(r.x + i, r.y, 1, r.h, to_rgb8(colour_map(t)));
    }
    // Frame the bar so that its light end stays visible on white.
    let frame = [90, 90, 90];
    img.fill_rect(r.x - 1, r.y - 1, r.w + 2, 1, frame);
    img.fill_rect(r.x - 1, r.bottom(), r.w + 2, 1, frame);
    img.fill_rect(r.x - 1, r.y - 1, 1, r.h + 2, frame);
    img.fill_rect(r.right(), r.y - 1, 1, r.h + 2, frame);
    // Tick marks one text-scale unit long (the gap above the labels).
    let mark = lay
        .tick_labels
        .first()
        .map(|l| (l.y - r.bottom()).max(1))
        .unwrap_or(1);
    for &tx in &lay.ticks {
        img.fill_rect(tx, r.bottom(), 1, mark, frame);
    }
    if let (Some(s), Some((_, c))) = (lay.swatch, &bar.swatch) {
        img.fill_rect(s.x, s.y, s.w, s.h, to_rgb8(*c));
    }
    for l in lay.labels() {
        l.draw(img, TEXT);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_ends_and_clamping() {
        assert_eq!(colour_map(0.0), ZERO);
        assert_eq!(colour_map(-1.0), ZERO);
        assert_eq!(colour_map(f64::NAN), ZERO);
        assert_eq!(colour_map(1.0), STOPS[4]);
        assert_eq!(colour_map(0.5), STOPS[2]);
        // The unprojectable colour is far from every colour of the map.
        for i in 0..=100 {
            let c = colour_map(i as f64 / 100.0);
            let d: f32 = (0..3).map(|k| (c[k] - UNPROJECTABLE[k]).abs()).sum();
            assert!(d > 0.3, "{i}: {c:?}");
        }
    }

    #[test]
    fn log_bar_positions() {
        let b = ColourBar {
            title: String::new(),
            lo: 0.01,
            hi: 1.0,
            scale: Scale::Log,
            swatch: None,
        };
        assert!((b.t(0.1) - 0.5).abs() < 1e-12);
        assert_eq!(b.t(0.0), 0.0);
        assert_eq!(b.t(5.0), 1.0);
    }

    #[test]
    fn tick_labels() {
        assert_eq!(format_tick(0.0), "0");
        assert_eq!(format_tick(2.5), "2.5");
        assert_eq!(format_tick(12.26), "12.3");
        assert_eq!(format_tick(0.01234), "0.0123");
        assert_eq!(format_tick(250.0), "250");
        assert_eq!(format_tick(2.66e-6), "2.7e-6");
    }
}
