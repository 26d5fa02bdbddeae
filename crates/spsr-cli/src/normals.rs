//! `spsr normals` and the normal estimation that `spsr reconstruct` runs on clouds without
//! normals: the flags shared by both ([`NormalOptions`]), the choice of orientation, and the
//! comparison with reference normals.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};

use crate::{exit, usage, Failure};

/// How the signs of estimated normals are chosen, as spelled on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OrientArg {
    /// Propagation along a minimum spanning tree of the neighbour graph, each connected piece
    /// turned outward.
    Mst,
    /// Towards --viewpoint, or towards each scan's sensor position recorded in the file (E57
    /// scan poses, PCD VIEWPOINT, spsr's PLY scan_origin comments).
    Viewpoint,
    /// mst, then corrected by the indicator function of Poisson reconstructions (right on thin
    /// parts and nearby sheets; slower).
    Global,
}

/// Flags of normal estimation and orientation, shared by `spsr normals` and `spsr reconstruct`.
#[derive(Debug, Clone, Args)]
pub struct NormalOptions {
    /// How to orient the estimated normals [default: viewpoint when --viewpoint is given or
    /// the file records scan positions, else mst]
    #[arg(long, value_enum, value_name = "MODE")]
    pub orient: Option<OrientArg>,

    /// Sensor position for --orient viewpoint: every normal points towards it [default: the
    /// scan positions recorded in the file, if any]
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_parser = parse_point,
        allow_hyphen_values = true
    )]
    pub viewpoint: Option<[f64; 3]>,

    /// Neighbours in each point's plane fit, at least 3 [default: chosen from the noise: 16 on
    /// clean clouds, 24 to 192 on noisy ones]
    #[arg(long, value_name = "K", value_parser = parse_neighbours)]
    pub neighbours: Option<usize>,
}

/// Parses `x,y,z` into three finite numbers.
fn parse_point(s: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "'{s}' is not a point: give three comma-separated numbers such as 0,0.1,1"
        ));
    }
    let mut p = [0.0; 3];
    for (v, t) in p.iter_mut().zip(&parts) {
        *v = t
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("'{t}' in '{s}' is not a finite number"))?;
    }
    Ok(p)
}

fn parse_neighbours(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number"))?;
    if n < 3 {
        return Err("must be at least 3 (a plane needs three points)".into());
    }
    Ok(n)
}

/// What [`estimate_normals`] did, for the verbose report.
pub struct NormalReport {
    /// The orientation used, in words.
    pub orientation: String,
    estimated: spsr::normals::Estimated,
    oriented: spsr::normals::OrientStats,
    estimating: Duration,
    orienting: Duration,
}

/// The file's scan positions as [`spsr::normals::Orientation::ScanOrigins`] wants them: empty
/// scans (an E57 file may hold some) left out, and the first scan starting at point 0 (points
/// before the first recorded scan, if any, are counted with it).
fn scan_ranges(scans: &[spsr::ScanOrigin], points: usize) -> Vec<(usize, [f64; 3])> {
    let mut ranges: Vec<(usize, [f64; 3])> = Vec::with_capacity(scans.len());
    for (i, s) in scans.iter().enumerate() {
        let end = scans.get(i + 1).map_or(points, |next| next.first_point);
        if s.first_point < end {
            ranges.push((s.first_point, s.origin));
        }
    }
    match ranges.first_mut() {
        Some(first) => first.0 = 0,
        None => ranges.push((0, scans[0].origin)),
    }
    ranges
}

impl NormalOptions {
    /// The orientation these options ask for on `cloud`, or a usage error.
    fn orientation(
        &self,
        cloud: &spsr::PointCloud,
    ) -> Result<(spsr::normals::Orientation, String), Failure> {
        use spsr::normals::Orientation;
        let scans = &cloud.scan_origins;
        let mode = self
            .orient
            .unwrap_or(if self.viewpoint.is_some() || !scans.is_empty() {
                OrientArg::Viewpoint
            } else {
                OrientArg::Mst
            });
        if self.viewpoint.is_some() && mode != OrientArg::Viewpoint {
            return Err(usage(
                "--viewpoint is only used by --orient viewpoint; leave out one of them".into(),
            ));
        }
        Ok(match mode {
            OrientArg::Mst => (Orientation::mst(), "mst".into()),
            OrientArg::Global => (Orientation::global(), "global".into()),
            OrientArg::Viewpoint => match self.viewpoint {
                Some(v) => (
                    Orientation::Viewpoint(v),
                    format!("viewpoint {},{},{}", v[0], v[1], v[2]),
                ),
                None if !scans.is_empty() => (
                    Orientation::ScanOrigins(scan_ranges(scans, cloud.len())),
                    format!("viewpoint: {} scan position(s) from the file", scans.len()),
                ),
                None => {
                    return Err(usage(
                        "--orient viewpoint needs --viewpoint X,Y,Z: the file records no scan \
                         positions"
                            .into(),
                    ))
                }
            },
        })
    }

