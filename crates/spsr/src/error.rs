//! Errors reported by the library. Every failure a user can cause (bad files, bad parameters,
//! unusable point clouds) is a variant here; the library never panics on user input.

use std::path::PathBuf;

use crate::pipeline::diagnose::Diagnosis;

/// Everything that can go wrong in spsr, one variant per stage or validation failure.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The operating system refused a read or write.
    #[error("{}: {source}", path.display())]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file's content is malformed (bad header, truncated body, unparsable number, ...).
    #[error("{}: {message}", path.display())]
    Parse {
        /// File concerned.
        path: PathBuf,
        /// What is wrong, with the line or element where known.
        message: String,
    },
    /// The point file has positions but no normals.
    #[error("{}: the points have no normals (nx, ny, nz); spsr needs oriented points", path.display())]
    MissingNormals {
        /// File concerned.
        path: PathBuf,
    },
    /// A parameter is outside its allowed range.
    #[error("invalid parameter {field} = {value}: expected {expected}")]
    InvalidParameter {
        /// The parameter as the library names it: the field of [`crate::Params`] (or of the
        /// operation's own parameters, such as `threshold` of [`crate::trim::TrimParams`]).
        /// Front ends render it in their own spelling (`--depth`, `depth=`).
        field: &'static str,
        /// The value given, as text.
        value: String,
        /// What is allowed (for example `an integer from 1 to 18`).
        expected: String,
    },
    /// Positions and normals (or other per-point arrays) differ in length.
    #[error("length mismatch: {positions} positions but {normals} normals")]
    LengthMismatch {
        /// Number of positions.
        positions: usize,
        /// Number of normals.
        normals: usize,
    },
    /// Not enough usable points to reconstruct anything.
    #[error("too few usable points: {usable} usable, {dropped} dropped (non-finite values or zero-length normals); at least {required} are needed")]
    TooFewPoints {
        /// Points that passed the validity filter.
        usable: usize,
        /// Points that were dropped.
        dropped: usize,
        /// Minimum number of points required.
        required: usize,
    },
    /// The usable points span no volume along any axis (all identical).
    #[error("degenerate input: {0}")]
    Degenerate(String),
    /// The run would need more memory than allowed (`Params::max_memory`, or the memory the
    /// machine has available). Nothing large has been allocated yet.
    #[error("{0}")]
    ResourceLimit(MemoryShortfall),
    /// A mesh given to a mesh operation (such as [`crate::trim::trim`]) cannot be used: it
    /// lacks the per-vertex data the operation needs, holds non-finite values, refers to
    /// vertices that do not exist, or has no triangles.
    #[error("{0}")]
    InvalidMesh(String),
    /// A mesh given to trimming has no per-vertex density.
    #[error("the mesh has no per-vertex density; reconstruct it with the density on (Params::density) to get one")]
    MissingDensity,
    /// A GPU was asked for ([`crate::Params::gpu`]) and none can be used: the reason names
    /// what is missing (the build's GPU support, the driver, a device, NVRTC).
    #[error("no usable GPU: {0}")]
    Gpu(String),
    /// The output path cannot be used.
    #[error("{}: {message}", path.display())]
    Output {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// Why a run was refused for its memory: the estimate, the limit and what would fit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemoryShortfall {
    /// Estimated peak memory of the run, in bytes.
    pub estimate: u64,
    /// The limit, in bytes.
    pub limit: u64,
    /// Where the limit came from.
    pub source: MemoryLimit,
    /// Octree nodes the run would hold.
    pub nodes: usize,
    /// The depth asked for.
    pub depth: u32,
    /// The deepest depth whose levels of the same tree fit, if any does.
    pub suggested_depth: Option<u32>,
}

/// Where a memory limit came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MemoryLimit {
    /// The caller's [`crate::Params::max_memory`].
    Requested,
    /// The memory the machine had available.
    Available,
}

/// Bytes as GiB with two decimals, as messages show memory.
pub fn gib(bytes: u64) -> String {
    format!("{:.2} GiB", bytes as f64 / (1u64 << 30) as f64)
}

impl MemoryShortfall {
    /// The explanation with what to do, naming parameters as a front end spells them:
    /// `spell(field, Some(value))` for a setting (`--depth 9`, `depth=9`) and
    /// `spell(field, None)` for the parameter alone (`--max-memory`, `max_memory`).
    pub fn message(&self, spell: &dyn Fn(&str, Option<u32>) -> String) -> String {
        let what = match self.source {
            MemoryLimit::Requested => format!("the {} limit", spell("max_memory", None)),
            MemoryLimit::Available => "the memory this machine has available".into(),
        };
        let advice = match self.suggested_depth {
            Some(d) => format!(
                "use {} or less, a larger {}, or raise {}",
                spell("depth", Some(d)),
                spell("samples_per_node", None),
                spell("max_memory", None)
            ),
            None => format!(
                "even the coarsest depth does not fit: raise {} or use fewer points",
                spell("max_memory", None)
            ),
        };
        format!(
            "this reconstruction needs about {} ({} octree nodes at {}), more than {what} \
             ({}); {advice}",
            gib(self.estimate),
            self.nodes,
            spell("depth", Some(self.depth)),
            gib(self.limit)
        )
    }
}

