//! Where the text and colour bars of a picture go: panel titles, colour
//! bars with their titles, tick labels and swatches. Pure geometry from
//! measured text ([`super::font`]), so the boxes can be checked without
//! rendering: [`PictureLayout::labels`] lists every label's rectangle.
//!
//! Rules: bands keep the heights of the old fixed layout (a title band of
//! `13 s` px above a panel, a bar band of `29 s` px below it, `s` the text
//! scale), so the surfaces are framed as before; a title too wide for its
//! panel is shrunk, then shortened with `…` ([`fit_label`]); tick labels are
//! measured and thinned (every tick, every other one, the ends, the low
//! end, none) until no two come closer than a gap; any label that would
//! still leave the image is dropped.

use super::colormap::{format_tick, ColourBar};
use super::font::{fit_label, line_height, Label, Rect};
use super::text_scale;

/// Height in pixels of the title band above a panel at text `scale`.
pub fn title_band(scale: usize) -> usize {
    13 * scale.max(1)
}

/// Height in pixels of a colour bar's band at text `scale`.
pub fn bar_band(scale: usize) -> usize {
    // title 9, gap 2, bar 6, tick mark + gap 1, tick labels 9, margin 2.
    29 * scale.max(1)
}

/// A colour bar laid out in its band.
#[derive(Clone, Debug, PartialEq)]
pub struct BarLayout {
    /// The colour ramp (its 1 px frame lies just outside).
    pub bar: Rect,
    /// The colour swatch after the ramp, if the bar has one.
    pub swatch: Option<Rect>,
    /// x of each labelled tick mark, below the ramp.
    pub ticks: Vec<i64>,
    pub title: Option<Label>,
    pub swatch_label: Option<Label>,
    pub tick_labels: Vec<Label>,
}

impl BarLayout {
    pub fn labels(&self) -> impl Iterator<Item = &Label> {
        self.title
            .iter()
            .chain(&self.swatch_label)
            .chain(&self.tick_labels)
    }
}

/// Tick labels centred on `ticks` `(x, value)` in the row at `top`, each
/// kept within `[lo, hi)`: the first of "every tick", "every other", …,
/// "the two ends", "the first" whose labels keep `gap` px apart.
fn tick_row(
    ticks: &[(i64, f64)],
    size: f32,
    top: i64,
    lo: i64,
    hi: i64,
    gap: i64,
) -> Vec<(i64, Label)> {
    let n = ticks.len();
    let mut subsets: Vec<Vec<usize>> = (1..n.max(2))
        .filter(|stride| (n - 1) % stride == 0)
        .map(|stride| (0..n).step_by(stride).collect())
        .collect();
    subsets.push(vec![0]);
    for subset in subsets {
        let labels: Vec<(i64, Label)> = subset
            .iter()
            .filter(|&&k| k < n)
            .map(|&k| {
                let (x, v) = ticks[k];
                let l = Label::new(format_tick(v), size).with_top(top);
                let left = (x - l.width() / 2).min(hi - l.width()).max(lo);
                (x, l.with_left(left))
            })
            .collect();
        let fits = labels.iter().all(|(_, l)| l.rect.right() <= hi);
        let apart = labels
            .windows(2)
            .all(|p| p[0].1.rect.right() + gap <= p[1].1.rect.x);
        if fits && apart {
            return labels;
        }
    }
    Vec::new()
}

/// `text` fitted into the box `[left, right) × [top, bottom)`, its
/// rectangle centred on `centre_y` where the box allows: at `size` if it
/// fits, else smaller, else shortened ([`fit_label`]); `None` if nothing
/// of it fits.
fn fit_between(
    text: &str,
    size: f32,
    (left, right): (i64, i64),
    (top, bottom): (i64, i64),
    centre_y: i64,
) -> Option<Label> {
    let mut s = size;
    loop {
        if let Some(l) = fit_label(text, s, right - left) {
            let l = l.with_left(left).with_top(0);
            let h = l.rect.h;
            if h <= bottom - top {
                let above = l.rect.y - l.y;
                let rect_top = (centre_y - h / 2).clamp(top, bottom - h);
                return Some(l.with_top(rect_top - above));
            }
        }
        if s <= 7.0 {
            return None;
        }
        s = (0.93 * s).max(7.0);
    }
}

