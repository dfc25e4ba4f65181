//! PNG figures for evaluation: the paper's Fig. 1 style 2D trajectories coloured by
//! mode ([`draw_trajectories`]) and line charts of metrics over training
//! ([`draw_curves`]).
//!
//! Rendering uses `plotters` with the bitmap backend. Text is drawn with DejaVu Sans,
//! built into the binary (the `dejavu` crate, ~740 KB), so a figure has its titles,
//! ticks and legend on any machine, fonts installed or not, and looks the same
//! everywhere; a TrueType file named by the `ESS_FONT` environment variable replaces it.
//! The drawing code keeps a no-text mode (labels and legends left out), which the tests
//! use to check that nothing in it depends on a font.
//!
//! Files are written atomically: the image is rendered to a temporary file in the
//! destination directory and renamed into place, so readers never see half a PNG.

use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use thiserror::Error;

/// Errors from drawing a figure; every variant names the destination file.
#[derive(Debug, Error)]
pub enum PlotError {
    /// The figure has nothing to lay out (no panels, or zero-sized panels).
    #[error("cannot draw {path}: {reason}")]
    InvalidFigure {
        /// Destination file.
        path: PathBuf,
        /// What is wrong with the request.
        reason: String,
    },
    /// The destination has no file name to write to.
    #[error("cannot draw {path}: the path has no file name")]
    NoFileName {
        /// Destination file.
        path: PathBuf,
    },
    /// `plotters` failed while rendering or encoding the image.
    #[error("failed to render {path}: {message}")]
    Render {
        /// Destination file.
        path: PathBuf,
        /// The backend's error message.
        message: String,
    },
    /// Moving the finished temporary file into place failed.
    #[error("failed to move the rendered plot {tmp} into {path}")]
    Persist {
        /// Destination file.
        path: PathBuf,
        /// The temporary file that was rendered.
        tmp: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
}

/// One panel of a trajectory figure.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrajPanel {
    /// Title drawn above the panel (e.g. the method name).
    pub title: String,
    /// Each path: its points `(x, y)` and a colour index into the palette (usually
    /// the latent code or ground-truth mode). Non-finite points are skipped.
    pub paths: Vec<(Vec<(f32, f32)>, usize)>,
}

/// Mode colours: the paper's red, green, blue, purple, then further distinct hues.
pub const PALETTE: [RGBColor; 12] = [
    RGBColor(214, 39, 40),   // red
    RGBColor(44, 160, 44),   // green
    RGBColor(31, 119, 180),  // blue
    RGBColor(148, 103, 189), // purple
    RGBColor(255, 127, 14),  // orange
    RGBColor(23, 190, 207),  // cyan
    RGBColor(140, 86, 75),   // brown
    RGBColor(227, 119, 194), // pink
    RGBColor(188, 189, 34),  // olive
    RGBColor(127, 127, 127), // grey
    RGBColor(0, 0, 128),     // navy
    RGBColor(0, 128, 128),   // teal
];

/// Size of a [`draw_curves`] image in pixels.
pub const CURVES_SIZE: (u32, u32) = (900, 560);

/// Font family name under which the loaded font is registered.
const FONT_FAMILY: &str = "sans-serif";
/// A family that is never registered: text styles in no-font mode point here, so any
/// accidental text drawing fails loudly in tests instead of silently using a font.
const NO_FONT_FAMILY: &str = "ess-plot-no-font";
/// Smallest panel side that leaves room for a plotting area.
const MIN_PANEL_PX: u32 = 32;

/// Which font family text is drawn with, or `None` to draw no text at all.
type Text = Option<&'static str>;

/// The palette colour of index `idx`.
pub fn palette_color(idx: usize) -> RGBColor {
    PALETTE[idx % PALETTE.len()]
}

