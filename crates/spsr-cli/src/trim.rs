//! `spsr trim`: cut a mesh with a density along an iso-line of the density.

use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;

use crate::args::CommonArgs;
use crate::files::input_name;
use crate::files::{check_output_arg, read_mesh_arg, report_written, write_mesh_arg};
use crate::Failure;

pub(crate) const TRIM_LONG_ABOUT: &str = "\
Remove the surface a reconstruction invented where there were no samples. Screened Poisson \
reconstruction closes every opening of the scanned surface (the floor under a statue, the open \
side of a room); the per-vertex density written by `spsr reconstruct --density` (the estimated \
sampling depth: one unit more means 4 times more samples per area) is low there.

The mesh is cut along the line where the density equals V (new vertices on the crossing edges, \
with every per-vertex value interpolated), and the part below V is removed. Then kept pieces \
smaller than --min-island-area of the total area are removed, and removed regions inside kept \
surface smaller than --hole-area are restored, as PoissonRecon's SurfaceTrimmer does.

--trim auto sets V = median - max(1, 4 x MAD) of the area-weighted vertex densities (MAD: the \
median absolute deviation): it removes surface with fewer than a quarter of the typical samples \
per area (further below for unevenly sampled scans), which keeps everything that was sampled, \
including the rims of real openings. A gap in a scan of a surface that continues looks like an \
opening; auto removes the fill of a large gap too. To keep it, give a lower V (-v prints the \
median density; e.g. median - 3.5 keeps the fill of a gap a fifth of the object's size).

Input: a mesh with per-vertex density, as written by `spsr reconstruct --density` in PLY (vertex \
property `density`) or GLB (attribute `_DENSITY`); OBJ, STL and OFF files cannot hold it. Output, by \
extension: .ply (binary, ASCII with --ascii), .obj, .stl, .off or .glb; only .ply and .glb keep the \
density. The output must not be the input; it appears only once complete.";

/// Arguments of `spsr trim`.
#[derive(Debug, Args)]
pub struct TrimArgs {
    /// Mesh with per-vertex density (from `spsr reconstruct --density`), PLY or GLB; `-` reads
    /// standard input.
    #[arg(value_name = "MESH")]
    pub mesh: PathBuf,

    /// Output mesh, by extension: .ply, .obj, .stl, .off or .glb; `-` writes PLY to standard
    /// output.
    #[arg(short, long, value_name = "OUTPUT")]
    pub output: PathBuf,

    /// Density below which the surface is removed, or `auto` to derive it from the mesh's
    /// density distribution. Required: no default, as in PoissonRecon 18's SurfaceTrimmer.
    #[arg(long, value_name = "V|auto", value_parser = parse_trim, allow_negative_numbers = true)]
    pub trim: spsr::trim::Threshold,

    /// Kept pieces smaller than this fraction of the total area are removed. Default as
    /// PoissonRecon 18's SurfaceTrimmer (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = spsr::trim::TrimParams::default().min_island_area,
        allow_negative_numbers = true
    )]
    pub min_island_area: f64,

    /// Removed regions inside kept surface smaller than this fraction of the total area are
    /// restored (small holes closed again). Default as PoissonRecon 18's SurfaceTrimmer
    /// (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = spsr::trim::TrimParams::default().hole_area,
        allow_negative_numbers = true
    )]
    pub hole_area: f64,

    #[command(flatten)]
    pub common: CommonArgs,
}

/// Runs `spsr trim`: reads the mesh, trims it, writes the result.
pub fn run_trim(args: &TrimArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.mesh.as_path();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));
    let params = spsr::trim::TrimParams {
        threshold: args.trim,
        min_island_area: args.min_island_area,
        hole_area: args.hole_area,
    };
    params.validate().map_err(fail)?;
    check_output_arg(output, input).map_err(fail)?;
    let mesh = read_mesh_arg(input).map_err(fail)?;
    if mesh.density.is_none() {
        return Err(no_density(input_name(input)));
    }
    let t = Instant::now();
    let (trimmed, stats) = spsr::trim::trim(&mesh, &params).map_err(fail)?;
    let time = t.elapsed();
    drop(mesh);
    let opts = spsr::io::WriteOptions {
        ascii: args.common.ascii,
    };
    write_mesh_arg(output, &trimmed, &opts).map_err(fail)?;
    if args.common.verbose {
        print_trim(&stats, time);
    }
    report_written(output, &trimmed, start);
    Ok(())
}

/// The mesh read has no density values to trim by: say where they come from.
fn no_density(input: &std::path::Path) -> Failure {
    Failure {
        code: crate::exit::DATA,
        error: anyhow::anyhow!(
            "{}: the mesh has no per-vertex density values to trim by; only PLY and GLB files \
             hold them: reconstruct with `spsr reconstruct --density -o mesh.ply` (or .glb) and \
             trim that mesh",
            input.display()
        ),
    }
}

pub(crate) fn print_trim(stats: &spsr::trim::TrimStats, time: Duration) {
    let mut err = std::io::stderr().lock();
    match &stats.auto {
        Some(a) => {
            let _ = writeln!(
                err,
                "trim        V = {} (auto: area-weighted median density {:.4}, MAD {:.4}; \
                 {:.3} % of the area below V)",
                stats.threshold,
                a.median,
                a.mad,
                100.0 * a.area_below
            );
        }
        None => {
            let _ = writeln!(err, "trim        V = {}", stats.threshold);
        }
    }
    let _ = writeln!(
        err,
        "            kept {:.3} % of the area ({:.6e} of {:.6e}); {} triangles of {}, \
         {} cut vertices, {} islands removed, {} holes restored; {:.3} s",
        100.0 * stats.kept_area / stats.total_area,
        stats.kept_area,
        stats.total_area,
        stats.triangles_out,
        stats.triangles_in,
        stats.cut_vertices,
        stats.islands_removed,
        stats.holes_filled,
        time.as_secs_f64()
    );
}

/// Parses `--trim`: `auto` (any case) or a finite density value.
pub(crate) fn parse_trim(s: &str) -> Result<spsr::trim::Threshold, String> {
    let t = s.trim();
    if t.eq_ignore_ascii_case("auto") {
        return Ok(spsr::trim::Threshold::Auto);
    }
    match t.parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(spsr::trim::Threshold::Value(v)),
        _ => Err(format!(
            "'{t}' is neither a density value (a finite number such as 6.5) nor 'auto'"
        )),
    }
}
