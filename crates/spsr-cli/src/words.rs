//! How the command line words the library's errors and warnings: the library names fields
//! (`depth`), the command line names flags (`--depth`).

use spsr::{Error, MemoryLimit, MemoryShortfall, Warning};

/// The flag that sets a library field.
pub fn flag(field: &str) -> String {
    match field {
        "weights" => "--confidence-property".into(),
        "threshold" => "--trim".into(),
        "orient_neighbours" => "--neighbours".into(),
        "scan_origins" => "the scan origins in the file".into(),
        "points" | "leaves" => field.into(),
        f => format!("--{}", f.replace('_', "-")),
    }
}

/// The message of a library error in the command line's words, where they differ from the
/// library's.
pub fn error(e: &Error) -> Option<String> {
    match e {
        Error::InvalidParameter {
            field,
            value,
            expected,
        } => Some(format!(
            "invalid parameter {} {value}: expected {expected}",
            flag(field)
        )),
        Error::ResourceLimit(m) => Some(shortfall(m)),
        Error::MissingDensity => Some(
            "the mesh has no per-vertex density; reconstruct it with --density to get one".into(),
        ),
        _ => None,
    }
}

fn shortfall(m: &MemoryShortfall) -> String {
    let what = match m.source {
        MemoryLimit::Requested => "the --max-memory limit",
        MemoryLimit::Available => "the memory this machine has available",
    };
    let advice = match m.suggested_depth {
        Some(d) => {
            format!("use --depth {d} or less, a larger --samples-per-node, or raise --max-memory")
        }
        None => {
            "even the coarsest depth does not fit: raise --max-memory or use fewer points".into()
        }
    };
    format!(
        "this reconstruction needs about {} ({} octree nodes at --depth {}), more than {what} \
         ({}); {advice}",
        spsr::gib(m.estimate),
        m.nodes,
        m.depth,
        spsr::gib(m.limit)
    )
}

/// A warning in the command line's words.
pub fn warning(w: &Warning) -> String {
    match w {
        Warning::DroppedPoints { dropped, total } => format!(
            "{dropped} of {total} points dropped (non-finite coordinates, zero-length normals \
             or unusable weights)"
        ),
        Warning::FarOutliers(o) => {
            let mut s = format!(
                "{}; remove those points (crop the input to that box)",
                o.describe("--depth ")
            );
            if let Some(d) = o.compensating_depth {
                s += &format!(", or raise --depth to {d}");
            }
            s
        }
        other => other.to_string(),
    }
}
