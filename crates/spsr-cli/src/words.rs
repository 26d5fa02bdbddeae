//! How the command line words the library's errors and warnings: the library names fields
//! (`depth`), the command line names flags (`--depth`).

use spsr::{Error, MemoryShortfall, Remedy, Warning};

/// The flag that sets a library field.
pub fn flag(field: &str) -> String {
    match field {
        "weights" => "--confidence-property".into(),
        "threshold" => "--trim".into(),
        "report_residuals" => "--residuals".into(),
        "attributes" => "attribute carrying (--no-attributes turns it off)".into(),
        "orient_neighbours" => "the orientation's neighbour count".into(),
        "scan_origins" => "the scan origins in the file".into(),
        "points" | "leaves" => field.into(),
        f => format!("--{}", f.replace('_', "-")),
    }
}

/// How the depth was chosen (`--width`, `--depth auto`), in the command line's words.
pub fn depth_choice(c: &spsr::DepthChoice) -> String {
    c.message(&flag)
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
        Error::Gpu(reason) => Some(format!(
            "no usable GPU: {reason}; run without --gpu, or with --gpu auto to fall back to \
             the CPU"
        )),
        Error::MissingDensity => Some(
            "the mesh has no per-vertex density; reconstruct it with --density to get one".into(),
        ),
        Error::Io { path, source } if disk_full(source) => Some(format!(
            "{}: {source}: the disk (or the space allowed) is full; free some space, or put \
             the output elsewhere and the spill files of --slabs on a larger disk with \
             --work-dir",
            path.display()
        )),
        _ => None,
    }
}

/// Whether a write failed for lack of space: a full disk, a quota, a file-size limit.
pub fn disk_full(e: &std::io::Error) -> bool {
    use std::io::ErrorKind as K;
    matches!(
        e.kind(),
        K::StorageFull | K::QuotaExceeded | K::FileTooLarge
    )
}

fn shortfall(m: &MemoryShortfall) -> String {
    m.message(&|field, value| match value {
        Some(v) => format!("{} {v}", flag(field)),
        None => flag(field),
    })
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
        other => other.advice(&remedy).unwrap_or_else(|| other.to_string()),
    }
}

/// A remedy a warning advises, in the command line's words.
fn remedy(r: Remedy) -> String {
    match r {
        Remedy::Field(field) => flag(field),
        Remedy::Set(field, value) => format!("{} {value}", flag(field)),
        Remedy::ReorientNormals => "re-estimate and orient the normals with --estimate-normals \
                                    (--orient global is the most robust; --orient viewpoint \
                                    for scans with known sensor positions)"
            .into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use spsr::MemoryLimit;

    /// Every field the library names in an `InvalidParameter` error, with the flag that sets
    /// it. Each flag is checked to exist on some subcommand.
    const FIELDS: [(&str, &str); 23] = [
        ("depth", "--depth"),
        ("full_depth", "--full-depth"),
        ("samples_per_node", "--samples-per-node"),
        ("point_weight", "--point-weight"),
        ("scale", "--scale"),
        ("max_memory", "--max-memory"),
        ("data_pull", "--data-pull"),
        ("iters", "--iters"),
        ("weights", "--confidence-property"),
        ("threshold", "--trim"),
        ("min_island_area", "--min-island-area"),
        ("hole_area", "--hole-area"),
        ("samples", "--samples"),
        ("reference_sphere", "--reference-sphere"),
        ("neighbours", "--neighbours"),
        ("orient_neighbours", "the orientation's neighbour count"),
        ("viewpoint", "--viewpoint"),
        ("target_error", "--target-error"),
        ("scan_origins", "the scan origins in the file"),
        ("size", "--size"),
        ("color", "--color"),
        ("view", "--view"),
        ("report_residuals", "--residuals"),
    ];

    #[test]
    fn every_library_field_maps_to_its_flag() {
        use clap::CommandFactory;
        let cli = crate::Cli::command();
        let flags: Vec<String> = cli
            .get_subcommands()
            .flat_map(|c| c.get_arguments().filter_map(|a| a.get_long()))
            .map(|l| format!("--{l}"))
            .collect();
        for (field, flag) in FIELDS {
            assert_eq!(super::flag(field), flag, "{field}");
            // --target-error is a library parameter with no flag (it keeps its default).
            if flag.starts_with("--") && field != "target_error" {
                assert!(flags.iter().any(|f| f == flag), "{flag} is no flag of spsr");
            }
        }
    }

    #[test]
    fn messages_name_the_flag_the_value_and_the_range() {
        let e = Error::invalid("samples_per_node", 0, "a positive number");
        assert_eq!(
            error(&e).unwrap(),
            "invalid parameter --samples-per-node 0: expected a positive number"
        );
        let m = MemoryShortfall {
            estimate: 3 << 30,
            limit: 1 << 30,
            source: MemoryLimit::Requested,
            nodes: 1000,
            depth: 11,
            suggested_depth: Some(9),
        };
        let text = error(&Error::ResourceLimit(m)).unwrap();
        assert!(
            text.contains("--depth 11")
                && text.contains("use --depth 9 or less")
                && text.contains("the --max-memory limit (1.00 GiB)"),
            "{text}"
        );
        let w = Warning::DroppedPoints {
            dropped: 3,
            total: 10,
        };
        assert!(warning(&w).starts_with("3 of 10 points dropped"));
    }

    #[test]
    fn the_advice_on_a_result_names_flags() {
        let d = spsr::Diagnosis {
            pieces: 40,
            closed: true,
            depth: 9,
            ..spsr::Diagnosis::default()
        };
        let text = warning(&Warning::ManyPieces(d));
        assert!(
            text.contains("--samples-per-node 5 to 10") && text.contains("--depth 8"),
            "{text}"
        );
        let open = spsr::Diagnosis { on_cube: 12, ..d };
        let text = warning(&Warning::SurfaceOnCube(open));
        assert!(
            text.contains("--estimate-normals") && text.contains("--trim auto"),
            "{text}"
        );
        let trimmed = spsr::Diagnosis {
            trimmed: true,
            ..open
        };
        assert!(!warning(&Warning::SurfaceOnCube(trimmed)).contains("--trim"));
    }
}