impl std::fmt::Display for MemoryShortfall {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message(&|field, value| match value {
            Some(v) => format!("{field} {v}"),
            None => field.to_string(),
        }))
    }
}

/// Something about the input that did not stop the reconstruction but that the user should
/// hear about, with its figures. Front ends render it in their own words.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Warning {
    /// Points were left out: a non-finite coordinate, a zero-length normal, or a weight that
    /// is not a positive finite number.
    DroppedPoints {
        /// Points left out.
        dropped: usize,
        /// Points given.
        total: usize,
    },
    /// A few far points make the bounding cube much larger than the bulk of the cloud; the
    /// cube sets the finest cell size, so they silently waste depth.
    FarOutliers(FarOutliers),
    /// Many normals contradicted their neighbours; they were made consistent (the default;
    /// keep them as given with `keep_normals`).
    NormalsReoriented {
        /// Samples whose normal changed sign.
        flipped: usize,
        /// Samples (points merged per finest cell).
        samples: usize,
        /// Share of the samples whose normal pointed against their cell's before.
        disagreeing: f64,
    },
    /// The far outliers of [`Warning::FarOutliers`] were left out (the default; keep them
    /// with `keep_outliers`).
    OutliersDropped(FarOutliers),
    /// Pieces of the mesh too small to be anything but bubbles left by noise were removed
    /// (with the noise adaptation on).
    FragmentsRemoved {
        /// Pieces removed.
        pieces: usize,
    },
    /// The surface runs on to the bounding cube, which cuts it open: normals flipped in
    /// places (or an open scan, whose surface is continued to the cube).
    SurfaceOnCube(Diagnosis),
    /// Many samples' normals point against the reconstructed surface: their orientations
    /// contradict each other.
    ContradictoryNormals(Diagnosis),
    /// The mesh falls into many pieces: noise reconstructed as small bubbles.
    ManyPieces(Diagnosis),
    /// The GPU asked for ([`crate::Gpu::Auto`], or a level it could not take) was not used;
    /// the CPU did the work, with the same result.
    GpuNotUsed {
        /// Why.
        reason: String,
    },
}

/// What the advice of a [`Warning`] asks for, for a front end to spell
/// (see [`Warning::advice`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Remedy<'a> {
    /// A parameter, by its library field name (`samples_per_node`).
    Field(&'static str),
    /// A parameter set to a value (`depth` 7; `threshold` auto, the trimming's).
    Set(&'static str, &'a str),
    /// Estimating and orienting the normals anew.
    ReorientNormals,
}

/// The figures of [`Warning::FarOutliers`].
#[derive(Debug, Clone, PartialEq)]
pub struct FarOutliers {
    /// Points far outside the bulk's box.
    pub far: usize,
    /// Usable points.
    pub total: usize,
    /// Lower corner of the box that holds the bulk of the points.
    pub bulk_min: [f64; 3],
    /// Upper corner of that box.
    pub bulk_max: [f64; 3],
    /// Largest side of all the points' bounding box.
    pub extent: f64,
    /// Largest side of the bulk's box.
    pub bulk_extent: f64,
    /// The depth asked for.
    pub depth: u32,
    /// The depth that resolves the surface as finely as `depth` would without the outliers.
    pub effective_depth: u32,
    /// The depth that would make up for the outliers, when it is allowed.
    pub compensating_depth: Option<u32>,
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Warning::DroppedPoints { dropped, total } => write!(
                f,
                "{dropped} of {total} points dropped (non-finite coordinates, zero-length \
                 normals or unusable weights)"
            ),
            Warning::GpuNotUsed { reason } => {
                write!(
                    f,
                    "the GPU was not used ({reason}); the CPU did the work instead"
                )
            }
            Warning::FragmentsRemoved { pieces } => write!(
                f,
                "removed {pieces} small piece(s) of the mesh (each under 0.1 % of its area), \
                 bubbles left by noise far from the surface"
            ),
            Warning::NormalsReoriented {
                flipped,
                samples,
                disagreeing,
            } => write!(
                f,
                "{:.1} % of the normals pointed against their neighbours'; re-oriented {flipped} \
                 of {samples} samples ({:.1} %) so that each connected piece follows the \
                 clear majority of its normals, or faces outward",
                100.0 * disagreeing,
                100.0 * *flipped as f64 / (*samples).max(1) as f64
            ),
            Warning::OutliersDropped(o) => {
                let fmt = |v: [f64; 3]| format!("({:.6e}, {:.6e}, {:.6e})", v[0], v[1], v[2]);
                write!(
                    f,
                    "left out {} far outlier(s) of {} points, kept the {} points in and \
                     near the box {} to {}",
                    o.far,
                    o.total,
                    o.total - o.far,
                    fmt(o.bulk_min),
                    fmt(o.bulk_max)
                )
            }
            Warning::FarOutliers(o) => {
                write!(
                    f,
                    "{}; remove those points (crop the input to that box)",
                    o.describe("depth ")
                )?;
                if let Some(d) = o.compensating_depth {
                    write!(f, ", or raise the depth to {d}")?;
                }
                Ok(())
            }
            _ => {
                let advice = self.advice(&|r| match r {
                    Remedy::Field(field) => field.to_string(),
                    Remedy::Set(field, value) => format!("{field} {value}"),
                    Remedy::ReorientNormals => {
                        "re-orient the normals (spsr::normals::estimate_normals)".into()
                    }
                });
                f.write_str(&advice.unwrap_or_default())
            }
        }
    }
}

