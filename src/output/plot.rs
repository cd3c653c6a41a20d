//! Line plots written as PNG files (training curves such as PSNR against time), and the
//! labels of comparison strips ([`label_panels`]).
//!
//! Lines and axes are drawn by `plotters`; every piece of text, in plots and strips alike, is
//! laid out here with `ab_glyph` ([`lay_out`]) in the font the viewer's egui already ships in
//! the binary (Ubuntu Light, from `epaint_default_fonts`): the build links no system font
//! libraries, and a plot looks the same on every machine, with no font files to find.

use std::path::{Path, PathBuf};

use image::{ExtendedColorType, ImageEncoder};
use plotters::prelude::*;
use plotters_backend::text_anchor::{HPos, Pos, VPos};
use plotters_backend::{BackendColor, BackendCoord, BackendTextStyle, DrawingErrorKind};

/// Width of the written PNG in pixels.
pub const WIDTH: u32 = 800;
/// Height of the written PNG in pixels.
pub const HEIGHT: u32 = 500;

/// One named line of (x, y) points.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Why a plot could not be written; every message starts with the file's path.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{}: cannot draw plot: {message}", path.display())]
    Draw { path: PathBuf, message: String },
    #[error("{}: cannot encode PNG: {source}", path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Writes an 800×500 PNG line plot of `series` to `path`, with title, axis labels, tick labels
/// and a legend of the series names.
///
/// Axis ranges cover all finite points plus a small margin. Non-finite points are skipped (the
/// line joins the neighbouring finite points); a series left with one point is drawn as a dot;
/// series with no points only appear in the legend; with no points at all the axes span about
/// [0, 1] and the plot says "no data". Each series gets its own colour (ten distinct ones, then more from
/// a larger palette).
///
/// The PNG is written to a temporary file in the same folder and renamed onto `path`, so `path`
/// never holds a partial image; on failure the temporary file is removed.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<(), PlotError> {
    let labels = Labels {
        title,
        x: x_label,
        y: y_label,
    };
    let rgb = render(series, &labels, font_available()).map_err(|message| PlotError::Draw {
        path: path.to_path_buf(),
        message,
    })?;
    write_png_atomic(path, &rgb)
}

struct Labels<'a> {
    title: &'a str,
    x: &'a str,
    y: &'a str,
}

/// Whether the embedded font parses: false only if it does not (then the plot is drawn
/// without text rather than not at all).
///
/// plotters sizes captions, label areas and the legend box through its own font table before
/// any text reaches the backend, so the same font is registered there once; the drawing and
/// the placement of glyphs stay with [`GlyphText`].
fn font_available() -> bool {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *REGISTERED.get_or_init(|| {
        ab_glyph::FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT).is_ok()
            && plotters::style::register_font(
                "sans-serif",
                plotters::style::FontStyle::Normal,
                epaint_default_fonts::UBUNTU_LIGHT,
            )
            .is_ok()
    })
}

/// Series colours: the ten "Tableau 10" colours, then plotters' 99-colour palette.
const COLOURS: [RGBColor; 10] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0xe3, 0x77, 0xc2),
    RGBColor(0x7f, 0x7f, 0x7f),
    RGBColor(0xbc, 0xbd, 0x22),
    RGBColor(0x17, 0xbe, 0xcf),
];

fn colour(i: usize) -> RGBColor {
    match COLOURS.get(i) {
        Some(&c) => c,
        None => {
            let (r, g, b) = Palette99::pick(i - COLOURS.len()).rgb();
            RGBColor(r, g, b)
        }
    }
}

fn finite_points(s: &Series) -> Vec<(f64, f64)> {
    s.points
        .iter()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect()
}

/// `[lo, hi]` covering `values` with a 5% margin each side (covering `[0, 1]` when there are no
/// values, a widened range when all are equal), never beyond ±1e300.
fn axis_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let (lo, hi) = if lo > hi { (0.0, 1.0) } else { (lo, hi) };
    // plotters' tick placement loops forever on an infinite span, so keep |ends| <= LIMIT.
    const LIMIT: f64 = 1e300;
    let (lo, hi) = (lo.clamp(-LIMIT, LIMIT), hi.clamp(-LIMIT, LIMIT));
    let span = hi - lo;
    let margin = if span > 0.0 {
        span * 0.05
    } else {
        (lo.abs() * 0.1).max(1.0)
    };
    ((lo - margin).max(-LIMIT), (hi + margin).min(LIMIT))
}