    /// Whether any of these options was given.
    pub fn any_given(&self) -> bool {
        self.orient.is_some() || self.viewpoint.is_some() || self.neighbours.is_some()
    }
}

/// Estimates and orients the normals of `cloud` in place (replacing any it has).
pub fn estimate_normals(
    cloud: &mut spsr::PointCloud,
    opts: &NormalOptions,
    input: &Path,
) -> Result<NormalReport, Failure> {
    let fail = |e: spsr::Error| Failure::from_spsr(e, input);
    let (how, orientation) = opts.orientation(cloud)?;
    let params = spsr::normals::NormalParams {
        neighbours: opts.neighbours,
        ..Default::default()
    };
    let t = Instant::now();
    let estimated = spsr::normals::estimate(&cloud.positions, &params).map_err(fail)?;
    let estimating = t.elapsed();
    let mut normals = estimated.normals.clone();
    let t = Instant::now();
    let oriented = spsr::normals::orient(&cloud.positions, &mut normals, &how).map_err(fail)?;
    let orienting = t.elapsed();
    cloud.normals = normals;
    Ok(NormalReport {
        orientation,
        estimated,
        oriented,
        estimating,
        orienting,
    })
}

impl NormalReport {
    /// Neighbours used in each plane fit.
    pub fn neighbours(&self) -> usize {
        self.estimated.neighbours
    }

    /// Prints what estimation and orientation did, and their times, to stderr.
    pub fn print(&self) {
        let e = &self.estimated;
        let o = &self.oriented;
        let mut err = std::io::stderr().lock();
        let _ = writeln!(
            err,
            "normals     {} neighbours per fit ({} cloud), {} degenerate neighbourhoods, {} \
             non-finite points",
            e.neighbours,
            if e.noisy { "noisy" } else { "clean" },
            e.degenerate,
            e.non_finite
        );
        let _ = writeln!(
            err,
            "orientation {}: {} connected pieces, {} normals not oriented, global corrections \
             per round {:?}",
            self.orientation, o.components, o.skipped, o.corrections
        );
        let _ = writeln!(
            err,
            "  {:<32} {:>9.3} s",
            "estimating normals",
            self.estimating.as_secs_f64()
        );
        let _ = writeln!(
            err,
            "  {:<32} {:>9.3} s",
            "orienting normals",
            self.orienting.as_secs_f64()
        );
    }
}

pub(crate) const NORMALS_LONG_ABOUT: &str = "\
Estimate and orient normals for a point cloud: a plane fitted to each point's nearest neighbours \
gives the normal's line, and --orient chooses its sign. Normals the file already has are replaced.

Input: a point cloud, with or without normals, in any format `spsr reconstruct` reads (PLY, \
LAS/LAZ, E57, PCD, text). Output: binary PLY (ASCII with --ascii), whatever the extension, with the \
same points in the same order, `nx ny nz` set, and every other property of the input kept. Points \
with a non-finite coordinate keep their place and get the normal 0 0 0. The output file appears \
only once it is complete, and must not be the input file.

--compare REFERENCE prints how the estimated normals agree with the normals of another file \
holding the same points in the same order: the percentage pointing to the same side, and the mean \
angle between the normal lines.";

/// Arguments of `spsr normals`.
#[derive(Debug, Args)]
pub struct NormalsArgs {
    /// Point cloud: PLY, LAS/LAZ, E57, PCD, or text with `x y z` per line.
    #[arg(value_name = "INPUT")]
    pub input: PathBuf,