/// Lays out `bar` in the band `(x, y, w, bar_band(scale))`.
pub fn bar_layout(bar: &ColourBar, x: usize, y: usize, w: usize, scale: usize) -> BarLayout {
    let s = scale.max(1);
    let size = line_height(s) as f32;
    let (xi, yi, wi, si) = (x as i64, y as i64, w as i64, s as i64);
    let (lo, hi) = (xi + si, xi + wi - si);
    let title = fit_label(&bar.title, size, hi - lo).map(|l| {
        let dy = l.y;
        l.with_centre(xi + wi / 2).with_top(yi + dy)
    });
    let swatch_text = bar
        .swatch
        .as_ref()
        .map(|(t, _)| Label::new(t.as_str(), size));
    let swatch_w = swatch_text
        .as_ref()
        .map(|l| (10 * s + 3 * s + 6 * s) as i64 + l.width())
        .unwrap_or(0)
        .max(0) as usize;
    let bar_w = (w * 6 / 10).min(w.saturating_sub(swatch_w + 8 * s)).max(10);
    let bx = x + w.saturating_sub(bar_w + swatch_w) / 2;
    let by = y + 11 * s;
    let bh = 6 * s;
    let ramp = Rect {
        x: bx as i64,
        y: by as i64,
        w: bar_w as i64,
        h: bh as i64,
    };
    let swatch = bar.swatch.as_ref().map(|_| Rect {
        x: ramp.right() + 6 * si,
        y: ramp.y,
        w: 10 * si,
        h: ramp.h,
    });
    let ticks: Vec<(i64, f64)> = {
        let values = bar.ticks();
        let k = values.len().saturating_sub(1).max(1) as f64;
        values
            .iter()
            .enumerate()
            .map(|(i, &v)| ((bx as f64 + bar_w as f64 * i as f64 / k).round() as i64, v))
            .collect()
    };
    let gap = (2 * si).max((0.35 * size).round() as i64);
    let (marks, tick_labels): (Vec<i64>, Vec<Label>) =
        tick_row(&ticks, size, ramp.bottom() + si, lo, hi, gap)
            .into_iter()
            .unzip();
    // The swatch label sits level with the ramp, below the bar title's
    // ink and above the tick labels' where they share columns.
    let swatch_label = swatch.zip(bar.swatch.as_ref()).and_then(|(r, (t, _))| {
        let (left, right) = (r.right() + 3 * si, hi);
        let shares = |l: &Label| l.rect.x < right && left < l.rect.right();
        let top = title
            .iter()
            .filter(|l| shares(l))
            .map(|l| l.rect.bottom())
            .fold(yi, i64::max);
        let bottom = tick_labels
            .iter()
            .filter(|l| shares(l))
            .map(|l| l.rect.y)
            .fold(yi + bar_band(s) as i64, i64::min);
        fit_between(t, size, (left, right), (top, bottom), ramp.y + ramp.h / 2)
    });
    BarLayout {
        bar: ramp,
        swatch,
        ticks: marks,
        title,
        swatch_label,
        tick_labels,
    }
}

/// The text of one panel: its title and colour bar.
#[derive(Clone, Copy, Debug, Default)]
pub struct Legend<'a> {
    pub title: Option<&'a str>,
    pub bar: Option<&'a ColourBar>,
}

/// One panel laid out: the surface picture at `(x, top)`, `w × h`.
#[derive(Clone, Debug, PartialEq)]
pub struct PanelLayout {
    pub x: usize,
    pub top: usize,
    pub w: usize,
    pub h: usize,
    pub title: Option<Label>,
    pub bar: Option<BarLayout>,
}

/// A whole picture laid out.
#[derive(Clone, Debug, PartialEq)]
pub struct PictureLayout {
    pub width: usize,
    pub height: usize,
    pub scale: usize,
    pub panels: Vec<PanelLayout>,
}