/// Tick label for `v` on an axis over `range` with about `ticks` ticks: just enough decimals
/// for the tick spacing, and scientific notation for very large or very small magnitudes
/// (plotters' own labels have no exponent form and at most five decimals).
fn tick_label(v: f64, (lo, hi): (f64, f64), ticks: usize) -> String {
    let step = (hi - lo) / ticks.max(1) as f64;
    if !(step.is_finite() && step > 0.0) {
        return format!("{v}");
    }
    // Tick positions come from float arithmetic: snap near-zero noise so it prints as 0, and
    // `+ 0.0` turns -0.0 into 0.0.
    let v = if v.abs() < step * 1e-6 { 0.0 } else { v } + 0.0;
    let magnitude = lo.abs().max(hi.abs());
    let decimals = (-step.log10()).ceil().max(0.0) as usize;
    if (1e-3..1e6).contains(&magnitude) && decimals <= 4 {
        format!("{v:.decimals$}")
    } else if v == 0.0 {
        "0".to_string()
    } else {
        let digits = (magnitude.log10().floor() - step.log10().floor()).clamp(0.0, 6.0) as usize;
        format!("{v:.digits$e}")
    }
}

/// Legend corner holding the fewest samples of the drawn lines, in axis-fraction coordinates.
fn legend_corner(lines: &[Vec<(f64, f64)>], x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    const SAMPLES_PER_SEGMENT: usize = 8;
    const BOX: f64 = 0.4; // legend box size as a fraction of the plot width and height
    let mut counts = [0usize; 4]; // upper left, upper right, lower left, lower right
    let mut count = |(px, py): (f64, f64)| {
        let fx = (px - x.0) / (x.1 - x.0);
        let fy = (py - y.0) / (y.1 - y.0);
        let left = fx <= BOX;
        let right = fx >= 1.0 - BOX;
        let lower = fy <= BOX;
        let upper = fy >= 1.0 - BOX;
        for (i, hit) in [upper && left, upper && right, lower && left, lower && right]
            .into_iter()
            .enumerate()
        {
            counts[i] += usize::from(hit);
        }
    };
    for line in lines {
        if let [only] = line.as_slice() {
            count(*only);
        }
        for w in line.windows(2) {
            let ((x0, y0), (x1, y1)) = (w[0], w[1]);
            for k in 0..SAMPLES_PER_SEGMENT {
                let t = k as f64 / SAMPLES_PER_SEGMENT as f64;
                count((x0 + t * (x1 - x0), y0 + t * (y1 - y0)));
            }
        }
        if let Some(&last) = line.last() {
            count(last);
        }
    }
    // Ties go to the earlier entry: upper right first, the usual place for a legend.
    let order = [1, 0, 3, 2];
    let best = order.into_iter().min_by_key(|&i| counts[i]).unwrap_or(1);
    match best {
        0 => SeriesLabelPosition::UpperLeft,
        2 => SeriesLabelPosition::LowerLeft,
        3 => SeriesLabelPosition::LowerRight,
        _ => SeriesLabelPosition::UpperRight,
    }
}

/// Draws the plot into an RGB8 buffer of `WIDTH * HEIGHT` pixels. With `text` false nothing
/// that needs a font is drawn.
fn render(series: &[Series], labels: &Labels, text: bool) -> Result<Vec<u8>, String> {
    let mut rgb = vec![0u8; WIDTH as usize * HEIGHT as usize * 3];
    draw(&mut rgb, series, labels, text).map_err(|e| e.to_string())?;
    Ok(rgb)
}

type DrawResult =
    Result<(), DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>>;

