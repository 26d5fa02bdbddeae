//! File arguments: `-` for standard input and output, reading and writing with errors that
//! name the file, and the closing summary line.

use std::path::Path;
use std::time::Instant;

/// `-` as a file name: standard input (for an input) or standard output (for an output).
pub fn is_std_stream(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// What messages call standard input and output.
const STDIN_NAME: &str = "<stdin>";
const STDOUT_NAME: &str = "<stdout>";

/// The name errors about an input give it: `<stdin>` for `-`.
pub(crate) fn input_name(path: &Path) -> &Path {
    if is_std_stream(path) {
        Path::new(STDIN_NAME)
    } else {
        path
    }
}

/// Reads a cloud with or without normals from a file, or from standard input for `-`.
pub fn read_cloud_arg(path: &Path) -> spsr::Result<spsr::PointCloud> {
    if is_std_stream(path) {
        spsr::io::read_cloud_from(std::io::stdin().lock(), Path::new(STDIN_NAME))
    } else {
        spsr::io::read_cloud(path)
    }
}

/// Reads a mesh from a file, or from standard input for `-`.
pub fn read_mesh_arg(path: &Path) -> spsr::Result<spsr::Mesh> {
    if is_std_stream(path) {
        spsr::io::read_mesh_from(std::io::stdin().lock(), Path::new(STDIN_NAME))
    } else {
        spsr::io::read_mesh(path)
    }
}

/// The up-front check of a mesh output, before any reading or computing: its extension names
/// a mesh format ([`spsr::io::MeshFormat::from_path`]), and the path can be written and is not
/// the input. Standard output (`-`, written as PLY) needs none.
pub fn check_output_arg(output: &Path, input: &Path) -> spsr::Result<()> {
    if is_std_stream(output) {
        return Ok(());
    }
    spsr::io::MeshFormat::from_path(output)?;
    spsr::io::check_output_path(output, input)
}

/// The up-front check of a point-cloud output: its extension names a format
/// [`spsr::io::write_cloud`] writes ([`spsr::io::CloudFormat::for_output`]), and the path can
/// be written and is not the input.
pub fn check_cloud_output_arg(output: &Path, input: &Path) -> spsr::Result<()> {
    spsr::io::CloudFormat::for_output(output)?;
    spsr::io::check_output_path(output, input)
}

/// Writes a mesh to a file (atomically), or as PLY to standard output for `-`.
pub fn write_mesh_arg(
    output: &Path,
    mesh: &spsr::Mesh,
    opts: &spsr::io::WriteOptions,
) -> spsr::Result<()> {
    if is_std_stream(output) {
        let mut out = std::io::stdout().lock();
        spsr::io::write_mesh_to(
            &mut out,
            Path::new(STDOUT_NAME),
            spsr::io::MeshFormat::Ply,
            mesh,
            opts,
        )
    } else {
        spsr::io::write_mesh(output, mesh, opts)
    }
}

/// The closing summary line: on stdout, or on stderr when stdout carries the mesh.
pub(crate) fn report_written(output: &Path, mesh: &spsr::Mesh, start: Instant) {
    report(
        output,
        &format!(
            "{} vertices, {} faces in {:.2} s",
            mesh.vertices.len(),
            mesh.triangles.len(),
            start.elapsed().as_secs_f64()
        ),
    );
}

/// `spsr: wrote OUTPUT: <what>`, on stdout, or on stderr when stdout carries the mesh.
pub(crate) fn report(output: &Path, what: &str) {
    let name = if is_std_stream(output) {
        Path::new(STDOUT_NAME)
    } else {
        output
    };
    let line = format!("spsr: wrote {}: {what}", name.display());
    if is_std_stream(output) {
        eprintln!("{line}");
    } else {
        println!("{line}");
    }
}