/// Draws `panels` side by side in one row, each `panel_px` x `panel_px` pixels
/// (title included), into the PNG at `path`.
///
/// All panels share one axis range, computed from every finite point with a 5%
/// margin and widened so that one unit is the same number of pixels on both axes
/// (circles look round). Each path is a line in [`palette_color`]`(idx)`; panels have
/// a title above them and no legend.
pub fn draw_trajectories(
    path: &Path,
    panels: &[TrajPanel],
    panel_px: u32,
) -> Result<(), PlotError> {
    draw_trajectories_with(path, panels, panel_px, font_family())
}

/// Draws a line chart of the named `series` (e.g. NMI over iterations) into the PNG
/// at `path` ([`CURVES_SIZE`] pixels), with `title`, `x_label` and a legend.
///
/// The axes span all finite points (5% margin on y); series are coloured by their
/// position with [`palette_color`]. An empty `series` draws empty axes.
pub fn draw_curves(
    path: &Path,
    title: &str,
    x_label: &str,
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), PlotError> {
    draw_curves_with(path, title, x_label, series, font_family())
}

/// Registers the font once per process: `ESS_FONT`'s file if it is one, else the
/// built-in DejaVu Sans.
fn font_family() -> Text {
    static LOADED: OnceLock<bool> = OnceLock::new();
    LOADED.get_or_init(register_font).then_some(FONT_FAMILY)
}

fn register_font() -> bool {
    let from_env = std::env::var_os("ESS_FONT").and_then(|p| {
        let bytes = std::fs::read(&p).ok();
        if bytes.is_none() {
            tracing::warn!(
                "ESS_FONT {}: not readable; using DejaVu Sans",
                Path::new(&p).display()
            );
        }
        bytes
    });
    if let Some(bytes) = from_env {
        // plotters keeps `&'static` font bytes; this runs at most once per process.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        if plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, bytes).is_ok() {
            return true;
        }
        tracing::warn!("ESS_FONT: not a TrueType font; using DejaVu Sans");
    }
    plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, dejavu::sans::regular()).is_ok()
}

fn render_err(path: &Path) -> impl Fn(&dyn Display) -> PlotError + '_ {
    move |e| PlotError::Render {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Renders via `draw` into a temporary PNG next to `path`, then renames it into place
/// ([`ess_envs::AtomicFile`]).
fn write_atomically<F>(path: &Path, size: (u32, u32), draw: F) -> Result<(), PlotError>
where
    F: FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), PlotError>,
{
    if path.file_name().is_none() {
        return Err(PlotError::NoFileName {
            path: path.to_path_buf(),
        });
    }
    let file = ess_envs::AtomicFile::new(path);
    {
        let root = BitMapBackend::new(file.tmp(), size).into_drawing_area();
        draw(&root)?;
        root.present().map_err(|e| render_err(path)(&e))?;
    }
    let tmp = file.tmp().to_path_buf();
    file.commit().map_err(|(_, source)| PlotError::Persist {
        path: path.to_path_buf(),
        tmp,
        source,
    })
}

/// Axis-aligned bounds of finite points.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Bounds {
    x: (f64, f64),
    y: (f64, f64),
}

fn bounds<I: IntoIterator<Item = (f64, f64)>>(points: I) -> Option<Bounds> {
    points
        .into_iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .fold(None, |acc, (x, y)| {
            Some(match acc {
                None => Bounds {
                    x: (x, x),
                    y: (y, y),
                },
                Some(b) => Bounds {
                    x: (b.x.0.min(x), b.x.1.max(x)),
                    y: (b.y.0.min(y), b.y.1.max(y)),
                },
            })
        })
}