fn draw(rgb: &mut [u8], series: &[Series], labels: &Labels, text: bool) -> DrawResult {
    let lines: Vec<Vec<(f64, f64)>> = series.iter().map(finite_points).collect();
    let x_range = axis_range(lines.iter().flatten().map(|p| p.0));
    let y_range = axis_range(lines.iter().flatten().map(|p| p.1));
    let has_data = lines.iter().any(|l| !l.is_empty());

    let Ok(font) = ab_glyph::FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT) else {
        return Err(DrawingAreaErrorKind::LayoutError);
    };
    let root = GlyphText {
        inner: BitMapBackend::with_buffer(rgb, (WIDTH, HEIGHT)),
        font: &font,
    }
    .into_drawing_area();
    root.fill(&WHITE)?;

    let mut builder = ChartBuilder::on(&root);
    if text {
        builder
            .caption(labels.title, (FontFamily::SansSerif, 24))
            .margin(12)
            .margin_right(24)
            .x_label_area_size(52)
            .y_label_area_size(78);
    } else {
        builder.margin(20);
    }
    let mut chart = builder.build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)?;

    const X_TICKS: usize = 10;
    const Y_TICKS: usize = 8;
    let x_format = |v: &f64| tick_label(*v, x_range, X_TICKS);
    let y_format = |v: &f64| tick_label(*v, y_range, Y_TICKS);
    let mut mesh = chart.configure_mesh();
    mesh.x_labels(X_TICKS)
        .y_labels(Y_TICKS)
        .x_label_formatter(&x_format)
        .y_label_formatter(&y_format)
        .bold_line_style(BLACK.mix(0.15))
        .light_line_style(BLACK.mix(0.05));
    if text {
        mesh.x_desc(labels.x)
            .y_desc(labels.y)
            .label_style((FontFamily::SansSerif, 16))
            .axis_desc_style((FontFamily::SansSerif, 18));
    }
    // Without label areas plotters draws no tick labels or axis titles, so no font is needed.
    mesh.draw()?;
    // Frame around the plot area (the axes in text mode, the only border otherwise).
    chart.plotting_area().draw(&Rectangle::new(
        [(x_range.0, y_range.0), (x_range.1, y_range.1)],
        BLACK.stroke_width(1),
    ))?;

    for (i, (s, line)) in series.iter().zip(&lines).enumerate() {
        let c = colour(i);
        let drawn = if line.len() == 1 {
            chart.draw_series(line.iter().map(|&p| Circle::new(p, 4, c.filled())))?
        } else {
            chart.draw_series(LineSeries::new(line.iter().copied(), c.stroke_width(2)))?
        };
        if text {
            drawn.label(s.name.as_str()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(3))
            });
        }
    }

    if text {
        if !series.is_empty() {
            chart
                .configure_series_labels()
                .position(legend_corner(&lines, x_range, y_range))
                .margin(10)
                .legend_area_size(30)
                .label_font((FontFamily::SansSerif, 16))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.4))
                .draw()?;
        }
        if !has_data {
            let centre = ((x_range.0 + x_range.1) / 2.0, (y_range.0 + y_range.1) / 2.0);
            let style = TextStyle::from((FontFamily::SansSerif, 22))
                .color(&RGBColor(0x66, 0x66, 0x66))
                .pos(Pos::new(HPos::Center, VPos::Center));
            chart
                .plotting_area()
                .draw(&Text::new("no data", centre, style))?;
        }
    }

    root.present()?;
    Ok(())
}

/// Encodes `rgb` as PNG into a temporary file next to `path`, then renames it onto `path`.
fn write_png_atomic(path: &Path, rgb: &[u8]) -> Result<(), PlotError> {
    let io = |source| PlotError::Io {
        path: path.to_path_buf(),
        source,
    };
    base::write_atomically_with(path, |w| {
        image::codecs::png::PngEncoder::new(w).write_image(
            rgb,
            WIDTH,
            HEIGHT,
            ExtendedColorType::Rgb8,
        )
    })
    .map_err(|e| match e {
        base::WriteError::Io(e) => io(e),
        base::WriteError::Body(source) => PlotError::Encode {
            path: path.to_path_buf(),
            source,
        },
    })
}

/// Height of the label band [`label_panels`] puts above a strip of pictures, in pixels.
pub const LABEL_BAND: u32 = 20;

/// `strip` (panels `panel_width` wide, `gap` apart, left to right) with a dark band above it
/// holding each panel's label at its left edge, cut at the panel's width: a comparison that
/// says what each picture is, and how close.
pub fn label_panels(
    strip: &image::RgbImage,
    panel_width: u32,
    gap: u32,
    labels: &[String],
) -> image::RgbImage {
    let (w, h) = strip.dimensions();
    let mut out = image::RgbImage::from_pixel(w, h + LABEL_BAND, image::Rgb([32, 32, 32]));
    image::imageops::replace(&mut out, strip, 0, LABEL_BAND as i64);
    let Ok(font) = ab_glyph::FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT) else {
        return out;
    };
    for (i, label) in labels.iter().enumerate() {
        let x0 = i as u32 * (panel_width + gap);
        if x0 >= w {
            break;
        }
        let right = (x0 + panel_width).min(w);
        draw_text(&mut out, &font, label, x0 + 4, right, LABEL_BAND);
    }
    out
}

/// Widest a PSF figure is drawn; a finer grid is shrunk to it (the full-resolution paper
/// grid would be thousands of pixels wide).
pub const PSF_FIGURE_WIDTH: u32 = 1500;

