//! The machine's memory bandwidth, for `bench/floor/run.py` (issue 20): a STREAM-style triad
//! `a[i] = b[i] + s·c[i]` over three `f64` arrays far larger than the last-level cache, run
//! `--repeats` times on 1 thread and on all of rayon's threads, best time kept.
//!
//! ```text
//! cargo run --release --example bandwidth -- [--mib M] [--repeats R] [--json]
//! ```
//!
//! Bytes are counted as STREAM counts them: 3 arrays × 8 bytes per element (b and c read, a
//! written). The write-allocate read of `a` (the cache line fetched before it is written,
//! without non-temporal stores) is *not* counted in `gbs`; `gbs_write_allocate` counts it (4 ×
//! 8 bytes), the traffic the memory actually served. The work model of `spsr::work` counts
//! bytes the STREAM way, so `gbs` is the bandwidth to compare its figures with.

use std::hint::black_box;
use std::time::Instant;

use rayon::prelude::*;

/// Elements per parallel task: large enough that scheduling is negligible.
const CHUNK: usize = 1 << 16;

fn triad_serial(a: &mut [f64], b: &[f64], c: &[f64], s: f64) {
    for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
        *a = b + s * c;
    }
}

fn triad_parallel(a: &mut [f64], b: &[f64], c: &[f64], s: f64) {
    a.par_chunks_mut(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .zip(c.par_chunks(CHUNK))
        .for_each(|((a, b), c)| triad_serial(a, b, c, s));
}

/// The best time of `repeats` triads (seconds).
fn best(repeats: usize, mut f: impl FnMut()) -> f64 {
    (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut mib = 256usize;
    let mut repeats = 10usize;
    let mut json = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--mib" => mib = args.next().ok_or("--mib needs a value")?.parse()?,
            "--repeats" => repeats = args.next().ok_or("--repeats needs a value")?.parse()?,
            "--json" => json = true,
            _ => return Err(format!("unknown argument {a}").into()),
        }
    }
    let n = mib * (1 << 20) / 8;
    // Touched in parallel, as the triad will touch them (first-touch page placement).
    let mut a = vec![0.0f64; n];
    let mut b = vec![0.0f64; n];
    let mut c = vec![0.0f64; n];
    b.par_iter_mut()
        .enumerate()
        .for_each(|(i, x)| *x = i as f64);
    c.par_iter_mut().for_each(|x| *x = 0.5);
    let s = 3.0;
    let threads = rayon::current_num_threads();
    let one = best(repeats, || triad_serial(black_box(&mut a), &b, &c, s));
    let all = best(repeats, || triad_parallel(black_box(&mut a), &b, &c, s));
    // A checked element, so the triads cannot be removed.
    let check = a[n / 3] - (b[n / 3] + s * c[n / 3]);
    assert!(check == 0.0, "the triad's result is wrong");
    let bytes = 3.0 * 8.0 * n as f64;
    let row = |t: usize, secs: f64| {
        format!(
            "{{\"threads\": {t}, \"best_s\": {secs:.6}, \"gbs\": {:.3}, \"gbs_write_allocate\": {:.3}}}",
            bytes / secs / 1e9,
            bytes * 4.0 / 3.0 / secs / 1e9
        )
    };
    if json {
        println!(
            "{{\"kernel\": \"triad\", \"elements\": {n}, \"array_mib\": {mib}, \"repeats\": {repeats}, \
             \"bytes_per_element\": 24, \"results\": [{}, {}]}}",
            row(1, one),
            row(threads, all)
        );
    } else {
        println!("triad over 3 arrays of {mib} MiB, best of {repeats} (24 bytes an element):");
        for (t, secs) in [(1, one), (threads, all)] {
            println!(
                "  {t:>3} thread(s)  {:>8.2} GB/s  ({:.2} GB/s with write-allocate)",
                bytes / secs / 1e9,
                bytes * 4.0 / 3.0 / secs / 1e9
            );
        }
    }
    Ok(())
}