impl Warning {
    /// The message of a warning on the result (the [`Diagnosis`] variants): what was found,
    /// the likely cause and what helps, with parameters and remedies spelled by `spell` as the
    /// front end names them. `None` for the other warnings, which front ends word themselves.
    pub fn advice(&self, spell: &dyn Fn(Remedy) -> String) -> Option<String> {
        let pct = |share: f64| format!("{:.0} %", 100.0 * share);
        let trim = |d: &Diagnosis| {
            if d.trimmed {
                String::new()
            } else {
                format!(
                    "; if the points are an open scan, trim the invented surface with {}",
                    spell(Remedy::Set("threshold", "auto"))
                )
            }
        };
        Some(match self {
            Warning::SurfaceOnCube(d) => format!(
                "the surface runs on to the bounding cube, which cuts it open ({} vertices on \
                 the cube's faces; {}, {}): the normals are likely flipped in places; {}{}",
                d.on_cube,
                pieces(d),
                closedness(d),
                spell(Remedy::ReorientNormals),
                trim(d)
            ),
            Warning::ContradictoryNormals(d) => format!(
                "{} of the points have normals pointing into the reconstructed solid ({}, {}): \
                 their orientations contradict each other; {}",
                pct(d.contradicted_normals),
                pieces(d),
                closedness(d),
                spell(Remedy::ReorientNormals)
            ),
            Warning::ManyPieces(d) => {
                let lower = d.depth.saturating_sub(1).max(1).to_string();
                format!(
                    "the mesh falls into {} pieces: the points are likely noisy; average more \
                     samples with {} to 10, or use a lower {} (such as {})",
                    d.pieces,
                    spell(Remedy::Set("samples_per_node", "5")),
                    spell(Remedy::Field("depth")),
                    spell(Remedy::Set("depth", &lower))
                )
            }
            _ => return None,
        })
    }
}

fn pieces(d: &Diagnosis) -> String {
    match d.pieces {
        1 => "1 piece".into(),
        n => format!("{n} pieces"),
    }
}

fn closedness(d: &Diagnosis) -> String {
    if d.closed {
        "closed".into()
    } else {
        format!("open, {} boundary edges", d.boundary_edges)
    }
}

impl FarOutliers {
    /// Whether `p` is far from the bulk: outside its box grown by its own size on every side.
    pub fn is_far(&self, p: [f64; 3]) -> bool {
        Self::far_from(self.bulk_min, self.bulk_max, self.bulk_extent, p)
    }

    pub(crate) fn far_from(lo: [f64; 3], hi: [f64; 3], size: f64, p: [f64; 3]) -> bool {
        (0..3).any(|a| p[a] < lo[a] - size || p[a] > hi[a] + size)
    }

    /// The finding, with depths spelled `depth_word` followed by the number (a front end
    /// passes `"--depth "` or `"depth="`), without the advice.
    pub fn describe(&self, depth_word: &str) -> String {
        let fmt = |v: [f64; 3]| format!("({:.6e}, {:.6e}, {:.6e})", v[0], v[1], v[2]);
        format!(
            "{} of {} points ({:.3} %) lie far outside the box {} to {} that holds the \
             others; they make the points span {:.4e} units instead of {:.4e}, so the \
             finest cells are about {:.0} times coarser ({depth_word}{} resolves the \
             surface like {depth_word}{})",
            self.far,
            self.total,
            100.0 * self.far as f64 / self.total as f64,
            fmt(self.bulk_min),
            fmt(self.bulk_max),
            self.extent,
            self.bulk_extent,
            self.extent / self.bulk_extent,
            self.depth,
            self.effective_depth
        )
    }
}

impl Error {
    /// An [`Error::InvalidParameter`] for `field` holding `value`.
    pub fn invalid(
        field: &'static str,
        value: impl std::fmt::Display,
        expected: impl Into<String>,
    ) -> Self {
        Error::InvalidParameter {
            field,
            value: value.to_string(),
            expected: expected.into(),
        }
    }

    /// The same error with the file `from` called `to` (a temporary copy named after its
    /// source).
    pub(crate) fn with_path(mut self, from: &std::path::Path, to: &std::path::Path) -> Self {
        match &mut self {
            Error::Io { path, .. }
            | Error::Parse { path, .. }
            | Error::MissingNormals { path }
            | Error::Output { path, .. }
                if path == from =>
            {
                *path = to.to_path_buf();
            }
            _ => {}
        }
        self
    }
}

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;
