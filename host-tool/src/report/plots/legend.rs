//! Legends: drawn in a strip reserved to the right of the plotting area, never over the data.

use super::*;

/// Width of the legend strip to the right of every chart, px.
pub(super) const LEGEND_W: i32 = 230;
/// Characters per legend line before it wraps.
pub(super) const LEGEND_WRAP: usize = 25;

/// How a legend entry is drawn.
#[derive(Clone, Copy)]
pub(super) enum Mark {
    /// A line in this style (dashed or solid).
    Line(ShapeStyle, bool),
    /// A filled swatch.
    Fill(RGBAColor),
}

/// One legend entry.
pub(super) struct Entry {
    pub(super) label: String,
    pub(super) mark: Mark,
}

pub(super) fn entry(label: impl Into<String>, mark: Mark) -> Entry {
    Entry {
        label: label.into(),
        mark,
    }
}

/// Splits `area` into the plotting part and the legend strip on its right.
pub(super) fn with_legend_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let w = area.dim_in_pixel().0 as i32;
    area.split_horizontally((w - LEGEND_W).max(w / 2))
}

/// `label` broken into lines of at most [`LEGEND_WRAP`] characters at spaces.
pub(super) fn wrap(label: &str) -> Vec<String> {
    let mut lines: Vec<String> = vec![];
    for word in label.split(' ') {
        match lines.last_mut() {
            Some(l) if l.chars().count() + 1 + word.chars().count() <= LEGEND_WRAP => {
                l.push(' ');
                l.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// Draws the legend entries top-down in `strip` (the area beside the chart).
pub(super) fn legend_strip<DB: DrawingBackend>(
    strip: &DrawingArea<DB, Shift>,
    entries: &[Entry],
) -> Result<()> {
    let mut y = 10;
    for e in entries {
        let (x0, x1, ym) = (6, 26, y + 7);
        match e.mark {
            Mark::Line(style, true) => strip.draw(&DashedPathElement::new(
                vec![(x0, ym), (x1, ym)],
                5,
                3,
                style.stroke_width(2),
            )),
            Mark::Line(style, false) => strip.draw(&PathElement::new(
                vec![(x0, ym), (x1, ym)],
                style.stroke_width(2),
            )),
            Mark::Fill(c) => strip.draw(&Rectangle::new([(x0, ym - 5), (x1, ym + 5)], c.filled())),
        }
        .map_err(err)?;
        for line in wrap(&e.label) {
            strip
                .draw(&Text::new(line, (x1 + 6, y), (FONT, 14)))
                .map_err(err)?;
            y += 17;
        }
        y += 5;
    }
    Ok(())
}