/// Ranges covering `b` with a 5% margin on each side, widened on one axis so that a
/// unit spans the same number of pixels on both axes of a `px_w` x `px_h` area.
fn equal_aspect_ranges(b: Option<Bounds>, px_w: u32, px_h: u32) -> (Range2, Range2) {
    let b = b.unwrap_or(Bounds {
        x: (-1.0, 1.0),
        y: (-1.0, 1.0),
    });
    let (cx, cy) = ((b.x.0 + b.x.1) / 2.0, (b.y.0 + b.y.1) / 2.0);
    let mut hx = (b.x.1 - b.x.0) / 2.0 * 1.1;
    let mut hy = (b.y.1 - b.y.0) / 2.0 * 1.1;
    if !(hx > 0.0 || hy > 0.0) {
        hx = 1.0;
        hy = 1.0;
    }
    let (w, h) = (f64::from(px_w.max(1)), f64::from(px_h.max(1)));
    let per_px = (hx / w).max(hy / h);
    hx = per_px * w;
    hy = per_px * h;
    ((cx - hx, cx + hx), (cy - hy, cy + hy))
}

type Range2 = (f64, f64);

/// Tick text: integers without a fractional part, others with at most 3 decimals.
fn tick_label(v: &f64) -> String {
    if (v - v.round()).abs() < 1e-9 {
        // `+ 0.0` turns -0 into 0.
        format!("{}", v.round() + 0.0)
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// Layout sizes derived from the panel size.
struct PanelLayout {
    title_h: u32,
    title_font: u32,
    label_area: u32,
    label_font: u32,
    margin: u32,
    stroke: u32,
}

impl PanelLayout {
    fn new(panel_px: u32, text: Text) -> Self {
        let title_font = (panel_px / 18).clamp(10, 40);
        let label_font = (panel_px / 30).clamp(8, 24);
        let has_text = text.is_some();
        Self {
            title_h: if has_text { title_font * 8 / 5 } else { 0 },
            title_font,
            label_area: if has_text { label_font * 3 } else { 0 },
            label_font,
            margin: (panel_px / 40).max(4),
            stroke: (panel_px / 200).max(1),
        }
    }
}

fn draw_trajectories_with(
    path: &Path,
    panels: &[TrajPanel],
    panel_px: u32,
    text: Text,
) -> Result<(), PlotError> {
    let invalid = |reason: String| PlotError::InvalidFigure {
        path: path.to_path_buf(),
        reason,
    };
    if panels.is_empty() {
        return Err(invalid("no panels to draw".into()));
    }
    if panel_px < MIN_PANEL_PX {
        return Err(invalid(format!(
            "panel size {panel_px}px is below the minimum of {MIN_PANEL_PX}px"
        )));
    }
    let width = u32::try_from(panels.len())
        .ok()
        .and_then(|n| n.checked_mul(panel_px))
        .ok_or_else(|| {
            invalid(format!(
                "{} panels of {panel_px}px are too wide",
                panels.len()
            ))
        })?;
    let layout = PanelLayout::new(panel_px, text);
    let all_points = panels
        .iter()
        .flat_map(|p| p.paths.iter())
        .flat_map(|(pts, _)| pts.iter())
        .map(|&(x, y)| (f64::from(x), f64::from(y)));
    let data_bounds = bounds(all_points);

    write_atomically(path, (width, panel_px), |root| {
        let err = render_err(path);
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let areas = root.split_evenly((1, panels.len()));
        // All panels have the same pixel size, so the plotting area of the first
        // fixes the shared equal-aspect ranges.
        let (plot_w, plot_h) = {
            let (w, h) = areas.first().map_or((0, 0), |a| a.dim_in_pixel());
            let side_used = 2 * layout.margin + layout.label_area;
            (
                w.saturating_sub(side_used),
                h.saturating_sub(side_used + layout.title_h),
            )
        };
        let (xr, yr) = equal_aspect_ranges(data_bounds, plot_w, plot_h);
        for (area, panel) in areas.iter().zip(panels) {
            draw_panel(area, panel, &layout, xr, yr, text).map_err(|e| err(&e))?;
        }
        Ok(())
    })
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &TrajPanel,
    layout: &PanelLayout,
    xr: Range2,
    yr: Range2,
    text: Text,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (title_area, body) = area.split_vertically(layout.title_h);
    if let Some(family) = text {
        let (w, h) = title_area.dim_in_pixel();
        let style = TextStyle::from((family, layout.title_font).into_font())
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Center));
        let centre = (
            i32::try_from(w / 2).unwrap_or(0),
            i32::try_from(h / 2).unwrap_or(0),
        );
        title_area.draw_text(&panel.title, &style, centre)?;
    }
    let family = text.unwrap_or(NO_FONT_FAMILY);
    let mut chart = ChartBuilder::on(&body)
        .margin(layout.margin)
        .x_label_area_size(layout.label_area)
        .y_label_area_size(layout.label_area)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    let n_labels = if text.is_some() { 5 } else { 0 };
    chart
        .configure_mesh()
        .x_labels(n_labels)
        .y_labels(n_labels)
        .max_light_lines(4)
        .x_label_formatter(&tick_label)
        .y_label_formatter(&tick_label)
        .label_style((family, layout.label_font))
        .axis_desc_style((family, layout.label_font))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(205, 205, 205))
        .draw()?;
    for (points, idx) in &panel.paths {
        let style = palette_color(*idx).stroke_width(layout.stroke);
        // A non-finite point breaks the line rather than joining its neighbours.
        for run in points.split(|(x, y)| !(x.is_finite() && y.is_finite())) {
            if run.is_empty() {
                continue;
            }
            let pts = run.iter().map(|&(x, y)| (f64::from(x), f64::from(y)));
            chart.draw_series(LineSeries::new(pts, style))?;
        }
    }
    // Frame the plotting area so panels read as separate boxes.
    let frame = Rectangle::new([(xr.0, yr.0), (xr.1, yr.1)], BLACK.stroke_width(1));
    chart.plotting_area().draw(&frame)?;
    Ok(())
}

