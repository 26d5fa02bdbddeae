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
    #[arg(long, value_name = "K", value_parser = parse_neighbours, allow_negative_numbers = true)]
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
LAS/LAZ, E57, PCD, text), or the vertices of a mesh file (OBJ, OFF, STL, GLB). Output, by \
extension: .ply (binary, ASCII with --ascii; every other property of the input kept) or .xyz/.txt \
(text: x y z nx ny nz, then r g b when the input has colours), with the same points in the same \
order and `nx ny nz` set. Points with a non-finite coordinate keep their place and get the normal \
0 0 0. The output file appears only once it is complete, and must not be the input file.

--compare REFERENCE prints how the estimated normals agree with the normals of another file \
holding the same points in the same order: the percentage pointing to the same side, and the mean \
angle between the normal lines. The reference is checked first: a different number of points, or \
a point farther than a millionth of the cloud's size from its counterpart, is refused.";

/// Arguments of `spsr normals`.
#[derive(Debug, Args)]
pub struct NormalsArgs {
    /// Point cloud: PLY, LAS/LAZ, E57, PCD, text with `x y z` per line, or a mesh's vertices
    /// (OBJ, OFF, STL, GLB).
    #[arg(value_name = "INPUT")]
    pub input: PathBuf,

    /// Output cloud, by extension: .ply, or .xyz/.txt (text); may be left out with --compare.
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
        crate::files::check_cloud_output_arg(output, input).map_err(fail)?;
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
    // The reference is read and checked before the work, so a wrong one costs nothing.
    let refcloud = match &args.compare {
        Some(reference) => Some(read_reference(reference, input, &cloud)?),
        None => None,
    };
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
    if let (Some(reference), Some(refcloud)) = (&args.compare, refcloud) {
        let rfail = |e: spsr::Error| Failure::from_spsr(e, reference);
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

/// Reads the `--compare` reference (with normals) and checks that it holds `cloud`'s points
/// in the same order.
fn read_reference(
    reference: &Path,
    input: &Path,
    cloud: &spsr::PointCloud,
) -> Result<spsr::PointCloud, Failure> {
    let refcloud = spsr::io::read_cloud(reference).map_err(|e| Failure::from_spsr(e, reference))?;
    if !refcloud.has_normals() {
        return Err(Failure {
            code: exit::DATA,
            error: anyhow::anyhow!(
                "{}: the reference has no normals (nx, ny, nz) to compare with",
                reference.display()
            ),
        });
    }
    let differ = |why: String| Failure {
        code: exit::DATA,
        error: anyhow::anyhow!(
            "{}: {why}: --compare needs the same points in the same order",
            reference.display()
        ),
    };
    if refcloud.len() != cloud.len() {
        return Err(differ(format!(
            "{} points, but {} has {}",
            refcloud.len(),
            input.display(),
            cloud.len()
        )));
    }
    if let Some(m) = PointMismatch::find(&cloud.positions, &refcloud.positions) {
        return Err(differ(format!(
            "its points differ from those of {}: {} of {} are farther than {:.3e} (a millionth \
             of the cloud's size) from their counterparts, the farthest (point {}, 0-based) by \
             {:.3e}",
            input.display(),
            m.differing,
            cloud.len(),
            m.tolerance,
            m.farthest,
            m.distance
        )));
    }
    Ok(refcloud)
}

/// How two clouds that should hold the same points differ.
#[derive(Debug, PartialEq)]
struct PointMismatch {
    /// Pairs farther apart than the tolerance (a pair with one non-finite point counts; a
    /// pair of two, which both readers keep in place and the pipeline drops, does not).
    differing: usize,
    /// The pair farthest apart, and its distance (infinite for a finite point against a
    /// non-finite one).
    farthest: usize,
    distance: f64,
    /// A millionth of the size of `points`: of its bounding-box diagonal, or of its largest
    /// coordinate when that is larger (so a reference saved in single precision, which
    /// rounds far-off coordinates by more than a millionth of the diagonal, still matches).
    tolerance: f64,
}

impl PointMismatch {
    /// The mismatch between `points` and `reference` (same length), if any pair differs.
    fn find(points: &[[f64; 3]], reference: &[[f64; 3]]) -> Option<Self> {
        let finite = |p: &[f64; 3]| p.iter().all(|c| c.is_finite());
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut largest = 0.0f64;
        for p in points.iter().filter(|p| finite(p)) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
                largest = largest.max(p[k].abs());
            }
        }
        let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
        let tolerance = 1e-6
            * if diagonal.is_finite() {
                diagonal.max(largest)
            } else {
                0.0
            };
        let mut m = PointMismatch {
            differing: 0,
            farthest: 0,
            distance: 0.0,
            tolerance,
        };
        for (i, (p, q)) in points.iter().zip(reference).enumerate() {
            let d = match (finite(p), finite(q)) {
                (false, false) => continue,
                (true, true) => (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt(),
                _ => f64::INFINITY,
            };
            if d > tolerance {
                m.differing += 1;
                if m.differing == 1 || d > m.distance {
                    (m.farthest, m.distance) = (i, d);
                }
            }
        }
        (m.differing > 0).then_some(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_differ_beyond_a_millionth_of_the_size() {
        let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [f64::NAN, 0.0, 0.0]];
        let mut b = a;
        assert_eq!(PointMismatch::find(&a, &b), None, "NaN pairs are skipped");
        b[1][1] = 0.9e-6;
        assert_eq!(PointMismatch::find(&a, &b), None);
        b[1][1] = 2e-6;
        let m = PointMismatch::find(&a, &b).unwrap();
        assert_eq!((m.differing, m.farthest), (1, 1));
        assert!((m.distance - 2e-6).abs() < 1e-12 && (m.tolerance - 1e-6).abs() < 1e-12);
        b[0] = [f64::NAN; 3];
        let m = PointMismatch::find(&a, &b).unwrap();
        assert_eq!((m.differing, m.farthest, m.distance), (2, 0, f64::INFINITY));
        // Far from the origin, single-precision rounding of the reference is tolerated.
        let far = [[500_000.123_456_7, 0.0, 0.0], [500_001.0, 1.0, 0.0]];
        let rounded = far.map(|p| p.map(|c| f64::from(c as f32)));
        assert_eq!(PointMismatch::find(&far, &rounded), None);
    }

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