impl PictureLayout {
    /// Every label of the picture (panel titles, bar titles, swatch and
    /// tick labels).
    pub fn labels(&self) -> Vec<&Label> {
        self.panels
            .iter()
            .flat_map(|p| p.title.iter().chain(p.bar.iter().flat_map(|b| b.labels())))
            .collect()
    }
}

/// Lays out `legends.len()` panels side by side in a `width × height`
/// picture; labels that would leave the picture are dropped.
pub fn layout_picture(legends: &[Legend], width: usize, height: usize) -> PictureLayout {
    let s = text_scale(width, height);
    let n = legends.len().max(1);
    let pw = width / n;
    let size = line_height(s) as f32;
    let inside = |l: &Label| l.rect.inside(width, height);
    let panels = legends
        .iter()
        .enumerate()
        .map(|(k, legend)| {
            let top = if legend.title.is_some() {
                title_band(s)
            } else {
                0
            };
            let bottom = if legend.bar.is_some() { bar_band(s) } else { 0 };
            let h = height.saturating_sub(top + bottom).max(8);
            let x = k * pw;
            let title = legend
                .title
                .and_then(|t| fit_label(t, size, pw as i64 - 2 * s as i64))
                .map(|l| {
                    let dy = l.y;
                    l.with_centre((x + pw / 2) as i64)
                        .with_top((2 * s) as i64 + dy)
                })
                .filter(inside);
            let bar = legend.bar.map(|b| {
                let mut bl = bar_layout(b, x, top + h, pw, s);
                bl.title = bl.title.filter(inside);
                bl.swatch_label = bl.swatch_label.filter(inside);
                bl.tick_labels.retain(inside);
                bl
            });
            PanelLayout {
                x,
                top,
                w: pw,
                h,
                title,
                bar,
            }
        })
        .collect();
    PictureLayout {
        width,
        height,
        scale: s,
        panels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::colormap::Scale;

    fn bar(lo: f64, hi: f64, scale: Scale, swatch: bool) -> ColourBar {
        ColourBar {
            title: "S-fitmap a, 1/d³ (d = 1% of diagonal)".into(),
            lo,
            hi,
            scale,
            swatch: swatch.then(|| ("unprojectable".into(), [1.0, 0.0, 1.0])),
        }
    }

    #[test]
    fn labels_never_overlap_and_stay_inside() {
        let bars = [
            bar(2.66e-6, 0.0123, Scale::Log, false),
            bar(0.0, 12.26, Scale::Linear, true),
            bar(-0.00123, 1234.5, Scale::Linear, true),
            bar(1e-9, 1e-3, Scale::Log, true),
        ];
        for (w, h) in [
            (16, 16),
            (120, 90),
            (300, 200),
            (640, 480),
            (1024, 768),
            (1900, 400),
        ] {
            for b in &bars {
                for n in 1..=3 {
                    let legends = vec![
                        Legend {
                            title: Some("F_S"),
                            bar: Some(b),
                        };
                        n
                    ];
                    let lay = layout_picture(&legends, w, h);
                    let labels = lay.labels();
                    for (i, a) in labels.iter().enumerate() {
                        assert!(a.rect.inside(w, h), "{w}x{h}: {a:?}");
                        for c in &labels[i + 1..] {
                            assert!(!a.rect.overlaps(&c.rect), "{w}x{h}: {a:?} and {c:?}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn crowded_ticks_are_thinned() {
        let b = bar(2.66e-6, 0.0123, Scale::Log, false);
        let wide = bar_layout(&b, 0, 0, 1000, 2);
        assert_eq!(wide.tick_labels.len(), 5);
        assert_eq!(wide.ticks.len(), 5);
        let narrow = bar_layout(&b, 0, 0, 200, 2);
        assert!(
            (1..5).contains(&narrow.tick_labels.len()),
            "{:?}",
            narrow.tick_labels
        );
        // The ends are kept first.
        assert_eq!(narrow.tick_labels[0].text, format_tick(2.66e-6));
    }
}