/// The PSF grid as people look at it: [`aberration::picture::psf_grid_picture`] shrunk to at
/// most [`PSF_FIGURE_WIDTH`], each channel's mosaic named (with its wavelength when known),
/// the field angle across a mosaic when known, and a colour bar of the log scale.
pub fn psf_figure(
    grid: &aberration::PsfGrid,
    wavelengths_nm: Option<[f64; 3]>,
    max_field_deg: Option<f64>,
) -> image::RgbImage {
    use aberration::picture::{CHANNEL_GAP, DECADES, psf_grid_picture, viridis};
    let raw = psf_grid_picture(grid);
    let scale = (PSF_FIGURE_WIDTH as f64 / raw.width() as f64).min(1.0);
    let img = if scale < 1.0 {
        let (w, h) = (
            (raw.width() as f64 * scale).round() as u32,
            (raw.height() as f64 * scale).round().max(1.0) as u32,
        );
        image::imageops::resize(&raw, w, h, image::imageops::FilterType::Triangle)
    } else {
        raw
    };
    let gap = (CHANNEL_GAP as f64 * scale).round() as u32;
    let panel = (img.width() - 2 * gap) / 3;
    let names = ["red", "green", "blue"];
    let labels: Vec<String> = (0..3)
        .map(|c| match wavelengths_nm {
            Some(l) => format!("{} {:.0} nm", names[c], l[c]),
            None => names[c].to_string(),
        })
        .collect();
    let labelled = label_panels(&img, panel, gap, &labels);
    // Below: the colour bar, and the field the mosaics span.
    let (w, h) = labelled.dimensions();
    let mut out = image::RgbImage::from_pixel(w.max(420), h + LABEL_BAND, image::Rgb([32, 32, 32]));
    image::imageops::replace(&mut out, &labelled, 0, 0);
    let mut bottom = image::RgbImage::from_pixel(out.width(), LABEL_BAND, image::Rgb([32, 32, 32]));
    let bar = (4u32, 120u32);
    for x in bar.0..bar.0 + bar.1 {
        let t = (x - bar.0) as f32 / (bar.1 - 1) as f32;
        for y in 4..LABEL_BAND - 4 {
            bottom.put_pixel(x, y, image::Rgb(viridis(t)));
        }
    }
    if let Ok(font) = ab_glyph::FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT) {
        let mut text = format!("1e-{DECADES:.0} to 1 of each channel's peak");
        if let Some(f) = max_field_deg {
            text += &format!("; each mosaic spans the field from -{f:.0} to +{f:.0} deg");
        }
        let right = bottom.width();
        draw_text(
            &mut bottom,
            &font,
            &text,
            bar.0 + bar.1 + 8,
            right,
            LABEL_BAND,
        );
    }
    image::imageops::replace(&mut out, &bottom, 0, h as i64);
    out
}

/// `text` on one line at `px` pixels per em, each glyph at its own side bearing and kerning:
/// the coverage (0 to 1) of a box as wide as the advances and as tall as the font's ascent to
/// descent, the baseline `ascent` rows from its top.
struct Coverage {
    width: u32,
    height: u32,
    ascent: f32,
    data: Vec<f32>,
}

fn lay_out(font: &ab_glyph::FontRef, text: &str, px: f32) -> Coverage {
    use ab_glyph::{Font, ScaleFont};
    let scaled = font.as_scaled(px);
    let ascent = scaled.ascent();
    let mut caret = 0.0f32;
    let mut previous = None;
    let mut glyphs = Vec::new();
    for c in text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = previous {
            caret += scaled.kern(p, id);
        }
        previous = Some(id);
        glyphs.push(id.with_scale_and_position(scaled.scale(), ab_glyph::point(caret, ascent)));
        caret += scaled.h_advance(id);
    }
    let (width, height) = (
        caret.ceil().max(0.0) as u32,
        (ascent - scaled.descent()).ceil().max(0.0) as u32,
    );
    let mut data = vec![0.0f32; width as usize * height as usize];
    for glyph in glyphs {
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let bounds = outline.px_bounds();
        outline.draw(|gx, gy, coverage| {
            let (x, y) = (
                bounds.min.x as i64 + gx as i64,
                bounds.min.y as i64 + gy as i64,
            );
            if (0..width as i64).contains(&x) && (0..height as i64).contains(&y) {
                let at = &mut data[y as usize * width as usize + x as usize];
                *at = (*at + coverage.clamp(0.0, 1.0)).min(1.0);
            }
        });
    }
    Coverage {
        width,
        height,
        ascent,
        data,
    }
}