    /// Output cloud (PLY); may be left out with --compare.
    #[arg(
        short,
        long,
        value_name = "OUTPUT",
        required_unless_present = "compare"
    )]
    pub output: Option<PathBuf>,

    #[command(flatten)]
    pub normals: NormalOptions,

    /// Compare the estimated normals with this file's normals (same points in the same order)
    /// and print the agreement [default: no comparison]
    #[arg(long, value_name = "REFERENCE")]
    pub compare: Option<PathBuf>,

    #[command(flatten)]
    pub common: crate::args::CommonArgs,
}

/// Runs `spsr normals`.
pub fn run_normals(args: &NormalsArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.input.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input);
    crate::start_threads(args.common.threads.threads)?;
    if let Some(output) = &args.output {
        spsr::io::check_output_path(output, input).map_err(fail)?;
    }
    if let Some(reference) = &args.compare {
        // A missing reference is found before the work, not after it.
        if !reference.is_file() {
            return Err(Failure {
                code: exit::DATA,
                error: anyhow::anyhow!("{}: no such file", reference.display()),
            });
        }
    }

    let t = Instant::now();
    let mut cloud = spsr::io::read_cloud(input).map_err(fail)?;
    let reading = t.elapsed();
    let report = estimate_normals(&mut cloud, &args.normals, input)?;

    let mut writing = Duration::ZERO;
    if let Some(output) = &args.output {
        let t = Instant::now();
        let opts = spsr::io::WriteOptions {
            ascii: args.common.ascii,
        };
        spsr::io::write_cloud(output, &cloud, &opts).map_err(fail)?;
        writing = t.elapsed();
    }
    if args.common.verbose {
        let mut err = std::io::stderr().lock();
        let _ = writeln!(err, "input       {}", input.display());
        let _ = writeln!(err, "points      {}", cloud.len());
        drop(err);
        report.print();
        let mut err = std::io::stderr().lock();
        let _ = writeln!(err, "  {:<32} {:>9.3} s", "reading", reading.as_secs_f64());
        let _ = writeln!(err, "  {:<32} {:>9.3} s", "writing", writing.as_secs_f64());
        let _ = writeln!(
            err,
            "  {:<32} {:>9.3} s",
            "total",
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(output) = &args.output {
        println!(
            "spsr: wrote {}: {} points with normals ({} neighbours, orient {}) in {:.2} s",
            output.display(),
            cloud.len(),
            report.neighbours(),
            report.orientation,
            start.elapsed().as_secs_f64()
        );
    }
    if let Some(reference) = &args.compare {
        let rfail = |e: spsr::Error| Failure::from_spsr(e, reference);
        let refcloud = spsr::io::read_points(reference).map_err(rfail)?;
        if refcloud.len() != cloud.len() {
            return Err(Failure {
                code: exit::DATA,
                error: anyhow::anyhow!(
                    "{}: {} points, but {} has {}: --compare needs the same points in the same \
                     order",
                    reference.display(),
                    refcloud.len(),
                    input.display(),
                    cloud.len()
                ),
            });
        }
        let c = spsr::normals::compare(&cloud.normals, &refcloud.normals).map_err(rfail)?;
        println!(
            "spsr: compared with {}: {:.3} % oriented like the reference, mean angle {:.2}° \
             (median {:.2}°, 95th percentile {:.2}°) over {} points, {} skipped",
            reference.display(),
            100.0 * (1.0 - c.flipped_fraction),
            c.mean_angle_deg,
            c.median_angle_deg,
            c.p95_angle_deg,
            c.compared,
            c.skipped
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(first_point: usize, x: f64) -> spsr::ScanOrigin {
        spsr::ScanOrigin {
            first_point,
            origin: [x, 0.0, 0.0],
        }
    }

    #[test]
    fn empty_scans_are_left_out_and_the_first_starts_at_zero() {
        let scans = [
            scan(2, 1.0),
            scan(5, 2.0),
            scan(5, 3.0),
            scan(9, 4.0),
            scan(9, 5.0),
        ];
        assert_eq!(
            scan_ranges(&scans, 9),
            vec![(0, [1.0, 0.0, 0.0]), (5, [3.0, 0.0, 0.0])]
        );
        assert_eq!(scan_ranges(&[scan(0, 7.0)], 0), vec![(0, [7.0, 0.0, 0.0])]);
    }
}
