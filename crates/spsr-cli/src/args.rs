//! Flags and parsers that several subcommands share, declared once.

use clap::Args;

/// Worker threads, for every subcommand that runs in parallel.
#[derive(Debug, Clone, Args)]
pub struct ThreadsArg {
    /// Number of worker threads, at least 1; results do not depend on it. Default: rayon's,
    /// which honours RAYON_NUM_THREADS [default: all cores]
    #[arg(long, value_name = "N", value_parser = parse_threads, allow_negative_numbers = true)]
    pub threads: Option<usize>,
}

/// The flags of every subcommand that writes a mesh or a cloud: threads, the encoding,
/// verbosity.
#[derive(Debug, Clone, Args)]
pub struct CommonArgs {
    #[command(flatten)]
    pub threads: ThreadsArg,

    /// Write ASCII PLY or STL instead of binary (.obj and .off are always text, .glb always
    /// binary) [default: off]
    #[arg(long)]
    pub ascii: bool,

    /// Print what the run did to stderr: per-stage timings and counts (reconstruct), the
    /// threshold and what was removed (trim), the neighbourhoods and orientation (normals)
    /// [default: off]
    #[arg(short, long)]
    pub verbose: bool,
}

/// Parses a memory size: a number of bytes, optionally with a binary suffix (K, M, G, T, with
/// or without a trailing `B`/`iB`).
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let upper = t.to_ascii_uppercase();
    let body = upper.trim_end_matches("IB").trim_end_matches('B');
    let (num, mul) = match body.chars().last() {
        Some('K') => (&body[..body.len() - 1], 1u64 << 10),
        Some('M') => (&body[..body.len() - 1], 1 << 20),
        Some('G') => (&body[..body.len() - 1], 1 << 30),
        Some('T') => (&body[..body.len() - 1], 1 << 40),
        _ => (body, 1),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{t}' is not a size such as 512M or 8G"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err("must be a positive size".into());
    }
    Ok((v * mul as f64) as u64)
}

pub fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s.parse().map_err(|e| format!("{e}"))?;
    if n == 0 {
        return Err("must be at least 1".into());
    }
    Ok(n)
}