/// Draws `text` in white from `x` to at most `right` (cut there), centred in a band of
/// `band` rows at the top of `img`.
fn draw_text(
    img: &mut image::RgbImage,
    font: &ab_glyph::FontRef,
    text: &str,
    x: u32,
    right: u32,
    band: u32,
) {
    use ab_glyph::{Font, ScaleFont};
    let px = band as f32 * 0.8;
    let scaled = font.as_scaled(px);
    let baseline = (band as f32 + scaled.ascent() + scaled.descent()) / 2.0;
    let c = lay_out(font, text, px);
    let top = (baseline - c.ascent).round() as i64;
    for gy in 0..c.height as i64 {
        for gx in 0..c.width as i64 {
            let (px, py) = (x as i64 + gx, top + gy);
            let coverage = c.data[(gy * c.width as i64 + gx) as usize];
            if coverage <= 0.0 || px >= right as i64 || py < 0 || py >= band as i64 {
                continue;
            }
            let p = img.get_pixel_mut(px as u32, py as u32);
            for v in &mut p.0 {
                *v = (*v as f32 + (255.0 - *v as f32) * coverage).round() as u8;
            }
        }
    }
}

/// A plotters backend whose text is laid out by [`lay_out`] (plotters' own `ab_glyph` text
/// drops each glyph's side bearing, so its letters crowd and gape); everything else is the
/// wrapped backend's.
struct GlyphText<'f, B> {
    inner: B,
    font: &'f ab_glyph::FontRef<'f>,
}