fn draw_curves_with(
    path: &Path,
    title: &str,
    x_label: &str,
    series: &[(String, Vec<(f64, f64)>)],
    text: Text,
) -> Result<(), PlotError> {
    let data = bounds(series.iter().flat_map(|(_, pts)| pts.iter().copied()));
    let (xr, yr) = match data {
        None => ((0.0, 1.0), (0.0, 1.0)),
        Some(b) => {
            let widen = |(lo, hi): Range2, frac: f64| -> Range2 {
                let span = hi - lo;
                if span > 0.0 {
                    (lo - span * frac, hi + span * frac)
                } else {
                    (lo - 0.5, hi + 0.5)
                }
            };
            (widen(b.x, 0.0), widen(b.y, 0.05))
        }
    };
    let family = text.unwrap_or(NO_FONT_FAMILY);
    write_atomically(path, CURVES_SIZE, |root| {
        let err = render_err(path);
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let mut builder = ChartBuilder::on(root);
        builder.margin(16);
        if let Some(family) = text {
            builder
                .caption(title, (family, 26))
                .x_label_area_size(48)
                .y_label_area_size(64);
        }
        let mut chart = builder
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
            .map_err(|e| err(&e))?;
        let n_labels = if text.is_some() { 8 } else { 0 };
        let mut mesh = chart.configure_mesh();
        mesh.x_labels(n_labels)
            .y_labels(n_labels)
            .x_label_formatter(&tick_label)
            .y_label_formatter(&tick_label)
            .label_style((family, 15))
            .axis_desc_style((family, 17))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(205, 205, 205));
        if text.is_some() {
            mesh.x_desc(x_label);
        }
        mesh.draw().map_err(|e| err(&e))?;
        for (i, (name, pts)) in series.iter().enumerate() {
            let color = palette_color(i);
            let style = color.stroke_width(2);
            let mut drawn = false;
            for run in pts.split(|(x, y)| !(x.is_finite() && y.is_finite())) {
                if run.is_empty() {
                    continue;
                }
                let anno = chart
                    .draw_series(LineSeries::new(run.iter().copied(), style))
                    .map_err(|e| err(&e))?;
                // Register each series in the legend once.
                if !drawn && text.is_some() {
                    anno.label(name.as_str()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
                }
                drawn = true;
            }
        }
        if let Some(family) = text
            && !series.is_empty()
        {
            chart
                .configure_series_labels()
                .label_font((family, 15))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .position(SeriesLabelPosition::MiddleRight)
                .draw()
                .map_err(|e| err(&e))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const PNG_MAGIC: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

    /// Width and height from the IHDR chunk, after checking the PNG signature.
    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = std::fs::read(path).expect("png readable");
        assert!(bytes.len() > 24, "file too short");
        assert_eq!(bytes[..8], PNG_MAGIC, "not a PNG");
        assert_eq!(&bytes[12..16], b"IHDR");
        let w = u32::from_be_bytes(bytes[16..20].try_into().expect("4 bytes"));
        let h = u32::from_be_bytes(bytes[20..24].try_into().expect("4 bytes"));
        (w, h)
    }

    fn circle(cx: f32, cy: f32, r: f32) -> Vec<(f32, f32)> {
        (0..=120)
            .map(|i| {
                let t = i as f32 / 120.0 * std::f32::consts::TAU;
                (cx + r * t.cos(), cy + r * t.sin())
            })
            .collect()
    }

    /// Two panels of four circles each, like the paper's 2D-trajectory modes.
    fn four_circle_panels() -> Vec<TrajPanel> {
        let circles = |r: f32| {
            vec![
                (circle(0.0, r, r), 0),
                (circle(0.0, -r, r), 1),
                (circle(r, 0.0, r), 2),
                (circle(-r, 0.0, r), 3),
            ]
        };
        vec![
            TrajPanel {
                title: "Expert".into(),
                paths: circles(10.0),
            },
            TrajPanel {
                title: "Ess-InfoGAIL".into(),
                paths: circles(8.0),
            },
        ]
    }

    fn curve_series() -> Vec<(String, Vec<(f64, f64)>)> {
        let nmi = (0..50)
            .map(|i| {
                (
                    f64::from(i) * 100.0,
                    1.0 - (-f64::from(i) / 12.0).exp() * 0.9,
                )
            })
            .collect();
        let ent = (0..50)
            .map(|i| (f64::from(i) * 100.0, 1.2 * (-f64::from(i) / 15.0).exp()))
            .collect();
        vec![("NMI".to_string(), nmi), ("ENT".to_string(), ent)]
    }

    fn keep_for_inspection(src: &Path, name: &str) {
        if let Some(dir) = std::env::var_os("ESS_PLOT_KEEP") {
            let _ = std::fs::copy(src, PathBuf::from(dir).join(name));
        }
    }

    #[test]
    fn two_panels_of_circles_make_a_png_of_the_expected_size() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("traj.png");
        draw_trajectories(&out, &four_circle_panels(), 400).expect("drawn");
        assert_eq!(png_size(&out), (800, 400));
        keep_for_inspection(&out, "traj.png");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path())
            .expect("readable")
            .flatten()
            .filter(|e| e.file_name() != "traj.png")
            .collect();
        assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    }

    #[test]
    fn trajectories_without_a_font_are_still_drawn() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("traj-no-font.png");
        draw_trajectories_with(&out, &four_circle_panels(), 300, None).expect("drawn");
        assert_eq!(png_size(&out), (600, 300));
        keep_for_inspection(&out, "traj-no-font.png");
    }

    #[test]
    fn curves_make_a_png_of_the_documented_size() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("curves.png");
        draw_curves(&out, "Disentanglement", "iteration", &curve_series()).expect("drawn");
        assert_eq!(png_size(&out), CURVES_SIZE);
        keep_for_inspection(&out, "curves.png");
    }

    #[test]
    fn text_is_drawn_with_the_built_in_font_whatever_the_machine_has() {
        // ESS_FONT is unset in tests: the font comes from the binary, not the system.
        assert_eq!(font_family(), Some(FONT_FAMILY));
        let (w, h) = (200u32, 60u32);
        let mut buf = vec![255u8; (w * h * 3) as usize];
        {
            let area = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
            let style = TextStyle::from((FONT_FAMILY, 30).into_font()).color(&BLACK);
            area.draw_text("NMI 0.93", &style, (5, 10)).expect("drawn");
            area.present().expect("presented");
        }
        let inked = buf.chunks(3).filter(|px| px[0] < 128).count();
        assert!(
            inked > 200,
            "only {inked} dark pixels: no glyphs were drawn"
        );
    }

    #[test]
    fn curves_without_a_font_are_still_drawn() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("curves-no-font.png");
        draw_curves_with(&out, "t", "x", &curve_series(), None).expect("drawn");
        assert_eq!(png_size(&out), CURVES_SIZE);
    }

    #[test]
    fn empty_or_degenerate_data_still_draws() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("empty.png");
        draw_curves(&out, "nothing", "x", &[]).expect("drawn");
        assert_eq!(png_size(&out), CURVES_SIZE);
        let panels = vec![TrajPanel {
            title: "one point".into(),
            paths: vec![(vec![(1.0, 1.0), (f32::NAN, 0.0)], 5), (vec![], 1)],
        }];
        draw_trajectories(&out, &panels, 100).expect("drawn");
        assert_eq!(png_size(&out), (100, 100));
    }

    #[test]
    fn drawing_over_an_existing_file_replaces_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("again.png");
        std::fs::write(&out, b"old").expect("writable");
        draw_trajectories(&out, &four_circle_panels(), 200).expect("drawn");
        assert_eq!(png_size(&out), (400, 200));
    }

    #[test]
    fn no_panels_or_tiny_panels_are_rejected_with_the_path() {
        let out = Path::new("/nonexistent/figure.png");
        let err = draw_trajectories(out, &[], 400).expect_err("no panels");
        assert!(matches!(&err, PlotError::InvalidFigure { path, .. } if path == out));
        let err = draw_trajectories(out, &four_circle_panels(), 8).expect_err("tiny");
        assert!(err.to_string().contains("/nonexistent/figure.png"), "{err}");
    }

    #[test]
    fn an_unwritable_directory_is_an_error_not_a_panic() {
        let out = Path::new("/nonexistent-ess-dir/figure.png");
        let err = draw_curves(out, "t", "x", &curve_series()).expect_err("unwritable");
        assert!(
            matches!(&err, PlotError::Render { path, .. } if path == out),
            "{err}"
        );
    }

    #[test]
    fn equal_aspect_ranges_give_both_axes_the_same_scale() {
        let b = Some(Bounds {
            x: (0.0, 10.0),
            y: (0.0, 2.0),
        });
        let ((x0, x1), (y0, y1)) = equal_aspect_ranges(b, 300, 200);
        assert!(((x1 - x0) / 300.0 - (y1 - y0) / 200.0).abs() < 1e-12);
        // The wider axis keeps exactly its 5% margins, centred on the data.
        assert!((x0 + 0.5).abs() < 1e-12 && (x1 - 10.5).abs() < 1e-12);
        assert!(((y0 + y1) / 2.0 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn tick_labels_drop_needless_decimals() {
        assert_eq!(tick_label(&20.0), "20");
        assert_eq!(tick_label(&-10.0), "-10");
        assert_eq!(tick_label(&0.30000000000000004), "0.3");
        assert_eq!(tick_label(&0.125), "0.125");
        assert_eq!(tick_label(&-0.0), "0");
    }

    #[test]
    fn palette_wraps_around_after_twelve_colours() {
        assert_eq!(palette_color(0), RGBColor(214, 39, 40));
        assert_eq!(palette_color(12), palette_color(0));
        assert_ne!(palette_color(1), palette_color(2));
    }
}
