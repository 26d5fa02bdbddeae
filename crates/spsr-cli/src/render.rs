//! `spsr render`: a shaded picture of a mesh, as PNG; and the preview of
//! `spsr reconstruct --preview`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use spsr::render::{ColorBy, Highlight, RenderOptions, View};

use crate::args::ThreadsArg;
use crate::files::{input_name, read_mesh_arg};
use crate::{start_threads, usage, Failure};

pub(crate) const RENDER_LONG_ABOUT: &str = "\
Draw a shaded picture of a mesh and write it as PNG, on the CPU (no display or GPU needed).

The camera is orthographic and fitted to the mesh in each view, assuming y is up: front looks \
along -z, side along -x (from the +x side), top along -y (down, the front at the bottom of the \
picture), iso along -(1,1,1) (from the +x +y +z corner); all puts front, side, top and iso in a \
2 x 2 grid. Faces are shaded flat with a light at the camera. Faces seen from behind are \
terracotta, so flipped or inside-out surface shows. By default the mesh's own vertex colours \
are used when it has them, else a light grey-blue.

--color density or --color attribute:NAME colours the surface by that per-vertex value through \
the viridis colour map (dark purple for low, yellow for high) between its 2nd and 98th \
percentiles (-v prints them). --highlight pieces paints every connected piece except the \
largest in magenta: loose fragments and floating islands stand out.

Input: a mesh in PLY, OBJ, STL, OFF or GLB (by its first bytes, else its extension); `-` reads \
standard input. Output: a .png file, which appears only once complete.";

/// Arguments of `spsr render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Mesh to draw: PLY, OBJ, STL, OFF or GLB; `-` reads standard input.
    #[arg(value_name = "MESH")]
    pub mesh: PathBuf,

    /// The picture, a .png file.
    #[arg(short, long, value_name = "PNG")]
    pub output: PathBuf,

    /// The side the mesh is seen from: front, side, top, iso, or all four in a 2 x 2 grid.
    #[arg(long, value_name = "VIEW", default_value = "iso", value_parser = parse_view)]
    pub view: View,

    /// Picture size in pixels, WIDTH x HEIGHT (or one number for a square), each from 1 to
    /// 16384.
    #[arg(
        long,
        value_name = "WxH",
        default_value = "800x800",
        value_parser = parse_size,
        allow_negative_numbers = true
    )]
    pub size: (u32, u32),

    /// What colours the surface: auto (the mesh's vertex colours when it has them), plain,
    /// density, or attribute:NAME (a per-vertex property, e.g. attribute:quality).
    #[arg(long, value_name = "WHAT", default_value = "auto", value_parser = parse_color)]
    pub color: ColorBy,

    /// What stands out in magenta: pieces (every connected piece except the largest)
    /// [default: nothing]
    #[arg(long, value_name = "WHAT", value_parser = parse_highlight)]
    pub highlight: Option<Highlight>,

    #[command(flatten)]
    pub threads: ThreadsArg,

    /// Print to stderr the mesh's size, the range of the colour map, the number of pieces
    /// and the time each step took [default: off]
    #[arg(short, long)]
    pub verbose: bool,
}

impl RenderArgs {
    /// The library's options these arguments describe (not yet validated).
    pub fn options(&self) -> RenderOptions {
        RenderOptions {
            view: self.view,
            width: self.size.0,
            height: self.size.1,
            color: self.color.clone(),
            highlight: self.highlight.unwrap_or_default(),
            ..Default::default()
        }
    }
}

/// A library parse error as clap's message: what is expected.
fn expected(e: spsr::Error) -> String {
    match e {
        spsr::Error::InvalidParameter { expected, .. } => format!("expected {expected}"),
        e => e.to_string(),
    }
}

fn parse_view(s: &str) -> Result<View, String> {
    s.parse().map_err(expected)
}

fn parse_color(s: &str) -> Result<ColorBy, String> {
    s.parse().map_err(expected)
}

fn parse_highlight(s: &str) -> Result<Highlight, String> {
    s.parse().map_err(expected)
}

/// Parses `--size`: `WxH` (`x` or `X`) or one number for a square; the range is the
/// library's to check.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let t = s.trim();
    let number = |v: &str| v.trim().parse::<u32>().ok();
    let size = match t.split_once(['x', 'X']) {
        Some((w, h)) => number(w).zip(number(h)),
        None => number(t).map(|n| (n, n)),
    };
    size.ok_or_else(|| format!("'{t}' is not a size such as 800x600 or 512"))
}

/// Refuses a picture name that does not end in `.png` (any case).
fn check_png_name(path: &Path) -> Result<(), Failure> {
    let png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if png {
        Ok(())
    } else {
        Err(usage(format!(
            "{}: pictures are written as PNG; give the output a .png name",
            path.display()
        )))
    }
}

/// The checks of a picture's output path made before anything is read: a .png name that
/// can be written and is not the input.
pub(crate) fn check_picture_path(path: &Path, input: &Path) -> Result<(), Failure> {
    check_png_name(path)?;
    spsr::io::check_output_path(path, input).map_err(|e| Failure::from_spsr(e, input_name(input)))
}

/// `spsr reconstruct --preview`: the default picture of the reconstructed mesh.
pub(crate) fn write_preview(mesh: &spsr::Mesh, path: &Path, input: &Path) -> Result<(), Failure> {
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));
    let image = spsr::render::render(mesh, &RenderOptions::default()).map_err(fail)?;
    image.write_png(path).map_err(fail)
}

/// Runs `spsr render`: reads the mesh, draws it, writes the PNG.
pub fn run_render(args: &RenderArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.mesh.as_path();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));
    let opts = args.options();
    opts.validate().map_err(fail)?;
    check_picture_path(output, input)?;
    start_threads(args.threads.threads)?;

    let t = Instant::now();
    let mesh = read_mesh_arg(input).map_err(fail)?;
    let reading = t.elapsed();
    let t = Instant::now();
    let image = spsr::render::render(&mesh, &opts).map_err(fail)?;
    let drawing = t.elapsed();
    let t = Instant::now();
    image.write_png(output).map_err(fail)?;
    let writing = t.elapsed();
    if args.verbose {
        let mut err = std::io::stderr().lock();
        let _ = writeln!(
            err,
            "mesh        {} vertices, {} faces ({:.3} s to read)",
            mesh.vertices.len(),
            mesh.triangles.len(),
            reading.as_secs_f64()
        );
        if let Some([lo, hi]) = image.value_range {
            let _ = writeln!(err, "colours     {lo} (purple) to {hi} (yellow)");
        }
        if let Some(n) = image.pieces {
            let _ = writeln!(err, "pieces      {n} ({} highlighted)", n.saturating_sub(1));
        }
        let _ = writeln!(
            err,
            "picture     {}x{} drawn in {:.3} s, written in {:.3} s",
            image.width,
            image.height,
            drawing.as_secs_f64(),
            writing.as_secs_f64()
        );
    }
    println!(
        "spsr: wrote {}: {}x{} picture of {} faces in {:.2} s",
        output.display(),
        image.width,
        image.height,
        mesh.triangles.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