impl<B: DrawingBackend> DrawingBackend for GlyphText<'_, B> {
    type ErrorType = B::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }

    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.ensure_prepared()
    }

    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.present()
    }

    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_pixel(point, color)
    }

    fn draw_line<S: plotters_backend::BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_line(from, to, style)
    }

    fn draw_rect<S: plotters_backend::BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_path(path, style)
    }

    fn draw_circle<S: plotters_backend::BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: plotters_backend::BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.fill_polygon(vert, style)
    }

    fn blit_bitmap(
        &mut self,
        pos: BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.blit_bitmap(pos, size, src)
    }

    fn estimate_text_size<S: BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let c = lay_out(self.font, text, style.size() as f32);
        Ok((c.width, c.height))
    }

    fn draw_text<S: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let colour = style.color();
        if colour.alpha == 0.0 {
            return Ok(());
        }
        let c = lay_out(self.font, text, style.size() as f32);
        let (w, h) = (c.width as i32, c.height as i32);
        // Anchored and turned as plotters' own text is.
        let dx = match style.anchor().h_pos {
            HPos::Left => 0,
            HPos::Right => -w,
            HPos::Center => -w / 2,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0,
            VPos::Center => -h / 2,
            VPos::Bottom => -h,
        };
        let turn = style.transform();
        let (sw, sh) = self.get_size();
        for gy in 0..h {
            for gx in 0..w {
                let coverage = c.data[(gy * w + gx) as usize];
                if coverage <= 0.0 {
                    continue;
                }
                let (x, y) = turn.transform(gx + dx, gy + dy);
                let (x, y) = (pos.0 + x, pos.1 + y);
                if (0..sw as i32).contains(&x) && (0..sh as i32).contains(&y) {
                    let alpha = colour.alpha * coverage as f64;
                    self.inner.draw_pixel(
                        (x, y),
                        BackendColor {
                            alpha,
                            rgb: colour.rgb,
                        },
                    )?;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(name: &str, points: &[(f64, f64)]) -> Series {
        Series {
            name: name.to_string(),
            points: points.to_vec(),
        }
    }

    fn labels() -> Labels<'static> {
        Labels {
            title: "PSNR during training",
            x: "time (s)",
            y: "PSNR (dB)",
        }
    }

    fn rgb_at(rgb: &[u8], x: u32, y: u32) -> [u8; 3] {
        let i = (y as usize * WIDTH as usize + x as usize) * 3;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    }

    /// Pixels exactly of colour `c` as (x, y).
    fn pixels_of(rgb: &[u8], c: RGBColor) -> Vec<(u32, u32)> {
        (0..HEIGHT)
            .flat_map(|y| (0..WIDTH).map(move |x| (x, y)))
            .filter(|&(x, y)| rgb_at(rgb, x, y) == [c.0, c.1, c.2])
            .collect()
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn writes_png_of_the_right_size_and_no_leftovers() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("psnr.png");
        let s = [
            series("plain", &[(0.0, 20.0), (10.0, 25.0), (20.0, 27.0)]),
            series("aware", &[(0.0, 21.0), (10.0, 28.0), (20.0, 31.0)]),
        ];
        line_plot(&path, "PSNR", "time (s)", "PSNR (dB)", &s).unwrap();
        let img = image::open(&path).unwrap();
        assert_eq!((img.width(), img.height()), (WIDTH, HEIGHT));
        assert_eq!(dir_entries(tmp.path()), ["psnr.png"]);
        // Overwriting an existing plot works too.
        line_plot(&path, "PSNR", "time (s)", "PSNR (dB)", &s[..1]).unwrap();
        assert_eq!(dir_entries(tmp.path()), ["psnr.png"]);
    }

    /// The embedded font registers on any machine, and text is drawn with it: the same plot
    /// with text has far more dark (text-coloured) pixels than without.
    #[test]
    fn the_embedded_font_draws_the_text() {
        assert!(font_available(), "the embedded font did not register");
        let s = [series("a line", &[(0.0, 1.0), (1.0, 2.0)])];
        let dark = |rgb: &[u8]| {
            rgb.chunks_exact(3)
                .filter(|p| p.iter().all(|&v| v < 80))
                .count()
        };
        let with = dark(&render(&s, &labels(), true).unwrap());
        let without = dark(&render(&s, &labels(), false).unwrap());
        assert!(
            with > without + 500,
            "{with} dark pixels with text, {without} without"
        );
    }

    #[test]
    fn series_colours_appear_in_the_written_plot() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("p.png");
        let s = [
            series("rising", &[(0.0, 0.0), (1.0, 1.0)]),
            series("falling", &[(0.0, 1.0), (1.0, 0.0)]),
        ];
        line_plot(&path, "t", "x", "y", &s).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        for c in [colour(0), colour(1)] {
            let n = img.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count();
            // A diagonal across the plot, 2 px wide, is far more than a 24 px legend swatch.
            assert!(n > 500, "only {n} pixels of {c:?}");
        }
    }

    #[test]
    fn lines_are_drawn_inside_the_frame_where_the_data_is() {
        // Text-free rendering has a fixed 20 px margin, so the data area is known exactly.
        let s = [series("flat", &[(0.0, 5.0), (10.0, 5.0)])];
        let rgb = render(&s, &labels(), false).unwrap();
        let px = pixels_of(&rgb, colour(0));
        assert!(px.len() > 700, "only {} line pixels", px.len());
        let mid = HEIGHT as f64 / 2.0;
        for &(x, y) in &px {
            assert!((20..WIDTH - 20).contains(&x), "pixel at x = {x}");
            assert!((y as f64 - mid).abs() < 4.0, "pixel at y = {y}");
        }
    }

    #[test]
    fn distinct_colours_per_series() {
        let all: Vec<RGBColor> = (0..30).map(colour).collect();
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                assert_ne!(a, b);
            }
        }
    }

    #[test]
    fn single_point_draws_a_marker_at_the_centre() {
        let s = [series("one", &[(3.0, 7.0)])];
        let rgb = render(&s, &labels(), false).unwrap();
        let px = pixels_of(&rgb, colour(0));
        assert!(px.len() >= 20, "only {} marker pixels", px.len());
        for &(x, y) in &px {
            assert!((x as i64 - WIDTH as i64 / 2).abs() <= 6, "pixel at x = {x}");
            assert!(
                (y as i64 - HEIGHT as i64 / 2).abs() <= 6,
                "pixel at y = {y}"
            );
        }
    }

    #[test]
    fn non_finite_points_are_skipped() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("nan.png");
        let s = [
            series(
                "gappy",
                &[
                    (0.0, 1.0),
                    (1.0, f64::NAN),
                    (f64::INFINITY, 2.0),
                    (2.0, f64::NEG_INFINITY),
                    (3.0, 3.0),
                ],
            ),
            series("all bad", &[(f64::NAN, f64::NAN), (1.0, f64::INFINITY)]),
        ];
        line_plot(&path, "t", "x", "y", &s).unwrap();
        assert_eq!(image::open(&path).unwrap().width(), WIDTH);
        // The ranges come from the finite points only.
        let lines: Vec<_> = s.iter().map(finite_points).collect();
        assert_eq!(lines[0], [(0.0, 1.0), (3.0, 3.0)]);
        assert!(lines[1].is_empty());
        let rgb = render(&s, &labels(), false).unwrap();
        assert!(pixels_of(&rgb, colour(0)).len() > 500);
    }

    #[test]
    fn empty_inputs_still_write_a_plot() {
        let tmp = tempfile::tempdir().unwrap();
        let cases: [&[Series]; 3] = [
            &[],
            &[series("empty", &[])],
            &[series("a", &[]), series("", &[(f64::NAN, 0.0)])],
        ];
        for (i, s) in cases.into_iter().enumerate() {
            let path = tmp.path().join(format!("empty{i}.png"));
            line_plot(&path, "", "", "", s).unwrap();
            let img = image::open(&path).unwrap();
            assert_eq!((img.width(), img.height()), (WIDTH, HEIGHT));
            render(s, &labels(), false).unwrap();
        }
    }

    #[test]
    fn extreme_values_do_not_fail() {
        let tmp = tempfile::tempdir().unwrap();
        let cases = [
            vec![(0.0, f64::MAX), (1.0, -f64::MAX)],
            vec![(0.0, 1e-300), (1e-300, 2e-300)],
            vec![(5.0, 5.0), (5.0, 5.0)],
            vec![(-1e12, 0.0), (1e12, 1e-12)],
            vec![(f64::MAX, f64::MAX)],
            vec![(0.0, 1.0), (1.0, 1.0 + 1e-15)],
            vec![(1e9, 1e9), (1e9 + 1e-6, 1e9 + 1e-6)],
            vec![(f64::MIN_POSITIVE, -1e300), (1e300, 1e300)],
        ];
        for (i, points) in cases.into_iter().enumerate() {
            let path = tmp.path().join(format!("x{i}.png"));
            let s = [series("s", &points)];
            line_plot(&path, "t", "x", "y", &s).unwrap();
            render(&s, &labels(), false).unwrap();
        }
    }

    #[test]
    fn axis_range_has_a_margin() {
        let (lo, hi) = axis_range([0.0, 10.0].into_iter());
        assert!(
            lo < 0.0 && lo > -1.0 && hi > 10.0 && hi < 11.0,
            "{lo}..{hi}"
        );
        let (lo, hi) = axis_range([30.0].into_iter());
        assert!(lo < 30.0 && hi > 30.0, "{lo}..{hi}");
        let (lo, hi) = axis_range(std::iter::empty());
        assert!(lo < 0.0 && hi > 1.0, "{lo}..{hi}");
        let (lo, hi) = axis_range([-f64::MAX, f64::MAX].into_iter());
        assert!(lo.is_finite() && hi.is_finite());
    }

    #[test]
    fn tick_labels_fit_the_spacing() {
        let psnr = (17.0, 32.0);
        assert_eq!(tick_label(20.0, psnr, 8), "20");
        assert_eq!(tick_label(0.5, (0.0, 4.0), 8), "0.5");
        assert_eq!(tick_label(0.05, (0.0, 0.3), 8), "0.05");
        assert_eq!(tick_label(-1e-17, (-0.3, 0.3), 8), "0.00");
        assert_eq!(tick_label(-0.0, (-30.0, 30.0), 8), "0");
        assert_eq!(tick_label(-0.0, (-3.0, 3.0), 8), "0.0");
        assert_eq!(tick_label(2.5e9, (0.0, 1e10), 10), "2.5e9");
        assert_eq!(tick_label(3e-7, (0.0, 1e-6), 10), "3.0e-7");
        assert_eq!(tick_label(0.0, (0.0, 1e-6), 10), "0");
    }

    #[test]
    fn legend_goes_where_the_lines_are_not() {
        let x = (0.0, 1.0);
        let y = (0.0, 1.0);
        // Rising line from lower left to upper right: the upper left corner is free first.
        let rising = vec![vec![(0.0, 0.0), (1.0, 1.0)]];
        let pos = legend_corner(&rising, x, y);
        assert!(matches!(pos, SeriesLabelPosition::UpperLeft), "{pos:?}");
        // Saturating curve high on the right: lower right is free.
        let saturating = vec![vec![(0.0, 0.0), (0.1, 0.9), (1.0, 1.0)]];
        let pos = legend_corner(&saturating, x, y);
        assert!(matches!(pos, SeriesLabelPosition::LowerRight), "{pos:?}");
    }

    #[test]
    fn missing_folder_is_an_error_naming_the_path() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("missing").join("plot.png");
        let err = line_plot(&path, "t", "x", "y", &[series("s", &[(0.0, 1.0)])]).unwrap_err();
        assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
        assert!(dir_entries(tmp.path()).is_empty());
    }

    #[test]
    fn failed_rename_is_an_error_naming_the_path_and_leaves_no_temp_file() {
        // The target is an existing folder: the temporary PNG is written, the rename fails.
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("plot.png");
        std::fs::create_dir(&path).unwrap();
        let err = line_plot(&path, "t", "x", "y", &[series("s", &[(0.0, 1.0)])]).unwrap_err();
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
        assert_eq!(dir_entries(tmp.path()), ["plot.png"]);
        assert!(dir_entries(&path).is_empty());
    }

    #[test]
    fn no_font_rendering_draws_lines_and_frame_only() {
        let s = [series("a", &[(0.0, 0.0), (1.0, 2.0)])];
        let rgb = render(&s, &labels(), false).unwrap();
        // A frame: the pixel 20 px in from the top left corner is dark.
        let [r, g, b] = rgb_at(&rgb, 20, 20);
        assert!(r < 80 && g < 80 && b < 80, "frame pixel {r},{g},{b}");
        // Outside the frame there is nothing but white (no title or tick labels).
        for y in 0..15 {
            for x in 0..WIDTH {
                assert_eq!(rgb_at(&rgb, x, y), [255, 255, 255], "at {x},{y}");
            }
        }
    }

    #[test]
    #[ignore = "writes /tmp/plot_example.png for a look"]
    fn example_plot() {
        let plain: Vec<(f64, f64)> = (0..=60)
            .map(|i| {
                let t = i as f64 * 5.0;
                (t, 18.0 + 8.0 * (1.0 - (-t / 60.0).exp()))
            })
            .collect();
        let aware: Vec<(f64, f64)> = (0..=60)
            .map(|i| {
                let t = i as f64 * 5.0;
                (t, 18.5 + 12.5 * (1.0 - (-t / 80.0).exp()))
            })
            .collect();
        line_plot(
            Path::new("/tmp/plot_example.png"),
            "Test-view PSNR during training",
            "time (s)",
            "PSNR (dB)",
            &[series("plain", &plain), series("aware", &aware)],
        )
        .unwrap();
    }

    #[test]
    fn labels_sit_above_their_panels_and_stay_inside_them() {
        let (pw, gap, h) = (40u32, 6u32, 10u32);
        let strip = image::RgbImage::from_pixel(2 * pw + gap, h, image::Rgb([10, 200, 30]));
        let labels = vec![
            "a label far longer than its panel".to_string(),
            "b".to_string(),
        ];
        let out = label_panels(&strip, pw, gap, &labels);
        assert_eq!(out.dimensions(), (2 * pw + gap, h + LABEL_BAND));
        for y in 0..h {
            for x in 0..strip.width() {
                assert_eq!(out.get_pixel(x, y + LABEL_BAND), strip.get_pixel(x, y));
            }
        }
        let bright = |x0: u32, x1: u32| {
            (x0..x1)
                .flat_map(|x| (0..LABEL_BAND).map(move |y| (x, y)))
                .filter(|&(x, y)| out.get_pixel(x, y).0[0] > 128)
                .count()
        };
        assert!(bright(0, pw) > 20, "no text over the first panel");
        assert!(
            bright(pw + gap, 2 * pw + gap) > 3,
            "no text over the second panel"
        );
        // The long label is cut at its panel: the gutter's band is empty.
        assert_eq!(bright(pw, pw + gap), 0);
    }

    #[test]
    fn a_psf_figure_stays_a_reasonable_size_and_carries_its_scale() {
        use aberration::picture::{psf_grid_picture, viridis};
        let big = aberration::PsfGrid::delta(9, 135);
        let raw = psf_grid_picture(&big);
        assert!(raw.width() > 2 * PSF_FIGURE_WIDTH);
        let fig = psf_figure(&big, Some([606.0, 511.0, 462.0]), Some(20.0));
        assert_eq!(fig.width(), PSF_FIGURE_WIDTH);
        let body = (raw.height() as f64 * PSF_FIGURE_WIDTH as f64 / raw.width() as f64).round();
        assert_eq!(fig.height(), body as u32 + 2 * LABEL_BAND);
        // The colour bar runs from the scale's bottom to its top.
        let y = fig.height() - LABEL_BAND / 2;
        assert_eq!(fig.get_pixel(4, y).0, viridis(0.0));
        assert_eq!(fig.get_pixel(123, y).0, viridis(1.0));
        // A small grid is drawn at its own size.
        let small = aberration::PsfGrid::delta(3, 5);
        let fig = psf_figure(&small, None, None);
        assert_eq!(
            fig.height(),
            psf_grid_picture(&small).height() + 2 * LABEL_BAND
        );
    }
}
